//! nia-train: training from config files (issue 5) and `synth`, the built-in synthetic dataset
//! in the exact ZJU-MoCap layout.
//!
//! `nia-train --config configs/quickstart.toml [--backend ndarray|flex|wgpu] [--resume]
//! [--out DIR] [--steps N]` (also as `nia-train train ...`), `nia-train synth ...` and
//! `nia-train ablation --config ...` (the paper's Table 3).

mod ablation_cmd;
mod log_lines;
mod synth_cmd;

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Parser, Subcommand};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use nia_model::device::{Backend, DeviceSpec};
use nia_model::store::checkpoint;
use nia_train::config::TrainConfig;
use nia_train::curves::RunCurves;
use nia_train::events::TrainEvent;
use nia_train::tensorboard::EventWriter;
use nia_train::train_loop::{train, RunOptions};

/// Train NIA models, or generate the synthetic ZJU-MoCap-layout dataset.
#[derive(Parser)]
#[command(version, about, args_conflicts_with_subcommands = true)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    train: TrainArgs,
}

#[derive(Subcommand)]
enum Command {
    /// Train from a config file (the same as the top-level flags).
    Train(TrainArgs),
    /// Generate synthetic subjects in the exact ZJU-MoCap layout.
    Synth(synth_cmd::SynthArgs),
    /// The paper's ablation (Table 3): variants (a)..(e) at equal budget, 1..3 source views,
    /// novel pose; writes a markdown table and a picture.
    Ablation(ablation_cmd::AblationArgs),
    /// Fit SMPL to a calibrated multi-view capture (images, person masks, OpenPose keypoints)
    /// and write the ZJU-MoCap layout the readers and the trainer take (docs/own-capture.md).
    Prepare(nia_train::prepare::PrepareArgs),
    /// Draw a run's loss and PSNR curves (`RUN/curves.svg`) from its `metrics.jsonl`, also
    /// while it trains.
    Curves {
        /// The run folder (holding metrics.jsonl).
        run: PathBuf,
    },
}

#[derive(Args, Debug)]
struct TrainArgs {
    /// Run config (TOML), e.g. configs/quickstart.toml.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override `train.backend`: ndarray, flex or wgpu.
    #[arg(long, value_parser = str::parse::<Backend>)]
    backend: Option<Backend>,
    /// Continue from the newest checkpoint in the output folder.
    #[arg(long)]
    resume: bool,
    /// Start afresh in an output folder that already holds a run: its checkpoints/,
    /// metrics.jsonl and evaluation/ are deleted first. Without `--resume` or `--overwrite`, a
    /// folder with checkpoints is refused.
    #[arg(long, conflicts_with = "resume")]
    overwrite: bool,
    /// Output folder (default `runs/<config name>`): metrics.jsonl and checkpoints/.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Override `train.steps`.
    #[arg(long, allow_negative_numbers = true)]
    steps: Option<u64>,
    /// Which GPU of a GPU backend (`--backend wgpu --device 1`: the second discrete GPU).
    #[arg(long, conflicts_with = "devices")]
    device: Option<usize>,
    /// Override `train.devices`: the devices of a step, one scene each, e.g. `wgpu:0,wgpu:1`.
    #[arg(long, value_delimiter = ',', value_parser = str::parse::<DeviceSpec>)]
    devices: Vec<DeviceSpec>,
    /// Override any config key, e.g. `--set train.mask_loss_weight=0.3` or
    /// `--set 'model.ray_sampler={ kind = "band" }'` (repeatable; TOML values, bare words are
    /// strings).
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    set: Vec<String>,
}

/// The config file's name without its extension (`quickstart` for configs/quickstart.toml),
/// which names the default output folder.
pub(crate) fn config_stem(path: &std::path::Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "run".into())
}

