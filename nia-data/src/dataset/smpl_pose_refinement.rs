//! SMPL pose refinement: bends the fit's joints onto the person its source masks show, after
//! the rigid alignment ([`super::smpl_alignment`]; `[data] smpl_alignment = { pose_iterations
//! = N }`, off while `N` is 0).
//!
//! A capture's fit is off by a few degrees per joint as well (worst at the wrists, ankles and
//! head), which no rigid motion reaches. The refinement minimises the rigid alignment's
//! silhouette energy `E` (same terms, same robust scale) plus a prior that keeps every joint
//! near the fit as given,
//!
//! `E + sigma^2 sum_k |log(R_k R_k^fit^T)|^2 / s^2`,
//!
//! over the 23 body joints' rotations `R_k` and the global `Rh`, `Th`; `s` =
//! [`SmplAlignment::pose_prior_deg`], `sigma^2` the views' mean robust scale squared (a joint
//! turned by `s` costs as much as one view's vertex term fully saturated). A twist about a
//! bone changes no silhouette: the prior keeps it where the fit had it.
//!
//! Levenberg-Marquardt as in the rigid alignment. The step is linearised in world-frame
//! rotations `omega_k` about the posed joints `J_k`: joint `k`'s subtree turns about `J_k`, so
//! a vertex `x` moves by `W_k(x) omega_k x (x - J_k)`, `W_k(x)` the vertex's skinning weight
//! summed over `k` and its descendants (pose blend shapes are left out of the step, not out of
//! `E`). `omega_k` becomes the local rotation `exp(Q_p^T omega_k) R_k` (`Q_p` the parent's
//! world rotation); every candidate is posed again by [`BodyModel::lbs`] and accepted only
//! where its energy falls, no joint moves more than [`SmplAlignment::max_joint_deg`] from the
//! fit, and the body's centre and orientation stay within the rigid bounds. The stored
//! vertices' own offsets from the model's LBS of the stored params are kept.

use glam::{Mat3, Mat4, Quat, Vec3};

use crate::body::{BodyModel, PosedAt, SmplParams, NUM_JOINTS};
use crate::dataset::silhouette_energy::{NormalEquations, Residual, SilhouetteTerms};
use crate::dataset::smpl_alignment::{AlignmentError, AlignmentView, SmplAlignment};

/// Parameters of a step: `omega` and `t` of the whole body, then `omega_k` of joints 1..23.
const PARAMS: usize = 6 + 3 * (NUM_JOINTS - 1);
/// Skinning weights below this do not enter a vertex's Jacobian row.
const MIN_SUBTREE_WEIGHT: f32 = 1e-4;

/// What the refinement did (the refined fit itself is [`refine_pose`]'s vertices and params).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseRefinement {
    /// The objective (module docs) of the fit as given and after the refinement (never
    /// larger).
    pub energy_before: f32,
    pub energy_after: f32,
    /// Mean and largest rotation of the 23 body joints away from the fit as given, degrees.
    pub mean_joint_deg: f32,
    pub max_joint_deg: f32,
    /// Accepted steps.
    pub steps: usize,
}

fn invalid(field: &str, expected: impl Into<String>, got: impl ToString) -> AlignmentError {
    AlignmentError::Invalid {
        field: field.into(),
        expected: expected.into(),
        got: got.to_string(),
    }
}

fn rotation(axis_angle: &[f32]) -> Quat {
    Quat::from_scaled_axis(Vec3::new(axis_angle[0], axis_angle[1], axis_angle[2]))
}

/// The world rotation of joint `k` of a body posed with `joint_transforms`.
fn world_rotation(joint_transforms: &[Mat4], k: usize) -> Quat {
    Quat::from_mat3(&Mat3::from_mat4(joint_transforms[k])).normalize()
}

/// `[24]` per joint: the rotation taking the fit's local rotation to `params`'.
fn joint_changes(params: &SmplParams, fit: &SmplParams) -> Vec<Quat> {
    (0..NUM_JOINTS)
        .map(|k| {
            let span = 3 * k..3 * k + 3;
            (rotation(&params.poses[span.clone()]) * rotation(&fit.poses[span]).inverse())
                .normalize()
        })
        .collect()
}

