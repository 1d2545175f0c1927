//! One face made ready for the pixel loop: projected to the screen, clipped against the near
//! plane when it crosses it, and turned into edge functions (top-left rule), inverse depths and
//! a pixel bounding box.

use glam::Vec3;

use super::NEAR_PLANE_M;
use crate::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};

/// Barycentrics of a face's own three vertices (the `to_face` of an unclipped face).
const IDENTITY: [[f32; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// The image triangles are set up for: the camera, its size in pixels, and the origin
/// `(W / 2, H / 2)` screen coordinates are taken relative to (exact in f64), so the edge
/// coefficients stay small.
#[derive(Debug, Clone, Copy)]
pub(super) struct Viewport<'a> {
    pub camera: &'a Camera,
    pub w: usize,
    pub h: usize,
    pub ox: f64,
    pub oy: f64,
}

impl<'a> Viewport<'a> {
    pub fn new(camera: &'a Camera) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        Viewport {
            camera,
            w,
            h,
            ox: w as f64 * 0.5,
            oy: h as f64 * 0.5,
        }
    }

    /// Screen position relative to `(ox, oy)` (f64), NaN when at or behind the camera
    /// plane (such vertices only occur in clipped faces, which do not use this value).
    #[inline]
    pub fn project(&self, p: Vec3) -> [f64; 2] {
        let (camera, ox, oy) = (self.camera, self.ox, self.oy);
        if p.z > 0.0 {
            let (x, y, z) = (p.x as f64, p.y as f64, p.z as f64);
            let (nx, ny) = (x / z, y / z);
            [
                camera.fx() as f64 * nx + camera.skew() as f64 * ny + camera.cx() as f64 - ox,
                camera.fy() as f64 * ny + camera.cy() as f64 - oy,
            ]
        } else {
            [f64::NAN, f64::NAN]
        }
    }
}

/// A triangle ready for the pixel loop: edge functions oriented so the inside is positive.
#[derive(Debug, Clone, Copy)]
pub(super) struct TriSetup {
    /// Edge `i` is opposite vertex `i`: `E_i(p) = A px + B py + C` (pixel coordinates relative
    /// to `(W / 2, H / 2)`, near the image centre, to keep the coefficients small), positive
    /// inside.
    pub edges: [[f64; 3]; 3],
    /// Whether a pixel centre exactly on edge `i` belongs to this triangle (top-left rule).
    pub top_left: [bool; 3],
    /// `1 / (2 * screen area)`.
    pub inv_area2: f64,
    /// `1 / z_c` of the three (possibly clipped) vertices.
    pub inv_z: [f64; 3],
    /// Inclusive pixel ranges `[x0, x1, y0, y1]` of the bounding box, clamped to the image.
    pub bbox: [u32; 4],
    pub face: u32,
    /// Barycentrics of the three vertices in the original face (identity unless clipped).
    pub to_face: [[f32; 3]; 3],
    pub clipped: bool,
}

/// A vertex in camera space with its barycentric in the original face.
#[derive(Debug, Clone, Copy)]
struct ClipVertex {
    p: Vec3,
    bary: [f32; 3],
}

/// The 0, 1 or 2 drawable pieces of one face (2 when near-plane clipping leaves a quad).
pub(super) fn setup_face(
    vp: &Viewport<'_>,
    cam: &[Vec3],
    screen: &[[f64; 2]],
    face: &[u32; 3],
    f: u32,
) -> [Option<TriSetup>; 2] {
    let idx = face.map(|i| i as usize);
    let pc = idx.map(|i| cam[i]);
    if !pc.iter().all(|p| p.is_finite()) {
        return [None, None];
    }
    let inside = pc.map(|p| p.z >= NEAR_PLANE_M);
    if inside.iter().all(|b| *b) {
        let s = idx.map(|i| screen[i]);
        let inv_z = pc.map(|p| 1.0 / p.z as f64);
        [setup(s, inv_z, IDENTITY, false, f, vp), None]
    } else if inside.iter().any(|b| *b) {
        clip_and_setup(vp, face, pc, f)
    } else {
        [None, None]
    }
}

/// Edge function coefficients of the directed edge `a -> b`: `E(p) = A px + B py + C`, with
/// `E(b -> a) == -E(a -> b)` exactly.
#[inline]
fn edge(a: [f64; 2], b: [f64; 2]) -> [f64; 3] {
    [a[1] - b[1], b[0] - a[0], a[0] * b[1] - a[1] * b[0]]
}

