//! SMPL's linear blend skinning on tensors, for a fixed subset of vertices (the fitter's
//! keypoint vertices and silhouette sample), differentiable in pose, shape and placement.
//!
//! The same steps as [`nia_data::body::lbs`] (which the tests check it against):
//! `v_shaped = T + S beta`, `J = J_regressor v_shaped = J_T + J_S beta` (the regressor is
//! linear, so it is applied to the template and blend shapes once, here), pose feature
//! `(R_j - I)` of joints 1..23, `v_posed = v_shaped + P . feature`, the kinematic chain
//! `G_k = G_parent(k) [R_k | J_k - J_parent(k)]`, `A_k = G_k translate(-J_k)`,
//! `v = (sum_k w_vk A_k) v_posed`, and ZJU-MoCap's placement `x @ R(Rh)^T + Th`.
//! The root's own rotation is the identity (ZJU-MoCap keeps it in `Rh`).

use burn::prelude::*;
use nia_data::body::{BodyModel, NUM_JOINTS, NUM_POSE_FEATURES};

use super::rotation::rodrigues;
use super::FitError;

/// Number of body-pose parameters the fitter optimises: joints 1..23, axis-angle.
pub const BODY_POSE_DIM: usize = 3 * (NUM_JOINTS - 1);

/// The model's arrays restricted to a vertex subset, as constant tensors on one device.
#[derive(Debug, Clone)]
pub struct SmplLayer {
    /// `[Vs]` model vertex index of each row.
    pub vertex_ids: Vec<usize>,
    /// `S`, the number of shape coefficients.
    pub num_betas: usize,
    parents: Vec<usize>,
    /// `[1, Vs * 3]` template vertices of the subset.
    template: Tensor<2>,
    /// `[S, Vs * 3]` shape blend shapes of the subset.
    shapedirs: Tensor<2>,
    /// `[207, Vs * 3]` pose blend shapes of the subset.
    posedirs: Tensor<2>,
    /// `[1, Vs, 24]` skinning weights of the subset.
    weights: Tensor<3>,
    /// `[1, 72]` rest joints of the template, `J_regressor T`.
    joint_template: Tensor<2>,
    /// `[S, 72]` `J_regressor S`: how the rest joints move per unit of each beta.
    joint_shapedirs: Tensor<2>,
}

/// A posed batch.
#[derive(Debug, Clone)]
pub struct PosedBatch {
    /// `[B, 24, 3]` world joints, metres.
    pub joints: Tensor<3>,
    /// `[B, Vs, 3]` world vertices of the subset, metres.
    pub vertices: Tensor<3>,
}

impl SmplLayer {
    /// The layer for `vertex_ids` of `model` (indices below `V`).
    pub fn new(model: &BodyModel, vertex_ids: &[usize], device: &Device) -> Result<Self, FitError> {
        let v_count = model.num_vertices();
        if let Some(&bad) = vertex_ids.iter().find(|&&v| v >= v_count) {
            return Err(FitError::BadBinding {
                keypoint: usize::MAX,
                what: format!("vertex {bad} of a model with {v_count} vertices"),
            });
        }
        let s = model.num_betas();
        let vs = vertex_ids.len();
        let mut template = Vec::with_capacity(vs * 3);
        let mut shapedirs = vec![0.0f32; s * vs * 3];
        let mut posedirs = vec![0.0f32; NUM_POSE_FEATURES * vs * 3];
        let mut weights = Vec::with_capacity(vs * NUM_JOINTS);
        for (row, &v) in vertex_ids.iter().enumerate() {
            template.extend(model.v_template[v].to_array());
            for c in 0..3 {
                for b in 0..s {
                    shapedirs[b * vs * 3 + row * 3 + c] = model.shapedirs[(v * 3 + c) * s + b];
                }
                for p in 0..NUM_POSE_FEATURES {
                    posedirs[p * vs * 3 + row * 3 + c] =
                        model.posedirs[(v * 3 + c) * NUM_POSE_FEATURES + p];
                }
            }
            weights.extend(model.weights[v]);
        }
        // The regressor applied to the template and to each shape blend shape (f64 sums).
        let mut joint_template = vec![0.0f32; NUM_JOINTS * 3];
        let mut joint_shapedirs = vec![0.0f32; s * NUM_JOINTS * 3];
        for (k, row) in model.j_regressor.iter().enumerate().take(NUM_JOINTS) {
            for c in 0..3 {
                let mut acc = 0.0f64;
                let mut acc_s = vec![0.0f64; s];
                for &(v, w) in row {
                    let v = v as usize;
                    acc += w as f64 * model.v_template[v][c] as f64;
                    for (b, a) in acc_s.iter_mut().enumerate() {
                        *a += w as f64 * model.shapedirs[(v * 3 + c) * s + b] as f64;
                    }
                }
                joint_template[k * 3 + c] = acc as f32;
                for (b, a) in acc_s.iter().enumerate() {
                    joint_shapedirs[b * NUM_JOINTS * 3 + k * 3 + c] = *a as f32;
                }
            }
        }
        let parents = (0..NUM_JOINTS)
            .map(|k| match model.parents.get(k) {
                Some(&p) if p >= 0 && (p as usize) < k => p as usize,
                _ => 0,
            })
            .collect();
        let t2 = |v: Vec<f32>, shape: [usize; 2]| {
            Tensor::<2>::from_data(TensorData::new(v, shape), device)
        };
        Ok(Self {
            vertex_ids: vertex_ids.to_vec(),
            num_betas: s,
            parents,
            template: t2(template, [1, vs * 3]),
            shapedirs: t2(shapedirs, [s, vs * 3]),
            posedirs: t2(posedirs, [NUM_POSE_FEATURES, vs * 3]),
            weights: Tensor::from_data(TensorData::new(weights, [1, vs, NUM_JOINTS]), device),
            joint_template: t2(joint_template, [1, NUM_JOINTS * 3]),
            joint_shapedirs: t2(joint_shapedirs, [s, NUM_JOINTS * 3]),
        })
    }

