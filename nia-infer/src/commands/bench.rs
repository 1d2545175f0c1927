//! `nia-infer bench`: forward and training-step throughput of the network at a given setting
//! (default: the paper's, 1024 rays x 64 samples x 3 views on 512x512 sources), with the share
//! of time per stage. Scene: the procedural body seen by a ring of cameras, patterned images.

use std::time::Instant;

use anyhow::Context;
use burn::optim::AdamConfig;
use burn::prelude::*;
use clap::Args;
use nia_data::geometry::rays::RayBundle;
use nia_data::rng::Rng;
use nia_data::scene::SceneInput;
use nia_model::device::{Backend, DeviceSpec};
use nia_model::loss::render_loss;
use nia_model::renderer::RenderOutput;
use nia_model::scene_encoding::cut::chunked_gradients;
use nia_model::timing::{Stage, StageTimes};
use nia_model::{ModelConfig, NiaModel};
use serde::Serialize;

use crate::output::progress_bar;
use scene::bench_scene;

mod scene;

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Backend: ndarray, flex or wgpu.
    #[arg(long, value_parser = str::parse::<Backend>, default_value = "ndarray")]
    pub backend: Backend,
    /// Which GPU of a GPU backend (`--backend wgpu --device 1`).
    #[arg(long)]
    pub device: Option<usize>,
    /// Rays per batch.
    #[arg(long, default_value_t = 1024)]
    pub rays: usize,
    /// Samples per ray.
    #[arg(long, default_value_t = 64)]
    pub samples: usize,
    /// Source views.
    #[arg(long, default_value_t = 3)]
    pub views: usize,
    /// Source image size (square).
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Timed repetitions (after one warm-up); the report gives their median.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u64).range(1..))]
    pub reps: u64,
    /// Use the tiny test network instead of the paper's.
    #[arg(long)]
    pub tiny: bool,
    /// Edge of the body volume's voxels in metres (`model.voxel_size_m`; default: the
    /// network's own, 0.005 for the paper's and 0.02 for the tiny one; the main command uses
    /// 0.01).
    #[arg(long)]
    pub voxel_size_m: Option<f32>,
    /// Skip the training step (forward only).
    #[arg(long)]
    pub no_train: bool,
    /// Skip the inference forward (training step only; the forward figures are then null).
    #[arg(long, conflicts_with_all = ["no_train", "check_against"])]
    pub train_only: bool,
    /// Rays per chunk of the training step's forward and backward (0: all at once; as
    /// `train.ray_chunk`): the step then holds one chunk's activations. In chunked steps the
    /// forward and backward interleave, so the step is reported whole (forward figure null).
    #[arg(long, default_value_t = 0)]
    pub ray_chunk: usize,
    /// Train with burn's gradient checkpointing (`Device::gradient_checkpointing`: memory-bound
    /// operations are recomputed in the backward instead of kept; as `train.gradient_checkpointing`).
    #[arg(long)]
    pub checkpointing: bool,
    /// Also run the forward with the same weights on this backend and report how far the
    /// colours differ (`--backend wgpu --check-against flex`: the GPU path against the CPU's);
    /// with the training step, also one training forward's gradients.
    #[arg(long, value_parser = str::parse::<Backend>)]
    pub check_against: Option<Backend>,
}

/// The forward's colours on two backends with the same weights and inputs.
#[derive(Serialize)]
struct BackendCheck {
    against: String,
    /// Largest |a - b| over the colours and opacities (both in [0, 1]).
    max_abs_diff: f32,
    /// ||a - b|| / ||b|| over the colours and opacities.
    rel_l2: f32,
    /// With the training step: per parameter, the largest |difference| of the gradients of
    /// one training forward (the same weights, rays and jitter) over the largest |gradient| on
    /// the other backend. Empty with `--no-train`.
    gradients: Vec<(String, f32)>,
}

