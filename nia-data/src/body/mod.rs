//! The body model: SMPL (loaded from the user's model file) or a procedural SMPL-compatible
//! body, linear blend skinning, and procedural motions.
//!
//! - [`smpl`]: [`BodyModel`], its validation, loading (`.pkl`/`.npz`) and SMPL-keyed arrays.
//! - [`lbs`]: SMPL's linear blend skinning with ZJU-MoCap's `Rh`/`Th`, and the per-point
//!   helpers reposing needs ([`rodrigues`], [`blend_transform`], [`inverse_lbs`]).
//! - [`procedural`]: a watertight, rigged human of SMPL's skeleton from a [`ProceduralSpec`].
//! - [`motion`]: walking and arm-swinging poses in SMPL axis-angle.
//! - [`reposing`]: the reposing transform of pose animation (target pose -> reference pose).
//! - [`topology`]: closed-manifold, orientation and Euler-characteristic checks of a mesh.

pub mod error;
pub mod lbs;
pub mod motion;
pub mod procedural;
pub mod reposing;
pub mod smpl;
pub mod topology;

pub use error::{BodyError, IN_MEMORY};
pub use lbs::{
    blend_transform, inverse_lbs, pose_feature, rodrigues, rodrigues_f64, Posed, PosedAt,
    SmplParams, INVERSE_LBS_MIN_DET,
};
pub use motion::{pose_for_motion, MotionKind};
pub use procedural::{ProceduralBody, ProceduralSpec};
pub use reposing::{Reposer, RepositionError, RepositionedPoints};
pub use smpl::{
    BodyModel, JOINT_NAMES, KINTREE_ROOT, NUM_JOINTS, NUM_POSE_FEATURES, SMPL_KEYS, SMPL_PARENTS,
    WEIGHT_SUM_TOL,
};
pub use topology::{signed_volume, MeshTopology};
