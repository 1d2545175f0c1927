//! SMPL alignment: moves a scene's fitted body rigidly onto the person its source masks show,
//! before anything reads it (`[data] smpl_alignment`, off by default; docs/robustness.md has
//! what it measured).
//!
//! A capture's SMPL fit is off the person by a centimetre or two of global placement and about
//! a degree of global rotation (docs/data.md, "Capture flaws"), and the network draws the body
//! where the fit says. The source views' masks show where the person is. The correction is the
//! rigid motion `x -> R (x - c) + c + t` (`c` the fit's vertex centroid) that minimises, over the
//! source views `n`,
//!
//! `E = sum_n [ mean_v rho(D_n(pi_n(x_v))^2) + mean_b rho(|b - pi_n(x_v*(b))|^2) ]`
//!
//! - `D_n`: the distance (pixels) to view `n`'s mask, 0 inside it, read bilinearly: a vertex
//!   that projects outside the mask is pulled in;
//! - `b`: the mask's boundary pixels (an evenly spaced sample), `v*(b)` the vertex projecting
//!   nearest to `b`: a part of the mask no vertex covers pulls the body out;
//! - `rho(s) = sigma^2 s / (sigma^2 + s)` (Geman-McClure), `sigma` = [`SmplAlignment::robust_m`]
//!   at the body's depth, in pixels: a hole, a lost hand or a blob in one mask, hair and loose
//!   clothes, all many `sigma` away, hardly pull.
//!
//! Levenberg-Marquardt on the reweighted least squares (the nearest vertices found again at
//! each evaluation, as in ICP), a step accepted only where `E` falls and the whole motion stays
//! within [`SmplAlignment::max_translation_m`] and [`SmplAlignment::max_rotation_deg`]. The
//! joints are not touched: what no rigid motion reaches (a forearm off by 5 degrees) stays.
//!
//! Only the scene's source views are read, never its target: the correction is what a user
//! has at test time.

use glam::{Quat, Vec3};
use serde::{Deserialize, Serialize};

use crate::body::SmplParams;
use crate::dataset::silhouette_energy::{NormalEquations, Residual, SilhouetteTerms};
use crate::geometry::camera::Camera;

/// The alignment's settings (`[data] smpl_alignment`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SmplAlignment {
    /// Levenberg-Marquardt iterations (accepted or refused steps), at most.
    #[serde(default = "default_iterations")]
    pub iterations: usize,
    /// The robust scale `sigma`, metres at the body's depth (module docs).
    #[serde(default = "default_robust_m")]
    pub robust_m: f32,
    /// Largest translation of the correction, metres.
    #[serde(default = "default_max_translation_m")]
    pub max_translation_m: f32,
    /// Largest rotation of the correction, degrees.
    #[serde(default = "default_max_rotation_deg")]
    pub max_rotation_deg: f32,
    /// Boundary pixels sampled per mask.
    #[serde(default = "default_boundary_samples")]
    pub boundary_samples: usize,
    /// Vertices used (every k-th of the mesh so that at most this many remain).
    #[serde(default = "default_vertex_samples")]
    pub vertex_samples: usize,
    /// Levenberg-Marquardt iterations of the pose refinement after the rigid alignment
    /// ([`super::smpl_pose_refinement`]); 0: rigid only.
    #[serde(default)]
    pub pose_iterations: usize,
    /// The same for training scenes (`None`: `pose_iterations`). A model trained on the rigid
    /// alignment alone still learns the fits' joint errors; the refinement then runs where
    /// images are rendered.
    #[serde(default)]
    pub train_pose_iterations: Option<usize>,
    /// The pose prior's scale `s`, degrees: a joint turned this far from the fit costs as much
    /// as one view's vertex term fully saturated.
    #[serde(default = "default_pose_prior_deg")]
    pub pose_prior_deg: f32,
    /// Largest rotation of a joint away from the fit, degrees.
    #[serde(default = "default_max_joint_deg")]
    pub max_joint_deg: f32,
}

fn default_iterations() -> usize {
    20
}
fn default_robust_m() -> f32 {
    0.03
}
fn default_max_translation_m() -> f32 {
    0.1
}
fn default_max_rotation_deg() -> f32 {
    10.0
}
fn default_boundary_samples() -> usize {
    400
}
fn default_vertex_samples() -> usize {
    2000
}
fn default_pose_prior_deg() -> f32 {
    40.0
}
fn default_max_joint_deg() -> f32 {
    15.0
}