/// Makes burn's default device the training backend (unless the user set `BURN_DEVICE`):
/// burn materialises restored optimiser state on the default device, which with the `wgpu`
/// feature compiled in would otherwise be the GPU even for a CPU run.
pub(crate) fn pin_default_device(backend: Backend) {
    if std::env::var_os("BURN_DEVICE").is_none() {
        std::env::set_var("BURN_DEVICE", backend.name());
    }
}

/// Writes `run/curves.svg` from `run/metrics.jsonl`.
fn write_curves(run: &std::path::Path) -> anyhow::Result<PathBuf> {
    let svg = RunCurves::read(&run.join(METRICS_FILE))?.svg()?;
    let path = run.join(CURVES_FILE);
    std::fs::write(&path, svg).with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// What a run folder holds besides its checkpoints (deleted by `--overwrite`).
const METRICS_FILE: &str = "metrics.jsonl";
const CURVES_FILE: &str = "curves.svg";
const TENSORBOARD_DIR: &str = "tensorboard";

fn main() -> anyhow::Result<()> {
    nia_eval::heap::keep_freed_memory()?;
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Synth(args)) => synth_cmd::run(args),
        Some(Command::Ablation(args)) => ablation_cmd::run(args),
        Some(Command::Train(args)) => run_train(args),
        Some(Command::Prepare(args)) => run_prepare(&args),
        Some(Command::Curves { run }) => {
            let path = write_curves(&run)?;
            println!("curves: {}", path.display());
            Ok(())
        }
        None => run_train(cli.train),
    }
}

/// `nia-train prepare`: one bar over the frames (read, fitted, written), then the summary.
fn run_prepare(args: &nia_train::prepare::PrepareArgs) -> anyhow::Result<()> {
    use nia_data::fitting::FitProgress;
    use nia_train::prepare::PrepareEvent;
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} {elapsed_precise}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let stage = |msg: &'static str, done: usize, total: usize| {
        bar.set_message(msg);
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let report = nia_train::prepare::run(args, &mut |e| match e {
        PrepareEvent::Loaded { done, total } => stage("reading", done, total),
        PrepareEvent::Fit(FitProgress::ShapeFrame { done, total }) => {
            stage("shape frames", done, total)
        }
        PrepareEvent::Fit(FitProgress::Shape) => stage("shape", 1, 1),
        PrepareEvent::Fit(FitProgress::Frame { done, total }) => stage("fitting", done, total),
        PrepareEvent::Written { done, total } => stage("writing", done, total),
    })?;
    bar.finish_and_clear();
    println!(
        "fitted {} frames x {} views ({} keypoints) -> {}",
        report.frames,
        report.views,
        report.layout,
        report.subject_dir.display()
    );
    println!(
        "fit time {:.2} s per frame; mean keypoint reprojection error {:.2} px",
        report.seconds_per_frame, report.keypoint_error_px
    );
    if let Some(t) = report.truth {
        println!(
            "against the truth: MPJPE {:.2} cm (worst frame {:.2} cm), mean vertex error {:.2} cm",
            t.mpjpe_cm, t.worst_frame_mpjpe_cm, t.vertex_cm
        );
    }
    println!(
        "check the fit: {}",
        report.subject_dir.join("fit_overlay").display()
    );
    Ok(())
}

