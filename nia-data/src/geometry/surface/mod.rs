//! Nearest-surface queries on a triangle mesh: which face of the SMPL mesh is closest to a
//! point, where on it, and at what distance. NIA reads the visibility `o_n` of a query point
//! and the skinning weights of pose animation from the nearest face (barycentric
//! interpolation of per-vertex values).
//!
//! A bounding volume hierarchy over the triangles (binned SAH build, O(F log F)) stored as a
//! flat node array with sibling nodes adjacent; queries descend nearest child first and prune
//! every subtree whose box is farther than the best distance found so far. The exact
//! point-triangle distance uses the Voronoi-region method of Ericson (Real-Time Collision
//! Detection, 5.1.5), which also yields the barycentrics.
//!
//! - [`build`]: the BVH's binned SAH build;
//! - [`any_within`]: whether any face lies within a distance (the occupancy grid's test);
//! - [`closest`]: the closest point on a triangle, and per-vertex values interpolated there.

use crate::geometry::raster::{validate_faces, MeshError};
use glam::Vec3;
use rayon::prelude::*;

mod any_within;
mod build;
mod closest;

pub(crate) use any_within::AnyWithinHint;
use build::{build, BuildRef};
pub use closest::{closest_point_on_triangle, interpolate_scalar, interpolate_weights};

/// Traversal stack entries; one sibling is pushed per level at most.
const STACK_DEPTH: usize = 64;

/// Batch queries per rayon task: large enough to amortise scheduling, small enough to balance.
const BATCH_MIN_LEN: usize = 256;

/// The closest point of the mesh to a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Nearest {
    /// Index of the nearest face; [`Nearest::MISS`] has `u32::MAX`.
    pub face: u32,
    /// Barycentrics of `point` in that face, in the face's vertex order (sum 1, each >= 0).
    pub bary: [f32; 3],
    /// [3] the closest point on the surface, metres.
    pub point: Vec3,
    /// Squared distance from the query to `point`, square metres.
    pub dist2: f32,
}

impl Nearest {
    /// What [`SurfaceIndex::nearest`] returns for a non-finite query point.
    pub const MISS: Nearest = Nearest {
        face: u32::MAX,
        bary: [0.0; 3],
        point: Vec3::splat(f32::NAN),
        dist2: f32::INFINITY,
    };

    /// Whether this is a real result (not [`Nearest::MISS`]).
    pub fn is_hit(&self) -> bool {
        self.face != u32::MAX
    }

    /// Distance to the surface, metres.
    pub fn dist(&self) -> f32 {
        self.dist2.sqrt()
    }
}

/// A BVH node, 32 bytes. Interior: `count == 0`, children at `index` and `index + 1`.
/// Leaf: triangles `index .. index + count` of the leaf-ordered arrays.
#[derive(Debug, Clone, Copy)]
#[repr(C)]
struct Node {
    min: Vec3,
    index: u32,
    max: Vec3,
    count: u32,
}

impl Node {
    /// Squared distance from `p` to the box (0 inside).
    #[inline(always)]
    fn dist2(&self, p: Vec3) -> f32 {
        let d = (self.min - p).max(p - self.max).max(Vec3::ZERO);
        d.dot(d)
    }
}

/// A BVH over a mesh's triangles for nearest-point queries. Holds a copy of the geometry.
#[derive(Debug, Clone)]
pub struct SurfaceIndex {
    nodes: Vec<Node>,
    /// Leaf-ordered triangles `[a, b, c]`, world metres, in the face's vertex order.
    tris: Vec<[Vec3; 3]>,
    /// Leaf-ordered original face index.
    tri_face: Vec<u32>,
    faces: Vec<[u32; 3]>,
    num_vertices: usize,
}

