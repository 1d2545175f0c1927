//! Geometry core: cameras and undistortion, rays and boxes, the rasteriser, vertex visibility
//! and nearest-surface queries, checked against analytic answers and brute force.

use glam::{Mat3, Vec2, Vec3};
use nia_data::camera::{Camera, PIXEL_CENTRE_OFFSET};
use nia_data::raster::{
    rasterize, rasterize_into, render_textured, Fragments, MeshError, EMPTY_FACE, NEAR_PLANE_M,
};
use nia_data::rays::{image_rays, mask_at_box, near_far, pixel_centre, pixel_ray, Aabb, Ray};
use nia_data::rng::Rng;
use nia_data::surface::{
    closest_point_on_triangle, interpolate_scalar, interpolate_weights, SurfaceIndex,
};
use nia_data::visibility::{vertex_visibility, visibility, DEFAULT_DEPTH_TOL_M};

/// f32 round-off on metre-scale coordinates after a handful of operations.
const GEOM_TOL: f32 = 1e-4;
/// Pixel positions through distortion round trips (f32, 30 fixed-point iterations).
const PIXEL_TOL: f32 = 1e-3;

type Mesh = (Vec<Vec3>, Vec<[u32; 3]>);

/// A UV sphere with outward-facing triangles; `radius(theta, phi)` allows bumpy shapes.
fn uv_sphere(centre: Vec3, n_lat: u32, n_lon: u32, radius: impl Fn(f32, f32) -> f32) -> Mesh {
    let mut v = vec![centre + Vec3::new(0.0, 0.0, radius(0.0, 0.0))];
    for i in 1..n_lat {
        let theta = std::f32::consts::PI * i as f32 / n_lat as f32;
        for j in 0..n_lon {
            let phi = std::f32::consts::TAU * j as f32 / n_lon as f32;
            let r = radius(theta, phi);
            v.push(
                centre
                    + r * Vec3::new(
                        theta.sin() * phi.cos(),
                        theta.sin() * phi.sin(),
                        theta.cos(),
                    ),
            );
        }
    }
    v.push(centre + Vec3::new(0.0, 0.0, -radius(std::f32::consts::PI, 0.0)));
    let south = v.len() as u32 - 1;
    let ring = |i: u32, j: u32| 1 + (i - 1) * n_lon + (j % n_lon);
    let mut f = Vec::new();
    for j in 0..n_lon {
        f.push([0, ring(1, j), ring(1, j + 1)]);
        f.push([south, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)]);
    }
    for i in 1..n_lat - 1 {
        for j in 0..n_lon {
            let (a, b, c, d) = (
                ring(i, j),
                ring(i, j + 1),
                ring(i + 1, j),
                ring(i + 1, j + 1),
            );
            f.push([a, c, d]);
            f.push([a, d, b]);
        }
    }
    (v, f)
}

/// A cube [-1, 1]^3 with each side an n x n grid, outward-facing triangles.
fn cube(n: u32) -> Mesh {
    let mut v: Vec<Vec3> = Vec::new();
    let mut f = Vec::new();
    let mut index = std::collections::HashMap::new();
    let mut vid = |p: Vec3, v: &mut Vec<Vec3>| -> u32 {
        let key = (p * 1000.0).round().as_ivec3().to_array();
        *index.entry(key).or_insert_with(|| {
            v.push(p);
            v.len() as u32 - 1
        })
    };
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let nrm = Vec3::from_array(std::array::from_fn(|k| if k == axis { sign } else { 0.0 }));
            let u = Vec3::from_array(std::array::from_fn(|k| {
                if k == (axis + 1) % 3 {
                    1.0
                } else {
                    0.0
                }
            }));
            let w = nrm.cross(u);
            let at = |i: u32, j: u32| {
                nrm + u * (2.0 * i as f32 / n as f32 - 1.0) + w * (2.0 * j as f32 / n as f32 - 1.0)
            };
            for i in 0..n {
                for j in 0..n {
                    let a = vid(at(i, j), &mut v);
                    let b = vid(at(i + 1, j), &mut v);
                    let c = vid(at(i + 1, j + 1), &mut v);
                    let d = vid(at(i, j + 1), &mut v);
                    // (u, w, nrm) is right-handed, so counter-clockwise in (u, w) faces out.
                    f.push([a, b, c]);
                    f.push([a, c, d]);
                }
            }
        }
    }
    (v, f)
}

/// Camera at the origin looking down +z with identity rotation (x right, y down).
fn front_camera(f: f32, size: u32) -> Camera {
    let c = Camera::look_at(Vec3::ZERO, Vec3::Z, -Vec3::Y, f, f, size, size).unwrap();
    assert!((c.r - Mat3::IDENTITY)
        .abs()
        .to_cols_array()
        .iter()
        .all(|e| *e < 1e-6));
    c
}

fn distorted_camera() -> Camera {
    Camera::from_rows(
        [[300.0, 0.0, 161.3], [0.0, 310.0, 118.7], [0.0, 0.0, 1.0]],
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0, 0.0, 0.0],
        [-0.28, 0.09, 0.0012, -0.0009, -0.01],
        320,
        240,
    )
    .unwrap()
}

// ---------------------------------------------------------------- camera

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

// ---------------------------------------------------------------- rays

