//! A z-buffer triangle rasteriser for the ideal pinhole (undistorted) camera.
//!
//! Pixel convention: [`PIXEL_CENTRE_OFFSET`] (OpenCV / ZJU-MoCap), i.e. pixel `(x, y)` has its
//! centre at image coordinate `(x, y)`, the same point [`crate::geometry::rays::image_rays`] casts its
//! ray through. Coverage is tested at these pixel centres with edge functions and the
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

// `!(a < b)` comparisons are deliberate: they reject NaN along with the failing case.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};
use glam::{Vec2, Vec3};
use image::RgbImage;
use rayon::prelude::*;

/// Near clipping plane, metres of camera depth: closer geometry is cut away (depths near 0
/// would blow screen coordinates up and make `1 / z` interpolation meaningless).
pub const NEAR_PLANE_M: f32 = 1e-4;

/// Rows per parallel work unit; 16 rows of a 512-wide image give 32 bands (enough for load
/// balance on a few cores, few enough that small triangles rarely straddle two bands).
const BAND_ROWS: usize = 16;

/// Pixels per rayon task when clearing buffers.
const CLEAR_MIN_LEN: usize = 1 << 14;

/// Faces per rayon task in the triangle setup.
const SETUP_CHUNK: usize = 1024;

/// Face value of a pixel no triangle covers.
pub const EMPTY_FACE: u32 = u32::MAX;

/// A mesh or per-vertex attribute that does not fit together.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshError {
    #[error(
        "{what}: faces[{face}][{corner}] = {index}, but `{field}` has only {len} entries \
         (expected an index below {len})"
    )]
    FaceIndex {
        what: &'static str,
        field: &'static str,
        face: usize,
        corner: usize,
        index: u32,
        len: usize,
    },
    #[error("{what}: `{field}` has {got} entries, expected {expected}")]
    Length {
        what: &'static str,
        field: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("{what}: `{field}`: expected {expected}")]
    Invalid {
        what: &'static str,
        field: &'static str,
        expected: &'static str,
    },
}

/// Checks every face index against `len` entries of `field` (e.g. the vertex array).
pub fn validate_faces(
    what: &'static str,
    field: &'static str,
    len: usize,
    faces: &[[u32; 3]],
) -> Result<(), MeshError> {
    if faces.len() >= EMPTY_FACE as usize {
        return Err(MeshError::Length {
            what,
            field: "faces",
            got: faces.len(),
            expected: EMPTY_FACE as usize - 1,
        });
    }
    for (f, tri) in faces.iter().enumerate() {
        for (c, &index) in tri.iter().enumerate() {
            if index as usize >= len {
                return Err(MeshError::FaceIndex {
                    what,
                    field,
                    face: f,
                    corner: c,
                    index,
                    len,
                });
            }
        }
    }
    Ok(())
}

/// The rasteriser's output, all [H * W] row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Fragments {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// [H * W] camera depth `z_c` of the nearest surface, metres; `+inf` where empty.
    pub depth: Vec<f32>,
    /// [H * W] index of the covering face; [`EMPTY_FACE`] where empty.
    pub face: Vec<u32>,
    /// [H * W] perspective-correct barycentrics in that face (sum 1); zeros where empty.
    pub bary: Vec<[f32; 3]>,
}

impl Fragments {
    /// Every face index the fragments hold addresses `faces` (checked before reading it).
    pub(crate) fn check_face_indices(
        &self,
        what: &'static str,
        faces: &[[u32; 3]],
    ) -> Result<(), MeshError> {
        match self
            .face
            .iter()
            .find(|f| **f != EMPTY_FACE && **f as usize >= faces.len())
        {
            Some(bad) => Err(MeshError::Length {
                what,
                field: "faces",
                got: faces.len(),
                expected: *bad as usize + 1,
            }),
            None => Ok(()),
        }
    }

    /// An empty buffer (nothing drawn).
    pub fn empty(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Fragments {
            width,
            height,
            depth: vec![f32::INFINITY; n],
            face: vec![EMPTY_FACE; n],
            bary: vec![[0.0; 3]; n],
        }
    }

    /// Resizes to `width x height` and clears every pixel (in parallel, reusing the memory).
    pub fn reset(&mut self, width: u32, height: u32) {
        let n = width as usize * height as usize;
        if self.depth.len() != n || self.face.len() != n || self.bary.len() != n {
            // Fresh buffers: `vec!` of zeros maps lazily-zeroed pages.
            *self = Fragments::empty(width, height);
            return;
        }
        self.width = width;
        self.height = height;
        self.depth
            .par_iter_mut()
            .with_min_len(CLEAR_MIN_LEN)
            .for_each(|d| *d = f32::INFINITY);
        self.face
            .par_iter_mut()
            .with_min_len(CLEAR_MIN_LEN)
            .for_each(|f| *f = EMPTY_FACE);
        self.bary
            .par_iter_mut()
            .with_min_len(CLEAR_MIN_LEN)
            .for_each(|b| *b = [0.0; 3]);
    }

    /// [H * W] true where a face covers the pixel.
    pub fn mask(&self) -> Vec<bool> {
        self.face.iter().map(|f| *f != EMPTY_FACE).collect()
    }

    /// Perspective-correct interpolation of a per-vertex attribute ([V] values, e.g. world
    /// positions) at every pixel: `None` where empty. `faces` must be the faces that were
    /// rasterised.
    pub fn interpolate(
        &self,
        faces: &[[u32; 3]],
        attribute: &[Vec3],
    ) -> Result<Vec<Option<Vec3>>, MeshError> {
        const WHAT: &str = "Fragments::interpolate";
        validate_faces(WHAT, "attribute", attribute.len(), faces)?;
        self.check_face_indices(WHAT, faces)?;
        Ok(self
            .face
            .par_iter()
            .zip(self.bary.par_iter())
            .map(|(&f, b)| {
                (f != EMPTY_FACE).then(|| {
                    let [i, j, k] = faces[f as usize];
                    attribute[i as usize] * b[0]
                        + attribute[j as usize] * b[1]
                        + attribute[k as usize] * b[2]
                })
            })
            .collect())
    }
}