#[derive(Serialize)]
struct Report {
    backend: String,
    /// The heap policy of this process ([`nia_eval::heap`]).
    heap: String,
    rays: usize,
    samples: usize,
    views: usize,
    size: u32,
    /// The median of the timed forwards ([`Report::forward_reps_s`]).
    forward_s: f64,
    forward_rays_per_s: f64,
    /// The warm-up forward: the time to a first result, shader compilation and autotuning
    /// included on GPU backends.
    first_forward_s: f64,
    /// The warm-up training step, likewise.
    first_train_step_s: Option<f64>,
    /// The median of the timed training steps ([`Report::train_reps_s`]).
    train_step_s: Option<f64>,
    /// Of the training step: the forward on the autodiff device (graph recording included).
    train_forward_s: Option<f64>,
    /// Of the training step: backward and the Adam update.
    train_backward_s: Option<f64>,
    train_rays_per_s: Option<f64>,
    /// Per stage, the median over the forwards timed per stage.
    stages_s: Vec<(String, f64)>,
    /// Whether those are forwards of their own (GPU backends: timing a stage synchronises the
    /// device, so `forward_s` is taken without it, as the PyTorch references take theirs) or
    /// the timed forwards themselves (CPU backends, where a synchronisation is free).
    stages_timed_apart: bool,
    /// Seconds of each timed forward after the warm-up, in order.
    forward_reps_s: Vec<f64>,
    /// Seconds of each timed training step after the warm-up, in order.
    train_reps_s: Vec<f64>,
    check: Option<BackendCheck>,
}

/// The median of `values` as the PyTorch references take it (`sorted(xs)[len(xs) // 2]`: the
/// upper of the middle two for an even count); NaN when empty.
fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The forward's colours and opacities as one host vector, refused if any is not finite.
fn forward_colours(out: RenderOutput) -> anyhow::Result<Vec<f32>> {
    let read = |t: Tensor<2>, what: &str| -> anyhow::Result<Vec<f32>> {
        t.try_into_data()
            .map_err(|e| anyhow::anyhow!("reading the forward's {what} from the device: {e:?}"))?
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("{e:?}"))
    };
    let mut values = read(out.rgb, "colours")?;
    values.extend(read(out.acc.unsqueeze_dim(1), "opacities")?);
    anyhow::ensure!(
        values.iter().all(|x| x.is_finite()),
        "non-finite colours in the benchmark forward"
    );
    Ok(values)
}

