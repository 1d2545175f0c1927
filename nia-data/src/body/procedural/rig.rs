//! Rigging the procedural mesh: skinning weights from distances to the bones, a joint regressor
//! that reproduces the designed joints exactly, and shape blend shapes that change proportions.

use glam::{DVec3, Mat3, Vec3};

use super::implicit::segment_param;
use crate::body::smpl::{NUM_JOINTS, SMPL_PARENTS};

/// Relative softness of the skinning weights: a bone `(1 + f) x` farther away than the nearest
/// bone gets `exp(-f / SKIN_FALLOFF)` of its weight, so at `f = 0.2` bones blend e^-1 and a
/// bone twice as far (the other thigh seen from the inner thigh) gets e^-5 < 1%.
pub const SKIN_FALLOFF: f32 = 0.2;

/// Skinning weights below this are dropped and the row renormalised (keeps rows sparse, as
/// SMPL's are; 0.5% of a joint's motion is invisible).
pub const SKIN_MIN_WEIGHT: f32 = 0.005;

/// Regressor weights below this are dropped before the final solve.
const REGRESSOR_MIN_WEIGHT: f64 = 1e-4;

/// The regressor solve stops when the weighted centroid is this close to the joint, metres.
const REGRESSOR_TOL_M: f64 = 1e-9;

/// Length of the bone segment given to joints without children (feet, head, hands), as a
/// fraction of the body's height.
const LEAF_BONE_FRACTION: f32 = 0.04;

/// Number of shape components of the procedural body.
pub const NUM_BETAS: usize = 10;

/// What each shape component does at `beta = +1` (negative betas do the opposite).
pub const BETA_NAMES: [&str; NUM_BETAS] = [
    "height: bones 6% longer, 2% thicker",
    "girth: every part 10% thicker",
    "leg length: thighs and shins 8% longer",
    "arm length: upper arms, forearms and hands 8% longer",
    "shoulder width: chest and collars 12% wider",
    "belly: abdomen and pelvis 25% deeper, 6% wider",
    "hip width: pelvis 15% wider, thighs 5% thicker",
    "head size: head 10% larger, neck 5% thicker",
    "torso length: spine 8% longer",
    "limb girth: thighs, shins and arms 20% thicker",
];

/// `[24]` bone segments of each joint: to each child, or a short stub for leaves.
fn bone_segments(joints: &[Vec3; NUM_JOINTS], height: f32) -> Vec<Vec<(Vec3, Vec3)>> {
    let mut segments: Vec<Vec<(Vec3, Vec3)>> = vec![Vec::new(); NUM_JOINTS];
    for c in 1..NUM_JOINTS {
        let p = SMPL_PARENTS[c] as usize;
        segments[p].push((joints[p], joints[c]));
    }
    for k in 0..NUM_JOINTS {
        if segments[k].is_empty() {
            let dir = bone_axis(joints, k);
            segments[k].push((joints[k], joints[k] + dir * (LEAF_BONE_FRACTION * height)));
        }
    }
    segments
}

/// Unit direction of joint `k`'s bone: towards its only child; up (+y) for the pelvis and
/// spine3 (several children) and the head; away from the parent for the other leaves.
fn bone_axis(joints: &[Vec3; NUM_JOINTS], k: usize) -> Vec3 {
    let children: Vec<usize> = (1..NUM_JOINTS)
        .filter(|&c| SMPL_PARENTS[c] as usize == k)
        .collect();
    let dir = match children.as_slice() {
        [c] => joints[*c] - joints[k],
        [] if k != 15 => joints[k] - joints[SMPL_PARENTS[k] as usize],
        _ => Vec3::Y,
    };
    dir.normalize_or(Vec3::Y)
}

fn distance_to_segment(p: Vec3, (a, b): (Vec3, Vec3)) -> f32 {
    p.distance(a + (b - a) * segment_param(p, a, b))
}

/// `[V, 24]` skinning weights: a softmax over joints of the relative excess distance to each
/// joint's bone segments (see [`SKIN_FALLOFF`]), pruned at [`SKIN_MIN_WEIGHT`], rows sum to 1.
pub fn skinning_weights(
    vertices: &[Vec3],
    joints: &[Vec3; NUM_JOINTS],
    height: f32,
) -> Vec<[f32; NUM_JOINTS]> {
    let segments = bone_segments(joints, height);
    // Distances are measured relative to at least 1 cm so the softmax stays soft for points
    // that sit on a bone.
    let min_scale = 0.01 * height / 1.7;
    vertices
        .iter()
        .map(|&p| {
            let d: Vec<f32> = segments
                .iter()
                .map(|segs| {
                    segs.iter()
                        .map(|&s| distance_to_segment(p, s))
                        .fold(f32::INFINITY, f32::min)
                })
                .collect();
            let nearest = d.iter().copied().fold(f32::INFINITY, f32::min);
            let scale = SKIN_FALLOFF * nearest.max(min_scale);
            let mut w = [0.0f32; NUM_JOINTS];
            for (wk, dk) in w.iter_mut().zip(&d) {
                *wk = (-(dk - nearest) / scale).exp();
            }
            normalise(&mut w);
            for wk in w.iter_mut() {
                if *wk < SKIN_MIN_WEIGHT {
                    *wk = 0.0;
                }
            }
            normalise(&mut w);
            w
        })
        .collect()
}