impl Default for SmplAlignment {
    fn default() -> Self {
        SmplAlignment {
            iterations: default_iterations(),
            robust_m: default_robust_m(),
            max_translation_m: default_max_translation_m(),
            max_rotation_deg: default_max_rotation_deg(),
            boundary_samples: default_boundary_samples(),
            vertex_samples: default_vertex_samples(),
            pose_iterations: 0,
            train_pose_iterations: None,
            pose_prior_deg: default_pose_prior_deg(),
            max_joint_deg: default_max_joint_deg(),
        }
    }
}

/// Bad settings or inputs of the alignment, naming the field and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum AlignmentError {
    #[error("SMPL alignment: {field}: expected {expected}, got {got}")]
    Invalid {
        field: String,
        expected: String,
        got: String,
    },
}

impl AlignmentError {
    /// The pose refinement asked for (`got`: the iterations) where no body model is at hand.
    pub(crate) fn no_body_model(got: String) -> Self {
        invalid(
            "pose_iterations",
            "0 when the scene source has no body model",
            got,
        )
    }
}

fn invalid(
    field: impl Into<String>,
    expected: impl Into<String>,
    got: impl ToString,
) -> AlignmentError {
    AlignmentError::Invalid {
        field: field.into(),
        expected: expected.into(),
        got: got.to_string(),
    }
}

/// `value` in `(0, max]` (NaN is not), else an error naming `field`.
fn in_range(field: &str, value: f32, max: f32, unit: &str) -> Result<(), AlignmentError> {
    if value > 0.0 && value <= max {
        Ok(())
    } else {
        Err(invalid(field, format!("{unit} in (0, {max}]"), value))
    }
}

impl SmplAlignment {
    /// The settings a training scene is aligned with: `pose_iterations` replaced by
    /// `train_pose_iterations` where that is given.
    pub fn for_training(&self) -> SmplAlignment {
        SmplAlignment {
            pose_iterations: self.train_pose_iterations.unwrap_or(self.pose_iterations),
            ..*self
        }
    }

    /// The pose refinement runs for some scenes (training or rendered ones).
    pub fn refines_pose(&self) -> bool {
        self.pose_iterations > 0 || self.train_pose_iterations.is_some_and(|n| n > 0)
    }

    /// Every field in its range.
    pub fn validate(&self) -> Result<(), AlignmentError> {
        if !(1..=1000).contains(&self.iterations) {
            return Err(invalid("iterations", "1..=1000", self.iterations));
        }
        in_range("robust_m", self.robust_m, 1.0, "metres")?;
        in_range("max_translation_m", self.max_translation_m, 1.0, "metres")?;
        in_range("max_rotation_deg", self.max_rotation_deg, 90.0, "degrees")?;
        if !(1..=100_000).contains(&self.boundary_samples) {
            return Err(invalid(
                "boundary_samples",
                "1..=100000",
                self.boundary_samples,
            ));
        }
        if !(1..=100_000).contains(&self.vertex_samples) {
            return Err(invalid("vertex_samples", "1..=100000", self.vertex_samples));
        }
        if self.pose_iterations > 1000 {
            return Err(invalid("pose_iterations", "0..=1000", self.pose_iterations));
        }
        if let Some(n) = self.train_pose_iterations.filter(|&n| n > 1000) {
            return Err(invalid("train_pose_iterations", "0..=1000", n));
        }
        in_range("pose_prior_deg", self.pose_prior_deg, 180.0, "degrees")?;
        in_range("max_joint_deg", self.max_joint_deg, 90.0, "degrees")?;
        Ok(())
    }
}

/// One source view as the alignment reads it.
#[derive(Debug, Clone, Copy)]
pub struct AlignmentView<'a> {
    /// Undistorted pinhole camera of the mask.
    pub camera: &'a Camera,
    /// `[H * W]` row-major, true on the person.
    pub mask: &'a [bool],
}

/// A rigid correction `x -> rotation (x - centre) + centre + translation` and what it did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidCorrection {
    pub rotation: Quat,
    /// The fit's vertex centroid, world metres.
    pub centre: Vec3,
    pub translation: Vec3,
    /// `E` (module docs) of the fit as given and after the correction (never larger).
    pub energy_before: f32,
    pub energy_after: f32,
    /// Source views that took part (a view with an empty mask does not).
    pub views_used: usize,
}

impl RigidCorrection {
    /// No motion about `centre`.
    pub fn identity(centre: Vec3) -> Self {
        RigidCorrection {
            rotation: Quat::IDENTITY,
            centre,
            translation: Vec3::ZERO,
            energy_before: 0.0,
            energy_after: 0.0,
            views_used: 0,
        }
    }

