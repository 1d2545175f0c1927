//! Per-vertex visibility of a mesh in a camera (NIA's per-view SMPL vertex visibility, 0/1).
//!
//! A vertex is visible when it projects inside the image and either the pixel it falls in
//! (the pixel with the nearest centre: with [`PIXEL_CENTRE_OFFSET`] = 0 pixel `i` covers
//! `[i - 0.5, i + 0.5)`) is empty (the vertex sits on the silhouette, just outside its faces'
//! coverage), or at some covered pixel of the `(2 r + 1) x (2 r + 1)` neighbourhood
//! (r = [`NEIGHBOURHOOD_RADIUS`]) of that pixel
//! - its camera depth is within `depth_tol_m` of the z-buffer (`z_v <= z_buf + tol`), or
//! - the face drawn there is one of the vertex's own faces.
//!
//! Empty neighbours do not count (otherwise every hidden vertex within a pixel of the
//! silhouette would pass).
//!
//! The neighbourhood (as NHP-style implementations that test the pixel and its neighbours) and
//! the incident-face rule make the decision independent of where inside its pixel a vertex
//! lands; the z-buffer is sampled at pixel centres, which can sit up to 0.7 pixels from the
//! vertex on a steep surface. The price is a band about one pixel wide around occlusion
//! boundaries where a just-hidden vertex counts as visible.

use crate::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};
use crate::geometry::raster::{rasterize, validate_faces, Fragments, MeshError, EMPTY_FACE};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// Pixels around the vertex's own pixel that are consulted (1: a 3x3 window).
pub const NEIGHBOURHOOD_RADIUS: i64 = 1;

/// A depth tolerance for human bodies seen at a few metres in 512-pixel images: a pixel spans
/// ~5 mm there and a tilted surface changes depth by a few mm across it, while the thinnest
/// occluders (fingers, arms in front of the torso) are several cm thick.
pub const DEFAULT_DEPTH_TOL_M: f32 = 0.01;

/// [V] 0/1 visibility of every vertex in `camera` given the mesh's rasterisation `fragments`
/// (from [`rasterize`] with the same camera, vertices and faces). `vertices`: [V] world
/// metres; `depth_tol_m`: metres of camera depth.
pub fn vertex_visibility(
    camera: &Camera,
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    fragments: &Fragments,
    depth_tol_m: f32,
) -> Result<Vec<u8>, MeshError> {
    const WHAT: &str = "vertex_visibility";
    validate_faces(WHAT, "vertices", vertices.len(), faces)?;
    if fragments.width != camera.width || fragments.height != camera.height {
        return Err(MeshError::Length {
            what: WHAT,
            field: "fragments width x height",
            got: fragments.width as usize * fragments.height as usize,
            expected: camera.width as usize * camera.height as usize,
        });
    }
    let n = camera.width as usize * camera.height as usize;
    for (field, len) in [
        ("fragments.depth", fragments.depth.len()),
        ("fragments.face", fragments.face.len()),
    ] {
        if len != n {
            return Err(MeshError::Length {
                what: WHAT,
                field,
                got: len,
                expected: n,
            });
        }
    }
    fragments.check_face_indices(WHAT, faces)?;
    if !(depth_tol_m >= 0.0) {
        return Err(MeshError::Invalid {
            what: WHAT,
            field: "depth_tol_m",
            expected: "a tolerance >= 0 metres",
        });
    }
    let (w, h) = (camera.width as i64, camera.height as i64);
    Ok(vertices
        .par_iter()
        .enumerate()
        .map(|(vi, v)| {
            let Some((uv, z)) = camera.project(*v) else {
                return 0;
            };
            // The pixel whose cell [i + offset - 0.5, i + offset + 0.5) holds uv; outside
            // the image (or NaN, which fails the range test) means unseen.
            let cell = (uv - Vec2::splat(PIXEL_CENTRE_OFFSET - 0.5)).floor();
            if !(cell.x >= 0.0 && cell.y >= 0.0 && cell.x < w as f32 && cell.y < h as f32) {
                return 0;
            }
            let (px, py) = (cell.x as i64, cell.y as i64);
            // The vertex's own pixel: empty means the vertex lies on the silhouette, just
            // outside the coverage of its faces.
            if fragments.face[(py * w + px) as usize] == EMPTY_FACE {
                return 1;
            }
            for qy in (py - NEIGHBOURHOOD_RADIUS).max(0)..=(py + NEIGHBOURHOOD_RADIUS).min(h - 1) {
                for qx in
                    (px - NEIGHBOURHOOD_RADIUS).max(0)..=(px + NEIGHBOURHOOD_RADIUS).min(w - 1)
                {
                    let q = (qy * w + qx) as usize;
                    let f = fragments.face[q];
                    if f == EMPTY_FACE {
                        continue;
                    }
                    if z <= fragments.depth[q] + depth_tol_m
                        || faces[f as usize].iter().any(|&c| c as usize == vi)
                    {
                        return 1;
                    }
                }
            }
            0
        })
        .collect())
}

/// Rasterises the mesh into `camera` and returns its [V] 0/1 vertex visibility (see
/// [`vertex_visibility`]).
pub fn visibility(
    camera: &Camera,
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    depth_tol_m: f32,
) -> Result<Vec<u8>, MeshError> {
    let fragments = rasterize(camera, vertices, faces)?;
    vertex_visibility(camera, vertices, faces, &fragments, depth_tol_m)
}
