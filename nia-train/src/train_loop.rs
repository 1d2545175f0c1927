//! The custom training loop on the autodiff device.
//!
//! Per step: the step's scene (a training frame, `source_views` random source cameras and one
//! other target camera, [`TrainData::request_for_step`]), its training rays (NHP sampling),
//! jittered stratified samples, the forward pass ([`NiaModel::encode`] +
//! [`NiaModel::render`]), the loss (NIA eq. 6), the backward pass, clipping of the gradient by
//! its global L2 norm, and an Adam step at the scheduled learning rate. A step whose loss or
//! gradient is not finite changes nothing and is reported as [`TrainEvent::Skipped`].
//!
//! Everything random in step `k` comes from `(seed, k)`: the loader's scene and rays, and the
//! jitter. With the model and optimiser state restored from a checkpoint, a resumed run takes
//! the same steps as an uninterrupted one.
//!
//! Data parallelism: one step is a function of (model, scene); with several devices each would
//! take its own scene and the gradients would be summed with burn's `MultiGradientsParams` and
//! `ModuleOptimizer::step_multi` before the same clipping and step.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::{AdamConfig, GradientsParams, MultiGradientsParams};
use burn::prelude::*;
use nia_data::dataset::loader::{Scene, SceneLoader, SceneTarget};
use nia_data::dataset::protocol::EvalSplit;
use nia_data::rng::Rng;
use nia_data::scene::SceneInput;
use nia_infer::eval::{
    eval_items, evaluate_images, evaluate_items, EvalError, EvalOptions, EvalSummary, EvalTask,
};
use nia_infer::pictures::{comparison_grid, save_evaluated};
use nia_model::c0_shuffle::C0Shuffle;
use nia_model::loss::{distortion_loss, ibr_loss, mask_loss, psnr_from_mse, render_loss};
use nia_model::store::checkpoint::{self, CheckpointError};
use nia_model::{ModelError, NiaModel};

use crate::config::TrainConfig;
use crate::data::{DataError, TrainData};
use crate::events::{Phase, TrainEvent};

/// Label of the jitter stream forked from a step's RNG (the loader uses the request seed).
const JITTER_STREAM: u64 = 1;
/// Label of the c0-shuffling stream forked from a step's RNG (`train.c0_shuffle`).
const C0_SHUFFLE_STREAM: u64 = 2;

/// Images of the final evaluation whose grids and blend maps are written (`<out>/evaluation/`).
pub const FINAL_PICTURES: usize = 4;
/// Validation images whose comparison grids are reported (TensorBoard).
pub const VALIDATION_PICTURES: usize = 2;

