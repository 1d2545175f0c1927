//! `nia-train synth`: the synthetic dataset, with a progress bar.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use nia_data::own_capture::KeypointLayout;
use nia_data::synth::capture::CapturePreset;
use nia_data::synth::{self, KeypointSpec, SynthEvent, SynthSection, SynthSpec};

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
    /// Also write the 2D keypoints a detector would report, in OpenPose's JSON:
    /// `CoreView_<id>/keypoints/Camera_B<k>/<frame:06>_keypoints.json` (the true body's
    /// keypoints seen by the true cameras, with noise, occluded ones and drops left out, and
    /// outliers; docs/data.md "Own-capture inputs").
    #[arg(long)]
    pub keypoints: bool,
    /// Keypoint set of `--keypoints`: `body25` (OpenPose BODY_25) or `coco18`.
    #[arg(long, default_value_t = KeypointSpec::default().layout, requires = "keypoints")]
    pub keypoint_layout: KeypointLayout,
    /// Standard deviation of the keypoints' pixel noise per axis, pixels.
    #[arg(long, default_value_t = KeypointSpec::default().noise_px, requires = "keypoints")]
    pub keypoint_noise_px: f32,
    /// Fraction of the visible keypoints not reported (a detector's misses).
    #[arg(long, default_value_t = KeypointSpec::default().drop, requires = "keypoints")]
    pub keypoint_drop: f32,
    /// Fraction of the reported keypoints moved 30 to 80 pixels (a detector's confusions).
    #[arg(long, default_value_t = KeypointSpec::default().outliers, requires = "keypoints")]
    pub keypoint_outliers: f32,
    /// The detector's hips, neck and shoulders a few centimetres off SMPL's joints, as
    /// OpenPose's are (docs/data.md "Own-capture inputs").
    #[arg(long, requires = "keypoints")]
    pub keypoint_offsets: bool,
    /// Probability per frame that a camera starts losing a keypoint for 3 to 8 frames in a
    /// row (a detector's misses come in runs).
    #[arg(long, default_value_t = KeypointSpec::default().lost_runs, requires = "keypoints")]
    pub keypoint_lost_runs: f32,
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
        keypoints: args.keypoints.then_some(KeypointSpec {
            layout: args.keypoint_layout,
            noise_px: args.keypoint_noise_px,
            drop: args.keypoint_drop,
            outliers: args.keypoint_outliers,
            detector_offsets: args.keypoint_offsets,
            lost_runs: args.keypoint_lost_runs,
        }),
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
    if let Some(k) = spec.keypoints {
        println!(
            "keypoints: OpenPose {} in CoreView_<id>/keypoints/ ({} px noise, {:.0}% dropped, {:.0}% outliers)",
            k.layout,
            k.noise_px,
            k.drop * 100.0,
            k.outliers * 100.0
        );
    }
    println!(
        "train subjects {:?}, unseen test subjects {:?}",
        summary.train_subjects, summary.test_subjects
    );
    Ok(())
}
