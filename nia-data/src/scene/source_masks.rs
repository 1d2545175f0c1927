//! The source views' person masks as read at a point's projection (the visual hull's carving,
//! [`super::VisualHull`]), and the masks with the fitted body's silhouette counted as person
//! ([`masks_with_body`]).

use glam::{Vec2, Vec3};

use crate::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};
use crate::geometry::raster::{rasterize, MeshError};

/// Errors in the masks, naming the reader, the field and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum MaskError {
    #[error("{what}: {field}: expected {expected}, got {got}")]
    Invalid {
        /// The reader the masks were given to ("visual hull").
        what: &'static str,
        field: String,
        expected: String,
        got: String,
    },
    #[error("{what}: the body's silhouette: {source}")]
    Body {
        what: &'static str,
        source: MeshError,
    },
}

/// The person masks of N source views, one image size.
#[derive(Debug, Clone)]
pub struct SourceMasks {
    width: usize,
    height: usize,
    /// [N][H * W] masks in [0, 1].
    maps: Vec<Vec<f32>>,
}

impl SourceMasks {
    /// `masks` ([N][H * W] person masks in [0, 1], row-major, one image size). `what` names
    /// the reader in errors.
    pub fn new(
        what: &'static str,
        masks: &[&[f32]],
        width: usize,
        height: usize,
    ) -> Result<Self, MaskError> {
        let invalid = |field: String, expected: String, got: String| MaskError::Invalid {
            what,
            field,
            expected,
            got,
        };
        if width == 0 || height == 0 {
            return Err(invalid(
                "image size".into(),
                "a non-empty image".into(),
                format!("{width}x{height}"),
            ));
        }
        let mut maps = Vec::with_capacity(masks.len());
        for (view, mask) in masks.iter().enumerate() {
            if mask.len() != width * height {
                return Err(invalid(
                    format!("views[{view}].mask"),
                    format!("[{height} * {width}] = {} values", width * height),
                    mask.len().to_string(),
                ));
            }
            if let Some(i) = mask
                .iter()
                .position(|v| !(v.is_finite() && (0.0..=1.0).contains(v)))
            {
                return Err(invalid(
                    format!("views[{view}].mask[{i}]"),
                    "a value in [0, 1]".into(),
                    mask[i].to_string(),
                ));
            }
            maps.push(mask.to_vec());
        }
        Ok(SourceMasks {
            width,
            height,
            maps,
        })
    }

    /// Number of views N.
    pub fn num_views(&self) -> usize {
        self.maps.len()
    }

    /// View `view`'s mask at the projection `uv` (pixels, OpenCV centres at integer
    /// coordinates), in [0, 1]: the bilinear read of the four pixels around it, pixels outside
    /// the image reading `outside`. A non-finite projection reads `outside` as well.
    pub fn read(&self, view: usize, uv: Vec2, outside: f32) -> f32 {
        let p = uv - Vec2::splat(PIXEL_CENTRE_OFFSET);
        if !p.is_finite() {
            return outside;
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
                    outside
                };
                value += wx * wy * m;
            }
        }
        value.clamp(0.0, 1.0)
    }
}

/// `masks` ([N][H * W], one per camera of `cameras`, each of that camera's size) with the
/// fitted body's silhouette in each view (`vertices` [V] world, `faces` [F]), shrunk by
/// `erode_px` pixels (the smallest value in a `2 erode_px + 1` square), counted as person: the
/// pixel-wise maximum of the two.
///
/// A segmentation network that cuts a band out of the person, or loses a hand, in one source
/// view would have the visual hull carve that part out of the person in every target view.
/// Where the fitted body covers a pixel by more than `erode_px`, that is not trusted: the
/// erosion keeps the body's silhouette inside the person's for a fit that is off by up to
/// about `erode_px` pixels, so the hull still carves the outline where the masks put it.
pub fn masks_with_body(
    masks: &[&[f32]],
    cameras: &[Camera],
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    erode_px: usize,
) -> Result<Vec<Vec<f32>>, MaskError> {
    const WHAT: &str = "visual hull";
    if masks.len() != cameras.len() {
        return Err(MaskError::Invalid {
            what: WHAT,
            field: "views".into(),
            expected: format!("one mask per camera ({})", cameras.len()),
            got: masks.len().to_string(),
        });
    }
    masks
        .iter()
        .zip(cameras)
        .enumerate()
        .map(|(view, (mask, camera))| {
            let (w, h) = (camera.width as usize, camera.height as usize);
            if mask.len() != w * h {
                return Err(MaskError::Invalid {
                    what: WHAT,
                    field: format!("views[{view}].mask"),
                    expected: format!("[{h} * {w}] = {} values (the camera's size)", w * h),
                    got: mask.len().to_string(),
                });
            }
            let outside: Vec<f32> = rasterize(camera, vertices, faces)
                .map_err(|source| MaskError::Body { what: WHAT, source })?
                .mask()
                .iter()
                .map(|&body| if body { 0.0 } else { 1.0 })
                .collect();
            // Erosion of the silhouette: the dilation of its complement.
            let grown_outside = dilate(&outside, w, h, erode_px);
            Ok(mask
                .iter()
                .zip(&grown_outside)
                .map(|(&m, &o)| m.max(1.0 - o))
                .collect())
        })
        .collect()
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
