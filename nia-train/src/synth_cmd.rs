//! `nia-train synth`: the synthetic dataset, with a progress bar.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use nia_data::synth::capture::CapturePreset;
use nia_data::synth::{self, SynthEvent, SynthSection, SynthSpec};

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// Output folder (created if missing); subjects go to `OUT/CoreView_<id>/`.
    #[arg(long)]
    pub out: PathBuf,
    /// Number of subjects.
    #[arg(long, default_value_t = SynthSpec::default().subjects)]
    pub subjects: usize,
    /// Frames per subject.
    #[arg(long, default_value_t = SynthSpec::default().frames)]
    pub frames: usize,
    /// Cameras per subject, on a ring around the subject.
    #[arg(long, default_value_t = SynthSpec::default().cameras)]
    pub cameras: usize,
    /// Square image size in pixels.
    #[arg(long, default_value_t = SynthSpec::default().size)]
    pub size: u32,
    /// Seed: the same seed gives the same bytes.
    #[arg(long, default_value_t = SynthSpec::default().seed)]
    pub seed: u64,
    /// Anti-aliasing: samples per pixel along each axis.
    #[arg(long, default_value_t = SynthSpec::default().supersample)]
    pub supersample: u32,
    /// Id of the first subject folder (`CoreView_<id>`).
    #[arg(long, default_value_t = SynthSpec::default().first_subject_id)]
    pub first_subject_id: u32,
    /// The flaws of a real capture: `none` (clean) or `zju_like` (a fitted SMPL, segmented
    /// masks, per-camera colour, approximate calibration, hair and loose clothes off SMPL;
    /// docs/data.md).
    #[arg(long, default_value = "none")]
    pub capture: CapturePreset,
    /// Level of the SMPL fit's error over the preset's (0: off, 1: zju_like, at most 4).
    #[arg(long)]
    pub smpl_fit_level: Option<f32>,
    /// Level of the calibration's error over the preset's.
    #[arg(long)]
    pub calibration_level: Option<f32>,
    /// Level of the per-camera colour response over the preset's.
    #[arg(long)]
    pub colour_level: Option<f32>,
    /// Level of the mask flaws over the preset's.
    #[arg(long)]
    pub mask_level: Option<f32>,
    /// Level of the geometry off SMPL (hair volume, loose swinging garments) over the
    /// preset's.
    #[arg(long)]
    pub geometry_level: Option<f32>,
}

pub fn run(args: SynthArgs) -> anyhow::Result<()> {
    let spec = SynthSpec {
        subjects: args.subjects,
        frames: args.frames,
        cameras: args.cameras,
        size: args.size,
        seed: args.seed,
        supersample: args.supersample,
        first_subject_id: args.first_subject_id,
        capture: SynthSection::capture_levels(
            args.capture,
            [
                args.smpl_fit_level,
                args.calibration_level,
                args.colour_level,
                args.mask_level,
                args.geometry_level,
            ],
        ),
        ..SynthSpec::default()
    };
    let bar = ProgressBar::new(spec.total_images() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} synth [{elapsed_precise}] {bar:40} {pos}/{len} images ({per_sec}, eta {eta}) {msg}",
        )
        .expect("static progress template"),
    );
    let summary = synth::generate(&spec, &args.out, &mut |event| match event {
        SynthEvent::SubjectStarted {
            index, count, id, ..
        } => bar.set_message(format!("subject {} of {count} (CoreView_{id})", index + 1)),
        SynthEvent::ImageWritten { done, .. } => bar.set_position(done as u64),
        _ => {}
    })
    .with_context(|| format!("generating the synthetic dataset in {}", args.out.display()))?;
    bar.finish_and_clear();
    println!(
        "wrote {} subjects ({} images, {:.1} images/s) to {}",
        summary.subjects.len(),
        summary.images,
        summary.images_per_second(),
        summary.out_dir.display()
    );
    println!("body model: {}", summary.body_model.display());
    println!(
        "train subjects {:?}, unseen test subjects {:?}",
        summary.train_subjects, summary.test_subjects
    );
    Ok(())
}
