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

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use burn::optim::AdamConfig;
use burn::optim::ModuleOptimizer;
use burn::prelude::*;
use nia_data::dataset::loader::{BandGrid, BodyVolumeGrid, LoaderConfig, SceneLoader};
use nia_data::dataset::protocol::EvalSplit;
use nia_eval::eval::{
    eval_items, evaluate_images, evaluate_items, EvalError, EvalOptions, EvalSummary, EvalTask,
};
use nia_eval::pictures::{comparison_grid, save_evaluated};
use nia_model::body_volume::NUM_SCALES;
use nia_model::kernels::host_op::runs_on_host;
use nia_model::kernels::readback::readbacks;
use nia_model::loss::psnr_from_mse;
use nia_model::lpips::Lpips;
use nia_model::renderer::call_size::rays_per_chunk;
use nia_model::sampler::RaySampler;
use nia_model::store::checkpoint::{self, CheckpointError};
use nia_model::{ModelError, NiaModel};

use crate::config::TrainConfig;
use crate::data::{DataError, TrainData};
use crate::events::{Phase, StepReport, TrainEvent};

mod gradients;
mod step;

use step::{train_step, StepOutcome};

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
    /// The model failed on a training scene (boxed: the largest error, it would make every
    /// `Result` of the loop carry its size).
    #[error("step {step} ({subject}, frame {frame}): {source}")]
    Model {
        step: u64,
        subject: String,
        frame: usize,
        source: Box<ModelError>,
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
    /// A device's thread pool could not be started (several devices per step).
    #[error("train.devices: starting a device's thread pool: {0}")]
    ThreadPool(#[from] rayon::ThreadPoolBuildError),
    /// `train.lpips` could not be loaded.
    #[error("train.lpips: {0}")]
    Lpips(#[from] nia_model::lpips::LpipsLoadError),
    /// `train.encoder_weights` could not be loaded into the encoder.
    #[error("train.encoder_weights: {0}")]
    EncoderWeights(#[from] nia_model::encoder::import::EncoderLoadError),
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
    let devices = training_devices(config)?;
    let k = devices.len() as u64;
    let device = devices[0].clone();
    device.seed(t.seed);
    // The model first: its initialisation draws from the seeded device.
    let (mut model, mut optimizer, first_step, last_checkpoint) =
        initial_state(config, options, &device)?;
    // LPIPS of validation and the final evaluation, on the evaluation (non-autodiff) device.
    let lpips = match &t.lpips {
        Some(files) => Some(Arc::new(files.load(&device.clone().inner())?)),
        None => None,
    };
    let evaluation = Evaluation {
        data: &data,
        config,
        device: &device,
        lpips,
    };
    on_event(TrainEvent::Started {
        first_step,
        steps: t.steps,
    });
    // Scene `step * K + i` of the run goes to device i (K = 1: scene `step`).
    let requests = (first_step..t.steps)
        .flat_map(|step| (0..k).map(move |i| step * k + i))
        .map(|scene| data.request_for_step(t.seed, scene, t.source_views))
        .collect();
    let pools = step::DevicePools::new(devices.len())?;
    let mut loader = SceneLoader::new(
        data.dataset.source.clone(),
        requests,
        loader_config(&data, &model, &devices),
    )?;
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
        let reads_before = readbacks();
        let lr = config.optim.lr_at(step);
        let outcome = train_step(
            &model,
            &pools,
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
                on_event(TrainEvent::Step(StepReport {
                    step,
                    loss,
                    mse,
                    mse0,
                    psnr: psnr_from_mse(mse),
                    rays_per_s: rays as f64 / seconds,
                    lr,
                    readbacks: readbacks() - reads_before,
                }));
            }
        }
        let done = step + 1;
        summary.steps = done;
        summary.steps_run += 1;
        if t.validate_every > 0 && done % t.validate_every == 0 {
            evaluation.validate(&model, done, on_event)?;
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
        evaluation.final_evaluation(&model, summary.steps, &options.out, on_event)?;
    }
    on_event(TrainEvent::Finished {
        steps: summary.steps,
        seconds: run_start.elapsed().as_secs_f64(),
    });
    Ok(summary)
}

/// The autodiff devices of `train.devices` (data parallelism: K devices, K scenes per step,
/// one per device; the first device holds the model and the optimiser), with gradient
/// checkpointing when asked for.
fn training_devices(config: &TrainConfig) -> Result<Vec<Device>, TrainError> {
    let t = &config.train;
    let devices = t
        .device_specs()
        .iter()
        .map(|s| {
            s.device().map(|d| match t.gradient_checkpointing {
                true => d.autodiff().gradient_checkpointing(),
                false => d.autodiff(),
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(devices)
}

/// The model and optimiser the run starts from, on `device`, with the first step and the
/// checkpoint they came from: the newest checkpoint in the output folder when resuming, else
/// a fresh model (from `train.init_from`'s weights, or with `train.encoder_weights`'
/// encoder).
fn initial_state(
    config: &TrainConfig,
    options: &RunOptions,
    device: &Device,
) -> Result<(NiaModel, ModuleOptimizer, u64, Option<PathBuf>), TrainError> {
    let t = &config.train;
    let mut model = config.model.init(device);
    let optimizer = adam(config).init();
    let resume_from = if options.resume {
        checkpoint::latest(&options.out)?
    } else {
        None
    };
    if let Some((_, dir)) = resume_from {
        let (model, optimizer, step) = checkpoint::load(&dir, model, optimizer)?;
        return Ok((model, optimizer, step, Some(dir)));
    }
    if let Some(dir) = &t.init_from {
        model = checkpoint::load_model(dir, model)?;
    } else if let Some(path) = &t.encoder_weights {
        model.encoder = model.encoder.load_torchvision(path)?;
    }
    Ok((model, optimizer, 0, None))
}

/// The loader settings of the run: the dataset's, with the geometry its workers build ahead of
/// each step for `model` on `devices`.
fn loader_config(data: &TrainData, model: &NiaModel, devices: &[Device]) -> LoaderConfig {
    let mut loader_config = data.dataset.loader;
    // The loader's workers build each training scene's band grid ahead of the step.
    loader_config.band_grid = match model.ray_sampler {
        RaySampler::Band { margin_m, cell_m } => Some(BandGrid {
            threshold_m: margin_m,
            cell_m,
        }),
        RaySampler::Stratified => None,
    };
    // ... and its body volume's sites and rulebooks, with the neighbour maps that the CPU's
    // host sparse convolution reads (any device on the host: the maps serve them all).
    loader_config.body_volume = model.variant.uses_body().then(|| BodyVolumeGrid {
        grid: model.voxel_grid(),
        levels: NUM_SCALES,
        neighbour_maps: devices.iter().any(runs_on_host),
    });
    loader_config
}

/// The event that `phase` starts, with `total` images to do.
fn phase_start(phase: Phase, total: usize) -> TrainEvent {
    TrainEvent::Progress {
        phase,
        done: 0,
        total,
    }
}

/// The run's held-out evaluations: validation every `train.validate_every` steps and the
/// final evaluation, novel views of the unseen subjects.
struct Evaluation<'a> {
    data: &'a TrainData,
    config: &'a TrainConfig,
    /// The training device (evaluations run on its non-autodiff version).
    device: &'a Device,
    lpips: Option<Arc<Lpips>>,
}

impl Evaluation<'_> {
    /// The settings of both evaluations: the training samples, the `[render]` options.
    fn options(&self) -> EvalOptions {
        let t = &self.config.train;
        EvalOptions {
            task: EvalTask::NovelView,
            samples: t.samples,
            chunk: rays_per_chunk(self.device, t.samples, &self.config.render),
            timed: false,
            render: self.config.render,
            lpips: self.lpips.clone(),
            truth: None,
        }
    }

    /// Validation after step `step` (`train.validation_images` images), reported with the
    /// comparison grids of the first [`VALIDATION_PICTURES`].
    fn validate(
        &self,
        model: &NiaModel,
        step: u64,
        on_event: &mut dyn FnMut(TrainEvent),
    ) -> Result<(), TrainError> {
        let items = eval_items(
            &self.data.dataset,
            EvalSplit::UnseenSubjects,
            EvalTask::NovelView,
            Some(self.config.train.validation_images),
        )?;
        let total = items.len();
        on_event(phase_start(Phase::Validation, total));
        let summary = evaluate_items(
            model,
            &self.data.dataset,
            &items,
            self.options(),
            self.device,
            &mut |done, evaluated| {
                if done <= VALIDATION_PICTURES {
                    let grid = comparison_grid(evaluated);
                    on_event(TrainEvent::ValidationImage {
                        step,
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
        )?;
        if let Some(m) = summary {
            on_event(TrainEvent::Validation {
                step,
                images: m.images,
                psnr: m.psnr,
                ssim: m.ssim,
                lpips: m.lpips,
            });
        }
        Ok(())
    }

    /// The final evaluation of the whole unseen-subject split after `step` steps, with the
    /// pictures of [`FINAL_PICTURES`] images spread over it in `<out>/evaluation/`.
    fn final_evaluation(
        &self,
        model: &NiaModel,
        step: u64,
        out: &Path,
        on_event: &mut dyn FnMut(TrainEvent),
    ) -> Result<(), TrainError> {
        let split = EvalSplit::UnseenSubjects;
        let items = eval_items(&self.data.dataset, split, EvalTask::NovelView, None)?;
        let pictures = out.join("evaluation");
        std::fs::create_dir_all(&pictures)
            .map_err(|e| EvalError::Output(format!("creating {}: {e}", pictures.display())))?;
        // Pictures of images spread over the split (every k-th), so they show several views.
        let every = items.len().div_ceil(FINAL_PICTURES).max(1);
        let mut index = 0usize;
        let total = items.len();
        on_event(phase_start(Phase::Evaluation, total));
        let results = evaluate_images(
            model,
            &self.data.dataset,
            split,
            &items,
            self.options(),
            self.device,
            &mut |evaluated| {
                let keep = index.is_multiple_of(every);
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
                step,
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
        Ok(())
    }
}

/// Adam with the configured betas and epsilon (clipping is applied by the loop, by global norm).
pub fn adam(config: &TrainConfig) -> AdamConfig {
    AdamConfig::new()
        .with_beta_1(config.optim.beta1)
        .with_beta_2(config.optim.beta2)
        .with_epsilon(config.optim.adam_eps)
}