fn run_train(args: TrainArgs) -> anyhow::Result<()> {
    let Some(config_path) = args.config.clone() else {
        anyhow::bail!("missing `--config <FILE>` (e.g. configs/quickstart.toml); see --help");
    };
    let config = train_config(&args, &config_path)?;
    pin_default_device(config.train.backend);
    if let Some(note) = config
        .train
        .device_specs()
        .iter()
        .find_map(|spec| spec.backend.start_up_note())
    {
        eprintln!("{note}");
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs").join(config_stem(&config_path)));
    prepare_out(&args, &out)?;
    let metrics_path = out.join(METRICS_FILE);
    let mut metrics = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&metrics_path)
        .with_context(|| format!("opening {}", metrics_path.display()))?;
    let multi = MultiProgress::new();
    let bar = multi.add(ProgressBar::new(config.train.steps));
    let mut phase_bar = log_lines::PhaseBar::default();
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} train [{elapsed_precise}] {bar:30} {pos}/{len} steps (eta {eta}) {msg}",
        )
        .expect("static progress template"),
    );
    let mut write_error: Option<std::io::Error> = None;
    let mut tensorboard = EventWriter::create(&out.join(TENSORBOARD_DIR))?;
    let mut tensorboard_error: Option<anyhow::Error> = None;
    let mut final_evaluation: Option<String> = None;
    let summary = train(
        &config,
        &RunOptions {
            out: out.clone(),
            resume: args.resume,
        },
        &mut |event| {
            if tensorboard_error.is_none() {
                if let Err(e) = tensorboard_record(&mut tensorboard, &event) {
                    tensorboard_error = Some(e);
                }
            }
            if let TrainEvent::Progress { phase, done, total } = &event {
                log_lines::phase(&bar, phase.name(), *done, *total);
                phase_bar.update(&multi, phase.name(), *done, *total);
                return;
            }
            if let TrainEvent::ValidationImage { .. } = &event {
                return;
            }
            if write_error.is_none() {
                let line = serde_json::to_string(&event).unwrap_or_default();
                if let Err(e) = writeln!(metrics, "{line}") {
                    write_error = Some(e);
                }
            }
            if let Some(line) = console_event(&bar, &event, &config) {
                final_evaluation = Some(line);
            }
        },
    )
    .with_context(|| format!("training {}", config_path.display()))?;
    bar.finish_and_clear();
    if let Some(e) = write_error {
        return Err(e).with_context(|| format!("writing {}", metrics_path.display()));
    }
    if let Some(e) = tensorboard_error {
        return Err(e);
    }
    tensorboard.flush()?;
    let curves = write_curves(&out)?;
    println!(
        "trained {} steps ({} this run, {} skipped); last loss {}; metrics {}",
        summary.steps,
        summary.steps_run,
        summary.skipped,
        summary
            .last_loss
            .map(|l| format!("{l:.5}"))
            .unwrap_or_else(|| "-".into()),
        metrics_path.display()
    );
    if let Some(c) = &summary.last_checkpoint {
        println!("checkpoint: {}", c.display());
    }
    println!(
        "curves: {}; TensorBoard: tensorboard --logdir {}",
        curves.display(),
        out.join(TENSORBOARD_DIR).display()
    );
    if let Some(line) = final_evaluation {
        println!("{line}");
        if let Some(c) = &summary.last_checkpoint {
            println!(
                "every image's grids and the per-image instruments: nia-infer export --checkpoint {} --out model.nia && nia-infer eval --model model.nia --out eval",
                c.display()
            );
        }
    }
    Ok(())
}

/// The run config of `config_path` with the command line's overrides (`--set`, `--backend`,
/// `--steps`, `--devices`, `--device`).
fn train_config(args: &TrainArgs, config_path: &std::path::Path) -> anyhow::Result<TrainConfig> {
    let mut config = TrainConfig::load_with(config_path, &args.set)?;
    if let Some(backend) = args.backend {
        config.train.backend = backend;
    }
    if let Some(steps) = args.steps {
        config.train.steps = steps;
    }
    if !args.devices.is_empty() {
        config.train.devices = args.devices.clone();
    }
    if let Some(index) = args.device {
        if !config.train.devices.is_empty() {
            anyhow::bail!(
                "--device {index}: the config lists train.devices; pass --devices instead"
            );
        }
        if !config.train.backend.is_gpu() {
            anyhow::bail!(
                "--device {index}: {} is a CPU backend with a single device",
                config.train.backend.name()
            );
        }
        config.train.devices = vec![DeviceSpec {
            backend: config.train.backend,
            index: Some(index),
        }];
    }
    Ok(config)
}

