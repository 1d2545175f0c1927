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

use glam::{Quat, Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::body::SmplParams;
use crate::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};
use crate::geometry::distance_transform::{boundary_pixels, distance_to_mask};
use crate::geometry::point_grid::PointGrid;

/// Cell of the grid the nearest projected vertex is looked up in, pixels.
const NEAREST_CELL_PX: f32 = 4.0;

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

impl Default for SmplAlignment {
    fn default() -> Self {
        SmplAlignment {
            iterations: default_iterations(),
            robust_m: default_robust_m(),
            max_translation_m: default_max_translation_m(),
            max_rotation_deg: default_max_rotation_deg(),
            boundary_samples: default_boundary_samples(),
            vertex_samples: default_vertex_samples(),
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

impl SmplAlignment {
    /// Every field in its range.
    pub fn validate(&self) -> Result<(), AlignmentError> {
        if !(1..=1000).contains(&self.iterations) {
            return Err(invalid("iterations", "1..=1000", self.iterations));
        }
        if !(self.robust_m > 0.0 && self.robust_m <= 1.0) {
            return Err(invalid("robust_m", "metres in (0, 1]", self.robust_m));
        }
        if !(self.max_translation_m > 0.0 && self.max_translation_m <= 1.0) {
            return Err(invalid(
                "max_translation_m",
                "metres in (0, 1]",
                self.max_translation_m,
            ));
        }
        if !(self.max_rotation_deg > 0.0 && self.max_rotation_deg <= 90.0) {
            return Err(invalid(
                "max_rotation_deg",
                "degrees in (0, 90]",
                self.max_rotation_deg,
            ));
        }
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

/// A view's mask as `E` reads it.
struct ViewTerm<'a> {
    camera: &'a Camera,
    /// `[H * W]` distance to the mask, pixels.
    distance: Vec<f32>,
    /// `[M]` boundary pixels.
    boundary: Vec<Vec2>,
    /// `sigma^2`, pixels squared.
    sigma2: f32,
}

/// The Geman-McClure `rho(s)` and its derivative `rho'(s)` (the reweighting) at `s = r^2`.
fn geman_mcclure(s: f32, sigma2: f32) -> (f32, f32) {
    let d = sigma2 + s;
    (sigma2 * s / d, sigma2 * sigma2 / (d * d))
}

impl<'a> ViewTerm<'a> {
    /// Distance and its gradient (pixels per pixel) at `uv`, extended past the image's edge by
    /// the distance to it.
    fn distance_at(&self, uv: Vec2) -> (f32, Vec2) {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let p = uv - Vec2::splat(PIXEL_CENTRE_OFFSET);
        let max = Vec2::new((w - 1) as f32, (h - 1) as f32);
        let c = p.clamp(Vec2::ZERO, max);
        let x0 = (c.x.floor() as usize).min(w.saturating_sub(2));
        let y0 = (c.y.floor() as usize).min(h.saturating_sub(2));
        let at = |x: usize, y: usize| self.distance[y.min(h - 1) * w + x.min(w - 1)];
        let (fx, fy) = (c.x - x0 as f32, c.y - y0 as f32);
        let (d00, d10, d01, d11) = (
            at(x0, y0),
            at(x0 + 1, y0),
            at(x0, y0 + 1),
            at(x0 + 1, y0 + 1),
        );
        let value = d00 * (1.0 - fx) * (1.0 - fy)
            + d10 * fx * (1.0 - fy)
            + d01 * (1.0 - fx) * fy
            + d11 * fx * fy;
        let mut grad = Vec2::new(
            (d10 - d00) * (1.0 - fy) + (d11 - d01) * fy,
            (d01 - d00) * (1.0 - fx) + (d11 - d10) * fx,
        );
        let over = p - c;
        let len = over.length();
        if len > 0.0 {
            // Outside the image: the edge's value plus the way out.
            if over.x != 0.0 {
                grad.x = 0.0;
            }
            if over.y != 0.0 {
                grad.y = 0.0;
            }
            return (value + len, grad + over / len);
        }
        (value, grad)
    }

    /// Pixel of the world point `x` and the Jacobian rows `d(u, v) / dx` (world), or `None`
    /// behind the camera.
    fn project(&self, x: Vec3) -> Option<(Vec2, Vec3, Vec3)> {
        let y = self.camera.world_to_camera(x);
        let uv = self.camera.project_camera(y)?;
        let (fx, fy, s) = (self.camera.fx(), self.camera.fy(), self.camera.skew());
        let iz = 1.0 / y.z;
        let du = Vec3::new(fx * iz, s * iz, -(fx * y.x + s * y.y) * iz * iz);
        let dv = Vec3::new(0.0, fy * iz, -fy * y.y * iz * iz);
        // d/dx of (row . (R x + T)) is R^T row.
        let rt = self.camera.r.transpose();
        Some((uv, rt * du, rt * dv))
    }
}

/// Normal equations of the 6 parameters `(omega, t)` of a step about the current centre.
#[derive(Default)]
struct System {
    h: [[f64; 6]; 6],
    g: [f64; 6],
}

impl System {
    /// Adds the residual `r` with the world Jacobian row `a` (`dr/dx`) at the point `x`, lever
    /// `d = x - c'`, weight `w`: `dr/domega = d x a`, `dr/dt = a`.
    fn add(&mut self, a: Vec3, d: Vec3, r: f32, w: f32) {
        let da = d.cross(a);
        let j = [da.x, da.y, da.z, a.x, a.y, a.z].map(f64::from);
        let (r, w) = (f64::from(r), f64::from(w));
        for i in 0..6 {
            self.g[i] += w * j[i] * r;
            for k in 0..6 {
                self.h[i][k] += w * j[i] * j[k];
            }
        }
    }

    /// `(H + lambda diag(H)) delta = -g`, by Gaussian elimination with partial pivoting;
    /// `None` when singular.
    fn solve(&self, lambda: f64) -> Option<[f64; 6]> {
        let mut a = [[0.0f64; 7]; 6];
        let scale = (0..6)
            .map(|i| self.h[i][i])
            .fold(0.0f64, f64::max)
            .max(1e-12);
        for i in 0..6 {
            for k in 0..6 {
                a[i][k] = self.h[i][k];
            }
            a[i][i] += lambda * self.h[i][i].max(1e-9 * scale);
            a[i][6] = -self.g[i];
        }
        for col in 0..6 {
            let pivot = (col..6).max_by(|&p, &q| a[p][col].abs().total_cmp(&a[q][col].abs()))?;
            if a[pivot][col].abs() < 1e-12 * scale {
                return None;
            }
            a.swap(col, pivot);
            for row in 0..6 {
                if row != col {
                    let f = a[row][col] / a[col][col];
                    for k in col..7 {
                        a[row][k] -= f * a[col][k];
                    }
                }
            }
        }
        let x: [f64; 6] = std::array::from_fn(|i| a[i][6] / a[i][i]);
        x.iter().all(|v| v.is_finite()).then_some(x)
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

    let mut terms = Vec::with_capacity(views.len());
    for (n, view) in views.iter().enumerate() {
        let (w, h) = (view.camera.width as usize, view.camera.height as usize);
        if view.mask.len() != w * h || w < 2 || h < 2 {
            return Err(invalid(
                format!("views[{n}].mask"),
                format!("[{h} * {w}] values (the camera's size, at least 2 x 2)"),
                view.mask.len(),
            ));
        }
        let depth = view.camera.world_to_camera(centre).z;
        if !(depth > 0.0) {
            return Err(invalid(
                format!("views[{n}].camera"),
                "the body's centre in front of the camera",
                format!("depth {depth} m"),
            ));
        }
        let all: Vec<Vec2> = boundary_pixels(w, h, |x, y| view.mask[y * w + x])
            .map(|(x, y)| Vec2::new(x as f32, y as f32) + Vec2::splat(PIXEL_CENTRE_OFFSET))
            .collect();
        if all.is_empty() {
            continue;
        }
        let m = config.boundary_samples.min(all.len());
        let boundary = (0..m).map(|i| all[i * all.len() / m]).collect();
        let sigma = config.robust_m * view.camera.fx() / depth;
        terms.push(ViewTerm {
            camera: view.camera,
            distance: distance_to_mask(w, h, |i| view.mask[i]),
            boundary,
            sigma2: sigma * sigma,
        });
    }
    if terms.is_empty() {
        return Ok(RigidCorrection::identity(centre));
    }

    // `E` of the fit moved by `state`, and with `system` its normal equations.
    let evaluate = |state: &RigidCorrection, system: Option<&mut System>| -> f32 {
        let moved_centre = centre + state.translation;
        let moved: Vec<Vec3> = sample.iter().map(|&v| state.apply_point(v)).collect();
        let mut energy = 0.0f64;
        let mut system = system;
        for term in &terms {
            let projected: Vec<Option<(Vec2, Vec3, Vec3)>> =
                moved.iter().map(|&x| term.project(x)).collect();
            // Vertices outside the mask: pulled in.
            let inv_v = 1.0 / moved.len() as f32;
            for (x, p) in moved.iter().zip(&projected) {
                let Some((uv, du, dv)) = *p else { continue };
                let (d, grad) = term.distance_at(uv);
                let (rho, w) = geman_mcclure(d * d, term.sigma2);
                energy += f64::from(rho * inv_v);
                if let Some(s) = system.as_deref_mut() {
                    s.add(du * grad.x + dv * grad.y, *x - moved_centre, d, w * inv_v);
                }
            }
            // Mask boundary pixels: pull their nearest projected vertex.
            let inv_b = 1.0 / term.boundary.len() as f32;
            let pixels: Vec<Vec2> = projected
                .iter()
                .map(|p| p.map_or(Vec2::NAN, |(uv, _, _)| uv))
                .collect();
            let grid = PointGrid::new(&pixels, NEAREST_CELL_PX);
            for &b in &term.boundary {
                let Some(i) = grid.nearest(b) else {
                    continue;
                };
                let Some((uv, du, dv)) = projected[i] else {
                    continue;
                };
                let e = uv - b;
                let (rho, w) = geman_mcclure(e.length_squared(), term.sigma2);
                energy += f64::from(rho * inv_b);
                if let Some(s) = system.as_deref_mut() {
                    let lever = moved[i] - moved_centre;
                    s.add(du, lever, e.x, w * inv_b);
                    s.add(dv, lever, e.y, w * inv_b);
                }
            }
        }
        energy as f32
    };

    let max_angle = config.max_rotation_deg.to_radians();
    let mut state = RigidCorrection {
        views_used: terms.len(),
        ..RigidCorrection::identity(centre)
    };
    let mut system = System::default();
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
            system = System::default();
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
