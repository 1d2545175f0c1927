//! Occupancy grids of recently seen meshes, shared instead of rebuilt.
//!
//! [`OccupancyGrid::build`] is a pure function of the mesh and the two distances, and the same
//! posed meshes come back again and again: training draws its scenes from a few subjects and
//! frames (the quickstart: 18 meshes over 1000 steps, each step building the band sampler's
//! grid, 11 % of the step's time in `perf`), and evaluation renders several target views of
//! each frame. [`shared_grid`] returns the grid of a mesh built before (compared exactly:
//! every vertex coordinate's bits, every face, both distances) or builds and remembers it. The
//! memo holds the [`MEMO_ENTRIES`] most recently used grids (about 0.2 MB each at the default
//! cells), process-wide ([`super::mesh_memo`]).

use std::sync::Arc;

use glam::Vec3;

use super::mesh_memo::MeshMemo;
use super::occupancy::{OccupancyError, OccupancyGrid};

/// Grids the memo keeps (most recently used first).
pub const MEMO_ENTRIES: usize = 64;

static MEMO: MeshMemo<OccupancyGrid> = MeshMemo::new(MEMO_ENTRIES);

/// The occupancy grid of the mesh (`vertices` [V] world metres, `faces` [F]) at `threshold_m`
/// and `cell_m`: the one built before for exactly this mesh and these distances, else a new
/// [`OccupancyGrid::build`], remembered. Errors are [`OccupancyGrid::build`]'s (not
/// remembered).
pub fn shared_grid(
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    threshold_m: f32,
    cell_m: f32,
) -> Result<Arc<OccupancyGrid>, OccupancyError> {
    let settings = [threshold_m.to_bits(), cell_m.to_bits()];
    MEMO.get_or_build(vertices, faces, &settings, || {
        OccupancyGrid::build(vertices, faces, threshold_m, cell_m)
    })
}

/// The grid [`shared_grid`] remembers for exactly this mesh and these distances, without
/// building one (`None` when it holds none).
pub fn remembered(
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    threshold_m: f32,
    cell_m: f32,
) -> Option<Arc<OccupancyGrid>> {
    MEMO.remembered(vertices, faces, &[threshold_m.to_bits(), cell_m.to_bits()])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetrahedron(scale: f32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let v = vec![
            Vec3::ZERO,
            Vec3::X * scale,
            Vec3::Y * scale,
            Vec3::Z * scale,
        ];
        (v, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    }

    #[test]
    fn the_same_mesh_shares_its_grid_and_any_change_builds_a_new_one() {
        let (v, f) = tetrahedron(0.3);
        let a = shared_grid(&v, &f, 0.03, 0.02).unwrap();
        let b = shared_grid(&v, &f, 0.03, 0.02).unwrap();
        assert!(Arc::ptr_eq(&a, &b), "same mesh, same grid");
        // The shared grid is the grid a fresh build gives.
        let fresh = OccupancyGrid::build(&v, &f, 0.03, 0.02).unwrap();
        for p in [
            Vec3::splat(0.05),
            Vec3::splat(0.5),
            Vec3::new(0.3, 0.0, 0.0),
        ] {
            assert_eq!(a.occupied(p), fresh.occupied(p), "{p}");
        }
        // A moved vertex, another distance or another cell: another grid.
        let mut moved = v.clone();
        moved[3].z += 1e-6;
        let c = shared_grid(&moved, &f, 0.03, 0.02).unwrap();
        assert!(!Arc::ptr_eq(&a, &c));
        assert!(!Arc::ptr_eq(&a, &shared_grid(&v, &f, 0.05, 0.02).unwrap()));
        assert!(!Arc::ptr_eq(&a, &shared_grid(&v, &f, 0.03, 0.01).unwrap()));
        // Errors are reported, not remembered.
        assert!(shared_grid(&v, &f, -1.0, 0.02).is_err());
        assert!(shared_grid(&v, &f, -1.0, 0.02).is_err());
    }
}
