//! `nia-train prepare`: a user's calibrated multi-view capture (images, person masks, OpenPose
//! keypoints, cameras) in, SMPL fitted per frame ([`nia_data::fitting`]), out the ZJU-MoCap
//! layout the readers and the trainer take unchanged:
//!
//! ```text
//! OUT/<subject>/annots.npy, params/<n>.npy, vertices/<n>.npy, <view>/<image>, mask/<view>/...
//! OUT/<subject>/fit_overlay/<view>/<image stem>.png   the fit drawn on the photos
//! OUT/<subject>/fit.json                               per-frame errors and timings, betas
//! ```
//!
//! - [`input`]: finding and reading the capture; [`output`]: the atomic write;
//!   [`overlay`]: the check pictures; [`truth`]: errors against a known body; [`error`].
//!
//! The library reports [`PrepareEvent`]s and never prints; the binary draws the bar.

pub mod error;
pub mod input;
pub mod output;
pub mod overlay;
pub mod truth;

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use glam::Vec3;
use nia_data::body::{BodyModel, SmplParams};
use nia_data::dataset::image_io;
use nia_data::dataset::zju::frame_number;
use nia_data::fitting::{
    FitConfig, FitProgress, Fitter, FrameObservation, KeypointBinding, SilhouetteTarget,
    ViewObservation,
};
use nia_data::own_capture::{keypoint_sources, keypoints_3d, KeypointLayout, KeypointSource};
use serde::Serialize;

pub use error::PrepareError;
pub use input::{CameraSource, Capture};
pub use truth::TruthErrors;

/// `nia-train prepare` flags.
#[derive(Args, Debug, Clone)]
pub struct PrepareArgs {
    /// The capture's subject folder: `<view>/<image>`, `mask/<view>/<image>.png`,
    /// `keypoints/<view>/<image stem>_keypoints.json` and (unless --cameras says otherwise)
    /// `annots.npy`.
    #[arg(long)]
    pub input: PathBuf,
    /// The SMPL model file (`.pkl` or `.npz`; the generator's `body_model.npz` for its sets).
    #[arg(long)]
    pub smpl: PathBuf,
    /// Output folder; the subject is written to `OUT/<input folder name>/`.
    #[arg(long)]
    pub out: PathBuf,
    /// Cameras: `annots` (the subject's annots.npy), `colmap:DIR` (COLMAP text model with
    /// PINHOLE, SIMPLE_PINHOLE or OPENCV cameras, metres) or `json:FILE` (cameras.json).
    #[arg(long, default_value = "annots", value_parser = str::parse::<CameraSource>)]
    pub cameras: CameraSource,
    /// Fit only the first N frames.
    #[arg(long)]
    pub frames: Option<usize>,
    /// Frames (evenly spaced) that get an overlay picture per view in `fit_overlay/`.
    #[arg(long, default_value_t = 3)]
    pub overlay_frames: usize,
    /// A subject folder with the true `params/` and `vertices/` (the generator's): prints and
    /// records MPJPE and mean vertex error in cm.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Replace an existing output subject folder.
    #[arg(long)]
    pub overwrite: bool,
    /// Fitter settings (JSON object with any keys of the fitter's config; the rest default).
    #[arg(long)]
    pub fit_config: Option<PathBuf>,
}

/// What [`run`] reports as it goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PrepareEvent {
    /// Frame `done` of `total` read (masks, keypoints).
    Loaded { done: usize, total: usize },
    /// The fitter's progress.
    Fit(FitProgress),
    /// Frame `done` of `total` written.
    Written { done: usize, total: usize },
}

/// What a finished run did.
#[derive(Debug, Clone, Serialize)]
pub struct PrepareReport {
    pub subject_dir: PathBuf,
    pub frames: usize,
    pub views: usize,
    pub layout: String,
    /// Fitting time per frame (shape stage spread over the frames), seconds.
    pub seconds_per_frame: f32,
    /// Mean keypoint reprojection error over frames, pixels.
    pub keypoint_error_px: f32,
    pub betas: Vec<f32>,
    pub truth: Option<TruthErrors>,
    pub per_frame: Vec<FrameRecord>,
}

/// One frame of [`PrepareReport`].
#[derive(Debug, Clone, Serialize)]
pub struct FrameRecord {
    pub number: usize,
    pub keypoint_error_px: f32,
    pub seconds: f32,
}