fn normalise(w: &mut [f32; NUM_JOINTS]) {
    let sum: f32 = w.iter().sum();
    if sum > 0.0 {
        for x in w.iter_mut() {
            *x /= sum;
        }
    }
}

/// `[24]` sparse regressor rows `(vertex, weight)` with `sum w v = joint` and `sum w = 1`,
/// `w > 0`: maximum-entropy weights over the vertices around each joint (a Gaussian prior
/// tilted by `exp(lambda . (v - joint))`, `lambda` found by Newton's method). `None` if some
/// joint is not surrounded by the mesh.
pub fn joint_regressor(
    vertices: &[Vec3],
    joints: &[Vec3; NUM_JOINTS],
) -> Option<Vec<Vec<(u32, f32)>>> {
    joints.iter().map(|&j| regressor_row(vertices, j)).collect()
}

fn regressor_row(vertices: &[Vec3], joint: Vec3) -> Option<Vec<(u32, f32)>> {
    let joint = joint.as_dvec3();
    let nearest = vertices
        .iter()
        .map(|v| v.as_dvec3().distance(joint))
        .fold(f64::INFINITY, f64::min);
    if !nearest.is_finite() {
        return None;
    }
    // Start with a ball 2.5x the distance to the surface: around a limb that takes in a ring
    // of the limb's surface, which surrounds the joint.
    let mut radius = (2.5 * nearest).max(0.01);
    for _ in 0..6 {
        let mut ids: Vec<usize> = (0..vertices.len())
            .filter(|&i| vertices[i].as_dvec3().distance(joint) < radius)
            .collect();
        let offsets = |ids: &[usize]| -> Vec<DVec3> {
            ids.iter()
                .map(|&i| vertices[i].as_dvec3() - joint)
                .collect()
        };
        let sigma = 0.5 * radius;
        let prior = |u: &[DVec3]| -> Vec<f64> {
            u.iter()
                .map(|d| (-(d.length_squared()) / (sigma * sigma)).exp())
                .collect()
        };
        let u = offsets(&ids);
        if let Some(w) = max_entropy_weights(&u, &prior(&u)) {
            ids = ids
                .into_iter()
                .zip(&w)
                .filter(|(_, &w)| w >= REGRESSOR_MIN_WEIGHT)
                .map(|(i, _)| i)
                .collect();
            let u = offsets(&ids);
            if let Some(w) = max_entropy_weights(&u, &prior(&u)) {
                return Some(
                    ids.iter()
                        .zip(w)
                        .map(|(&i, w)| (i as u32, w as f32))
                        .collect(),
                );
            }
        }
        radius *= 1.5;
    }
    None
}

/// Weights `w_i = prior_i exp(lambda . u_i) / Z` with `sum w_i u_i = 0` (the origin is the
/// weighted centroid of the offsets `u`). Newton's method on the convex `log Z(lambda)` with
/// backtracking; `None` when the origin is not strictly inside the offsets' convex hull.
fn max_entropy_weights(u: &[DVec3], prior: &[f64]) -> Option<Vec<f64>> {
    if u.len() < 4 {
        return None;
    }
    let weights = |lambda: DVec3| -> (Vec<f64>, f64) {
        let e: Vec<f64> = u.iter().map(|x| lambda.dot(*x)).collect();
        let m = e.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let w: Vec<f64> = e
            .iter()
            .zip(prior)
            .map(|(&ei, &p)| p * (ei - m).exp())
            .collect();
        let z: f64 = w.iter().sum();
        let log_z = z.ln() + m;
        (w.into_iter().map(|x| x / z).collect(), log_z)
    };
    let mut lambda = DVec3::ZERO;
    let (mut w, mut log_z) = weights(lambda);
    for _ in 0..100 {
        let g: DVec3 = u.iter().zip(&w).map(|(x, &wi)| *x * wi).sum();
        if g.length() < REGRESSOR_TOL_M {
            return Some(w);
        }
        let mut h = glam::DMat3::ZERO;
        for (x, &wi) in u.iter().zip(&w) {
            h += glam::DMat3::from_cols(*x * x.x, *x * x.y, *x * x.z) * wi;
        }
        h -= glam::DMat3::from_cols(g * g.x, g * g.y, g * g.z);
        if h.determinant().abs() < 1e-30 {
            return None;
        }
        let step = h.inverse() * g;
        let mut t = 1.0;
        loop {
            let candidate = lambda - step * t;
            let (wc, lc) = weights(candidate);
            if lc <= log_z + 1e-4 * t * g.dot(-step) || t < 1e-6 {
                lambda = candidate;
                w = wc;
                log_z = lc;
                break;
            }
            t *= 0.5;
        }
        if !lambda.is_finite() {
            return None;
        }
    }
    None
}

