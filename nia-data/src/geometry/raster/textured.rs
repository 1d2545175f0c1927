//! A textured mesh rendered through the rasteriser: perspective-correct texture coordinates
//! per pixel, sampled bilinearly.

use glam::{Vec2, Vec3};
use image::RgbImage;
use rayon::prelude::*;

use super::{rasterize, MeshError, EMPTY_FACE};
use crate::geometry::camera::Camera;

/// Renders a textured mesh: per pixel, the perspective-correct texture coordinate of the
/// visible face, bilinearly sampled (texel `i` centred at `u = (i + 0.5) / width`: OpenGL's
/// texture convention, independent of
/// [`PIXEL_CENTRE_OFFSET`](crate::geometry::camera::PIXEL_CENTRE_OFFSET); clamped at the
/// border), black where no face is. `uvs`: [V] per-vertex texture coordinates in `[0, 1]`, OBJ/OpenGL
/// convention (`u` right, `v` up: `v = 1` is the texture's top row). Returns the image and the
/// [H * W] coverage mask.
pub fn render_textured(
    camera: &Camera,
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    uvs: &[Vec2],
    texture: &RgbImage,
) -> Result<(RgbImage, Vec<bool>), MeshError> {
    const WHAT: &str = "render_textured";
    if uvs.len() != vertices.len() {
        return Err(MeshError::Length {
            what: WHAT,
            field: "uvs",
            got: uvs.len(),
            expected: vertices.len(),
        });
    }
    if texture.width() == 0 || texture.height() == 0 {
        return Err(MeshError::Invalid {
            what: WHAT,
            field: "texture",
            expected: "a non-empty image",
        });
    }
    let frags = rasterize(camera, vertices, faces)?;
    let w = camera.width as usize;
    let mut pixels = vec![0u8; frags.face.len() * 3];
    if w > 0 {
        pixels
            .par_chunks_mut(w * 3)
            .enumerate()
            .for_each(|(y, row)| {
                for x in 0..w {
                    let i = y * w + x;
                    let f = frags.face[i];
                    if f == EMPTY_FACE {
                        continue;
                    }
                    let [a, b, c] = faces[f as usize];
                    let bc = frags.bary[i];
                    let uv =
                        uvs[a as usize] * bc[0] + uvs[b as usize] * bc[1] + uvs[c as usize] * bc[2];
                    let rgb = sample_texture(texture, uv);
                    row[x * 3..x * 3 + 3].copy_from_slice(&rgb);
                }
            });
    }
    let image =
        RgbImage::from_raw(camera.width, camera.height, pixels).ok_or(MeshError::Invalid {
            what: WHAT,
            field: "camera width/height",
            expected: "an image size whose buffer fits in memory",
        })?;
    Ok((image, frags.mask()))
}

/// Bilinear texture lookup at `uv` (OBJ convention, see [`render_textured`]), edge-clamped.
fn sample_texture(texture: &RgbImage, uv: Vec2) -> [u8; 3] {
    let (tw, th) = (texture.width() as usize, texture.height() as usize);
    if !uv.is_finite() {
        return [0; 3];
    }
    let sx = (uv.x * tw as f32 - 0.5).clamp(0.0, (tw - 1) as f32);
    let sy = ((1.0 - uv.y) * th as f32 - 0.5).clamp(0.0, (th - 1) as f32);
    let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(tw - 1), (y0 + 1).min(th - 1));
    let (fx, fy) = (sx - x0 as f32, sy - y0 as f32);
    let raw = texture.as_raw();
    let at = |x: usize, y: usize, c: usize| raw[(y * tw + x) * 3 + c] as f32;
    std::array::from_fn(|c| {
        let top = at(x0, y0, c) * (1.0 - fx) + at(x1, y0, c) * fx;
        let bottom = at(x0, y1, c) * (1.0 - fx) + at(x1, y1, c) * fx;
        (top * (1.0 - fy) + bottom * fy).round().clamp(0.0, 255.0) as u8
    })
}
