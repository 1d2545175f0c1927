//! The silhouette energy, the one every fit minimises against person masks:
//!
//! `E_sil = sum_n [ w_out mean_v rho_n(D_n(pi_n(x_v))^2) + w_in mean_b rho_n(|b - pi_n(x_v*(b))|^2) ]`
//!
//! over the views `n` that have a mask:
//! - `D_n`: the distance (pixels) to view `n`'s mask, 0 inside it, read bilinearly (extended
//!   past the image's edge by the distance to it): a vertex that projects outside the mask is
//!   pulled in;
//! - `b`: the mask's boundary pixels (an evenly spaced sample), `v*(b)` the vertex projecting
//!   nearest to `b`, found again at each evaluation (as in ICP): a part of the mask no vertex
//!   covers pulls the body out;
//! - `rho_n(s) = sigma_n^2 s / (sigma_n^2 + s)` (Geman-McClure), `sigma_n` in the view's
//!   pixels: a hole, a lost hand or a blob in one mask, hair and loose clothes, all many
//!   `sigma` away, hardly pull.
//!
//! [`SilhouetteTerms::energy`] evaluates it for a set of world points and hands each residual
//! to a sink with its world Jacobian row, so that the solver chains it through the fit's
//! parameters ([`super::body`]).

use glam::{Vec2, Vec3};

use super::projection::{project, Pixels};
use super::FitError;
use crate::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};
use crate::geometry::distance_transform::{boundary_pixels, distance_to_mask};
use crate::geometry::point_grid::PointGrid;

/// Cell of the grid the nearest projected vertex is looked up in, pixels.
const NEAREST_CELL_PX: f32 = 4.0;

/// A person mask as the energy reads it: the distance map and a boundary sample.
#[derive(Debug, Clone, PartialEq)]
pub struct SilhouetteTarget {
    pub width: u32,
    pub height: u32,
    /// `[H * W]` row-major Euclidean distance to the nearest mask pixel, pixels (0 inside).
    pub distance: Vec<f32>,
    /// `[M]` boundary pixels (mask pixels with a 4-neighbour outside the mask) at their
    /// centres, evenly spaced along the scan order, at most the number asked for.
    pub boundary: Vec<Vec2>,
}

impl SilhouetteTarget {
    /// From a `[H * W]` row-major mask (true: person), keeping at most `boundary_samples`
    /// boundary pixels; `None` for an empty mask (a view that takes no part). Errors name a
    /// mask of the wrong size.
    pub fn from_mask(
        mask: &[bool],
        width: u32,
        height: u32,
        boundary_samples: usize,
    ) -> Result<Option<Self>, FitError> {
        let (w, h) = (width as usize, height as usize);
        if w < 2 || h < 2 || mask.len() != w * h {
            return Err(FitError::invalid(
                "mask",
                format!("[{h} * {w}] values (the camera's size, at least 2 x 2)"),
                mask.len(),
            ));
        }
        let all: Vec<Vec2> = boundary_pixels(w, h, |x, y| mask[y * w + x])
            .map(|(x, y)| Vec2::new(x as f32, y as f32) + Vec2::splat(PIXEL_CENTRE_OFFSET))
            .collect();
        if all.is_empty() {
            return Ok(None);
        }
        let m = boundary_samples.clamp(1, all.len());
        Ok(Some(SilhouetteTarget {
            width,
            height,
            distance: distance_to_mask(w, h, |i| mask[i]),
            boundary: (0..m).map(|i| all[i * all.len() / m]).collect(),
        }))
    }

    /// Distance and its gradient (pixels per pixel) at `uv`, extended past the image's edge by
    /// the distance to it.
    fn distance_at(&self, uv: Vec2) -> (f32, Vec2) {
        let (w, h) = (self.width as usize, self.height as usize);
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
}

/// The Geman-McClure `rho(s)` and its derivative `rho'(s)` (the reweighting) at `s = r^2`.
pub(crate) fn geman_mcclure(s: f32, sigma2: f32) -> (f32, f32) {
    let d = sigma2 + s;
    (sigma2 * s / d, sigma2 * sigma2 / (d * d))
}

/// One residual: `w r^2` is its (reweighted) share, `a = dr/dx` its world Jacobian row at the
/// point `index` of the points the energy was evaluated on.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Residual {
    pub index: usize,
    pub a: Vec3,
    pub r: f32,
    pub w: f32,
}

/// One view of [`SilhouetteTerms`].
pub(crate) struct SilhouetteView<'a> {
    pub target: &'a SilhouetteTarget,
    pub camera: &'a Camera,
    pub pixels: Pixels,
    /// `sigma_n^2`, pixels squared.
    pub sigma2: f32,
}

