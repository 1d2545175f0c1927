//! Rays and boxes: pixel rays, near/far, AABB helpers, the box mask.

use super::*;

/// The ray through a projected point's pixel position passes through the point; the rays of
/// whole images (`image_rays`, `RayBundle::through_pixels`) are those pixel rays at the pixel
/// centres.
#[test]
fn pixel_ray_passes_through_projected_points() {
    let (eye, target) = (Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.0, 0.8, 0.0));
    let c = Camera::look_at(eye, target, Vec3::Y, 400.0, 410.0, 200, 150).unwrap();
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
    // A box around the camera and the scene keeps every pixel, in order, one centre ray each.
    let around = Aabb::new(Vec3::splat(-10.0), Vec3::splat(10.0));
    let bundle = RayBundle::through_pixels(&c, &around, None);
    assert_eq!(bundle.len(), all.len());
    for (i, ray) in all.iter().enumerate() {
        assert_eq!(bundle.pixels[i], i as u32);
        assert_eq!((bundle.origins[i], bundle.dirs[i]), (ray.origin, ray.dir));
        assert!(bundle.far[i] > bundle.near[i]);
    }
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
    let (eye, target) = (Vec3::new(2.0, 1.5, 3.5), Vec3::new(0.0, 0.1, 0.0));
    let c = Camera::look_at(eye, target, Vec3::Y, 180.0, 180.0, 128, 96).unwrap();
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

/// Supersampling: s x s rays per pixel through the centres of the s x s cells of the pixel's
/// square, all of a pixel's rays kept when one crosses the box (those that miss as zero-length
/// rays), and s = 1 is the one centre ray of `through_pixels`.
#[test]
fn pixel_footprints_cover_the_pixel_square() {
    let (eye, target) = (Vec3::new(0.0, 0.5, 3.0), Vec3::new(0.0, 0.5, 0.0));
    let c = Camera::look_at(eye, target, Vec3::Y, 60.0, 60.0, 32, 24).unwrap();
    let aabb = Aabb::new(Vec3::new(-0.3, 0.0, -0.3), Vec3::new(0.3, 1.0, 0.3));
    let one = RayBundle::through_pixels(&c, &aabb, None);
    assert_eq!(RayBundle::through_pixel_footprints(&c, &aabb, None, 1), one);
    assert!(
        !one.is_empty() && one.len() < 32 * 24,
        "the box covers part of the image"
    );

    let s = 3;
    let many = RayBundle::through_pixel_footprints(&c, &aabb, None, s);
    assert_eq!(many.len() % (s * s), 0);
    let mut pixels: Vec<u32> = many.pixels.chunks(s * s).map(|p| p[0]).collect();
    for (chunk, &p) in many.pixels.chunks(s * s).zip(&pixels) {
        assert!(chunk.iter().all(|&q| q == p), "a pixel's rays are together");
    }
    // Every pixel whose centre ray crosses the box is there, and a few more at the outline.
    assert!(one.pixels.iter().all(|p| pixels.contains(p)));
    assert!(pixels.len() > one.len());
    pixels.dedup();
    assert_eq!(pixels.len() * s * s, many.len(), "each pixel once");
    let mut zero_length = 0;
    for (k, chunk) in (0..many.len())
        .collect::<Vec<_>>()
        .chunks(s * s)
        .enumerate()
    {
        let p = pixels[k] as usize;
        let (x, y) = ((p % 32) as f32, (p / 32) as f32);
        for (cell, &i) in chunk.iter().enumerate() {
            // The ray passes through the centre of its cell: 1/3 px apart, within the pixel.
            let expected = Vec2::new(
                x + (cell % s) as f32 / 3.0 - 1.0 / 3.0,
                y + (cell / s) as f32 / 3.0 - 1.0 / 3.0,
            );
            let through = c.project(many.origins[i] + many.dirs[i]).unwrap().0;
            assert!(
                (through - expected).length() < 1e-3,
                "{through} vs {expected}"
            );
            if many.near[i] == many.far[i] {
                zero_length += 1;
                assert!(
                    near_far(&pixel_ray(&c, expected), &aabb).is_none_or(|(near, far)| far <= near)
                );
            } else {
                assert!(many.far[i] > many.near[i]);
            }
        }
    }
    assert!(
        zero_length > 0,
        "rays of outline pixels that miss the box are kept"
    );
}

