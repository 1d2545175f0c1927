//! Sparse voxel grids in SMPL coordinates, the geometry of the body volume (no tensors):
//!
//! - [`voxelize`]: SMPL-frame vertices + [`VoxelBox`] -> active sites and a vertex -> site map;
//!   [`ScaleGeometry`], the placement of each grid level.
//! - [`rulebook`]: active sites -> submanifold / strided convolution rulebooks, [`SiteIndex`];
//!   [`neighbour_maps`]: a rulebook as dense maps for the host convolution.
//! - [`corners`]: query points -> the 8 corner sites and trilinear weights on one level.
//! - [`pyramid`]: every level's sites and rulebooks of one body, remembered for recent bodies.

pub mod corners;
pub mod neighbour_maps;
pub mod pyramid;
pub mod rulebook;
pub mod voxelize;

pub use corners::{TrilinearCorners, CORNERS};
pub use neighbour_maps::NeighbourMaps;
pub use pyramid::{remembered_pyramid, shared_pyramid, SitePyramid};
pub use rulebook::{kernel_offset, Rulebook, RulebookKind, SiteIndex, KERNEL_VOLUME};
pub use voxelize::{
    strided_dim, voxelize, ScaleGeometry, VoxelBox, VoxelGridSpec, Voxelization, MAX_GRID_DIM,
    PAPER_BOX_ENLARGE, PAPER_VOXEL_SIZE_M,
};

/// An invalid input of the sparse-grid geometry, naming the argument (`field`) and what was
/// expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("body volume `{field}`: expected {expected}, got {got}")]
pub struct SparseGridError {
    pub field: &'static str,
    pub expected: String,
    pub got: String,
}

impl SparseGridError {
    pub(crate) fn invalid(
        field: &'static str,
        expected: impl Into<String>,
        got: impl std::fmt::Debug,
    ) -> Self {
        SparseGridError {
            field,
            expected: expected.into(),
            got: format!("{got:?}"),
        }
    }
}
