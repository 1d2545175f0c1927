//! The capture rig: a ring of cameras around the subject, as in ZJU-MoCap (world z up).

use crate::geometry::camera::{Camera, CameraError};
use crate::rng::Rng;
use glam::Vec3;
use std::f32::consts::TAU;

/// Ring radius range (camera distance from the body's vertical axis), metres.
pub const RING_RADIUS_M: (f32, f32) = (2.5, 3.0);
/// Camera height relative to the body centre, metres (slightly varied, mostly above).
pub const HEIGHT_OFFSET_M: (f32, f32) = (-0.15, 0.35);
/// Azimuth jitter as a fraction of the spacing between neighbouring cameras.
pub const AZIMUTH_JITTER: f32 = 0.15;
/// Fraction of the image height the standing body fills.
pub const BODY_FILL: f32 = 0.7;
/// Principal point jitter as a fraction of the image size (real calibrations are off-centre).
pub const PRINCIPAL_JITTER: f32 = 0.01;

/// What the ring is built around.
#[derive(Debug, Clone, Copy)]
pub struct RingSpec {
    /// Number of cameras.
    pub count: usize,
    /// Square image size, pixels.
    pub size: u32,
    /// World point the cameras look at (the body centre), metres.
    pub centre: Vec3,
    /// Standing body height, metres (sets the focal length so the body fills [`BODY_FILL`]).
    pub body_height_m: f32,
}

/// `count` cameras on a ring around `centre` (world z up), ordered by azimuth, each looking at
/// the centre from 2.5-3 m at a slightly different height, with `fx = fy` chosen so the body
/// fills about 70% of the image height, principal point near the image centre and `D = 0`.
pub fn camera_ring(spec: &RingSpec, rng: &mut Rng) -> Result<Vec<Camera>, CameraError> {
    let n = spec.count.max(1);
    let spacing = TAU / n as f32;
    let start = rng.range(0.0, TAU);
    let size = spec.size as f32;
    (0..n)
        .map(|k| {
            let azimuth = start + spacing * (k as f32 + rng.range(-AZIMUTH_JITTER, AZIMUTH_JITTER));
            let radius = rng.range(RING_RADIUS_M.0, RING_RADIUS_M.1);
            let height = rng.range(HEIGHT_OFFSET_M.0, HEIGHT_OFFSET_M.1);
            let eye =
                spec.centre + Vec3::new(radius * azimuth.cos(), radius * azimuth.sin(), height);
            let distance = (spec.centre - eye).length();
            let f = BODY_FILL * size * distance / spec.body_height_m.max(0.1);
            let mut camera =
                Camera::look_at(eye, spec.centre, Vec3::Z, f, f, spec.size, spec.size)?;
            camera.k.z_axis.x += size * rng.range(-PRINCIPAL_JITTER, PRINCIPAL_JITTER);
            camera.k.z_axis.y += size * rng.range(-PRINCIPAL_JITTER, PRINCIPAL_JITTER);
            camera.validate()?;
            Ok(camera)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_looks_at_the_centre_from_the_right_distance() {
        let spec = RingSpec {
            count: 5,
            size: 100,
            centre: Vec3::new(0.1, -0.2, 0.9),
            body_height_m: 1.7,
        };
        let cams = camera_ring(&spec, &mut Rng::new(3)).unwrap();
        assert_eq!(cams.len(), 5);
        for cam in &cams {
            let (uv, depth) = cam.project(spec.centre).unwrap();
            // Within the principal point jitter of the image centre.
            assert!(
                (uv.x - 50.0).abs() <= 1.0 + 1e-3 && (uv.y - 50.0).abs() <= 1.0 + 1e-3,
                "{uv}"
            );
            assert!(depth > RING_RADIUS_M.0 && depth < 3.1);
            // A point 0.85 m above the centre lands about 35% of the image above it.
            let (top, _) = cam.project(spec.centre + Vec3::Z * 0.85).unwrap();
            assert!(top.y < uv.y - 25.0 && top.y > uv.y - 45.0, "{top} {uv}");
        }
    }
}