#[test]
fn pixel_rays_pass_through_projected_points() {
    let c = Camera::look_at(
        Vec3::new(1.0, 2.0, 3.0),
        Vec3::new(0.0, 0.8, 0.0),
        Vec3::Y,
        400.0,
        410.0,
        200,
        150,
    )
    .unwrap();
    let mut rng = Rng::new(3);
    for _ in 0..200 {
        let p = Vec3::new(
            rng.range(-0.5, 0.5),
            rng.range(0.3, 1.3),
            rng.range(-0.5, 0.5),
        );
        let (uv, _) = c.project(p).unwrap();
        let ray = pixel_ray(&c, uv);
        assert!((ray.dir.length() - 1.0).abs() < 1e-5);
        let t = (p - ray.origin).dot(ray.dir);
        assert!((ray.at(t) - p).length() < GEOM_TOL);
    }
    let all = image_rays(&c);
    assert_eq!(all.len(), 200 * 150);
    // Pixel (17, 33) has its centre at image coordinate (17, 33) (OpenCV convention).
    let r = pixel_ray(&c, Vec2::new(17.0, 33.0));
    assert!((all[33 * 200 + 17].dir - r.dir).length() < 1e-6);
    assert_eq!(all[33 * 200 + 17], r);
}

#[test]
fn near_far_analytic_cases() {
    let unit = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let hit = |o: Vec3, d: Vec3| {
        near_far(
            &Ray {
                origin: o,
                dir: d.normalize(),
            },
            &unit,
        )
    };
    // Straight through along +x.
    let (n, f) = hit(Vec3::new(-5.0, 0.5, 0.5), Vec3::X).unwrap();
    assert!((n - 5.0).abs() < 1e-6 && (f - 6.0).abs() < 1e-6);
    // Diagonal.
    let (n, f) = hit(Vec3::splat(-1.0), Vec3::ONE).unwrap();
    assert!((n - 3f32.sqrt()).abs() < 1e-5 && (f - 2.0 * 3f32.sqrt()).abs() < 1e-5);
    // Starting inside: near = 0.
    let (n, f) = hit(Vec3::splat(0.5), Vec3::Z).unwrap();
    assert!(n == 0.0 && (f - 0.5).abs() < 1e-6);
    // Parallel to the x and y slabs (two zero components), inside them: finite.
    let (n, f) = hit(Vec3::new(0.2, 0.7, -2.0), Vec3::Z).unwrap();
    assert!((n - 2.0).abs() < 1e-6 && (f - 3.0).abs() < 1e-6);
    // Parallel and outside a slab: miss.
    assert!(hit(Vec3::new(1.5, 0.5, -2.0), Vec3::Z).is_none());
    // Sliding inside a face plane (origin exactly on x = 1): hit, no NaN.
    let (n, f) = hit(Vec3::new(1.0, 0.5, -2.0), Vec3::Z).unwrap();
    assert!(n.is_finite() && f.is_finite() && (f - n - 1.0).abs() < 1e-6);
    // Origin on a face plane with the direction in the plane of a zero component: 0 * inf.
    let (n, f) = hit(Vec3::new(0.0, 0.0, 0.5), Vec3::new(1.0, 1.0, 0.0)).unwrap();
    assert!(n == 0.0 && (f - 2f32.sqrt()).abs() < 1e-5);
    // Through an edge only (zero-length overlap): miss.
    assert!(hit(Vec3::new(-1.0, 0.0, 0.5), Vec3::new(1.0, 1.0, 0.0)).is_none());
    // Box behind the origin.
    assert!(hit(Vec3::new(0.5, 0.5, 3.0), Vec3::Z).is_none());
    // Leaving the box from inside.
    let (n, f) = hit(Vec3::new(0.5, 0.5, 0.9), Vec3::Z).unwrap();
    assert!(n == 0.0 && (f - 0.1).abs() < 1e-6);
    // Garbage in, no panic, no NaN out.
    assert!(hit(Vec3::new(f32::NAN, 0.5, 0.5), Vec3::X).is_none());
    assert!(near_far(
        &Ray {
            origin: Vec3::splat(0.5),
            dir: Vec3::ZERO
        },
        &unit
    )
    .is_none());
    let nan_box = Aabb::new(Vec3::splat(f32::NAN), Vec3::ONE);
    assert!(near_far(
        &Ray {
            origin: Vec3::splat(-1.0),
            dir: Vec3::X
        },
        &nan_box
    )
    .is_none());
}

#[test]
fn aabb_helpers() {
    let pts = [Vec3::new(0.0, -1.0, 2.0), Vec3::new(2.0, 1.0, 3.0)];
    let b = Aabb::from_points(&pts).unwrap();
    let e = b.enlarged(0.025);
    assert!((e.min - Vec3::new(-0.05, -1.05, 1.975)).length() < 1e-6);
    assert!((e.max - Vec3::new(2.05, 1.05, 3.025)).length() < 1e-6);
    assert!((b.padded(0.05).min - Vec3::new(-0.05, -1.05, 1.95)).length() < 1e-6);
    assert!(Aabb::from_points(&[]).is_none());
    assert!(Aabb::from_points(&[Vec3::NAN]).is_none());
    assert_eq!(b.corners()[7], b.max);
    assert!(b.contains(b.centre()) && !b.contains(Vec3::splat(9.0)));
}

/// Signed distances of `p` to the edges of a counter-clockwise convex polygon (positive inside).
fn hull_margin(hull: &[Vec2], p: Vec2) -> f32 {
    (0..hull.len())
        .map(|i| {
            let (a, b) = (hull[i], hull[(i + 1) % hull.len()]);
            let e = (b - a).normalize();
            e.perp_dot(p - a)
        })
        .fold(f32::INFINITY, f32::min)
}

fn convex_hull(mut pts: Vec<Vec2>) -> Vec<Vec2> {
    pts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    let cross = |o: Vec2, a: Vec2, b: Vec2| (a - o).perp_dot(b - o);
    let mut lower: Vec<Vec2> = Vec::new();
    for p in &pts {
        while lower.len() >= 2 && cross(lower[lower.len() - 2], lower[lower.len() - 1], *p) <= 0.0 {
            lower.pop();
        }
        lower.push(*p);
    }
    let mut upper: Vec<Vec2> = Vec::new();
    for p in pts.iter().rev() {
        while upper.len() >= 2 && cross(upper[upper.len() - 2], upper[upper.len() - 1], *p) <= 0.0 {
            upper.pop();
        }
        upper.push(*p);
    }
    lower.pop();
    upper.pop();
    lower.extend(upper);
    lower
}

