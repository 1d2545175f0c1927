//! One training step: each device's scene through the forward pass and the loss, its
//! gradients, and their sum, clipped by the global norm (the parent module's docs).

use std::ops::Range;

use burn::module::Module;
use burn::optim::{GradientsParams, MultiGradientsParams};
use burn::prelude::*;
use nia_data::dataset::loader::{Scene, SceneTarget};
use nia_data::dataset::sampling::TrainRays;
use nia_data::rng::Rng;
use nia_data::scene::SceneInput;
use nia_model::ibr::c0_shuffle::C0Shuffle;
use nia_model::kernels::readback::host_values_of;
use nia_model::loss::{
    colour_matched_target, distortion_loss, mask_loss, patch_ssim_loss, render_loss, RenderLoss,
};
use nia_model::renderer::RenderOutput;
use nia_model::scene_encoding::cut::chunked_gradients;
use nia_model::{ModelError, NiaModel};

use super::gradients::{scale_gradients, squared_norm, Merge};
use super::TrainError;
use crate::config::TrainConfig;

/// Label of the jitter stream forked from a step's RNG (the loader uses the request seed).
const JITTER_STREAM: u64 = 1;
/// Label of the c0-shuffling stream forked from a step's RNG (`train.c0_shuffle`).
const C0_SHUFFLE_STREAM: u64 = 2;

pub(super) enum StepOutcome {
    Taken {
        grads: GradientsParams,
        loss: f64,
        mse: f64,
        mse0: f64,
        rays: usize,
    },
    Skipped(String),
}

/// The CPU threads each device's work runs on. One device uses rayon's global pool; several
/// devices each get a pool of their own with an equal share of the global pool's threads (at
/// least one), so that two devices' parallel kernels do not queue on one pool (measured in
/// docs/data.md, "Training on a GPU, or on several devices").
pub(super) struct DevicePools(Vec<rayon::ThreadPool>);

impl DevicePools {
    pub(super) fn new(devices: usize) -> Result<Self, TrainError> {
        if devices < 2 {
            return Ok(Self(Vec::new()));
        }
        let threads = (rayon::current_num_threads() / devices).max(1);
        let pools = (0..devices)
            .map(|i| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .thread_name(move |t| format!("nia-device-{i}-{t}"))
                    .build()
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self(pools))
    }

    /// Runs `work` on device `i`'s pool (on the calling thread where there is none).
    fn install<R: Send>(&self, i: usize, work: impl FnOnce() -> R + Send) -> R {
        match self.0.get(i) {
            Some(pool) => pool.install(work),
            None => work(),
        }
    }
}

