//! `nia-infer inspect DIR [--format zju|monocap] [--smpl MODEL] [--ratio R]`.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use nia_data::dataset::{inspect, DatasetConfig, DatasetFormat};

/// Arguments of `inspect`.
#[derive(Args, Debug)]
pub struct InspectArgs {
    /// The subject folder (holding `annots.npy`).
    pub dir: PathBuf,
    /// Folder layout: `zju` (ZJU-MoCap and the synthetic set) or `monocap` (adds `lbs/`).
    #[arg(long, default_value = "zju")]
    pub format: DatasetFormat,
    /// The SMPL model (`SMPL_NEUTRAL.pkl` or `.npz`): adds `lbs_max_err_m`, the largest
    /// distance between LBS of frame 0's params and its stored vertices.
    #[arg(long)]
    pub smpl: Option<PathBuf>,
    /// Image resize ratio in (0, 1] (default: 0.5 for zju, 1 for monocap).
    #[arg(long)]
    pub ratio: Option<f32>,
}

/// Prints the report as one JSON object on one line of stdout.
pub fn run(args: &InspectArgs) -> anyhow::Result<()> {
    let config = DatasetConfig {
        ratio: args.ratio,
        smpl_model: args.smpl.clone(),
        ..DatasetConfig::for_format(args.format)
    };
    let report = inspect(&args.dir, &config)
        .with_context(|| format!("cannot inspect {}", args.dir.display()))?;
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}
