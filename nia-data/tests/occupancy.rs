//! The occupancy grid keeps every point near the surface or inside the body (conservative),
//! skips space far from it, and refuses bad settings.

use glam::Vec3;
use nia_data::body::{ProceduralBody, ProceduralSpec};
use nia_data::geometry::occupancy::{OccupancyError, OccupancyGrid};
use nia_data::geometry::surface::SurfaceIndex;
use nia_data::rng::Rng;

/// A UV sphere of radius `r` centred at `c`.
fn sphere(c: Vec3, r: f32, rings: usize, segments: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut v = vec![c + Vec3::new(0.0, r, 0.0)];
    for i in 1..rings {
        let th = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..segments {
            let ph = 2.0 * std::f32::consts::PI * j as f32 / segments as f32;
            v.push(c + r * Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()));
        }
    }
    v.push(c - Vec3::new(0.0, r, 0.0));
    let last = (v.len() - 1) as u32;
    let at = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
    let mut f = Vec::new();
    for j in 0..segments {
        f.push([0, at(1, j + 1), at(1, j)]);
        f.push([last, at(rings - 1, j), at(rings - 1, j + 1)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            f.push([at(i, j), at(i, j + 1), at(i + 1, j)]);
            f.push([at(i + 1, j), at(i, j + 1), at(i + 1, j + 1)]);
        }
    }
    (v, f)
}

/// The procedural body's template mesh at about `target_vertices` vertices (2 cm grid).
fn procedural_body(target_vertices: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let body = ProceduralBody::new(&ProceduralSpec {
        grid_step_m: 0.02,
        target_vertices,
        ..ProceduralSpec::default()
    })
    .unwrap()
    .build()
    .unwrap();
    (body.v_template, body.faces)
}

#[test]
fn sphere_keeps_the_shell_and_the_inside_and_skips_the_rest() {
    let (r, threshold, cell) = (0.3, 0.05, 0.02);
    let c = Vec3::new(0.1, 1.0, -0.2);
    let (v, f) = sphere(c, r, 48, 96);
    let grid = OccupancyGrid::build(&v, &f, threshold, cell).unwrap();
    // A kept cell reaches at most threshold + a cell diagonal beyond the surface.
    let far = r + threshold + cell * 3f32.sqrt() + 1e-3;
    let mut rng = Rng::new(1);
    let (mut near_checked, mut far_checked) = (0, 0);
    for _ in 0..50_000 {
        let p = c + Vec3::new(
            rng.uniform() * 1.0 - 0.5,
            rng.uniform() * 1.0 - 0.5,
            rng.uniform() * 1.0 - 0.5,
        );
        let d = (p - c).length();
        // The polygon is inside the sphere by at most r (1 - cos(pi/48)) ~ 0.6 mm.
        if d <= r + threshold - 1e-3 {
            assert!(
                grid.occupied(p),
                "point at {d} m from the centre was skipped"
            );
            near_checked += 1;
        } else if d > far {
            assert!(!grid.occupied(p), "point at {d} m from the centre was kept");
            far_checked += 1;
        }
    }
    assert!(near_checked > 1000 && far_checked > 1000);
    // Deep inside (0.25 m from the surface, far beyond the threshold) is kept.
    assert!(grid.occupied(c));
    assert!(!grid.occupied(Vec3::new(f32::NAN, 0.0, 0.0)));
    assert!(!grid.occupied(c + Vec3::splat(5.0)));
}

#[test]
fn body_mesh_points_within_the_threshold_are_always_kept() {
    let (v, f) = procedural_body(1500);
    let threshold = 0.04;
    let grid = OccupancyGrid::build(&v, &f, threshold, 0.02).unwrap();
    let index = SurfaceIndex::new(&v, &f).unwrap();
    let lo = v.iter().fold(Vec3::splat(f32::MAX), |a, &b| a.min(b)) - Vec3::splat(0.1);
    let hi = v.iter().fold(Vec3::splat(f32::MIN), |a, &b| a.max(b)) + Vec3::splat(0.1);
    let mut rng = Rng::new(2);
    let (mut kept, mut total) = (0usize, 0usize);
    for _ in 0..40_000 {
        let t = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
        let p = lo + (hi - lo) * t;
        let d = index.nearest(p).dist2.sqrt();
        if d <= threshold {
            assert!(grid.occupied(p), "point {d} m from the surface was skipped");
        }
        kept += grid.occupied(p) as usize;
        total += 1;
    }
    // Most of the body's padded box is empty space.
    let share = kept as f64 / total as f64;
    assert!(share < 0.5, "kept share of the box {share}");
}

#[test]
fn bad_settings_are_refused() {
    let (v, f) = sphere(Vec3::ZERO, 0.3, 8, 16);
    assert!(matches!(
        OccupancyGrid::build(&v, &f, 0.05, 0.0),
        Err(OccupancyError::Setting {
            field: "cell_m",
            ..
        })
    ));
    assert!(matches!(
        OccupancyGrid::build(&v, &f, f32::NAN, 0.02),
        Err(OccupancyError::Setting {
            field: "threshold_m",
            ..
        })
    ));
    assert_eq!(
        OccupancyGrid::build(&[], &[], 0.05, 0.02),
        Err(OccupancyError::EmptyMesh)
    );
    assert!(matches!(
        OccupancyGrid::build(&v, &[[0, 1, 999]], 0.05, 0.02),
        Err(OccupancyError::Face { vertex: 999, .. })
    ));
    assert!(matches!(
        OccupancyGrid::build(&v, &f, 0.05, 1e-4),
        Err(OccupancyError::TooLarge { .. })
    ));
}