pub(super) fn train_step(
    model: &NiaModel,
    pools: &DevicePools,
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
    // One device stays on the calling thread: burn 0.22's batch-norm running statistics keep a
    // pending update per thread and average them in a hash map's order, so a new thread each
    // step would make them differ between runs in the last bit (nia-train/tests/determinism.rs).
    if let ([scene], [device]) = (scenes, devices) {
        let outcome = scene_gradients(model, scene, faces, config, step, step, device);
        return combine(model, vec![outcome], devices, config);
    }
    // Several: one thread per device, each on its replica of the model (forked to it; the first
    // is the model itself), all at once. A panic on a device's thread is passed on unchanged,
    // as the same panic on one thread would be.
    let outcomes: Vec<Result<ScenePart, TrainError>> = std::thread::scope(|threads| {
        let handles: Vec<_> = scenes
            .iter()
            .zip(devices)
            .enumerate()
            .map(|(i, (scene, device))| {
                let replica = if i == 0 {
                    model.clone()
                } else {
                    model.clone().fork(device)
                };
                let index = step * k + i as u64;
                threads.spawn(move || {
                    pools.install(i, || {
                        scene_gradients(&replica, scene, faces, config, step, index, device)
                    })
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
            })
            .collect()
    });
    combine(model, outcomes, devices, config)
}

/// The step of the devices' `outcomes`: the summed, clipped gradient and the scenes' mean
/// losses, or skipped where a loss or the gradient norm is not finite.
///
/// The losses stay on their devices until here, and the first device's are read together with
/// the gradient's squared norm: one read back per step on one device (one more per further
/// device), which the loss log needs anyway (docs/speed.md, "Readbacks").
fn combine(
    model: &NiaModel,
    outcomes: Vec<Result<ScenePart, TrainError>>,
    devices: &[Device],
    config: &TrainConfig,
) -> Result<StepOutcome, TrainError> {
    let main = &devices[0];
    let parts = outcomes.into_iter().collect::<Result<Vec<_>, _>>()?;
    let rays = parts.iter().map(|p| p.rays).sum();
    let mut losses = Vec::with_capacity(parts.len());
    let mut per_device = Vec::with_capacity(parts.len());
    for (part, device) in parts.into_iter().zip(devices) {
        losses.push(part.losses);
        per_device.push((part.grads, device.clone()));
    }
    // The gradient of the summed loss: burn's MultiGradientsParams adds each parameter's
    // gradients from every device; the sum is moved to the model's device.
    let mut grads = if per_device.len() == 1 {
        per_device.pop().expect("one device").0
    } else {
        let mut multi = MultiGradientsParams { grads: per_device };
        let mut merge = Merge {
            multi: &mut multi,
            out: GradientsParams::new(),
            device: main,
        };
        model.visit(&mut merge);
        merge.out
    };
    let squared = squared_norm(model, &grads).unwrap_or_else(|| Tensor::zeros([1], main));
    let mut losses = losses.into_iter();
    let first = Tensor::cat(
        vec![losses.next().expect("one device at least"), squared],
        0,
    );
    // [total, mse, mse0, |g|^2] of the first device, then [total, mse, mse0] of each other.
    let read = std::iter::once(("the step's losses and gradient norm", first, 4))
        .chain(losses.map(|other| ("a device's losses", other, 3)))
        .map(|(what, values, len)| {
            host_values_of(what, values)
                .ok()
                .filter(|values| values.len() == len)
        })
        .collect::<Option<Vec<_>>>();
    let Some(read) = read else {
        return Ok(StepOutcome::Skipped("the loss could not be read".into()));
    };
    let mut sums = [0.0f64; 3];
    for values in &read {
        let total = f64::from(values[0]);
        if !total.is_finite() {
            return Ok(StepOutcome::Skipped(format!("loss is {total}")));
        }
        for (s, v) in sums.iter_mut().zip(&values[..3]) {
            *s += f64::from(*v);
        }
    }
    let n = read.len() as f64;
    let [loss, mse, mse0] = sums.map(|s| s / n);
    let norm = f64::from(read[0][3]).sqrt();
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
    /// `[3]` the weighted sums over the chunks of the total loss, the MSE and the MSE of c0,
    /// on the scene's device (read in [`combine`]).
    losses: Tensor<1>,
    rays: usize,
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
) -> Result<ScenePart, TrainError> {
    let SceneTarget::Rays(rays) = &scene.target else {
        return Err(TrainError::NoRays(step));
    };
    let model_err = |source: ModelError| TrainError::Model {
        step,
        subject: scene.subject.clone(),
        frame: scene.frame,
        source: Box::new(source),
    };
    let input = SceneInput::from_loaded(scene, faces);
    let augments_c0 = config.train.c0_shuffle > 0.0 || config.train.c0_noise_std > 0.0;
    let c0_shuffle = augments_c0.then(|| C0Shuffle {
        fraction: config.train.c0_shuffle,
        seed: Rng::new(config.train.seed)
            .fork(index)
            .fork(C0_SHUFFLE_STREAM)
            .next_u64(),
        seen_only: config.train.c0_shuffle_seen_only,
        noise_std: config.train.c0_noise_std,
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
    let n = rays.len() as f32;
    // [total, mse, mse0], each chunk's weighted by its share of the rays, kept on the device:
    // the step reads them once, with the gradient norm ([`combine`]).
    let mut losses: Option<Tensor<1>> = None;
    let grads = chunked_gradients(
        model,
        &encoded,
        &rays.rays,
        samples,
        Some(&jitter),
        config.train.ray_chunk,
        |out, range| {
            let share = range.len() as f32 / n;
            let loss = chunk_loss(out, rays, range, config, device)?;
            let values = Tensor::cat(
                vec![
                    loss.total.clone().detach(),
                    loss.mse.detach(),
                    loss.mse0.detach(),
                ],
                0,
            )
            .mul_scalar(share);
            losses = Some(match losses.take() {
                Some(sum) => sum + values,
                None => values,
            });
            // Without chunks the share is 1, and x * 1 is x exactly.
            Ok(loss.total.mul_scalar(share))
        },
    )
    .map_err(model_err)?;
    let losses = losses.ok_or(TrainError::NoRays(step))?;
    Ok(ScenePart {
        grads,
        losses,
        rays: rays.len(),
    })
}

/// The loss of one chunk of a scene's rays (`range` of `rays`; all of them without chunking):
/// the paper's terms and the switchable ones of `config.train`, each a mean over the chunk.
fn chunk_loss(
    out: RenderOutput,
    rays: &TrainRays,
    range: Range<usize>,
    config: &TrainConfig,
    device: &Device,
) -> Result<RenderLoss, ModelError> {
    let shape = ModelError::Shape;
    let r = range.len();
    let gt: Vec<f32> = rays.rgb[range.clone()].iter().flatten().copied().collect();
    let gt = Tensor::<2>::from_data(TensorData::new(gt, [r, 3]), device);
    let gt =
        colour_matched_target(&out.rgb, gt, config.train.colour_gain_tolerance).map_err(shape)?;
    let acc = out.acc.clone();
    let distortion = if config.train.distortion_loss_weight > 0.0 {
        Some(
            distortion_loss(out.weights.clone(), out.t.clone(), out.delta.clone())
                .map_err(shape)?,
        )
    } else {
        None
    };
    let ssim = if config.train.ssim_loss_weight > 0.0 {
        Some(
            patch_ssim_loss(out.rgb.clone(), gt.clone(), config.train.ssim_patch_px)
                .map_err(shape)?,
        )
    } else {
        None
    };
    let mut loss = render_loss(out.rgb, out.rgb0, gt).map_err(shape)?;
    if let Some(ssim) = ssim {
        loss.total = loss.total + ssim.mul_scalar(config.train.ssim_loss_weight);
    }
    if config.train.mask_loss_weight > 0.0 {
        let on_body: Vec<f32> = rays.on_body[range]
            .iter()
            .map(|&b| b as u8 as f32)
            .collect();
        let on_body = Tensor::<1>::from_data(TensorData::new(on_body, [r]), device);
        let mask = mask_loss(acc, on_body).map_err(shape)?;
        loss.total = loss.total + mask.mul_scalar(config.train.mask_loss_weight);
    }
    if let Some(distortion) = distortion {
        loss.total = loss.total + distortion.mul_scalar(config.train.distortion_loss_weight);
    }
    Ok(loss)
}
