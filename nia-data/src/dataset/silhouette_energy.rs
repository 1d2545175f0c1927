//! The silhouette energy both SMPL corrections minimise ([`super::smpl_alignment`] moves the
//! fit rigidly, [`super::smpl_pose_refinement`] bends its joints), and the damped normal
//! equations they solve it with.
//!
//! `E = sum_n [ mean_v rho(D_n(pi_n(x_v))^2) + mean_b rho(|b - pi_n(x_v*(b))|^2) ]` over the
//! source views `n` (the terms are described in [`super::smpl_alignment`]'s module docs).
//! [`SilhouetteTerms::energy`] evaluates it for a set of world points and hands each residual
//! to a sink with its world Jacobian row, so that each caller chains it through its own
//! parameters.

use glam::{Vec2, Vec3};

use crate::dataset::smpl_alignment::{AlignmentError, AlignmentView, SmplAlignment};
use crate::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};
use crate::geometry::distance_transform::{boundary_pixels, distance_to_mask};
use crate::geometry::point_grid::PointGrid;

/// Cell of the grid the nearest projected vertex is looked up in, pixels.
const NEAREST_CELL_PX: f32 = 4.0;

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

/// The source views' masks, ready to evaluate `E` on.
pub(crate) struct SilhouetteTerms<'a> {
    terms: Vec<ViewTerm<'a>>,
    /// Mean of the views' `sigma^2`, pixels squared (the scale the pose prior is set in).
    pub mean_sigma2: f32,
}

/// One residual of `E`: `w r^2` is its (reweighted) share, `a = dr/dx` its world Jacobian row
/// at the point `index`.
pub(crate) struct Residual {
    pub index: usize,
    pub a: Vec3,
    pub r: f32,
    pub w: f32,
}

