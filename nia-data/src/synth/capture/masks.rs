//! Masks as a segmentation network gets them wrong. ZJU-MoCap's masks come from a human-parsing
//! network, not a renderer: their outlines are ragged and a few pixels off, hands and feet are
//! now and then lost, and background (a floor shadow, clutter next to the person) is now and
//! then taken for the person. Carving or supervising with masks must survive that.
//!
//! Magnitudes at level 1 (`zju_like`) in units of `r = radius_px` (the person's height / 20;
//! the pixels in brackets are for a 100 px tall person, r = 5 px):
//! - boundary jitter: a smooth displacement of the outline, two octaves of value noise with
//!   standard deviations 0.2 r (wavelength ~4 r) and 0.1 r (~1.5 r) [about 1 px, now and then
//!   2-3], as segmentation outlines wander by about 1 % of the person's height;
//! - erosion or dilation of the whole mask by up to 0.2 r [1 px]: a network's bias one way or
//!   the other per image, depending on the contrast with the background;
//! - 0 to 3 holes of radius 0.15-0.35 r inside the person: misclassified texture patches;
//! - probability 0.1: a missing hand or foot, a disk of radius 1.0-1.5 r (a hand is ~2 r long)
//!   erased around one of the caller's extremities;
//! - probability 0.1: a false foreground blob, an irregular ellipse of radii 0.5-1.5 r on the
//!   background within 2 r of the person.
//!
//! Level 2 doubles the displacements, hole sizes, hole counts and probabilities (a missing
//! hand keeps a hand's size). These are estimates from ZJU-MoCap's masks, not measurements.

use crate::rng::Rng;

/// Degrades `mask` ([H * W] u8, 255 = person, 0 = background, row-major, `width` x `height`)
/// in place at `level` (0: unchanged, exactly, drawing nothing; 1: the zju_like magnitudes of
/// the module doc; 2: twice), drawing from `rng`. `extremities` are the pixel positions of the
/// hands and feet in this view (those outside the image are skipped); `radius_px` scales every
/// pixel magnitude (the person's height in pixels / 20). Values >= 128 count as person; the
/// result is 0 or 255. A mask shorter than `width * height` is left unchanged.
pub fn degrade_mask(
    mask: &mut [u8],
    width: u32,
    height: u32,
    extremities: &[[f32; 2]],
    radius_px: f32,
    level: f32,
    rng: &mut Rng,
) {
    let (w, h) = (width as usize, height as usize);
    let n = w.checked_mul(h).unwrap_or(0);
    if !level.is_finite() || level <= 0.0 || n == 0 || mask.len() < n {
        return;
    }
    let r = radius_px.max(0.5).min(w.max(h) as f32); // NaN: 0.5
    let orig: Vec<bool> = mask[..n].iter().map(|&v| v >= 128).collect();
    let d_in = chamfer(&orig, w, h, false); // person pixels: distance to the background
    let d_out = chamfer(&orig, w, h, true); // background pixels: distance to the person

    // Boundary jitter and erosion/dilation: keep a pixel where its signed distance to the
    // outline plus a smooth displacement is positive.
    let coarse = Noise::new(w, h, 4.0 * r, rng);
    let fine = Noise::new(w, h, 1.5 * r, rng);
    let (a1, a2) = (0.2 * r * level, 0.1 * r * level);
    let bias = 0.2 * r * level * rng.range(-1.0, 1.0);
    let reach = bias.abs() + 4.0 * (a1 + a2) + 1.0;
    let mut out: Vec<u8> = orig.iter().map(|&o| 255 * o as u8).collect();
    for i in 0..n {
        let sd = [0.5 - d_out[i], d_in[i] - 0.5][orig[i] as usize]; // > 0 inside
        if sd.abs() <= reach {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            out[i] = 255 * (sd + bias + a1 * coarse.at(x, y) + a2 * fine.at(x, y) > 0.0) as u8;
        }
    }

    // Person bounding box, for the draws that need a person.
    let (mut x0, mut y0, mut x1, mut y1) = (w, h, 0, 0);
    for i in (0..n).filter(|&i| orig[i]) {
        (x0, y0, x1, y1) = (x0.min(i % w), y0.min(i / w), x1.max(i % w), y1.max(i / w));
    }
    if x0 <= x1 {
        // Holes strictly inside the person.
        let holes = rng.below((3.0 * level).round().clamp(0.0, 64.0) as usize + 1);
        for _ in 0..holes {
            let hr = r * level * rng.range(0.15, 0.35);
            if let Some(c) = pick(rng, (x0, y0, x1, y1), w, |i| orig[i] && d_in[i] > hr + 1.0) {
                ellipse(&mut out, w, c, (hr, hr), 0.0, None);
            }
        }
        // A missing hand or foot.
        if rng.uniform() < 0.1 * level {
            let ok =
                |p: &&[f32; 2]| p[0] >= 0.0 && p[1] >= 0.0 && p[0] < w as f32 && p[1] < h as f32;
            let inside: Vec<_> = extremities.iter().filter(ok).collect();
            let er = r * rng.range(1.0, 1.5);
            if !inside.is_empty() {
                let p = inside[rng.below(inside.len())];
                ellipse(&mut out, w, (p[0], p[1]), (er, er), 0.0, None);
            }
        }
        // A false foreground blob on the background near the person.
        if rng.uniform() < 0.1 * level {
            let radii = (r * rng.range(0.5, 1.5), r * rng.range(0.5, 1.5));
            let angle = rng.range(0.0, std::f32::consts::PI);
            let m = (2.0 * r).ceil() as usize + 1;
            let (bx, by) = (x0.saturating_sub(m), y0.saturating_sub(m));
            let bbox = (bx, by, (x1 + m).min(w - 1), (y1 + m).min(h - 1));
            if let Some(c) = pick(rng, bbox, w, |i| !orig[i] && d_out[i] <= 2.0 * r) {
                ellipse(&mut out, w, c, radii, angle, Some(&fine));
            }
        }
    }
    mask[..n].copy_from_slice(&out);
}