/// A name, vertices and faces.
type NamedMesh = (&'static str, Vec<Vec3>, Vec<[u32; 3]>);

/// A body with thin limbs, a closed cavity (a sphere inside a sphere: the shell between them
/// is inside, the hollow is not reachable from outside) and a triangle soup.
fn assorted_meshes() -> Vec<NamedMesh> {
    let (body_v, body_f) = procedural_body(3000);
    let (mut hollow_v, mut hollow_f) = sphere(Vec3::new(0.0, 1.0, 0.0), 0.4, 24, 48);
    let (inner_v, inner_f) = sphere(Vec3::new(0.05, 1.0, 0.0), 0.2, 12, 24);
    let base = hollow_v.len() as u32;
    hollow_v.extend(inner_v);
    hollow_f.extend(inner_f.iter().map(|f| f.map(|i| i + base)));
    let mut rng = Rng::new(7);
    let mut soup_v = Vec::new();
    let mut soup_f = Vec::new();
    for t in 0..400u32 {
        let c = Vec3::new(rng.uniform(), rng.uniform() * 1.5, rng.uniform() * 0.5);
        for _ in 0..3 {
            soup_v.push(c + 0.08 * Vec3::new(rng.normal(), rng.normal(), rng.normal()));
        }
        soup_f.push([3 * t, 3 * t + 1, 3 * t + 2]);
    }
    // A degenerate face (three equal points) and a sliver.
    soup_v.extend([Vec3::splat(0.3), Vec3::splat(0.3), Vec3::splat(0.3)]);
    soup_f.push([1200, 1201, 1202]);
    vec![
        ("body", body_v, body_f),
        ("hollow sphere", hollow_v, hollow_f),
        ("triangle soup", soup_v, soup_f),
    ]
}

#[test]
fn cell_by_cell_build_marks_exactly_the_cells_of_the_face_by_face_build() {
    for (name, v, f) in assorted_meshes() {
        for (threshold, cell) in [(0.03, 0.02), (0.05, 0.02), (0.03, 0.01), (0.0, 0.015)] {
            let fast = OccupancyGrid::build(&v, &f, threshold, cell).unwrap();
            let reference = OccupancyGrid::build_face_by_face(&v, &f, threshold, cell).unwrap();
            assert_eq!(fast.dims(), reference.dims(), "{name} {threshold} {cell}");
            assert!(
                fast == reference,
                "{name} at {threshold} m, {cell} m cells: the grids differ"
            );
        }
    }
}

#[test]
fn the_inside_of_a_closed_shell_is_kept_and_a_sealed_hollow_too() {
    // The hollow inside the inner sphere is not connected to the border: it is kept, like any
    // inside. Space between the spheres is inside the outer one: kept.
    let (_, v, f) = assorted_meshes().swap_remove(1);
    let grid = OccupancyGrid::build(&v, &f, 0.02, 0.02).unwrap();
    assert!(grid.occupied(Vec3::new(0.05, 1.0, 0.0)));
    assert!(grid.occupied(Vec3::new(-0.3, 1.0, 0.0)));
    assert!(!grid.occupied(Vec3::new(-0.5, 1.0, 0.0)));
    assert!(!grid.occupied(Vec3::new(0.0, 1.5, 0.0)));
}

#[test]
fn a_non_finite_vertex_is_refused_by_name() {
    let (mut v, f) = sphere(Vec3::ZERO, 0.3, 16, 32);
    v[5].y = f32::NAN;
    for build in [OccupancyGrid::build, OccupancyGrid::build_face_by_face] {
        let err = build(&v, &f, 0.03, 0.02).unwrap_err();
        assert!(
            matches!(err, OccupancyError::NonFiniteVertex { vertex: 5, .. }),
            "{err:?}"
        );
        assert!(err.to_string().contains("vertex 5"), "{err}");
    }
}

#[test]
fn any_within_agrees_with_the_nearest_distance() {
    let (_, v, f) = assorted_meshes().swap_remove(0);
    let index = SurfaceIndex::new(&v, &f).unwrap();
    let mut rng = Rng::new(11);
    let (mut near, mut far) = (0, 0);
    for _ in 0..20_000 {
        // Around a vertex, up to 15 cm off it, asked for up to 10 cm.
        let anchor = v[rng.below(v.len())];
        let p = anchor
            + 0.15
                * rng.uniform()
                * Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize_or_zero();
        let r = rng.uniform() * 0.1;
        let expected = index.nearest_within(p, r).is_some();
        assert_eq!(index.any_within(p, r), expected, "{p} at {r} m");
        if expected {
            near += 1;
        } else {
            far += 1;
        }
    }
    assert!(near > 1000 && far > 1000, "{near} near, {far} far");
    assert!(!index.any_within(Vec3::NAN, 1.0));
    assert!(!index.any_within(Vec3::ZERO, -1.0));
    assert!(!index.any_within(Vec3::ZERO, f32::NAN));
    assert!(index.any_within(v[0], 0.0));
}
