//! The Euclidean distance transform of a binary mask and its boundary pixels: what silhouette
//! terms read (the SMPL fitter's in nia-model, the loader's SMPL alignment).
//!
//! [`distance_to_mask`] is exact (Felzenszwalb and Huttenlocher's lower envelope of parabolas,
//! a column pass then a row pass), O(W H).

/// Squared distance standing for "no mask pixel on this line" in the 1D transform.
const FAR: f32 = 1e20;

/// Felzenszwalb and Huttenlocher's 1D squared distance transform of `f` (lower envelope of
/// parabolas), in place. `v`, `z` and `out` are scratch of `f.len()`, `f.len() + 1` and
/// `f.len()` values.
fn edt_1d(f: &mut [f32], v: &mut [usize], z: &mut [f32], out: &mut [f32]) {
    let n = f.len();
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f32::NEG_INFINITY;
    z[1] = f32::INFINITY;
    for q in 1..n {
        loop {
            let p = v[k];
            let s = ((f[q] + (q * q) as f32) - (f[p] + (p * p) as f32)) / (2.0 * (q - p) as f32);
            if s <= z[k] && k > 0 {
                k -= 1;
            } else {
                k += 1;
                v[k] = q;
                z[k] = s;
                z[k + 1] = f32::INFINITY;
                break;
            }
        }
    }
    k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while z[k + 1] < q as f32 {
            k += 1;
        }
        let p = v[k];
        let d = q as f32 - p as f32;
        *o = d * d + f[p];
    }
    f.copy_from_slice(out);
}

/// `[H * W]` row-major Euclidean distance (pixels) from each pixel of the `width` x `height`
/// image to the nearest pixel where `inside` is true (0 on those). With no such pixel every
/// value is about 1e10 (the square root of the transform's "far").
pub fn distance_to_mask(width: usize, height: usize, inside: impl Fn(usize) -> bool) -> Vec<f32> {
    let (w, h) = (width, height);
    let mut d: Vec<f32> = (0..w * h)
        .map(|i| if inside(i) { 0.0 } else { FAR })
        .collect();
    let n = w.max(h);
    if n == 0 {
        return d;
    }
    let (mut v, mut z, mut out, mut line) = (
        vec![0usize; n],
        vec![0.0f32; n + 1],
        vec![0.0f32; n],
        vec![0.0f32; n],
    );
    for x in 0..w {
        for y in 0..h {
            line[y] = d[y * w + x];
        }
        edt_1d(&mut line[..h], &mut v, &mut z, &mut out[..h]);
        for y in 0..h {
            d[y * w + x] = line[y];
        }
    }
    for y in 0..h {
        let row = &mut d[y * w..(y + 1) * w];
        line[..w].copy_from_slice(row);
        edt_1d(&mut line[..w], &mut v, &mut z, &mut out[..w]);
        row.copy_from_slice(&line[..w]);
    }
    d.iter().map(|&s| s.min(FAR).sqrt()).collect()
}

/// The pixels `(x, y)` of the `w` x `h` region `inside` that border a pixel outside it (or the
/// picture's edge), row by row.
pub fn boundary_pixels(
    w: usize,
    h: usize,
    inside: impl Fn(usize, usize) -> bool,
) -> impl Iterator<Item = (usize, usize)> {
    (0..h)
        .flat_map(move |y| (0..w).map(move |x| (x, y)))
        .filter(move |&(x, y)| {
            inside(x, y)
                && (x == 0
                    || y == 0
                    || x + 1 == w
                    || y + 1 == h
                    || !inside(x - 1, y)
                    || !inside(x + 1, y)
                    || !inside(x, y - 1)
                    || !inside(x, y + 1))
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact transform's values are square roots of integers; f32 keeps ~1e-6 relative.
    const EDT_TOL: f32 = 1e-4;

    #[test]
    fn distance_is_euclidean_to_the_nearest_mask_pixel() {
        let (w, h) = (9usize, 7usize);
        let mut mask = vec![false; w * h];
        mask[3 * 9 + 4] = true;
        mask[9 + 7] = true;
        let d = distance_to_mask(w, h, |i| mask[i]);
        for y in 0..h {
            for x in 0..w {
                let a = ((x as f32 - 4.0).powi(2) + (y as f32 - 3.0).powi(2)).sqrt();
                let b = ((x as f32 - 7.0).powi(2) + (y as f32 - 1.0).powi(2)).sqrt();
                let got = d[y * w + x];
                assert!((got - a.min(b)).abs() < EDT_TOL, "({x}, {y}): {got}");
            }
        }
        let boundary: Vec<_> = boundary_pixels(w, h, |x, y| mask[y * w + x]).collect();
        assert_eq!(boundary, vec![(7, 1), (4, 3)]);
    }

    #[test]
    fn an_empty_mask_is_far_everywhere() {
        let d = distance_to_mask(4, 3, |_| false);
        assert!(d.iter().all(|&v| v > 1e9 && v.is_finite()));
    }
}
