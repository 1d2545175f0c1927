//! Whether any face of a [`SurfaceIndex`] lies within a distance of a point: a traversal that
//! stops at the first face found, for the occupancy grid's cell-by-cell test
//! ([`crate::geometry::occupancy`]).

use glam::Vec3;

use super::{closest_point_on_triangle, SurfaceIndex, STACK_DEPTH};

/// The face that answered a run of [`SurfaceIndex::any_within_squared`] queries last (leaf
/// order), tried first by the next query.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct AnyWithinHint {
    last: Option<u32>,
}

impl SurfaceIndex {
    /// Whether some face lies within `max_dist` metres of `p` (inclusive): the test
    /// `nearest_within(p, max_dist).is_some()` answers, but it stops at the first face found
    /// instead of looking for the nearest. `false` for a non-finite `p` or a negative or NaN
    /// `max_dist`.
    pub fn any_within(&self, p: Vec3, max_dist: f32) -> bool {
        if !(max_dist >= 0.0) {
            return false;
        }
        let mut hint = AnyWithinHint::default();
        self.any_within_squared(p, max_dist * max_dist, &mut hint)
    }

    /// [`Self::any_within`] for the squared distance `r2`: whether some face's closest point
    /// `q` has `(q - p).length_squared() <= r2` (that exact f32 test, so a caller that tested
    /// faces one by one gets the same answers). `hint` remembers the face that answered last
    /// and is tried first: neighbouring queries are often answered by the same face. `false`
    /// for a non-finite `p` or a negative or NaN `r2`.
    pub(crate) fn any_within_squared(&self, p: Vec3, r2: f32, hint: &mut AnyWithinHint) -> bool {
        if !(p.is_finite() && r2 >= 0.0) {
            return false;
        }
        let within = |t: usize| {
            let tri = &self.tris[t];
            let (q, _) = closest_point_on_triangle(p, tri[0], tri[1], tri[2]);
            (q - p).length_squared() <= r2
        };
        if hint.last.is_some_and(|t| within(t as usize)) {
            return true;
        }
        // Boxes are pruned against a slightly larger bound: a box holds its triangles exactly,
        // but the closest point on a triangle is computed with rounding, which must not make a
        // box look farther than a triangle inside it.
        let prune2 = r2 * (1.0 + 1e-4) + 1e-12;
        let nodes = &self.nodes[..];
        let mut stack = [0u32; STACK_DEPTH];
        let mut top = 0usize;
        let mut node = 0usize;
        if !(nodes[0].dist2(p) <= prune2) {
            return false;
        }
        loop {
            let n = &nodes[node];
            if n.count > 0 {
                let start = n.index as usize;
                if let Some(t) = (start..start + n.count as usize).find(|&t| within(t)) {
                    hint.last = Some(t as u32);
                    return true;
                }
            } else {
                let left = n.index as usize;
                let (dl, dr) = (nodes[left].dist2(p), nodes[left + 1].dist2(p));
                match (dl <= prune2, dr <= prune2) {
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
                return false;
            }
            top -= 1;
            node = stack[top] as usize;
        }
    }
}