#[test]
fn mask_at_box_is_the_projected_hull() {
    let c = Camera::look_at(
        Vec3::new(2.0, 1.5, 3.5),
        Vec3::new(0.0, 0.1, 0.0),
        Vec3::Y,
        180.0,
        180.0,
        128,
        96,
    )
    .unwrap();
    let b = Aabb::new(Vec3::new(-0.4, -0.9, -0.3), Vec3::new(0.5, 1.0, 0.2));
    let mask = mask_at_box(&c, &b);
    let hull = convex_hull(
        b.corners()
            .iter()
            .map(|p| c.project(*p).unwrap().0)
            .collect(),
    );
    // Counter-clockwise in (x right, y down) means positive perp_dot inside.
    let mut inside = 0;
    for y in 0..96 {
        for x in 0..128 {
            // Pixel (x, y)'s ray goes through image coordinate (x, y).
            let m = hull_margin(&hull, Vec2::new(x as f32, y as f32));
            if m.abs() < 1e-2 {
                continue;
            }
            assert_eq!(mask[y * 128 + x], m > 0.0, "pixel ({x}, {y}) margin {m}");
            inside += (m > 0.0) as usize;
        }
    }
    assert!(inside > 500 && inside < 128 * 96 - 500, "{inside}");
    // The bounding-rectangle shortcut changes nothing: same as testing every pixel's ray, for
    // boxes in front, around the camera, straddling the camera plane (3 corners behind) and
    // behind it.
    let rays = image_rays(&c);
    for bx in [
        b,
        Aabb::new(Vec3::new(1.0, 0.5, 2.0), Vec3::new(3.0, 2.0, 5.0)),
        Aabb::new(Vec3::new(0.5, 0.2, 3.0), Vec3::new(1.8, 1.4, 4.5)),
        Aabb::new(Vec3::new(3.0, 2.0, 4.5), Vec3::new(4.0, 3.0, 6.0)),
        Aabb::new(Vec3::splat(-10.0), Vec3::splat(10.0)),
    ] {
        let brute: Vec<bool> = rays.iter().map(|r| near_far(r, &bx).is_some()).collect();
        assert_eq!(mask_at_box(&c, &bx), brute, "{bx:?}");
    }
    // Box behind the camera: nothing. Camera inside the box: everything.
    let behind = Aabb::new(Vec3::new(3.0, 2.0, 4.5), Vec3::new(4.0, 3.0, 6.0));
    assert!(mask_at_box(&c, &behind).iter().all(|m| !m));
    let around = Aabb::new(Vec3::splat(-10.0), Vec3::splat(10.0));
    assert!(mask_at_box(&c, &around).iter().all(|m| *m));
}

// ---------------------------------------------------------------- raster

#[test]
fn fronto_parallel_quad_covers_the_expected_pixels() {
    // look_at gives exactly R = I, T = 0 here, so the projections below are exact.
    let c = front_camera(100.0, 64);
    assert_eq!((c.cx(), c.cy()), (32.0, 32.0));
    // Quad A: x in [-0.5, 0.28125], y in [-0.5, 0.25] at z = 2 -> u in [7, 46.0625],
    // v in [7, 44.5]. Pixel centres are at integer coordinates, so the left (u = 7) and top
    // (v = 7) edges run exactly through pixel centres and the top-left rule gives column 7 and
    // row 7 to the quad; columns up to 46 and rows up to 44 have their centres inside.
    // Quad B shares A's left edge: x in [-0.625, -0.5] -> u in [0.75, 7]; column 7 lies on its
    // right edge and is not B's, so B covers columns 1..=6.
    let (ya, yb) = (-0.5, 0.25);
    let v = vec![
        Vec3::new(-0.5, ya, 2.0),
        Vec3::new(0.28125, ya, 2.0),
        Vec3::new(0.28125, yb, 2.0),
        Vec3::new(-0.5, yb, 2.0),
        Vec3::new(-0.625, ya, 2.0),
        Vec3::new(-0.625, yb, 2.0),
    ];
    for (k, uv) in [
        (0, Vec2::new(7.0, 7.0)),
        (2, Vec2::new(46.0625, 44.5)),
        (4, Vec2::new(0.75, 7.0)),
    ] {
        assert_eq!(c.project(v[k]).unwrap().0, uv, "vertex {k}");
    }
    let f = vec![[0, 1, 2], [0, 2, 3], [4, 0, 3], [4, 3, 5]];
    let fr = rasterize(&c, &v, &f).unwrap();
    for y in 0..64 {
        for x in 0..64 {
            let i = y * 64 + x;
            let rows = (7..=44).contains(&y);
            let in_a = (7..=46).contains(&x) && rows;
            let in_b = (1..=6).contains(&x) && rows;
            let face = fr.face[i];
            assert_eq!(face < 2, in_a, "pixel ({x}, {y}) face {face}");
            assert_eq!(face == 2 || face == 3, in_b, "pixel ({x}, {y}) face {face}");
            if in_a || in_b {
                assert!((fr.depth[i] - 2.0).abs() < 1e-5);
                let b = fr.bary[i];
                assert!((b[0] + b[1] + b[2] - 1.0).abs() < 1e-5);
            } else {
                assert_eq!(face, EMPTY_FACE, "pixel ({x}, {y})");
                assert_eq!(fr.depth[i], f32::INFINITY);
            }
        }
    }
}

