//! The run configuration (`configs/*.toml`): data, model, optimiser, training and an optional
//! synthetic dataset. Every section rejects unknown keys; errors name the file and the key.

use std::path::{Path, PathBuf};

use nia_data::dataset::DatasetFormat;
use nia_data::synth::SynthSpec;
use nia_model::adaptive::AdaptiveConfig;
use nia_model::device::Backend;
use nia_model::{ModelConfig, Variant};
use serde::{Deserialize, Serialize};

/// A configuration error, naming the file and the key.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// toml's message names the key path (`unknown field `x``, `invalid type ... for key `a.b``).
    #[error("{}: {message}", path.display())]
    Parse { path: PathBuf, message: String },
    #[error("{}: `{key}`: expected {expected}, got {got}", path.display())]
    Invalid {
        path: PathBuf,
        key: &'static str,
        expected: &'static str,
        got: String,
    },
}

/// Which split protocol the data follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProtocolName {
    /// The split written by `synth` (needs the `[synth]` section).
    Synthetic,
    /// NHP's ZJU-MoCap protocol.
    Nhp,
    /// MonoCap evaluation.
    Monocap,
}

/// `[data]`: where the subjects are and how to read them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    /// Folder holding the `CoreView_*` subjects (relative paths: to the working directory).
    pub root: PathBuf,
    #[serde(default = "default_format")]
    pub format: DatasetFormat,
    /// Image resize ratio in (0, 1]; default: the format's (ZJU 0.5).
    #[serde(default)]
    pub ratio: Option<f32>,
    /// SMPL model (`.pkl`/`.npz`); default for synthetic data: `ROOT/body_model.npz`.
    #[serde(default)]
    pub smpl_model: Option<PathBuf>,
    #[serde(default = "default_protocol")]
    pub protocol: ProtocolName,
    /// Visibility cache folder (default `ROOT/.visibility_cache`).
    #[serde(default)]
    pub visibility_cache: Option<PathBuf>,
    /// Mask border band excluded from ray sampling, pixels (NHP 5 at 512 px).
    #[serde(default = "default_border_px")]
    pub border_px: usize,
    /// Share of rays drawn on the body (NHP 0.5).
    #[serde(default = "default_body_fraction")]
    pub body_fraction: f32,
    /// Loader worker threads.
    #[serde(default = "default_threads")]
    pub loader_threads: usize,
}

fn default_format() -> DatasetFormat {
    DatasetFormat::Zju
}
fn default_protocol() -> ProtocolName {
    ProtocolName::Synthetic
}
fn default_border_px() -> usize {
    nia_data::sampling::NHP_BORDER_PX
}
fn default_body_fraction() -> f32 {
    nia_data::sampling::NHP_BODY_FRACTION
}
fn default_threads() -> usize {
    2
}

/// Network preset the `[model]` overrides start from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelPreset {
    /// The paper's sizes ([`ModelConfig::new`]).
    Paper,
    /// Narrow layers for CPU runs and tests ([`ModelConfig::tiny`]).
    Tiny,
}

/// `[model]`: a preset and optional overrides of its scalar fields.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSection {
    #[serde(default = "default_preset")]
    pub preset: ModelPreset,
    #[serde(default)]
    pub variant: Option<Variant>,
    #[serde(default)]
    pub encoder_width: Option<usize>,
    #[serde(default)]
    pub d_model: Option<usize>,
    #[serde(default)]
    pub d_hidden: Option<usize>,
    #[serde(default)]
    pub d_blend: Option<usize>,
    #[serde(default)]
    pub dir_frequencies: Option<usize>,
    /// Voxel edge, metres.
    #[serde(default)]
    pub voxel_size_m: Option<f32>,
    #[serde(default)]
    pub box_enlarge: Option<f32>,
    #[serde(default)]
    pub cosine_temperature: Option<f32>,
}

fn default_preset() -> ModelPreset {
    ModelPreset::Paper
}

impl Default for ModelSection {
    fn default() -> Self {
        ModelSection {
            preset: ModelPreset::Paper,
            variant: None,
            encoder_width: None,
            d_model: None,
            d_hidden: None,
            d_blend: None,
            dir_frequencies: None,
            voxel_size_m: None,
            box_enlarge: None,
            cosine_temperature: None,
        }
    }
}

