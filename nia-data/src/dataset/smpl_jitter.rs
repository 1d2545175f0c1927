//! SMPL jitter: a training augmentation that moves the SMPL body a training scene hands the
//! network off the body its images show, as a fitted SMPL is off a real person
//! (`[data] smpl_jitter_m`, off by default; docs/robustness.md has what it measured).
//!
//! A network trained only on exact fits learns to put density where the SMPL-anchored features
//! are; given a fit a few centimetres off, it renders the fit, not the person. Moving the body
//! by a different random amount in every training scene makes the SMPL a hint whose error
//! varies, so the network has to find the surface in the source images (their pixel-aligned
//! features and masks) as well.
//!
//! The displacement of a vertex at `x` (metres), drawn per scene with amplitude `a` uniform in
//! `[0, max_m]`:
//! - a global translation, `a / 2` per axis (standard deviation);
//! - a rotation about the body's centre, `a / 2` radians per axis for a 1 m lever (so a point a
//!   metre from the centre moves by about `a / 2` more);
//! - a smooth field, [`WAVES`] plane waves `a / 2 * sin(k . x + phi)` along random directions
//!   with wavelengths 0.4-1.0 m, so limbs move against each other as joint errors move them.
//!
//! The mean vertex displacement is then about `1.1 a` (unit test). The translation is also
//! added to `Th`, so the params and the vertices agree on where the body is.

use glam::{Quat, Vec3};

use crate::body::SmplParams;
use crate::rng::Rng;

/// Plane waves of the smooth displacement field.
pub const WAVES: usize = 3;
/// Largest jitter amplitude accepted, metres.
pub const MAX_SMPL_JITTER_M: f32 = 0.2;

/// Moves `vertices` ([V] world metres) and `params` by a displacement drawn from `rng` with
/// amplitude uniform in `[0, max_m]` (module docs). `max_m <= 0` leaves both unchanged and draws
/// nothing.
pub fn jitter_smpl(vertices: &mut [Vec3], params: &mut SmplParams, max_m: f32, rng: &mut Rng) {
    if !(max_m > 0.0) || vertices.is_empty() {
        return;
    }
    let a = max_m * rng.uniform();
    let normal3 = |rng: &mut Rng| Vec3::new(rng.normal(), rng.normal(), rng.normal());
    let translation = normal3(rng) * (0.5 * a);
    let rotation = Quat::from_scaled_axis(normal3(rng) * (0.5 * a));
    let waves: Vec<(Vec3, f32, Vec3)> = (0..WAVES)
        .map(|_| {
            let k =
                normal3(rng).normalize_or(Vec3::Y) * std::f32::consts::TAU / rng.range(0.4, 1.0);
            let phase = rng.range(0.0, std::f32::consts::TAU);
            (k, phase, normal3(rng) * (0.5 * a / 3f32.sqrt()))
        })
        .collect();
    let centre = vertices.iter().copied().sum::<Vec3>() / vertices.len() as f32;
    for v in vertices.iter_mut() {
        let field: Vec3 = waves
            .iter()
            .map(|&(k, phase, amp)| amp * (k.dot(*v) + phase).sin())
            .sum();
        *v = centre + rotation * (*v - centre) + translation + field;
    }
    params.th += translation;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body() -> Vec<Vec3> {
        // A 1.7 m tall column, 30 cm wide, around (0, 0.9, 3): 40 rings of 100 points, each
        // ring's neighbours 9.4 mm apart.
        (0..4000)
            .map(|i| {
                let angle = (i % 100) as f32 * std::f32::consts::TAU / 100.0;
                let y = 0.05 + 1.7 * (i / 100) as f32 / 40.0;
                Vec3::new(0.15 * angle.cos(), y, 3.0 + 0.15 * angle.sin())
            })
            .collect()
    }

    fn params() -> SmplParams {
        SmplParams {
            poses: [0.0; 72],
            shapes: vec![0.0; 10],
            rh: Vec3::ZERO,
            th: Vec3::new(0.0, 0.0, 3.0),
        }
    }

    #[test]
    fn zero_amplitude_changes_nothing() {
        let mut v = body();
        let mut p = params();
        let mut rng = Rng::new(3);
        let before = rng.clone().uniform();
        jitter_smpl(&mut v, &mut p, 0.0, &mut rng);
        jitter_smpl(&mut v, &mut p, f32::NAN, &mut rng);
        assert_eq!(v, body());
        assert_eq!(p, params());
        assert_eq!(rng.uniform(), before, "nothing drawn");
    }

    /// Mean displacement about 1.1 a (a uniform in [0, max]: mean over scenes ~0.6 max), smooth
    /// over the body (neighbours on a ring move alike: independent per-point noise of this size
    /// would differ by ~4x their distance), finite, and Th moves with the body.
    #[test]
    fn displacement_has_the_stated_size_and_is_smooth() {
        let max = 0.04;
        let (mut mean, mut rough) = (0.0f32, 0.0f32);
        let scenes = 200;
        let rest = body();
        for s in 0..scenes {
            let mut v = rest.clone();
            let mut p = params();
            jitter_smpl(&mut v, &mut p, max, &mut Rng::new(s));
            let d: Vec<Vec3> = v.iter().zip(&rest).map(|(a, b)| *a - *b).collect();
            assert!(v.iter().all(|x| x.is_finite()));
            mean += d.iter().map(|x| x.length()).sum::<f32>() / d.len() as f32;
            for ring in 0..40 {
                for j in 0..99 {
                    let (i0, i1) = (100 * ring + j, 100 * ring + j + 1);
                    let apart = (rest[i0] - rest[i1]).length();
                    rough = rough.max((d[i0] - d[i1]).length() / apart);
                }
            }
            assert!((p.th - params().th).length() < 0.2);
        }
        let mean = mean / scenes as f32;
        assert!(
            (0.4 * max..1.0 * max).contains(&mean),
            "mean displacement {mean} m for max {max}"
        );
        assert!(rough < 1.0, "neighbours differ by {rough} x their distance");
    }
}