#[test]
fn pixel_centres_are_at_integer_coordinates() {
    // The project's (OpenCV / ZJU-MoCap) convention, shared by rays, rasteriser, visibility.
    assert_eq!(PIXEL_CENTRE_OFFSET, 0.0);
    assert_eq!(pixel_centre(17, 33), Vec2::new(17.0, 33.0));
    let c = front_camera(100.0, 64);
    // Principal point (32, 32): pixel (32, 32)'s ray is the optical axis; pixel 31's leans left.
    let rays = image_rays(&c);
    assert!((rays[32 * 64 + 32].dir - Vec3::Z).length() < 1e-7);
    assert!(rays[32 * 64 + 31].dir.x < 0.0 && rays[31 * 64 + 32].dir.y < 0.0);
    // A triangle around image coordinate (10, 20), 0.3 pixels across in each direction, covers
    // exactly pixel (10, 20) (its only pixel centre), at its centre.
    let corners = [
        Vec2::new(9.7, 19.7),
        Vec2::new(10.3, 19.7),
        Vec2::new(10.0, 20.3),
    ];
    let v: Vec<Vec3> = corners.iter().map(|uv| unproject(&c, *uv, 2.0)).collect();
    let fr = rasterize(&c, &v, &[[0, 1, 2]]).unwrap();
    let covered: Vec<usize> = (0..64 * 64).filter(|i| fr.face[*i] == 0).collect();
    assert_eq!(covered, vec![20 * 64 + 10]);
    let p = fr.interpolate(&[[0, 1, 2]], &v).unwrap()[20 * 64 + 10].unwrap();
    assert!((c.project(p).unwrap().0 - Vec2::new(10.0, 20.0)).length() < PIXEL_TOL);
    // mask_at_box of a thin box around the ray of pixel (10, 20) is that pixel alone.
    let centre = unproject(&c, Vec2::new(10.0, 20.0), 2.0);
    let bx = Aabb::new(centre - Vec3::splat(0.002), centre + Vec3::splat(0.002));
    let mask = mask_at_box(&c, &bx);
    let hits: Vec<usize> = (0..64 * 64).filter(|i| mask[*i]).collect();
    assert_eq!(hits, vec![20 * 64 + 10]);
}

#[test]
fn visibility_uses_the_pixel_with_the_nearest_centre() {
    // Every pixel is covered by face 0 at depth 1 m except one empty pixel; the test vertices
    // lie 5 m deep (hidden) and are not on face 0, so a vertex is visible iff its own pixel
    // (the one whose centre is nearest: pixel i spans [i - 0.5, i + 0.5)) is the empty one.
    let c = front_camera(100.0, 64);
    let probes = [
        (Vec2::new(10.4, 20.4), Some((10, 20))),
        (Vec2::new(10.6, 20.6), Some((11, 21))),
        (Vec2::new(9.6, 19.6), Some((10, 20))),
        (Vec2::new(-0.4, 3.2), Some((0, 3))),
        (Vec2::new(63.4, 62.6), Some((63, 63))),
        (Vec2::new(-0.6, 3.2), None),
        (Vec2::new(63.6, 3.2), None),
    ];
    let mut v: Vec<Vec3> = probes
        .iter()
        .map(|(uv, _)| unproject(&c, *uv, 5.0))
        .collect();
    let n = v.len() as u32;
    v.extend([
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(0.1, 0.0, 1.0),
        Vec3::new(0.0, 0.1, 1.0),
    ]);
    let faces = [[n, n + 1, n + 2]];
    // Each probe against every probe's pixel (e.g. (10.6, 20.6) must not read pixel (10, 20))
    // and a far-away one.
    let pixels: Vec<(usize, usize)> = probes
        .iter()
        .filter_map(|(_, own)| *own)
        .chain([(30, 30)])
        .collect();
    for (k, (_, own)) in probes.iter().enumerate() {
        for &(ex, ey) in &pixels {
            let mut fr = Fragments::empty(64, 64);
            fr.face.fill(0);
            fr.depth.fill(1.0);
            fr.face[ey * 64 + ex] = EMPTY_FACE;
            fr.depth[ey * 64 + ex] = f32::INFINITY;
            let vis = vertex_visibility(&c, &v, &faces, &fr, DEFAULT_DEPTH_TOL_M).unwrap();
            let expected = *own == Some((ex, ey));
            assert_eq!(vis[k] == 1, expected, "probe {k}, empty pixel ({ex}, {ey})");
        }
    }
}

/// World point at pixel position `uv` and depth `z` for [`front_camera`].
fn unproject(c: &Camera, uv: Vec2, z: f32) -> Vec3 {
    (c.normalized_from_pixel(uv) * z).extend(z)
}