/// The fitter's binding of each keypoint of `layout` on `model`.
pub fn bindings(layout: KeypointLayout, model: &BodyModel) -> Vec<KeypointBinding> {
    keypoint_sources(layout, model)
        .into_iter()
        .map(|s| match s {
            KeypointSource::Joint(j) => KeypointBinding::joint(j),
            KeypointSource::Vertex(v) => KeypointBinding::vertex(v),
            KeypointSource::Midpoint(a, b) => KeypointBinding::midpoint(a, b),
            KeypointSource::Unmapped => KeypointBinding::default(),
        })
        .collect()
}

fn load_fit_config(path: Option<&Path>) -> Result<FitConfig, PrepareError> {
    let Some(path) = path else {
        return Ok(FitConfig::default());
    };
    let text = std::fs::read_to_string(path)
        .map_err(|e| PrepareError::io(path, "read the fit config", e))?;
    serde_json::from_str(&text)
        .map_err(|e| PrepareError::invalid(path, format!("not a fitter config (JSON): {e}")))
}

/// Reads the capture, fits, writes `OUT/<subject>/` (module docs).
pub fn run(
    args: &PrepareArgs,
    progress: &mut dyn FnMut(PrepareEvent),
) -> Result<PrepareReport, PrepareError> {
    let config = load_fit_config(args.fit_config.as_deref())?;
    let name = args.input.file_name().ok_or_else(|| {
        PrepareError::Usage(format!(
            "--input {}: not a folder name",
            args.input.display()
        ))
    })?;
    let final_dir = args.out.join(name);
    if final_dir.exists() && !args.overwrite {
        return Err(PrepareError::Exists(final_dir));
    }
    let capture = Capture::find(&args.input, &args.cameras, args.frames)?;
    let model = BodyModel::load(&args.smpl)?;

    // Observations: every mask and keypoint file read and checked before fitting.
    let total = capture.frames.len();
    let mut layout = None;
    let mut observations = Vec::with_capacity(total);
    let mut detected: Vec<Vec<Vec<[f32; 3]>>> = Vec::with_capacity(total);
    for (f, files) in capture.frames.iter().enumerate() {
        let mut views = Vec::with_capacity(files.len());
        let mut points = Vec::with_capacity(files.len());
        for (vf, (_, camera)) in files.iter().zip(&capture.views) {
            let kp = input::read_keypoints(&vf.keypoints, &mut layout)?;
            let mask = input::read_mask_bytes(&vf.mask, camera)?;
            let on_person: Vec<bool> = mask.iter().map(|&m| m != 0).collect();
            // An empty mask (the person out of view) leaves the view to its keypoints.
            let silhouette = SilhouetteTarget::from_mask(
                &on_person,
                camera.width,
                camera.height,
                config.boundary_samples,
            )?;
            let keypoints: Vec<[f32; 3]> = kp.map(|k| k.points).unwrap_or_default();
            points.push(keypoints.clone());
            views.push(ViewObservation {
                camera: *camera,
                keypoints,
                silhouette,
            });
        }
        if points.iter().all(|p| p.iter().all(|k| k[2] <= 0.0)) {
            let dir = files[0]
                .keypoints
                .parent()
                .and_then(Path::parent)
                .unwrap_or(Path::new("keypoints"));
            return Err(PrepareError::invalid(
                dir,
                format!(
                    "frame {}: no view has a detected keypoint ({}_keypoints.json in every view)",
                    files[0].image_rel,
                    stem(&files[0].image_rel)
                ),
            ));
        }
        observations.push(FrameObservation { views });
        detected.push(points);
        progress(PrepareEvent::Loaded { done: f + 1, total });
    }
    let layout = layout.ok_or_else(|| {
        PrepareError::invalid(args.input.join("keypoints"), "no file names a person")
    })?;
    let bindings = bindings(layout, &model);

    let started = Instant::now();
    let fitter = Fitter::new(&model, bindings, config)?;
    let fit = fitter.fit_subject(&observations, &mut |p| progress(PrepareEvent::Fit(p)))?;
    let seconds_per_frame = started.elapsed().as_secs_f32() / total as f32;
    drop(observations);

    let numbers: Vec<usize> = capture
        .frames
        .iter()
        .enumerate()
        .map(|(i, files)| frame_number(&files[0].image_rel).unwrap_or(i))
        .collect();
    let fitted: Vec<(usize, SmplParams, Vec<Vec3>)> = fit
        .frames
        .iter()
        .zip(&numbers)
        .map(|(fr, &n)| (n, fr.params.clone(), model.lbs(&fr.params).vertices))
        .collect();
    let truth = args
        .truth
        .as_deref()
        .map(|t| truth::compare(t, &model, &fitted))
        .transpose()?;

    let staging = output::staging_dir(&final_dir);
    let result = write_all(
        &staging, &capture, &model, layout, &fitted, &detected, args, progress,
    )
    .and_then(|()| {
        let report = PrepareReport {
            subject_dir: final_dir.clone(),
            frames: total,
            views: capture.views.len(),
            layout: layout.name().to_string(),
            seconds_per_frame,
            keypoint_error_px: fit.frames.iter().map(|f| f.keypoint_error_px).sum::<f32>()
                / total as f32,
            betas: fit.betas.clone(),
            truth,
            per_frame: fit
                .frames
                .iter()
                .zip(&numbers)
                .map(|(f, &n)| FrameRecord {
                    number: n,
                    keypoint_error_px: f.keypoint_error_px,
                    seconds: f.seconds,
                })
                .collect(),
        };
        let json = serde_json::to_string_pretty(&report).unwrap_or_default();
        let path = staging.join("fit.json");
        std::fs::write(&path, json).map_err(|e| PrepareError::io(&path, "write", e))?;
        output::commit(&staging, &final_dir, args.overwrite)?;
        Ok(report)
    });
    if result.is_err() && staging.exists() {
        let _ = std::fs::remove_dir_all(&staging);
    }
    result
}

