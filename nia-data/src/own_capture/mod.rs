//! Inputs of "bring your own capture": what a user with their own multi-view rig has, read
//! into the project's types, so `nia-train prepare` can fit SMPL and write the ZJU-MoCap
//! layout the readers take. Formats in docs/data.md, "Own-capture inputs".
//!
//! - [`keypoints`]: 2D keypoints in OpenPose's JSON (BODY_25, COCO-18), read and written;
//! - [`keypoint_map`]: where each OpenPose keypoint lies on an SMPL-compatible body (joints,
//!   joint midpoints, surface vertices), and the 3D keypoints of a posed body;
//! - [`cameras`]: COLMAP's text model and a small `cameras.json` (ZJU-MoCap's `annots.npy` is
//!   read by [`crate::dataset::zju::read_annots`]);
//! - [`error`]: [`OwnCaptureError`], naming the file, the line or field, and what was expected.

pub mod cameras;
pub mod error;
pub mod keypoint_map;
pub mod keypoints;

pub use cameras::{read_cameras_json, read_colmap_text, write_cameras_json, write_colmap_text};
pub use error::OwnCaptureError;
pub use keypoint_map::{keypoint_sources, keypoints_3d, KeypointSource};
pub use keypoints::{keypoint_names, read_openpose, write_openpose, KeypointLayout, Keypoints2d};
