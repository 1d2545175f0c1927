//! Occupancy grids of recently seen meshes, shared instead of rebuilt.
//!
//! [`OccupancyGrid::build`] is a pure function of the mesh and the two distances, and the same
//! posed meshes come back again and again: training draws its scenes from a few subjects and
//! frames (the quickstart: 18 meshes over 1000 steps, each step building the band sampler's
//! grid, 11 % of the step's time in `perf`), and evaluation renders several target views of
//! each frame. [`shared_grid`] returns the grid of a mesh built before (compared exactly:
//! every vertex coordinate's bits, every face, both distances) or builds and remembers it. The
//! memo holds the [`MEMO_ENTRIES`] most recently used grids (about 0.2 MB each at the default
//! cells), process-wide, behind a mutex; a build runs outside the lock.

use std::collections::VecDeque;
use std::hash::{Hash, Hasher};
use std::sync::{Arc, Mutex};

use glam::Vec3;

use super::occupancy::{OccupancyError, OccupancyGrid};

/// Grids the memo keeps (most recently used first).
pub const MEMO_ENTRIES: usize = 64;

struct Entry {
    hash: u64,
    threshold_bits: u32,
    cell_bits: u32,
    vertices: Vec<Vec3>,
    faces: Vec<[u32; 3]>,
    grid: Arc<OccupancyGrid>,
}

impl Entry {
    fn matches(&self, hash: u64, vertices: &[Vec3], faces: &[[u32; 3]], t: u32, c: u32) -> bool {
        self.hash == hash
            && self.threshold_bits == t
            && self.cell_bits == c
            && self.faces.as_slice() == faces
            && self.vertices.len() == vertices.len()
            && self
                .vertices
                .iter()
                .zip(vertices)
                .all(|(a, b)| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits))
    }
}

static MEMO: Mutex<VecDeque<Entry>> = Mutex::new(VecDeque::new());

fn mesh_hash(vertices: &[Vec3], faces: &[[u32; 3]], t: u32, c: u32) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    (t, c, vertices.len(), faces.len()).hash(&mut h);
    for v in vertices {
        v.to_array().map(f32::to_bits).hash(&mut h);
    }
    faces.hash(&mut h);
    h.finish()
}

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
    let (t, c) = (threshold_m.to_bits(), cell_m.to_bits());
    let hash = mesh_hash(vertices, faces, t, c);
    {
        let mut memo = MEMO.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = memo
            .iter()
            .position(|e| e.matches(hash, vertices, faces, t, c))
        {
            let entry = memo.remove(i).expect("found above");
            let grid = entry.grid.clone();
            memo.push_front(entry);
            return Ok(grid);
        }
    }
    let grid = Arc::new(OccupancyGrid::build(vertices, faces, threshold_m, cell_m)?);
    let mut memo = MEMO.lock().unwrap_or_else(|e| e.into_inner());
    memo.push_front(Entry {
        hash,
        threshold_bits: t,
        cell_bits: c,
        vertices: vertices.to_vec(),
        faces: faces.to_vec(),
        grid: grid.clone(),
    });
    memo.truncate(MEMO_ENTRIES);
    Ok(grid)
}

/// The grid [`shared_grid`] remembers for exactly this mesh and these distances, without
/// building one (`None` when it holds none).
pub fn remembered(
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    threshold_m: f32,
    cell_m: f32,
) -> Option<Arc<OccupancyGrid>> {
    let (t, c) = (threshold_m.to_bits(), cell_m.to_bits());
    let hash = mesh_hash(vertices, faces, t, c);
    let memo = MEMO.lock().unwrap_or_else(|e| e.into_inner());
    memo.iter()
        .find(|e| e.matches(hash, vertices, faces, t, c))
        .map(|e| e.grid.clone())
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
