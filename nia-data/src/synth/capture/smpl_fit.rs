//! The SMPL fit a capture writes is not the body its images show. ZJU-MoCap's `params/` come
//! from EasyMocap fitting SMPL to multi-view 2D keypoints: joint rotations off by a few degrees
//! (worst at the wrists, ankles and head, whose keypoints are few and noisy), a global
//! placement off by a centimetre or two, and one shape per subject that does not match the
//! clothed person. A fit jitters slowly, not per frame: the errors here are smooth in time,
//! drawn at knots [`KNOT_SECONDS`] apart and blended with a cosine between them.
//!
//! Level-1 magnitudes (standard deviations), scaled linearly with the level:
//! - [`JOINT_DEG`] per axis for the body's joints, [`EXTREMITY_DEG`] for wrists, hands, ankles,
//!   feet and head;
//! - [`GLOBAL_DEG`] per axis of the global rotation `Rh`, [`GLOBAL_CM`] per axis of `Th`;
//! - [`BETA_STD`] per shape coefficient, fixed per subject.

use glam::{Quat, Vec3};

use crate::body::SmplParams;
use crate::rng::Rng;

/// Seconds between the knots of the slowly varying errors.
pub const KNOT_SECONDS: f32 = 0.5;
/// Joint rotation error of the body's joints at level 1, degrees per axis.
pub const JOINT_DEG: f32 = 2.0;
/// Joint rotation error of the extremities and head at level 1, degrees per axis.
pub const EXTREMITY_DEG: f32 = 5.0;
/// Global rotation error at level 1, degrees per axis.
pub const GLOBAL_DEG: f32 = 1.0;
/// Global translation error at level 1, centimetres per axis.
pub const GLOBAL_CM: f32 = 1.0;
/// Shape coefficient error at level 1 (betas are in standard deviations of the shape space).
pub const BETA_STD: f32 = 0.2;
/// SMPL joints whose fit is worst: neck, head, ankles, feet, wrists, hands.
const EXTREMITIES: [usize; 9] = [7, 8, 10, 11, 12, 15, 20, 21, 22];

/// One subject's fit error over its frames.
#[derive(Debug, Clone, PartialEq)]
pub struct SmplFitError {
    /// The level it was drawn at; 0 writes the true fit unchanged.
    level: f32,
    /// Frames per second of the capture (knot spacing in frames).
    fps: f32,
    /// `[knots][25]` rotation errors (axis-angle, radians): joints 1..24, then the global one.
    rotations: Vec<[Vec3; 25]>,
    /// `[knots]` translation errors, metres.
    translations: Vec<Vec3>,
    /// `[S]` shape errors.
    betas: Vec<f32>,
}

impl SmplFitError {
    /// The errors of a subject with `frames` frames at `fps`, with `shapes` shape coefficients,
    /// drawn from `rng` at `level` (module docs).
    pub fn draw(level: f32, frames: usize, fps: f32, shapes: usize, rng: &mut Rng) -> Self {
        let knots = ((frames.max(1) as f32 - 1.0) / (KNOT_SECONDS * fps)).ceil() as usize + 2;
        let rad = |deg: f32| deg.to_radians() * level;
        let mut noise = |std: f32| Vec3::new(rng.normal(), rng.normal(), rng.normal()) * std;
        let mut rotations = Vec::with_capacity(knots);
        let mut translations = Vec::with_capacity(knots);
        for _ in 0..knots {
            let mut knot = [Vec3::ZERO; 25];
            for (j, r) in knot.iter_mut().enumerate().take(24).skip(1) {
                let deg = if EXTREMITIES.contains(&j) {
                    EXTREMITY_DEG
                } else {
                    JOINT_DEG
                };
                *r = noise(rad(deg));
            }
            knot[24] = noise(rad(GLOBAL_DEG));
            rotations.push(knot);
            translations.push(noise(0.01 * GLOBAL_CM * level));
        }
        let betas = (0..shapes)
            .map(|_| rng.normal() * BETA_STD * level)
            .collect();
        SmplFitError {
            level,
            fps,
            rotations,
            translations,
            betas,
        }
    }

    /// The knots around `frame` and the cosine blend weight of the later one.
    fn at(&self, frame: usize) -> (usize, usize, f32) {
        let u = frame as f32 / (KNOT_SECONDS * self.fps);
        let last = self.rotations.len() - 1;
        let k = (u.floor() as usize).min(last);
        let t = (u - k as f32).clamp(0.0, 1.0);
        (
            k,
            (k + 1).min(last),
            0.5 - 0.5 * (std::f32::consts::PI * t).cos(),
        )
    }

