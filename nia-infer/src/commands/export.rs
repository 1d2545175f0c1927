//! `nia-infer export`: a training checkpoint (or the newest one of a run folder) to one
//! self-describing `.nia` model file ([`nia_model::store::model_file`]).

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use nia_model::store::checkpoint::{self, CONFIG_FILE, STEP_FILE};
use nia_model::store::model_file::ModelFile;
use serde::Serialize;

#[derive(Args, Debug)]
pub struct ExportArgs {
    /// A checkpoint folder (`runs/X/checkpoints/step_00001000`) or a run folder (`runs/X`:
    /// its newest checkpoint).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// The model file to write (written to a temporary name, then renamed).
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Serialize)]
struct Report<'a> {
    model: &'a Path,
    checkpoint: &'a Path,
    step: u64,
    variant: nia_model::Variant,
    bytes: u64,
    weights_fnv1a64: &'a str,
}

pub fn run(args: &ExportArgs) -> anyhow::Result<()> {
    let path = &args.checkpoint;
    let dir = checkpoint::resolve(path)?.with_context(|| {
        format!(
            "{}: not a checkpoint (no {STEP_FILE}) and no complete checkpoint under {}",
            path.display(),
            path.join(checkpoint::CHECKPOINT_DIR).display()
        )
    })?;
    let config_path = dir.join(CONFIG_FILE);
    let saved = checkpoint::read_config(&dir).with_context(|| {
        format!(
            "{}: not a nia-train checkpoint config",
            config_path.display()
        )
    })?;
    saved
        .model
        .check()
        .map_err(|e| anyhow::anyhow!("{}: model config: {e}", config_path.display()))?;
    let step = checkpoint::read_step(&dir).with_context(|| {
        format!(
            "{}: expected {{\"step\": N}}",
            dir.join(STEP_FILE).display()
        )
    })?;
    // Loading into a network of the saved config checks that the weights fit it.
    #[allow(deprecated)] // burn 0.22 spells the CPU device this way.
    let device = burn::prelude::Device::ndarray();
    let model = checkpoint::load_model(&dir, saved.model.init(&device)).with_context(|| {
        format!(
            "the weights of {} do not fit its {} (trained with another config?)",
            dir.display(),
            CONFIG_FILE
        )
    })?;
    let file = ModelFile::from_model(&model, &saved.model, saved.run.clone(), step)
        .map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
    file.write(&args.out)?;
    let bytes = std::fs::metadata(&args.out)
        .with_context(|| format!("reading back {}", args.out.display()))?
        .len();
    let report = Report {
        model: &args.out,
        checkpoint: &dir,
        step,
        variant: saved.model.variant,
        bytes,
        weights_fnv1a64: &file.header.weights.fnv1a64,
    };
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