    /// Pose and place a batch.
    ///
    /// # Shapes
    /// - `body_pose`: `[B, 69]` axis-angle of joints 1..23 (`poses[3..72]`)
    /// - `betas`: `[B, S]`
    /// - `rh`, `th`: `[B, 3]` global axis-angle and translation (metres)
    pub fn forward(
        &self,
        body_pose: Tensor<2>,
        betas: Tensor<2>,
        rh: Tensor<2>,
        th: Tensor<2>,
    ) -> PosedBatch {
        let [b, _] = body_pose.dims();
        let vs = self.vertex_ids.len();
        let device = body_pose.device();
        let v_shaped = if self.num_betas > 0 {
            self.template.clone() + betas.clone().matmul(self.shapedirs.clone())
        } else {
            self.template.clone().expand([b, vs * 3])
        };
        let rest = if self.num_betas > 0 {
            self.joint_template.clone() + betas.matmul(self.joint_shapedirs.clone())
        } else {
            self.joint_template.clone().expand([b, NUM_JOINTS * 3])
        }
        .reshape([b, NUM_JOINTS, 3]);

        let rot = rodrigues(body_pose.reshape([b * (NUM_JOINTS - 1), 3])).reshape([
            b,
            NUM_JOINTS - 1,
            3,
            3,
        ]);
        let eye = Tensor::<2>::eye(3, &device).reshape([1, 1, 3, 3]);
        let feature = (rot.clone() - eye).reshape([b, NUM_POSE_FEATURES]);
        let v_posed = (v_shaped + feature.matmul(self.posedirs.clone())).reshape([b, vs, 3]);

        // The kinematic chain: rotations [B, 3, 3] and translations [B, 3, 1] of G_k.
        let joint = |k: usize| rest.clone().narrow(1, k, 1).reshape([b, 3, 1]);
        let mut g_rot: Vec<Tensor<3>> = Vec::with_capacity(NUM_JOINTS);
        let mut g_trans: Vec<Tensor<3>> = Vec::with_capacity(NUM_JOINTS);
        g_rot.push(
            Tensor::<2>::eye(3, &device)
                .unsqueeze_dim::<3>(0)
                .expand([b, 3, 3]),
        );
        g_trans.push(joint(0));
        for k in 1..NUM_JOINTS {
            let p = self.parents[k];
            let r_k = rot.clone().narrow(1, k - 1, 1).reshape([b, 3, 3]);
            let offset = joint(k) - joint(p);
            g_trans.push(g_rot[p].clone().matmul(offset) + g_trans[p].clone());
            g_rot.push(g_rot[p].clone().matmul(r_k));
        }
        // A_k = [G_rot | G_trans - G_rot J_k], flattened row-major to [B, 24, 12].
        let a: Vec<Tensor<3>> = (0..NUM_JOINTS)
            .map(|k| {
                let t = g_trans[k].clone() - g_rot[k].clone().matmul(joint(k));
                Tensor::cat(vec![g_rot[k].clone(), t], 2).reshape([b, 1, 12])
            })
            .collect();
        let a = Tensor::cat(a, 1); // [B, 24, 12]
        let blended = self
            .weights
            .clone()
            .expand([b, vs, NUM_JOINTS])
            .matmul(a)
            .reshape([b, vs, 3, 4]);
        let linear = blended.clone().narrow(3, 0, 3); // [B, Vs, 3, 3]
        let shift = blended.narrow(3, 3, 1).reshape([b, vs, 3]);
        let local = (linear * v_posed.unsqueeze_dim::<4>(2))
            .sum_dim(3)
            .reshape([b, vs, 3])
            + shift;
        let joints_local = Tensor::cat(g_trans, 2).swap_dims(1, 2); // [B, 24, 3]

        let global_t = rodrigues(rh).swap_dims(1, 2); // R(Rh)^T, [B, 3, 3]
        let th = th.unsqueeze_dim::<3>(1); // [B, 1, 3]
        PosedBatch {
            joints: joints_local.matmul(global_t.clone()) + th.clone(),
            vertices: local.matmul(global_t) + th,
        }
    }
}
