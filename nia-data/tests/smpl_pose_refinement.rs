//! SMPL pose refinement (`nia_data::fitting::align::refine_pose`): a fit whose joints are
//! bent off the person comes closer to it from three source masks, an exact fit stays, no
//! joint leaves its bound, the refined params pose the refined vertices (offsets kept), and bad
//! input is refused by name.

use std::sync::OnceLock;

use glam::{Quat, Vec3};
use nia_data::body::ProceduralBody;
use nia_data::body::{pose_for_motion, BodyModel, MotionKind, ProceduralSpec, SmplParams};
use nia_data::fitting::{refine_pose, AlignmentView, FitError, SmplAlignment};
use nia_data::geometry::camera::Camera;
use nia_data::geometry::raster::rasterize;

/// Image side, pixels (the quickstart's).
const SIZE: u32 = 128;
/// Distance of the cameras from the body's centre, metres.
const RING_M: f32 = 3.0;

/// A coarse procedural body model, made once.
fn model() -> &'static BodyModel {
    static MODEL: OnceLock<BodyModel> = OnceLock::new();
    MODEL.get_or_init(|| {
        let spec = ProceduralSpec {
            grid_step_m: 0.02,
            target_vertices: 2500,
            relax_iterations: 1,
            ..ProceduralSpec::default()
        };
        ProceduralBody::generate(&spec).unwrap()
    })
}

/// The person: mid-stride, turned and placed away from the origin.
fn true_params() -> SmplParams {
    SmplParams {
        poses: pose_for_motion(0.3, MotionKind::Walk),
        shapes: Vec::new(),
        rh: Vec3::new(0.0, 0.7, 0.0),
        th: Vec3::new(0.3, 0.1, -0.2),
    }
}

/// The fit: the person with these joints turned by `deg` about alternating axes.
fn bent(joints: &[usize], deg: f32) -> SmplParams {
    let mut p = true_params();
    let axes = [Vec3::X, Vec3::Z, Vec3::new(1.0, 0.0, 1.0).normalize()];
    for (n, &k) in joints.iter().enumerate() {
        let span = 3 * k..3 * k + 3;
        let r = Quat::from_scaled_axis(Vec3::from_slice(&p.poses[span.clone()]));
        let turned = Quat::from_axis_angle(axes[n % 3], deg.to_radians()) * r;
        p.poses[span].copy_from_slice(&turned.to_scaled_axis().to_array());
    }
    p
}

/// Shoulders, elbows, hips and knees.
const LIMBS: [usize; 8] = [16, 17, 18, 19, 1, 2, 4, 5];

fn centroid(v: &[Vec3]) -> Vec3 {
    v.iter().copied().sum::<Vec3>() / v.len() as f32
}

/// Three cameras 120 degrees apart around the person (up is y, SMPL's), the body filling about
/// 80 % of the picture's height.
fn cameras() -> Vec<Camera> {
    let v = model().lbs(&true_params()).vertices;
    let c = centroid(&v);
    let f = 0.8 * SIZE as f32 * RING_M / 1.7;
    (0..3)
        .map(|k| {
            let a = k as f32 * std::f32::consts::TAU / 3.0 + 0.4;
            let dir = Vec3::new(a.cos(), 0.0, a.sin());
            Camera::look_at(
                c + dir * RING_M + Vec3::Y * 0.2,
                c,
                Vec3::Y,
                f,
                f,
                SIZE,
                SIZE,
            )
            .unwrap()
        })
        .collect()
}

fn masks(cameras: &[Camera]) -> Vec<Vec<bool>> {
    let v = model().lbs(&true_params()).vertices;
    cameras
        .iter()
        .map(|c| rasterize(c, &v, &model().faces).unwrap().mask())
        .collect()
}

fn views<'a>(cameras: &'a [Camera], masks: &'a [Vec<bool>]) -> Vec<AlignmentView<'a>> {
    cameras
        .iter()
        .zip(masks)
        .map(|(camera, mask)| AlignmentView { camera, mask })
        .collect()
}

fn mean_error(a: &[Vec3], b: &[Vec3]) -> f32 {
    a.iter().zip(b).map(|(p, q)| p.distance(*q)).sum::<f32>() / a.len() as f32
}

fn posing(iterations: usize) -> SmplAlignment {
    SmplAlignment {
        pose_iterations: iterations,
        ..SmplAlignment::default()
    }
}

