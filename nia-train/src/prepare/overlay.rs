//! The overlay pictures users check a fit with: the fitted mesh's outline (magenta) and its
//! keypoints (cyan) over the photo, with the detected keypoints (red) and a line from each
//! detected keypoint to its fitted counterpart. The mask's outline (yellow) is drawn under the
//! mesh's: where the two agree only magenta shows, so yellow marks the mask's edge the fit
//! misses (and shows the person where dark clothes meet a dark background). Photos smaller
//! than [`MIN_OVERLAY_PX`] are enlarged by a whole factor (nearest pixel) before drawing, so
//! the lines and dots stay thin against the body.

use std::path::Path;

use glam::{Vec2, Vec3};
use image::imageops::FilterType;
use image::{Rgb, RgbImage};
use nia_data::geometry::camera::Camera;
use nia_data::geometry::distance_transform::boundary_pixels;
use nia_data::geometry::raster::{rasterize, EMPTY_FACE};

use super::PrepareError;

const OUTLINE: Rgb<u8> = Rgb([255, 0, 255]);
const DETECTED: Rgb<u8> = Rgb([255, 40, 40]);
const FITTED: Rgb<u8> = Rgb([40, 220, 255]);
const MASK_EDGE: Rgb<u8> = Rgb([255, 220, 0]);

/// Overlays are drawn at least this many pixels on the longer side (photos enlarged by a whole
/// factor, at most 8).
pub const MIN_OVERLAY_PX: u32 = 512;

/// The whole factor a `width` x `height` photo is enlarged by for its overlay.
pub fn overlay_scale(width: u32, height: u32) -> u32 {
    MIN_OVERLAY_PX
        .div_ceil(width.max(height).max(1))
        .clamp(1, 8)
}

/// Draws `color` on every pixel of the `w` x `h` region `inside` that borders a pixel outside
/// it (or the picture's edge).
fn outline(
    img: &mut RgbImage,
    w: usize,
    h: usize,
    inside: impl Fn(usize, usize) -> bool,
    c: Rgb<u8>,
) {
    for (x, y) in boundary_pixels(w, h, inside) {
        put(img, x as i64, y as i64, c);
    }
}

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

/// A square marker of radius `r` with a one-pixel black border, so it stands out from any
/// clothing pattern.
fn dot(img: &mut RgbImage, p: Vec2, r: i64, c: Rgb<u8>) {
    let (x, y) = (p.x.round() as i64, p.y.round() as i64);
    for dy in -r - 1..=r + 1 {
        for dx in -r - 1..=r + 1 {
            let border = dx.abs() > r || dy.abs() > r;
            put(img, x + dx, y + dy, if border { Rgb([0, 0, 0]) } else { c });
        }
    }
}

fn line(img: &mut RgbImage, a: Vec2, b: Vec2, c: Rgb<u8>) {
    let steps = (a - b).abs().max_element().ceil().clamp(1.0, 4096.0) as usize;
    for i in 0..=steps {
        let p = a.lerp(b, i as f32 / steps as f32);
        put(img, p.x.round() as i64, p.y.round() as i64, c);
    }
}

/// Draws the overlay of one view and writes it as PNG.
///
/// `mask`: the view's person mask (non-zero = person), the photo's size; `detected`: `[K]`
/// keypoints `(x, y, confidence)` in the photo's pixels; `fitted`: `[K]` the fitted body's
/// keypoints in world coordinates (`None` where a keypoint has no place on the body).
#[allow(clippy::too_many_arguments)]
pub fn write_overlay(
    path: &Path,
    photo: RgbImage,
    mask: &[u8],
    camera: &Camera,
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    detected: &[[f32; 3]],
    fitted: &[Option<Vec3>],
) -> Result<(), PrepareError> {
    let (pw, ph) = photo.dimensions();
    let scale = overlay_scale(pw, ph);
    let mut img = if scale > 1 {
        image::imageops::resize(&photo, pw * scale, ph * scale, FilterType::Nearest)
    } else {
        photo
    };
    let camera = camera
        .scaled(scale as f32)
        .map_err(|e| PrepareError::invalid(path, format!("enlarging the overlay: {e}")))?;
    let s = scale as usize;
    if mask.len() == (pw * ph) as usize {
        let (w, h) = (pw as usize * s, ph as usize * s);
        outline(
            &mut img,
            w,
            h,
            |x, y| mask[(y / s) * pw as usize + x / s] != 0,
            MASK_EDGE,
        );
    }
    let frags = rasterize(&camera, vertices, faces)
        .map_err(|e| PrepareError::invalid(path, format!("rasterising the fit: {e}")))?;
    let (w, h) = (frags.width as usize, frags.height as usize);
    outline(
        &mut img,
        w,
        h,
        |x, y| frags.face[y * w + x] != EMPTY_FACE,
        OUTLINE,
    );
    let radius = (img.width().max(img.height()) / 256).max(1) as i64;
    // Lines first, then the fitted keypoints, then the detected ones on top.
    let pairs: Vec<(Option<Vec2>, Option<Vec2>)> = detected
        .iter()
        .zip(fitted)
        .map(|(d, f)| {
            let at = (d[2] > 0.0).then(|| Vec2::new(d[0], d[1]) * scale as f32);
            let projected = f
                .and_then(|p| camera.project_distorted(p))
                .map(|(uv, _)| uv);
            (at, projected)
        })
        .collect();
    for (at, projected) in &pairs {
        if let (Some(a), Some(p)) = (at, projected) {
            line(&mut img, *a, *p, DETECTED);
        }
    }
    for (_, projected) in &pairs {
        if let Some(p) = projected {
            dot(&mut img, *p, radius, FITTED);
        }
    }
    for (at, _) in &pairs {
        if let Some(a) = at {
            dot(&mut img, *a, radius, DETECTED);
        }
    }
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)
            .map_err(|e| PrepareError::io(dir, "create the overlay folder", e))?;
    }
    img.save(path)
        .map_err(|e| PrepareError::invalid(path, format!("cannot write PNG: {e}")))
}
