//! The reposing transform of pose animation on the procedural body: the identity, vertex
//! correspondence between poses, exact rigid maps for a global change, directions following a
//! rotated limb, the near-singular fallback, far and non-finite points, and input errors.

use std::sync::OnceLock;
use std::time::Instant;

use glam::Vec3;
use nia_data::body::reposing::{Reposer, RepositionError};
use nia_data::body::{
    pose_for_motion, rodrigues, BodyModel, MotionKind, ProceduralBody, ProceduralSpec, SmplParams,
    NUM_JOINTS,
};
use nia_data::rng::Rng;

/// Target vertices mapped to the reference pose vs the reference vertices, metres. At a vertex
/// the nearest target face gives that vertex's own weights (barycentrics (1, 0, 0)), so the
/// map is the vertex's own skinning undone and redone: what remains is f32 round-off of ~2 m
/// coordinates through two transforms (~1e-6 m; measured 4e-7 m), plus the canonical point
/// landing a round-off away from the canonical vertex, which mixes in the neighbours' weights
/// by a negligible fraction. Off the vertices the face-interpolated weights differ from any
/// vertex's: that is the method, not an error, and is not tested against a tolerance.
const VERTEX_TOL_M: f32 = 1e-5;

/// A rigid map of coordinates up to ~3 m in f32: a few ulps (2.4e-7 m each) per operation.
const RIGID_TOL_M: f32 = 1e-5;

/// Unit directions after an f64 transform rounded to f32.
const DIR_TOL: f32 = 1e-5;

/// Rotation of the left elbow in the limb test, radians.
const ELBOW_ANGLE: f32 = 1.1;

/// SMPL joint indices used below.
const L_SHOULDER: usize = 16;
const L_ELBOW: usize = 18;

fn model() -> &'static BodyModel {
    static MODEL: OnceLock<BodyModel> = OnceLock::new();
    MODEL.get_or_init(|| {
        ProceduralBody::generate(&ProceduralSpec::default()).expect("procedural body builds")
    })
}

fn params(poses: [f32; 72], rh: [f32; 3], th: [f32; 3]) -> SmplParams {
    SmplParams {
        poses,
        shapes: vec![0.5, -0.3, 0.2],
        rh: rh.into(),
        th: th.into(),
    }
}

fn random_unit(rng: &mut Rng) -> Vec3 {
    loop {
        let v = Vec3::new(rng.normal(), rng.normal(), rng.normal());
        if v.length() > 1e-3 {
            return v.normalize();
        }
    }
}

/// `count` points around the vertices, Gaussian offsets of `sigma` metres.
fn points_near(vertices: &[Vec3], count: usize, sigma: f32, rng: &mut Rng) -> Vec<Vec3> {
    (0..count)
        .map(|_| {
            let v = vertices[rng.below(vertices.len())];
            v + Vec3::new(rng.normal(), rng.normal(), rng.normal()) * sigma
        })
        .collect()
}

/// The largest distance between corresponding points.
fn worst_distance(a: &[Vec3], b: &[Vec3]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0f32, f32::max)
}

fn walk_reference() -> SmplParams {
    params(
        pose_for_motion(0.3, MotionKind::Walk),
        [0.0, 0.4, 0.0],
        [0.1, 0.9, -0.2],
    )
}

fn arm_swing_target() -> SmplParams {
    params(
        pose_for_motion(0.9, MotionKind::ArmSwing),
        [0.1, -0.5, 0.05],
        [-0.3, 1.0, 0.4],
    )
}

#[test]
fn identity_is_exact_and_not_needed() {
    let reference = walk_reference();
    assert!(!Reposer::needed(&reference, &reference.clone()));
    // Missing shape coefficients count as zero.
    let mut padded = reference.clone();
    padded.shapes.extend([0.0; 7]);
    assert!(!Reposer::needed(&reference, &padded));
    assert!(Reposer::needed(&reference, &arm_swing_target()));

    let reposer = Reposer::new(model(), &reference, &padded).unwrap();
    assert!(reposer.is_identity());
    assert_eq!(reposer.target_vertices(), reposer.reference_vertices());
    let mut rng = Rng::new(1);
    let points = points_near(reposer.target_vertices(), 500, 0.05, &mut rng);
    let dirs: Vec<Vec3> = (0..500).map(|_| random_unit(&mut rng)).collect();
    let out = reposer.map_points(&points, &dirs).unwrap();
    assert_eq!(out.points, points);
    assert_eq!(out.dirs, dirs);
    assert_eq!(out.fallback, 0);
}