fn stem(rel: &str) -> String {
    Path::new(rel)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

#[allow(clippy::too_many_arguments)]
fn write_all(
    staging: &Path,
    capture: &Capture,
    model: &BodyModel,
    layout: KeypointLayout,
    fitted: &[(usize, SmplParams, Vec<Vec3>)],
    detected: &[Vec<Vec<[f32; 3]>>],
    args: &PrepareArgs,
    progress: &mut dyn FnMut(PrepareEvent),
) -> Result<(), PrepareError> {
    if staging.exists() {
        std::fs::remove_dir_all(staging)
            .map_err(|e| PrepareError::io(staging, "clear the staging folder", e))?;
    }
    for dir in ["params", "vertices"] {
        output::create_dir(&staging.join(dir))?;
    }
    let cameras: Vec<_> = capture.views.iter().map(|(_, c)| *c).collect();
    let ims: Vec<Vec<String>> = capture
        .frames
        .iter()
        .map(|files| files.iter().map(|f| f.image_rel.clone()).collect())
        .collect();
    output::write_annots(staging, &cameras, &ims)?;
    let total = fitted.len();
    let overlay_count = args.overlay_frames.min(total);
    let overlay_at: Vec<usize> = (0..overlay_count)
        .map(|i| i * total / overlay_count.max(1))
        .collect();
    let sources = keypoint_sources(layout, model);
    for (f, ((number, params, vertices), files)) in fitted.iter().zip(&capture.frames).enumerate() {
        output::write_body(staging, *number, params, vertices)?;
        for vf in files {
            output::link_or_copy(
                &capture.root.join(&vf.image_rel),
                &staging.join(&vf.image_rel),
            )?;
            let rel = vf.mask.strip_prefix(&capture.root).unwrap_or(&vf.mask);
            output::link_or_copy(&vf.mask, &staging.join(rel))?;
        }
        if overlay_at.contains(&f) {
            let posed = model.lbs(params);
            let fitted_kp = keypoints_3d(&sources, &posed.vertices, &posed.joints);
            for (v, ((view, camera), vf)) in capture.views.iter().zip(files).enumerate() {
                let photo = image_io::read_rgb8(&capture.root.join(&vf.image_rel))?;
                let mask = input::read_mask_bytes(&vf.mask, camera)?;
                let path = staging
                    .join("fit_overlay")
                    .join(view)
                    .join(format!("{}.png", stem(&vf.image_rel)));
                overlay::write_overlay(
                    &path,
                    photo,
                    &mask,
                    camera,
                    vertices,
                    &model.faces,
                    &detected[f][v],
                    &fitted_kp,
                )?;
            }
        }
        progress(PrepareEvent::Written { done: f + 1, total });
    }
    Ok(())
}