/// The output folder made ready: one that already holds a run is cleared with `--overwrite`
/// (its checkpoints, evaluation, TensorBoard files, metrics and curves), continued with
/// `--resume`, else refused.
fn prepare_out(args: &TrainArgs, out: &std::path::Path) -> anyhow::Result<()> {
    let existing = checkpoint::latest(out)
        .with_context(|| format!("reading the checkpoints of {}", out.display()))?;
    if let Some((step, _)) = existing {
        if args.overwrite {
            for name in ["checkpoints", "evaluation", TENSORBOARD_DIR] {
                let dir = out.join(name);
                if dir.exists() {
                    std::fs::remove_dir_all(&dir)
                        .with_context(|| format!("deleting {}", dir.display()))?;
                }
            }
            for name in [METRICS_FILE, CURVES_FILE] {
                let file = out.join(name);
                if file.exists() {
                    std::fs::remove_file(&file)
                        .with_context(|| format!("deleting {}", file.display()))?;
                }
            }
        } else if !args.resume {
            anyhow::bail!(
                "{} already holds a run (its newest checkpoint is step {step}): pass --resume to \
                 continue it, --overwrite to start afresh there, or --out for another folder",
                out.display()
            );
        }
    }
    std::fs::create_dir_all(out)
        .with_context(|| format!("creating the output folder {}", out.display()))
}

/// `event` on the console (above `bar`, or as plain lines without a terminal); the final
/// evaluation's lines are also returned, to repeat at the end.
fn console_event(bar: &ProgressBar, event: &TrainEvent, config: &TrainConfig) -> Option<String> {
    match event {
        TrainEvent::DataReady {
            root,
            train_subjects,
            unseen_subjects,
            generated,
        } => log_lines::line(
            bar,
            format!(
                "data {}{}: train {:?}, held out {:?}",
                root.display(),
                if *generated { " (generated)" } else { "" },
                train_subjects,
                unseen_subjects
            ),
        ),
        TrainEvent::Started { first_step, .. } => bar.set_position(*first_step),
        TrainEvent::Step(s) => {
            bar.set_position(s.step + 1);
            let message = format!(
                "loss {:.4} psnr {:.2} dB {:.0} rays/s lr {:.2e}",
                s.loss, s.psnr, s.rays_per_s, s.lr
            );
            log_lines::progress(bar, s.step + 1, config.train.steps, &message);
            bar.set_message(message);
        }
        TrainEvent::Skipped { step, reason } => {
            bar.set_position(step + 1);
            log_lines::line(bar, format!("step {step} skipped: {reason}"));
        }
        TrainEvent::Checkpoint { path, .. } => {
            log_lines::line(bar, format!("checkpoint {}", path.display()))
        }
        TrainEvent::Validation {
            step,
            images,
            psnr,
            ssim,
            lpips,
        } => log_lines::line(
            bar,
            format!(
                "validation after {step} steps: PSNR {psnr:.2} dB, SSIM {ssim:.4}{} on {images} held-out images",
                lpips_text(*lpips, config.train.lpips.as_ref())
            ),
        ),
        TrainEvent::Evaluation { .. } => {
            let line = evaluation_lines(event, config)?;
            log_lines::line(bar, &line);
            return Some(line);
        }
        TrainEvent::Finished { .. }
        | TrainEvent::Progress { .. }
        | TrainEvent::ValidationImage { .. } => {}
    }
    None
}

