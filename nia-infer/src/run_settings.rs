//! The settings inference takes from the run a model was trained with: the model file's header
//! carries the whole run config (the trainer's schema); inference reads only the sections it
//! needs, so it does not depend on the trainer.

use crate::perceptual::LpipsFiles;
use nia_data::dataset::DataConfig;
use nia_data::synth::SynthSection;
use nia_model::device::Backend;
use nia_model::sampler::AdaptiveConfig;
use serde::Deserialize;

/// The `[data]`, `[synth]`, `[render]` and sampling settings of a run config (other keys are
/// ignored).
#[derive(Debug, Clone, Deserialize)]
pub struct RunSettings {
    /// Where the data of the run was and how it was read.
    pub data: DataConfig,
    /// The synthetic dataset the run generated, if any (its split protocol).
    #[serde(default)]
    pub synth: Option<SynthSection>,
    /// Adaptive work defaults (empty-space skipping).
    #[serde(default)]
    pub render: AdaptiveConfig,
    /// The `[train]` settings inference reuses.
    pub train: TrainSettings,
}

/// The part of `[train]` inference reuses.
#[derive(Debug, Clone, Deserialize)]
pub struct TrainSettings {
    /// Samples per ray.
    pub samples: usize,
    /// Source views per scene.
    pub source_views: usize,
    /// The backend it trained on (absent in hand-made headers).
    #[serde(default)]
    pub backend: Option<Backend>,
    /// The LPIPS network of its validation and evaluation, if it had one.
    #[serde(default)]
    pub lpips: Option<LpipsFiles>,
}

impl RunSettings {
    /// The settings of a run config given as JSON (a model file's header `run`).
    pub fn from_json(run: &serde_json::Value) -> Result<Self, serde_json::Error> {
        RunSettings::deserialize(run)
    }
}