#[test]
fn shared_edges_cover_every_pixel_centre_exactly_once() {
    let c = front_camera(64.0, 32);
    // A 4x4 grid of cells whose vertices sit exactly on pixel centres, i.e. on integer image
    // coordinates (so many centres lie on edges), and a jittered copy.
    for jitter in [0.0f32, 1.3] {
        let mut rng = Rng::new(5);
        let n = 4;
        let mut v = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let mut uv = Vec2::new(4.0 + 6.0 * i as f32, 4.0 + 6.0 * j as f32);
                if i > 0 && i < n && j > 0 && j < n {
                    uv += Vec2::new(rng.range(-jitter, jitter), rng.range(-jitter, jitter));
                }
                v.push(unproject(&c, uv, 2.0));
            }
        }
        let id = |i: u32, j: u32| j * (n + 1) + i;
        let mut f = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let (a, b, cc, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
                if (i + j) % 2 == 0 {
                    f.push([a, b, cc]);
                    f.push([a, cc, d]);
                } else {
                    f.push([a, b, d]);
                    f.push([b, cc, d]);
                }
            }
        }
        let mut count = vec![0u32; 32 * 32];
        for face in &f {
            let fr = rasterize(&c, &v, std::slice::from_ref(face)).unwrap();
            for (k, fc) in fr.face.iter().enumerate() {
                count[k] += (*fc != EMPTY_FACE) as u32;
            }
        }
        for y in 0..32 {
            for x in 0..32 {
                let (cx, cy) = (x as f32, y as f32);
                let interior = cx > 4.0 && cx < 28.0 && cy > 4.0 && cy < 28.0;
                let outside = !(4.0..=28.0).contains(&cx) || !(4.0..=28.0).contains(&cy);
                if interior {
                    assert_eq!(count[y * 32 + x], 1, "jitter {jitter}, pixel ({x}, {y})");
                } else if outside {
                    assert_eq!(count[y * 32 + x], 0, "jitter {jitter}, pixel ({x}, {y})");
                } else {
                    assert!(count[y * 32 + x] <= 1);
                }
            }
        }
    }
}

/// Ray/plane intersection for the centre of pixel `(x, y)`, image coordinate `(x, y)`.
fn ray_plane(c: &Camera, x: usize, y: usize, p0: Vec3, n: Vec3) -> Option<Vec3> {
    let ray = pixel_ray(c, Vec2::new(x as f32, y as f32));
    let denom = ray.dir.dot(n);
    if denom.abs() < 1e-9 {
        return None;
    }
    let t = (p0 - ray.origin).dot(n) / denom;
    (t > 0.0).then(|| ray.at(t))
}

#[test]
fn perspective_correct_barycentrics_on_a_slanted_quad() {
    let c = front_camera(40.0, 64);
    let v = vec![
        Vec3::new(-1.0, -1.0, 2.0),
        Vec3::new(1.0, -1.0, 4.5),
        Vec3::new(1.0, 1.0, 4.5),
        Vec3::new(-1.0, 1.0, 2.0),
    ];
    let f = vec![[0, 1, 2], [0, 2, 3]];
    let fr = rasterize(&c, &v, &f).unwrap();
    let pos = fr.interpolate(&f, &v).unwrap();
    let n = (v[1] - v[0]).cross(v[3] - v[0]).normalize();
    let mut covered = 0;
    let mut affine_err = 0.0f32;
    for y in 0..64 {
        for x in 0..64 {
            let i = y * 64 + x;
            let Some(p) = pos[i] else { continue };
            covered += 1;
            let hit = ray_plane(&c, x, y, v[0], n).unwrap();
            assert!(
                (p - hit).length() < GEOM_TOL * 5.0,
                "({x},{y}) {p} vs {hit}"
            );
            assert!((fr.depth[i] - hit.z).abs() < GEOM_TOL * 5.0);
            // What screen-space (affine) barycentrics would have given.
            let [a, b, cc] = f[fr.face[i] as usize].map(|k| c.project(v[k as usize]).unwrap().0);
            let q = Vec2::new(x as f32, y as f32);
            let area = (b - a).perp_dot(cc - a);
            let l1 = (q - a).perp_dot(cc - a) / area;
            let l2 = (b - a).perp_dot(q - a) / area;
            let [ia, ib, ic] = f[fr.face[i] as usize].map(|k| v[k as usize]);
            let affine = ia * (1.0 - l1 - l2) + ib * l1 + ic * l2;
            affine_err = affine_err.max((affine - hit).length());
        }
    }
    assert!(covered > 500, "{covered}");
    assert!(
        affine_err > 0.05,
        "the test needs visible perspective: {affine_err}"
    );
    // Faces that do not match the rasterised ones: an error, not a panic.
    let err = fr.interpolate(&f[..1], &v).unwrap_err();
    assert!(matches!(err, MeshError::Length { .. }));
}

#[test]
fn near_plane_clipping_draws_the_visible_part_exactly() {
    let c = front_camera(30.0, 48);
    let floor_y = 0.5;
    // One and two vertices behind the camera, on the plane y = 0.5 (below the horizon).
    let cases: [[Vec3; 3]; 2] = [
        [
            Vec3::new(-4.0, floor_y, -1.0),
            Vec3::new(0.0, floor_y, 6.0),
            Vec3::new(4.0, floor_y, -1.0),
        ],
        [
            Vec3::new(0.0, floor_y, -1.0),
            Vec3::new(-4.0, floor_y, 5.0),
            Vec3::new(4.0, floor_y, 5.0),
        ],
    ];
    for tri in cases {
        let v = tri.to_vec();
        let f = vec![[0u32, 1, 2]];
        let fr = rasterize(&c, &v, &f).unwrap();
        let pos = fr.interpolate(&f, &v).unwrap();
        let inside_tri = |p: Vec3| {
            let q = Vec2::new(p.x, p.z);
            let [a, b, cc] = tri.map(|t| Vec2::new(t.x, t.z));
            let s = (b - a).perp_dot(cc - a).signum();
            [(a, b), (b, cc), (cc, a)]
                .iter()
                .map(|(e0, e1)| s * (*e1 - *e0).perp_dot(q - *e0) / (*e1 - *e0).length())
                .fold(f32::INFINITY, f32::min)
        };
        let mut covered = 0;
        for y in 0..48 {
            for x in 0..48 {
                let i = y * 48 + x;
                let hit = ray_plane(&c, x, y, Vec3::new(0.0, floor_y, 0.0), Vec3::Y);
                let expected = hit.map(|h| (inside_tri(h), h));
                match (expected, pos[i]) {
                    (Some((m, h)), Some(p)) => {
                        assert!(m > -1e-2, "covered outside the triangle ({x}, {y})");
                        assert!((p - h).length() < 1e-3 * h.length().max(1.0), "{p} vs {h}");
                        assert!(fr.depth[i] >= NEAR_PLANE_M);
                        covered += 1;
                    }
                    (Some((m, _)), None) => assert!(m < 1e-2, "missed pixel ({x}, {y}) {m}"),
                    (None, Some(p)) => panic!("pixel ({x}, {y}) above the horizon drew {p}"),
                    (None, None) => {}
                }
            }
        }
        assert!(covered > 200, "{covered}");
    }
}

