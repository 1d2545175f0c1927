//! Per-camera colour response: the 23 ZJU-MoCap cameras differ visibly in colour, because each
//! camera has its own exposure, white balance and tone curve, and its lens darkens the corners.
//! A method that compares pixel colours across views (image-based rendering, colour losses) must
//! survive that, so the generator can give every camera its own fixed response.
//!
//! The response is applied in linear light: decode sRGB, multiply by
//! `gain * white_balance[c] * vignetting(x, y)`, raise to `gamma`, re-encode, clamp and round.
//! Black pixels (the background outside the person) stay black, so the masks stay valid.
//!
//! Magnitudes at level 1 (`zju_like`); level 2 doubles every deviation from identity:
//! - gain 1 +- 0.15 (+-15 % exposure, about +-0.2 stop: unsynchronised auto exposure of a rig);
//! - white balance 1 +- 0.06 per channel (a few hundred kelvin of white-balance error, the
//!   visible green/magenta and warm/cool casts between ZJU-MoCap views);
//! - gamma 1 +- 0.08 (camera tone curves differ slightly even between units of one model);
//! - vignetting up to 12 % darker in the corners (typical of C-mount machine-vision lenses
//!   at an open aperture, a quadratic fall-off with the distance from the image centre).
//!
//! These are estimates of what is visible in ZJU-MoCap frames, not measured calibrations.

use crate::rng::Rng;

/// Level-1 half-width of the exposure gain around 1.
const GAIN: f32 = 0.15;
/// Level-1 half-width of each white-balance gain around 1.
const WHITE_BALANCE: f32 = 0.06;
/// Level-1 half-width of the gamma around 1.
const GAMMA: f32 = 0.08;
/// Level-1 maximum corner darkening.
const VIGNETTING: f32 = 0.12;

/// One camera's colour response: exposure gain, white balance (per-channel gains), gamma and
/// vignetting (radial fall-off towards the corners), fixed per camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColourResponse {
    /// Exposure gain on linear light.
    pub gain: f32,
    /// Per-channel (R, G, B) gains on linear light.
    pub white_balance: [f32; 3],
    /// Exponent on linear light after the gains (1: none; > 1 darkens the mid-tones).
    pub gamma: f32,
    /// Fraction by which the corners are darkened (0: none); the fall-off is quadratic in the
    /// distance from the image centre, 1 at the corners.
    pub vignetting: f32,
}

impl ColourResponse {
    /// The identity response (level 0).
    pub fn identity() -> Self {
        Self {
            gain: 1.0,
            white_balance: [1.0; 3],
            gamma: 1.0,
            vignetting: 0.0,
        }
    }

    /// One camera's response drawn from `rng` at `level` (0: identity, exactly, drawing
    /// nothing; 1: the zju_like magnitudes of the module doc; 2: twice as far from identity).
    pub fn draw(level: f32, rng: &mut Rng) -> Self {
        if !level.is_finite() || level <= 0.0 {
            return Self::identity();
        }
        let mut sym = |half: f32| level * half * rng.range(-1.0, 1.0);
        let gain = (1.0 + sym(GAIN)).max(0.05);
        let white_balance = [
            (1.0 + sym(WHITE_BALANCE)).max(0.05),
            (1.0 + sym(WHITE_BALANCE)).max(0.05),
            (1.0 + sym(WHITE_BALANCE)).max(0.05),
        ];
        let gamma = (1.0 + sym(GAMMA)).max(0.1);
        let vignetting = (level * VIGNETTING * rng.uniform()).min(0.95);
        Self {
            gain,
            white_balance,
            gamma,
            vignetting,
        }
    }

    pub fn is_identity(&self) -> bool {
        *self == Self::identity()
    }

