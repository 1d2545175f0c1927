//! `prepare`'s SMPL fitter (`nia_data::fitting::Fitter`): fits from exact keypoints and
//! silhouettes recovering a known pose and shape, and inputs it must refuse or survive.

use glam::{Quat, Vec3};
use nia_data::body::{
    pose_for_motion, BodyModel, MotionKind, ProceduralBody, ProceduralSpec, SmplParams,
};
use nia_data::fitting::{
    FitConfig, FitError, Fitter, FrameObservation, KeypointBinding, SilhouetteTarget,
    ViewObservation,
};
use nia_data::geometry::camera::Camera;
use nia_data::geometry::raster::rasterize;

/// Mean joint error of a fit from exact keypoints and silhouettes in 4 views, metres.
const EXACT_FIT_MPJPE_M: f32 = 0.02;

fn model() -> BodyModel {
    ProceduralBody::generate(&ProceduralSpec {
        target_vertices: 1500,
        ..ProceduralSpec::default()
    })
    .unwrap()
}

fn truth(frame: usize) -> SmplParams {
    let mut poses = pose_for_motion(0.3 + 0.1 * frame as f32, MotionKind::Walk);
    poses[..3].fill(0.0);
    SmplParams {
        poses,
        shapes: vec![0.6, -0.4, 0.3, 0.0, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0],
        rh: (Quat::from_rotation_z(0.7) * Quat::from_rotation_x(std::f32::consts::FRAC_PI_2))
            .to_scaled_axis(),
        th: Vec3::new(0.1 + 0.02 * frame as f32, -0.05, 0.95),
    }
}

fn cameras(count: usize, size: u32) -> Vec<Camera> {
    let centre = Vec3::new(0.1, -0.05, 0.9);
    (0..count)
        .map(|i| {
            let a = i as f32 * std::f32::consts::TAU / count as f32 + 0.3;
            let eye = centre + Vec3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.4);
            let f = size as f32 * 1.5;
            Camera::look_at(eye, centre, Vec3::Z, f, f, size, size).unwrap()
        })
        .collect()
}

/// Every joint but the hands, and the vertex at the top of the head.
fn bindings(model: &BodyModel) -> Vec<KeypointBinding> {
    let mut b: Vec<KeypointBinding> = (0..22).map(KeypointBinding::joint).collect();
    let top = (0..model.num_vertices())
        .max_by(|&a, &c| model.v_template[a].y.total_cmp(&model.v_template[c].y))
        .unwrap();
    b.push(KeypointBinding::vertex(top));
    b.push(KeypointBinding::midpoint(1, 2));
    b
}

fn position(b: &KeypointBinding, joints: &[Vec3], vertices: &[Vec3]) -> Vec3 {
    b.joints.iter().map(|&(j, w)| joints[j] * w).sum::<Vec3>()
        + b.vertices
            .iter()
            .map(|&(v, w)| vertices[v] * w)
            .sum::<Vec3>()
}

/// Frames seen by `cams` with exact keypoints (confidence 1) and rasterised silhouettes.
fn observe(model: &BodyModel, cams: &[Camera], frames: usize) -> Vec<FrameObservation> {
    let bindings = bindings(model);
    (0..frames)
        .map(|f| {
            let posed = model.lbs(&truth(f));
            let views = cams
                .iter()
                .map(|cam| {
                    let keypoints = bindings
                        .iter()
                        .map(|b| {
                            let (uv, _) = cam
                                .project(position(b, &posed.joints, &posed.vertices))
                                .unwrap();
                            [uv.x, uv.y, 1.0]
                        })
                        .collect();
                    let frags = rasterize(cam, &posed.vertices, &model.faces).unwrap();
                    let mask: Vec<bool> = frags.depth.iter().map(|d| d.is_finite()).collect();
                    ViewObservation {
                        camera: *cam,
                        keypoints,
                        silhouette: SilhouetteTarget::from_mask(&mask, cam.width, cam.height, 100)
                            .unwrap(),
                    }
                })
                .collect();
            FrameObservation { views }
        })
        .collect()
}

fn small_config() -> FitConfig {
    FitConfig {
        shape_frames: 2,
        silhouette_vertices: 300,
        ..FitConfig::default()
    }
}

