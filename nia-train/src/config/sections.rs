//! The run config's `[optim]` and `[train]` sections.

use std::path::PathBuf;

use nia_eval::perceptual::LpipsFiles;
use nia_model::device::{Backend, DeviceSpec};
use serde::{Deserialize, Serialize};

/// `[optim]`: Adam with an exponentially decaying learning rate (NHP:
/// `lr * 0.1^(step / decay_steps)`) and gradient clipping by global norm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimConfig {
    #[serde(default = "default_lr")]
    pub lr: f64,
    #[serde(default = "default_beta1")]
    pub beta1: f32,
    #[serde(default = "default_beta2")]
    pub beta2: f32,
    #[serde(default = "default_eps")]
    pub adam_eps: f32,
    /// Steps over which the learning rate falls tenfold.
    #[serde(default = "default_decay")]
    pub decay_steps: u64,
    /// Largest global L2 norm of the gradient (0: no clipping).
    #[serde(default = "default_clip")]
    pub grad_clip_norm: f32,
}

fn default_lr() -> f64 {
    5e-4
}
fn default_beta1() -> f32 {
    0.9
}
fn default_beta2() -> f32 {
    0.999
}
fn default_eps() -> f32 {
    1e-8
}
fn default_decay() -> u64 {
    500_000
}
fn default_clip() -> f32 {
    1.0
}

impl Default for OptimConfig {
    fn default() -> Self {
        OptimConfig {
            lr: default_lr(),
            beta1: default_beta1(),
            beta2: default_beta2(),
            adam_eps: default_eps(),
            decay_steps: default_decay(),
            grad_clip_norm: default_clip(),
        }
    }
}

impl OptimConfig {
    /// The learning rate at `step` (0-based): `lr * 0.1^(step / decay_steps)`.
    pub fn lr_at(&self, step: u64) -> f64 {
        self.lr * 0.1f64.powf(step as f64 / self.decay_steps.max(1) as f64)
    }
}

