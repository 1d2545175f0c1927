//! The rasteriser: coverage, pixel centres, barycentrics, clipping, bad input.

use super::*;

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
