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

// `!(a < b)` comparisons are deliberate: they reject NaN along with the failing case.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::geometry::raster::{validate_faces, MeshError};
use glam::Vec3;
use rayon::prelude::*;

/// Triangles per leaf: small leaves prune better, large ones amortise the box tests; 4 is the
/// usual sweet spot for closest-point queries.
const MAX_LEAF: usize = 4;

/// SAH bins per axis.
const SAH_BINS: usize = 16;

/// Below this depth splits use SAH; deeper (rare, very unbalanced inputs) they use the median,
/// which halves the count, so the tree depth stays below [`STACK_DEPTH`] for any F < 2^31.
const SAH_MAX_DEPTH: usize = 30;

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

/// The face that answered a run of [`SurfaceIndex::any_within_squared`] queries last (leaf
/// order), tried first by the next query.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct AnyWithinHint {
    last: Option<u32>,
}

/// What [`SurfaceIndex::any_within_squared`] found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Reach {
    /// A face within the distance.
    Within,
    /// No face within the distance; every face is at least `lower_bound2.sqrt()` away (up to
    /// rounding: callers keep a margin).
    Beyond { lower_bound2: f32 },
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

/// Per-triangle build record.
#[derive(Debug, Clone, Copy)]
struct BuildRef {
    min: Vec3,
    max: Vec3,
    centroid: Vec3,
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

    /// Whether some face lies within `max_dist` metres of `p` (inclusive): the test
    /// `nearest_within(p, max_dist).is_some()` answers, but it stops at the first face found
    /// instead of looking for the nearest. `false` for a non-finite `p` or a negative or NaN
    /// `max_dist`.
    pub fn any_within(&self, p: Vec3, max_dist: f32) -> bool {
        if !(max_dist >= 0.0) {
            return false;
        }
        let mut hint = AnyWithinHint::default();
        matches!(
            self.any_within_squared(p, max_dist * max_dist, &mut hint),
            Reach::Within
        )
    }

