//! nia-infer: render, animate, evaluate, export, inspect.
use clap::Parser;

/// Inference tools for nia-rs.
#[derive(Parser)]
#[command(version, about)]
enum Cli {}

fn main() -> anyhow::Result<()> {
    let _cli = Cli::parse();
    Ok(())
}
