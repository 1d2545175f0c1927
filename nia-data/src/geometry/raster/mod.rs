//! A z-buffer triangle rasteriser for the ideal pinhole (undistorted) camera.
//!
//! Pixel convention: [`PIXEL_CENTRE_OFFSET`](crate::geometry::camera::PIXEL_CENTRE_OFFSET)
//! (OpenCV / ZJU-MoCap), i.e. pixel `(x, y)` has its centre at image coordinate `(x, y)`, the
//! same point [`crate::geometry::rays::image_rays`] casts its ray through. Coverage is tested at these pixel centres with edge functions and the
//! top-left fill rule, so two triangles sharing an edge never both cover (and never both miss)
//! a pixel centre lying exactly on it. The edge functions are evaluated in f64 as
//! `A px + B py + C` with `(A, B, C)` computed from the two endpoints; reversing an edge
//! negates all three exactly, which is what makes the shared-edge decision consistent.
//!
//! Depth is the camera `z_c` (metres), interpolated perspective-correctly (`1 / z` is affine in
//! screen space); barycentrics are perspective-correct, i.e. the weights that reproduce the 3D
//! point on the triangle.
//!
//! Near plane: triangles are *clipped* against `z_c = NEAR_PLANE_M` (Sutherland-Hodgman in
//! camera space), so a triangle partly behind the camera still draws its visible part;
//! barycentrics of clipped pieces are expressed in the original triangle.
//!
//! Degenerate (zero screen area) or non-finite triangles are skipped. No back-face culling.
//! Rows are processed in parallel bands; triangles are binned into the bands they touch and
//! drawn in face order within a band, so ties (equal depth) go to the lower face index and the
//! output does not depend on the thread count.
//!
//! - this file: [`rasterize`], binning the triangles into row bands drawn in parallel;
//! - `setup.rs`: one face made ready for the pixel loop (projection, near-plane clipping,
//!   edge functions, bounding box);
//! - `draw.rs`: the pixel loop of one triangle (coverage, depth test, barycentrics);
//! - `fragments.rs`: the output buffer [`Fragments`] and what it is read with;
//! - `error.rs`: [`MeshError`] and the face-index check every mesh consumer shares;
//! - `textured.rs`: [`render_textured`], a textured mesh rendered through the rasteriser.

use crate::geometry::camera::Camera;
use glam::Vec3;
use rayon::prelude::*;

mod draw;
mod error;
mod fragments;
mod setup;
mod textured;

pub use error::{validate_faces, MeshError};
pub use fragments::{Fragments, EMPTY_FACE};
pub use textured::render_textured;

use draw::draw_rows;
use setup::{setup_face, TriSetup, Viewport};

/// Near clipping plane, metres of camera depth: closer geometry is cut away (depths near 0
/// would blow screen coordinates up and make `1 / z` interpolation meaningless).
pub const NEAR_PLANE_M: f32 = 1e-4;

/// Rows per parallel work unit; 16 rows of a 512-wide image give 32 bands (enough for load
/// balance on a few cores, few enough that small triangles rarely straddle two bands).
const BAND_ROWS: usize = 16;

/// Faces per rayon task in the triangle setup.
const SETUP_CHUNK: usize = 1024;

/// Rasterises a world-space mesh into `camera`'s ideal pinhole image.
///
/// `vertices`: [V] world positions, metres; `faces`: [F] vertex index triples. Errors when a
/// face index is out of range. Non-finite vertices only drop their faces.
pub fn rasterize(
    camera: &Camera,
    vertices: &[Vec3],
    faces: &[[u32; 3]],
) -> Result<Fragments, MeshError> {
    let mut frags = Fragments::empty(0, 0);
    rasterize_into(camera, vertices, faces, &mut frags)?;
    Ok(frags)
}

/// [`rasterize`] into an existing buffer (resized to the camera's image), so repeated views
/// reuse its memory instead of faulting in ~5 MB of fresh pages per 512x512 view.
pub fn rasterize_into(
    camera: &Camera,
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    frags: &mut Fragments,
) -> Result<(), MeshError> {
    validate_faces("rasterize", "vertices", vertices.len(), faces)?;
    let vp = Viewport::new(camera);
    let (w, h) = (vp.w, vp.h);
    frags.reset(camera.width, camera.height);
    if w == 0 || h == 0 || faces.is_empty() {
        return Ok(());
    }

    // Camera-space vertices and their screen positions (shared by every face using them, so a
    // shared edge has bit-identical endpoints in both faces).
    let cam: Vec<Vec3> = vertices
        .iter()
        .map(|v| camera.world_to_camera(*v))
        .collect();
    let screen: Vec<[f64; 2]> = cam.iter().map(|p| vp.project(*p)).collect();

    // Triangle setup in parallel chunks; order (and so tie-breaking) stays the face order.
    let chunks: Vec<Vec<TriSetup>> = faces
        .par_chunks(SETUP_CHUNK)
        .enumerate()
        .map(|(c, chunk)| {
            let mut out = Vec::with_capacity(chunk.len());
            for (k, face) in chunk.iter().enumerate() {
                let f = (c * SETUP_CHUNK + k) as u32;
                out.extend(
                    setup_face(&vp, &cam, &screen, face, f)
                        .into_iter()
                        .flatten(),
                );
            }
            out
        })
        .collect();
    let tris = chunks.concat();

    // Bin triangles into row bands (CSR).
    let n_bands = h.div_ceil(BAND_ROWS);
    let mut band_start = vec![0u32; n_bands + 1];
    for t in &tris {
        for b in (t.bbox[2] as usize / BAND_ROWS)..=(t.bbox[3] as usize / BAND_ROWS) {
            band_start[b + 1] += 1;
        }
    }
    for b in 0..n_bands {
        band_start[b + 1] += band_start[b];
    }
    let mut fill = band_start.clone();
    let mut band_tris = vec![0u32; band_start[n_bands] as usize];
    for (ti, t) in tris.iter().enumerate() {
        for b in (t.bbox[2] as usize / BAND_ROWS)..=(t.bbox[3] as usize / BAND_ROWS) {
            band_tris[fill[b] as usize] = ti as u32;
            fill[b] += 1;
        }
    }

    let band_px = BAND_ROWS * w;
    frags
        .depth
        .par_chunks_mut(band_px)
        .zip(frags.face.par_chunks_mut(band_px))
        .zip(frags.bary.par_chunks_mut(band_px))
        .enumerate()
        .for_each(|(b, ((depth, face), bary))| {
            let y_begin = b * BAND_ROWS;
            let y_end = y_begin + depth.len() / w; // exclusive
            let list = &band_tris[band_start[b] as usize..band_start[b + 1] as usize];
            for &ti in list {
                let t = &tris[ti as usize];
                let y0 = (t.bbox[2] as usize).max(y_begin);
                let y1 = (t.bbox[3] as usize + 1).min(y_end);
                draw_rows(t, y0..y1, y_begin, &vp, depth, face, bary);
            }
        });
    Ok(())
}