    /// [`Self::any_within`] for the squared distance `r2`: [`Reach::Within`] when some face's
    /// closest point `q` has `(q - p).length_squared() <= r2` (that exact f32 test, so a caller
    /// that tested faces one by one gets the same answers); otherwise a lower bound on the
    /// distance from `p` to the mesh, which lets the caller pass over points near `p`. `hint`
    /// remembers the face that answered last and is tried first: neighbouring queries are
    /// often answered by the same face. A non-finite `p` or a negative or NaN `r2` is
    /// [`Reach::Beyond`] with a bound of 0.
    pub(crate) fn any_within_squared(&self, p: Vec3, r2: f32, hint: &mut AnyWithinHint) -> Reach {
        const NOTHING_KNOWN: Reach = Reach::Beyond { lower_bound2: 0.0 };
        if !(p.is_finite() && r2 >= 0.0) {
            return NOTHING_KNOWN;
        }
        let distance2 = |t: usize| {
            let tri = &self.tris[t];
            let (q, _) = closest_point_on_triangle(p, tri[0], tri[1], tri[2]);
            (q - p).length_squared()
        };
        // Every face not yet tested lies in a subtree that is pruned or still to visit; the
        // smallest distance of the faces tested and the boxes pruned bounds the mesh's.
        let mut lower2 = f32::INFINITY;
        if let Some(t) = hint.last {
            let d2 = distance2(t as usize);
            if d2 <= r2 {
                return Reach::Within;
            }
        }
        // Boxes are pruned against a slightly larger bound: a box holds its triangles exactly,
        // but the closest point on a triangle is computed with rounding, which must not make a
        // box look farther than a triangle inside it.
        let prune2 = r2 * (1.0 + 1e-4) + 1e-12;
        let nodes = &self.nodes[..];
        let mut stack = [0u32; STACK_DEPTH];
        let mut top = 0usize;
        let mut node = 0usize;
        let root2 = nodes[0].dist2(p);
        if !(root2 <= prune2) {
            return Reach::Beyond {
                lower_bound2: root2,
            };
        }
        loop {
            let n = &nodes[node];
            if n.count > 0 {
                let start = n.index as usize;
                for t in start..start + n.count as usize {
                    let d2 = distance2(t);
                    if d2 <= r2 {
                        hint.last = Some(t as u32);
                        return Reach::Within;
                    }
                    lower2 = lower2.min(d2);
                }
            } else {
                let left = n.index as usize;
                let (dl, dr) = (nodes[left].dist2(p), nodes[left + 1].dist2(p));
                let (near_left, near_right) = (dl <= prune2, dr <= prune2);
                if !near_left {
                    lower2 = lower2.min(dl);
                }
                if !near_right {
                    lower2 = lower2.min(dr);
                }
                match (near_left, near_right) {
                    (true, true) => {
                        // The nearer child first: where a face is close, it is found sooner.
                        let (near, far) = if dl <= dr {
                            (left, left + 1)
                        } else {
                            (left + 1, left)
                        };
                        if top < STACK_DEPTH {
                            stack[top] = far as u32;
                            top += 1;
                        }
                        node = near;
                        continue;
                    }
                    (true, false) => {
                        node = left;
                        continue;
                    }
                    (false, true) => {
                        node = left + 1;
                        continue;
                    }
                    (false, false) => {}
                }
            }
            if top == 0 {
                return Reach::Beyond {
                    lower_bound2: lower2,
                };
            }
            top -= 1;
            node = stack[top] as usize;
        }
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

/// Builds the flat BVH, reordering `order` into leaf order. Root is node 0.
fn build(refs: &[BuildRef], order: &mut [u32]) -> Vec<Node> {
    let mut nodes = Vec::with_capacity(2 * refs.len().div_ceil(MAX_LEAF) + 1);
    nodes.push(Node {
        min: Vec3::ZERO,
        index: 0,
        max: Vec3::ZERO,
        count: 0,
    });
    // (node, start, end, depth)
    let mut tasks = vec![(0usize, 0usize, order.len(), 0usize)];
    while let Some((ni, start, end, depth)) = tasks.pop() {
        let range = &mut order[start..end];
        let (mut bmin, mut bmax) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let (mut cmin, mut cmax) = (bmin, bmax);
        for &t in range.iter() {
            let r = &refs[t as usize];
            bmin = bmin.min(r.min);
            bmax = bmax.max(r.max);
            cmin = cmin.min(r.centroid);
            cmax = cmax.max(r.centroid);
        }
        nodes[ni].min = bmin;
        nodes[ni].max = bmax;
        let count = end - start;
        if count <= MAX_LEAF {
            nodes[ni].index = start as u32;
            nodes[ni].count = count as u32;
            continue;
        }
        let split = if depth < SAH_MAX_DEPTH {
            sah_split(refs, range, cmin, cmax)
        } else {
            None
        }
        .unwrap_or_else(|| median_split(refs, range, cmin, cmax));
        let mid = start + split;
        let left = nodes.len();
        for _ in 0..2 {
            nodes.push(Node {
                min: Vec3::ZERO,
                index: 0,
                max: Vec3::ZERO,
                count: 0,
            });
        }
        nodes[ni].index = left as u32;
        nodes[ni].count = 0;
        tasks.push((left + 1, mid, end, depth + 1));
        tasks.push((left, start, mid, depth + 1));
    }
    nodes
}

fn surface_area(min: Vec3, max: Vec3) -> f32 {
    let e = (max - min).max(Vec3::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// Binned SAH over the three axes; partitions `range` and returns the split position (both
/// sides non-empty), or `None` if no bin boundary separates the centroids.
fn sah_split(refs: &[BuildRef], range: &mut [u32], cmin: Vec3, cmax: Vec3) -> Option<usize> {
    #[derive(Clone, Copy)]
    struct Bin {
        min: Vec3,
        max: Vec3,
        count: usize,
    }
    let empty = Bin {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
        count: 0,
    };
    let extent = cmax - cmin;
    let mut best: Option<(f32, usize, usize)> = None; // (cost, axis, bins left of the split)
    for axis in 0..3 {
        if !(extent[axis] > 0.0) {
            continue;
        }
        let scale = SAH_BINS as f32 / extent[axis];
        let bin_of = |c: f32| (((c - cmin[axis]) * scale) as usize).min(SAH_BINS - 1);
        let mut bins = [empty; SAH_BINS];
        for &t in range.iter() {
            let r = &refs[t as usize];
            let b = &mut bins[bin_of(r.centroid[axis])];
            b.min = b.min.min(r.min);
            b.max = b.max.max(r.max);
            b.count += 1;
        }
        // Suffix sweeps: right side areas and counts for each split k (left = bins[..k]).
        let mut right_area = [0.0f32; SAH_BINS];
        let mut right_count = [0usize; SAH_BINS];
        let mut acc = empty;
        for k in (1..SAH_BINS).rev() {
            acc.min = acc.min.min(bins[k].min);
            acc.max = acc.max.max(bins[k].max);
            acc.count += bins[k].count;
            right_area[k] = surface_area(acc.min, acc.max);
            right_count[k] = acc.count;
        }
        let mut acc = empty;
        for k in 1..SAH_BINS {
            acc.min = acc.min.min(bins[k - 1].min);
            acc.max = acc.max.max(bins[k - 1].max);
            acc.count += bins[k - 1].count;
            if acc.count == 0 || right_count[k] == 0 {
                continue;
            }
            let cost = acc.count as f32 * surface_area(acc.min, acc.max)
                + right_count[k] as f32 * right_area[k];
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, k));
            }
        }
    }
    let (_, axis, k) = best?;
    let scale = SAH_BINS as f32 / extent[axis];
    let bin_of = |c: f32| (((c - cmin[axis]) * scale) as usize).min(SAH_BINS - 1);
    // In-place partition: bins < k to the left.
    let mut i = 0;
    let mut j = range.len();
    while i < j {
        if bin_of(refs[range[i] as usize].centroid[axis]) < k {
            i += 1;
        } else {
            j -= 1;
            range.swap(i, j);
        }
    }
    (i > 0 && i < range.len()).then_some(i)
}

/// Splits at the median centroid along the widest centroid axis (any split when they coincide).
fn median_split(refs: &[BuildRef], range: &mut [u32], cmin: Vec3, cmax: Vec3) -> usize {
    let extent = cmax - cmin;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let mid = range.len() / 2;
    range.select_nth_unstable_by(mid, |a, b| {
        refs[*a as usize].centroid[axis].total_cmp(&refs[*b as usize].centroid[axis])
    });
    mid
}

#[inline(always)]
fn ratio(num: f32, den: f32) -> f32 {
    if den > 0.0 {
        (num / den).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Closest point to `p` on segment `a b` and its parameter (0 at `a`).
#[inline]
fn closest_on_segment(p: Vec3, a: Vec3, b: Vec3) -> (Vec3, f32) {
    let ab = b - a;
    let t = ratio((p - a).dot(ab), ab.dot(ab));
    (a + ab * t, t)
}

/// Closest point to `p` on triangle `a b c` and its barycentrics `(u, v, w)` with
/// `point = u a + v b + w c` (Ericson's Voronoi-region tests). Degenerate triangles fall back
/// to the closest of their three edges.
#[inline]
pub fn closest_point_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> (Vec3, [f32; 3]) {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, [1.0, 0.0, 0.0]);
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, [0.0, 1.0, 0.0]);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = ratio(d1, d1 - d3);
        return (a + ab * v, [1.0 - v, v, 0.0]);
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, [0.0, 0.0, 1.0]);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = ratio(d2, d2 - d6);
        return (a + ac * w, [1.0 - w, 0.0, w]);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = ratio(d4 - d3, (d4 - d3) + (d5 - d6));
        return (b + (c - b) * w, [0.0, 1.0 - w, w]);
    }
    let sum = va + vb + vc;
    if sum > 0.0 {
        let v = vb / sum;
        let w = vc / sum;
        return (a + ab * v + ac * w, [1.0 - v - w, v, w]);
    }
    // Zero-area triangle: the answer lies on one of its edges.
    let (q0, t0) = closest_on_segment(p, a, b);
    let (q1, t1) = closest_on_segment(p, b, c);
    let (q2, t2) = closest_on_segment(p, c, a);
    let (e0, e1, e2) = (
        (q0 - p).length_squared(),
        (q1 - p).length_squared(),
        (q2 - p).length_squared(),
    );
    if e0 <= e1 && e0 <= e2 {
        (q0, [1.0 - t0, t0, 0.0])
    } else if e1 <= e2 {
        (q1, [0.0, 1.0 - t1, t1])
    } else {
        (q2, [t2, 0.0, 1.0 - t2])
    }
}

