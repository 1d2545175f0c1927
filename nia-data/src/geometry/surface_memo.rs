//! Nearest-surface indices of recently seen meshes, shared instead of rebuilt.
//!
//! Every scene's geometry ([`crate::scene::SceneGeometry`]) holds the [`SurfaceIndex`] of its
//! posed body (the band sampler's and the ray box's nearest-surface queries). Building the BVH
//! of a 12k-face body was 2 % of the quickstart's step, on the thread that trains; the loader's
//! workers now build it ahead ([`crate::dataset::loader`]) and the step finds it here. Compared
//! bit for bit ([`super::mesh_memo`]), so the index is the one a fresh build gives.

use std::sync::Arc;

use glam::Vec3;

use super::mesh_memo::MeshMemo;
use super::raster::MeshError;
use super::surface::SurfaceIndex;

/// Indices the memo keeps (about 1 MB each for a 12k-face body).
pub const MEMO_ENTRIES: usize = 16;

static MEMO: MeshMemo<SurfaceIndex> = MeshMemo::new(MEMO_ENTRIES);

/// The [`SurfaceIndex`] of the mesh (`vertices` [V] metres, `faces` [F]): the one built before
/// for exactly this mesh, else [`SurfaceIndex::new`], remembered. Errors are
/// [`SurfaceIndex::new`]'s (not remembered).
pub fn shared_surface(
    vertices: &[Vec3],
    faces: &[[u32; 3]],
) -> Result<Arc<SurfaceIndex>, MeshError> {
    MEMO.get_or_build(vertices, faces, &[], || SurfaceIndex::new(vertices, faces))
}

/// The index [`shared_surface`] remembers for exactly this mesh, without building one (`None`
/// when it holds none).
pub fn remembered_surface(vertices: &[Vec3], faces: &[[u32; 3]]) -> Option<Arc<SurfaceIndex>> {
    MEMO.remembered(vertices, faces, &[])
}
