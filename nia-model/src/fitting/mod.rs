//! Fitting SMPL to calibrated multi-view photos (2D keypoints and person masks), with burn's
//! autodiff on the CPU. What `nia-train prepare` runs to turn a user's capture into the
//! ZJU-MoCap layout.
//!
//! - [`smpl_layer`]: SMPL's LBS on tensors for a vertex subset (differentiable);
//! - [`rotation`]: Rodrigues on tensors;
//! - [`projection`]: the cameras as tensors (OpenCV model with distortion);
//! - [`observation`]: what a frame gives (keypoints, their bindings to the body, silhouettes);
//! - [`silhouette`]: a mask's distance map and boundary sample;
//! - [`initialise`]: triangulated keypoints and the torso's rigid placement;
//! - [`objective`]: the energy (keypoints with Geman-McClure, silhouettes, priors, temporal);
//! - [`adam`]: the host-side optimiser; [`fitter`]: the stages; [`config`], [`error`].
//!
//! This module reads no files; masks come in as pixel buffers.

pub mod adam;
pub mod config;
pub mod error;
pub mod fitter;
pub mod initialise;
pub mod objective;
pub mod observation;
pub mod projection;
pub mod rotation;
pub mod silhouette;
pub mod smpl_layer;

pub use config::FitConfig;
pub use error::FitError;
pub use fitter::{FitProgress, Fitter, FrameFit, SubjectFit};
pub use observation::{FrameObservation, KeypointBinding, ViewObservation};
pub use silhouette::SilhouetteTarget;
pub use smpl_layer::{PosedBatch, SmplLayer, BODY_POSE_DIM};