#[test]
fn target_vertices_map_to_reference_vertices() {
    let (reference, target) = (walk_reference(), arm_swing_target());
    let reposer = Reposer::new(model(), &reference, &target).unwrap();
    assert!(!reposer.is_identity() && !reposer.is_rigid());
    let out = reposer.map_points(reposer.target_vertices(), &[]).unwrap();
    assert_eq!(out.fallback, 0);
    assert!(out.dirs.is_empty());
    let worst = worst_distance(&out.points, reposer.reference_vertices());
    assert!(worst < VERTEX_TOL_M, "worst vertex error {worst} m");
    // The poses really differ: the vertices moved by decimetres.
    let moved = worst_distance(reposer.target_vertices(), reposer.reference_vertices());
    assert!(moved > 0.3, "largest vertex motion {moved} m");
}

#[test]
fn global_change_only_is_the_rigid_map() {
    let reference = walk_reference();
    let mut target = reference.clone();
    target.rh = Vec3::new(0.3, -1.2, 0.2);
    target.th = Vec3::new(1.5, 0.7, -2.0);
    assert!(Reposer::needed(&reference, &target));
    let reposer = Reposer::new(model(), &reference, &target).unwrap();
    assert!(reposer.is_rigid());

    // x' = R_ref R_tgt^T (x - Th_tgt) + Th_ref, for points near and far from the body.
    let rotation = rodrigues(reference.rh) * rodrigues(target.rh).transpose();
    let mut rng = Rng::new(2);
    let mut points = points_near(reposer.target_vertices(), 1000, 0.1, &mut rng);
    points.extend(points_near(reposer.target_vertices(), 100, 3.0, &mut rng));
    let dirs: Vec<Vec3> = points.iter().map(|_| random_unit(&mut rng)).collect();
    let out = reposer.map_points(&points, &dirs).unwrap();
    assert_eq!(out.fallback, 0);
    for (i, (&x, &d)) in points.iter().zip(&dirs).enumerate() {
        let expected = rotation * (x - target.th) + reference.th;
        let tol = RIGID_TOL_M * (1.0 + x.length());
        assert!(out.points[i].distance(expected) < tol, "point {i}");
        assert!(out.dirs[i].distance(rotation * d) < DIR_TOL, "dir {i}");
    }
    // And the body itself follows.
    let out = reposer.map_points(reposer.target_vertices(), &[]).unwrap();
    let worst = worst_distance(&out.points, reposer.reference_vertices());
    assert!(worst < RIGID_TOL_M * 4.0, "worst vertex error {worst} m");
}

#[test]
fn pose_blend_shapes_follow_the_vertex_correspondence() {
    // Give the procedural body pose-corrective blend shapes (it has none), smooth over the
    // body: a random direction per (coordinate, pose feature) of a few millimetres per unit of
    // feature, scaled by a wave along the height.
    let mut model = model().clone();
    let features = model.posedirs.len() / (3 * model.weights.len());
    let mut rng = Rng::new(7);
    let pattern: Vec<f32> = (0..3 * features).map(|_| 5e-3 * rng.normal()).collect();
    for (i, p) in model.posedirs.iter_mut().enumerate() {
        let (v, entry) = (i / (3 * features), i % (3 * features));
        *p = pattern[entry] * (4.0 * model.v_template[v].y).sin();
    }
    model.validate().unwrap();
    let (reference, target) = (walk_reference(), arm_swing_target());
    let reposer = Reposer::new(&model, &reference, &target).unwrap();

    // The corrective offsets move the vertices by millimetres to centimetres (ignoring them
    // in the map leaves errors of that size)...
    let plain = Reposer::new(self::model(), &reference, &target).unwrap();
    let offset = worst_distance(reposer.target_vertices(), plain.target_vertices());
    assert!(offset > 5e-3, "largest pose-corrective offset {offset} m");
    // ...and still every target vertex lands on its reference vertex.
    let out = reposer.map_points(reposer.target_vertices(), &[]).unwrap();
    assert_eq!(out.fallback, 0);
    let worst = worst_distance(&out.points, reposer.reference_vertices());
    assert!(worst < VERTEX_TOL_M, "worst vertex error {worst} m");
}

