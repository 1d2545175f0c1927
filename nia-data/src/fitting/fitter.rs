//! `nia-train prepare`'s fitter: SMPL fitted to calibrated multi-view photos (2D keypoints and
//! person masks), stage by stage, each stage the one solver under one [`Freedom`]:
//!
//! 1. Shape frames (`shape_frames`, evenly spaced), each fitted from scratch with zero betas:
//!    `Rh`, `Th` from the triangulated torso keypoints ([`super::initialise::place_torso`]),
//!    the body moved rigidly onto the torso keypoints ([`Freedom::Rigid`]), then posed onto
//!    every keypoint and the silhouettes ([`Freedom::Joints`]).
//! 2. The shape stage: the betas (one shape for the subject) with those frames' poses,
//!    jointly ([`Freedom::Full`]).
//! 3. Every frame in order with the betas fixed: warm-started from the previous frame's fit
//!    (its `Th` moved by the torso's triangulated displacement), posed with the temporal prior
//!    to the previous frame ([`Freedom::Joints`]).
//!
//! The energy is `E_kp + E_sil + priors` ([`super::keypoints`], [`super::silhouette`],
//! [`super::priors`]: the pose prior to the mean pose, the joint limits, the temporal terms),
//! with `FitConfig`'s weights.

use std::time::Instant;

use glam::Vec3;

use super::body::{BodyPoints, FrameState, Freedom, RigidMotion};
use super::config::FitConfig;
use super::initialise::{place_torso, torso_shift};
use super::keypoints::{KeypointBinding, KeypointTerms, KeypointView};
use super::observation::{check_frames, FrameObservation};
use super::priors::Priors;
use super::problem::{FrameTerms, Problem};
use super::projection::Pixels;
use super::silhouette::{SilhouetteTerms, SilhouetteView};
use super::solver::levenberg_marquardt;
use super::FitError;
use crate::body::{BodyModel, SmplParams};

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

/// The stages (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    Global,
    Pose,
    Shape,
}

impl Stage {
    fn name(self) -> &'static str {
        match self {
            Stage::Global => "global",
            Stage::Pose => "pose",
            Stage::Shape => "shape",
        }
    }

    fn freedom(self) -> Freedom {
        match self {
            Stage::Global => Freedom::Rigid,
            Stage::Pose => Freedom::Joints,
            Stage::Shape => Freedom::Full,
        }
    }
}

/// SMPL fitting to multi-view keypoints and silhouettes.
pub struct Fitter<'m> {
    model: &'m BodyModel,
    bindings: Vec<KeypointBinding>,
    config: FitConfig,
    /// The silhouette term's vertex sample (evenly spaced).
    sample: Vec<usize>,
}