impl<'a> SilhouetteTerms<'a> {
    /// The terms of `views` for a body about `centre` (world metres): each mask's distance
    /// map and boundary sample, its robust scale in pixels at the body's depth. A view with an
    /// empty mask takes no part. Errors name a mask of the wrong size or a body behind a
    /// camera.
    pub fn new(
        views: &[AlignmentView<'a>],
        centre: Vec3,
        config: &SmplAlignment,
    ) -> Result<Self, AlignmentError> {
        let mut terms = Vec::with_capacity(views.len());
        for (n, view) in views.iter().enumerate() {
            let (w, h) = (view.camera.width as usize, view.camera.height as usize);
            if view.mask.len() != w * h || w < 2 || h < 2 {
                return Err(AlignmentError::Invalid {
                    field: format!("views[{n}].mask"),
                    expected: format!("[{h} * {w}] values (the camera's size, at least 2 x 2)"),
                    got: view.mask.len().to_string(),
                });
            }
            let depth = view.camera.world_to_camera(centre).z;
            if !(depth > 0.0) {
                return Err(AlignmentError::Invalid {
                    field: format!("views[{n}].camera"),
                    expected: "the body's centre in front of the camera".into(),
                    got: format!("depth {depth} m"),
                });
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
        let mean_sigma2 = if terms.is_empty() {
            0.0
        } else {
            terms.iter().map(|t| t.sigma2).sum::<f32>() / terms.len() as f32
        };
        Ok(SilhouetteTerms { terms, mean_sigma2 })
    }

    /// Views that take part.
    pub fn len(&self) -> usize {
        self.terms.len()
    }

    /// No view takes part.
    pub fn is_empty(&self) -> bool {
        self.terms.is_empty()
    }

    /// `E` of the world points `points`; with `sink`, every residual as well.
    pub fn energy(&self, points: &[Vec3], mut sink: Option<&mut dyn FnMut(Residual)>) -> f32 {
        let mut energy = 0.0f64;
        for term in &self.terms {
            let projected: Vec<Option<(Vec2, Vec3, Vec3)>> =
                points.iter().map(|&x| term.project(x)).collect();
            // Points outside the mask: pulled in.
            let inv_v = 1.0 / points.len() as f32;
            for (index, p) in projected.iter().enumerate() {
                let Some((uv, du, dv)) = *p else { continue };
                let (d, grad) = term.distance_at(uv);
                let (rho, w) = geman_mcclure(d * d, term.sigma2);
                energy += f64::from(rho * inv_v);
                if let Some(s) = sink.as_deref_mut() {
                    s(Residual {
                        index,
                        a: du * grad.x + dv * grad.y,
                        r: d,
                        w: w * inv_v,
                    });
                }
            }
            // Mask boundary pixels: pull their nearest projected point.
            let inv_b = 1.0 / term.boundary.len() as f32;
            let pixels: Vec<Vec2> = projected
                .iter()
                .map(|p| p.map_or(Vec2::NAN, |(uv, _, _)| uv))
                .collect();
            let grid = PointGrid::new(&pixels, NEAREST_CELL_PX);
            for &b in &term.boundary {
                let Some(index) = grid.nearest(b) else {
                    continue;
                };
                let Some((uv, du, dv)) = projected[index] else {
                    continue;
                };
                let e = uv - b;
                let (rho, w) = geman_mcclure(e.length_squared(), term.sigma2);
                energy += f64::from(rho * inv_b);
                if let Some(s) = sink.as_deref_mut() {
                    let w = w * inv_b;
                    s(Residual {
                        index,
                        a: du,
                        r: e.x,
                        w,
                    });
                    s(Residual {
                        index,
                        a: dv,
                        r: e.y,
                        w,
                    });
                }
            }
        }
        energy as f32
    }
}

/// Normal equations `H delta = -g` of a reweighted least-squares step in `n` parameters.
pub(crate) struct NormalEquations {
    n: usize,
    /// `[n * n]` row-major.
    h: Vec<f64>,
    /// `[n]`.
    g: Vec<f64>,
}

impl NormalEquations {
    pub fn new(n: usize) -> Self {
        NormalEquations {
            n,
            h: vec![0.0; n * n],
            g: vec![0.0; n],
        }
    }

    /// Adds the residual `r` with weight `w` and the sparse Jacobian row `j` (`(parameter,
    /// dr/dparameter)`, each parameter at most once). Only `H`'s upper triangle is summed
    /// ([`NormalEquations::solve`] mirrors it).
    pub fn add(&mut self, j: &[(usize, f32)], r: f32, w: f32) {
        let (r, w) = (f64::from(r), f64::from(w));
        for (i, &(p, jp)) in j.iter().enumerate() {
            let wjp = w * f64::from(jp);
            self.g[p] += wjp * r;
            for &(q, jq) in &j[i..] {
                self.h[p.min(q) * self.n + p.max(q)] += wjp * f64::from(jq);
            }
        }
    }

    /// `(H + lambda diag(H)) delta = -g`, by Gaussian elimination with partial pivoting;
    /// `None` when singular or not finite.
    pub fn solve(&self, lambda: f64) -> Option<Vec<f64>> {
        let n = self.n;
        let cols = n + 1;
        let scale = (0..n)
            .map(|i| self.h[i * n + i])
            .fold(0.0f64, f64::max)
            .max(1e-12);
        let mut a = vec![0.0f64; n * cols];
        for i in 0..n {
            for k in 0..n {
                a[i * cols + k] = self.h[i.min(k) * n + i.max(k)];
            }
            a[i * cols + i] += lambda * self.h[i * n + i].max(1e-9 * scale);
            a[i * cols + n] = -self.g[i];
        }
        for col in 0..n {
            let pivot = (col..n)
                .max_by(|&p, &q| a[p * cols + col].abs().total_cmp(&a[q * cols + col].abs()))?;
            if !(a[pivot * cols + col].abs() >= 1e-12 * scale) {
                return None;
            }
            if pivot != col {
                for k in 0..cols {
                    a.swap(col * cols + k, pivot * cols + k);
                }
            }
            let diag = a[col * cols + col];
            for row in 0..n {
                if row == col {
                    continue;
                }
                let f = a[row * cols + col] / diag;
                if f == 0.0 {
                    continue;
                }
                for k in col..cols {
                    a[row * cols + k] -= f * a[col * cols + k];
                }
            }
        }
        let x: Vec<f64> = (0..n).map(|i| a[i * cols + n] / a[i * cols + i]).collect();
        x.iter().all(|v| v.is_finite()).then_some(x)
    }
}