/// `[V, 3, NUM_BETAS]` shape blend shapes (flat C order): for each component, the displacement
/// at `beta = 1` of a morph that scales body parts about their joints, carried to the vertices
/// by the skinning weights: `sum_k w_vk ((J'_k - J_k) + (S_k - I)(x - J_k))`, where `S_k` is the
/// component's scaling of part `k` and the new joints follow the chain `J'_c = J'_p +
/// S_p (J_c - J_p)` (the pelvis stays put).
pub fn shape_blend_shapes(
    vertices: &[Vec3],
    weights: &[[f32; NUM_JOINTS]],
    joints: &[Vec3; NUM_JOINTS],
) -> Vec<f32> {
    let mut shapedirs = vec![0.0f32; vertices.len() * 3 * NUM_BETAS];
    for s in 0..NUM_BETAS {
        let scales: Vec<Mat3> = (0..NUM_JOINTS)
            .map(|k| part_scale(s, k, bone_axis(joints, k)))
            .collect();
        let mut moved = [Vec3::ZERO; NUM_JOINTS];
        moved[0] = joints[0];
        for c in 1..NUM_JOINTS {
            let p = SMPL_PARENTS[c] as usize;
            moved[c] = moved[p] + scales[p] * (joints[c] - joints[p]);
        }
        for (v, (&x, w)) in vertices.iter().zip(weights).enumerate() {
            let mut d = Vec3::ZERO;
            for k in 0..NUM_JOINTS {
                if w[k] != 0.0 {
                    let local = x - joints[k];
                    d += (moved[k] - joints[k] + scales[k] * local - local) * w[k];
                }
            }
            for c in 0..3 {
                shapedirs[(v * 3 + c) * NUM_BETAS + s] = d[c];
            }
        }
    }
    shapedirs
}

/// Scaling of body part `k` (about its joint) by shape component `s` at `beta = 1`.
fn part_scale(s: usize, k: usize, axis: Vec3) -> Mat3 {
    // `l` along the bone, `g` across it.
    let along = |l: f32, g: f32| {
        let aa = Mat3::from_cols(axis * axis.x, axis * axis.y, axis * axis.z);
        aa * l + (Mat3::IDENTITY - aa) * g
    };
    let diag = |x: f32, y: f32, z: f32| Mat3::from_diagonal(Vec3::new(x, y, z));
    let legs = [1, 2, 4, 5];
    let arms = [16, 17, 18, 19, 20, 21];
    match s {
        0 => along(1.06, 1.02),
        1 => along(1.0, 1.10),
        2 if legs.contains(&k) => along(1.08, 1.0),
        3 if arms.contains(&k) => along(1.08, 1.0),
        4 if [9, 13, 14].contains(&k) => diag(1.12, 1.0, 1.0),
        5 if [0, 3, 6].contains(&k) => diag(1.06, 1.0, 1.25),
        6 if k == 0 => diag(1.15, 1.0, 1.0),
        6 if [1, 2].contains(&k) => along(1.0, 1.05),
        7 if k == 15 => Mat3::IDENTITY * 1.10,
        7 if k == 12 => along(1.0, 1.05),
        8 if [0, 3, 6, 9].contains(&k) => diag(1.0, 1.08, 1.0),
        9 if legs.contains(&k) || [16, 17, 18, 19].contains(&k) => along(1.0, 1.20),
        _ => Mat3::IDENTITY,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn max_entropy_weights_reproduce_an_interior_point() {
        let u: Vec<DVec3> = (0..20)
            .map(|i| {
                let a = i as f64 * 0.7;
                DVec3::new(a.cos() + 0.3, a.sin(), ((i % 3) as f64 - 1.0) * 0.5)
            })
            .collect();
        let prior = vec![1.0; u.len()];
        let w = max_entropy_weights(&u, &prior).expect("origin is inside");
        let centroid: DVec3 = u.iter().zip(&w).map(|(x, &wi)| *x * wi).sum();
        assert!(centroid.length() < 1e-8 && w.iter().all(|&x| x > 0.0));
        let outside: Vec<DVec3> = u.iter().map(|x| *x + DVec3::X * 5.0).collect();
        assert!(max_entropy_weights(&outside, &prior).is_none());
    }
}
