//! `nia-train ablation`: the paper's Table 3 on a run config, with a progress bar per variant.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use nia_model::device::Backend;
use nia_train::ablation::{self, AblationEvent};
use nia_train::config::TrainConfig;
use nia_train::events::TrainEvent;

use crate::log_lines;

#[derive(Args, Debug)]
pub struct AblationArgs {
    /// Run config (TOML) every variant is trained with, e.g. configs/quickstart.toml.
    #[arg(long)]
    pub config: PathBuf,
    /// Output folder (default `runs/ablation_<config name>`); a rerun resumes each variant.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override `train.steps` (the budget of every variant).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Override `train.backend`.
    #[arg(long, value_parser = str::parse::<Backend>)]
    pub backend: Option<Backend>,
    /// Override `data.root` (with `[synth]`, the dataset is generated there if missing).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Override `synth.seed`: other synthetic people (use with `--data`, a fresh folder).
    #[arg(long, requires = "data")]
    pub synth_seed: Option<u64>,
    /// Override any config key (repeatable), as `nia-train --set`.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    pub set: Vec<String>,
}

pub fn run(args: AblationArgs) -> anyhow::Result<()> {
    let mut config = TrainConfig::load_with(&args.config, &args.set)?;
    if let Some(steps) = args.steps {
        config.train.steps = steps;
    }
    if let Some(backend) = args.backend {
        config.train.backend = backend;
    }
    if let Some(root) = args.data {
        config.data.root = root;
    }
    if let Some(seed) = args.synth_seed {
        let Some(synth) = config.synth.as_mut() else {
            anyhow::bail!(
                "--synth-seed needs a `[synth]` section in {}",
                args.config.display()
            );
        };
        synth.seed = seed;
    }
    crate::pin_default_device(config.train.backend);
    let out = args.out.unwrap_or_else(|| {
        PathBuf::from("runs").join(format!("ablation_{}", crate::config_stem(&args.config)))
    });
    let steps = config.train.steps;
    let style = ProgressStyle::with_template(
        "{spinner} {prefix:>18} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}",
    )
    .expect("static progress template");
    let bar = ProgressBar::new(steps).with_style(style);
    let report = ablation::run(&config, &out, &mut |event| match event {
        AblationEvent::Train { variant, event } => match event {
            TrainEvent::Started { first_step, .. } => {
                bar.set_prefix(format!(
                    "({}) {}",
                    ablation::paper_letter(variant),
                    variant.name()
                ));
                bar.set_length(steps);
                bar.set_position(*first_step);
                bar.set_message("training");
            }
            TrainEvent::Step(s) => {
                bar.set_position(s.step + 1);
                let message = format!("{}: training, psnr {:.2} dB", variant.name(), s.psnr);
                log_lines::progress(&bar, s.step + 1, steps, &message);
                bar.set_message(message);
            }
            TrainEvent::Skipped { step, reason } => log_lines::line(
                &bar,
                format!("{}: step {step} skipped: {reason}", variant.name()),
            ),
            TrainEvent::Progress { phase, done, total } => {
                let name = format!("{}: {}", variant.name(), phase.name());
                log_lines::phase(&bar, &name, *done, *total);
                bar.set_message(format!("{name}: {done}/{total} images"));
            }
            _ => {}
        },
        AblationEvent::Generating { done, total } => {
            log_lines::phase(&bar, "generating the synthetic dataset", done, total);
            bar.set_message(format!(
                "generating the synthetic dataset: {done}/{total} images"
            ));
        }
        AblationEvent::Evaluating { label } => {
            let message = format!("evaluating {label}");
            if bar.is_hidden() {
                println!("{message}");
            }
            bar.set_message(message);
        }
        AblationEvent::Row(row) => log_lines::line(
            &bar,
            format!(
                "{:<28} PSNR {:.2} dB  SSIM {:.4}  ({} images, {} views, train {:.0} s)",
                row.label, row.psnr, row.ssim, row.images, row.views, row.train_seconds
            ),
        ),
    })
    .with_context(|| format!("ablation of {}", args.config.display()))?;
    bar.finish_and_clear();
    for line in ablation::orderings(&report.rows) {
        println!("{line}");
    }
    println!("table: {}", report.table.display());
    println!(
        "picture (ground truth, then each row): {}",
        report.picture.display()
    );
    Ok(())
}
