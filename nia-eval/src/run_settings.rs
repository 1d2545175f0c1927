//! The settings inference takes from the run a model was trained with: the model file's header
//! carries the whole run config (the trainer's schema); inference reads only the sections it
//! needs, so it does not depend on the trainer.

use crate::perceptual::LpipsFiles;
use nia_data::dataset::opened::OpenError;
use nia_data::dataset::protocol::Protocol;
use nia_data::dataset::{DataConfig, ProtocolName};
use nia_data::synth::SynthSection;
use nia_model::device::Backend;
use nia_model::render_options::RenderOptions;
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
    pub render: RenderOptions,
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

impl RunSettings {
    /// The split protocol of the dataset `data` (the run's own `[data]`, or another root): the
    /// run's, except that a synthetic set other than the run's own brings its own split (its
    /// `synth.json`), so a model trained on 8 synthetic people evaluates on a set of 4 from
    /// another seed, and renders take that set's source views.
    pub fn protocol_for(&self, data: &DataConfig) -> Result<Protocol, OpenError> {
        if data.protocol == ProtocolName::Subjects {
            // Subjects named by the config or the command line: no synthetic split applies.
            return data.protocol(None);
        }
        let run_spec = self.synth.as_ref().map(|s| s.spec());
        let spec = match run_spec {
            Some(run_spec) if data.root != self.data.root => {
                Some(data.own_synth_spec()?.unwrap_or(run_spec))
            }
            other => other,
        };
        data.protocol(spec.as_ref())
    }
}
