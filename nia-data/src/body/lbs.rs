//! Linear blend skinning exactly as SMPL does it, plus the per-point helpers reposing needs.
//!
//! For pose `theta` (axis-angle per joint) and shape `beta`:
//!
//! 1. `v_shaped = v_template + shapedirs . beta`
//! 2. `J = J_regressor . v_shaped` (rest joints)
//! 3. pose feature `= concat_{j=1..23} (R_j - I)` flattened row-major, `R_j = Rodrigues(theta_j)`
//! 4. `v_posed = v_shaped + posedirs . pose_feature`
//! 5. `G_0 = [R_0 | J_0]`, `G_k = G_parent(k) [R_k | J_k - J_parent(k)]` (world transforms)
//! 6. `A_k = G_k translate(-J_k)` (maps rest-pose space to posed space)
//! 7. `v = (sum_k w_vk A_k) v_posed`
//! 8. ZJU-MoCap's global placement: `world = v @ Rodrigues(Rh)^T + Th`.
//!
//! The transform chain runs in f64 and is rounded to f32 once at the end.

use glam::{DMat3, DMat4, DVec3, Mat3, Mat4, Vec3};
use rayon::prelude::*;

use super::smpl::{BodyModel, NUM_JOINTS, NUM_POSE_FEATURES};

/// Below this rotation angle (radians) Rodrigues' formula switches to its Taylor expansion:
/// `sin(t)/t` and `(1 - cos(t))/t^2` lose all f64 digits as `t -> 0`, their series to second
/// order are exact to f64 precision below 1e-4 (next term ~ t^4 / 120 < 1e-18).
pub const RODRIGUES_SMALL_ANGLE: f64 = 1e-4;

/// [`inverse_lbs`] gives up when the determinant of the blended 3x3 part is smaller than this.
/// A convex blend of rotations has a determinant in [0, 1]; it reaches 0 when two rotations
/// about 180 degrees apart are blended half and half. Below 1e-3 at least one direction is
/// squashed by ~10x or more (1/det^(1/3)) and the inverse turns millimetres of error into
/// centimetres or metres: such points lie far from any sensible body pose.
pub const INVERSE_LBS_MIN_DET: f64 = 1e-3;

/// SMPL pose and shape parameters of one frame, ZJU-MoCap convention.
#[derive(Debug, Clone, PartialEq)]
pub struct SmplParams {
    /// `[24 x 3]` axis-angle per joint, radians, in SMPL joint order. Joint 0 is the root
    /// orientation; ZJU-MoCap stores zeros there and puts the global rotation in `rh`.
    pub poses: [f32; 72],
    /// `[S]` shape coefficients beta (10 in ZJU-MoCap). Missing ones count as zero, extra
    /// ones beyond the model's `S` are ignored.
    pub shapes: Vec<f32>,
    /// Global rotation, axis-angle (radians).
    pub rh: Vec3,
    /// Global translation, metres.
    pub th: Vec3,
}

impl Default for SmplParams {
    /// The rest pose at the origin with zero shape.
    fn default() -> Self {
        Self {
            poses: [0.0; 72],
            shapes: Vec::new(),
            rh: Vec3::ZERO,
            th: Vec3::ZERO,
        }
    }
}

/// A posed body.
#[derive(Debug, Clone, PartialEq)]
pub struct Posed {
    /// `[V]` posed vertices in world coordinates (after `Rh`, `Th`), metres.
    pub vertices: Vec<Vec3>,
    /// `[24]` posed joint locations in world coordinates, metres.
    pub joints: Vec<Vec3>,
    /// `[24]` per-joint skinning transforms `M_global A_k`: map a point of the shaped rest pose
    /// (`v_shaped` space, before pose blend shapes) to world coordinates.
    pub joint_transforms: Vec<Mat4>,
    /// `[V]` shaped rest-pose vertices `v_template + shapedirs . beta`, metres.
    pub v_shaped: Vec<Vec3>,
    /// `[24]` rest joint locations `J_regressor . v_shaped`, metres.
    pub rest_joints: Vec<Vec3>,
}

/// Rotation matrix of an axis-angle vector (radians), Rodrigues' formula.
/// Exactly the identity at angle 0 and smooth through it.
pub fn rodrigues(axis_angle: Vec3) -> Mat3 {
    rodrigues_f64(axis_angle.as_dvec3()).as_mat3()
}

/// [`rodrigues`] in f64: `R = I + a K + b K^2`, `K = [r]_x`, `a = sin(t)/t`,
/// `b = (1 - cos(t))/t^2`, `t = |r|`.
pub fn rodrigues_f64(r: DVec3) -> DMat3 {
    let t2 = r.length_squared();
    let t = t2.sqrt();
    let (a, b) = if t < RODRIGUES_SMALL_ANGLE {
        (1.0 - t2 / 6.0, 0.5 - t2 / 24.0)
    } else {
        (t.sin() / t, (1.0 - t.cos()) / t2)
    };
    let k = DMat3::from_cols(
        DVec3::new(0.0, r.z, -r.y),
        DVec3::new(-r.z, 0.0, r.x),
        DVec3::new(r.y, -r.x, 0.0),
    );
    DMat3::IDENTITY + k * a + (k * k) * b
}

