//! The closest point of a triangle to a point (Ericson, Real-Time Collision Detection, 5.1.5:
//! by Voronoi region, with the barycentrics), and per-vertex values interpolated at a
//! [`Nearest`] point.

use glam::Vec3;

use super::Nearest;
use crate::geometry::raster::MeshError;

#[inline(always)]
fn ratio(num: f32, den: f32) -> f32 {
    if den > 0.0 {
        (num / den).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Closest point to `p` on segment `a b` and its parameter (0 at `a`).
#[inline]
fn closest_on_segment(p: Vec3, a: Vec3, b: Vec3) -> (Vec3, f32) {
    let ab = b - a;
    let t = ratio((p - a).dot(ab), ab.dot(ab));
    (a + ab * t, t)
}

/// Closest point to `p` on triangle `a b c` and its barycentrics `(u, v, w)` with
/// `point = u a + v b + w c` (Ericson's Voronoi-region tests). Degenerate triangles fall back
/// to the closest of their three edges.
#[inline]
pub fn closest_point_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> (Vec3, [f32; 3]) {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, [1.0, 0.0, 0.0]);
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, [0.0, 1.0, 0.0]);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = ratio(d1, d1 - d3);
        return (a + ab * v, [1.0 - v, v, 0.0]);
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, [0.0, 0.0, 1.0]);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = ratio(d2, d2 - d6);
        return (a + ac * w, [1.0 - w, 0.0, w]);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = ratio(d4 - d3, (d4 - d3) + (d5 - d6));
        return (b + (c - b) * w, [0.0, 1.0 - w, w]);
    }
    let sum = va + vb + vc;
    if sum > 0.0 {
        let v = vb / sum;
        let w = vc / sum;
        return (a + ab * v + ac * w, [1.0 - v - w, v, w]);
    }
    // Zero-area triangle: the answer lies on one of its edges.
    let (q0, t0) = closest_on_segment(p, a, b);
    let (q1, t1) = closest_on_segment(p, b, c);
    let (q2, t2) = closest_on_segment(p, c, a);
    let (e0, e1, e2) = (
        (q0 - p).length_squared(),
        (q1 - p).length_squared(),
        (q2 - p).length_squared(),
    );
    if e0 <= e1 && e0 <= e2 {
        (q0, [1.0 - t0, t0, 0.0])
    } else if e1 <= e2 {
        (q1, [0.0, 1.0 - t1, t1])
    } else {
        (q2, [t2, 0.0, 1.0 - t2])
    }
}

/// The face of `nearest` checked against `faces` and `len` per-vertex entries.
fn face_of(
    what: &'static str,
    nearest: &Nearest,
    faces: &[[u32; 3]],
    field: &'static str,
    len: usize,
) -> Result<[usize; 3], MeshError> {
    let f = faces.get(nearest.face as usize).ok_or(MeshError::Length {
        what,
        field: "faces",
        got: faces.len(),
        expected: nearest.face as usize + 1,
    })?;
    for (corner, &index) in f.iter().enumerate() {
        if index as usize >= len {
            return Err(MeshError::FaceIndex {
                what,
                field,
                face: nearest.face as usize,
                corner,
                index,
                len,
            });
        }
    }
    Ok(f.map(|i| i as usize))
}

/// Barycentric interpolation of a per-vertex scalar ([V], e.g. a view's 0/1 vertex
/// visibility, giving NIA's `o_n`) at the nearest point.
pub fn interpolate_scalar(
    nearest: &Nearest,
    faces: &[[u32; 3]],
    values: &[f32],
) -> Result<f32, MeshError> {
    let [i, j, k] = face_of("interpolate_scalar", nearest, faces, "values", values.len())?;
    let b = nearest.bary;
    Ok(values[i] * b[0] + values[j] * b[1] + values[k] * b[2])
}

/// Barycentric interpolation of per-vertex vectors of `k` values (`weights`: [V * k],
/// row-major, e.g. SMPL skinning weights with k = 24) into `out` ([k]); allocation-free.
pub fn interpolate_weights(
    nearest: &Nearest,
    faces: &[[u32; 3]],
    weights: &[f32],
    k: usize,
    out: &mut [f32],
) -> Result<(), MeshError> {
    const WHAT: &str = "interpolate_weights";
    if k == 0 || !weights.len().is_multiple_of(k) {
        return Err(MeshError::Invalid {
            what: WHAT,
            field: "weights",
            expected: "a [V * k] array with k > 0",
        });
    }
    if out.len() != k {
        return Err(MeshError::Length {
            what: WHAT,
            field: "out",
            got: out.len(),
            expected: k,
        });
    }
    let [i, j, l] = face_of(WHAT, nearest, faces, "weights", weights.len() / k)?;
    let b = nearest.bary;
    let (wi, wj, wl) = (
        &weights[i * k..(i + 1) * k],
        &weights[j * k..(j + 1) * k],
        &weights[l * k..(l + 1) * k],
    );
    for (c, o) in out.iter_mut().enumerate() {
        *o = wi[c] * b[0] + wj[c] * b[1] + wl[c] * b[2];
    }
    Ok(())
}