impl ModelSection {
    /// The network configuration: the preset with the overrides applied.
    pub fn build(&self) -> ModelConfig {
        let mut c = match self.preset {
            ModelPreset::Paper => ModelConfig::new(),
            ModelPreset::Tiny => ModelConfig::tiny(),
        };
        if let Some(v) = self.variant {
            c.variant = v;
        }
        if let Some(v) = self.encoder_width {
            c.encoder_width = v;
        }
        if let Some(v) = self.d_model {
            c.d_model = v;
        }
        if let Some(v) = self.d_hidden {
            c.d_hidden = v;
        }
        if let Some(v) = self.d_blend {
            c.d_blend = v;
        }
        if let Some(v) = self.dir_frequencies {
            c.dir_frequencies = v;
        }
        if let Some(v) = self.voxel_size_m {
            c.voxel_size_m = v;
        }
        if let Some(v) = self.box_enlarge {
            c.box_enlarge = v;
        }
        if let Some(v) = self.cosine_temperature {
            c.cosine_temperature = v;
        }
        c
    }
}

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
    /// Start from the weights of this checkpoint folder (e.g. a ZJU-MoCap model evaluated on
    /// MonoCap with `steps = 0`); `--resume` from the run's own checkpoints takes precedence.
    #[serde(default)]
    pub init_from: Option<PathBuf>,
}

fn default_rays() -> usize {
    nia_data::sampling::NHP_RAYS_PER_IMAGE
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

/// `[synth]`: generate this synthetic dataset into `data.root` when it is missing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SynthSection {
    pub subjects: usize,
    pub frames: usize,
    pub cameras: usize,
    pub size: u32,
    #[serde(default)]
    pub seed: u64,
    #[serde(default = "default_supersample")]
    pub supersample: u32,
    #[serde(default = "default_test_fraction")]
    pub test_fraction: f32,
}

fn default_supersample() -> u32 {
    2
}
fn default_test_fraction() -> f32 {
    SynthSpec::default().test_fraction
}

impl SynthSection {
    pub fn spec(&self) -> SynthSpec {
        SynthSpec {
            subjects: self.subjects,
            frames: self.frames,
            cameras: self.cameras,
            size: self.size,
            seed: self.seed,
            supersample: self.supersample,
            test_fraction: self.test_fraction,
            ..SynthSpec::default()
        }
    }
}

/// The `[synth]` key of a [`SynthSpec`] field name.
fn synth_key(field: &'static str) -> &'static str {
    match field {
        "subjects" => "synth.subjects",
        "frames" => "synth.frames",
        "cameras" => "synth.cameras",
        "size" => "synth.size",
        "seed" => "synth.seed",
        "supersample" => "synth.supersample",
        "test_fraction" => "synth.test_fraction",
        _ => "synth",
    }
}

/// The dotted key (`section.key`) whose line holds byte `offset` of `text`, from the nearest
/// `[section]` header above it and the text before `=` on that line.
fn key_at(text: &str, offset: usize) -> Option<String> {
    let offset = offset.min(text.len());
    let line_start = text[..offset].rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[offset..].find('\n').map_or(text.len(), |i| offset + i);
    let key = text[line_start..line_end].split('=').next()?.trim();
    if key.is_empty() || key.starts_with('[') {
        return None;
    }
    let section = text[..line_start].lines().rev().find_map(|l| {
        let l = l.trim();
        l.strip_prefix('[')
            .and_then(|r| r.strip_suffix(']'))
            .map(|s| s.trim().to_string())
    });
    Some(match section {
        Some(section) => format!("{section}.{key}"),
        None => key.to_string(),
    })
}

/// A whole run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    pub data: DataConfig,
    #[serde(default)]
    pub model: ModelSection,
    #[serde(default)]
    pub optim: OptimConfig,
    pub train: TrainSection,
    #[serde(default)]
    pub synth: Option<SynthSection>,
    /// `[render]`: adaptive work of evaluation and inference (empty-space skipping).
    #[serde(default)]
    pub render: AdaptiveConfig,
}