#[test]
fn bent_limbs_come_back_towards_the_person() {
    let (cams, masks) = (cameras(), masks(&cameras()));
    let truth = model().lbs(&true_params()).vertices;
    let fit = bent(&LIMBS, 8.0);
    let fit_vertices = model().lbs(&fit).vertices;
    let (refined, params, report) = refine_pose(
        model(),
        &fit_vertices,
        &fit,
        &views(&cams, &masks),
        &posing(20),
    )
    .unwrap();
    let (before, after) = (
        mean_error(&fit_vertices, &truth),
        mean_error(&refined, &truth),
    );
    assert!(report.steps > 0);
    assert!(report.energy_after < report.energy_before);
    assert!(report.energy_after.is_finite() && report.mean_joint_deg.is_finite());
    // Measured: 3.4 cm -> 0.9 cm.
    assert!(
        after < 0.4 * before,
        "mean vertex error: fit {before} m, refined {after} m"
    );
    // The shape is never touched.
    assert_eq!(params.shapes, fit.shapes);
}

#[test]
fn an_exact_fit_stays_where_it_is() {
    let (cams, masks) = (cameras(), masks(&cameras()));
    let fit = true_params();
    let vertices = model().lbs(&fit).vertices;
    let (refined, _, report) =
        refine_pose(model(), &vertices, &fit, &views(&cams, &masks), &posing(20)).unwrap();
    // The masks are pixels (1.7 cm here): the energy's minimum is within a fraction of one
    // of the truth (measured 1.4 mm).
    assert!(
        mean_error(&refined, &vertices) < 0.005,
        "{} m",
        mean_error(&refined, &vertices)
    );
    assert!(report.max_joint_deg < 3.0, "{report:?}");
}

#[test]
fn no_joint_leaves_its_bound() {
    let (cams, masks) = (cameras(), masks(&cameras()));
    // 20 degrees off: the refinement may take back at most 4 of them.
    let fit = bent(&LIMBS, 20.0);
    let vertices = model().lbs(&fit).vertices;
    let config = SmplAlignment {
        max_joint_deg: 4.0,
        ..posing(30)
    };
    let (_, _, report) =
        refine_pose(model(), &vertices, &fit, &views(&cams, &masks), &config).unwrap();
    assert!(report.max_joint_deg <= 4.0 + 1e-3, "{report:?}");
    assert!(report.energy_after <= report.energy_before);
}

#[test]
fn the_stored_offsets_are_kept() {
    // A dataset's vertices need not be exactly the model's LBS of its params: what lies
    // between them rides along with the refined pose.
    let (cams, masks) = (cameras(), masks(&cameras()));
    let fit = bent(&LIMBS, 8.0);
    let posed = model().lbs(&fit).vertices;
    let offset = Vec3::new(0.0, 0.004, 0.0);
    let stored: Vec<Vec3> = posed.iter().map(|&v| v + offset).collect();
    let (refined, params, _) =
        refine_pose(model(), &stored, &fit, &views(&cams, &masks), &posing(20)).unwrap();
    let again = model().lbs(&params).vertices;
    for (a, b) in refined.iter().zip(&again) {
        assert!((*a - *b - offset).length() < 1e-4);
    }
}

#[test]
fn off_or_without_a_person_nothing_moves() {
    let (cams, masks) = (cameras(), masks(&cameras()));
    let fit = bent(&LIMBS, 8.0);
    let vertices = model().lbs(&fit).vertices;
    let (same, params, report) =
        refine_pose(model(), &vertices, &fit, &views(&cams, &masks), &posing(0)).unwrap();
    assert_eq!(same, vertices);
    assert_eq!((report.steps, &params), (0, &fit));
    let empty = vec![vec![false; (SIZE * SIZE) as usize]; 3];
    let (same, params, report) =
        refine_pose(model(), &vertices, &fit, &views(&cams, &empty), &posing(20)).unwrap();
    assert_eq!(same, vertices);
    assert_eq!((report.steps, &params), (0, &fit));
}

fn field_of(e: FitError) -> String {
    match e {
        FitError::Invalid { field, .. } => field,
        other => panic!("not an invalid-input error: {other}"),
    }
}

