//! The fitting objective of a batch of `B` frames (one frame, or the shape frames jointly):
//!
//! `E = E_kp + w_out E_sil_out + w_in E_sil_in + w_pose |theta|^2 + w_lim E_lim + w_beta |beta|^2
//!      + w_t |theta - theta_prev|^2 + w_T |Th - Th_prev|^2`,
//!
//! - `E_kp = sum c rho(|pi(X_k) - x_k|^2) / sum c` over keypoints and views, `rho` the
//!   Geman-McClure function `rho(e2) = sigma^2 e2 / (sigma^2 + e2)` (SMPLify's data term);
//! - `E_sil_out`: mean `rho(D(pi(v))^2)` of the projected vertices `v` over the mask's distance
//!   map `D` (zero inside the mask);
//! - `E_sil_in`: mean `rho(|b - pi(v_nearest(b))|^2)` over the mask's boundary samples `b`;
//! - `E_lim = sum_j max(0, s_j theta_j)^2` over knee and elbow angles bending the wrong way
//!   (SMPLify's angle prior, as a hinge).
//!
//! Prior and temporal terms are divided by `B` so that the weights mean the same per frame.

use burn::prelude::*;

use super::config::FitConfig;
use super::projection::ViewTensors;
use super::silhouette::SilhouetteTarget;
use super::smpl_layer::{SmplLayer, BODY_POSE_DIM};

/// `(body-pose index, s)`: the hinge penalises `s theta > 0`. Knees (`poses[12]`, `poses[15]`,
/// about x) bend with positive angles; the left elbow (`poses[55]`, about y) with negative and
/// the right (`poses[58]`) with positive ones (SMPL axes; SMPLify's `angle_prior` indices).
pub const JOINT_LIMITS: [(usize, f32); 4] = [
    (12 - 3, -1.0),
    (15 - 3, -1.0),
    (55 - 3, 1.0),
    (58 - 3, -1.0),
];

/// Which parameters a stage moves and which terms it uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// `Rh`, `Th` on the torso keypoints only.
    Global,
    /// Body pose, `Rh`, `Th`; every term but the shape prior.
    Pose,
    /// As `Pose`, plus the betas.
    Shape,
}

impl Stage {
    pub fn name(self) -> &'static str {
        match self {
            Stage::Global => "global",
            Stage::Pose => "pose",
            Stage::Shape => "shape",
        }
    }
}

/// The constant side of a batch: observations and regularisation targets.
pub(crate) struct Targets<'a> {
    /// `[B]`.
    pub batch: usize,
    pub views: ViewTensors,
    /// `[1, K, 24 + Vk]` keypoints as combinations of joints and keypoint vertices.
    pub bindings: Tensor<3>,
    /// `Vk`, the keypoint vertices at the front of the layer's subset.
    pub keypoint_vertices: usize,
    /// `[B, K, N]` observed pixels and confidences.
    pub kp_u: Tensor<3>,
    pub kp_v: Tensor<3>,
    pub conf: Tensor<3>,
    pub conf_sum: f32,
    /// `conf` restricted to torso keypoints, and its sum.
    pub conf_torso: Tensor<3>,
    pub conf_torso_sum: f32,
    /// `[B][N]` silhouettes.
    pub silhouettes: Vec<Vec<Option<&'a SilhouetteTarget>>>,
    /// `[B, 69]`, `[B, 3]` previous frame's pose and translation, `[B, 1]` 1 where there is one.
    pub prev_pose: Tensor<2>,
    pub prev_th: Tensor<2>,
    pub has_prev: Tensor<2>,
    /// `[1, 69]` joint-limit signs.
    pub limit_signs: Tensor<2>,
}

/// The variables of a batch (autodiff leaves).
pub(crate) struct Variables {
    /// `[B, 69]`, `[B, S]`, `[B, 3]`, `[B, 3]`.
    pub pose: Tensor<2>,
    pub betas: Tensor<2>,
    pub rh: Tensor<2>,
    pub th: Tensor<2>,
}

/// Geman-McClure: `sigma^2 e2 / (sigma^2 + e2)`.
fn geman_mcclure(e2: Tensor<3>, sigma: f32) -> Tensor<3> {
    let s2 = sigma * sigma;
    e2.clone() * s2 / (e2 + s2)
}