/// The face of `nearest` checked against `faces` and `len` per-vertex entries.
fn face_of(
    what: &'static str,
    nearest: &Nearest,
    faces: &[[u32; 3]],
    field: &'static str,
    len: usize,
) -> Result<[usize; 3], MeshError> {
    let f = faces.get(nearest.face as usize).ok_or(MeshError::Length {
        what,
        field: "faces",
        got: faces.len(),
        expected: nearest.face as usize + 1,
    })?;
    for (corner, &index) in f.iter().enumerate() {
        if index as usize >= len {
            return Err(MeshError::FaceIndex {
                what,
                field,
                face: nearest.face as usize,
                corner,
                index,
                len,
            });
        }
    }
    Ok(f.map(|i| i as usize))
}

/// Barycentric interpolation of a per-vertex scalar ([V], e.g. a view's 0/1 vertex
/// visibility, giving NIA's `o_n`) at the nearest point.
pub fn interpolate_scalar(
    nearest: &Nearest,
    faces: &[[u32; 3]],
    values: &[f32],
) -> Result<f32, MeshError> {
    let [i, j, k] = face_of("interpolate_scalar", nearest, faces, "values", values.len())?;
    let b = nearest.bary;
    Ok(values[i] * b[0] + values[j] * b[1] + values[k] * b[2])
}

/// Barycentric interpolation of per-vertex vectors of `k` values (`weights`: [V * k],
/// row-major, e.g. SMPL skinning weights with k = 24) into `out` ([k]); allocation-free.
pub fn interpolate_weights(
    nearest: &Nearest,
    faces: &[[u32; 3]],
    weights: &[f32],
    k: usize,
    out: &mut [f32],
) -> Result<(), MeshError> {
    const WHAT: &str = "interpolate_weights";
    if k == 0 || !weights.len().is_multiple_of(k) {
        return Err(MeshError::Invalid {
            what: WHAT,
            field: "weights",
            expected: "a [V * k] array with k > 0",
        });
    }
    if out.len() != k {
        return Err(MeshError::Length {
            what: WHAT,
            field: "out",
            got: out.len(),
            expected: k,
        });
    }
    let [i, j, l] = face_of(WHAT, nearest, faces, "weights", weights.len() / k)?;
    let b = nearest.bary;
    let (wi, wj, wl) = (
        &weights[i * k..(i + 1) * k],
        &weights[j * k..(j + 1) * k],
        &weights[l * k..(l + 1) * k],
    );
    for (c, o) in out.iter_mut().enumerate() {
        *o = wi[c] * b[0] + wj[c] * b[1] + wl[c] * b[2];
    }
    Ok(())
}