#[test]
fn a_fit_from_exact_keypoints_recovers_the_pose() {
    let model = model();
    let cams = cameras(4, 256);
    let frames = observe(&model, &cams, 3);
    let fitter = Fitter::new(&model, bindings(&model), small_config()).unwrap();
    let fit = fitter.fit_subject(&frames, &mut |_| {}).unwrap();
    for (f, frame) in fit.frames.iter().enumerate() {
        let got = model.lbs(&frame.params);
        let want = model.lbs(&truth(f));
        let mpjpe: f32 = (0..22)
            .map(|j| (got.joints[j] - want.joints[j]).length())
            .sum::<f32>()
            / 22.0;
        assert!(
            mpjpe < EXACT_FIT_MPJPE_M,
            "frame {f}: MPJPE {mpjpe} m, keypoints {} px",
            frame.keypoint_error_px
        );
        assert_eq!(frame.params.poses[..3], [0.0; 3]);
    }
}

#[test]
fn a_view_without_keypoints_is_skipped_and_no_confidence_at_all_is_an_error() {
    let model = model();
    let cams = cameras(4, 128);
    let mut frames = observe(&model, &cams, 1);
    frames[0].views[1].keypoints.clear();
    for p in &mut frames[0].views[2].keypoints {
        p[2] = 0.0;
    }
    let config = FitConfig {
        cold_iterations: 20,
        warm_iterations: 5,
        shape_iterations: 5,
        ..small_config()
    };
    let fitter = Fitter::new(&model, bindings(&model), config).unwrap();
    let fit = fitter.fit_subject(&frames, &mut |_| {}).unwrap();
    assert!(fit.frames[0].params.poses.iter().all(|x| x.is_finite()));

    for view in &mut frames[0].views {
        for p in &mut view.keypoints {
            p[2] = 0.0;
        }
    }
    let err = fitter.fit_subject(&frames, &mut |_| {}).unwrap_err();
    assert!(matches!(err, FitError::NoKeypoints { frame: 0 }), "{err}");
}

#[test]
fn malformed_observations_are_refused_naming_frame_and_view() {
    let model = model();
    let cams = cameras(3, 64);
    let fitter = Fitter::new(&model, bindings(&model), small_config()).unwrap();
    let good = observe(&model, &cams, 2);

    let mut frames = good.clone();
    frames[1].views[2].keypoints.pop();
    let err = fitter.fit_subject(&frames, &mut |_| {}).unwrap_err();
    assert!(
        matches!(
            err,
            FitError::KeypointCount {
                frame: 1,
                view: 2,
                ..
            }
        ),
        "{err}"
    );

    let mut frames = good.clone();
    let square: Vec<bool> = (0..32 * 32)
        .map(|i| (i % 32) < 10 && (i / 32) < 10)
        .collect();
    frames[0].views[1].silhouette = SilhouetteTarget::from_mask(&square, 32, 32, 10).unwrap();
    assert!(frames[0].views[1].silhouette.is_some());
    let err = fitter.fit_subject(&frames, &mut |_| {}).unwrap_err();
    assert!(
        matches!(
            err,
            FitError::MaskSize {
                frame: 0,
                view: 1,
                ..
            }
        ),
        "{err}"
    );

    let mut frames = good.clone();
    frames[1].views.pop();
    assert!(matches!(
        fitter.fit_subject(&frames, &mut |_| {}).unwrap_err(),
        FitError::ViewCount { frame: 1, .. }
    ));

    let mut frames = good;
    frames[0].views[0].keypoints[3][0] = f32::NAN;
    assert!(matches!(
        fitter.fit_subject(&frames, &mut |_| {}).unwrap_err(),
        FitError::BadKeypoint {
            frame: 0,
            view: 0,
            keypoint: 3,
            ..
        }
    ));

    assert!(matches!(
        fitter.fit_subject(&[], &mut |_| {}).unwrap_err(),
        FitError::NoFrames
    ));
    let bad = vec![KeypointBinding::joint(30)];
    assert!(Fitter::new(&model, bad, FitConfig::default()).is_err());
}
