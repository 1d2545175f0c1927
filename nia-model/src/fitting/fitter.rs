//! The fitter: stages per frame (global placement, then pose), one shape per subject fitted
//! on a few frames jointly, and a warm-started pass over every frame.
//!
//! 1. Shape frames (`shape_frames`, evenly spaced): each fitted from scratch with zero betas:
//!    `Rh`, `Th` from the triangulated torso keypoints ([`super::initialise::place_torso`]),
//!    the global stage, then the pose stage.
//! 2. The shape stage: betas (one row for the subject) with those frames' poses, jointly.
//! 3. Every frame in order with the betas fixed: warm-started from the previous frame's fit
//!    (its `Th` moved by the torso's triangulated displacement), the pose stage with the
//!    temporal term to the previous frame.

use std::time::Instant;

use burn::prelude::*;
use glam::Vec3;
use nia_data::body::{BodyModel, SmplParams, NUM_JOINTS};

use super::adam::HostAdam;
use super::config::FitConfig;
use super::initialise::{place_torso, torso_shift};
use super::objective::{limit_signs, objective, Stage, Targets, Variables};
use super::observation::{check_frames, FrameObservation, KeypointBinding};
use super::projection::ViewTensors;
use super::smpl_layer::{SmplLayer, BODY_POSE_DIM};
use super::FitError;

/// One fitted frame.
#[derive(Debug, Clone)]
pub struct FrameFit {
    /// ZJU-MoCap parameters: `poses[0..3] = 0`, global rotation in `rh`.
    pub params: SmplParams,
    /// Mean reprojection error of the keypoints with confidence > 0, pixels.
    pub keypoint_error_px: f32,
    /// Wall time of this frame's final pass, seconds.
    pub seconds: f32,
}

/// A fitted subject.
#[derive(Debug, Clone)]
pub struct SubjectFit {
    /// `[S]` the subject's shape.
    pub betas: Vec<f32>,
    /// One fit per input frame, in order.
    pub frames: Vec<FrameFit>,
    /// Wall time of the shape frames and the shape stage, seconds.
    pub shape_seconds: f32,
}

/// What the fitter reports as it goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FitProgress {
    /// Shape frame `done` of `total` fitted.
    ShapeFrame { done: usize, total: usize },
    /// The shape stage finished.
    Shape,
    /// Frame `done` of `total` fitted in the final pass.
    Frame { done: usize, total: usize },
}

/// Host copy of a batch's parameters.
#[derive(Debug, Clone)]
struct BatchParams {
    pose: Vec<f32>,
    rh: Vec<f32>,
    th: Vec<f32>,
    betas: Vec<f32>,
}

/// SMPL fitting to multi-view keypoints and silhouettes.
pub struct Fitter<'m> {
    model: &'m BodyModel,
    bindings: Vec<KeypointBinding>,
    config: FitConfig,
    device: Device,
    layer: SmplLayer,
    /// `[1, K, 24 + Vk]`.
    binding_matrix: Tensor<3>,
    keypoint_vertices: usize,
}

impl<'m> Fitter<'m> {
    /// A fitter for `model` and keypoints bound by `bindings`, on the autodiff `device`
    /// (e.g. `Device::flex().autodiff()`).
    pub fn new(
        model: &'m BodyModel,
        bindings: Vec<KeypointBinding>,
        config: FitConfig,
        device: Device,
    ) -> Result<Self, FitError> {
        config.validate()?;
        let v_count = model.num_vertices();
        for (k, b) in bindings.iter().enumerate() {
            b.check(k, v_count)?;
        }
        let mut kp_vertices: Vec<usize> = Vec::new();
        for b in &bindings {
            for &(v, _) in &b.vertices {
                if !kp_vertices.contains(&v) {
                    kp_vertices.push(v);
                }
            }
        }
        let sample = config.silhouette_vertices.min(v_count);
        let mut ids = kp_vertices.clone();
        ids.extend((0..sample).map(|i| i * v_count / sample.max(1)));
        let layer = SmplLayer::new(model, &ids, &device)?;
        let columns = NUM_JOINTS + kp_vertices.len();
        let mut m = vec![0.0f32; bindings.len() * columns];
        for (k, b) in bindings.iter().enumerate() {
            for &(j, w) in &b.joints {
                m[k * columns + j] += w;
            }
            for &(v, w) in &b.vertices {
                let i = kp_vertices.iter().position(|&x| x == v).unwrap_or(0);
                m[k * columns + NUM_JOINTS + i] += w;
            }
        }
        let binding_matrix =
            Tensor::from_data(TensorData::new(m, [1, bindings.len(), columns]), &device);
        Ok(Self {
            model,
            bindings,
            config,
            device,
            layer,
            binding_matrix,
            keypoint_vertices: kp_vertices.len(),
        })
    }