/// `[train]`: the loop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainSection {
    pub steps: u64,
    #[serde(default = "default_rays")]
    pub rays_per_step: usize,
    #[serde(default = "default_samples")]
    pub samples: usize,
    /// Rays per chunk of the step's forward and backward (0: all rays at once). The per-scene
    /// encoding is computed once and each chunk's graph is freed by its own backward, so the
    /// step's memory holds one chunk's activations: the same gradient to float rounding,
    /// except that `colour_gain_tolerance` fits its gain per chunk and `c0_shuffle` draws the
    /// borrowed c0 from the same chunk (see `nia_model::scene_encoding::cut`).
    #[serde(default)]
    pub ray_chunk: usize,
    /// Burn's gradient checkpointing on the training devices: the backward recomputes the
    /// memory-bound operations (element-wise, reshapes) instead of keeping their outputs, and
    /// keeps the matrix products' and convolutions'. Less memory for more time, the same
    /// gradient (docs/speed.md, "Memory"). Off by default.
    #[serde(default)]
    pub gradient_checkpointing: bool,
    #[serde(default = "default_sources")]
    pub source_views: usize,
    #[serde(default)]
    pub seed: u64,
    /// Checkpoint every this many steps (and at the end).
    #[serde(default = "default_ckpt")]
    pub checkpoint_every: u64,
    /// Checkpoints kept.
    #[serde(default = "default_keep")]
    pub keep_last: usize,
    /// Validation every this many steps (0: never).
    #[serde(default)]
    pub validate_every: u64,
    /// Held-out images rendered per validation.
    #[serde(default = "default_validation_images")]
    pub validation_images: usize,
    /// Evaluate every unseen-subject image of the protocol at the end (PSNR/SSIM).
    #[serde(default)]
    pub evaluate_at_end: bool,
    #[serde(default = "default_backend")]
    pub backend: Backend,
    /// Data parallelism: the devices of a step (`["wgpu:0", "wgpu:1"]`, `["flex", "ndarray"]`),
    /// each taking one scene; gradients are summed and one optimiser step is taken on the
    /// first, which holds the model. Empty: one device, `backend`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub devices: Vec<DeviceSpec>,
    /// Start from the weights of this checkpoint folder (e.g. a ZJU-MoCap model evaluated on
    /// MonoCap with `steps = 0`); `--resume` from the run's own checkpoints takes precedence.
    #[serde(default)]
    pub init_from: Option<PathBuf>,
    /// torchvision `resnet18` weights (`resnet18-f37072fd.pth`, ImageNet) loaded into the
    /// image encoder before the first step, as NHP and NIA start (conv1..layer3; needs
    /// `model.encoder_width = 64`, the paper preset). Ignored when resuming or with
    /// `init_from`, whose weights already hold a trained encoder. None: the encoder starts from
    /// random weights.
    #[serde(default)]
    pub encoder_weights: Option<PathBuf>,
    /// LPIPS in validation and the final evaluation (and the default of `nia-infer eval` for
    /// the exported model): `{ net = "alex", backbone = "alexnet-owt-7be5be79.pth", heads =
    /// "lpips/weights/v0.1/alex.pth" }`, the user's files. None: PSNR and SSIM only.
    #[serde(default)]
    pub lpips: Option<LpipsFiles>,
    /// Weight of the mask loss `mean (acc - mask)^2` added to the paper's loss (0: the paper's
    /// loss only; see `nia_model::loss::mask_loss`).
    #[serde(default)]
    pub mask_loss_weight: f32,
    /// Weight of the distortion loss (mip-NeRF 360) that pulls each ray's compositing weights
    /// into one compact interval (0: the paper's loss only; see
    /// `nia_model::loss::distortion_loss`).
    #[serde(default)]
    pub distortion_loss_weight: f32,
    /// Training rays drawn in square patches of this side (0: one pixel at a time, the
    /// paper's); `rays_per_step` and `ray_chunk` must be multiples of its square. See
    /// `nia_data::dataset::sampling::RaySamplingConfig::patch_px`.
    #[serde(default)]
    pub ssim_patch_px: usize,
    /// Weight of the patch-wise structural loss `1 - mean SSIM` of the blended colour over the
    /// patches (0: the paper's loss only; needs `ssim_patch_px`; see
    /// `nia_model::loss::patch_ssim_loss`).
    #[serde(default)]
    pub ssim_loss_weight: f32,
    /// Fraction of training points whose c0 in the blend is another point's (0: off, the
    /// paper's training; see `nia_model::ibr::c0_shuffle`).
    #[serde(default)]
    pub c0_shuffle: f32,
    /// Shuffle c0 only at points some source view sees; unseen points keep their own c0
    /// (false: every point may be shuffled; see `nia_model::ibr::c0_shuffle`).
    #[serde(default)]
    pub c0_shuffle_seen_only: bool,
    /// Standard deviation of the Gaussian noise on the c0 that F_B blends at the points
    /// `c0_shuffle_seen_only` lets through, per channel (0: off, the paper's training; see
    /// `nia_model::ibr::c0_shuffle`).
    #[serde(default)]
    pub c0_noise_std: f32,
    /// Per-channel gain of the target, relative, that the loss ignores (0: off, the paper's
    /// loss; see `nia_model::loss::colour_matched_target`).
    #[serde(default)]
    pub colour_gain_tolerance: f32,
}

impl TrainSection {
    /// The devices of a step: `devices`, else `backend`'s default device.
    pub fn device_specs(&self) -> Vec<DeviceSpec> {
        if self.devices.is_empty() {
            vec![DeviceSpec::of(self.backend)]
        } else {
            self.devices.clone()
        }
    }
}

fn default_rays() -> usize {
    nia_data::dataset::sampling::NHP_RAYS_PER_IMAGE
}
fn default_samples() -> usize {
    64
}
fn default_sources() -> usize {
    3
}
fn default_ckpt() -> u64 {
    1000
}
fn default_keep() -> usize {
    3
}
fn default_validation_images() -> usize {
    2
}
fn default_backend() -> Backend {
    Backend::Flex
}
