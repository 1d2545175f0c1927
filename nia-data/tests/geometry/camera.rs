//! Cameras: look-at, validation, scaling, distortion round trips.

use super::*;

#[test]
fn look_at_projects_target_to_centre_and_up_upwards() {
    let eye = Vec3::new(0.4, 1.2, 3.0);
    let target = Vec3::new(0.0, 0.9, 0.0);
    let c = Camera::look_at(eye, target, Vec3::Y, 500.0, 480.0, 512, 384).unwrap();
    assert!((c.centre() - eye).length() < GEOM_TOL);
    let (uv, z) = c.project(target).unwrap();
    assert!((uv - Vec2::new(256.0, 192.0)).length() < PIXEL_TOL);
    assert!((z - (target - eye).length()).abs() < GEOM_TOL);
    let (above, _) = c.project(target + 0.1 * Vec3::Y).unwrap();
    assert!(
        above.y < uv.y - 10.0,
        "world up must go up the image (v decreases)"
    );
    // Behind the camera: no pixel.
    assert!(c.project(eye + (eye - target)).is_none());
    // Round trip through the world/camera transforms.
    let p = Vec3::new(0.3, -0.2, 0.5);
    assert!((c.camera_to_world(c.world_to_camera(p)) - p).length() < GEOM_TOL);
    assert!(Camera::look_at(eye, eye, Vec3::Y, 500.0, 500.0, 8, 8).is_err());
    assert!(Camera::look_at(eye, eye + Vec3::Y, Vec3::Y, 500.0, 500.0, 8, 8).is_err());
}

#[test]
fn validation_names_the_field() {
    let mut c = distorted_camera();
    c.k.x_axis.x = -1.0;
    assert!(c.validate().unwrap_err().to_string().contains("`k`"));
    let mut c = distorted_camera();
    c.r = Mat3::from_diagonal(Vec3::new(1.0, 1.0, 2.0));
    assert!(c.validate().unwrap_err().to_string().contains("`r`"));
    let mut c = distorted_camera();
    c.t.x = f32::NAN;
    assert!(c.validate().unwrap_err().to_string().contains("`t`"));
}

#[test]
fn scaled_camera_scales_pixels_and_size() {
    let c = Camera::look_at(
        Vec3::new(0.0, 0.0, -3.0),
        Vec3::ZERO,
        Vec3::Y,
        1100.0,
        1090.0,
        1024,
        1024,
    )
    .unwrap();
    let s = c.scaled(0.5).unwrap();
    assert_eq!((s.width, s.height), (512, 512));
    assert_eq!(
        (s.fx(), s.fy(), s.cx(), s.cy()),
        (550.0, 545.0, 256.0, 256.0)
    );
    let p = Vec3::new(0.2, -0.4, 0.1);
    let (a, _) = c.project(p).unwrap();
    let (b, _) = s.project(p).unwrap();
    assert!((a * 0.5 - b).length() < PIXEL_TOL);
    assert!(c.scaled(0.0).is_err() && c.scaled(f32::NAN).is_err());
    assert!(c.scaled(1e-4).is_err(), "a zero-pixel image is an error");
}

#[test]
fn distort_undistort_points_round_trip() {
    let c = distorted_camera();
    let mut rng = Rng::new(11);
    let ideal: Vec<Vec2> = (0..2000)
        .map(|_| Vec2::new(rng.range(0.0, 320.0), rng.range(0.0, 240.0)))
        .collect();
    let raw: Vec<Vec2> = ideal.iter().map(|p| c.distort_pixel(*p)).collect();
    let back = c.undistort_points(&raw);
    for (a, b) in ideal.iter().zip(&back) {
        assert!((*a - *b).length() < PIXEL_TOL, "{a} -> {b}");
    }
    // The distortion is not negligible here (otherwise the test says nothing).
    let moved = ideal
        .iter()
        .zip(&raw)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0f32, f32::max);
    assert!(moved > 10.0, "max displacement {moved} px");
    // project_distorted = distort(project).
    let p = Vec3::new(0.21, -0.13, 1.1);
    let (u, _) = c.project(p).unwrap();
    let (d, _) = c.project_distorted(p).unwrap();
    assert!((c.distort_pixel(u) - d).length() < PIXEL_TOL);
}

/// A smooth test pattern over normalised image coordinates, values in [0, 255].
fn pattern(n: Vec2, channel: usize) -> f32 {
    let k = 1.0 + channel as f32;
    127.5 + 100.0 * (5.0 * k * n.x).sin() * (4.0 * n.y + 0.3 * k).cos()
}

#[test]
fn undistorting_a_distorted_rendering_gives_the_pinhole_image() {
    let c = distorted_camera();
    let (w, h) = (c.width as usize, c.height as usize);
    // Raw image: what the distorted lens sees of the pattern (OpenCV pixel-centre convention).
    let mut raw = vec![0.0f32; w * h * 3];
    let mut ideal = vec![0.0f32; w * h * 3];
    for y in 0..h {
        for x in 0..w {
            let px = Vec2::new(x as f32, y as f32);
            let n_raw = c.undistort_normalized(c.normalized_from_pixel(px));
            let n_ideal = c.normalized_from_pixel(px);
            for ch in 0..3 {
                raw[(y * w + x) * 3 + ch] = pattern(n_raw, ch);
                ideal[(y * w + x) * 3 + ch] = pattern(n_ideal, ch);
            }
        }
    }
    let out = c.undistort_channels(&raw, 3).unwrap();
    let map = c.undistort_map().unwrap();
    // Bilinear interpolation of the pattern: |f''| h^2 / 8 ~ 100 (15/300)^2 / 8 ~ 0.03.
    const BILINEAR_TOL: f32 = 0.1;
    let mut checked = 0;
    for y in 0..h {
        for x in 0..w {
            let s = map.source[y * w + x];
            if s.x < 1.0 || s.y < 1.0 || s.x > w as f32 - 2.0 || s.y > h as f32 - 2.0 {
                continue;
            }
            checked += 1;
            for ch in 0..3 {
                let i = (y * w + x) * 3 + ch;
                assert!(
                    (out[i] - ideal[i]).abs() < BILINEAR_TOL,
                    "pixel ({x}, {y}) ch {ch}: {} vs {}",
                    out[i],
                    ideal[i]
                );
            }
        }
    }
    assert!(checked > w * h * 8 / 10, "interior too small: {checked}");
    // The 8-bit path agrees with the float path up to rounding.
    let raw8: Vec<u8> = raw.iter().map(|v| v.round() as u8).collect();
    let img = image::RgbImage::from_raw(c.width, c.height, raw8).unwrap();
    let out8 = c.undistort_image(&img).unwrap();
    for y in 0..h {
        for x in 0..w {
            let s = map.source[y * w + x];
            if s.x < 1.0 || s.y < 1.0 || s.x > w as f32 - 2.0 || s.y > h as f32 - 2.0 {
                continue;
            }
            for ch in 0..3 {
                let i = (y * w + x) * 3 + ch;
                assert!((out8.as_raw()[i] as f32 - ideal[i]).abs() <= 1.5);
            }
        }
    }
    // Wrong size: a typed error naming what was expected.
    let small = image::RgbImage::new(10, 10);
    let err = c.undistort_image(&small).unwrap_err().to_string();
    assert!(err.contains("320x240"), "{err}");
    // No distortion: a copy.
    let mut pin = c;
    pin.dist = [0.0; 5];
    assert_eq!(pin.undistort_image(&img).unwrap(), img);
}