    /// Fits every frame (module docs for the order of the stages).
    pub fn fit_subject(
        &self,
        frames: &[FrameObservation],
        progress: &mut dyn FnMut(FitProgress),
    ) -> Result<SubjectFit, FitError> {
        check_frames(frames, &self.bindings)?;
        let started = Instant::now();
        let count = frames.len();
        let k = self.config.shape_frames.min(count);
        let shape_ids: Vec<usize> = (0..k).map(|i| i * count / k).collect();
        let s = self.layer.num_betas;
        let mut shape_fits = Vec::with_capacity(k);
        for (done, &f) in shape_ids.iter().enumerate() {
            shape_fits.push(self.fit_cold(frames, f, &vec![0.0; s])?);
            progress(FitProgress::ShapeFrame {
                done: done + 1,
                total: k,
            });
        }
        // The shape stage: the shape frames as one batch with shared betas.
        let mut batch = BatchParams {
            pose: shape_fits.iter().flat_map(|p| p.pose.clone()).collect(),
            rh: shape_fits.iter().flat_map(|p| p.rh.clone()).collect(),
            th: shape_fits.iter().flat_map(|p| p.th.clone()).collect(),
            betas: vec![0.0; s],
        };
        let chosen: Vec<&FrameObservation> = shape_ids.iter().map(|&f| &frames[f]).collect();
        self.optimise(
            &chosen,
            shape_ids[0],
            &mut batch,
            None,
            Stage::Shape,
            self.config.shape_iterations,
        )?;
        let betas = batch.betas.clone();
        progress(FitProgress::Shape);
        let shape_seconds = started.elapsed().as_secs_f32();

        let mut out: Vec<FrameFit> = Vec::with_capacity(count);
        let mut prev: Option<BatchParams> = None;
        for f in 0..count {
            let t0 = Instant::now();
            let from_shape = shape_ids.iter().position(|&x| x == f).map(|i| BatchParams {
                pose: batch.pose[i * BODY_POSE_DIM..(i + 1) * BODY_POSE_DIM].to_vec(),
                rh: batch.rh[i * 3..i * 3 + 3].to_vec(),
                th: batch.th[i * 3..i * 3 + 3].to_vec(),
                betas: betas.clone(),
            });
            let mut params = match (&prev, from_shape) {
                (_, Some(p)) => p,
                (Some(p), None) => self.warm_start(&frames[f], p),
                (None, None) => self.fit_cold(frames, f, &betas)?,
            };
            let iterations = self.config.warm_iterations;
            let err = self.optimise(
                &[&frames[f]],
                f,
                &mut params,
                prev.as_ref(),
                Stage::Pose,
                iterations,
            )?;
            out.push(FrameFit {
                params: to_smpl(&params, 0),
                keypoint_error_px: err,
                seconds: t0.elapsed().as_secs_f32(),
            });
            prev = Some(params);
            progress(FitProgress::Frame {
                done: f + 1,
                total: count,
            });
        }
        Ok(SubjectFit {
            betas,
            frames: out,
            shape_seconds,
        })
    }

    /// A frame from scratch: torso placement, the global stage, the pose stage.
    fn fit_cold(
        &self,
        frames: &[FrameObservation],
        f: usize,
        betas: &[f32],
    ) -> Result<BatchParams, FitError> {
        let rest = SmplParams {
            shapes: betas.to_vec(),
            ..SmplParams::default()
        };
        let (rh, th) = place_torso(self.model, &self.bindings, &frames[f], &rest)
            .map_err(|what| FitError::Unplaceable { frame: f, what })?;
        let mut params = BatchParams {
            pose: vec![0.0; BODY_POSE_DIM],
            rh: rh.to_array().to_vec(),
            th: th.to_array().to_vec(),
            betas: betas.to_vec(),
        };
        let frame = [&frames[f]];
        self.optimise(
            &frame,
            f,
            &mut params,
            None,
            Stage::Global,
            self.config.global_iterations,
        )?;
        self.optimise(
            &frame,
            f,
            &mut params,
            None,
            Stage::Pose,
            self.config.cold_iterations,
        )?;
        Ok(params)
    }

