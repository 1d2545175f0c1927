//! Geometry core timings: rasteriser, vertex visibility and nearest-surface queries on a
//! body-sized mesh (6,856 vertices, 13,688 faces: six closed ellipsoids laid out like a
//! standing person, so limbs occlude each other) in 512x512 views.
//!
//! `CARGO_TARGET_DIR=/work/target-data cargo bench -p nia-data --bench geometry`
//! Plain `main` with `std::time::Instant`: warm-up, then the median and best of several
//! repetitions.

use glam::Vec3;
use nia_data::geometry::camera::Camera;
use nia_data::geometry::occupancy::OccupancyGrid;
use nia_data::geometry::raster::{rasterize, rasterize_into};
use nia_data::geometry::rays::{mask_at_box, near_far, Aabb, Ray};
use nia_data::geometry::surface::SurfaceIndex;
use nia_data::geometry::visibility::{vertex_visibility, visibility, DEFAULT_DEPTH_TOL_M};
use nia_data::rng::Rng;
use std::time::Instant;

#[path = "../tests/geometry/sphere.rs"]
mod sphere;
use sphere::{uv_sphere, Mesh};

const WARMUP: usize = 3;
const REPS: usize = 15;

/// The body's ellipsoids: centre and radii (metres), latitude rings, longitude segments.
const TRUNK: [([f32; 3], [f32; 3], u32, u32); 2] = [
    ([0.0, 1.2, 0.0], [0.19, 0.32, 0.12], 30, 60), // torso
    ([0.0, 1.63, 0.0], [0.09, 0.12, 0.1], 24, 48), // head
];

/// The limbs on the person's left (+x), mirrored to the right: arm, leg.
const LIMBS: [([f32; 3], [f32; 3], u32, u32); 2] = [
    ([0.26, 1.15, 0.05], [0.05, 0.33, 0.05], 26, 40),
    ([0.1, 0.45, 0.0], [0.075, 0.45, 0.08], 26, 40),
];

/// Torso, head, arms and legs (metres, y up, person ~1.75 m tall facing +z): each a unit
/// [`uv_sphere`] (z up) turned y up by swapping y and z, which mirrors it, so its triangles are
/// reversed to keep them outward, then scaled by the radii and moved to the centre.
fn body_like_mesh() -> Mesh {
    let mut parts = TRUNK.to_vec();
    for s in [-1.0f32, 1.0] {
        parts.extend(
            LIMBS.map(|([x, y, z], radii, n_lat, n_lon)| ([x * s, y, z], radii, n_lat, n_lon)),
        );
    }
    let (mut v, mut f) = (Vec::new(), Vec::new());
    for (centre, radii, n_lat, n_lon) in parts {
        let (sv, sf) = uv_sphere(Vec3::ZERO, n_lat, n_lon, |_, _| 1.0);
        let base = v.len() as u32;
        v.extend(
            sv.iter()
                .map(|p| Vec3::from(centre) + Vec3::new(p.x, p.z, p.y) * Vec3::from(radii)),
        );
        f.extend(sf.iter().map(|&[a, b, c]| [a + base, c + base, b + base]));
    }
    (v, f)
}