#[test]
fn bad_input_is_refused_by_name() {
    let (cams, masks) = (cameras(), masks(&cameras()));
    let fit = true_params();
    let vertices = model().lbs(&fit).vertices;
    let views = views(&cams, &masks);
    let short = &vertices[..vertices.len() - 1];
    let e = refine_pose(model(), short, &fit, &views, &posing(20)).unwrap_err();
    assert_eq!(field_of(e), "vertices");
    let mut nan = vertices.clone();
    nan[7] = Vec3::NAN;
    let e = refine_pose(model(), &nan, &fit, &views, &posing(20)).unwrap_err();
    assert_eq!(field_of(e), "vertices");
    let mut bad = fit.clone();
    bad.poses[40] = f32::NAN;
    let e = refine_pose(model(), &vertices, &bad, &views, &posing(20)).unwrap_err();
    assert_eq!(field_of(e), "params");
    let bad = SmplParams {
        th: Vec3::new(0.0, f32::INFINITY, 0.0),
        ..fit.clone()
    };
    let e = refine_pose(model(), &vertices, &bad, &views, &posing(20)).unwrap_err();
    assert_eq!(field_of(e), "params");
    for (config, field) in [
        (
            SmplAlignment {
                pose_iterations: 5000,
                ..SmplAlignment::default()
            },
            "pose_iterations",
        ),
        (
            SmplAlignment {
                train_pose_iterations: Some(1001),
                ..SmplAlignment::default()
            },
            "train_pose_iterations",
        ),
        (
            SmplAlignment {
                pose_prior_deg: 0.0,
                ..posing(20)
            },
            "pose_prior_deg",
        ),
        (
            SmplAlignment {
                pose_prior_deg: f32::NAN,
                ..posing(20)
            },
            "pose_prior_deg",
        ),
        (
            SmplAlignment {
                max_joint_deg: 120.0,
                ..posing(20)
            },
            "max_joint_deg",
        ),
    ] {
        let e = refine_pose(model(), &vertices, &fit, &views, &config).unwrap_err();
        assert_eq!(field_of(e), field);
    }
}

#[test]
fn the_settings_read_with_defaults() {
    let s: SmplAlignment = serde_json::from_str(r#"{"pose_iterations": 20}"#).unwrap();
    assert_eq!(s, posing(20));
    assert_eq!(
        SmplAlignment::default().pose_iterations,
        0,
        "rigid only by default"
    );
    assert!(serde_json::from_str::<SmplAlignment>(r#"{"pose_iteration": 20}"#).is_err());
    // Training scenes may be aligned rigidly only.
    let s: SmplAlignment =
        serde_json::from_str(r#"{"pose_iterations": 20, "train_pose_iterations": 0}"#).unwrap();
    assert_eq!(s.for_training().pose_iterations, 0);
    assert!(s.refines_pose());
    assert_eq!(posing(20).for_training(), posing(20));
    let train_only = SmplAlignment {
        train_pose_iterations: Some(5),
        ..SmplAlignment::default()
    };
    assert!(train_only.refines_pose());
    assert_eq!(train_only.for_training().pose_iterations, 5);
}

/// `cargo test -p nia-data --test smpl_pose_refinement -- --ignored --nocapture`: the time of
/// one refinement at the test's size (2500 vertices, three 128 px views).
#[test]
#[ignore = "timing, not a check"]
fn refinement_time() {
    let (cams, masks) = (cameras(), masks(&cameras()));
    let fit = bent(&LIMBS, 8.0);
    let vertices = model().lbs(&fit).vertices;
    let views = views(&cams, &masks);
    let start = std::time::Instant::now();
    let runs = 10;
    for _ in 0..runs {
        refine_pose(model(), &vertices, &fit, &views, &posing(20)).unwrap();
    }
    println!(
        "{:.1} ms per refinement",
        1000.0 * start.elapsed().as_secs_f64() / runs as f64
    );
}

/// The refinement poses only its sample vertices (`BodyModel::lbs_at`): the same points as the
/// whole body's LBS.
#[test]
fn posing_some_vertices_matches_posing_all() {
    let shaped = model().lbs(&SmplParams::default());
    let params = bent(&LIMBS, 8.0);
    let all = model().lbs(&params);
    let indices: Vec<usize> = (0..all.vertices.len()).step_by(7).collect();
    let at = model().lbs_at(&params, &shaped, &indices);
    assert_eq!(at.vertices.len(), indices.len());
    for (p, &i) in at.vertices.iter().zip(&indices) {
        assert!(p.distance(all.vertices[i]) < 1e-5, "vertex {i}");
    }
    for (a, b) in at.joints.iter().zip(&all.joints) {
        assert!(a.distance(*b) < 1e-5);
    }
    // Indices past the body are skipped.
    let past = model().lbs_at(&params, &shaped, &[0, usize::MAX]);
    assert_eq!(past.vertices.len(), 1);
}