/// Two-pass chamfer distance (1, sqrt 2) from every pixel to the nearest pixel whose value is
/// `to`; pixels already equal to `to` get 0, and with none in the image every pixel gets 1e9.
fn chamfer(m: &[bool], w: usize, h: usize, to: bool) -> Vec<f32> {
    const D: f32 = std::f32::consts::SQRT_2;
    let mut d: Vec<f32> = m.iter().map(|&v| if v == to { 0.0 } else { 1e9 }).collect();
    // The neighbours before a pixel in raster order; the backward pass mirrors them.
    let before = [(-1, 0, 1.0), (-1, -1, D), (0, -1, 1.0), (1, -1, D)];
    for (pass, sign) in [(0, 1), (1, -1)] {
        for k in 0..w * h {
            let i = if pass == 0 { k } else { w * h - 1 - k };
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            for (dx, dy, cost) in before {
                let (nx, ny) = (x + sign * dx, y + sign * dy);
                if nx >= 0 && ny >= 0 && (nx as usize) < w && (ny as usize) < h {
                    d[i] = d[i].min(d[ny as usize * w + nx as usize] + cost);
                }
            }
        }
    }
    d
}

/// Smooth value noise of unit standard deviation at the grid nodes: normals on a grid of
/// `cell` px, interpolated with smoothstep weights.
struct Noise {
    cell: f32,
    gw: usize,
    values: Vec<f32>,
}

impl Noise {
    fn new(w: usize, h: usize, cell: f32, rng: &mut Rng) -> Self {
        let cell = cell.max(2.0);
        let gw = (w as f32 / cell) as usize + 2;
        let gh = (h as f32 / cell) as usize + 2;
        let values = (0..gw * gh).map(|_| rng.normal()).collect();
        Self { cell, gw, values }
    }