/// A triangle ready for the pixel loop: edge functions oriented so the inside is positive.
#[derive(Debug, Clone, Copy)]
struct TriSetup {
    /// Edge `i` is opposite vertex `i`: `E_i(p) = A px + B py + C` (pixel coordinates relative
    /// to `(W / 2, H / 2)`, near the image centre, to keep the coefficients small), positive
    /// inside.
    edges: [[f64; 3]; 3],
    /// Whether a pixel centre exactly on edge `i` belongs to this triangle (top-left rule).
    top_left: [bool; 3],
    /// `1 / (2 * screen area)`.
    inv_area2: f64,
    /// `1 / z_c` of the three (possibly clipped) vertices.
    inv_z: [f64; 3],
    /// Inclusive pixel ranges `[x0, x1, y0, y1]` of the bounding box, clamped to the image.
    bbox: [u32; 4],
    face: u32,
    /// Barycentrics of the three vertices in the original face (identity unless clipped).
    to_face: [[f32; 3]; 3],
    clipped: bool,
}

/// A vertex in camera space with its barycentric in the original face.
#[derive(Debug, Clone, Copy)]
struct ClipVertex {
    p: Vec3,
    bary: [f32; 3],
}

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
    let (w, h) = (camera.width as usize, camera.height as usize);
    frags.reset(camera.width, camera.height);
    if w == 0 || h == 0 || faces.is_empty() {
        return Ok(());
    }

    // Camera-space vertices and their screen positions (shared by every face using them, so a
    // shared edge has bit-identical endpoints in both faces). Screen coordinates are taken
    // relative to (W / 2, H / 2) (exact in f64) so the edge coefficients stay small.
    let ox = w as f64 * 0.5;
    let oy = h as f64 * 0.5;
    let cam: Vec<Vec3> = vertices
        .iter()
        .map(|v| camera.world_to_camera(*v))
        .collect();
    let screen: Vec<[f64; 2]> = cam.iter().map(|p| project(camera, *p, ox, oy)).collect();

    // Triangle setup in parallel chunks; order (and so tie-breaking) stays the face order.
    let chunks: Vec<Vec<TriSetup>> = faces
        .par_chunks(SETUP_CHUNK)
        .enumerate()
        .map(|(c, chunk)| {
            let mut out = Vec::with_capacity(chunk.len());
            for (k, face) in chunk.iter().enumerate() {
                let f = (c * SETUP_CHUNK + k) as u32;
                out.extend(
                    setup_face(camera, &cam, &screen, face, f, w, h, ox, oy)
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
                draw_rows(t, y0..y1, y_begin, w, ox, oy, depth, face, bary);
            }
        });
    Ok(())
}

/// The 0, 1 or 2 drawable pieces of one face (2 when near-plane clipping leaves a quad).
#[allow(clippy::too_many_arguments)]
fn setup_face(
    camera: &Camera,
    cam: &[Vec3],
    screen: &[[f64; 2]],
    face: &[u32; 3],
    f: u32,
    w: usize,
    h: usize,
    ox: f64,
    oy: f64,
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
        let id = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        [setup(s, inv_z, id, false, f, w, h), None]
    } else if inside.iter().any(|b| *b) {
        clip_and_setup(camera, face, pc, f, w, h, ox, oy)
    } else {
        [None, None]
    }
}

/// Screen position relative to `(ox, oy)` (f64), NaN when at or behind the camera
/// plane (such vertices only occur in clipped faces, which do not use this value).
#[inline]
fn project(camera: &Camera, p: Vec3, ox: f64, oy: f64) -> [f64; 2] {
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
    w: usize,
    h: usize,
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
    let (ox, oy) = (w as f64 * 0.5, h as f64 * 0.5);
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
#[allow(clippy::too_many_arguments)]
fn clip_and_setup(
    camera: &Camera,
    face: &[u32; 3],
    pc: [Vec3; 3],
    f: u32,
    w: usize,
    h: usize,
    ox: f64,
    oy: f64,
) -> [Option<TriSetup>; 2] {
    let unit = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let verts: [ClipVertex; 3] = std::array::from_fn(|i| ClipVertex {
        p: pc[i],
        bary: unit[i],
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
        let s = piece.map(|v| project(camera, v.p, ox, oy));
        let inv_z = piece.map(|v| 1.0 / v.p.z as f64);
        let to_face = piece.map(|v| v.bary);
        out[k - 1] = setup(s, inv_z, to_face, true, f, w, h);
    }
    out
}

/// Draws rows `rows` (absolute) of one triangle into a band starting at row `y_begin`.
#[allow(clippy::too_many_arguments)]
#[inline]
fn draw_rows(
    t: &TriSetup,
    rows: std::ops::Range<usize>,
    y_begin: usize,
    w: usize,
    ox: f64,
    oy: f64,
    depth: &mut [f32],
    face: &mut [u32],
    bary: &mut [[f32; 3]],
) {
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

/// Renders a textured mesh: per pixel, the perspective-correct texture coordinate of the
/// visible face, bilinearly sampled (texel `i` centred at `u = (i + 0.5) / width`: OpenGL's
/// texture convention, independent of [`PIXEL_CENTRE_OFFSET`]; clamped at the border), black
/// where no face is. `uvs`: [V] per-vertex texture coordinates in `[0, 1]`, OBJ/OpenGL
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