    /// The previous frame's fit, its `Th` moved by how far the triangulated torso moved.
    fn warm_start(&self, frame: &FrameObservation, prev: &BatchParams) -> BatchParams {
        let mut p = prev.clone();
        let posed = self.model.lbs(&to_smpl(prev, 0));
        if let Some(shift) = torso_shift(&self.bindings, frame, &posed) {
            for (t, s) in p.th.iter_mut().zip(shift.to_array()) {
                *t += s;
            }
        }
        p
    }

    /// Adam on one stage; returns the mean keypoint reprojection error (pixels) at the end.
    fn optimise(
        &self,
        frames: &[&FrameObservation],
        first_frame: usize,
        params: &mut BatchParams,
        prev: Option<&BatchParams>,
        stage: Stage,
        iterations: usize,
    ) -> Result<f32, FitError> {
        let b = frames.len();
        let s = self.layer.num_betas;
        let targets = self.targets(frames, prev);
        let c = &self.config;
        let (lr_rot, lr_pose, lr_shape) = match stage {
            Stage::Global => (c.lr_rotation, 0.0, 0.0),
            Stage::Pose => (c.lr_rotation, c.lr_rotation, 0.0),
            Stage::Shape => (c.lr_rotation, c.lr_rotation, c.lr_shape),
        };
        let mut lr = vec![lr_pose; b * BODY_POSE_DIM];
        lr.extend(vec![lr_rot; b * 3]);
        lr.extend(vec![c.lr_translation; b * 3]);
        lr.extend(vec![lr_shape; s]);
        let mut adam = HostAdam::new(lr);
        let mut x: Vec<f32> = [&params.pose[..], &params.rh, &params.th, &params.betas].concat();
        let diverged = |what| FitError::NonFinite {
            frame: first_frame,
            stage: stage.name(),
            what,
        };
        let mut error_px = f32::NAN;
        for it in 0..=iterations {
            let (pose, rest) = x.split_at(b * BODY_POSE_DIM);
            let (rh, rest) = rest.split_at(b * 3);
            let (th, betas) = rest.split_at(b * 3);
            let leaf = |v: &[f32], shape: [usize; 2]| {
                Tensor::<2>::from_data(TensorData::new(v.to_vec(), shape), &self.device)
                    .require_grad()
            };
            let vars = Variables {
                pose: leaf(pose, [b, BODY_POSE_DIM]),
                betas: leaf(betas, [1, s]),
                rh: leaf(rh, [b, 3]),
                th: leaf(th, [b, 3]),
            };
            let expanded = Variables {
                betas: vars.betas.clone().expand([b, s]),
                pose: vars.pose.clone(),
                rh: vars.rh.clone(),
                th: vars.th.clone(),
            };
            let (loss, ku, kv) = objective(&self.layer, &targets, &expanded, stage, c);
            if it == iterations {
                error_px = self.keypoint_error(frames, ku, kv);
                break;
            }
            let grads = loss.backward();
            let grad = |t: &Tensor<2>, n: usize| -> Vec<f32> {
                t.grad(&grads)
                    .and_then(|g| g.into_data().try_to_vec::<f32>().ok())
                    .unwrap_or_else(|| vec![0.0; n])
            };
            let g: Vec<f32> = [
                grad(&vars.pose, b * BODY_POSE_DIM),
                grad(&vars.rh, b * 3),
                grad(&vars.th, b * 3),
                grad(&vars.betas, s),
            ]
            .concat();
            if !g.iter().all(|v| v.is_finite()) {
                return Err(diverged("gradient"));
            }
            let progress = it as f32 / iterations.max(1) as f32;
            let scale = 1.0 - (1.0 - c.lr_final_fraction) * progress;
            adam.step(&mut x, &g, scale);
        }
        if !x.iter().all(|v| v.is_finite()) {
            return Err(diverged("parameters"));
        }
        let (pose, rest) = x.split_at(b * BODY_POSE_DIM);
        let (rh, rest) = rest.split_at(b * 3);
        let (th, betas) = rest.split_at(b * 3);
        *params = BatchParams {
            pose: pose.to_vec(),
            rh: rh.to_vec(),
            th: th.to_vec(),
            betas: betas.to_vec(),
        };
        Ok(error_px)
    }

