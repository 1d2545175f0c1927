//! nia-train: training from config files (issue 5) and `synth`, the built-in synthetic dataset
//! in the exact ZJU-MoCap layout.

mod synth_cmd;

use clap::{Parser, Subcommand};

/// Train NIA models, or generate the synthetic ZJU-MoCap-layout dataset.
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate synthetic subjects in the exact ZJU-MoCap layout.
    Synth(synth_cmd::SynthArgs),
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Synth(args) => synth_cmd::run(args),
    }
}