/// SMPL's pose feature: for joints 1..23, `(R_j - I)` flattened row-major
/// (`feature[(j - 1) * 9 + r * 3 + c] = R_j[r][c] - delta_rc`).
pub fn pose_feature(rotations: &[DMat3]) -> [f32; NUM_POSE_FEATURES] {
    let mut feature = [0.0f32; NUM_POSE_FEATURES];
    for (j, rot) in rotations.iter().enumerate().skip(1).take(NUM_JOINTS - 1) {
        for r in 0..3 {
            for c in 0..3 {
                let identity = if r == c { 1.0 } else { 0.0 };
                // glam is column-major: column c, row r.
                feature[(j - 1) * 9 + r * 3 + c] = (rot.col(c)[r] - identity) as f32;
            }
        }
    }
    feature
}

/// The blended skinning transform `sum_k w_k T_k` of one point. Pairs beyond the shorter of the
/// two slices are ignored; zero weights are skipped.
pub fn blend_transform(weights: &[f32], transforms: &[Mat4]) -> Mat4 {
    let mut cols = [glam::Vec4::ZERO; 4];
    for (&w, t) in weights.iter().zip(transforms) {
        if w != 0.0 {
            cols[0] += t.x_axis * w;
            cols[1] += t.y_axis * w;
            cols[2] += t.z_axis * w;
            cols[3] += t.w_axis * w;
        }
    }
    Mat4::from_cols(cols[0], cols[1], cols[2], cols[3])
}

/// Inverse LBS of one point: the rest-space point `x` with `(sum_k w_k T_k) x = point`.
///
/// Returns `None` when the blended 3x3 part has `|det| <` [`INVERSE_LBS_MIN_DET`] (e.g. two
/// opposite rotations blended half and half) or the result is not finite; never NaN. The
/// blended matrix is treated as affine (its bottom row is ignored, as SMPL does).
pub fn inverse_lbs(point: Vec3, weights: &[f32], transforms: &[Mat4]) -> Option<Vec3> {
    let blended = blend_transform(weights, transforms).as_dmat4();
    let linear = DMat3::from_mat4(blended);
    let det = linear.determinant();
    if det.is_nan() || det.abs() < INVERSE_LBS_MIN_DET {
        return None;
    }
    let x = linear.inverse() * (point.as_dvec3() - blended.w_axis.truncate());
    x.is_finite().then(|| x.as_vec3())
}

/// `[R | t]` as a 4x4 matrix.
fn rigid(rotation: DMat3, translation: DVec3) -> DMat4 {
    DMat4::from_cols(
        rotation.x_axis.extend(0.0),
        rotation.y_axis.extend(0.0),
        rotation.z_axis.extend(0.0),
        translation.extend(1.0),
    )
}

/// The pose side of a posed body: what every vertex's skinning reads.
struct PoseTransforms {
    /// `[24]` world joint locations, metres.
    joints: Vec<Vec3>,
    /// `[24]` skinning transforms (see [`Posed::joint_transforms`]).
    joint_transforms: Vec<Mat4>,
    feature: [f32; NUM_POSE_FEATURES],
    /// Some pose blend shape is active (the feature is not all zero).
    posed_shape: bool,
}

/// Some of a posed body's vertices ([`BodyModel::lbs_at`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PosedAt {
    /// `[indices]` posed world vertices, metres.
    pub vertices: Vec<Vec3>,
    /// `[24]` posed world joints, metres.
    pub joints: Vec<Vec3>,
    /// `[24]` skinning transforms, as [`Posed::joint_transforms`].
    pub joint_transforms: Vec<Mat4>,
}

impl BodyModel {
    /// Pose and place the body (SMPL's LBS followed by ZJU-MoCap's `Rh`, `Th`; module docs).
    ///
    /// Expects a validated model ([`BodyModel::validate`]); malformed fields edited in after
    /// validation give a meaningless body but no panic.
    pub fn lbs(&self, params: &SmplParams) -> Posed {
        let v_shaped = self.shape_vertices(&params.shapes);
        let rest = self.regress_joints_f64(&v_shaped);
        let pose = self.pose_transforms(params, &rest);
        let vertices = (0..v_shaped.len())
            .into_par_iter()
            .map(|v| self.skin(v, v_shaped[v], &pose))
            .collect();
        Posed {
            vertices,
            joints: pose.joints,
            joint_transforms: pose.joint_transforms,
            v_shaped,
            rest_joints: (0..NUM_JOINTS)
                .map(|k| rest.get(k).copied().unwrap_or(DVec3::ZERO).as_vec3())
                .collect(),
        }
    }

