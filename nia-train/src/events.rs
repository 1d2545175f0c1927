//! What a training run reports: the library sends these through a callback; the binary draws
//! the progress bar and appends each one as a JSON line to `OUT/metrics.jsonl`.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// One training event. Losses are the means of the step's rays (colours in [0, 1]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum TrainEvent {
    /// The dataset is open (generated first when a `[synth]` section asked for it).
    DataReady {
        root: PathBuf,
        train_subjects: Vec<String>,
        unseen_subjects: Vec<String>,
        generated: bool,
    },
    /// Training starts at `first_step` (0, or the step after a resumed checkpoint).
    Started { first_step: u64, steps: u64 },
    /// A step was taken.
    Step(StepReport),
    /// A step whose loss or gradients were not finite: no parameter was changed.
    Skipped { step: u64, reason: String },
    /// A checkpoint was written (atomically) after `step` steps.
    Checkpoint { step: u64, path: PathBuf },
    /// Periodic held-out check on the first few unseen-subject images: mean PSNR (dB, over
    /// `mask_at_box`) and SSIM (NHP's setting).
    Validation {
        step: u64,
        images: usize,
        psnr: f64,
        ssim: f64,
        /// Mean LPIPS with `train.lpips`'s network.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        lpips: Option<f64>,
    },
    /// The final evaluation of a split (every image of the opened subjects), as NHP reports it.
    Evaluation {
        step: u64,
        split: String,
        images: usize,
        psnr: f64,
        ssim: f64,
        /// Mean LPIPS with `train.lpips`'s network.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        lpips: Option<f64>,
        /// Mean blend weight of the NeRF colour c0 on person pixels some source view sees.
        c0_share_seen: Option<f64>,
        /// PSNR of the IBR-only and NeRF-only composites (`nia_eval::diagnostics`).
        psnr_ibr: f64,
        psnr_nerf: f64,
        /// The PSNR split into the pixels next to the person's outline and the rest.
        #[serde(default)]
        psnr_silhouette: Option<f64>,
        #[serde(default)]
        psnr_interior: Option<f64>,
        /// Folder with grids and blend maps of a few of the evaluated images.
        pictures: PathBuf,
    },
    /// The run ended after `steps` steps.
    Finished { steps: u64, seconds: f64 },
    /// The comparison grid (sources | prediction | ground truth | error) of validation image
    /// `index` after `step` steps, `width` x `height` RGB bytes row by row (for TensorBoard;
    /// not a record either).
    ValidationImage {
        step: u64,
        index: usize,
        width: u32,
        height: u32,
        rgb: Vec<u8>,
    },
    /// Progress inside a long phase that is not a step: `done` of `total` units (images) of
    /// `phase`. For progress bars and plain progress lines; not a record (the binary leaves it
    /// out of `metrics.jsonl`).
    Progress {
        phase: Phase,
        done: usize,
        total: usize,
    },
}

/// What a taken step reports ([`TrainEvent::Step`]; in the metrics log its fields stand beside
/// `"event": "step"`). `loss = mse + mse0`; `psnr` of the blended colour (dB).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepReport {
    pub step: u64,
    pub loss: f64,
    pub mse: f64,
    pub mse0: f64,
    pub psnr: f64,
    pub rays_per_s: f64,
    pub lr: f64,
    /// Tensor reads the step made, Adam's update included (on a GPU each is a wait for the
    /// device; `nia_model::kernels::readback::readbacks`): one on one device, the losses with
    /// the gradient norm. 0 in logs written before it was counted.
    #[serde(default)]
    pub readbacks: u64,
}

/// A long phase of a run besides the training steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Writing the `[synth]` dataset's images.
    Generation,
    /// Rendering the periodic validation images.
    Validation,
    /// Rendering every held-out image at the end.
    Evaluation,
}

impl Phase {
    /// The phase's name in progress lines.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Generation => "generating the synthetic dataset",
            Phase::Validation => "validation",
            Phase::Evaluation => "final evaluation",
        }
    }
}