    /// Mean distance (pixels) between the projected and observed keypoints with confidence.
    fn keypoint_error(&self, frames: &[&FrameObservation], ku: Tensor<3>, kv: Tensor<3>) -> f32 {
        let u = ku.into_data().try_to_vec::<f32>().unwrap_or_default();
        let v = kv.into_data().try_to_vec::<f32>().unwrap_or_default();
        let k = self.bindings.len();
        let (mut sum, mut count) = (0.0f64, 0usize);
        for (bi, frame) in frames.iter().enumerate() {
            let n = frame.views.len();
            for (ni, view) in frame.views.iter().enumerate() {
                for (ki, p) in view.keypoints.iter().enumerate() {
                    if p[2] > 0.0 && !self.bindings[ki].is_unmapped() {
                        let i = (bi * k + ki) * n + ni;
                        sum += ((u[i] - p[0]).powi(2) + (v[i] - p[1]).powi(2)).sqrt() as f64;
                        count += 1;
                    }
                }
            }
        }
        (sum / count.max(1) as f64) as f32
    }

    /// The constant tensors of a batch.
    fn targets<'a>(
        &self,
        frames: &[&'a FrameObservation],
        prev: Option<&BatchParams>,
    ) -> Targets<'a> {
        let b = frames.len();
        let k = self.bindings.len();
        let n = frames[0].views.len();
        let mut u = vec![0.0f32; b * k * n];
        let mut v = vec![0.0f32; b * k * n];
        let mut conf = vec![0.0f32; b * k * n];
        let mut torso = vec![0.0f32; b * k * n];
        for (bi, frame) in frames.iter().enumerate() {
            for (ni, view) in frame.views.iter().enumerate() {
                for (ki, p) in view.keypoints.iter().enumerate() {
                    if self.bindings[ki].is_unmapped() {
                        continue;
                    }
                    let i = (bi * k + ki) * n + ni;
                    u[i] = p[0];
                    v[i] = p[1];
                    conf[i] = p[2];
                    if self.bindings[ki].is_torso() {
                        torso[i] = p[2];
                    }
                }
            }
        }
        let conf_sum = conf.iter().sum();
        let conf_torso_sum = torso.iter().sum();
        let d = &self.device;
        let t3 = |x: Vec<f32>| Tensor::<3>::from_data(TensorData::new(x, [b, k, n]), d);
        let (prev_pose, prev_th, has_prev) = match prev {
            Some(p) => (p.pose.clone(), p.th.clone(), vec![1.0f32; b]),
            None => (
                vec![0.0; b * BODY_POSE_DIM],
                vec![0.0; b * 3],
                vec![0.0f32; b],
            ),
        };
        let t2 = |x: Vec<f32>, c: usize| Tensor::<2>::from_data(TensorData::new(x, [b, c]), d);
        Targets {
            batch: b,
            views: ViewTensors::new(
                &frames[0].views.iter().map(|v| v.camera).collect::<Vec<_>>(),
                d,
            ),
            bindings: self.binding_matrix.clone(),
            keypoint_vertices: self.keypoint_vertices,
            kp_u: t3(u),
            kp_v: t3(v),
            conf: t3(conf),
            conf_sum,
            conf_torso: t3(torso),
            conf_torso_sum,
            silhouettes: frames
                .iter()
                .map(|f| f.views.iter().map(|v| v.silhouette.as_ref()).collect())
                .collect(),
            prev_pose: t2(prev_pose, BODY_POSE_DIM),
            prev_th: t2(prev_th, 3),
            has_prev: t2(has_prev, 1),
            limit_signs: limit_signs(d),
        }
    }
}

/// Frame `i` of a batch as ZJU-MoCap parameters.
fn to_smpl(p: &BatchParams, i: usize) -> SmplParams {
    let mut poses = [0.0f32; 72];
    poses[3..].copy_from_slice(&p.pose[i * BODY_POSE_DIM..(i + 1) * BODY_POSE_DIM]);
    let v3 = |x: &[f32]| Vec3::new(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
    SmplParams {
        poses,
        shapes: p.betas.clone(),
        rh: v3(&p.rh),
        th: v3(&p.th),
    }
}