impl TrainConfig {
    /// Parses TOML text; `path` only names the source in errors.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let config: TrainConfig = toml::from_str(text).map_err(|e| {
            let mut message = e.to_string().trim_end().to_string();
            if let Some(key) = e.span().and_then(|span| key_at(text, span.start)) {
                message = format!("key `{key}`: {message}");
            }
            ConfigError::Parse {
                path: path.to_path_buf(),
                message,
            }
        })?;
        config.validate(path)?;
        Ok(config)
    }

    /// Reads and checks a config file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml(&text, path)
    }

    /// Range checks, and the data root must exist unless `[synth]` generates it.
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &'static str, expected: &'static str, got: String| ConfigError::Invalid {
            path: path.to_path_buf(),
            key,
            expected,
            got,
        };
        let t = &self.train;
        if t.rays_per_step == 0 {
            return Err(bad("train.rays_per_step", ">= 1", "0".into()));
        }
        if t.samples < 2 {
            return Err(bad("train.samples", ">= 2", t.samples.to_string()));
        }
        if t.source_views == 0 {
            return Err(bad("train.source_views", ">= 1", "0".into()));
        }
        if t.checkpoint_every == 0 {
            return Err(bad("train.checkpoint_every", ">= 1", "0".into()));
        }
        if t.keep_last == 0 {
            return Err(bad("train.keep_last", ">= 1", "0".into()));
        }
        if let Some(synth) = &self.synth {
            if let Err(nia_data::synth::SynthError::Spec {
                field,
                expected,
                got,
            }) = synth.spec().validate()
            {
                return Err(ConfigError::Invalid {
                    path: path.to_path_buf(),
                    key: synth_key(field),
                    expected,
                    got,
                });
            }
        }
        if let Err(message) = self.model.build().check() {
            return Err(bad("model", "a buildable network", message));
        }
        let d = &self.data;
        if !(d.body_fraction.is_finite() && (0.0..=1.0).contains(&d.body_fraction)) {
            return Err(bad(
                "data.body_fraction",
                "a fraction in [0, 1]",
                d.body_fraction.to_string(),
            ));
        }
        let r = &self.render;
        if !(r.empty_space_m.is_finite() && r.empty_space_m >= 0.0) {
            return Err(bad(
                "render.empty_space_m",
                "a distance >= 0 (metres)",
                r.empty_space_m.to_string(),
            ));
        }
        if !(r.occupancy_cell_m.is_finite() && r.occupancy_cell_m >= 0.005) {
            return Err(bad(
                "render.occupancy_cell_m",
                "a cell edge >= 0.005 (metres)",
                r.occupancy_cell_m.to_string(),
            ));
        }
        let o = &self.optim;
        for (key, beta) in [("optim.beta1", o.beta1), ("optim.beta2", o.beta2)] {
            if !(beta.is_finite() && (0.0..1.0).contains(&beta)) {
                return Err(bad(key, "a number in [0, 1)", beta.to_string()));
            }
        }
        if !(o.adam_eps.is_finite() && o.adam_eps > 0.0) {
            return Err(bad(
                "optim.adam_eps",
                "a positive number",
                o.adam_eps.to_string(),
            ));
        }
        if !(o.lr.is_finite() && o.lr > 0.0) {
            return Err(bad("optim.lr", "a positive number", o.lr.to_string()));
        }
        if !(o.grad_clip_norm.is_finite() && o.grad_clip_norm >= 0.0) {
            return Err(bad(
                "optim.grad_clip_norm",
                ">= 0 (0: no clipping)",
                o.grad_clip_norm.to_string(),
            ));
        }
        if let Some(r) = self.data.ratio {
            if !(r > 0.0 && r <= 1.0) {
                return Err(bad("data.ratio", "a number in (0, 1]", r.to_string()));
            }
        }
        if self.data.loader_threads == 0 {
            return Err(bad("data.loader_threads", ">= 1", "0".into()));
        }
        if self.synth.is_none() {
            if !self.data.root.is_dir() {
                return Err(bad(
                    "data.root",
                    "an existing folder (or a [synth] section to generate it)",
                    self.data.root.display().to_string(),
                ));
            }
            if self.data.protocol == ProtocolName::Synthetic {
                return Err(bad(
                    "data.protocol",
                    "nhp or monocap when there is no [synth] section",
                    "synthetic".into(),
                ));
            }
        }
        if let Some(dir) = &t.init_from {
            if !dir.join(crate::checkpoint::MODEL_FILE).is_file() {
                return Err(bad(
                    "train.init_from",
                    "a checkpoint folder holding model.bpk",
                    dir.display().to_string(),
                ));
            }
        }
        if let Some(m) = &self.data.smpl_model {
            if !m.is_file() {
                return Err(bad(
                    "data.smpl_model",
                    "an existing SMPL model file",
                    m.display().to_string(),
                ));
            }
        } else if self.synth.is_none() {
            return Err(bad(
                "data.smpl_model",
                "the path of SMPL_NEUTRAL.pkl (needed for visibility)",
                "nothing".into(),
            ));
        }
        Ok(())
    }
}
