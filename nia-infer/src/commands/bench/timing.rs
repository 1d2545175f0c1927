//! `nia-infer bench`'s timed repetitions: the forward on the inference device (per stage, on
//! GPU backends in forwards of their own) and the training step on the autodiff device, each
//! after one warm-up.

use std::time::Instant;

use burn::optim::AdamConfig;
use burn::prelude::*;
use nia_data::rng::Rng;
use nia_model::loss::render_loss;
use nia_model::scene_encoding::cut::chunked_gradients;
use nia_model::timing::StageTimes;
use nia_model::{ModelConfig, NiaModel};

use super::check::forward_colours;
use super::Bench;

/// The median of `values` as the PyTorch references take it (`sorted(xs)[len(xs) // 2]`: the
/// upper of the middle two for an even count); NaN when empty.
pub(super) fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The forward's repetitions.
pub(super) struct ForwardTimes {
    /// The warm-up forward: the time to a first result, shader compilation and autotuning
    /// included on GPU backends.
    pub first_s: f64,
    /// Seconds of each timed forward after the warm-up, in order.
    pub reps_s: Vec<f64>,
    /// The stage times of the forwards timed per stage.
    pub stage_reps: Vec<StageTimes>,
    /// The warm-up forward's colours and opacities (what `--check-against` compares).
    pub colours: Vec<f32>,
}

/// The training step's repetitions.
pub(super) struct TrainTimes {
    /// The warm-up step.
    pub first_s: f64,
    /// (step, its forward) seconds of each timed step after the warm-up, in order.
    pub reps_s: Vec<(f64, f64)>,
}

impl Bench<'_> {
    /// One warm-up and `--reps` timed repetitions of the forward of `model` on `device`
    /// (none with `--train-only`), then with `stages_apart` `--reps` more timed per stage.
    pub(super) fn time_forwards(
        &self,
        model: &NiaModel,
        device: &Device,
        stages_apart: bool,
    ) -> anyhow::Result<ForwardTimes> {
        let args = self.args;
        let stage_only_reps = if stages_apart { args.reps } else { 0 };
        let mut times_out = ForwardTimes {
            first_s: 0.0,
            reps_s: Vec::new(),
            stage_reps: Vec::new(),
            colours: Vec::new(),
        };
        let forward_reps = if args.train_only { 0 } else { args.reps + 1 };
        for rep in 0..forward_reps + stage_only_reps {
            // Repetitions 1..=reps time the forward; with the stages apart, the ones after
            // them time the stages.
            let stage_rep = rep > args.reps;
            let mut times = (!stages_apart || stage_rep).then(StageTimes::default);
            let start = Instant::now();
            let scene = model.encode(self.input, None, device, times.as_mut())?;
            let out = model.render(&scene, self.rays, args.samples, None, times.as_mut())?;
            let rgb = forward_colours(out)?;
            let seconds = start.elapsed().as_secs_f64();
            if rep == 0 {
                times_out.first_s = seconds;
                times_out.colours = rgb;
            } else if !stage_rep {
                times_out.reps_s.push(seconds);
            }
            if rep > 0 {
                times_out.stage_reps.extend(times);
            }
            let label = match rep {
                0 => " (warm-up)",
                _ if stage_rep => " (stage timings)",
                _ => "",
            };
            self.note(format!("forward rep {rep}{label}: {seconds:.2} s"));
            self.bar.inc(1);
        }
        Ok(times_out)
    }

    /// One warm-up and `--reps` timed training steps (forward, loss, backward, Adam) of a
    /// fresh `config` network on the autodiff version of `device`.
    pub(super) fn time_training(
        &self,
        config: &ModelConfig,
        device: &Device,
    ) -> anyhow::Result<TrainTimes> {
        let (args, rays) = (self.args, self.rays);
        let ad = device.clone().autodiff();
        let ad = if args.checkpointing {
            ad.gradient_checkpointing()
        } else {
            ad
        };
        ad.seed(0);
        let mut model = config.init(&ad);
        let mut optim = AdamConfig::new().with_epsilon(1e-8).init();
        let gt = Tensor::<2>::ones([rays.len(), 3], &ad).mul_scalar(0.5);
        let mut times = TrainTimes {
            first_s: 0.0,
            reps_s: Vec::new(),
        };
        let mut rng = Rng::new(3);
        for rep in 0..=args.reps {
            let jitter: Vec<f32> = (0..rays.len() * args.samples)
                .map(|_| rng.uniform())
                .collect();
            let start = Instant::now();
            let scene = model.encode(self.input, None, &ad, None)?;
            let chunked = args.ray_chunk > 0 && args.ray_chunk < rays.len();
            let mut forward_dt = f64::NAN;
            let n = rays.len() as f32;
            let grads = chunked_gradients::<anyhow::Error, _>(
                &model,
                &scene,
                rays,
                args.samples,
                Some(&jitter),
                args.ray_chunk,
                |out, range| {
                    let share = range.len() as f32 / n;
                    let gt = gt.clone().slice([range.clone(), 0..3]);
                    let loss = render_loss(out.rgb, out.rgb0, gt)?.total.mul_scalar(share);
                    if !chunked {
                        // The forward's own time on asynchronous backends too.
                        ad.sync().map_err(|e| anyhow::anyhow!("{e:?}"))?;
                        forward_dt = start.elapsed().as_secs_f64();
                    }
                    Ok(loss)
                },
            )?;
            model = optim.step(5e-4, model, grads);
            ad.sync().map_err(|e| anyhow::anyhow!("{e:?}"))?;
            let dt = start.elapsed().as_secs_f64();
            let split = if chunked {
                format!(
                    "{} chunks of {} rays",
                    rays.len().div_ceil(args.ray_chunk),
                    args.ray_chunk
                )
            } else {
                format!(
                    "forward {forward_dt:.2} s, backward + Adam {:.2} s",
                    dt - forward_dt
                )
            };
            self.note(format!(
                "train rep {rep}{}: {dt:.2} s ({split})",
                if rep == 0 { " (warm-up)" } else { "" },
            ));
            self.bar.inc(1);
            if rep == 0 {
                times.first_s = dt;
            } else {
                times.reps_s.push((dt, forward_dt));
            }
        }
        Ok(times)
    }
}