/// The gradients of one training forward and backward (render loss against grey, the same
/// weights, rays and jitter) on `device` and on `other`: per parameter, the largest
/// |difference| over the largest |gradient| on `other`.
fn gradient_check(
    config: &ModelConfig,
    input: &SceneInput,
    rays: &RayBundle,
    samples: usize,
    device: &Device,
    other: &Device,
) -> anyhow::Result<Vec<(String, f32)>> {
    let ad = device.clone().autodiff();
    ad.seed(0);
    let model = config.init(&ad);
    let mut rng = Rng::new(5);
    let jitter: Vec<f32> = (0..rays.len() * samples).map(|_| rng.uniform()).collect();
    let gradients = |model: &NiaModel, d: &Device| -> anyhow::Result<Vec<(String, Vec<f32>)>> {
        let scene = model.encode(input, None, d, None)?;
        let out = model.render(&scene, rays, samples, Some(&jitter), None)?;
        let gt = Tensor::<2>::ones([rays.len(), 3], d).mul_scalar(0.5);
        let grads = render_loss(out.rgb, out.rgb0, gt)?.total.backward();
        let read = |name: &str, g: Option<Tensor<1>>| -> anyhow::Result<(String, Vec<f32>)> {
            let g = g.with_context(|| format!("{name} has no gradient"))?;
            let values = g
                .try_into_data()
                .map_err(|e| anyhow::anyhow!("reading the {name} gradient from the device: {e:?}"))?
                .try_to_vec::<f32>()
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            Ok((name.to_string(), values))
        };
        Ok(vec![
            read(
                "encoder.conv1",
                model
                    .encoder
                    .conv1
                    .weight
                    .val()
                    .grad(&grads)
                    .map(|g| g.flatten(0, 3)),
            )?,
            read(
                "body_volume.full[0]",
                model
                    .body_volume
                    .full
                    .first()
                    .and_then(|b| b.conv.weight.val().grad(&grads))
                    .map(|g| g.flatten(0, 2)),
            )?,
            read(
                "density",
                model.density.layers[0]
                    .weight
                    .val()
                    .grad(&grads)
                    .map(|g| g.flatten(0, 1)),
            )?,
            read(
                "blender.token_input",
                model
                    .blender
                    .token_input
                    .weight
                    .val()
                    .grad(&grads)
                    .map(|g| g.flatten(0, 1)),
            )?,
        ])
    };
    let other_ad = other.clone().autodiff();
    let ours = gradients(&model, &ad)?;
    let theirs = gradients(&model.clone().fork(&other_ad), &other_ad)?;
    Ok(ours
        .into_iter()
        .zip(theirs)
        .map(|((name, a), (_, b))| {
            let largest = b.iter().fold(0.0f32, |m, x| m.max(x.abs()));
            let diff = a
                .iter()
                .zip(&b)
                .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
            (name, diff / largest.max(f32::MIN_POSITIVE))
        })
        .collect())
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    let backend = args.backend;
    let device = DeviceSpec {
        backend,
        index: args.device,
    }
    .device()?;
    if let Some(note) = backend.start_up_note() {
        eprintln!("{note}");
    }
    let config = if args.tiny {
        ModelConfig::tiny()
    } else {
        ModelConfig::new()
    };
    let config = match args.voxel_size_m {
        Some(v) => config.with_voxel_size_m(v),
        None => config,
    };
    config
        .check()
        .map_err(|e| anyhow::anyhow!("--voxel-size-m: {e}"))?;
    let (input, rays) =
        bench_scene(args.size, args.views, args.rays).context("building the benchmark scene")?;
    device.seed(0);
    let model = config.init(&device);

    // One warm-up and `reps` timed repetitions of the forward, and of the training step.
    let passes = if args.no_train || args.train_only {
        1
    } else {
        2
    };
    // The forward's figure comes from repetitions without stage timings, as the PyTorch
    // references take theirs: timing a stage synchronises the device at its end, which on a GPU
    // backend adds waits and keeps the host's work from overlapping the device's. There the
    // stage table comes from `reps` repetitions of its own, timed per stage; on the CPU
    // backends a synchronisation is free and the same repetitions give both.
    let stages_apart = args.backend.is_gpu() && !args.train_only;
    let stage_only_reps = if stages_apart { args.reps } else { 0 };
    let bar = progress_bar(passes * (args.reps + 1) + stage_only_reps, "bench");
    // Per-repetition times: above the bar, or on stderr without a terminal (stdout carries the
    // table and the JSON line).
    let note = |line: String| {
        if bar.is_hidden() {
            eprintln!("{line}");
        } else {
            bar.println(line);
        }
    };

    // Forward (inference device), per stage.
    // Each timed repetition's seconds and stage times; the report takes their medians, as the
    // PyTorch references do, so one repetition that meets a new kernel does not set the figure.
    let mut forward_reps_s = Vec::new();
    let mut stage_reps = Vec::new();
    let mut first_forward_s = 0.0;
    let mut colours = Vec::new();
    let forward_reps = if args.train_only { 0 } else { args.reps + 1 };
    for rep in 0..forward_reps + stage_only_reps {
        // Repetitions 1..=reps time the forward; with the stages apart, the ones after them
        // time the stages.
        let stage_rep = rep > args.reps;
        let mut times = (!stages_apart || stage_rep).then(StageTimes::default);
        let start = Instant::now();
        let scene = model.encode(&input, None, &device, times.as_mut())?;
        let out = model.render(&scene, &rays, args.samples, None, times.as_mut())?;
        let rgb = forward_colours(out)?;
        let seconds = start.elapsed().as_secs_f64();
        if rep == 0 {
            first_forward_s = seconds;
            colours = rgb;
        } else if !stage_rep {
            forward_reps_s.push(seconds);
        }
        if rep > 0 {
            stage_reps.extend(times);
        }
        let label = match rep {
            0 => " (warm-up)",
            _ if stage_rep => " (stage timings)",
            _ => "",
        };
        note(format!("forward rep {rep}{label}: {seconds:.2} s"));
        bar.inc(1);
    }
    let mut forward_s = median(&forward_reps_s);
    if args.train_only {
        // Serialised as null.
        forward_s = f64::NAN;
        first_forward_s = f64::NAN;
    }

    let check = match args.check_against {
        None => None,
        Some(against) => {
            let other = DeviceSpec {
                backend: against,
                index: None,
            }
            .device()?;
            let reference = model.clone().to_device(&other);
            let scene = reference.encode(&input, None, &other, None)?;
            let theirs =
                forward_colours(reference.render(&scene, &rays, args.samples, None, None)?)?;
            let (mut max_abs_diff, mut diff2, mut ref2) = (0.0f32, 0.0f64, 0.0f64);
            for (a, b) in colours.iter().zip(&theirs) {
                max_abs_diff = max_abs_diff.max((a - b).abs());
                diff2 += f64::from(a - b).powi(2);
                ref2 += f64::from(*b).powi(2);
            }
            note(format!(
                "{} against {}: max |difference| {max_abs_diff:.2e}, relative L2 {:.2e}",
                args.backend.name(),
                against.name(),
                (diff2 / ref2.max(1e-30)).sqrt()
            ));
            let gradients = if args.no_train {
                Vec::new()
            } else {
                let gradients =
                    gradient_check(&config, &input, &rays, args.samples, &device, &other)?;
                for (name, rel) in &gradients {
                    note(format!(
                        "{name}: gradients {} against {} differ by {rel:.2e} of the largest",
                        args.backend.name(),
                        against.name()
                    ));
                }
                gradients
            };
            Some(BackendCheck {
                against: against.name().to_string(),
                max_abs_diff,
                rel_l2: (diff2 / ref2.max(1e-30)).sqrt() as f32,
                gradients,
            })
        }
    };

    // Training step (autodiff device): forward, loss, backward, Adam.
    // (step, its forward) seconds of each timed training repetition.
    let mut train_reps_s: Vec<(f64, f64)> = Vec::new();
    let (train_step_s, train_forward_s, train_rays_per_s, first_train_step_s) = if args.no_train {
        (None, None, None, None)
    } else {
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
        let mut first = 0.0;
        let mut rng = Rng::new(3);
        for rep in 0..=args.reps {
            let jitter: Vec<f32> = (0..rays.len() * args.samples)
                .map(|_| rng.uniform())
                .collect();
            let start = Instant::now();
            let scene = model.encode(&input, None, &ad, None)?;
            let chunked = args.ray_chunk > 0 && args.ray_chunk < rays.len();
            let mut forward_dt = f64::NAN;
            let n = rays.len() as f32;
            let grads = chunked_gradients::<anyhow::Error, _>(
                &model,
                &scene,
                &rays,
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
            note(format!(
                "train rep {rep}{}: {dt:.2} s ({split})",
                if rep == 0 { " (warm-up)" } else { "" },
            ));
            bar.inc(1);
            if rep == 0 {
                first = dt;
            } else {
                train_reps_s.push((dt, forward_dt));
            }
        }
        let step = median(&train_reps_s.iter().map(|r| r.0).collect::<Vec<_>>());
        (
            Some(step),
            Some(median(
                &train_reps_s.iter().map(|r| r.1).collect::<Vec<_>>(),
            )),
            Some(rays.len() as f64 / step),
            Some(first),
        )
    };

    bar.finish_and_clear();
    let report = Report {
        backend: args.backend.name().to_string(),
        heap: nia_eval::heap::current()
            .map_or("system (policy not set)", |p| p.name())
            .to_string(),
        rays: rays.len(),
        samples: args.samples,
        views: args.views,
        size: args.size,
        forward_s,
        forward_rays_per_s: rays.len() as f64 / forward_s,
        first_forward_s,
        first_train_step_s,
        train_step_s,
        // Chunked steps interleave forward and backward: no split (null, not NaN).
        train_forward_s: train_forward_s.filter(|f| f.is_finite()),
        // The median step less the median forward, so that the two parts add up to the step.
        train_backward_s: train_step_s
            .zip(train_forward_s)
            .map(|(s, f)| s - f)
            .filter(|b| b.is_finite()),
        train_rays_per_s,
        stages_s: Stage::ALL
            .iter()
            .map(|s| {
                let per_rep: Vec<f64> =
                    stage_reps.iter().map(|t| t.get(*s).as_secs_f64()).collect();
                (s.name().to_string(), median(&per_rep))
            })
            .collect(),
        stages_timed_apart: stages_apart,
        forward_reps_s,
        train_reps_s: train_reps_s.iter().map(|r| r.0).collect(),
        check,
    };
    if args.train_only {
        // The stages are timed in the inference forward, which --train-only skips.
        println!("stages: not timed (--train-only)");
    } else {
        if report.stages_timed_apart {
            println!(
                "stages: timed in {} forwards of their own (the forward's figure is untimed)",
                args.reps
            );
        }
        println!("| stage | seconds | share |\n|---|---|---|");
        let staged: f64 = report.stages_s.iter().map(|(_, t)| t).sum();
        for (name, t) in &report.stages_s {
            println!(
                "| {name} | {t:.3} | {:.1}% |",
                100.0 * t / staged.max(1e-12)
            );
        }
    }
    println!(
        "\nforward: {}; training step: {}",
        if args.train_only {
            "skipped".to_string()
        } else {
            format!(
                "{:.3} s per batch, {:.0} rays/s",
                report.forward_s, report.forward_rays_per_s
            )
        },
        match (
            report.train_step_s,
            report.train_rays_per_s,
            report.train_forward_s,
            report.train_backward_s,
        ) {
            (Some(s), Some(r), Some(f), Some(b)) =>
                format!("{s:.3} s, {r:.0} rays/s (forward {f:.3} s, backward + Adam {b:.3} s)"),
            (Some(s), Some(r), _, _) => format!(
                "{s:.3} s, {r:.0} rays/s (in chunks of {} rays)",
                args.ray_chunk
            ),
            _ => "skipped".into(),
        }
    );
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}
