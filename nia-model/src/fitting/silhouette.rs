//! A person mask as the fitter reads it: the distance (pixels) from each pixel to the nearest
//! mask pixel (0 inside), computed once on the host, and a fixed sample of the mask's boundary
//! pixels.
//!
//! The silhouette term runs both ways: projected vertices read the distance map bilinearly (a
//! vertex outside the mask is pulled in), and each boundary sample is pulled towards its
//! nearest projected vertex (a mask part no vertex covers pulls the body out).

pub use nia_data::geometry::distance_transform::boundary_pixels;
use nia_data::geometry::distance_transform::distance_to_mask;

use super::FitError;

/// A mask's distance map and boundary sample.
#[derive(Debug, Clone)]
pub struct SilhouetteTarget {
    pub width: u32,
    pub height: u32,
    /// `[H * W]` row-major Euclidean distance to the nearest mask pixel, pixels (0 inside).
    pub distance: Vec<f32>,
    /// `[M]` boundary pixels `(x, y)` (mask pixels with a 4-neighbour outside the mask),
    /// evenly spaced along the scan order, at most the number asked for.
    pub boundary: Vec<[f32; 2]>,
}

impl SilhouetteTarget {
    /// From a `[H * W]` row-major mask (non-zero = person), keeping at most `boundary_samples`
    /// boundary pixels.
    pub fn new(
        mask: &[u8],
        width: u32,
        height: u32,
        boundary_samples: usize,
    ) -> Result<Self, FitError> {
        let (w, h) = (width as usize, height as usize);
        if w == 0 || h == 0 || mask.len() != w * h {
            return Err(FitError::Mask(format!(
                "{} values for a {width}x{height} image",
                mask.len()
            )));
        }
        let inside = |x: usize, y: usize| mask[y * w + x] != 0;
        let distance = distance_to_mask(w, h, |i| mask[i] != 0);

        let all: Vec<[f32; 2]> = boundary_pixels(w, h, inside)
            .map(|(x, y)| [x as f32, y as f32])
            .collect();
        if all.is_empty() {
            return Err(FitError::Mask("the mask is empty".into()));
        }
        let m = boundary_samples.min(all.len()).max(1);
        let boundary = (0..m).map(|i| all[i * all.len() / m]).collect();
        Ok(Self {
            width,
            height,
            distance,
            boundary,
        })
    }

    /// The distance at `(x, y)` (pixels) as `A + B fx + C fy + D fx fy` with `fx = x - x0`,
    /// `fy = y - y0`, plus a linear overshoot term for points outside the image: returns
    /// `[A, B, C, D, x0, y0, sx, sy, xe, ye]` where the full value is
    /// `A + B fx + C fy + D fx fy + sx (x - xe) + sy (y - ye)`.
    pub fn bilinear_coefficients(&self, x: f32, y: f32) -> [f32; 10] {
        let (w, h) = (self.width as usize, self.height as usize);
        let max_x = (w - 1) as f32;
        let max_y = (h - 1) as f32;
        let clamp = |p: f32, max: f32| {
            if p.is_finite() {
                p.clamp(0.0, max)
            } else {
                0.0
            }
        };
        let (cx, cy) = (clamp(x, max_x), clamp(y, max_y));
        let sign = |p: f32, c: f32| {
            if !p.is_finite() || p == c {
                0.0
            } else if p > c {
                1.0
            } else {
                -1.0
            }
        };
        let (sx, sy) = (sign(x, cx), sign(y, cy));
        let x0 = cx.floor().min((w.saturating_sub(2)) as f32).max(0.0);
        let y0 = cy.floor().min((h.saturating_sub(2)) as f32).max(0.0);
        let (ix, iy) = (x0 as usize, y0 as usize);
        let at = |xx: usize, yy: usize| self.distance[yy.min(h - 1) * w + xx.min(w - 1)];
        let (d00, d10, d01, d11) = (
            at(ix, iy),
            at(ix + 1, iy),
            at(ix, iy + 1),
            at(ix + 1, iy + 1),
        );
        let mut c = [
            d00,
            d10 - d00,
            d01 - d00,
            d11 - d10 - d01 + d00,
            x0,
            y0,
            sx,
            sy,
            cx,
            cy,
        ];
        if sx != 0.0 || sy != 0.0 {
            // Outside the image: the value at the clamped point, constant in the bilinear part.
            let fx = cx - x0;
            let fy = cy - y0;
            c[0] = d00 + c[1] * fx + c[2] * fy + c[3] * fx * fy;
            c[1] = 0.0;
            c[2] = 0.0;
            c[3] = 0.0;
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact transform's values are square roots of integers; f32 keeps ~1e-6 relative.
    const EDT_TOL: f32 = 1e-4;

    #[test]
    fn distance_is_euclidean_to_the_nearest_mask_pixel() {
        let (w, h) = (9u32, 7u32);
        let mut mask = vec![0u8; 63];
        mask[3 * 9 + 4] = 255;
        mask[9 + 7] = 255;
        let s = SilhouetteTarget::new(&mask, w, h, 10).unwrap();
        for y in 0..7 {
            for x in 0..9 {
                let a = (((x as f32 - 4.0).powi(2) + (y as f32 - 3.0).powi(2)) as f32).sqrt();
                let b = (((x as f32 - 7.0).powi(2) + (y as f32 - 1.0).powi(2)) as f32).sqrt();
                let got = s.distance[y * 9 + x];
                assert!((got - a.min(b)).abs() < EDT_TOL, "({x}, {y}): {got}");
            }
        }
        assert_eq!(s.boundary.len(), 2);
    }

    #[test]
    fn empty_mask_is_an_error() {
        assert!(SilhouetteTarget::new(&[0u8; 4], 2, 2, 5).is_err());
        assert!(SilhouetteTarget::new(&[1u8; 3], 2, 2, 5).is_err());
    }
}