    fn at(&self, x: f32, y: f32) -> f32 {
        let (gx, gy) = ((x / self.cell).max(0.0), (y / self.cell).max(0.0));
        let gh = self.values.len() / self.gw;
        let (i, j) = ((gx as usize).min(self.gw - 2), (gy as usize).min(gh - 2));
        let s = |t: f32| t * t * (3.0 - 2.0 * t);
        let t = |g: f32, k: usize| s((g - k as f32).clamp(0.0, 1.0));
        let (tx, ty) = (t(gx, i), t(gy, j));
        let v = |a: usize, b: usize| self.values[b * self.gw + a];
        let top = v(i, j) * (1.0 - tx) + v(i + 1, j) * tx;
        let bottom = v(i, j + 1) * (1.0 - tx) + v(i + 1, j + 1) * tx;
        top * (1.0 - ty) + bottom * ty
    }
}

/// An inclusive pixel box `(x0, y0, x1, y1)`.
type Bbox = (usize, usize, usize, usize);

/// A random pixel of the box that satisfies `ok`, in at most 64 tries, as (x, y).
fn pick(rng: &mut Rng, b: Bbox, w: usize, ok: impl Fn(usize) -> bool) -> Option<(f32, f32)> {
    for _ in 0..64 {
        let x = b.0 + rng.below(b.2 - b.0 + 1);
        let y = b.1 + rng.below(b.3 - b.1 + 1);
        if ok(y * w + x) {
            return Some((x as f32, y as f32));
        }
    }
    None
}

