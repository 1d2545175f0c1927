//! The extrinsics a capture writes are not exactly the cameras that took the images: each
//! written camera is turned about its own centre by a small rotation and its centre moved a
//! few millimetres, fixed per camera (a calibration is done once per session). At level 1
//! ([`ROTATION_DEG`], [`TRANSLATION_MM`] per axis, standard deviations) a point 3 m away moves
//! by about one to two pixels at ZJU-MoCap's 1024 px, the reprojection error of a good
//! calibration.

use glam::{Mat3, Vec3};

use crate::geometry::camera::Camera;
use crate::rng::Rng;

/// Rotation error at level 1, degrees per axis.
pub const ROTATION_DEG: f32 = 0.1;
/// Camera centre error at level 1, millimetres per axis.
pub const TRANSLATION_MM: f32 = 4.0;

/// `camera` as a calibration at `level` writes it, drawn from `rng`; level 0 returns it
/// unchanged without drawing.
pub fn miscalibrate(camera: &Camera, level: f32, rng: &mut Rng) -> Camera {
    if level == 0.0 {
        return *camera;
    }
    let mut axis = || Vec3::new(rng.normal(), rng.normal(), rng.normal());
    let turn = Mat3::from_axis_angle_scaled(axis() * ROTATION_DEG.to_radians() * level);
    let moved = axis() * TRANSLATION_MM * 1e-3 * level;
    let centre = camera.centre() + moved;
    let r = turn * camera.r;
    Camera {
        r,
        t: -(r * centre),
        ..*camera
    }
}

/// `Mat3::from_axis_angle` of an axis-angle vector (identity for zero).
trait FromScaledAxis {
    fn from_axis_angle_scaled(v: Vec3) -> Mat3;
}

impl FromScaledAxis for Mat3 {
    fn from_axis_angle_scaled(v: Vec3) -> Mat3 {
        let angle = v.length();
        if angle == 0.0 {
            Mat3::IDENTITY
        } else {
            Mat3::from_axis_angle(v / angle, angle)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        let r = Mat3::IDENTITY;
        Camera {
            k: Mat3::from_cols(
                Vec3::new(1000.0, 0.0, 0.0),
                Vec3::new(0.0, 1000.0, 0.0),
                Vec3::new(512.0, 512.0, 1.0),
            ),
            r,
            t: Vec3::new(0.0, 0.0, 3.0),
            dist: [0.0; 5],
            width: 1024,
            height: 1024,
        }
    }

    #[test]
    fn level_zero_is_the_camera_and_level_one_moves_points_a_pixel_or_two() {
        let c = camera();
        assert_eq!(miscalibrate(&c, 0.0, &mut Rng::new(3)), c);
        let p = Vec3::new(0.2, -0.3, 0.0);
        let (uv, _) = c.project(p).unwrap();
        let mut shifts = Vec::new();
        for seed in 0..200 {
            let m = miscalibrate(&c, 1.0, &mut Rng::new(seed));
            assert_eq!((m.k, m.dist, m.width), (c.k, c.dist, c.width));
            // Still a rotation.
            assert!((m.r * m.r.transpose()).abs_diff_eq(Mat3::IDENTITY, 1e-5));
            let (uv2, _) = m.project(p).unwrap();
            shifts.push((uv2 - uv).length());
        }
        let mean = shifts.iter().sum::<f32>() / shifts.len() as f32;
        assert!(
            (0.5..3.0).contains(&mean),
            "mean reprojection shift {mean} px"
        );
    }
}
