//! Placing the body before the first solver step: keypoints triangulated across views (linear DLT)
//! and the rigid motion that carries the model's torso keypoints onto them (Kabsch, via the
//! polar decomposition of the cross-covariance).

use crate::body::{BodyModel, Posed, SmplParams};
use glam::{DMat3, DQuat, DVec3, Vec2, Vec3};

use super::keypoints::KeypointBinding;
use super::observation::FrameObservation;

/// Fewest triangulated torso keypoints the rigid placement needs (three non-collinear points
/// fix a rotation).
pub const MIN_TORSO_POINTS: usize = 3;

/// Smallest `|det|` of the DLT normal equations (normalised image units, summed over views)
/// that counts as a triangulation: two rays closer to parallel than ~1 degree are rejected.
const MIN_DLT_DET: f64 = 1e-9;

/// The world point whose projections best match keypoint `k` over the views that see it
/// (confidence-weighted linear least squares on undistorted normalised coordinates:
/// `(x r3 - r1) . X = x t3 - t1`, `(y r3 - r2) . X = y t3 - t2`). `None` with fewer than two
/// views or near-parallel rays.
pub fn triangulate(frame: &FrameObservation, k: usize) -> Option<Vec3> {
    let mut a = DMat3::ZERO;
    let mut rhs = DVec3::ZERO;
    let mut seen = 0;
    for view in &frame.views {
        let Some(p) = view.keypoints.get(k) else {
            continue;
        };
        if p[2] <= 0.0 {
            continue;
        }
        seen += 1;
        let cam = &view.camera;
        let n = cam
            .undistort_normalized(cam.normalized_from_pixel(Vec2::new(p[0], p[1])))
            .as_dvec2();
        let r = cam.r.as_dmat3().transpose(); // columns = rows of R
        let t = cam.t.as_dvec3();
        let w = p[2] as f64;
        for (coord, axis) in [(n.x, 0usize), (n.y, 1usize)] {
            let row = r.col(2) * coord - r.col(axis);
            let b = t[axis] - coord * t[2];
            a += outer(row, row) * w;
            rhs += row * (b * w);
        }
    }
    if seen < 2 || a.determinant().abs() < MIN_DLT_DET {
        return None;
    }
    let x = a.inverse() * rhs;
    x.is_finite().then(|| x.as_vec3())
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// The position of a keypoint on a posed body (world coordinates).
pub fn binding_position(binding: &KeypointBinding, posed: &Posed) -> Vec3 {
    let mut p = DVec3::ZERO;
    for &(j, w) in &binding.joints {
        p += posed.joints[j].as_dvec3() * w as f64;
    }
    for &(v, w) in &binding.vertices {
        p += posed.vertices[v].as_dvec3() * w as f64;
    }
    p.as_vec3()
}

/// Eigenvector of the largest eigenvalue of a symmetric 4x4 matrix (cyclic Jacobi).
fn top_eigenvector(mut a: [[f64; 4]; 4]) -> [f64; 4] {
    let mut v = [[0.0f64; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..50 {
        let off: f64 = (0..4)
            .flat_map(|i| (0..4).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-24 {
            break;
        }
        for p in 0..4 {
            for q in p + 1..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in a.iter_mut() {
                    let (akp, akq) = (row[p], row[q]);
                    row[p] = c * akp - s * akq;
                    row[q] = s * akp + c * akq;
                }
                let (row_p, row_q) = (a[p], a[q]);
                for (k, (apk, aqk)) in row_p.into_iter().zip(row_q).enumerate() {
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let best = (0..4)
        .max_by(|&i, &j| a[i][i].total_cmp(&a[j][j]))
        .unwrap_or(0);
    [v[0][best], v[1][best], v[2][best], v[3][best]]
}

/// The rotation that best carries the centred points `model` onto `world` (Horn's closed form
/// with unit quaternions: the top eigenvector of his 4x4 matrix; fine for coplanar points).
fn best_rotation(pairs: &[(DVec3, DVec3)]) -> DQuat {
    let mut s = [[0.0f64; 3]; 3]; // s[a][b] = sum m_a w_b
    for (m, w) in pairs {
        for a in 0..3 {
            for b in 0..3 {
                s[a][b] += m[a] * w[b];
            }
        }
    }
    let [[xx, xy, xz], [yx, yy, yz], [zx, zy, zz]] = s;
    let n = [
        [xx + yy + zz, yz - zy, zx - xz, xy - yx],
        [yz - zy, xx - yy - zz, xy + yx, zx + xz],
        [zx - xz, xy + yx, -xx + yy - zz, yz + zy],
        [xy - yx, zx + xz, yz + zy, -xx - yy + zz],
    ];
    let [w, x, y, z] = top_eigenvector(n);
    DQuat::from_xyzw(x, y, z, w).normalize()
}

/// `Rh`, `Th` that carry the torso keypoints of `body` (posed at the origin with `params`'
/// pose and shape, `Rh = Th = 0`) onto their triangulations in `frame`. `Err` says why not.
pub fn place_torso(
    model: &BodyModel,
    bindings: &[KeypointBinding],
    frame: &FrameObservation,
    params: &SmplParams,
) -> Result<(Vec3, Vec3), String> {
    let local = model.lbs(&SmplParams {
        rh: Vec3::ZERO,
        th: Vec3::ZERO,
        ..params.clone()
    });
    let pairs: Vec<(DVec3, DVec3)> = bindings
        .iter()
        .enumerate()
        .filter(|(_, b)| b.is_torso())
        .filter_map(|(k, b)| {
            triangulate(frame, k).map(|w| (binding_position(b, &local).as_dvec3(), w.as_dvec3()))
        })
        .collect();
    if pairs.len() < MIN_TORSO_POINTS {
        return Err(format!(
            "{} torso keypoints (hips, shoulders, neck) seen in two or more views, need {MIN_TORSO_POINTS}",
            pairs.len()
        ));
    }
    let count = pairs.len() as f64;
    let cm = pairs.iter().map(|p| p.0).sum::<DVec3>() / count;
    let cw = pairs.iter().map(|p| p.1).sum::<DVec3>() / count;
    let centred: Vec<(DVec3, DVec3)> = pairs.iter().map(|(m, w)| (*m - cm, *w - cw)).collect();
    let q = best_rotation(&centred);
    if !q.is_finite() {
        return Err("the torso keypoints do not fix a rotation".to_string());
    }
    let rh = q.to_scaled_axis().as_vec3();
    let th = (cw - q * cm).as_vec3();
    Ok((rh, th))
}

/// Translation shift that moves `body`'s triangulated torso centroid onto this frame's: the
/// warm start's correction for how far the person moved since the previous frame. `None`
/// when fewer than [`MIN_TORSO_POINTS`] torso keypoints triangulate.
pub fn torso_shift(
    bindings: &[KeypointBinding],
    frame: &FrameObservation,
    posed: &Posed,
) -> Option<Vec3> {
    let pairs: Vec<DVec3> = bindings
        .iter()
        .enumerate()
        .filter(|(_, b)| b.is_torso())
        .filter_map(|(k, b)| {
            triangulate(frame, k).map(|w| w.as_dvec3() - binding_position(b, posed).as_dvec3())
        })
        .collect();
    (pairs.len() >= MIN_TORSO_POINTS)
        .then(|| (pairs.iter().sum::<DVec3>() / pairs.len() as f64).as_vec3())
}