/// Refines the pose of the fit `vertices` ([V] world metres, the model's vertex order) with
/// parameters `params` onto the masks of `views` (module docs): the refined vertices, the
/// refined parameters (shape untouched) and what was done. A view with an empty mask takes no part; with none left the fit is returned as
/// it is (`steps` 0). Errors name a vertex count that is not the model's, a mask of the wrong
/// size or a body behind a camera.
pub fn refine_pose(
    model: &BodyModel,
    vertices: &[Vec3],
    params: &SmplParams,
    views: &[AlignmentView<'_>],
    config: &SmplAlignment,
) -> Result<(Vec<Vec3>, SmplParams, PoseRefinement), AlignmentError> {
    config.validate()?;
    if vertices.len() != model.v_template.len() || vertices.iter().any(|v| !v.is_finite()) {
        return Err(invalid(
            "vertices",
            format!(
                "{} finite world points (the body model's vertices)",
                model.v_template.len()
            ),
            format!("{} vertices", vertices.len()),
        ));
    }
    let finite = params
        .poses
        .iter()
        .chain(&params.shapes)
        .all(|x| x.is_finite())
        && params.rh.is_finite()
        && params.th.is_finite();
    if !finite {
        return Err(invalid(
            "params",
            "finite poses, shapes, Rh and Th",
            "a NaN or infinite value",
        ));
    }
    let fit = params.clone();
    let posed = model.lbs(params);
    let offsets: Vec<Vec3> = vertices
        .iter()
        .zip(&posed.vertices)
        .map(|(v, p)| *v - *p)
        .collect();
    let unchanged = PoseRefinement {
        energy_before: 0.0,
        energy_after: 0.0,
        mean_joint_deg: 0.0,
        max_joint_deg: 0.0,
        steps: 0,
    };
    if config.pose_iterations == 0 {
        return Ok((vertices.to_vec(), fit, unchanged));
    }
    let stride = vertices.len().div_ceil(config.vertex_samples).max(1);
    let sample: Vec<usize> = (0..vertices.len()).step_by(stride).collect();
    // The sample vertices of the body posed by `params` (the stored offsets added).
    let pose_sample = |params: &SmplParams| -> (PosedAt, Vec<Vec3>) {
        let at = model.lbs_at(params, &posed, &sample);
        let points = at
            .vertices
            .iter()
            .zip(&sample)
            .map(|(p, &i)| *p + offsets[i])
            .collect();
        (at, points)
    };
    let centroid = |points: &[Vec3]| points.iter().copied().sum::<Vec3>() / points.len() as f32;
    let (_, start_points) = pose_sample(&fit);
    let start_centre = centroid(&start_points);
    let terms = SilhouetteTerms::new(views, start_centre, config)?;
    if terms.is_empty() {
        return Ok((vertices.to_vec(), fit, unchanged));
    }

    // `[samples][24]` skinning weight summed over each joint's subtree.
    let parent = |k: usize| {
        model
            .parents
            .get(k)
            .copied()
            .filter(|&p| p >= 0 && (p as usize) < k)
            .map(|p| p as usize)
    };
    let subtree: Vec<[f32; NUM_JOINTS]> = sample
        .iter()
        .map(|&i| {
            let mut w = [0.0f32; NUM_JOINTS];
            if let Some(weights) = model.weights.get(i) {
                for (j, &wj) in weights.iter().enumerate() {
                    let mut k = Some(j);
                    while let Some(kk) = k {
                        w[kk] += wj;
                        k = parent(kk);
                    }
                }
            }
            w
        })
        .collect();

    let s = config.pose_prior_deg.to_radians();
    let prior_weight = terms.mean_sigma2 / (s * s);
    let max_joint = config.max_joint_deg.to_radians();
    let max_global = config.max_rotation_deg.to_radians();
    let start_rh = Quat::from_scaled_axis(fit.rh);

    // The objective of `params`, posed, and its sample points.
    let evaluate = |params: &SmplParams| {
        let (posed, points) = pose_sample(params);
        let prior: f32 = joint_changes(params, &fit)
            .iter()
            .skip(1)
            .map(|q| q.to_scaled_axis().length_squared())
            .sum();
        let energy = terms.energy(&points, None) + prior_weight * prior;
        (energy, posed, points)
    };
    // Normal equations of the step at `params` (module docs).
    let linearise = |params: &SmplParams, posed: &PosedAt, points: &[Vec3]| {
        let mut system = NormalEquations::new(PARAMS);
        let centre = centroid(points);
        let mut row = Vec::with_capacity(PARAMS);
        let mut sink = |res: Residual| {
            let x = points[res.index];
            row.clear();
            let d = (x - centre).cross(res.a);
            row.extend([(0, d.x), (1, d.y), (2, d.z), (3, res.a.x), (4, res.a.y)]);
            row.push((5, res.a.z));
            for (k, &w) in subtree[res.index].iter().enumerate().skip(1) {
                if w < MIN_SUBTREE_WEIGHT {
                    continue;
                }
                let d = (x - posed.joints[k]).cross(res.a) * w;
                let p = 6 + 3 * (k - 1);
                row.extend([(p, d.x), (p + 1, d.y), (p + 2, d.z)]);
            }
            system.add(&row, res.r, res.w);
        };
        terms.energy(points, Some(&mut sink));
        for (k, change) in joint_changes(params, &fit).iter().enumerate().skip(1) {
            // The change in world axes: `omega_k` adds to it.
            let q_parent = parent(k).map_or(Quat::IDENTITY, |p| {
                world_rotation(&posed.joint_transforms, p)
            });
            let r = q_parent * change.to_scaled_axis();
            let p = 6 + 3 * (k - 1);
            for (m, rm) in [r.x, r.y, r.z].into_iter().enumerate() {
                system.add(&[(p + m, 1.0)], rm, prior_weight);
            }
        }
        (system, centre)
    };
    // The parameters after the step `delta` about `centre`.
    let step = |params: &SmplParams, posed: &PosedAt, centre: Vec3, delta: &[f64]| {
        let v = |i: usize| Vec3::new(delta[i] as f32, delta[i + 1] as f32, delta[i + 2] as f32);
        let turn = Quat::from_scaled_axis(v(0));
        let mut next = params.clone();
        next.rh = (turn * Quat::from_scaled_axis(params.rh))
            .normalize()
            .to_scaled_axis();
        next.th = turn * (params.th - centre) + centre + v(3);
        for k in 1..NUM_JOINTS {
            let q_parent = parent(k).map_or(Quat::IDENTITY, |p| {
                world_rotation(&posed.joint_transforms, p)
            });
            let local = Quat::from_scaled_axis(q_parent.inverse() * v(6 + 3 * (k - 1)));
            let span = 3 * k..3 * k + 3;
            let r = (local * rotation(&params.poses[span.clone()]))
                .normalize()
                .to_scaled_axis();
            next.poses[span].copy_from_slice(&r.to_array());
        }
        next
    };
    let within = |params: &SmplParams, points: &[Vec3]| {
        let joints_ok = joint_changes(params, &fit)
            .iter()
            .skip(1)
            .all(|q| q.angle_between(Quat::IDENTITY) <= max_joint);
        let global_ok = Quat::from_scaled_axis(params.rh).angle_between(start_rh) <= max_global;
        let moved_ok = centroid(points).distance(start_centre) <= config.max_translation_m;
        joints_ok && global_ok && moved_ok
    };

    let mut state = fit.clone();
    let (energy_before, mut at, mut points) = evaluate(&state);
    let mut energy = energy_before;
    let (mut system, mut centre) = linearise(&state, &at, &points);
    let mut lambda = 1e-3f64;
    let mut steps = 0;
    for _ in 0..config.pose_iterations {
        let Some(delta) = system.solve(lambda) else {
            break;
        };
        let candidate = step(&state, &at, centre, &delta);
        let (candidate_energy, candidate_posed, candidate_points) = evaluate(&candidate);
        let accepted = candidate_energy.is_finite()
            && candidate_energy < energy
            && within(&candidate, &candidate_points);
        if accepted {
            let converged = energy - candidate_energy <= 1e-6 * energy.max(1e-12);
            state = candidate;
            energy = candidate_energy;
            at = candidate_posed;
            points = candidate_points;
            steps += 1;
            lambda = (lambda / 3.0).max(1e-7);
            if converged {
                break;
            }
            (system, centre) = linearise(&state, &at, &points);
        } else {
            lambda *= 10.0;
            if lambda > 1e8 {
                break;
            }
        }
    }
    let angles: Vec<f32> = joint_changes(&state, &fit)
        .iter()
        .skip(1)
        .map(|q| q.angle_between(Quat::IDENTITY).to_degrees())
        .collect();
    let refined: Vec<Vec3> = model
        .lbs(&state)
        .vertices
        .iter()
        .zip(&offsets)
        .map(|(p, o)| *p + *o)
        .collect();
    Ok((
        refined,
        state,
        PoseRefinement {
            energy_before,
            energy_after: energy,
            mean_joint_deg: angles.iter().sum::<f32>() / angles.len() as f32,
            max_joint_deg: angles.iter().copied().fold(0.0, f32::max),
            steps,
        },
    ))
}