#[test]
fn reused_buffers_and_thread_count_do_not_change_the_result() {
    let (v, f) = uv_sphere(Vec3::new(0.1, 0.0, 0.0), 24, 48, |t, p| {
        1.0 + 0.2 * (3.0 * t).sin() * p.cos()
    });
    let c = Camera::look_at(
        Vec3::new(0.5, 2.0, 3.0),
        Vec3::ZERO,
        Vec3::Y,
        150.0,
        150.0,
        120,
        90,
    )
    .unwrap();
    let fresh = rasterize(&c, &v, &f).unwrap();
    // A buffer left over from a different, larger view.
    let big = Camera {
        width: 200,
        height: 170,
        ..c
    };
    let mut reused = rasterize(&big, &v, &f).unwrap();
    rasterize_into(&c, &v, &f, &mut reused).unwrap();
    assert_eq!(reused, fresh);
    let mut again = fresh.clone();
    rasterize_into(&c, &v, &f, &mut again).unwrap();
    assert_eq!(again, fresh);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    assert_eq!(one.install(|| rasterize(&c, &v, &f).unwrap()), fresh);
    assert!(fresh.face.iter().filter(|f| **f != EMPTY_FACE).count() > 1000);
}

#[test]
fn degenerate_and_bad_input_is_handled() {
    let c = front_camera(50.0, 32);
    let v = vec![
        Vec3::new(0.0, 0.0, 2.0),
        Vec3::new(0.5, 0.5, 2.0),
        Vec3::new(1.0, 1.0, 2.0), // collinear with the first two
        Vec3::new(f32::NAN, 0.0, 2.0),
        Vec3::new(0.0, 0.0, -2.0),
        Vec3::new(0.3, 0.0, -2.0),
        Vec3::new(0.0, 0.3, -2.0),
    ];
    let f = vec![[0, 1, 2], [0, 0, 1], [0, 1, 3], [4, 5, 6]];
    let fr = rasterize(&c, &v, &f).unwrap();
    assert!(fr.face.iter().all(|f| *f == EMPTY_FACE));
    let err = rasterize(&c, &v, &[[0, 1, 7]]).unwrap_err().to_string();
    assert!(err.contains("faces[0][2] = 7"), "{err}");
    assert!(visibility(&c, &v, &[[0, 9, 1]], 0.01).is_err());
}

#[test]
fn textured_render_samples_the_texture() {
    let c = front_camera(64.0, 64);
    // A square filling pixels [8, 56) at depth 2 (pixel i spans [i - 0.5, i + 0.5), so the
    // square's sides are at 7.5 and 55.5), uv = (0,0) bottom-left .. (1,1) top-right.
    let v = vec![
        unproject(&c, Vec2::new(7.5, 55.5), 2.0),
        unproject(&c, Vec2::new(55.5, 55.5), 2.0),
        unproject(&c, Vec2::new(55.5, 7.5), 2.0),
        unproject(&c, Vec2::new(7.5, 7.5), 2.0),
    ];
    let uv = vec![
        Vec2::new(0.0, 0.0),
        Vec2::new(1.0, 0.0),
        Vec2::new(1.0, 1.0),
        Vec2::new(0.0, 1.0),
    ];
    let f = vec![[0, 1, 2], [0, 2, 3]];
    // Texture: red grows with x, green with the row index (so with 1 - v).
    let tex = image::RgbImage::from_fn(48, 48, |x, y| {
        image::Rgb([(x * 5) as u8, (y * 5) as u8, 77])
    });
    let (img, mask) = render_textured(&c, &v, &f, &uv, &tex).unwrap();
    for y in 0..64u32 {
        for x in 0..64u32 {
            let inside = (8..56).contains(&x) && (8..56).contains(&y);
            assert_eq!(mask[(y * 64 + x) as usize], inside);
            let p = img.get_pixel(x, y).0;
            if inside {
                // One output pixel = one texel here, aligned: exact texel values.
                assert_eq!(
                    p,
                    [((x - 8) * 5) as u8, ((y - 8) * 5) as u8, 77],
                    "({x},{y})"
                );
            } else {
                assert_eq!(p, [0, 0, 0]);
            }
        }
    }
    assert!(render_textured(&c, &v, &f, &uv[..3], &tex).is_err());
}

// ---------------------------------------------------------------- visibility

fn front_facing_cos(cam: Vec3, v: Vec3, n: Vec3) -> f32 {
    (cam - v).normalize().dot(n)
}

/// Largest `cos` between the view direction and the normals of the faces around each vertex:
/// on a convex polyhedron a vertex is seen iff one of its faces is front-facing (`cos > 0`).
fn face_cosines(eye: Vec3, v: &[Vec3], f: &[[u32; 3]]) -> Vec<f32> {
    let mut cos = vec![f32::NEG_INFINITY; v.len()];
    for tri in f {
        let [a, b, c] = tri.map(|k| v[k as usize]);
        let n = (b - a).cross(c - a).normalize();
        for k in tri {
            let p = v[*k as usize];
            cos[*k as usize] = cos[*k as usize].max(front_facing_cos(eye, p, n));
        }
    }
    cos
}

