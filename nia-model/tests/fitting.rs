//! The SMPL fitter: the tensor LBS against nia-data's host LBS (values and gradients), fits
//! from exact keypoints recovering a known pose, and inputs it must refuse or survive.

use burn::prelude::*;
use glam::{Quat, Vec3};
use nia_data::body::{
    pose_for_motion, BodyModel, MotionKind, ProceduralBody, ProceduralSpec, SmplParams,
};
use nia_data::geometry::camera::Camera;
use nia_data::geometry::raster::rasterize;
use nia_model::fitting::{
    FitConfig, FitError, Fitter, FrameObservation, KeypointBinding, SilhouetteTarget, SmplLayer,
    ViewObservation, BODY_POSE_DIM,
};

/// The tensor LBS runs in f32 from f32 arrays; the host chain runs in f64. Vertices of a
/// ~1.7 m body agree to a few micrometres.
const LBS_TOL_M: f32 = 2e-5;
/// Relative agreement of the autodiff gradient with central differences of the host LBS
/// (step 1e-3 rad in f64 arithmetic on f32-rounded vertices).
const GRAD_REL_TOL: f32 = 2e-2;
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
                    let mask: Vec<u8> = frags
                        .depth
                        .iter()
                        .map(|d| if d.is_finite() { 255 } else { 0 })
                        .collect();
                    ViewObservation {
                        camera: *cam,
                        keypoints,
                        silhouette: Some(
                            SilhouetteTarget::new(&mask, cam.width, cam.height, 100).unwrap(),
                        ),
                    }
                })
                .collect();
            FrameObservation { views }
        })
        .collect()
}

fn device() -> Device {
    #[allow(deprecated)]
    Device::ndarray().autodiff()
}

fn small_config() -> FitConfig {
    FitConfig {
        shape_frames: 2,
        silhouette_vertices: 300,
        ..FitConfig::default()
    }
}

#[test]
fn tensor_lbs_matches_the_host_lbs_and_its_gradient_matches_finite_differences() {
    let model = model();
    let dev = device();
    let ids: Vec<usize> = (0..model.num_vertices()).step_by(37).collect();
    let layer = SmplLayer::new(&model, &ids, &dev).unwrap();
    let params = truth(2);
    let host = model.lbs(&params);
    let tensor =
        |v: Vec<f32>, shape: [usize; 2]| Tensor::<2>::from_data(TensorData::new(v, shape), &dev);
    let pose = tensor(params.poses[3..].to_vec(), [1, BODY_POSE_DIM]).require_grad();
    let posed = layer.forward(
        pose.clone(),
        tensor(params.shapes.clone(), [1, 10]),
        tensor(params.rh.to_array().to_vec(), [1, 3]),
        tensor(params.th.to_array().to_vec(), [1, 3]),
    );
    let verts = posed
        .vertices
        .clone()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    for (row, &v) in ids.iter().enumerate() {
        let got = Vec3::from_slice(&verts[row * 3..row * 3 + 3]);
        assert!(
            (got - host.vertices[v]).length() < LBS_TOL_M,
            "vertex {v}: {got} vs {}",
            host.vertices[v]
        );
    }
    let joints = posed
        .joints
        .clone()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    for j in 0..24 {
        let got = Vec3::from_slice(&joints[j * 3..j * 3 + 3]);
        assert!((got - host.joints[j]).length() < LBS_TOL_M, "joint {j}");
    }
    // A fixed weighting of the subset's coordinates, differentiated in the pose.
    let weights: Vec<f32> = (0..ids.len() * 3)
        .map(|i| ((i * 7919) % 13) as f32 / 13.0 - 0.4)
        .collect();
    let wt = Tensor::<3>::from_data(TensorData::new(weights.clone(), [1, ids.len(), 3]), &dev);
    let grads = (posed.vertices * wt).sum().backward();
    let got = pose
        .grad(&grads)
        .unwrap()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    let energy = |p: &SmplParams| -> f64 {
        let v = model.lbs(p).vertices;
        ids.iter()
            .enumerate()
            .map(|(row, &i)| {
                (0..3)
                    .map(|c| weights[row * 3 + c] as f64 * v[i][c] as f64)
                    .sum::<f64>()
            })
            .sum()
    };
    let h = 1e-3f32;
    for i in [0usize, 9, 12, 45, 52, 55, 60] {
        let mut plus = params.clone();
        plus.poses[3 + i] += h;
        let mut minus = params.clone();
        minus.poses[3 + i] -= h;
        let fd = ((energy(&plus) - energy(&minus)) / (2.0 * h as f64)) as f32;
        let scale = fd.abs().max(got[i].abs()).max(1e-2);
        assert!(
            (fd - got[i]).abs() / scale < GRAD_REL_TOL,
            "pose {i}: autodiff {} vs fd {fd}",
            got[i]
        );
    }
}

#[test]
fn a_fit_from_exact_keypoints_recovers_the_pose() {
    let model = model();
    let cams = cameras(4, 256);
    let frames = observe(&model, &cams, 3);
    let fitter = Fitter::new(&model, bindings(&model), small_config(), device()).unwrap();
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
    let fitter = Fitter::new(&model, bindings(&model), config, device()).unwrap();
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
    let fitter = Fitter::new(&model, bindings(&model), small_config(), device()).unwrap();
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
    frames[0].views[1].silhouette =
        Some(SilhouetteTarget::new(&[255u8; 32 * 32], 32, 32, 10).unwrap());
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
    assert!(Fitter::new(&model, bad, FitConfig::default(), device()).is_err());
}