/// Runs `f` WARMUP + REPS times; returns (median, best) seconds.
fn time<T>(mut f: impl FnMut() -> T) -> (f64, f64) {
    for _ in 0..WARMUP {
        std::hint::black_box(f());
    }
    let mut t: Vec<f64> = (0..REPS)
        .map(|_| {
            let s = Instant::now();
            std::hint::black_box(f());
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    (t[REPS / 2], t[0])
}

fn report(name: &str, (median, best): (f64, f64), items: Option<(f64, &str)>) {
    match items {
        Some((n, unit)) => println!(
            "{name:<44} median {:>9.3} ms  best {:>9.3} ms  {:>12.0} {unit}/s (median)",
            median * 1e3,
            best * 1e3,
            n / median
        ),
        None => println!(
            "{name:<44} median {:>9.3} ms  best {:>9.3} ms",
            median * 1e3,
            best * 1e3
        ),
    }
}

fn main() {
    let (vertices, faces) = body_like_mesh();
    println!(
        "mesh: {} vertices, {} faces; rayon threads (default pool): {}",
        vertices.len(),
        faces.len(),
        rayon::current_num_threads()
    );
    // ZJU-like view at 512x512: the person spans most of the image height (~390 px).
    let camera = Camera::look_at(
        Vec3::new(0.6, 1.0, 2.4),
        Vec3::new(0.0, 0.9, 0.0),
        Vec3::Y,
        560.0,
        560.0,
        512,
        512,
    )
    .expect("camera");

    let frags = rasterize(&camera, &vertices, &faces).expect("raster");
    let covered = frags.face.iter().filter(|f| **f != u32::MAX).count();
    let vis = visibility(&camera, &vertices, &faces, DEFAULT_DEPTH_TOL_M).expect("vis");
    println!(
        "512x512 view: {covered} covered pixels, {} of {} vertices visible",
        vis.iter().map(|v| *v as usize).sum::<usize>(),
        vertices.len()
    );

    report(
        "rasterize 512x512",
        time(|| rasterize(&camera, &vertices, &faces).unwrap()),
        None,
    );
    let mut reused = frags.clone();
    report(
        "rasterize_into 512x512 (reused buffers)",
        time(|| rasterize_into(&camera, &vertices, &faces, &mut reused).unwrap()),
        None,
    );
    report(
        "visibility 512x512, reused buffers",
        time(|| {
            rasterize_into(&camera, &vertices, &faces, &mut reused).unwrap();
            vertex_visibility(&camera, &vertices, &faces, &reused, DEFAULT_DEPTH_TOL_M).unwrap()
        }),
        None,
    );
    report(
        "visibility 512x512 (rasterize + vertex test)",
        time(|| visibility(&camera, &vertices, &faces, DEFAULT_DEPTH_TOL_M).unwrap()),
        None,
    );
    report(
        "vertex_visibility only (given fragments)",
        time(|| {
            vertex_visibility(&camera, &vertices, &faces, &frags, DEFAULT_DEPTH_TOL_M).unwrap()
        }),
        None,
    );
    let bounds = Aabb::from_points(&vertices).unwrap().padded(0.05);
    report(
        "mask_at_box 512x512",
        time(|| mask_at_box(&camera, &bounds)),
        Some((512.0 * 512.0, "pixels")),
    );
    report(
        "undistort map 512x512",
        time(|| {
            Camera {
                dist: [-0.3, 0.1, 1e-3, -1e-3, 0.0],
                ..camera
            }
            .undistort_map()
            .unwrap()
        }),
        None,
    );

    // The occupancy grids (docs/speed.md): the renderer's (3 cm from the surface, 2 cm
    // cells), the band sampler's in training (5 cm, 2 cm cells) and 1 cm cells. `build` finds
    // the mesh's index in the memo after the first repetition (as a training scene finds the
    // one its loader built), so the BVH's own build is timed below, not here.
    for (threshold, cell) in [(0.03f32, 0.02f32), (0.05, 0.02), (0.03, 0.01)] {
        let what = format!("{:.0} cm, {:.0} cm cells", threshold * 100.0, cell * 100.0);
        report(
            &format!("occupancy face by face {what}"),
            time(|| OccupancyGrid::build_face_by_face(&vertices, &faces, threshold, cell).unwrap()),
            None,
        );
        report(
            &format!("occupancy build {what}"),
            time(|| OccupancyGrid::build(&vertices, &faces, threshold, cell).unwrap()),
            None,
        );
    }
    report(
        "SurfaceIndex::new (BVH build)",
        time(|| SurfaceIndex::new(&vertices, &faces).unwrap()),
        None,
    );
    let index = SurfaceIndex::new(&vertices, &faces).unwrap();
    // Query points within 10 cm of the surface: random surface samples pushed along a random
    // direction by up to 10 cm.
    let mut rng = Rng::new(2023);
    let n_points = 200_000;
    let points: Vec<Vec3> = (0..n_points)
        .map(|_| {
            let t = faces[rng.below(faces.len())];
            let (a, b) = (rng.uniform(), rng.uniform());
            let (a, b) = if a + b > 1.0 {
                (1.0 - a, 1.0 - b)
            } else {
                (a, b)
            };
            let s = vertices[t[0] as usize] * (1.0 - a - b)
                + vertices[t[1] as usize] * a
                + vertices[t[2] as usize] * b;
            let d = Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize_or_zero();
            s + d * rng.range(0.0, 0.1)
        })
        .collect();
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        let t = pool.install(|| time(|| index.nearest_batch(&points)));
        report(
            &format!("nearest_batch, {threads} thread(s), 200k pts <10 cm"),
            t,
            Some((n_points as f64, "queries")),
        );
        let t = pool.install(|| time(|| index.nearest_batch_within(&points, 0.1)));
        report(
            &format!("nearest_batch_within 0.1 m, {threads} thread(s)"),
            t,
            Some((n_points as f64, "queries")),
        );
    }
    // The renderer's order: 64 samples along each ray through the body's 30 cm band (points
    // within 15 cm of the surface kept, as a band sampler keeps them), consecutive points
    // near each other. docs/speed.md: starting each search from the previous point's face
    // made no difference here.
    let bounds = Aabb::from_points(&vertices).unwrap().padded(0.15);
    let mut ray_points = Vec::new();
    while ray_points.len() < n_points {
        let eye = Vec3::new(rng.range(-2.5, 2.5), rng.range(0.0, 2.0), 2.5);
        let target = Vec3::new(
            rng.range(-0.4, 0.4),
            rng.range(0.0, 1.8),
            rng.range(-0.2, 0.2),
        );
        let dir = (target - eye).normalize();
        let Some((near, far)) = near_far(&Ray { origin: eye, dir }, &bounds) else {
            continue;
        };
        ray_points.extend(
            (0..64)
                .map(|s| eye + dir * (near + (far - near) * (s as f32 + 0.5) / 64.0))
                .filter(|&p| index.nearest_within(p, 0.15).is_some()),
        );
    }
    println!(
        "{} points along rays, within 15 cm of the surface",
        ray_points.len()
    );
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        let n = ray_points.len() as f64;
        let t = pool.install(|| time(|| index.nearest_batch(&ray_points)));
        report(
            &format!("nearest_batch along rays, {threads} thread(s)"),
            t,
            Some((n, "queries")),
        );
    }
}
