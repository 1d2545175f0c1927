//! A camera path around the subject from a dataset's calibrated cameras: the ring they stand
//! on (ZJU-MoCap's 21-23 cameras, a synthetic set's ring), continued as a full 360-degree
//! orbit at the ring's mean radius and height, looking at the body.

use glam::Vec3;

use super::camera::Camera;

/// Why no orbit can be made from the cameras.
#[derive(Debug, thiserror::Error)]
pub enum OrbitError {
    #[error("an orbit needs at least one calibrated camera")]
    NoCameras,
    #[error("orbit: the cameras' image-up directions cancel out (no common up)")]
    NoUp,
    #[error("orbit: the cameras stand on the vertical axis through the target (no ring radius)")]
    NoRadius,
    #[error("orbit: {0}")]
    Camera(#[from] super::camera::CameraError),
    #[error("orbit: {count} views: expected at least 1")]
    NoViews { count: usize },
}

/// The ring the calibrated cameras stand on, around a vertical axis through a target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ring {
    /// World up: the mean of the cameras' image-up directions.
    pub up: Vec3,
    /// The point on the axis at target height.
    pub target: Vec3,
    /// Mean horizontal distance of the camera centres from the axis, metres.
    pub radius: f32,
    /// Mean height of the camera centres above the target, metres.
    pub height: f32,
    /// Unit horizontal direction of the first camera from the axis (angle 0).
    pub start: Vec3,
    /// Unit horizontal direction of increasing angle (the way the second camera lies).
    pub turn: Vec3,
}

impl Ring {
    /// The ring of `cameras` around the vertical axis through `target`.
    pub fn of(cameras: &[Camera], target: Vec3) -> Result<Ring, OrbitError> {
        let first = cameras.first().ok_or(OrbitError::NoCameras)?;
        // Row 1 of R is the camera's image-down axis in world coordinates.
        let up = cameras
            .iter()
            .map(|c| -c.r.row(1))
            .sum::<Vec3>()
            .try_normalize()
            .ok_or(OrbitError::NoUp)?;
        let horizontal = |c: &Camera| {
            let d = c.centre() - target;
            (d - d.dot(up) * up, d.dot(up))
        };
        let n = cameras.len() as f32;
        let radius = cameras
            .iter()
            .map(|c| horizontal(c).0.length())
            .sum::<f32>()
            / n;
        let height = cameras.iter().map(|c| horizontal(c).1).sum::<f32>() / n;
        let start = horizontal(first)
            .0
            .try_normalize()
            .ok_or(OrbitError::NoRadius)?;
        if !(radius.is_finite() && radius > 1e-6 && height.is_finite()) {
            return Err(OrbitError::NoRadius);
        }
        let mut turn = up.cross(start);
        if let Some(second) = cameras.get(1) {
            if horizontal(second).0.dot(turn) < 0.0 {
                turn = -turn;
            }
        }
        Ok(Ring {
            up,
            target,
            radius,
            height,
            start,
            turn,
        })
    }

    /// The point of the ring at `angle` radians from the first camera.
    pub fn eye(&self, angle: f32) -> Vec3 {
        self.target
            + self.height * self.up
            + self.radius * (angle.cos() * self.start + angle.sin() * self.turn)
    }

    /// A camera at `azimuth` radians around the ring from the first camera and `elevation`
    /// radians above the ring's own elevation (seen from the target), at `zoom` times the
    /// ring's distance, looking at the target; `like`'s focal lengths and image size scaled by
    /// `scale` (a reduced preview keeps the field of view). The interactive viewer's camera.
    pub fn view(
        &self,
        azimuth: f32,
        elevation: f32,
        zoom: f32,
        like: &Camera,
        scale: f32,
    ) -> Result<Camera, OrbitError> {
        let distance = self.radius.hypot(self.height) * zoom;
        let base = self.height.atan2(self.radius);
        // Keep clear of the poles, where the up vector and the view direction meet.
        let limit = 85f32.to_radians();
        let tilt = (base + elevation).clamp(-limit, limit);
        let around = azimuth.cos() * self.start + azimuth.sin() * self.turn;
        let eye = self.target + distance * (tilt.cos() * around + tilt.sin() * self.up);
        let width = ((like.width as f32 * scale).round() as u32).max(1);
        let height = ((like.height as f32 * scale).round() as u32).max(1);
        let s = width as f32 / like.width as f32;
        Ok(Camera::look_at(
            eye,
            self.target,
            self.up,
            like.fx() * s,
            like.fy() * s,
            width,
            height,
        )?)
    }

