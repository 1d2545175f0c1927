//! The implicit body volume (docs/method.md "Method", step 3): per-vertex features of every source
//! view are placed in a sparse voxel grid in SMPL coordinates and diffused by a sparse 3D
//! convolution network (Neural Body / NHP `SparseConvNet`), then read back at four scales by
//! trilinear sampling at query points, on the active sites only (no dense grid anywhere).
//!
//! Pipeline, per frame (geometry: CPU, once, in [`nia_data::geometry::sparse`]: voxelisation,
//! active sites, rulebooks, trilinear corners) and per forward (tensors, here):
//! - [`sparse_conv`]: [`SparseConv3d`], a gather / matmul / scatter convolution on the sites.
//! - [`host_conv`]: the same convolution on flex's buffers, forward and a hand-written backward.
//! - [`site_norm`]: [`SiteNorm`], per-view channel normalisation over the active sites.
//! - [`network`]: [`BodyVolumeNet`] and [`BodyVolumeGeometry`] -> [`BodyVolume`].
//! - [`trilinear`]: the tensor-side trilinear sampling at the corners of the query points.
//! - `view_rows`: the row indices of N stacked views, laid out on the host.
//!
//! Coordinates: `x_smpl = (x_world - Th) @ R(Rh)` (the caller converts), metres.

use nia_data::geometry::sparse::SparseGridError;

pub mod host_conv;
pub mod host_read;
pub mod im2col_op;
pub mod network;
pub mod site_norm;
pub mod site_norm_device;
pub mod site_norm_op;
pub mod sparse_conv;
pub mod trilinear;
mod view_rows;

pub use host_read::HostVolume;
pub use network::{
    BodyVolume, BodyVolumeGeometry, BodyVolumeNet, BodyVolumeNetConfig, ScaleVolume, NUM_SCALES,
};
pub use site_norm::{SiteNorm, SiteNormConfig};
pub use sparse_conv::{ConvMethod, RulebookTensors, SparseConv3d, SparseConv3dConfig};
pub use trilinear::TrilinearTensors;

/// Errors of the body volume: bad geometry inputs or tensors whose shapes do not match the
/// geometry they are used with. Each names the argument (`field`) and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BodyVolumeError {
    /// The sparse-grid geometry (voxel box, vertices, sites) was invalid.
    #[error(transparent)]
    Grid(#[from] SparseGridError),
    /// An argument had an invalid value (empty, non-finite, non-positive, out of range).
    #[error("body volume `{field}`: expected {expected}, got {got}")]
    Invalid {
        field: &'static str,
        expected: String,
        got: String,
    },
    /// A tensor's shape did not match the geometry or the layer.
    #[error("body volume `{field}`: expected shape {expected}, got {got:?}")]
    Shape {
        field: &'static str,
        expected: String,
        got: Vec<usize>,
    },
}

impl BodyVolumeError {
    pub(crate) fn invalid(
        field: &'static str,
        expected: impl Into<String>,
        got: impl std::fmt::Debug,
    ) -> Self {
        BodyVolumeError::Invalid {
            field,
            expected: expected.into(),
            got: format!("{got:?}"),
        }
    }

    pub(crate) fn shape(field: &'static str, expected: impl Into<String>, got: &[usize]) -> Self {
        BodyVolumeError::Shape {
            field,
            expected: expected.into(),
            got: got.to_vec(),
        }
    }
}
