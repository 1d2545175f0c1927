//! A world point's pixel and its Jacobian, as every image term of a fit reads it.

use glam::{Vec2, Vec3};

use crate::geometry::camera::Camera;

/// How a view's pixels relate to its camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pixels {
    /// An undistorted image: the pinhole projection (what the loader's scenes hold).
    Pinhole,
    /// The raw image of a camera with lens distortion (OpenCV's radial-tangential model):
    /// what a user's photos, masks and keypoints are in.
    Distorted,
}

/// Step of the central differences of the distortion, in normalised coordinates (about
/// 0.05 px at a focal length of 500 px): the distortion is smooth at this scale.
const DISTORTION_STEP: f32 = 1e-4;

/// The pixel of the world point `x` in `camera` and the Jacobian rows `d(u, v) / dx` (world),
/// or `None` behind the camera. With [`Pixels::Distorted`] the normalised coordinate goes
/// through the camera's distortion ([`Camera::project_distorted`]'s pixel), whose 2 x 2
/// Jacobian is taken by central differences.
pub fn project(camera: &Camera, pixels: Pixels, x: Vec3) -> Option<(Vec2, Vec3, Vec3)> {
    let y = camera.world_to_camera(x);
    // Behind or on the camera plane: no pixel (the camera's own rule).
    camera.project_camera(y)?;
    let iz = 1.0 / y.z;
    let n = y.truncate() / y.z;
    // d n / d y (camera frame), rows; d/dx of (row . (R x + T)) is R^T row.
    let rt = camera.r.transpose();
    let dn_x = rt * Vec3::new(iz, 0.0, -n.x * iz);
    let dn_y = rt * Vec3::new(0.0, iz, -n.y * iz);
    let (n, dn_x, dn_y) = match pixels {
        Pixels::Pinhole => (n, dn_x, dn_y),
        Pixels::Distorted => {
            let h = DISTORTION_STEP;
            let d = |p: Vec2| camera.distort_normalized(p);
            let along_x = (d(n + Vec2::new(h, 0.0)) - d(n - Vec2::new(h, 0.0))) / (2.0 * h);
            let along_y = (d(n + Vec2::new(0.0, h)) - d(n - Vec2::new(0.0, h))) / (2.0 * h);
            let nd = d(n);
            if !(nd.is_finite() && along_x.is_finite() && along_y.is_finite()) {
                return None;
            }
            (
                nd,
                dn_x * along_x.x + dn_y * along_y.x,
                dn_x * along_x.y + dn_y * along_y.y,
            )
        }
    };
    let (fx, fy, s) = (camera.fx(), camera.fy(), camera.skew());
    Some((
        camera.pixel_from_normalized(n),
        dn_x * fx + dn_y * s,
        dn_y * fy,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// f32 finite differences of a projection at ~100 px: ~1e-3 relative.
    const JACOBIAN_REL_TOL: f32 = 2e-2;

    fn camera(dist: [f32; 5]) -> Camera {
        let mut c = Camera::look_at(
            Vec3::new(0.3, -2.5, 1.1),
            Vec3::new(0.0, 0.0, 0.9),
            Vec3::Z,
            300.0,
            310.0,
            256,
            256,
        )
        .unwrap();
        c.dist = dist;
        c
    }

    #[test]
    fn the_jacobian_matches_finite_differences_with_and_without_distortion() {
        let x = Vec3::new(0.2, 0.1, 1.3);
        for (pixels, dist) in [
            (Pixels::Pinhole, [0.0; 5]),
            (Pixels::Distorted, [-0.2, 0.05, 0.002, -0.001, 0.01]),
        ] {
            let c = camera(dist);
            let (uv, du, dv) = project(&c, pixels, x).unwrap();
            let expected = match pixels {
                Pixels::Pinhole => c.project(x),
                Pixels::Distorted => c.project_distorted(x),
            };
            assert_eq!(uv, expected.unwrap().0);
            let h = 1e-3;
            for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
                let plus = project(&c, pixels, x + axis * h).unwrap().0;
                let minus = project(&c, pixels, x - axis * h).unwrap().0;
                let numeric = (plus - minus) / (2.0 * h);
                let analytic = Vec2::new(du.dot(axis), dv.dot(axis));
                let err = (numeric - analytic).length() / analytic.length().max(1.0);
                assert!(
                    err < JACOBIAN_REL_TOL,
                    "{pixels:?} {axis}: {analytic} vs {numeric}"
                );
            }
        }
        assert!(project(
            &camera([0.0; 5]),
            Pixels::Pinhole,
            Vec3::new(0.0, -5.0, 1.0)
        )
        .is_none());
    }
}
