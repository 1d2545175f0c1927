//! The run configuration (`configs/*.toml`): data, model, optimiser, training and an optional
//! synthetic dataset. Every section rejects unknown keys; errors name the file and the key.

use std::path::{Path, PathBuf};

use nia_data::dataset::smpl_jitter::MAX_SMPL_JITTER_M;
use nia_data::dataset::DataConfig;
use nia_data::fitting::FitError;
use nia_data::synth::SynthSection;
use nia_model::render_options::RenderOptions;
use nia_model::store::checkpoint;
use nia_model::ModelConfig;
use serde::{Deserialize, Serialize};

mod data_checks;
mod model_section;
mod sections;

use model_section::model_from_preset;
pub use model_section::ModelPreset;
pub use sections::{OptimConfig, TrainSection};

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
    /// A `--set section.key=value` override that cannot be applied.
    #[error("{}: --set `{setting}`: {message}", path.display())]
    Override {
        path: PathBuf,
        setting: String,
        message: String,
    },
    #[error("{}: `{key}`: expected {expected}, got {got}", path.display())]
    Invalid {
        path: PathBuf,
        key: String,
        expected: String,
        got: String,
    },
}

/// Writes one `section.key=value` over `table` (see [`TrainConfig::load_with`]).
fn apply_override(table: &mut toml::Table, setting: &str) -> Result<(), String> {
    let Some((key, value)) = setting.split_once('=') else {
        return Err("expected `section.key=value`".into());
    };
    let parts: Vec<&str> = key.trim().split('.').map(str::trim).collect();
    if parts.len() < 2 || parts.iter().any(|p| p.is_empty()) {
        return Err(format!(
            "`{}` is not `section.key` (e.g. `train.steps`)",
            key.trim()
        ));
    }
    let value = value.trim();
    let value = match toml::from_str::<toml::Table>(&format!("v = {value}")) {
        Ok(mut t) => t.remove("v").unwrap_or(toml::Value::String(value.into())),
        Err(_) => toml::Value::String(value.into()),
    };
    let (last, sections) = parts.split_last().expect("two parts or more");
    let mut current = table;
    for (i, part) in sections.iter().enumerate() {
        let entry = current
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        current = match entry {
            toml::Value::Table(t) => t,
            _ => {
                return Err(format!(
                    "`{}` is a value, not a section",
                    parts[..=i].join(".")
                ))
            }
        };
    }
    current.insert(last.to_string(), value);
    Ok(())
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
    #[serde(default = "ModelConfig::new", deserialize_with = "model_from_preset")]
    pub model: ModelConfig,
    #[serde(default)]
    pub optim: OptimConfig,
    pub train: TrainSection,
    #[serde(default)]
    pub synth: Option<SynthSection>,
    /// `[render]`: adaptive work of evaluation and inference (empty-space skipping).
    #[serde(default)]
    pub render: RenderOptions,
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
        Self::load_with(path, &[])
    }

    /// [`TrainConfig::load`] with `section.key=value` overrides (`--set`, in order) written over
    /// the file's keys first; nested keys take more dots (`model.body_volume.full_convs=2`).
    /// The value is TOML (`0.3`, `true`, `"band"`, `{ kind = "band" }`); a bare word that is not
    /// TOML (`flex`) is taken as a string. The result is checked like a file: an unknown key or
    /// a value of the wrong type is an error naming the key.
    pub fn load_with(path: &Path, overrides: &[String]) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        if overrides.is_empty() {
            return Self::from_toml(&text, path);
        }
        let mut table: toml::Table = toml::from_str(&text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string().trim_end().to_string(),
        })?;
        for setting in overrides {
            apply_override(&mut table, setting).map_err(|message| ConfigError::Override {
                path: path.to_path_buf(),
                setting: setting.clone(),
                message,
            })?;
        }
        let text = toml::to_string(&table).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: format!("after the --set overrides: {e}"),
        })?;
        Self::from_toml(&text, path).map_err(|e| match e {
            ConfigError::Parse { path, message } => ConfigError::Parse {
                path,
                message: format!(
                    "{message}\n(--set overrides applied: lines and columns are of the merged config)"
                ),
            },
            other => other,
        })
    }

    /// Range checks, and the data root must exist unless `[synth]` generates it. The checks
    /// run in this order and the first failure is the error.
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        self.check_train(path)?;
        self.check_synth(path)?;
        if let Err(message) = self.model.check() {
            return Err(invalid(path, "model", "a buildable network", message));
        }
        self.check_data_ranges(path)?;
        if let Err(e) = self.render.check() {
            return Err(invalid(
                path,
                &format!("render.{}", e.key),
                &e.expected,
                e.got,
            ));
        }
        self.check_optim(path)?;
        if let Some(r) = self.data.ratio {
            if !(r > 0.0 && r <= 1.0) {
                return Err(invalid(
                    path,
                    "data.ratio",
                    "a number in (0, 1]",
                    r.to_string(),
                ));
            }
        }
        if self.data.loader_threads == 0 {
            return Err(invalid(path, "data.loader_threads", ">= 1", "0".into()));
        }
        self.check_data(path)?;
        self.check_files(path)
    }

    /// The `[train]` section's ranges.
    fn check_train(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, expected: &str, got: String| invalid(path, key, expected, got);
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
        if !(0.0..=1.0).contains(&t.c0_shuffle) {
            return Err(bad(
                "train.c0_shuffle",
                "a fraction in [0, 1]",
                t.c0_shuffle.to_string(),
            ));
        }
        if !(t.c0_noise_std.is_finite() && t.c0_noise_std >= 0.0) {
            return Err(bad(
                "train.c0_noise_std",
                "a finite value >= 0",
                t.c0_noise_std.to_string(),
            ));
        }
        if !(t.mask_loss_weight.is_finite() && t.mask_loss_weight >= 0.0) {
            return Err(bad(
                "train.mask_loss_weight",
                "a finite value >= 0",
                t.mask_loss_weight.to_string(),
            ));
        }
        if !(t.ssim_loss_weight.is_finite() && t.ssim_loss_weight >= 0.0) {
            return Err(bad(
                "train.ssim_loss_weight",
                "a finite value >= 0",
                t.ssim_loss_weight.to_string(),
            ));
        }
        if t.ssim_loss_weight > 0.0 && t.ssim_patch_px < 2 {
            return Err(bad(
                "train.ssim_patch_px",
                "a patch side >= 2 (the SSIM loss reads patches)",
                t.ssim_patch_px.to_string(),
            ));
        }
        if t.ssim_patch_px > 0 {
            let area = t.ssim_patch_px * t.ssim_patch_px;
            for (key, value) in [
                ("train.rays_per_step", t.rays_per_step),
                ("train.ray_chunk", t.ray_chunk),
            ] {
                if value % area != 0 {
                    return Err(bad(
                        key,
                        &format!("a multiple of ssim_patch_px^2 = {area}"),
                        value.to_string(),
                    ));
                }
            }
        }
        if !(t.distortion_loss_weight.is_finite() && t.distortion_loss_weight >= 0.0) {
            return Err(bad(
                "train.distortion_loss_weight",
                "a finite value >= 0",
                t.distortion_loss_weight.to_string(),
            ));
        }
        if !(t.colour_gain_tolerance.is_finite() && (0.0..=1.0).contains(&t.colour_gain_tolerance))
        {
            return Err(bad(
                "train.colour_gain_tolerance",
                "a relative gain in [0, 1]",
                t.colour_gain_tolerance.to_string(),
            ));
        }
        if t.checkpoint_every == 0 {
            return Err(bad("train.checkpoint_every", ">= 1", "0".into()));
        }
        if t.keep_last == 0 {
            return Err(bad("train.keep_last", ">= 1", "0".into()));
        }
        Ok(())
    }

    /// The `[synth]` section, as the generator checks it.
    fn check_synth(&self, path: &Path) -> Result<(), ConfigError> {
        if let Some(synth) = &self.synth {
            if let Err(nia_data::synth::SynthError::Spec {
                field,
                expected,
                got,
            }) = synth.spec().validate()
            {
                return Err(ConfigError::Invalid {
                    path: path.to_path_buf(),
                    key: SynthSection::key(field).to_string(),
                    expected: expected.to_string(),
                    got,
                });
            }
        }
        Ok(())
    }

    /// The `[data]` section's ranges: the body fraction, the SMPL jitter and alignment.
    fn check_data_ranges(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, expected: &str, got: String| invalid(path, key, expected, got);
        let d = &self.data;
        if !(d.body_fraction.is_finite() && (0.0..=1.0).contains(&d.body_fraction)) {
            return Err(bad(
                "data.body_fraction",
                "a fraction in [0, 1]",
                d.body_fraction.to_string(),
            ));
        }
        if !(d.smpl_jitter_m.is_finite() && (0.0..=MAX_SMPL_JITTER_M).contains(&d.smpl_jitter_m)) {
            return Err(bad(
                "data.smpl_jitter_m",
                &format!("a distance in [0, {MAX_SMPL_JITTER_M}] metres"),
                d.smpl_jitter_m.to_string(),
            ));
        }
        if let Some(Err(FitError::Invalid {
            field,
            expected,
            got,
        })) = d.smpl_alignment.map(|a| a.validate())
        {
            return Err(bad(&format!("data.smpl_alignment.{field}"), &expected, got));
        }
        Ok(())
    }

    /// The `[optim]` section's ranges.
    fn check_optim(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, expected: &str, got: String| invalid(path, key, expected, got);
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
        Ok(())
    }

    /// The files and devices the run will open: `train.init_from`, `data.smpl_model`,
    /// `train.devices`, `train.lpips` and `train.encoder_weights`.
    fn check_files(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, expected: &str, got: String| invalid(path, key, expected, got);
        let t = &self.train;
        if let Some(dir) = &t.init_from {
            if !dir.join(checkpoint::MODEL_FILE).is_file() {
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
        }
        for spec in &t.devices {
            if spec.index.is_some() && !spec.backend.is_gpu() {
                return Err(bad(
                    "train.devices",
                    "CPU backends without an index (flex, ndarray) or GPUs as wgpu:N",
                    spec.to_string(),
                ));
            }
        }
        if let Some(l) = &t.lpips {
            if let Some(missing) = l.missing().first() {
                return Err(bad(
                    "train.lpips",
                    "existing backbone and heads files",
                    missing.display().to_string(),
                ));
            }
        }
        if let Some(w) = &t.encoder_weights {
            if !w.is_file() {
                return Err(bad(
                    "train.encoder_weights",
                    "an existing torchvision resnet18 state dict (.pth)",
                    w.display().to_string(),
                ));
            }
        }
        Ok(())
    }
}

/// A [`ConfigError::Invalid`] of the file `path`: `key` holds `got`, not `expected`.
fn invalid(path: &Path, key: &str, expected: &str, got: String) -> ConfigError {
    ConfigError::Invalid {
        path: path.to_path_buf(),
        key: key.to_string(),
        expected: expected.to_string(),
        got,
    }
}
