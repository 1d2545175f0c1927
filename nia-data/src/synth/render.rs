//! Rendering one view of a clothed subject: rasterise the clothed mesh, evaluate the procedural
//! appearance per sample on the canonical body (perspective-correct barycentrics), shade with
//! a fixed Lambert key and fill light plus ambient, and box-filter the supersamples down to the
//! output image and a binary foreground mask. Background is black.

use super::clothing::{classify, BodyFrame, Cut, PART_COUNT};
use super::texture::Look;
use crate::geometry::camera::Camera;
use crate::geometry::raster::{rasterize, MeshError, EMPTY_FACE};
use glam::Vec3;
use rayon::prelude::*;

/// Fixed world lights (world z up): a key light from above-front and a weaker fill from the
/// opposite side, so the subject reads as a lit 3D person from every camera on the ring.
pub const KEY_LIGHT_DIR: Vec3 = Vec3::new(0.45, -0.55, 0.70);
pub const FILL_LIGHT_DIR: Vec3 = Vec3::new(-0.5, 0.6, 0.15);
pub const KEY_LIGHT: f32 = 0.65;
pub const FILL_LIGHT: f32 = 0.25;
pub const AMBIENT_LIGHT: f32 = 0.38;

/// What the shader reads per vertex of the clothed mesh (same topology as the body).
pub struct SurfaceAttributes<'a> {
    /// [V] canonical (rest-pose, shaped) body positions, metres: where the pattern lives.
    pub canonical: &'a [Vec3],
    /// [V] skinning weights summed per body part.
    pub parts: &'a [[f32; PART_COUNT]],
    pub frame: &'a BodyFrame,
    pub cut: &'a Cut,
    pub look: &'a Look,
}

/// One rendered view.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedView {
    pub width: u32,
    pub height: u32,
    /// [H * W * 3] sRGB, row-major.
    pub rgb: Vec<u8>,
    /// [H * W] 255 where the clothed person covers at least half of the pixel, else 0.
    pub mask: Vec<u8>,
}

/// Render `camera`'s view of the clothed mesh `vertices` [V] (world, metres) with unit vertex
/// normals `normals` [V] and faces [F], at `supersample` x `supersample` samples per pixel.
pub fn render_view(
    camera: &Camera,
    supersample: u32,
    vertices: &[Vec3],
    normals: &[Vec3],
    faces: &[[u32; 3]],
    surface: &SurfaceAttributes<'_>,
) -> Result<RenderedView, MeshError> {
    let ss = supersample.max(1);
    let (width, height) = (camera.width, camera.height);
    let fine_camera = if ss == 1 {
        *camera
    } else {
        // Fine pixel centres must sit at x + (2k + 1 - ss) / (2 ss) around each coarse centre:
        // with integer centres the principal point maps c -> (c + 0.5) ss - 0.5.
        let mut fine = camera.scaled(ss as f32).map_err(|_| MeshError::Invalid {
            what: "render_view",
            field: "supersample",
            expected: "a supersampling factor the camera can be scaled by",
        })?;
        let shift = (ss as f32 - 1.0) * 0.5;
        fine.k.z_axis.x += shift;
        fine.k.z_axis.y += shift;
        fine
    };
    for (field, len) in [
        ("normals", normals.len()),
        ("canonical", surface.canonical.len()),
        ("parts", surface.parts.len()),
    ] {
        if len != vertices.len() {
            return Err(MeshError::Length {
                what: "render_view",
                field,
                got: len,
                expected: vertices.len(),
            });
        }
    }
    let frags = rasterize(&fine_camera, vertices, faces)?;
    let fine_w = fine_camera.width as usize;
    let eye = camera.centre();
    let key = KEY_LIGHT_DIR.normalize();
    let fill = FILL_LIGHT_DIR.normalize();

    // Shade one fine sample: sRGB colour in [0, 1], or None where nothing covers it.
    let shade = |i: usize| -> Option<Vec3> {
        let f = frags.face[i];
        if f == EMPTY_FACE {
            return None;
        }
        let [a, b, c] = faces[f as usize].map(|k| k as usize);
        let w = frags.bary[i];
        let canonical =
            surface.canonical[a] * w[0] + surface.canonical[b] * w[1] + surface.canonical[c] * w[2];
        let mut parts = [0.0f32; PART_COUNT];
        for (k, p) in parts.iter_mut().enumerate() {
            *p = surface.parts[a][k] * w[0]
                + surface.parts[b][k] * w[1]
                + surface.parts[c][k] * w[2];
        }
        let world = vertices[a] * w[0] + vertices[b] * w[1] + vertices[c] * w[2];
        let mut n = (normals[a] * w[0] + normals[b] * w[1] + normals[c] * w[2]).normalize_or_zero();
        // Two-sided: a normal facing away from the eye belongs to the other side of the sheet.
        if n.dot(eye - world) < 0.0 {
            n = -n;
        }
        let gp = classify(surface.frame, surface.cut, canonical, &parts);
        let albedo = surface.look.albedo(surface.frame, &gp);
        let light =
            AMBIENT_LIGHT + KEY_LIGHT * n.dot(key).max(0.0) + FILL_LIGHT * n.dot(fill).max(0.0);
        Some((albedo * light).clamp(Vec3::ZERO, Vec3::ONE))
    };

    let (w, h) = (width as usize, height as usize);
    let samples = (ss * ss) as f32;
    let mut rgb = vec![0u8; w * h * 3];
    let mut mask = vec![0u8; w * h];
    rgb.par_chunks_mut(w * 3)
        .zip(mask.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (rgb_row, mask_row))| {
            for x in 0..w {
                let mut sum = Vec3::ZERO;
                let mut covered = 0u32;
                for sy in 0..ss as usize {
                    let row = (y * ss as usize + sy) * fine_w;
                    for sx in 0..ss as usize {
                        if let Some(c) = shade(row + x * ss as usize + sx) {
                            sum += c;
                            covered += 1;
                        }
                    }
                }
                let c = sum / samples * 255.0;
                rgb_row[3 * x] = c.x.round() as u8;
                rgb_row[3 * x + 1] = c.y.round() as u8;
                rgb_row[3 * x + 2] = c.z.round() as u8;
                mask_row[x] = if 2 * covered >= ss * ss && covered > 0 {
                    255
                } else {
                    0
                };
            }
        });
    Ok(RenderedView {
        width,
        height,
        rgb,
        mask,
    })
}