/// The objective `[1]` and the keypoints' projections `[B, K, N]` (u, v).
pub(crate) fn objective(
    layer: &SmplLayer,
    targets: &Targets<'_>,
    vars: &Variables,
    stage: Stage,
    config: &FitConfig,
) -> (Tensor<1>, Tensor<3>, Tensor<3>) {
    let b = targets.batch;
    let device = vars.pose.device();
    let posed = layer.forward(
        vars.pose.clone(),
        vars.betas.clone(),
        vars.rh.clone(),
        vars.th.clone(),
    );
    let [_, vs, _] = posed.vertices.dims();
    let [_, k, _] = targets.bindings.dims();
    let sources = Tensor::cat(
        vec![
            posed.joints,
            posed
                .vertices
                .clone()
                .narrow(1, 0, targets.keypoint_vertices),
        ],
        1,
    );
    let keypoints = targets
        .bindings
        .clone()
        .expand([b, k, sources.dims()[1]])
        .matmul(sources);
    let with_silhouette =
        stage != Stage::Global && targets.silhouettes.iter().flatten().any(|s| s.is_some());
    let points = if with_silhouette {
        Tensor::cat(vec![keypoints, posed.vertices], 1)
    } else {
        keypoints
    };
    let proj = targets.views.project(points);
    let n = targets.views.count;
    let ku = proj.u.clone().narrow(1, 0, k);
    let kv = proj.v.clone().narrow(1, 0, k);
    let e2 =
        (ku.clone() - targets.kp_u.clone()).square() + (kv.clone() - targets.kp_v.clone()).square();
    let rho = geman_mcclure(e2, config.keypoint_sigma_px);
    let (conf, conf_sum) = match stage {
        Stage::Global => (targets.conf_torso.clone(), targets.conf_torso_sum),
        _ => (targets.conf.clone(), targets.conf_sum),
    };
    let mut total = (rho * conf).sum() / conf_sum.max(1e-12);

    if with_silhouette {
        let su = proj.u.narrow(1, k, vs);
        let sv = proj.v.narrow(1, k, vs);
        let (out, inward) = silhouette_terms(targets, su, sv, b, vs, n, config, &device);
        total = total + out * config.silhouette_out_weight + inward * config.silhouette_in_weight;
    }
    if stage != Stage::Global {
        let pose = vars.pose.clone();
        let bf = b as f32;
        total = total + pose.clone().square().sum() * (config.pose_prior_weight / bf);
        let hinge = (pose.clone() * targets.limit_signs.clone()).clamp_min(0.0);
        total = total + hinge.square().sum() * (config.joint_limit_weight / bf);
        let dp = (pose - targets.prev_pose.clone()).square() * targets.has_prev.clone();
        let dt = (vars.th.clone() - targets.prev_th.clone()).square() * targets.has_prev.clone();
        total = total
            + dp.sum() * (config.temporal_pose_weight / bf)
            + dt.sum() * (config.temporal_translation_weight / bf);
    }
    if stage == Stage::Shape {
        // The betas are one row repeated B times: |beta|^2 once.
        total = total + vars.betas.clone().square().sum() * (config.shape_prior_weight / b as f32);
    }
    (total, ku, kv)
}

/// `(E_sil_out, E_sil_in)`, each `[1]`, from the silhouette vertices' projections `[B, Vs, N]`.
#[allow(clippy::too_many_arguments)]
fn silhouette_terms(
    targets: &Targets<'_>,
    su: Tensor<3>,
    sv: Tensor<3>,
    b: usize,
    vs: usize,
    n: usize,
    config: &FitConfig,
    device: &Device,
) -> (Tensor<1>, Tensor<1>) {
    let hu = su
        .clone()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap_or_default();
    let hv = sv
        .clone()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap_or_default();
    let len = b * vs * n;
    let mut coef = vec![vec![0.0f32; len]; 10];
    let mut sampled = 0usize;
    let mut picks: Vec<i64> = Vec::new();
    let mut goal_u: Vec<f32> = Vec::new();
    let mut goal_v: Vec<f32> = Vec::new();
    for bi in 0..b {
        for ni in 0..n {
            let Some(s) = targets.silhouettes[bi][ni] else {
                continue;
            };
            for vi in 0..vs {
                let idx = (bi * vs + vi) * n + ni;
                let c = s.bilinear_coefficients(hu[idx], hv[idx]);
                for (q, value) in c.iter().enumerate() {
                    coef[q][idx] = *value;
                }
            }
            sampled += vs;
            for p in &s.boundary {
                let mut best = (f32::INFINITY, 0usize);
                for vi in 0..vs {
                    let idx = (bi * vs + vi) * n + ni;
                    let d = (hu[idx] - p[0]).powi(2) + (hv[idx] - p[1]).powi(2);
                    if d < best.0 {
                        best = (d, idx);
                    }
                }
                if best.0.is_finite() {
                    picks.push(best.1 as i64);
                    goal_u.push(p[0]);
                    goal_v.push(p[1]);
                }
            }
        }
    }
    let zero = || Tensor::<1>::zeros([1], device);
    if sampled == 0 {
        return (zero(), zero());
    }
    let t = |v: Vec<f32>| Tensor::<3>::from_data(TensorData::new(v, [b, vs, n]), device);
    let mut c = coef.into_iter().map(t);
    let (a, bx, cy, dxy) = (
        c.next().unwrap(),
        c.next().unwrap(),
        c.next().unwrap(),
        c.next().unwrap(),
    );
    let (x0, y0, sx, sy) = (
        c.next().unwrap(),
        c.next().unwrap(),
        c.next().unwrap(),
        c.next().unwrap(),
    );
    let (xe, ye) = (c.next().unwrap(), c.next().unwrap());
    let fx = su.clone() - x0;
    let fy = sv.clone() - y0;
    let dist = a
        + bx * fx.clone()
        + cy * fy.clone()
        + dxy * fx * fy
        + sx * (su.clone() - xe)
        + sy * (sv.clone() - ye);
    let out = geman_mcclure(dist.square(), config.silhouette_sigma_px).sum() / sampled as f32;

    let inward = if picks.is_empty() {
        zero()
    } else {
        let m = picks.len();
        let index = Tensor::<1, Int>::from_data(TensorData::new(picks, [m]), device);
        let pu = su.reshape([len]).select(0, index.clone());
        let pv = sv.reshape([len]).select(0, index);
        let gu = Tensor::<1>::from_data(TensorData::new(goal_u, [m]), device);
        let gv = Tensor::<1>::from_data(TensorData::new(goal_v, [m]), device);
        let e2 = ((pu - gu).square() + (pv - gv).square()).reshape([1, 1, m]);
        geman_mcclure(e2, config.silhouette_sigma_px).sum() / m as f32
    };
    (out, inward)
}

/// `[1, 69]` signs of [`JOINT_LIMITS`] (0 elsewhere).
pub(crate) fn limit_signs(device: &Device) -> Tensor<2> {
    let mut s = vec![0.0f32; BODY_POSE_DIM];
    for (i, sign) in JOINT_LIMITS {
        s[i] = sign;
    }
    Tensor::from_data(TensorData::new(s, [1, BODY_POSE_DIM]), device)
}
