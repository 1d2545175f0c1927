//! The priors of a fit, each a quadratic term on the parameters (zero where unused):
//!
//! - pose: `w_pose sum_k |Q_p log(R_k R_k^ref^T)|^2` over the 23 body joints, the rotation
//!   from a reference pose in world axes (`prepare`: the mean pose, zero, so the term is
//!   `|theta|^2`; the loader's refinement: the fit as given);
//! - joint limits: `w_lim sum max(0, s theta_j)^2` over knee and elbow angles bending the wrong
//!   way (SMPLify's angle prior, as a hinge);
//! - temporal: `w_t sum_k |Q_p log(R_k R_k^prev^T)|^2 + w_T |Th - Th^prev|^2` to the previous
//!   frame's fit.
//!
//! The rotation residuals' rows in the step's `omega_k` are the identity (first order at the
//! current pose); the limits' are the rows of `Q_p^T`.

use glam::{Mat3, Quat, Vec3};

use super::body::{joint_changes, local_axis_angle, BodyPoints, FrameState, PosedPoints};
use super::solver::NormalEquations;
use crate::body::{SmplParams, NUM_JOINTS};

/// `(joint, axis, s)`: the hinge penalises `s theta > 0` on that axis of the joint's local
/// rotation. Knees (joints 4 and 5, about x) bend with positive angles; the left elbow (18,
/// about y) with negative and the right (19) with positive ones (SMPL axes; SMPLify's
/// `angle_prior` indices 55, 58, 12, 15 of the pose vector).
pub const JOINT_LIMITS: [(usize, usize, f32); 4] =
    [(4, 0, -1.0), (5, 0, -1.0), (18, 1, 1.0), (19, 1, -1.0)];

/// A frame's priors (module docs).
#[derive(Debug, Clone, Default)]
pub(crate) struct Priors {
    /// The reference pose and `w_pose`.
    pub pose: Option<(SmplParams, f32)>,
    /// `w_lim` (0: off).
    pub limits: f32,
    /// The previous frame's fit, `w_t` and `w_T`.
    pub temporal: Option<(SmplParams, f32, f32)>,
}

impl Priors {
    /// The priors' energy at `state`.
    pub fn energy(&self, state: &FrameState) -> f32 {
        let mut e = 0.0f32;
        let rotations = |reference: &SmplParams| -> f32 {
            joint_changes(&state.params, reference)
                .iter()
                .skip(1)
                .map(|q| q.to_scaled_axis().length_squared())
                .sum()
        };
        if let Some((reference, w)) = &self.pose {
            e += w * rotations(reference);
        }
        if self.limits > 0.0 {
            for (k, axis, s) in JOINT_LIMITS {
                let hinge = (s * local_axis_angle(&state.params, k)[axis]).max(0.0);
                e += self.limits * hinge * hinge;
            }
        }
        if let Some((prev, w_pose, w_th)) = &self.temporal {
            e += w_pose * rotations(prev);
            e += w_th * (state.params.th - prev.th).length_squared();
        }
        e
    }

    /// Adds the priors' residuals at `state` to `system`, this frame's parameters starting at
    /// `offset`.
    pub fn linearise(
        &self,
        body: &BodyPoints<'_>,
        state: &FrameState,
        posed: &PosedPoints,
        system: &mut NormalEquations,
        offset: usize,
    ) {
        let joint_param = |k: usize| offset + 6 + 3 * (k - 1);
        let mut rotations = |reference: &SmplParams, w: f32| {
            for (k, change) in joint_changes(&state.params, reference)
                .iter()
                .enumerate()
                .skip(1)
            {
                let r = body.parent_rotation(posed, k) * change.to_scaled_axis();
                let p = joint_param(k);
                for (m, rm) in r.to_array().into_iter().enumerate() {
                    system.add(&[(p + m, 1.0)], rm, w);
                }
            }
        };
        if let Some((reference, w)) = &self.pose {
            rotations(reference, *w);
        }
        if let Some((prev, w_pose, w_th)) = &self.temporal {
            rotations(prev, *w_pose);
            // Th moves by omega_0 x (Th - c) + t: row of component i over omega_0 is
            // (Th - c) x e_i.
            let m = state.params.th - posed.centre;
            let r = state.params.th - prev.th;
            for (i, e) in [Vec3::X, Vec3::Y, Vec3::Z].into_iter().enumerate() {
                let d = m.cross(e);
                system.add(
                    &[
                        (offset, d.x),
                        (offset + 1, d.y),
                        (offset + 2, d.z),
                        (offset + 3 + i, 1.0),
                    ],
                    r[i],
                    *w_th,
                );
            }
        }
        if self.limits > 0.0 {
            for (k, axis, s) in JOINT_LIMITS {
                let theta = local_axis_angle(&state.params, k)[axis];
                if s * theta <= 0.0 {
                    continue;
                }
                // d theta / d omega_k = Q_p^T to first order: its row `axis`.
                let q = Mat3::from_quat(body.parent_rotation(posed, k).inverse());
                let row = q.row(axis) * s;
                let p = joint_param(k);
                system.add(
                    &[(p, row.x), (p + 1, row.y), (p + 2, row.z)],
                    s * theta,
                    self.limits,
                );
            }
        }
    }
}

/// The largest rotation of the 23 body joints away from `reference`, and their mean, degrees.
pub(crate) fn joint_angles_deg(params: &SmplParams, reference: &SmplParams) -> (f32, f32) {
    let angles: Vec<f32> = joint_changes(params, reference)
        .iter()
        .skip(1)
        .map(|q| q.angle_between(Quat::IDENTITY).to_degrees())
        .collect();
    let mean = angles.iter().sum::<f32>() / (NUM_JOINTS - 1) as f32;
    (angles.iter().copied().fold(0.0, f32::max), mean)
}
