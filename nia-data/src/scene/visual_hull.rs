//! Visual-hull carving of the density (not in the paper; `[render] visual_hull` and
//! `hull_dilate_px`, at evaluation and inference only): the source views' person masks, dilated
//! by a margin, and how far inside all of them a point projects.
//!
//! F_sigma reads the person's outline only through SMPL-anchored features and pixel features of
//! the masked source images, a few pixels wide after the encoder's strides, so on a person
//! whose clothes stand off the body by more or less than the training people's, the outline
//! it draws is the training people's average margin (the seed-8 person of docs/results.md is drawn
//! half a pixel fat). The masks are inputs the reader loads anyway and they state the outline
//! exactly: a point that projects outside the person in any source view is empty space (the
//! visual hull, Laurentini 1994). The carving multiplies the density by
//!
//! ```text
//! hull(x) = min_n sum_k a_k M'_n(p_k)
//! ```
//!
//! with `p_k` the four pixels around x's projection in view n, `a_k` their bilinear weights and
//! `M'_n` view n's mask dilated by `dilate_px` pixels (a square window: the margin noisy masks
//! need; the synthetic masks are exact). Pixels outside the image read 1 (no evidence either
//! way), so a view that does not see a point never carves it. The hull is loose between the
//! source views (three views carve a hexagon around a round limb) and tight where a target ray
//! grazes the person along a source camera's line of sight: at the outline of a target view
//! opposite a source view, where the synthetic protocol's targets sit (on ZJU-MoCap's ring of
//! 21-23 cameras, a few targets are near-opposite a source view).
//!
//! The carving is applied when rendering, not in training: a network trained with it no longer
//! has to place empty space next to the person itself, and some such runs left holes in the
//! person (docs/results.md, "Tried and not kept"). Where the hull says 0 the density is exactly 0, so empty-space
//! skipping leaves those samples out of the network.

use glam::{Vec2, Vec3};

use crate::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};

/// Errors in the hull's inputs, naming the field and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum VisualHullError {
    #[error("visual hull: {field}: expected {expected}, got {got}")]
    Invalid {
        field: String,
        expected: String,
        got: String,
    },
}

/// The dilated masks of the source views.
#[derive(Debug, Clone)]
pub struct VisualHull {
    /// Pixels the masks were grown by.
    pub dilate_px: usize,
    width: usize,
    height: usize,
    /// [N][H * W] dilated masks in [0, 1].
    maps: Vec<Vec<f32>>,
}

impl VisualHull {
    /// The hull of `masks` ([N][H * W] person masks in [0, 1], row-major, one image size),
    /// each grown by `dilate_px` pixels (the largest value in a `2 dilate_px + 1` square).
    pub fn new(
        masks: &[&[f32]],
        width: usize,
        height: usize,
        dilate_px: usize,
    ) -> Result<Self, VisualHullError> {
        if width == 0 || height == 0 {
            return Err(VisualHullError::Invalid {
                field: "image size".into(),
                expected: "a non-empty image".into(),
                got: format!("{width}x{height}"),
            });
        }
        if dilate_px > width.max(height) {
            return Err(VisualHullError::Invalid {
                field: "dilate_px".into(),
                expected: format!("at most the image's larger side ({})", width.max(height)),
                got: dilate_px.to_string(),
            });
        }
        let mut maps = Vec::with_capacity(masks.len());
        for (view, mask) in masks.iter().enumerate() {
            if mask.len() != width * height {
                return Err(VisualHullError::Invalid {
                    field: format!("views[{view}].mask"),
                    expected: format!("[{height} * {width}] = {} values", width * height),
                    got: mask.len().to_string(),
                });
            }
            if let Some(i) = mask
                .iter()
                .position(|v| !(v.is_finite() && (0.0..=1.0).contains(v)))
            {
                return Err(VisualHullError::Invalid {
                    field: format!("views[{view}].mask[{i}]"),
                    expected: "a value in [0, 1]".into(),
                    got: mask[i].to_string(),
                });
            }
            maps.push(dilate(mask, width, height, dilate_px));
        }
        Ok(VisualHull {
            dilate_px,
            width,
            height,
            maps,
        })
    }