    /// The vertices `indices` of the body posed by `params`, whose shape is `shaped`'s (a
    /// [`Posed`] of the same betas: its `v_shaped` and `rest_joints` are reused). The same
    /// numbers as [`BodyModel::lbs`] at those vertices (the rest joints rounded to f32 once);
    /// indices past the model's vertices are skipped.
    pub fn lbs_at(&self, params: &SmplParams, shaped: &Posed, indices: &[usize]) -> PosedAt {
        let rest: Vec<DVec3> = shaped.rest_joints.iter().map(|j| j.as_dvec3()).collect();
        let pose = self.pose_transforms(params, &rest);
        let vertices = indices
            .iter()
            .filter_map(|&v| shaped.v_shaped.get(v).map(|&p| self.skin(v, p, &pose)))
            .collect();
        PosedAt {
            vertices,
            joints: pose.joints,
            joint_transforms: pose.joint_transforms,
        }
    }

    /// Steps 3, 5 and 6 of the module docs for `params` with rest joints `rest`.
    fn pose_transforms(&self, params: &SmplParams, rest: &[DVec3]) -> PoseTransforms {
        let rest = |k: usize| rest.get(k).copied().unwrap_or(DVec3::ZERO);
        let rotations: Vec<DMat3> = (0..NUM_JOINTS)
            .map(|k| {
                let p = &params.poses[3 * k..3 * k + 3];
                rodrigues_f64(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            })
            .collect();
        let feature = pose_feature(&rotations);
        let posed_shape = feature.iter().any(|&x| x != 0.0);

        // World transforms G_k along the kinematic chain.
        let mut world = vec![DMat4::IDENTITY; NUM_JOINTS];
        for k in 0..NUM_JOINTS {
            let parent = self
                .parents
                .get(k)
                .copied()
                .filter(|&p| p >= 0 && (p as usize) < k)
                .map(|p| p as usize);
            world[k] = match parent {
                None => rigid(rotations[k], rest(k)),
                Some(p) => world[p] * rigid(rotations[k], rest(k) - rest(p)),
            };
        }
        let global = rigid(rodrigues_f64(params.rh.as_dvec3()), params.th.as_dvec3());
        let joints = world
            .iter()
            .map(|g| global.transform_point3(g.w_axis.truncate()).as_vec3())
            .collect();
        let joint_transforms: Vec<Mat4> = world
            .iter()
            .enumerate()
            .map(|(k, g)| {
                // A_k = G_k translate(-J_k): same rotation, translation t - R J_k.
                let mut a = *g;
                let t = g.w_axis.truncate() - DMat3::from_mat4(*g) * rest(k);
                a.w_axis = t.extend(1.0);
                (global * a).as_mat4()
            })
            .collect();
        PoseTransforms {
            joints,
            joint_transforms,
            feature,
            posed_shape,
        }
    }

    /// Steps 4 and 7 of the module docs for vertex `v` at its shaped rest position `p`.
    fn skin(&self, v: usize, mut p: Vec3, pose: &PoseTransforms) -> Vec3 {
        if pose.posed_shape {
            let span = v * 3 * NUM_POSE_FEATURES..(v + 1) * 3 * NUM_POSE_FEATURES;
            if let Some(dirs) = self.posedirs.get(span) {
                for (c, row) in dirs.chunks_exact(NUM_POSE_FEATURES).enumerate() {
                    let offset: f32 = row.iter().zip(&pose.feature).map(|(&d, &f)| d * f).sum();
                    p[c] += offset;
                }
            }
        }
        match self.weights.get(v) {
            Some(w) => blend_transform(w, &pose.joint_transforms).transform_point3(p),
            None => p,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Entries of matrices built from f64 trigonometry and rounded to f32.
    const F32_TOL: f32 = 1e-6;

    #[test]
    fn rodrigues_matches_glam_and_is_identity_at_zero() {
        assert_eq!(rodrigues(Vec3::ZERO), Mat3::IDENTITY);
        let axis = Vec3::new(1.0, -2.0, 0.5).normalize();
        for angle in [1e-7f32, 1e-5, 1e-3, 0.3, 2.0, 3.1] {
            let expected = Mat3::from_axis_angle(axis, angle);
            let got = rodrigues(axis * angle);
            assert!(got.abs_diff_eq(expected, F32_TOL), "angle {angle}");
        }
    }

    #[test]
    fn pose_feature_is_row_major_r_minus_identity() {
        let mut rotations = vec![DMat3::IDENTITY; NUM_JOINTS];
        rotations[2] = DMat3::from_rotation_z(std::f64::consts::FRAC_PI_2);
        let f = pose_feature(&rotations);
        // Rz(90) = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]; joint 2 occupies entries 9..18.
        let expected = [-1.0, -1.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, 0.0];
        for (i, e) in expected.iter().enumerate() {
            assert!((f[9 + i] - e).abs() < F32_TOL, "entry {i}: {}", f[9 + i]);
        }
        assert!(f[..9].iter().chain(&f[18..]).all(|&x| x == 0.0));
    }
}