    /// `params` (the rendered body's) as the capture's fit writes them at `frame`: every joint
    /// rotation and the global rotation composed with its error, the translation and the shape
    /// offset. Joint 0 keeps its zeros (ZJU-MoCap puts the root orientation in `Rh`).
    pub fn perturb(&self, frame: usize, params: &SmplParams) -> SmplParams {
        if self.level == 0.0 {
            return params.clone();
        }
        let (a, b, w) = self.at(frame);
        let error = |j: usize| self.rotations[a][j].lerp(self.rotations[b][j], w);
        let compose = |aa: Vec3, e: Vec3| {
            (Quat::from_scaled_axis(aa) * Quat::from_scaled_axis(e)).to_scaled_axis()
        };
        let mut poses = params.poses;
        for j in 1..24 {
            let aa = Vec3::from_slice(&poses[3 * j..3 * j + 3]);
            poses[3 * j..3 * j + 3].copy_from_slice(&compose(aa, error(j)).to_array());
        }
        let shapes = params
            .shapes
            .iter()
            .zip(self.betas.iter().chain(std::iter::repeat(&0.0)))
            .map(|(s, e)| s + e)
            .collect();
        SmplParams {
            poses,
            shapes,
            rh: compose(params.rh, error(24)),
            th: params.th + self.translations[a].lerp(self.translations[b], w),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> SmplParams {
        let mut poses = [0.0; 72];
        poses[3 * 18 + 2] = 0.7;
        SmplParams {
            poses,
            shapes: vec![0.5; 10],
            rh: Vec3::new(0.0, 1.0, 0.0),
            th: Vec3::new(0.1, 0.0, 2.0),
        }
    }

    #[test]
    fn level_zero_writes_the_true_fit() {
        let e = SmplFitError::draw(0.0, 30, 10.0, 10, &mut Rng::new(1));
        for frame in [0, 7, 29] {
            assert_eq!(e.perturb(frame, &params()), params());
        }
    }

    /// At level 1 the errors have the stated size, the root stays zero, and neighbouring frames
    /// differ far less than frames a second apart (a slow jitter).
    #[test]
    fn errors_are_the_stated_size_and_smooth_in_time() {
        let e = SmplFitError::draw(1.0, 200, 10.0, 10, &mut Rng::new(2));
        let p0 = params();
        let angle = |p: &SmplParams, j: usize| {
            let q = Quat::from_scaled_axis(Vec3::from_slice(&p.poses[3 * j..3 * j + 3]));
            let t = Quat::from_scaled_axis(Vec3::from_slice(&p0.poses[3 * j..3 * j + 3]));
            q.angle_between(t).to_degrees()
        };
        let (mut sum, mut n, mut step, mut far) = (0.0, 0, 0.0f32, 0.0f32);
        for frame in 0..190 {
            let p = e.perturb(frame, &p0);
            let next = e.perturb(frame + 1, &p0);
            let later = e.perturb(frame + 10, &p0);
            assert_eq!(&p.poses[0..3], &[0.0; 3]);
            for j in (1..24).filter(|j| !EXTREMITIES.contains(j)) {
                sum += angle(&p, j);
                n += 1;
                let q = |a: &SmplParams| {
                    Quat::from_scaled_axis(Vec3::from_slice(&a.poses[3 * j..3 * j + 3]))
                };
                step = step.max(q(&p).angle_between(q(&next)).to_degrees());
                far = far.max(q(&p).angle_between(q(&later)).to_degrees());
            }
        }
        // The angle of a 3-axis Gaussian of sigma s has mean s * sqrt(8 / pi) ~ 1.6 s.
        let mean = sum / n as f32;
        assert!(
            (0.8 * 1.6 * JOINT_DEG..1.2 * 1.6 * JOINT_DEG).contains(&mean),
            "{mean}"
        );
        assert!(
            step < 0.5 * far,
            "frame to frame {step} deg against {far} a second apart"
        );
        let p = e.perturb(50, &p0);
        let dt = (p.th - p0.th).length() * 100.0;
        assert!(dt > 0.0 && dt < 6.0 * GLOBAL_CM, "{dt} cm");
        assert!(p.shapes.iter().zip(&p0.shapes).any(|(a, b)| a != b));
    }
}