impl SurfaceIndex {
    /// Builds the index. `vertices`: [V] metres, finite; `faces`: [F >= 1] index triples.
    pub fn new(vertices: &[Vec3], faces: &[[u32; 3]]) -> Result<Self, MeshError> {
        const WHAT: &str = "SurfaceIndex::new";
        if faces.is_empty() {
            return Err(MeshError::Invalid {
                what: WHAT,
                field: "faces",
                expected: "at least one face",
            });
        }
        validate_faces(WHAT, "vertices", vertices.len(), faces)?;
        if !vertices.iter().all(|v| v.is_finite()) {
            return Err(MeshError::Invalid {
                what: WHAT,
                field: "vertices",
                expected: "finite coordinates",
            });
        }
        let refs: Vec<BuildRef> = faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| vertices[i as usize]);
                let min = a.min(b).min(c);
                let max = a.max(b).max(c);
                BuildRef {
                    min,
                    max,
                    centroid: (a + b + c) / 3.0,
                }
            })
            .collect();
        let mut order: Vec<u32> = (0..faces.len() as u32).collect();
        let nodes = build(&refs, &mut order);
        let tris = order
            .iter()
            .map(|&f| faces[f as usize].map(|i| vertices[i as usize]))
            .collect();
        Ok(SurfaceIndex {
            nodes,
            tris,
            tri_face: order,
            faces: faces.to_vec(),
            num_vertices: vertices.len(),
        })
    }

    /// The faces the index was built on.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }

    /// Number of vertices of the indexed mesh.
    pub fn num_vertices(&self) -> usize {
        self.num_vertices
    }

    /// The nearest surface point to `p` (metres); [`Nearest::MISS`] if `p` is not finite.
    pub fn nearest(&self, p: Vec3) -> Nearest {
        self.search(p, f32::INFINITY).unwrap_or(Nearest::MISS)
    }

    /// The nearest surface point if it lies within `max_dist` metres of `p` (inclusive);
    /// subtrees farther than that are never visited, so far points are cheap.
    pub fn nearest_within(&self, p: Vec3, max_dist: f32) -> Option<Nearest> {
        if !(max_dist >= 0.0) {
            return None;
        }
        let r2 = max_dist * max_dist;
        // The search keeps strictly closer candidates: start just above r^2 to include it.
        let bound = if r2.is_finite() {
            f32::from_bits(r2.to_bits() + 1)
        } else {
            f32::INFINITY
        };
        self.search(p, bound).filter(|n| n.dist2 <= r2)
    }

    /// [N] nearest points, in parallel.
    pub fn nearest_batch(&self, points: &[Vec3]) -> Vec<Nearest> {
        points
            .par_iter()
            .with_min_len(BATCH_MIN_LEN)
            .map(|p| self.nearest(*p))
            .collect()
    }

    /// [N] [`SurfaceIndex::nearest_within`], in parallel.
    pub fn nearest_batch_within(&self, points: &[Vec3], max_dist: f32) -> Vec<Option<Nearest>> {
        points
            .par_iter()
            .with_min_len(BATCH_MIN_LEN)
            .map(|p| self.nearest_within(*p, max_dist))
            .collect()
    }

    /// Nearest-first, box-pruned traversal; candidates must be strictly closer than `bound`.
    fn search(&self, p: Vec3, bound: f32) -> Option<Nearest> {
        if !p.is_finite() {
            return None;
        }
        let mut best_d2 = bound;
        let mut best: Option<(usize, [f32; 3], Vec3)> = None;
        let mut stack = [(0u32, 0.0f32); STACK_DEPTH];
        let mut top = 0usize;
        let nodes = &self.nodes[..];
        let mut node = 0usize;
        if !(nodes[0].dist2(p) < best_d2) {
            return None;
        }
        loop {
            let n = &nodes[node];
            if n.count > 0 {
                let start = n.index as usize;
                for (k, tri) in self.tris[start..start + n.count as usize]
                    .iter()
                    .enumerate()
                {
                    let (q, bary) = closest_point_on_triangle(p, tri[0], tri[1], tri[2]);
                    let d = q - p;
                    let d2 = d.dot(d);
                    if d2 < best_d2 {
                        best_d2 = d2;
                        best = Some((start + k, bary, q));
                    }
                }
            } else {
                let left = n.index as usize;
                let dl = nodes[left].dist2(p);
                let dr = nodes[left + 1].dist2(p);
                let (near, d_near, far, d_far) = if dl <= dr {
                    (left, dl, left + 1, dr)
                } else {
                    (left + 1, dr, left, dl)
                };
                if d_near < best_d2 {
                    if d_far < best_d2 && top < STACK_DEPTH {
                        stack[top] = (far as u32, d_far);
                        top += 1;
                    }
                    node = near;
                    continue;
                }
            }
            // Pop the next subtree that can still hold a closer point.
            loop {
                if top == 0 {
                    return best.map(|(t, bary, point)| Nearest {
                        face: self.tri_face[t],
                        bary,
                        point,
                        dist2: best_d2,
                    });
                }
                top -= 1;
                let (m, d) = stack[top];
                if d < best_d2 {
                    node = m as usize;
                    break;
                }
            }
        }
    }
}
