//! The depth test of o_n (not in the paper; `ModelConfig::visibility_depth_tol_m`): the posed
//! body's z-buffer in every source view, and how much of a point's projection is not hidden
//! behind it.
//!
//! The paper's o_n interpolates per-vertex visibility on the point's nearest body face. At a
//! few centimetres per pixel that decision is coarse where limbs overlap: a vertex counts as
//! visible when any pixel of its 3 x 3 neighbourhood passes (`geometry::visibility`), so the
//! inner side of a leg that the other leg hides in a source view still reads that view, and
//! what it fetches there is the other leg or the gap between them. The depth test asks the
//! question of the point itself: at its projection in view n, is its camera depth within
//! `tol` of the body's nearest surface there?
//!
//! ```text
//! o_n(x) = o_vertex_n(x) * sum_k a_k [z_n(x) <= D_n(p_k) + tol]
//! ```
//!
//! with `p_k` the four pixels around the projection, `a_k` their bilinear weights, `D_n` the
//! z-buffer (`+inf` where the body does not cover a pixel, which passes). The result stays in
//! [0, 1] and moves continuously as the projection crosses an occlusion edge.

use glam::{Vec2, Vec3};

use crate::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};
use crate::geometry::raster::{rasterize, MeshError};

/// Per-view z-buffers of the posed body and the tolerance of the test.
#[derive(Debug, Clone)]
pub struct SourceDepth {
    /// Metres a point may sit behind the body's nearest surface and still count as seen (the
    /// clothing and the body model's fit: a point on the clothed surface sits in front of the
    /// body, a point a little inside it behind).
    pub tol_m: f32,
    width: usize,
    height: usize,
    /// [N][H * W] camera depth of the nearest body surface, `+inf` where empty.
    maps: Vec<Vec<f32>>,
}

impl SourceDepth {
    /// Rasterises the body (`vertices` [V] world, `faces` [F]) into every camera; the cameras
    /// must share one image size (an error naming `cameras` otherwise).
    pub fn rasterise(
        cameras: &[Camera],
        vertices: &[Vec3],
        faces: &[[u32; 3]],
        tol_m: f32,
    ) -> Result<Self, MeshError> {
        if !(tol_m.is_finite() && tol_m >= 0.0) {
            return Err(MeshError::Invalid {
                what: "source depth test",
                field: "tol_m",
                expected: "a finite tolerance >= 0 metres",
            });
        }
        let (width, height) = cameras
            .first()
            .map_or((0, 0), |c| (c.width as usize, c.height as usize));
        // One size for every map, so `unhidden` can index any of them with it.
        if cameras
            .iter()
            .any(|c| (c.width as usize, c.height as usize) != (width, height))
        {
            return Err(MeshError::Invalid {
                what: "source depth test",
                field: "cameras",
                expected: "every source camera of one image size",
            });
        }
        let maps = cameras
            .iter()
            .map(|camera| rasterize(camera, vertices, faces).map(|f| f.depth))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(SourceDepth {
            tol_m,
            width,
            height,
            maps,
        })
    }

    /// The share in [0, 1] of the projection `uv` (pixels) of a point at camera depth `z` in
    /// view `view` that is not hidden: the bilinear weights of the four pixels around `uv`
    /// whose z-buffer is at least `z - tol_m` (pixels outside the image or not covered by the
    /// body pass; a non-finite projection has nothing to read and gets 0). `PointInputs`
    /// projects each point again for it rather than reading the normalised grid back, because
    /// the test also needs the camera depth: one projection per point and view, with the
    /// switch on only.
    pub fn unhidden(&self, view: usize, uv: Vec2, z: f32) -> f32 {
        let map = &self.maps[view];
        let p = uv - Vec2::splat(PIXEL_CENTRE_OFFSET);
        if !p.is_finite() {
            return 0.0;
        }
        let (x0, y0) = (p.x.floor(), p.y.floor());
        let (fx, fy) = (p.x - x0, p.y - y0);
        let mut share = 0.0;
        for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
            for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
                let (x, y) = (x0 as i64 + dx, y0 as i64 + dy);
                let inside =
                    x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height;
                let passes = !inside || z <= map[y as usize * self.width + x as usize] + self.tol_m;
                if passes {
                    share += wx * wy;
                }
            }
        }
        share
    }
}