#[inline]
fn eval(e: &[f64; 3], x: f64, y: f64) -> f64 {
    e[0] * x + (e[1] * y + e[2])
}

/// Edge functions, orientation, bounding box; `None` for degenerate or off-screen triangles.
fn setup(
    s: [[f64; 2]; 3],
    inv_z: [f64; 3],
    to_face: [[f32; 3]; 3],
    clipped: bool,
    face: u32,
    vp: &Viewport<'_>,
) -> Option<TriSetup> {
    if !s.iter().flatten().all(|c| c.is_finite()) {
        return None;
    }
    let mut edges = [edge(s[1], s[2]), edge(s[2], s[0]), edge(s[0], s[1])];
    let area2 = eval(&edges[0], s[0][0], s[0][1]);
    if !(area2.abs() > 0.0) || !area2.is_finite() {
        return None;
    }
    if area2 < 0.0 {
        for e in &mut edges {
            *e = [-e[0], -e[1], -e[2]];
        }
    }
    // Inward normal (A, B) pointing right, or straight down (y grows downwards): the edge is a
    // left or a top edge and owns the pixel centres lying on it.
    let top_left = edges.map(|e| e[0] > 0.0 || (e[0] == 0.0 && e[1] > 0.0));
    let (w, h, ox, oy) = (vp.w, vp.h, vp.ox, vp.oy);
    let min_x = s[0][0].min(s[1][0]).min(s[2][0]) + ox;
    let max_x = s[0][0].max(s[1][0]).max(s[2][0]) + ox;
    let min_y = s[0][1].min(s[1][1]).min(s[2][1]) + oy;
    let max_y = s[0][1].max(s[1][1]).max(s[2][1]) + oy;
    // Pixel x is covered only if its centre x + PIXEL_CENTRE_OFFSET lies in [min_x, max_x].
    let off = PIXEL_CENTRE_OFFSET as f64;
    let x0 = (min_x - off).ceil().max(0.0);
    let x1 = (max_x - off).floor().min(w as f64 - 1.0);
    let y0 = (min_y - off).ceil().max(0.0);
    let y1 = (max_y - off).floor().min(h as f64 - 1.0);
    if !(x0 <= x1 && y0 <= y1) {
        return None;
    }
    Some(TriSetup {
        edges,
        top_left,
        inv_area2: 1.0 / area2.abs(),
        inv_z,
        bbox: [x0 as u32, x1 as u32, y0 as u32, y1 as u32],
        face,
        to_face,
        clipped,
    })
}

/// Clips a face with 1 or 2 vertices in front of the near plane and sets up the 1 or 2 pieces.
fn clip_and_setup(
    vp: &Viewport<'_>,
    face: &[u32; 3],
    pc: [Vec3; 3],
    f: u32,
) -> [Option<TriSetup>; 2] {
    let verts: [ClipVertex; 3] = std::array::from_fn(|i| ClipVertex {
        p: pc[i],
        bary: IDENTITY[i],
    });
    let mut poly = [verts[0]; 4];
    let mut n = 0;
    for i in 0..3 {
        let j = (i + 1) % 3;
        let (a, b) = (verts[i], verts[j]);
        let a_in = a.p.z >= NEAR_PLANE_M;
        let b_in = b.p.z >= NEAR_PLANE_M;
        if a_in {
            poly[n] = a;
            n += 1;
        }
        if a_in != b_in {
            // Intersect with the endpoints in a canonical order (lower vertex index first), so
            // the neighbouring face sharing this edge gets the bit-identical point.
            let (p, q) = if face[i] <= face[j] { (a, b) } else { (b, a) };
            let t = (NEAR_PLANE_M - p.p.z) / (q.p.z - p.p.z);
            let mut x = p.p + (q.p - p.p) * t;
            x.z = NEAR_PLANE_M;
            let bary = std::array::from_fn(|k| p.bary[k] + (q.bary[k] - p.bary[k]) * t);
            poly[n] = ClipVertex { p: x, bary };
            n += 1;
        }
    }
    // Fan triangulation of the 3- or 4-gon.
    let mut out = [None, None];
    for k in 1..n.saturating_sub(1) {
        let piece = [poly[0], poly[k], poly[k + 1]];
        let s = piece.map(|v| vp.project(v.p));
        let inv_z = piece.map(|v| 1.0 / v.p.z as f64);
        let to_face = piece.map(|v| v.bary);
        out[k - 1] = setup(s, inv_z, to_face, true, f, vp);
    }
    out
}