/// Agreement with the analytic front-facing set: exact away from the silhouette
/// (`|cos| > 0.2`), and overall above 97% (the rest is a sub-pixel band around the limb).
fn check_visibility(vis: &[u8], cosines: &[f32], name: &str) {
    let mut agree = 0;
    for (i, (&s, &cos)) in vis.iter().zip(cosines).enumerate() {
        if (s == 1) == (cos > 0.0) {
            agree += 1;
        } else {
            assert!(
                cos.abs() <= 0.2,
                "{name}: vertex {i} cos {cos} visibility {s}"
            );
        }
    }
    let frac = agree as f32 / vis.len() as f32;
    assert!(frac > 0.97, "{name}: agreement {frac}");
}

#[test]
fn sphere_and_cube_visibility_match_front_facing() {
    let (sv, sf) = uv_sphere(Vec3::ZERO, 48, 96, |_, _| 1.0);
    let (cv, cf) = cube(16);
    // A generic view, one with both poles of the UV sphere on the silhouette (densest rings in
    // the ambiguous band), one along a cube diagonal. The sphere spans ~200 pixels.
    for dir in [
        Vec3::new(0.7, -0.9, 3.3),
        Vec3::new(0.1, 5.0, 0.3),
        Vec3::new(1.0, 1.0, 1.0),
    ] {
        let eye = dir.normalize() * 4.5;
        let up = if dir.y.abs() > 4.0 { Vec3::Z } else { Vec3::Y };
        let c = Camera::look_at(eye, Vec3::ZERO, up, 450.0, 450.0, 512, 512).unwrap();
        let vis = visibility(&c, &sv, &sf, DEFAULT_DEPTH_TOL_M).unwrap();
        check_visibility(&vis, &face_cosines(eye, &sv, &sf), "sphere (face normals)");
        // The smooth sphere's normals: same guarantee away from the silhouette.
        let smooth: Vec<f32> = sv
            .iter()
            .map(|p| front_facing_cos(eye, *p, p.normalize()))
            .collect();
        for (i, (&s, &cos)) in vis.iter().zip(&smooth).enumerate() {
            assert!(
                cos.abs() <= 0.2 || (s == 1) == (cos > 0.0),
                "sphere vertex {i}"
            );
        }
        let vis = visibility(&c, &cv, &cf, DEFAULT_DEPTH_TOL_M).unwrap();
        check_visibility(&vis, &face_cosines(eye, &cv, &cf), "cube");
    }
}

#[test]
fn occluded_front_facing_vertices_are_invisible() {
    // Sphere B behind sphere A as seen from the camera.
    let eye = Vec3::new(0.0, 0.0, 5.0);
    let c = Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 200.0, 200.0, 192, 192).unwrap();
    let (mut v, mut f) = uv_sphere(Vec3::ZERO, 32, 64, |_, _| 0.6);
    let nb = v.len() as u32;
    let centre_b = Vec3::new(0.5, 0.0, -2.0);
    let (vb, fb) = uv_sphere(centre_b, 32, 64, |_, _| 1.0);
    v.extend(&vb);
    f.extend(fb.iter().map(|t| t.map(|k| k + nb)));
    let fr = rasterize(&c, &v, &f).unwrap();
    let vis = vertex_visibility(&c, &v, &f, &fr, DEFAULT_DEPTH_TOL_M).unwrap();
    let (mut hidden, mut shown) = (0, 0);
    for (i, p) in vb.iter().enumerate() {
        let s = vis[nb as usize + i];
        let cos = front_facing_cos(eye, *p, (*p - centre_b).normalize());
        // Distance from sphere A's centre (origin) to the line eye -> p.
        let d = (p - eye).normalize();
        let line_dist = (-eye - d * (-eye).dot(d)).length();
        // A's silhouette is ~24 px in radius; stay 10% (2.4 px) away from it on both sides,
        // beyond the one-pixel neighbourhood the visibility test consults.
        if line_dist < 0.6 * 0.9 {
            assert_eq!(s, 0, "B vertex {i} behind A is visible");
            hidden += 1;
        } else if line_dist > 0.6 * 1.1 && cos > 0.2 {
            assert_eq!(s, 1, "B vertex {i} in plain view is invisible");
            shown += 1;
        }
    }
    assert!(hidden > 50 && shown > 50, "{hidden} {shown}");
    // Wrong fragment size: an error.
    let other = Camera { width: 10, ..c };
    assert!(vertex_visibility(&other, &v, &f, &fr, 0.01).is_err());
}

// ---------------------------------------------------------------- surface

fn brute_nearest(v: &[Vec3], f: &[[u32; 3]], p: Vec3) -> f32 {
    f.iter()
        .map(|t| {
            let [a, b, c] = t.map(|k| v[k as usize]);
            (closest_point_on_triangle(p, a, b, c).0 - p).length_squared()
        })
        .fold(f32::INFINITY, f32::min)
}