impl<'m> Fitter<'m> {
    /// A fitter for `model` and keypoints bound by `bindings`.
    pub fn new(
        model: &'m BodyModel,
        bindings: Vec<KeypointBinding>,
        config: FitConfig,
    ) -> Result<Self, FitError> {
        config.validate()?;
        let v_count = model.num_vertices();
        for (k, b) in bindings.iter().enumerate() {
            b.check(k, v_count)?;
        }
        let s = config.silhouette_vertices.min(v_count);
        let sample = (0..s).map(|i| i * v_count / s.max(1)).collect();
        Ok(Self {
            model,
            bindings,
            config,
            sample,
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
        let zero_betas = vec![0.0; self.model.num_betas()];
        let mut shape_fits = Vec::with_capacity(k);
        for (done, &f) in shape_ids.iter().enumerate() {
            shape_fits.push(self.fit_cold(frames, f, &zero_betas)?);
            progress(FitProgress::ShapeFrame {
                done: done + 1,
                total: k,
            });
        }
        // The shape stage: the shape frames as one problem with shared betas.
        let chosen: Vec<&FrameObservation> = shape_ids.iter().map(|&f| &frames[f]).collect();
        let (shaped, _) = self.solve(&chosen, shape_ids[0], shape_fits, None, Stage::Shape)?;
        let betas = shaped[0].shapes.clone();
        progress(FitProgress::Shape);
        let shape_seconds = started.elapsed().as_secs_f32();

        let mut out: Vec<FrameFit> = Vec::with_capacity(count);
        let mut prev: Option<SmplParams> = None;
        for f in 0..count {
            let t0 = Instant::now();
            let start = match (shape_ids.iter().position(|&x| x == f), &prev) {
                (Some(i), _) => shaped[i].clone(),
                (None, Some(p)) => self.warm_start(&frames[f], p),
                (None, None) => self.fit_cold(frames, f, &betas)?,
            };
            let (fitted, error) =
                self.solve(&[&frames[f]], f, vec![start], prev.as_ref(), Stage::Pose)?;
            let params = fitted.into_iter().next().expect("one frame in, one out");
            out.push(FrameFit {
                params: params.clone(),
                keypoint_error_px: error,
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
    ) -> Result<SmplParams, FitError> {
        let rest = SmplParams {
            shapes: betas.to_vec(),
            ..SmplParams::default()
        };
        let (rh, th) = place_torso(self.model, &self.bindings, &frames[f], &rest)
            .map_err(|what| FitError::Unplaceable { frame: f, what })?;
        let placed = SmplParams { rh, th, ..rest };
        let frame = [&frames[f]];
        let (global, _) = self.solve(&frame, f, vec![placed], None, Stage::Global)?;
        let (posed, _) = self.solve(&frame, f, global, None, Stage::Pose)?;
        Ok(posed.into_iter().next().expect("one frame in, one out"))
    }

    /// The previous frame's fit, its `Th` moved by how far the triangulated torso moved.
    fn warm_start(&self, frame: &FrameObservation, prev: &SmplParams) -> SmplParams {
        let mut p = prev.clone();
        let posed = self.model.lbs(prev);
        if let Some(shift) = torso_shift(&self.bindings, frame, &posed) {
            p.th += shift;
        }
        p
    }

    /// The solver on one stage over `frames` (`first_frame`: the first one's index, for
    /// errors) from `start` (one parameter set per frame); returns the fitted parameters and the
    /// mean keypoint reprojection error (pixels) of the last frame.
    fn solve(
        &self,
        frames: &[&FrameObservation],
        first_frame: usize,
        start: Vec<SmplParams>,
        prev: Option<&SmplParams>,
        stage: Stage,
    ) -> Result<(Vec<SmplParams>, f32), FitError> {
        let c = &self.config;
        let freedom = stage.freedom();
        let fits = frames
            .iter()
            .zip(&start)
            .map(|(frame, params)| self.frame_fit(frame, params, prev, stage))
            .collect();
        let problem = Problem {
            freedom,
            frames: fits,
            shape_prior: c.shape_prior_weight,
            bounds: None,
        };
        let states: Vec<FrameState> = start
            .into_iter()
            .zip(&problem.frames)
            .map(|(params, fit)| {
                let centre = fit
                    .body
                    .pose(&FrameState {
                        params: params.clone(),
                        rigid: RigidMotion::identity(Vec3::ZERO),
                    })
                    .centre;
                FrameState {
                    params,
                    rigid: RigidMotion::identity(centre),
                }
            })
            .collect();
        let iterations = match stage {
            Stage::Global => c.global_iterations,
            Stage::Shape => c.shape_iterations,
            Stage::Pose if prev.is_some() => c.warm_iterations,
            Stage::Pose => c.cold_iterations,
        };
        let solution = levenberg_marquardt(&problem, states, iterations);
        let diverged = |what| FitError::NonFinite {
            frame: first_frame,
            stage: stage.name(),
            what,
        };
        if !solution.energy.is_finite() {
            return Err(diverged("energy"));
        }
        let error = match (problem.frames.last(), solution.at.last()) {
            (Some(fit), Some(posed)) => fit
                .keypoints
                .as_ref()
                .map_or(f32::NAN, |k| k.mean_error_px(&posed.keypoints)),
            _ => f32::NAN,
        };
        let params: Vec<SmplParams> = solution
            .state
            .into_iter()
            .map(|s| {
                let mut params = s.params;
                if freedom == Freedom::Rigid {
                    // The rigid stage moved the posed body; its parameters follow it.
                    s.rigid.apply(&mut [], &mut params);
                }
                params
            })
            .collect();
        let finite = params.iter().all(|p| {
            p.poses.iter().chain(&p.shapes).all(|x| x.is_finite())
                && p.rh.is_finite()
                && p.th.is_finite()
        });
        if !finite {
            return Err(diverged("parameters"));
        }
        Ok((params, error))
    }

    /// One frame's terms and priors for `stage`.
    fn frame_fit<'a>(
        &'a self,
        frame: &'a FrameObservation,
        params: &SmplParams,
        prev: Option<&SmplParams>,
        stage: Stage,
    ) -> FrameTerms<'a> {
        let c = &self.config;
        let mut body =
            BodyPoints::with_model(self.model, &self.sample, &self.bindings, params, None);
        if stage == Stage::Global {
            body.freeze_at(params);
        }
        let with_masks: Vec<SilhouetteView<'a>> = if stage == Stage::Global {
            Vec::new()
        } else {
            frame
                .views
                .iter()
                .filter_map(|v| {
                    v.silhouette.as_ref().map(|target| SilhouetteView {
                        target,
                        camera: &v.camera,
                        pixels: Pixels::Distorted,
                        sigma2: c.silhouette_sigma_px * c.silhouette_sigma_px,
                    })
                })
                .collect()
        };
        let views_with_masks = with_masks.len().max(1) as f32;
        let keypoints = KeypointTerms {
            views: frame
                .views
                .iter()
                .map(|v| KeypointView {
                    camera: &v.camera,
                    pixels: Pixels::Distorted,
                    keypoints: &v.keypoints,
                })
                .collect(),
            bindings: &self.bindings,
            sigma2: c.keypoint_sigma_px * c.keypoint_sigma_px,
            torso_only: stage == Stage::Global,
            // The placement needs the torso's keypoints; the pose trusts the offset-prone
            // ones less.
            offset_prone_weight: if stage == Stage::Global {
                1.0
            } else {
                c.offset_prone_weight
            },
        };
        let priors = if stage == Stage::Global {
            Priors::default()
        } else {
            Priors {
                pose: Some((
                    SmplParams {
                        poses: [0.0; 72],
                        ..params.clone()
                    },
                    c.pose_prior_weight,
                )),
                limits: c.joint_limit_weight,
                temporal: prev.map(|p| {
                    (
                        p.clone(),
                        c.temporal_pose_weight,
                        c.temporal_translation_weight,
                    )
                }),
            }
        };
        FrameTerms {
            body,
            silhouettes: SilhouetteTerms {
                views: with_masks,
                weight_out: c.silhouette_out_weight / views_with_masks,
                weight_in: c.silhouette_in_weight / views_with_masks,
            },
            keypoints: Some(keypoints),
            priors,
        }
    }
}
