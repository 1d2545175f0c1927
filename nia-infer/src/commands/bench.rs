//! `nia-infer bench`: forward and training-step throughput of the network at a given setting
//! (default: the paper's, 1024 rays x 64 samples x 3 views on 512x512 sources), with the share
//! of time per stage. Scene: the procedural body seen by a ring of cameras, patterned images.

use anyhow::Context;
use clap::Args;
use indicatif::ProgressBar;
use nia_data::geometry::rays::RayBundle;
use nia_data::scene::SceneInput;
use nia_model::device::Backend;
use nia_model::timing::Stage;
use nia_model::ModelConfig;
use serde::Serialize;

use crate::model_load::open_device;
use crate::output::progress_bar;
use check::BackendCheck;
use scene::bench_scene;
use timing::{median, ForwardTimes, TrainTimes};

mod check;
mod scene;
mod timing;

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

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    let device = open_device(args.backend, args.device)?;
    let config = model_config(&args)?;
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
    let bench = Bench {
        args: &args,
        input: &input,
        rays: &rays,
        bar: &bar,
    };
    // Forward (inference device), per stage. The report takes the medians of the timed
    // repetitions, as the PyTorch references do, so one repetition that meets a new kernel
    // does not set the figure.
    let forwards = bench.time_forwards(&model, &device, stages_apart)?;
    let check = match args.check_against {
        None => None,
        Some(against) => {
            Some(bench.backend_check(&config, &model, &device, against, &forwards.colours)?)
        }
    };
    // Training step (autodiff device): forward, loss, backward, Adam.
    let training = if args.no_train {
        None
    } else {
        Some(bench.time_training(&config, &device)?)
    };
    bar.finish_and_clear();
    let report = Report::new(&args, rays.len(), forwards, training, check, stages_apart);
    print_report(&args, &report);
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}

/// The network benchmarked: the paper's or the tiny one, with `--voxel-size-m`, checked.
fn model_config(args: &BenchArgs) -> anyhow::Result<ModelConfig> {
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
    Ok(config)
}

/// What the timings run on: the arguments, the scene and its rays, and the progress bar.
struct Bench<'a> {
    args: &'a BenchArgs,
    input: &'a SceneInput,
    rays: &'a RayBundle,
    bar: &'a ProgressBar,
}

impl Bench<'_> {
    /// A per-repetition line: above the bar, or on stderr without a terminal (stdout carries
    /// the table and the JSON line).
    fn note(&self, line: String) {
        if self.bar.is_hidden() {
            eprintln!("{line}");
        } else {
            self.bar.println(line);
        }
    }
}

impl Report {
    /// The report of the repetitions of `rays` rays: medians of the timed ones, the warm-ups
    /// apart.
    fn new(
        args: &BenchArgs,
        rays: usize,
        forwards: ForwardTimes,
        training: Option<TrainTimes>,
        check: Option<BackendCheck>,
        stages_timed_apart: bool,
    ) -> Self {
        let (forward_s, first_forward_s) = if args.train_only {
            // Serialised as null.
            (f64::NAN, f64::NAN)
        } else {
            (median(&forwards.reps_s), forwards.first_s)
        };
        let train_reps_s = training.as_ref().map_or(Vec::new(), |t| t.reps_s.clone());
        let train_step_s = training
            .as_ref()
            .map(|_| median(&train_reps_s.iter().map(|r| r.0).collect::<Vec<_>>()));
        let train_forward_s = training
            .as_ref()
            .map(|_| median(&train_reps_s.iter().map(|r| r.1).collect::<Vec<_>>()));
        Report {
            backend: args.backend.name().to_string(),
            heap: nia_eval::heap::current()
                .map_or("system (policy not set)", |p| p.name())
                .to_string(),
            rays,
            samples: args.samples,
            views: args.views,
            size: args.size,
            forward_s,
            forward_rays_per_s: rays as f64 / forward_s,
            first_forward_s,
            first_train_step_s: training.as_ref().map(|t| t.first_s),
            train_step_s,
            // Chunked steps interleave forward and backward: no split (null, not NaN).
            train_forward_s: train_forward_s.filter(|f| f.is_finite()),
            // The median step less the median forward, so that the two parts add up to the
            // step.
            train_backward_s: train_step_s
                .zip(train_forward_s)
                .map(|(s, f)| s - f)
                .filter(|b| b.is_finite()),
            train_rays_per_s: train_step_s.map(|step| rays as f64 / step),
            stages_s: Stage::ALL
                .iter()
                .map(|s| {
                    let per_rep: Vec<f64> = forwards
                        .stage_reps
                        .iter()
                        .map(|t| t.get(*s).as_secs_f64())
                        .collect();
                    (s.name().to_string(), median(&per_rep))
                })
                .collect(),
            stages_timed_apart,
            forward_reps_s: forwards.reps_s,
            train_reps_s: train_reps_s.iter().map(|r| r.0).collect(),
            check,
        }
    }
}

/// The stage table and the summary line on stdout.
fn print_report(args: &BenchArgs, report: &Report) {
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
}
