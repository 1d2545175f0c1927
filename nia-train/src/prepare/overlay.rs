//! The overlay pictures users check a fit with: the fitted mesh's outline (magenta) and its
//! keypoints (cyan) over the photo, with the detected keypoints (red) and a line from each
//! detected keypoint to its fitted counterpart.

use std::path::Path;

use glam::{Vec2, Vec3};
use image::{Rgb, RgbImage};
use nia_data::geometry::camera::Camera;
use nia_data::geometry::raster::{rasterize, EMPTY_FACE};

use super::PrepareError;

const OUTLINE: Rgb<u8> = Rgb([255, 0, 255]);
const DETECTED: Rgb<u8> = Rgb([255, 40, 40]);
const FITTED: Rgb<u8> = Rgb([40, 220, 255]);

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

fn dot(img: &mut RgbImage, p: Vec2, r: i64, c: Rgb<u8>) {
    let (x, y) = (p.x.round() as i64, p.y.round() as i64);
    for dy in -r..=r {
        for dx in -r..=r {
            put(img, x + dx, y + dy, c);
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
/// `detected`: `[K]` keypoints `(x, y, confidence)`; `fitted`: `[K]` the fitted body's
/// keypoints in world coordinates (`None` where a keypoint has no place on the body).
pub fn write_overlay(
    path: &Path,
    photo: RgbImage,
    camera: &Camera,
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    detected: &[[f32; 3]],
    fitted: &[Option<Vec3>],
) -> Result<(), PrepareError> {
    let mut img = photo;
    let frags = rasterize(camera, vertices, faces)
        .map_err(|e| PrepareError::invalid(path, format!("rasterising the fit: {e}")))?;
    let (w, h) = (frags.width as usize, frags.height as usize);
    let covered = |x: usize, y: usize| frags.face[y * w + x] != EMPTY_FACE;
    for y in 0..h {
        for x in 0..w {
            if covered(x, y) {
                let edge = x == 0
                    || y == 0
                    || x + 1 == w
                    || y + 1 == h
                    || !covered(x - 1, y)
                    || !covered(x + 1, y)
                    || !covered(x, y - 1)
                    || !covered(x, y + 1);
                if edge {
                    put(&mut img, x as i64, y as i64, OUTLINE);
                }
            }
        }
    }
    let radius = (img.width().max(img.height()) / 256).max(1) as i64;
    for (d, f) in detected.iter().zip(fitted) {
        let projected = f
            .and_then(|p| camera.project_distorted(p))
            .map(|(uv, _)| uv);
        if d[2] > 0.0 {
            let at = Vec2::new(d[0], d[1]);
            if let Some(p) = projected {
                line(&mut img, at, p, DETECTED);
            }
            dot(&mut img, at, radius, DETECTED);
        }
        if let Some(p) = projected {
            dot(&mut img, p, radius, FITTED);
        }
    }
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)
            .map_err(|e| PrepareError::io(dir, "create the overlay folder", e))?;
    }
    img.save(path)
        .map_err(|e| PrepareError::invalid(path, format!("cannot write PNG: {e}")))
}