/// Vertices skinned to `joint` alone whose every incident face is too, so that any point of
/// those faces interpolates pure `joint` weights.
fn pure_vertices(model: &BodyModel, joint: usize) -> Vec<usize> {
    let pure = |v: usize| model.weights[v][joint] == 1.0;
    let mut ok: Vec<bool> = (0..model.weights.len()).map(pure).collect();
    for f in &model.faces {
        if !f.iter().all(|&v| pure(v as usize)) {
            for &v in f {
                ok[v as usize] = false;
            }
        }
    }
    (0..ok.len()).filter(|&v| ok[v]).collect()
}

#[test]
fn directions_follow_a_rotated_limb() {
    let reference = params([0.0; 72], [0.0; 3], [0.0; 3]);
    let mut target = reference.clone();
    let axis_angle = Vec3::new(0.3, 0.8, -0.2).normalize() * ELBOW_ANGLE;
    target.poses[3 * L_ELBOW..3 * L_ELBOW + 3].copy_from_slice(&axis_angle.to_array());
    let reposer = Reposer::new(model(), &reference, &target).unwrap();

    let forearm = pure_vertices(model(), L_ELBOW);
    assert!(
        forearm.len() >= 20,
        "{} pure forearm vertices",
        forearm.len()
    );
    let mut rng = Rng::new(3);
    let points: Vec<Vec3> = forearm
        .iter()
        .map(|&v| reposer.target_vertices()[v])
        .collect();
    let dirs: Vec<Vec3> = points.iter().map(|_| random_unit(&mut rng)).collect();
    let out = reposer.map_points(&points, &dirs).unwrap();
    assert_eq!(out.fallback, 0);
    // Reference at rest, parents unrotated: the relative rotation is R_elbow^T.
    let undo_elbow = rodrigues(axis_angle).transpose();
    for (i, &d) in out.dirs.iter().enumerate() {
        assert!((d.length() - 1.0).abs() < DIR_TOL, "|d'| = {}", d.length());
        let expected = undo_elbow * dirs[i];
        assert!(d.distance(expected) < DIR_TOL, "dir {i}: {d} vs {expected}");
    }
    let reference_forearm: Vec<Vec3> = forearm
        .iter()
        .map(|&v| reposer.reference_vertices()[v])
        .collect();
    let worst = worst_distance(&out.points, &reference_forearm);
    assert!(worst < VERTEX_TOL_M, "worst vertex error {worst} m");
    // The forearm really turned: directions changed by the elbow angle.
    let turned = worst_distance(&dirs, &out.dirs);
    assert!(turned > 0.5, "largest direction change {turned}");
}

#[test]
fn opposite_rotations_blended_half_and_half_fall_back() {
    // Forearm and hand skinned half to the shoulder, half to the elbow; the elbow turned by
    // pi about the arm's own axis (+x): 0.5 (I + R_x(pi)) = diag(1, 0, 0), determinant 0.
    let mut model = model().clone();
    let rest = model.v_template.clone();
    let mut region = Vec::new();
    for (v, w) in model.weights.iter_mut().enumerate() {
        if rest[v].x > 0.45 {
            *w = [0.0; NUM_JOINTS];
            w[L_SHOULDER] = 0.5;
            w[L_ELBOW] = 0.5;
            region.push(v);
        }
    }
    model.validate().unwrap();
    assert!(!region.is_empty());
    let reference = params([0.0; 72], [0.0, 0.2, 0.0], [0.0, 1.0, 0.0]);
    let mut target = reference.clone();
    target.poses[3 * L_ELBOW] = std::f32::consts::PI;
    let reposer = Reposer::new(&model, &reference, &target).unwrap();

    let mut rng = Rng::new(4);
    let region_points: Vec<Vec3> = region
        .iter()
        .map(|&v| reposer.target_vertices()[v])
        .collect();
    let mut points = region_points.clone();
    // Points around the collapsed forearm, and the rest of the body.
    points.extend(points_near(&region_points, 200, 0.05, &mut rng));
    points.extend(
        (0..model.weights.len())
            .filter(|&v| rest[v].x < 0.2)
            .map(|v| reposer.target_vertices()[v]),
    );
    let dirs: Vec<Vec3> = points.iter().map(|_| random_unit(&mut rng)).collect();
    let out = reposer.map_points(&points, &dirs).unwrap();
    assert!(out.points.iter().all(|p| p.is_finite()));
    assert!(out.dirs.iter().all(|d| (d.length() - 1.0).abs() < DIR_TOL));
    assert!(
        out.fallback >= region.len() && out.fallback < points.len(),
        "{} fallbacks for {} region vertices of {} points",
        out.fallback,
        region.len(),
        points.len()
    );
}