/// Sets the pixels of an ellipse (radii `r`, rotated by `rot`) around `c`: to background when
/// `blob` is None, else to person, with the outline made irregular by `blob`.
fn ellipse(m: &mut [u8], w: usize, c: (f32, f32), r: (f32, f32), rot: f32, blob: Option<&Noise>) {
    let (ra, rb, h) = (r.0.max(0.5), r.1.max(0.5), m.len() / w);
    let e = ra.max(rb).ceil() + 1.0;
    let (cos, sin) = (rot.cos(), rot.sin());
    let xs = (c.0 - e).max(0.0) as usize..=((c.0 + e).max(0.0) as usize).min(w - 1);
    for y in (c.1 - e).max(0.0) as usize..=((c.1 + e).max(0.0) as usize).min(h - 1) {
        for x in xs.clone() {
            let (dx, dy) = (x as f32 - c.0, y as f32 - c.1);
            let (u, v) = ((cos * dx + sin * dy) / ra, (cos * dy - sin * dx) / rb);
            let limit = blob.map_or(1.0, |nz| (1.0 + 0.3 * nz.at(x as f32, y as f32)).max(0.0));
            if u * u + v * v <= limit * limit {
                m[y * w + x] = 255 * blob.is_some() as u8;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disk_mask(w: usize, cx: f32, cy: f32, radius: f32) -> Vec<u8> {
        let inside = |i: usize| ((i % w) as f32 - cx).hypot((i / w) as f32 - cy) <= radius;
        (0..w * w).map(|i| 255 * inside(i) as u8).collect()
    }

    #[test]
    fn level_zero_is_unchanged_and_draws_nothing() {
        let (orig, mut rng) = (disk_mask(64, 30.0, 20.0, 15.0), Rng::new(4));
        let (mut m, mut untouched) = (orig.clone(), rng.clone());
        degrade_mask(&mut m, 64, 64, &[[30.0, 5.0]], 2.0, 0.0, &mut rng);
        assert_eq!(m, orig);
        assert_eq!(rng.next_u64(), untouched.next_u64());
    }

    #[test]
    fn level_one_damages_little_and_mostly_near_the_boundary() {
        let orig = disk_mask(128, 64.0, 64.0, 40.0);
        let root = Rng::new(21);
        for seed in 0..20 {
            let mut m = orig.clone();
            degrade_mask(&mut m, 128, 128, &[], 4.0, 1.0, &mut root.fork(seed));
            assert!(m.iter().all(|&v| v == 0 || v == 255));
            let (mut inter, mut union, mut changed, mut far) = (0, 0, 0, 0);
            for (i, (&a, &b)) in orig.iter().zip(&m).enumerate() {
                let d = ((i % 128) as f32 - 64.0).hypot((i / 128) as f32 - 64.0);
                inter += (a & b) as usize / 255;
                union += (a | b) as usize / 255;
                changed += (a != b) as usize;
                far += (a != b && (d - 40.0).abs() > 16.0) as usize; // 4 radius_px off
            }
            let iou = inter as f32 / union as f32;
            assert!(iou > 0.85, "seed {seed}: IoU {iou}");
            assert!(changed > 0 && changed < 1365, "seed {seed}: {changed}"); // < 1 / 12
            assert!(far * 10 <= changed, "seed {seed}: {far} far");
        }
        let (mut a, mut b) = (orig.clone(), orig.clone());
        degrade_mask(&mut a, 128, 128, &[], 4.0, 1.0, &mut root.fork(3));
        degrade_mask(&mut b, 128, 128, &[], 4.0, 1.0, &mut root.fork(3));
        assert_eq!(a, b);
    }

    #[test]
    fn a_missing_extremity_is_erased_now_and_then() {
        // A body disk with an arm reaching to a 10 x 10 hand centred on (105, 35).
        let mut orig = disk_mask(128, 64.0, 70.0, 30.0);
        for (i, v) in orig.iter_mut().enumerate() {
            let (x, y) = (i % 128, i / 128);
            let hand = (100..110).contains(&x) && (30..40).contains(&y);
            let arm = (80..105).contains(&x) && (33..37).contains(&y);
            *v |= 255 * (hand || arm || (80..84).contains(&x) && (33..50).contains(&y)) as u8;
        }
        let extremities = [[-10.0, 5.0], [105.0, 35.0], [500.0, 500.0], [f32::NAN, 3.0]];
        // Pixels within 3.5 px of the hand's centre: inside any erased disk (radius >= 4 px).
        let hand = disk_mask(128, 105.0, 35.0, 3.5);
        let near = |m: &[u8]| m.iter().zip(&hand).filter(|p| *p.0 & *p.1 == 255).count();
        let (total, root, mut erased) = (near(&orig), Rng::new(8), 0);
        for seed in 0..100 {
            let mut m = orig.clone();
            let rng = &mut root.fork(seed);
            degrade_mask(&mut m, 128, 128, &extremities, 4.0, 1.0, rng);
            match near(&m) {
                0 => erased += 1,
                k => assert!(k * 10 >= total * 9, "seed {seed}: {k} of {total} left"),
            }
        }
        assert!((2..=30).contains(&erased), "hand erased in {erased} of 100");
    }

    #[test]
    fn degenerate_inputs_do_not_panic() {
        let far = [[-1.0, -1.0], [1e9, 3.0], [f32::NAN, f32::INFINITY]];
        let levels = [1.0, 2.0, 1e6].map(|l| [0.0, 4.0, f32::NAN, 1e9].map(|r| (l, r)));
        for (level, r) in levels.into_iter().flatten() {
            for (w, h) in [(1u32, 1u32), (0, 0), (0, 7), (1, 9), (9, 1), (3, 3)] {
                for fill in [0, 255] {
                    let mut m = vec![fill; (w * h) as usize];
                    degrade_mask(&mut m, w, h, &far, r, level, &mut Rng::new(1));
                }
            }
            let mut short = vec![255u8; 5];
            degrade_mask(&mut short, 4, 4, &far, r, level, &mut Rng::new(1));
            assert_eq!(short, vec![255u8; 5]);
        }
        let mut empty = vec![0u8; 64 * 64];
        degrade_mask(
            &mut empty,
            64,
            64,
            &[[9.0, 9.0]],
            3.0,
            2.0,
            &mut Rng::new(2),
        );
        assert!(empty.iter().all(|&v| v == 0));
    }
}