/// The footprint bundle tests only the pixels of the box's projected rectangle
/// (`box_pixel_bounds`): the same rays, in the same order, as testing every pixel, for boxes
/// inside the image, cut by its edges, off the image, with the camera inside the box, and with
/// a skewed `K`; supersampled and not.
#[test]
fn the_box_rectangle_leaves_out_only_pixels_whose_rays_miss() {
    let every_pixel = |c: &Camera, aabb: &Aabb, s: usize| {
        let mut bundle = RayBundle::default();
        let (w, h) = (c.width as usize, c.height as usize);
        for p in 0..w * h {
            let centre = pixel_centre(p % w, p / w);
            let rays: Vec<_> = (0..s * s)
                .map(|k| {
                    let cell = |i: usize| (i as f32 + 0.5) / s as f32 - 0.5;
                    let ray = pixel_ray(c, centre + Vec2::new(cell(k % s), cell(k / s)));
                    (ray, near_far(&ray, aabb).filter(|(n, f)| f > n))
                })
                .collect();
            if rays.iter().any(|(_, i)| i.is_some()) {
                for (ray, i) in rays {
                    let (n, f) = i.unwrap_or((0.0, 0.0));
                    bundle.push(ray, n, f, p as u32);
                }
            }
        }
        bundle
    };
    let body = Aabb::new(Vec3::new(-0.3, 0.0, -0.3), Vec3::new(0.3, 1.0, 0.3));
    let look = |eye: Vec3, target: Vec3| {
        Camera::look_at(eye, target, Vec3::Y, 60.0, 60.0, 48, 40).unwrap()
    };
    let mut skewed = look(Vec3::new(0.4, 0.6, 2.5), Vec3::new(0.0, 0.5, 0.0));
    skewed.k.y_axis.x = 4.0; // K[0][1], the skew
    let cases = [
        (
            "inside the image",
            look(Vec3::new(0.0, 0.5, 3.0), Vec3::new(0.0, 0.5, 0.0)),
            body,
        ),
        (
            "cut by the edges",
            look(Vec3::new(0.0, 0.5, 1.0), Vec3::new(0.3, 0.9, 0.0)),
            body,
        ),
        (
            "off the image",
            look(Vec3::new(0.0, 0.5, 3.0), Vec3::new(3.0, 0.5, 0.0)),
            body,
        ),
        (
            "camera inside",
            look(Vec3::new(0.0, 0.5, 0.0), Vec3::new(0.0, 0.5, 1.0)),
            body,
        ),
        ("skewed K", skewed, body),
    ];
    for (what, c, aabb) in cases {
        let ([x0, x1], [y0, y1]) = box_pixel_bounds(&c, &aabb);
        assert!(x0 <= x1 && x1 <= 48 && y0 <= y1 && y1 <= 40, "{what}");
        for s in [1, 2] {
            let fast = RayBundle::through_pixel_footprints(&c, &aabb, None, s);
            assert_eq!(fast, every_pixel(&c, &aabb, s), "{what}, {s} x {s} rays");
        }
        if what == "inside the image" {
            assert!((x1 - x0) * (y1 - y0) < 48 * 40 / 2, "the rectangle narrows");
        }
        if what == "camera inside" {
            assert_eq!((x0, x1, y0, y1), (0, 48, 0, 40), "the whole image");
        }
    }
}

/// `RayBundle::select` keeps the named rays in the order named, every field with them, and
/// agrees with `slice` on a range.
#[test]
fn select_keeps_the_named_rays_in_order() {
    let camera = Camera::look_at(
        Vec3::new(0.0, 0.5, 3.0),
        Vec3::new(0.0, 0.5, 0.0),
        Vec3::Y,
        60.0,
        60.0,
        8,
        6,
    )
    .unwrap();
    let body = Aabb::new(Vec3::new(-0.3, 0.0, -0.3), Vec3::new(0.3, 1.0, 0.3));
    let bundle = RayBundle::through_pixels(&camera, &body, None);
    assert!(bundle.len() > 4, "{} rays", bundle.len());
    let index = [3, 0, 3, bundle.len() - 1];
    let picked = bundle.select(&index);
    assert_eq!(picked.len(), index.len());
    for (j, &r) in index.iter().enumerate() {
        assert_eq!(picked.origins[j], bundle.origins[r]);
        assert_eq!(picked.dirs[j], bundle.dirs[r]);
        assert_eq!(
            (picked.near[j], picked.far[j]),
            (bundle.near[r], bundle.far[r])
        );
        assert_eq!(picked.pixels[j], bundle.pixels[r]);
    }
    let range: Vec<usize> = (1..4).collect();
    assert_eq!(bundle.select(&range), bundle.slice(1..4));
    assert!(bundle.select(&[]).is_empty());
}