    /// The corrected position of the world point `x`.
    pub fn apply_point(&self, x: Vec3) -> Vec3 {
        self.rotation * (x - self.centre) + self.centre + self.translation
    }

    /// Moves `vertices` ([V] world) and `params` so that they still agree: the SMPL world vertex
    /// `Rh v + Th` becomes `R Rh v + R (Th - c) + c + t`.
    pub fn apply(&self, vertices: &mut [Vec3], params: &mut SmplParams) {
        for v in vertices.iter_mut() {
            *v = self.apply_point(*v);
        }
        params.rh = (self.rotation * Quat::from_scaled_axis(params.rh)).to_scaled_axis();
        params.th = self.apply_point(params.th);
    }

    /// The rotation's angle, degrees.
    pub fn rotation_deg(&self) -> f32 {
        self.rotation.angle_between(Quat::IDENTITY).to_degrees()
    }
}

/// The rigid correction of `vertices` ([V] world metres) that best fits the masks of `views`
/// (module docs). A view with an empty mask takes no part; with none left the correction is
/// the identity (`views_used` 0). Errors name a mask of the wrong size or a body behind a
/// camera.
pub fn align_to_masks(
    vertices: &[Vec3],
    views: &[AlignmentView<'_>],
    config: &SmplAlignment,
) -> Result<RigidCorrection, AlignmentError> {
    config.validate()?;
    if vertices.is_empty() || vertices.iter().any(|v| !v.is_finite()) {
        return Err(invalid(
            "vertices",
            "a non-empty set of finite world points",
            format!("{} vertices", vertices.len()),
        ));
    }
    let centre = vertices.iter().copied().sum::<Vec3>() / vertices.len() as f32;
    let stride = vertices.len().div_ceil(config.vertex_samples).max(1);
    let sample: Vec<Vec3> = vertices.iter().step_by(stride).copied().collect();

    let terms = SilhouetteTerms::new(views, centre, config)?;
    if terms.is_empty() {
        return Ok(RigidCorrection::identity(centre));
    }

    // `E` of the fit moved by `state`, and with `system` its normal equations in the step
    // `(omega, t)` about the moved centre: `dr/domega = (x - c') x a`, `dr/dt = a`.
    let evaluate = |state: &RigidCorrection, system: Option<&mut NormalEquations>| -> f32 {
        let moved_centre = centre + state.translation;
        let moved: Vec<Vec3> = sample.iter().map(|&v| state.apply_point(v)).collect();
        match system {
            None => terms.energy(&moved, None),
            Some(system) => {
                let mut sink = |res: Residual| {
                    let da = (moved[res.index] - moved_centre).cross(res.a);
                    let a = res.a;
                    let j = [da.x, da.y, da.z, a.x, a.y, a.z];
                    let row: [(usize, f32); 6] = std::array::from_fn(|i| (i, j[i]));
                    system.add(&row, res.r, res.w);
                };
                terms.energy(&moved, Some(&mut sink))
            }
        }
    };

    let max_angle = config.max_rotation_deg.to_radians();
    let mut state = RigidCorrection {
        views_used: terms.len(),
        ..RigidCorrection::identity(centre)
    };
    let mut system = NormalEquations::new(6);
    let energy_before = evaluate(&state, Some(&mut system));
    let mut energy = energy_before;
    let mut lambda = 1e-3f64;
    for _ in 0..config.iterations {
        let Some(delta) = system.solve(lambda) else {
            break;
        };
        let omega = Vec3::new(delta[0] as f32, delta[1] as f32, delta[2] as f32);
        let step = Vec3::new(delta[3] as f32, delta[4] as f32, delta[5] as f32);
        let candidate = RigidCorrection {
            rotation: (Quat::from_scaled_axis(omega) * state.rotation).normalize(),
            translation: state.translation + step,
            ..state
        };
        let within = candidate.translation.length() <= config.max_translation_m
            && candidate.rotation.angle_between(Quat::IDENTITY) <= max_angle;
        let candidate_energy = if within {
            evaluate(&candidate, None)
        } else {
            f32::INFINITY
        };
        if candidate_energy.is_finite() && candidate_energy < energy {
            let converged = energy - candidate_energy <= 1e-6 * energy.max(1e-12);
            state = candidate;
            energy = candidate_energy;
            lambda = (lambda / 3.0).max(1e-7);
            if converged {
                break;
            }
            system = NormalEquations::new(6);
            evaluate(&state, Some(&mut system));
        } else {
            lambda *= 10.0;
            if lambda > 1e8 {
                break;
            }
        }
    }
    Ok(RigidCorrection {
        energy_before,
        energy_after: energy,
        ..state
    })
}