#[test]
fn nearest_matches_brute_force() {
    let (mut v, mut f) = uv_sphere(Vec3::ZERO, 30, 60, |t, p| {
        1.0 + 0.25 * (3.0 * t).sin() * (2.0 * p).cos()
    });
    // Add a few degenerate faces (zero area, repeated vertices) and a far-off sliver.
    let nv = v.len() as u32;
    v.extend([
        Vec3::new(3.0, 0.0, 0.0),
        Vec3::new(3.0, 0.0, 0.0),
        Vec3::new(3.0, 1.0, 0.0),
    ]);
    f.extend([[nv, nv + 1, nv + 2], [0, 0, 1], [5, 6, 5]]);
    let index = SurfaceIndex::new(&v, &f).unwrap();
    let mut rng = Rng::new(42);
    let mut points = Vec::new();
    for _ in 0..2500 {
        // Near the surface: a surface sample pushed by up to 10 cm.
        let t = &f[rng.below(f.len())];
        let (a, b) = (rng.uniform(), rng.uniform());
        let (a, b) = if a + b > 1.0 {
            (1.0 - a, 1.0 - b)
        } else {
            (a, b)
        };
        let s = v[t[0] as usize] * (1.0 - a - b) + v[t[1] as usize] * a + v[t[2] as usize] * b;
        let dir = Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize_or_zero();
        points.push(s + dir * rng.range(0.0, 0.1));
    }
    for _ in 0..1000 {
        points.push(Vec3::new(
            rng.range(-5.0, 5.0),
            rng.range(-5.0, 5.0),
            rng.range(-5.0, 5.0),
        ));
    }
    let batch = index.nearest_batch(&points);
    for (p, n) in points.iter().zip(&batch) {
        let brute = brute_nearest(&v, &f, *p);
        assert!(n.is_hit());
        assert!(
            (n.dist2 - brute).abs() <= 1e-5 * brute.max(1e-3),
            "{p}: bvh {} brute {brute}",
            n.dist2
        );
        assert!(((n.point - *p).length_squared() - n.dist2).abs() <= 1e-5 * n.dist2.max(1e-3));
        let b = n.bary;
        assert!(b.iter().all(|x| *x >= -1e-6) && (b[0] + b[1] + b[2] - 1.0).abs() < 1e-5);
        let [ia, ib, ic] = f[n.face as usize].map(|k| v[k as usize]);
        assert!((ia * b[0] + ib * b[1] + ic * b[2] - n.point).length() < GEOM_TOL);
    }
    assert_eq!(index.nearest(points[7]), batch[7]);
    // Bounded queries.
    for p in points.iter().take(500) {
        let n = index.nearest(*p);
        let d = n.dist();
        assert_eq!(
            index.nearest_within(*p, d * 1.01 + 1e-6).map(|m| m.dist2),
            Some(n.dist2)
        );
        if d > 1e-3 {
            assert!(index.nearest_within(*p, d * 0.99).is_none());
        }
    }
    assert!(!index.nearest(Vec3::NAN).is_hit());
    assert!(index.nearest_within(Vec3::ZERO, -1.0).is_none());
    assert!(SurfaceIndex::new(&v, &[]).is_err());
    assert!(SurfaceIndex::new(&v, &[[0, 1, 100000]]).is_err());
}

#[test]
fn closest_point_regions() {
    let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
    let cases = [
        (
            Vec3::new(0.2, 0.3, 0.5),
            Vec3::new(0.2, 0.3, 0.0),
            [0.5, 0.2, 0.3],
        ), // face
        (Vec3::new(-1.0, -1.0, 0.2), a, [1.0, 0.0, 0.0]), // vertex a
        (Vec3::new(2.0, -0.5, 0.0), b, [0.0, 1.0, 0.0]),  // vertex b
        (Vec3::new(-0.2, 3.0, 0.0), c, [0.0, 0.0, 1.0]),  // vertex c
        (
            Vec3::new(0.4, -2.0, 1.0),
            Vec3::new(0.4, 0.0, 0.0),
            [0.6, 0.4, 0.0],
        ), // edge ab
        (
            Vec3::new(-1.0, 0.7, 0.0),
            Vec3::new(0.0, 0.7, 0.0),
            [0.3, 0.0, 0.7],
        ), // edge ac
        (
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.5, 0.5, 0.0),
            [0.0, 0.5, 0.5],
        ), // edge bc
    ];
    for (p, q, bary) in cases {
        let (got, gb) = closest_point_on_triangle(p, a, b, c);
        assert!((got - q).length() < 1e-6, "{p}: {got} vs {q}");
        for k in 0..3 {
            assert!((gb[k] - bary[k]).abs() < 1e-6, "{p}: {gb:?} vs {bary:?}");
        }
    }
    // Degenerate: a segment and a point.
    let (q, bary) = closest_point_on_triangle(Vec3::new(0.5, 1.0, 0.0), a, b, b * 0.5);
    assert!((q - Vec3::new(0.5, 0.0, 0.0)).length() < 1e-6);
    assert!((bary.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    let (q, _) = closest_point_on_triangle(Vec3::ONE, a, a, a);
    assert_eq!(q, a);
}

#[test]
fn interpolation_helpers_reproduce_linear_data() {
    let (v, f) = cube(3);
    let index = SurfaceIndex::new(&v, &f).unwrap();
    let xs: Vec<f32> = v.iter().map(|p| p.x).collect();
    let flat: Vec<f32> = v.iter().flat_map(|p| p.to_array()).collect();
    let mut rng = Rng::new(9);
    let mut out = [0.0f32; 3];
    for _ in 0..300 {
        let p = Vec3::new(
            rng.range(-2.0, 2.0),
            rng.range(-2.0, 2.0),
            rng.range(-2.0, 2.0),
        );
        let n = index.nearest(p);
        let x = interpolate_scalar(&n, index.faces(), &xs).unwrap();
        assert!((x - n.point.x).abs() < 1e-5);
        interpolate_weights(&n, index.faces(), &flat, 3, &mut out).unwrap();
        assert!((Vec3::from(out) - n.point).length() < 1e-5);
    }
    let n = index.nearest(Vec3::ZERO);
    assert!(interpolate_scalar(&n, index.faces(), &xs[..2]).is_err());
    assert!(interpolate_scalar(&nia_data::surface::Nearest::MISS, index.faces(), &xs).is_err());
    assert!(interpolate_weights(&n, index.faces(), &flat, 3, &mut [0.0; 2]).is_err());
    assert!(interpolate_weights(&n, index.faces(), &flat[..10], 3, &mut out).is_err());
}
