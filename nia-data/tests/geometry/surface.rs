//! Nearest-surface queries and interpolation helpers against brute force.

use super::*;

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
    assert!(interpolate_scalar(
        &nia_data::geometry::surface::Nearest::MISS,
        index.faces(),
        &xs
    )
    .is_err());
    assert!(interpolate_weights(&n, index.faces(), &flat, 3, &mut [0.0; 2]).is_err());
    assert!(interpolate_weights(&n, index.faces(), &flat[..10], 3, &mut out).is_err());
}
