//! The pixel loop of one set-up triangle: coverage at pixel centres by the edge functions and
//! the top-left rule, the depth test, and perspective-correct barycentrics in the original face.

use super::setup::{TriSetup, Viewport};
use crate::geometry::camera::PIXEL_CENTRE_OFFSET;

/// Draws rows `rows` (absolute) of one triangle into a band starting at row `y_begin`.
#[inline]
pub(super) fn draw_rows(
    t: &TriSetup,
    rows: std::ops::Range<usize>,
    y_begin: usize,
    vp: &Viewport<'_>,
    depth: &mut [f32],
    face: &mut [u32],
    bary: &mut [[f32; 3]],
) {
    let (w, ox, oy) = (vp.w, vp.ox, vp.oy);
    let [e0, e1, e2] = &t.edges;
    let (x0, x1) = (t.bbox[0] as usize, t.bbox[1] as usize);
    // Pixel centres relative to the image centre (exact in f64 for any image size).
    let (cx, cy) = (
        PIXEL_CENTRE_OFFSET as f64 - ox,
        PIXEL_CENTRE_OFFSET as f64 - oy,
    );
    for y in rows {
        let py = y as f64 + cy;
        let r0 = e0[1] * py + e0[2];
        let r1 = e1[1] * py + e1[2];
        let r2 = e2[1] * py + e2[2];
        let row = (y - y_begin) * w;
        for x in x0..=x1 {
            let px = x as f64 + cx;
            let a0 = e0[0] * px + r0;
            let a1 = e1[0] * px + r1;
            let a2 = e2[0] * px + r2;
            let inside = (a0 > 0.0 || (a0 == 0.0 && t.top_left[0]))
                && (a1 > 0.0 || (a1 == 0.0 && t.top_left[1]))
                && (a2 > 0.0 || (a2 == 0.0 && t.top_left[2]));
            if !inside {
                continue;
            }
            // Perspective-correct weights: screen barycentric / z, renormalised.
            let w0 = a0 * t.inv_area2 * t.inv_z[0];
            let w1 = a1 * t.inv_area2 * t.inv_z[1];
            let w2 = a2 * t.inv_area2 * t.inv_z[2];
            let sum = w0 + w1 + w2;
            let z = (1.0 / sum) as f32;
            let i = row + x;
            if !(z < depth[i]) {
                continue;
            }
            let inv = 1.0 / sum;
            let mut b = [(w0 * inv) as f32, (w1 * inv) as f32, (w2 * inv) as f32];
            if t.clipped {
                let m = &t.to_face;
                b = std::array::from_fn(|k| b[0] * m[0][k] + b[1] * m[1][k] + b[2] * m[2][k]);
            }
            depth[i] = z;
            face[i] = t.face;
            bary[i] = b;
        }
    }
}