    /// Number of views N.
    pub fn num_views(&self) -> usize {
        self.maps.len()
    }

    /// `hull(x)` of the module docs for the world point `x`, in [0, 1]: the least of
    /// [`Self::inside`] over the views, `cameras` ([N], the source cameras in view order)
    /// projecting it; views beyond the shorter of the two lists are not read. A view behind
    /// whose camera `x` lies does not carve it.
    pub fn carving(&self, cameras: &[Camera], x: Vec3) -> f32 {
        cameras
            .iter()
            .take(self.maps.len())
            .enumerate()
            .map(|(view, camera)| match camera.project(x) {
                Some((uv, _depth)) => self.inside(view, uv),
                None => 1.0,
            })
            .fold(1.0, f32::min)
    }

    /// How far inside view `view`'s dilated mask the projection `uv` (pixels, OpenCV centres
    /// at integer coordinates) lies, in [0, 1]: the bilinear read of the four pixels around
    /// it, pixels outside the image reading 1. A non-finite projection reads 1 as well: a
    /// point behind the camera or at its centre is not seen by the view, which then says
    /// nothing about it.
    pub fn inside(&self, view: usize, uv: Vec2) -> f32 {
        let p = uv - Vec2::splat(PIXEL_CENTRE_OFFSET);
        if !p.is_finite() {
            return 1.0;
        }
        let map = &self.maps[view];
        let (x0, y0) = (p.x.floor(), p.y.floor());
        let (fx, fy) = (p.x - x0, p.y - y0);
        let mut value = 0.0;
        for (dy, wy) in [(0.0, 1.0 - fy), (1.0, fy)] {
            for (dx, wx) in [(0.0, 1.0 - fx), (1.0, fx)] {
                let (x, y) = (x0 + dx, y0 + dy);
                let inside =
                    x >= 0.0 && y >= 0.0 && x < self.width as f32 && y < self.height as f32;
                let m = if inside {
                    map[y as usize * self.width + x as usize]
                } else {
                    1.0
                };
                value += wx * wy * m;
            }
        }
        value.clamp(0.0, 1.0)
    }
}

/// `mask` grown by `r` pixels: the largest value in the `(2r + 1)^2` square around each pixel
/// (a row pass, then a column pass).
fn dilate(mask: &[f32], width: usize, height: usize, r: usize) -> Vec<f32> {
    if r == 0 {
        return mask.to_vec();
    }
    let window_max = |read: &dyn Fn(usize) -> f32, len: usize, i: usize| {
        let (lo, hi) = (i.saturating_sub(r), (i + r).min(len - 1));
        (lo..=hi).map(read).fold(0.0f32, f32::max)
    };
    let mut rows = vec![0.0f32; mask.len()];
    for y in 0..height {
        let row = &mask[y * width..(y + 1) * width];
        for x in 0..width {
            rows[y * width + x] = window_max(&|i| row[i], width, x);
        }
    }
    let mut out = vec![0.0f32; mask.len()];
    for x in 0..width {
        for y in 0..height {
            out[y * width + x] = window_max(&|i| rows[i * width + x], height, y);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dilation_grows_a_pixel_by_a_square() {
        let (w, h) = (7, 5);
        let mut mask = vec![0.0f32; w * h];
        mask[2 * w + 3] = 1.0;
        let grown = dilate(&mask, w, h, 1);
        for y in 0..h {
            for x in 0..w {
                let expected = (x as i32 - 3).abs() <= 1 && (y as i32 - 2).abs() <= 1;
                assert_eq!(grown[y * w + x], expected as u8 as f32, "({x}, {y})");
            }
        }
        assert_eq!(dilate(&mask, w, h, 0), mask);
    }
}