#[test]
fn far_and_non_finite_points() {
    let (reference, target) = (walk_reference(), arm_swing_target());
    let reposer = Reposer::new(model(), &reference, &target).unwrap();
    let mut rng = Rng::new(5);
    let mut points = Vec::new();
    for distance in [2.0f32, 10.0, 1e3, 1e5] {
        for _ in 0..50 {
            points.push(random_unit(&mut rng) * distance);
        }
    }
    let dirs: Vec<Vec3> = points.iter().map(|_| random_unit(&mut rng)).collect();
    let out = reposer.map_points(&points, &dirs).unwrap();
    assert!(out.points.iter().all(|p| p.is_finite()));
    assert!(out.dirs.iter().all(|d| (d.length() - 1.0).abs() < DIR_TOL));

    // A non-finite query comes back unchanged and counts as a fallback.
    let out = reposer
        .map_points(
            &[Vec3::new(f32::NAN, 0.0, 0.0), Vec3::Y],
            &[Vec3::Z, Vec3::ZERO],
        )
        .unwrap();
    assert!(out.points[0].x.is_nan());
    assert_eq!(out.dirs[0], Vec3::Z);
    // A zero direction stays zero rather than becoming NaN.
    assert_eq!(out.dirs[1], Vec3::ZERO);
    assert_eq!(out.fallback, 1);
}

#[test]
fn bad_inputs_are_typed_errors() {
    let (reference, target) = (walk_reference(), arm_swing_target());
    let reposer = Reposer::new(model(), &reference, &target).unwrap();
    let err = reposer
        .map_points(&[Vec3::ZERO, Vec3::ZERO], &[Vec3::Z])
        .unwrap_err();
    assert!(matches!(
        err,
        RepositionError::DirsLength {
            got: 1,
            expected: 2
        }
    ));
    assert!(err.to_string().contains("`dirs`"));

    let mut bad = target.clone();
    bad.poses[7] = f32::NAN;
    let err = Reposer::new(model(), &reference, &bad).unwrap_err();
    assert!(matches!(
        err,
        RepositionError::Params {
            which: "target",
            field: "poses",
            ..
        }
    ));

    let mut other_shape = target.clone();
    other_shape.shapes[1] = 1.0;
    let err = Reposer::new(model(), &reference, &other_shape).unwrap_err();
    assert!(matches!(
        err,
        RepositionError::ShapeMismatch { index: 1, .. }
    ));
    assert!(err.to_string().contains("`shapes`"));
}

/// Timing by hand:
/// `CARGO_TARGET_DIR=$HOME/.cache/nia-rs/target cargo test --workspace --all-features --test
/// reposing -- --ignored --nocapture`
#[test]
#[ignore = "timing, run by hand"]
fn timing_65536_points_near_the_body() {
    let (reference, target) = (walk_reference(), arm_swing_target());
    let model = model();
    let start = Instant::now();
    let reposer = Reposer::new(model, &reference, &target).unwrap();
    let build_ms = start.elapsed().as_secs_f64() * 1e3;
    let mut rng = Rng::new(6);
    let points = points_near(reposer.target_vertices(), 65_536, 0.05, &mut rng);
    let dirs: Vec<Vec3> = points.iter().map(|_| random_unit(&mut rng)).collect();
    let mut best = f64::INFINITY;
    let mut fallback = 0;
    for _ in 0..5 {
        let start = Instant::now();
        let out = reposer.map_points(&points, &dirs).unwrap();
        best = best.min(start.elapsed().as_secs_f64() * 1e3);
        fallback = out.fallback;
    }
    println!(
        "Reposer::new {build_ms:.1} ms; map_points of {} points within ~5 cm of the body: \
         {best:.1} ms (best of 5), {fallback} fallbacks, {} vertices, {} rayon threads",
        points.len(),
        model.weights.len(),
        rayon::current_num_threads()
    );
}

/// f32 rigid transform and back of points within ~2 m of the origin.
const SMPL_FRAME_TOL_M: f32 = 1e-5;

#[test]
fn target_vertices_in_the_smpl_frame_undo_the_global_placement() {
    let reference = walk_reference();
    let target = arm_swing_target();
    let reposer = Reposer::new(model(), &reference, &target).unwrap();
    let local = reposer.target_vertices_smpl();
    let rotation = nia_data::body::rodrigues(target.rh);
    for (world, smpl) in reposer.target_vertices().iter().zip(&local) {
        let back = rotation * Vec3::from_array(*smpl) + target.th;
        assert!(
            back.distance(*world) < SMPL_FRAME_TOL_M,
            "{back} vs {world}"
        );
    }
}