/// The final evaluation's report: scores, the hybrid's instruments and where the pictures
/// are (`None` for any other event).
fn evaluation_lines(event: &TrainEvent, config: &TrainConfig) -> Option<String> {
    let TrainEvent::Evaluation {
        split,
        images,
        psnr,
        ssim,
        lpips,
        c0_share_seen,
        psnr_ibr,
        psnr_nerf,
        psnr_silhouette,
        psnr_interior,
        pictures,
        ..
    } = event
    else {
        return None;
    };
    let share = c0_share_seen
        .map(|s| format!("{s:.2}"))
        .unwrap_or_else(|| "-".into());
    let db = |v: &Option<f64>| v.map_or("-".into(), |v| format!("{v:.2} dB"));
    Some(format!(
        "evaluation ({split}, {images} images): PSNR {psnr:.2} dB, SSIM {ssim:.4}{}\n  \
         IBR-only {psnr_ibr:.2} dB, NeRF-only {psnr_nerf:.2} dB, NeRF-colour share where a source sees {share}\n  \
         PSNR next to the outline {}, elsewhere {}\n  \
         grids and blend maps: {}",
        lpips_text(*lpips, config.train.lpips.as_ref()),
        db(psnr_silhouette),
        db(psnr_interior),
        pictures.display()
    ))
}

/// The TensorBoard record of `event`: scalars of steps, validations and the final evaluation,
/// validation grids as images; checkpoints flush the file.
fn tensorboard_record(tb: &mut EventWriter, event: &TrainEvent) -> anyhow::Result<()> {
    match event {
        TrainEvent::Step(s) => {
            let step = s.step + 1;
            tb.scalar("train/loss", step, s.loss as f32)?;
            tb.scalar("train/psnr", step, s.psnr as f32)?;
            tb.scalar("train/lr", step, s.lr as f32)?;
            tb.scalar("train/rays_per_s", step, s.rays_per_s as f32)?;
        }
        TrainEvent::Validation {
            step,
            psnr,
            ssim,
            lpips,
            ..
        } => {
            tb.scalar("validation/psnr", *step, *psnr as f32)?;
            tb.scalar("validation/ssim", *step, *ssim as f32)?;
            if let Some(l) = lpips {
                tb.scalar("validation/lpips", *step, *l as f32)?;
            }
            tb.flush()?;
        }
        TrainEvent::ValidationImage {
            step,
            index,
            width,
            height,
            rgb,
        } => {
            let image = image::RgbImage::from_raw(*width, *height, rgb.clone())
                .context("a validation grid whose size does not match its pixels")?;
            let mut png = Vec::new();
            image
                .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
                .context("encoding a validation grid as PNG")?;
            tb.png(
                &format!("validation/image_{index}"),
                *step,
                *width,
                *height,
                &png,
            )?;
        }
        TrainEvent::Evaluation {
            step,
            split,
            psnr,
            ssim,
            psnr_ibr,
            psnr_nerf,
            psnr_silhouette,
            psnr_interior,
            lpips,
            ..
        } => {
            for (name, value) in [
                ("psnr_silhouette", psnr_silhouette),
                ("psnr_interior", psnr_interior),
            ] {
                if let Some(v) = value {
                    tb.scalar(&format!("evaluation/{split}/{name}"), *step, *v as f32)?;
                }
            }
            if let Some(l) = lpips {
                tb.scalar(&format!("evaluation/{split}/lpips"), *step, *l as f32)?;
            }
            tb.scalar(&format!("evaluation/{split}/psnr"), *step, *psnr as f32)?;
            tb.scalar(&format!("evaluation/{split}/ssim"), *step, *ssim as f32)?;
            tb.scalar(
                &format!("evaluation/{split}/psnr_ibr"),
                *step,
                *psnr_ibr as f32,
            )?;
            tb.scalar(
                &format!("evaluation/{split}/psnr_nerf"),
                *step,
                *psnr_nerf as f32,
            )?;
            tb.flush()?;
        }
        TrainEvent::Checkpoint { .. } | TrainEvent::Finished { .. } => tb.flush()?,
        _ => {}
    }
    Ok(())
}

/// `, LPIPS 0.1234 (alex)` when LPIPS was scored.
fn lpips_text(value: Option<f64>, files: Option<&nia_eval::perceptual::LpipsFiles>) -> String {
    match (value, files) {
        (Some(v), Some(f)) => format!(", LPIPS {v:.4} ({})", f.net.name()),
        (Some(v), None) => format!(", LPIPS {v:.4}"),
        _ => String::new(),
    }
}