/// The views with a mask, ready to evaluate `E_sil` on.
pub(crate) struct SilhouetteTerms<'a> {
    pub views: Vec<SilhouetteView<'a>>,
    /// `w_out`, `w_in` (module docs).
    pub weight_out: f32,
    pub weight_in: f32,
}

impl SilhouetteTerms<'_> {
    /// Mean of the views' `sigma^2`, pixels squared (0 without views).
    pub fn mean_sigma2(&self) -> f32 {
        if self.views.is_empty() {
            return 0.0;
        }
        self.views.iter().map(|v| v.sigma2).sum::<f32>() / self.views.len() as f32
    }

    /// `E_sil` of the world points `points`; with `sink`, every residual as well.
    pub fn energy(&self, points: &[Vec3], mut sink: Option<&mut dyn FnMut(Residual)>) -> f32 {
        if points.is_empty() {
            return 0.0;
        }
        let mut energy = 0.0f64;
        for view in &self.views {
            let projected: Vec<Option<(Vec2, Vec3, Vec3)>> = points
                .iter()
                .map(|&x| project(view.camera, view.pixels, x))
                .collect();
            // Points outside the mask: pulled in.
            let w_v = self.weight_out / points.len() as f32;
            for (index, p) in projected.iter().enumerate() {
                let Some((uv, du, dv)) = *p else { continue };
                let (d, grad) = view.target.distance_at(uv);
                let (rho, w) = geman_mcclure(d * d, view.sigma2);
                energy += f64::from(rho * w_v);
                if let Some(s) = sink.as_deref_mut() {
                    s(Residual {
                        index,
                        a: du * grad.x + dv * grad.y,
                        r: d,
                        w: w * w_v,
                    });
                }
            }
            // Mask boundary pixels: pull their nearest projected point.
            let w_b = self.weight_in / view.target.boundary.len() as f32;
            let pixels: Vec<Vec2> = projected
                .iter()
                .map(|p| p.map_or(Vec2::NAN, |(uv, _, _)| uv))
                .collect();
            let grid = PointGrid::new(&pixels, NEAREST_CELL_PX);
            for &b in &view.target.boundary {
                let Some(index) = grid.nearest(b) else {
                    continue;
                };
                let Some((uv, du, dv)) = projected[index] else {
                    continue;
                };
                let e = uv - b;
                let (rho, w) = geman_mcclure(e.length_squared(), view.sigma2);
                energy += f64::from(rho * w_b);
                if let Some(s) = sink.as_deref_mut() {
                    let w = w * w_b;
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact transform's values are square roots of integers; f32 keeps ~1e-6 relative.
    const EDT_TOL: f32 = 1e-4;

    #[test]
    fn distance_is_euclidean_to_the_nearest_mask_pixel() {
        let mut mask = vec![false; 63];
        mask[3 * 9 + 4] = true;
        mask[9 + 7] = true;
        let s = SilhouetteTarget::from_mask(&mask, 9, 7, 10)
            .unwrap()
            .unwrap();
        for y in 0..7 {
            for x in 0..9 {
                let a = ((x as f32 - 4.0).powi(2) + (y as f32 - 3.0).powi(2)).sqrt();
                let b = ((x as f32 - 7.0).powi(2) + (y as f32 - 1.0).powi(2)).sqrt();
                let got = s.distance[y * 9 + x];
                assert!((got - a.min(b)).abs() < EDT_TOL, "({x}, {y}): {got}");
            }
        }
        assert_eq!(s.boundary.len(), 2);
    }

    #[test]
    fn an_empty_mask_takes_no_part_and_a_short_one_is_an_error() {
        assert!(SilhouetteTarget::from_mask(&[false; 4], 2, 2, 5)
            .unwrap()
            .is_none());
        let err = SilhouetteTarget::from_mask(&[true; 3], 2, 2, 5).unwrap_err();
        assert!(err.to_string().contains("mask"), "{err}");
    }

    #[test]
    fn the_robust_penalty_saturates_at_sigma_squared() {
        let sigma2 = 4.0;
        let (near, w_near) = geman_mcclure(0.01, sigma2);
        let (far, w_far) = geman_mcclure(1e6, sigma2);
        assert!((near - 0.01).abs() < 1e-4 && (w_near - 1.0).abs() < 1e-2);
        assert!(far < sigma2 && far > 0.99 * sigma2 && w_far < 1e-9);
    }
}
