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
    let body = ProceduralBody::new(&ProceduralSpec {
        grid_step_m: 0.02,
        target_vertices: 1500,
        ..ProceduralSpec::default()
    })
    .unwrap()
    .build()
    .unwrap();
    let (v, f) = (body.v_template.clone(), body.faces.clone());
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
