//! SMPL fitted to what images show: one room for every fit nia-rs makes.
//!
//! - The energy: keypoints ([`keypoints`]: detections against the body's keypoints,
//!   Geman-McClure), silhouettes ([`silhouette`]: the one silhouette energy, vertices outside
//!   a mask pulled in and mask boundaries pulled out, Geman-McClure) and priors ([`priors`]:
//!   a pose prior, joint limits, temporal terms, a shape prior).
//! - The one optimiser ([`solver`]): Levenberg-Marquardt on reweighted least squares, steps
//!   accepted only where the energy falls and the fit stays within its bounds.
//! - The parameterisation ([`body`], [`Freedom`]), the one thing that differs between the
//!   fits: the body moved rigidly, its joints bent, or its shape fitted as well.
//!
//! Who uses it:
//! - the loader ([`align`]): a stored fit moved onto a scene's source masks before anything
//!   reads it (`[data] smpl_alignment`): rigid, then the joints;
//! - `nia-train prepare` ([`fitter`]): a user's capture fitted from keypoints and masks:
//!   rigid on the torso keypoints, the joints, the shape over a few frames, then every frame.
//!
//! Host code only, no tensors.

pub mod align;
pub mod body;
pub mod config;
pub mod error;
pub mod fitter;
pub mod initialise;
pub mod keypoints;
pub mod observation;
pub(crate) mod priors;
pub(crate) mod problem;
pub mod projection;
pub mod silhouette;
pub(crate) mod solver;

pub use align::{align_fit, align_to_masks, refine_pose, AlignedFit, AlignmentView};
pub use body::{Freedom, RigidMotion};
pub use config::{FitConfig, SmplAlignment};
pub use error::FitError;
pub use fitter::{FitProgress, Fitter, FrameFit, SubjectFit};
pub use keypoints::KeypointBinding;
pub use observation::{FrameObservation, ViewObservation};
pub use projection::Pixels;
pub use silhouette::SilhouetteTarget;
