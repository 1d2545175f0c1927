//! nia-infer: export, render, animate, orbit, evaluate, sweep, bench, inspect, metrics.
//!
//! A thin binary: each subcommand parses its arguments and calls the libraries; all data
//! and model logic lives in `nia-data` and `nia-model`, evaluation in this crate's library.

mod commands;
mod model_load;
mod output;
mod session;
mod subject_scene;
mod viewer;

use std::process::ExitCode;

use clap::Parser;

/// Inference tools for nia-rs.
#[derive(Parser)]
#[command(version, about)]
enum Cli {
    /// Summarise a subject folder (ZJU-MoCap `CoreView_XXX`, MonoCap, or synthetic) as one JSON
    /// object: cameras, frames, image size, camera 0, body bounds, mask coverage and, with
    /// `--smpl`, how well the model's LBS reproduces the stored vertices.
    Inspect(commands::inspect::InspectArgs),
    /// PSNR and SSIM of a predicted image against the ground truth, as NHP/NIA report them,
    /// printed as `{"psnr": .., "ssim": ..}`.
    Metrics(commands::metrics::MetricsArgs),
    /// Throughput of the network's forward pass and training step (rays/s) with the share of
    /// time per stage, on a procedural-body scene (paper setting by default).
    Bench(commands::bench::BenchArgs),
    /// Pack a training checkpoint into one self-describing model file (`.nia`).
    Export(commands::export::ExportArgs),
    /// Render novel views of one frame from a few source views (PNGs, opacity and blend-weight
    /// maps, render.json with rays, network evaluations and time per stage).
    Render(commands::render::RenderArgs),
    /// Repose the subject of a reference frame to other frames' SMPL poses: PNG frames and an
    /// animated GIF.
    Animate(commands::animate::AnimateArgs),
    /// A 360-degree turn around the subject of one frame on the ring of the calibrated
    /// cameras: PNG frames, an animated GIF and an MP4 where ffmpeg is installed.
    Orbit(commands::orbit::OrbitArgs),
    /// Score a split with the protocol's PSNR and SSIM: metrics.json, metrics.csv, report.md,
    /// comparison grids and blend-weight maps.
    Eval(commands::eval::EvalArgs),
    /// What accuracy costs in time: PSNR, SSIM, milliseconds and network points per image over
    /// samples per ray, source views, resolution and empty-space skipping (sweep.csv,
    /// sweep.md, sweep.svg with the Pareto front).
    Sweep(commands::sweep::SweepArgs),
    /// Orbit an unseen person in the browser: a local server with the page, renders on demand
    /// (drag to orbit, wheel to zoom, pose slider, colour / NeRF colour / blend / opacity /
    /// depth), the source views and the cost of every frame.
    View(commands::view::ViewArgs),
}

/// Runs the subcommand; on failure prints the error and its causes on one line to stderr
/// (no backtrace, whatever `RUST_BACKTRACE` says) and exits with status 1.
fn main() -> ExitCode {
    if let Err(e) = nia_eval::heap::keep_freed_memory() {
        eprintln!("error: {e}");
        return ExitCode::FAILURE;
    }
    let result = match Cli::parse() {
        Cli::Inspect(args) => commands::inspect::run(&args),
        Cli::Metrics(args) => commands::metrics::run(&args),
        Cli::Bench(args) => commands::bench::run(args),
        Cli::Export(args) => commands::export::run(&args),
        Cli::Render(args) => commands::render::run(&args),
        Cli::Animate(args) => commands::animate::run(&args),
        Cli::Orbit(args) => commands::orbit::run(&args),
        Cli::Eval(args) => commands::eval::run(&args),
        Cli::Sweep(args) => commands::sweep::run(&args),
        Cli::View(args) => commands::view::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