/// A training error.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Data(#[from] DataError),
    #[error("loader: {0}")]
    Loader(#[from] nia_data::dataset::loader::LoaderError),
    #[error("{0}")]
    Backend(#[from] nia_model::device::BackendUnavailable),
    #[error("train.devices: {0}")]
    Device(#[from] nia_model::device::DeviceError),
    #[error("step {step} ({subject}, frame {frame}): {source}")]
    Model {
        step: u64,
        subject: String,
        frame: usize,
        source: ModelError,
    },
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error("checkpoint: {0}")]
    Checkpoint(#[from] CheckpointError),
    #[error("{}: cannot create the output folder: {source}", path.display())]
    Out {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("the loader produced a scene without training rays at step {0}")]
    NoRays(u64),
    /// `train.lpips` could not be loaded.
    #[error("train.lpips: {0}")]
    Lpips(#[from] nia_model::lpips::LpipsLoadError),
    /// `train.encoder_weights` could not be loaded into the encoder.
    #[error("train.encoder_weights: {0}")]
    EncoderWeights(#[from] nia_model::field::encoder_import::EncoderLoadError),
}

/// What a finished run reports.
#[derive(Debug, Clone)]
pub struct TrainSummary {
    /// Steps completed in all (including those of a resumed checkpoint).
    pub steps: u64,
    /// Steps taken by this call.
    pub steps_run: u64,
    /// Steps skipped for non-finite loss or gradients.
    pub skipped: u64,
    /// Loss of the last taken step.
    pub last_loss: Option<f64>,
    pub last_checkpoint: Option<PathBuf>,
}

/// Run options beyond the config file.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Output folder: `metrics.jsonl` is the binary's, `checkpoints/` the loop's.
    pub out: PathBuf,
    /// Continue from the newest checkpoint in `out`, if there is one.
    pub resume: bool,
}

/// Trains `config` and reports through `on_event`.
pub fn train(
    config: &TrainConfig,
    options: &RunOptions,
    on_event: &mut dyn FnMut(TrainEvent),
) -> Result<TrainSummary, TrainError> {
    std::fs::create_dir_all(&options.out).map_err(|source| TrainError::Out {
        path: options.out.clone(),
        source,
    })?;
    let data = TrainData::open(config, &mut |done, total| {
        on_event(TrainEvent::Progress {
            phase: Phase::Generation,
            done,
            total,
        })
    })?;
    on_event(TrainEvent::DataReady {
        root: config.data.root.clone(),
        train_subjects: data.train_subject_names(),
        unseen_subjects: data.unseen_subject_names(),
        generated: data.generated,
    });
    let t = &config.train;
    // Data parallelism: K devices, K scenes per step, one per device; the first device holds
    // the model and the optimiser.
    let specs = t.device_specs();
    let devices = specs
        .iter()
        .map(|s| s.device().map(|d| d.autodiff()))
        .collect::<Result<Vec<_>, _>>()?;
    let k = devices.len() as u64;
    let device = devices[0].clone();
    device.seed(t.seed);
    let mut model = config.model.init(&device);
    let mut optimizer = adam(config).init();
    // LPIPS of validation and the final evaluation, on the evaluation (non-autodiff) device.
    let lpips = match &t.lpips {
        Some(files) => Some(Arc::new(files.load(&device.clone().inner())?)),
        None => None,
    };
    let mut first_step = 0;
    let mut last_checkpoint = None;
    let resume_from = if options.resume {
        checkpoint::latest(&options.out)?
    } else {
        None
    };
    if let Some((_, dir)) = resume_from {
        let (m, o, step) = checkpoint::load(&dir, model, optimizer)?;
        model = m;
        optimizer = o;
        first_step = step;
        last_checkpoint = Some(dir);
    } else if let Some(dir) = &t.init_from {
        model = checkpoint::load_model(dir, model)?;
    } else if let Some(path) = &t.encoder_weights {
        model.encoder = model.encoder.load_torchvision(path)?;
    }
    on_event(TrainEvent::Started {
        first_step,
        steps: t.steps,
    });
    // Scene `step * K + i` of the run goes to device i (K = 1: scene `step`).
    let requests = (first_step..t.steps)
        .flat_map(|step| (0..k).map(move |i| step * k + i))
        .map(|scene| data.request_for_step(t.seed, scene, t.source_views))
        .collect();
    let mut loader = SceneLoader::new(data.dataset.source.clone(), requests, data.dataset.loader)?;
    let run_start = Instant::now();
    let mut summary = TrainSummary {
        steps: first_step,
        steps_run: 0,
        skipped: 0,
        last_loss: None,
        last_checkpoint,
    };
    for step in first_step..t.steps {
        let scenes = loader
            .by_ref()
            .take(devices.len())
            .collect::<Result<Vec<_>, _>>()?;
        let started = Instant::now();
        let lr = config.optim.lr_at(step);
        let outcome = train_step(
            &model,
            &scenes,
            &data.dataset.source.faces,
            config,
            step,
            &devices,
        )?;
        match outcome {
            StepOutcome::Skipped(reason) => {
                summary.skipped += 1;
                on_event(TrainEvent::Skipped { step, reason });
            }
            StepOutcome::Taken {
                grads,
                loss,
                mse,
                mse0,
                rays,
            } => {
                model = optimizer.step(lr, model, grads);
                let seconds = started.elapsed().as_secs_f64().max(1e-9);
                summary.last_loss = Some(loss);
                on_event(TrainEvent::Step {
                    step,
                    loss,
                    mse,
                    mse0,
                    psnr: psnr_from_mse(mse),
                    rays_per_s: rays as f64 / seconds,
                    lr,
                });
            }
        }
        let done = step + 1;
        summary.steps = done;
        summary.steps_run += 1;
        if t.validate_every > 0 && done % t.validate_every == 0 {
            let items = eval_items(
                &data.dataset,
                EvalSplit::UnseenSubjects,
                Some(t.validation_images),
            )?;
            let chunk = t.rays_per_step;
            let total = items.len();
            let done_steps = done;
            on_event(TrainEvent::Progress {
                phase: Phase::Validation,
                done: 0,
                total,
            });
            if let Some(m) = evaluate_items(
                &model,
                &data.dataset,
                &items,
                t.samples,
                chunk,
                config.render,
                lpips.clone(),
                &device,
                &mut |done, evaluated| {
                    if done <= VALIDATION_PICTURES {
                        let grid = comparison_grid(evaluated);
                        on_event(TrainEvent::ValidationImage {
                            step: done_steps,
                            index: done - 1,
                            width: grid.width(),
                            height: grid.height(),
                            rgb: grid.into_raw(),
                        });
                    }
                    on_event(TrainEvent::Progress {
                        phase: Phase::Validation,
                        done,
                        total,
                    })
                },
            )? {
                on_event(TrainEvent::Validation {
                    step: done,
                    images: m.images,
                    psnr: m.psnr,
                    ssim: m.ssim,
                    lpips: m.lpips,
                });
            }
        }
        if done % t.checkpoint_every == 0 || done == t.steps {
            let path = checkpoint::save(
                &options.out,
                done,
                &model,
                &optimizer,
                config,
                &config.model,
                t.keep_last,
            )?;
            on_event(TrainEvent::Checkpoint {
                step: done,
                path: path.clone(),
            });
            summary.last_checkpoint = Some(path);
        }
    }
    if t.evaluate_at_end {
        let split = EvalSplit::UnseenSubjects;
        let items = eval_items(&data.dataset, split, None)?;
        let pictures = options.out.join("evaluation");
        std::fs::create_dir_all(&pictures)
            .map_err(|e| EvalError::Output(format!("creating {}: {e}", pictures.display())))?;
        // Pictures of images spread over the split (every k-th), so they show several views.
        let every = items.len().div_ceil(FINAL_PICTURES).max(1);
        let mut index = 0usize;
        let total = items.len();
        on_event(TrainEvent::Progress {
            phase: Phase::Evaluation,
            done: 0,
            total,
        });
        let results = evaluate_images(
            &model,
            &data.dataset,
            split,
            &items,
            EvalOptions {
                task: EvalTask::NovelView,
                samples: t.samples,
                chunk: t.rays_per_step,
                timed: false,
                adaptive: config.render,
                lpips: lpips.clone(),
            },
            &device,
            &mut |evaluated| {
                let keep = index % every == 0;
                index += 1;
                if keep {
                    save_evaluated(&pictures, &evaluated)
                        .map_err(|e| EvalError::Output(e.to_string()))?;
                }
                on_event(TrainEvent::Progress {
                    phase: Phase::Evaluation,
                    done: index,
                    total,
                });
                Ok(())
            },
        )?;
        if let Some(m) = EvalSummary::of(&results) {
            on_event(TrainEvent::Evaluation {
                step: summary.steps,
                split: split.name().to_string(),
                images: m.images,
                psnr: m.psnr,
                ssim: m.ssim,
                lpips: m.lpips,
                c0_share_seen: m.diagnostics.c0_weight_seen,
                psnr_ibr: m.diagnostics.psnr_ibr,
                psnr_nerf: m.diagnostics.psnr_nerf,
                psnr_silhouette: m.diagnostics.psnr_silhouette,
                psnr_interior: m.diagnostics.psnr_interior,
                pictures: pictures.clone(),
            });
        }
    }
    on_event(TrainEvent::Finished {
        steps: summary.steps,
        seconds: run_start.elapsed().as_secs_f64(),
    });
    Ok(summary)
}

/// Adam with the configured betas and epsilon (clipping is applied by the loop, by global norm).
pub fn adam(config: &TrainConfig) -> AdamConfig {
    AdamConfig::new()
        .with_beta_1(config.optim.beta1)
        .with_beta_2(config.optim.beta2)
        .with_epsilon(config.optim.adam_eps)
}

enum StepOutcome {
    Taken {
        grads: GradientsParams,
        loss: f64,
        mse: f64,
        mse0: f64,
        rays: usize,
    },
    Skipped(String),
}

fn train_step(
    model: &NiaModel,
    scenes: &[Scene],
    faces: &[[u32; 3]],
    config: &TrainConfig,
    step: u64,
    devices: &[Device],
) -> Result<StepOutcome, TrainError> {
    if scenes.len() != devices.len() {
        return Err(TrainError::NoRays(step));
    }
    let k = devices.len() as u64;
    // The devices take their scenes one after the other, each on its replica of the model
    // (forked to it; the first is the model itself). Running the replicas' backward passes
    // on threads at once gave other gradients than one at a time with burn 0.22's autodiff
    // (weights 0.76 apart after 2 steps, nia-train/tests/multi_device.rs), so this build
    // does not overlap devices.
    let mut outcomes = Vec::with_capacity(scenes.len());
    for (i, (scene, device)) in scenes.iter().zip(devices).enumerate() {
        let replica = if i == 0 {
            model.clone()
        } else {
            model.clone().fork(device)
        };
        let index = step * k + i as u64;
        outcomes.push(scene_gradients(
            &replica, scene, faces, config, step, index, device,
        ));
    }
    combine(model, outcomes, devices, config)
}

/// The step of the devices' `outcomes`: skipped if any scene was, else the summed, clipped
/// gradient and the scenes' mean losses.
fn combine(
    model: &NiaModel,
    outcomes: Vec<Result<SceneOutcome, TrainError>>,
    devices: &[Device],
    config: &TrainConfig,
) -> Result<StepOutcome, TrainError> {
    let main = &devices[0];
    let mut parts = Vec::with_capacity(outcomes.len());
    for (outcome, device) in outcomes.into_iter().zip(devices) {
        match outcome? {
            SceneOutcome::Skipped(reason) => return Ok(StepOutcome::Skipped(reason)),
            SceneOutcome::Taken(part) => parts.push((part, device.clone())),
        }
    }
    let n = parts.len() as f64;
    let loss = parts.iter().map(|(p, _)| p.loss).sum::<f64>() / n;
    let mse = parts.iter().map(|(p, _)| p.mse).sum::<f64>() / n;
    let mse0 = parts.iter().map(|(p, _)| p.mse0).sum::<f64>() / n;
    let rays = parts.iter().map(|(p, _)| p.rays).sum();
    // The gradient of the summed loss: burn's MultiGradientsParams adds each parameter's
    // gradients from every device; the sum is moved to the model's device.
    let mut grads = if parts.len() == 1 {
        parts.pop().expect("one part").0.grads
    } else {
        let mut multi = MultiGradientsParams {
            grads: parts.into_iter().map(|(p, d)| (p.grads, d)).collect(),
        };
        let mut merge = Merge {
            multi: &mut multi,
            out: GradientsParams::new(),
            device: main,
        };
        model.visit(&mut merge);
        merge.out
    };
    let norm = global_norm(model, &grads);
    if !norm.is_finite() {
        return Ok(StepOutcome::Skipped(format!("gradient norm is {norm}")));
    }
    let max_norm = config.optim.grad_clip_norm as f64;
    if max_norm > 0.0 && norm > max_norm {
        scale_gradients(model, &mut grads, (max_norm / norm) as f32);
    }
    Ok(StepOutcome::Taken {
        grads,
        loss,
        mse,
        mse0,
        rays,
    })
}

/// One scene's share of a step.
struct ScenePart {
    grads: GradientsParams,
    loss: f64,
    mse: f64,
    mse0: f64,
    rays: usize,
}

enum SceneOutcome {
    Taken(ScenePart),
    Skipped(String),
}

/// The loss of one scene on `device` (the model's replica there) and its raw gradients.
/// `index` (the scene's number in the run) seeds the sample jitter.
fn scene_gradients(
    model: &NiaModel,
    scene: &Scene,
    faces: &[[u32; 3]],
    config: &TrainConfig,
    step: u64,
    index: u64,
    device: &Device,
) -> Result<SceneOutcome, TrainError> {
    let SceneTarget::Rays(rays) = &scene.target else {
        return Err(TrainError::NoRays(step));
    };
    let model_err = |source| TrainError::Model {
        step,
        subject: scene.subject.clone(),
        frame: scene.frame,
        source,
    };
    let input = SceneInput::from_loaded(scene, faces);
    let c0_shuffle = (config.train.c0_shuffle > 0.0).then(|| C0Shuffle {
        fraction: config.train.c0_shuffle,
        seed: Rng::new(config.train.seed)
            .fork(index)
            .fork(C0_SHUFFLE_STREAM)
            .next_u64(),
        seen_only: config.train.c0_shuffle_seen_only,
    });
    let encoded = model
        .encode(&input, None, device, None)
        .map_err(model_err)?
        .with_c0_shuffle(c0_shuffle);
    let samples = config.train.samples;
    let mut jitter_rng = Rng::new(config.train.seed).fork(index).fork(JITTER_STREAM);
    let jitter: Vec<f32> = (0..rays.len() * samples)
        .map(|_| jitter_rng.uniform())
        .collect();
    let out = model
        .render(&encoded, &rays.rays, samples, Some(&jitter), None)
        .map_err(model_err)?;
    let gt: Vec<f32> = rays.rgb.iter().flatten().copied().collect();
    let gt = Tensor::<2>::from_data(TensorData::new(gt, [rays.len(), 3]), device);
    let acc = out.acc.clone();
    let distortion = if config.train.distortion_loss_weight > 0.0 {
        Some(
            distortion_loss(out.weights.clone(), out.t.clone(), out.delta.clone())
                .map_err(|e| model_err(ModelError::Shape(e)))?,
        )
    } else {
        None
    };
    let ibr = if config.train.ibr_loss_weight > 0.0 {
        // NiaModel::render always fills the IBR-only composite; its absence is an error, not a
        // loss term silently left out.
        let rgb_ibr = out.rgb_ibr.clone().ok_or_else(|| {
            model_err(ModelError::Input(
                "train.ibr_loss_weight > 0 but the render has no IBR-only composite".into(),
            ))
        })?;
        Some(ibr_loss(rgb_ibr, gt.clone()).map_err(|e| model_err(ModelError::Shape(e)))?)
    } else {
        None
    };
    let mut loss =
        render_loss(out.rgb, out.rgb0, gt).map_err(|e| model_err(ModelError::Shape(e)))?;
    if let Some(ibr) = ibr {
        loss.total = loss.total + ibr.mul_scalar(config.train.ibr_loss_weight);
    }
    if config.train.mask_loss_weight > 0.0 {
        let on_body: Vec<f32> = rays.on_body.iter().map(|&b| b as u8 as f32).collect();
        let on_body = Tensor::<1>::from_data(TensorData::new(on_body, [rays.len()]), device);
        let mask = mask_loss(acc, on_body).map_err(|e| model_err(ModelError::Shape(e)))?;
        loss.total = loss.total + mask.mul_scalar(config.train.mask_loss_weight);
    }
    if let Some(distortion) = distortion {
        loss.total = loss.total + distortion.mul_scalar(config.train.distortion_loss_weight);
    }
    let values = Tensor::cat(
        vec![
            loss.total.clone().detach(),
            loss.mse.detach(),
            loss.mse0.detach(),
        ],
        0,
    )
    .into_data()
    .convert::<f32>()
    .try_to_vec::<f32>()
    .unwrap_or_default();
    let [total, mse, mse0] = match values.as_slice() {
        [a, b, c] => [*a as f64, *b as f64, *c as f64],
        _ => return Ok(SceneOutcome::Skipped("the loss could not be read".into())),
    };
    if !total.is_finite() {
        return Ok(SceneOutcome::Skipped(format!("loss is {total}")));
    }
    let grads = loss.total.backward();
    let grads = GradientsParams::from_grads(grads, model);
    Ok(SceneOutcome::Taken(ScenePart {
        grads,
        loss: total,
        mse,
        mse0,
        rays: rays.len(),
    }))
}

/// Every parameter's gradient summed over the devices of a [`MultiGradientsParams`], on
/// `device`.
struct Merge<'a> {
    multi: &'a mut MultiGradientsParams,
    out: GradientsParams,
    device: &'a Device,
}

impl ModuleVisitor for Merge<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some((g, _)) = self.multi.remove::<D>(param.id) {
            self.out.register(param.id, g.to_device(self.device));
        }
    }
}

/// Sum of squares of every parameter gradient, as one tensor read.
struct SquaredNorm<'a> {
    grads: &'a GradientsParams,
    total: Option<Tensor<1>>,
}

impl ModuleVisitor for SquaredNorm<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.get::<D>(param.id) {
            let s = g.square().sum();
            self.total = Some(match self.total.take() {
                Some(t) => t + s,
                None => s,
            });
        }
    }
}

/// The global L2 norm of the gradient (NaN or infinite when any entry is).
fn global_norm(model: &NiaModel, grads: &GradientsParams) -> f64 {
    let mut v = SquaredNorm { grads, total: None };
    model.visit(&mut v);
    match v.total {
        Some(t) => (t.into_scalar::<f32>() as f64).sqrt(),
        None => 0.0,
    }
}

struct Scale<'a> {
    grads: &'a mut GradientsParams,
    factor: f32,
}

impl ModuleVisitor for Scale<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.remove::<D>(param.id) {
            self.grads.register(param.id, g.mul_scalar(self.factor));
        }
    }
}

fn scale_gradients(model: &NiaModel, grads: &mut GradientsParams, factor: f32) {
    model.visit(&mut Scale { grads, factor });
}