    /// Applies the response in place to an sRGB image `rgb` ([H * W * 3] u8, row-major) of
    /// `width` x `height`, in linear light. The identity leaves every byte unchanged; pixels
    /// that are 0 in all channels stay 0. A buffer shorter than `H * W * 3` is processed up to
    /// its last whole pixel; nothing panics.
    pub fn apply(&self, rgb: &mut [u8], width: u32, height: u32) {
        if self.is_identity() || width == 0 || height == 0 {
            return;
        }
        let (w, h) = (width as usize, height as usize);
        let decode: [f32; 256] = std::array::from_fn(|i| srgb_to_linear(i as f32 / 255.0));
        let gamma = self.gamma;
        // encode(y) with y = x^gamma: the power branch is 1.055 x^(gamma / 2.4) - 0.055, taken
        // where y > 0.0031308, i.e. x > 0.0031308^(1 / gamma); one powf per channel.
        let threshold = 0.003_130_8f32.powf(1.0 / gamma);
        let exponent = gamma / 2.4;
        let scale = [0, 1, 2].map(|c| self.gain * self.white_balance[c]);
        let (cx, cy) = ((w as f32 - 1.0) * 0.5, (h as f32 - 1.0) * 0.5);
        let inv_r2 = 1.0 / (cx * cx + cy * cy).max(1e-12);
        for (i, px) in rgb
            .chunks_exact_mut(3)
            .take(w.saturating_mul(h))
            .enumerate()
        {
            if px[0] == 0 && px[1] == 0 && px[2] == 0 {
                continue;
            }
            let (dx, dy) = ((i % w) as f32 - cx, (i / w) as f32 - cy);
            let vig = 1.0 - self.vignetting * ((dx * dx + dy * dy) * inv_r2).min(1.0);
            for c in 0..3 {
                let x = (decode[px[c] as usize] * scale[c] * vig).clamp(0.0, 1.0);
                let s = if x > threshold {
                    1.055 * x.powf(exponent) - 0.055
                } else {
                    12.92 * x.powf(gamma)
                };
                px[c] = (s * 255.0).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
}

fn srgb_to_linear(s: f32) -> f32 {
    if s <= 0.04045 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_image(w: usize, h: usize) -> Vec<u8> {
        let mut rng = Rng::new(3);
        let mut img: Vec<u8> = (0..w * h * 3).map(|_| rng.below(256) as u8).collect();
        // Black background in the left third.
        for y in 0..h {
            for x in 0..w / 3 {
                img[(y * w + x) * 3..(y * w + x) * 3 + 3].fill(0);
            }
        }
        img
    }

    #[test]
    fn level_zero_is_identity_and_draws_nothing() {
        let mut rng = Rng::new(1);
        let mut untouched = rng.clone();
        let r = ColourResponse::draw(0.0, &mut rng);
        assert!(r.is_identity());
        assert_eq!(rng.next_u64(), untouched.next_u64());
        let orig = test_image(17, 9);
        let mut img = orig.clone();
        r.apply(&mut img, 17, 9);
        assert_eq!(img, orig);
    }

    #[test]
    fn level_one_changes_colours_keeps_black_and_stays_in_range() {
        let root = Rng::new(5);
        for cam in 0..23 {
            let r = ColourResponse::draw(1.0, &mut root.fork(cam));
            assert!(!r.is_identity());
            assert!((1.0 - GAIN..=1.0 + GAIN).contains(&r.gain));
            for g in r.white_balance {
                assert!((1.0 - WHITE_BALANCE..=1.0 + WHITE_BALANCE).contains(&g));
            }
            assert!((1.0 - GAMMA..=1.0 + GAMMA).contains(&r.gamma));
            assert!((0.0..=VIGNETTING).contains(&r.vignetting));
            let (w, h) = (30, 20);
            let orig = test_image(w, h);
            let mut img = orig.clone();
            r.apply(&mut img, w as u32, h as u32);
            let changed = img.iter().zip(&orig).filter(|(a, b)| a != b).count();
            assert!(
                changed > orig.len() / 4,
                "camera {cam}: only {changed} bytes changed"
            );
            for (p, q) in img.chunks(3).zip(orig.chunks(3)) {
                if q == [0, 0, 0] {
                    assert_eq!(p, [0, 0, 0]);
                }
                for c in 0..3 {
                    // Within the level-2 envelope of a mid-tone change: no wild values.
                    assert!((p[c] as i32 - q[c] as i32).abs() <= 60, "{p:?} from {q:?}");
                }
            }
        }
    }

    #[test]
    fn cameras_from_different_forks_differ() {
        let root = Rng::new(11);
        let a = ColourResponse::draw(1.0, &mut root.fork(0));
        let b = ColourResponse::draw(1.0, &mut root.fork(1));
        assert_ne!(a, b);
        assert_eq!(a, ColourResponse::draw(1.0, &mut root.fork(0)));
        // Level 2 is twice as far from identity as level 1 for the same draws.
        let c = ColourResponse::draw(2.0, &mut root.fork(0));
        assert!(((c.gain - 1.0) - 2.0 * (a.gain - 1.0)).abs() < 1e-5);
        assert!((c.vignetting - 2.0 * a.vignetting).abs() < 1e-5);
    }

    #[test]
    fn vignetting_darkens_corners_more_than_centre() {
        let r = ColourResponse {
            vignetting: VIGNETTING,
            ..ColourResponse::identity()
        };
        let (w, h) = (41usize, 31usize);
        let mut img = vec![180u8; w * h * 3];
        r.apply(&mut img, w as u32, h as u32);
        let at = |x: usize, y: usize| img[(y * w + x) * 3];
        assert_eq!(at(20, 15), 180);
        for (x, y) in [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)] {
            assert!(at(x, y) < 175, "corner ({x}, {y}) = {}", at(x, y));
        }
        assert!(at(0, 0) < at(10, 8) && at(10, 8) < at(20, 15));
    }

    #[test]
    fn degenerate_sizes_do_not_panic() {
        let r = ColourResponse::draw(2.0, &mut Rng::new(9));
        for (w, h, len) in [
            (1, 1, 3),
            (0, 0, 0),
            (0, 5, 6),
            (4, 4, 7),
            (1, 1, 0),
            (2, 1, 6),
        ] {
            let mut img = vec![128u8; len];
            r.apply(&mut img, w, h);
        }
        let mut huge = ColourResponse::draw(1e9, &mut Rng::new(9));
        huge.apply(&mut [200, 10, 0], 1, 1);
        huge = ColourResponse::draw(f32::NAN, &mut Rng::new(9));
        assert!(huge.is_identity());
    }
}