    /// `views` cameras evenly around the ring (the first at the first camera's place), looking
    /// at the target with `like`'s focal lengths and image size, without distortion.
    pub fn orbit(&self, views: usize, like: &Camera) -> Result<Vec<Camera>, OrbitError> {
        if views == 0 {
            return Err(OrbitError::NoViews { count: views });
        }
        (0..views)
            .map(|k| {
                let angle = std::f32::consts::TAU * k as f32 / views as f32;
                Ok(Camera::look_at(
                    self.eye(angle),
                    self.target,
                    self.up,
                    like.fx(),
                    like.fy(),
                    like.width,
                    like.height,
                )?)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Cameras on a ring of radius 3 at height 0.5 above (1, 1, 2), world up +z (ZJU-MoCap's),
    /// each looking at the target.
    fn ring_cameras(count: usize) -> (Vec<Camera>, Vec3) {
        let target = Vec3::new(1.0, 1.0, 2.0);
        let cams = (0..count)
            .map(|i| {
                let a = 0.3 + std::f32::consts::TAU * i as f32 / count as f32;
                let eye = target + Vec3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.5);
                Camera::look_at(eye, target, Vec3::Z, 500.0, 500.0, 64, 48).unwrap()
            })
            .collect();
        (cams, target)
    }

    #[test]
    fn the_ring_of_a_ring_of_cameras_is_that_ring() {
        let (cams, target) = ring_cameras(7);
        let ring = Ring::of(&cams, target).unwrap();
        assert!((ring.up - Vec3::Z).length() < 1e-4, "{:?}", ring.up);
        assert!((ring.radius - 3.0).abs() < 1e-4);
        assert!((ring.height - 0.5).abs() < 1e-4);
        let orbit = ring.orbit(12, &cams[0]).unwrap();
        assert_eq!(orbit.len(), 12);
        // The first orbit view stands where the first camera does; every view is on the ring
        // and sees the target at its principal point.
        assert!((orbit[0].centre() - cams[0].centre()).length() < 1e-3);
        for c in &orbit {
            let d = c.centre() - target;
            assert!((d.z - 0.5).abs() < 1e-4);
            assert!((d.truncate().length() - 3.0).abs() < 1e-3);
            let p = c.project_camera(c.world_to_camera(target)).unwrap();
            assert!(
                (p.x - 32.0).abs() < 1e-2 && (p.y - 24.0).abs() < 1e-2,
                "{p:?}"
            );
            assert_eq!((c.width, c.height), (64, 48));
        }
        // It turns the way the cameras are numbered: view 1 is nearer camera 1 than view 11.
        let near = |k: usize| (orbit[k].centre() - cams[1].centre()).length();
        assert!(near(1) < near(11));
    }

    #[test]
    fn the_viewer_camera_turns_tilts_zooms_and_scales() {
        let (cams, target) = ring_cameras(6);
        let ring = Ring::of(&cams, target).unwrap();
        // At rest it is the first camera's place (up to the lens).
        let rest = ring.view(0.0, 0.0, 1.0, &cams[0], 1.0).unwrap();
        assert!((rest.centre() - cams[0].centre()).length() < 1e-3);
        // Half a turn: the opposite side, same height.
        let back = ring
            .view(std::f32::consts::PI, 0.0, 1.0, &cams[0], 1.0)
            .unwrap();
        let (a, b) = (rest.centre() - target, back.centre() - target);
        assert!((a.truncate() + b.truncate()).length() < 1e-3 && (a.z - b.z).abs() < 1e-3);
        // Tilting up raises the eye; zoom 0.5 halves the distance; scale shrinks the image
        // and the focal length together.
        let up = ring.view(0.0, 0.3, 0.5, &cams[0], 0.25).unwrap();
        let d = up.centre() - target;
        assert!(d.z > a.z * 0.5);
        assert!((d.length() - 0.5 * a.length()).abs() < 1e-3);
        assert_eq!((up.width, up.height), (16, 12));
        assert!((up.fx() - 125.0).abs() < 1e-3);
        let p = up.project_camera(up.world_to_camera(target)).unwrap();
        assert!((p.x - 8.0).abs() < 1e-2 && (p.y - 6.0).abs() < 1e-2);
        // Straight up is clamped short of the pole: still a valid camera.
        assert!(ring.view(0.0, 10.0, 1.0, &cams[0], 1.0).is_ok());
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let (cams, target) = ring_cameras(3);
        assert!(matches!(Ring::of(&[], target), Err(OrbitError::NoCameras)));
        let ring = Ring::of(&cams, target).unwrap();
        assert!(matches!(
            ring.orbit(0, &cams[0]),
            Err(OrbitError::NoViews { .. })
        ));
        // Two cameras, one upside down: their ups cancel.
        let eye = target + Vec3::X * 3.0;
        let upright = Camera::look_at(eye, target, Vec3::Z, 500.0, 500.0, 8, 8).unwrap();
        let flipped = Camera::look_at(eye, target, -Vec3::Z, 500.0, 500.0, 8, 8).unwrap();
        assert!(matches!(
            Ring::of(&[upright, flipped], target),
            Err(OrbitError::NoUp)
        ));
        // A target at the camera: no radius.
        assert!(matches!(
            Ring::of(&[upright], eye),
            Err(OrbitError::NoRadius)
        ));
    }
}
