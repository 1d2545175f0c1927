//! `[synth]` of a run config: the synthetic dataset a run generates into `data.root` when it is
//! missing, and whose split protocol it follows.

use serde::{Deserialize, Serialize};

use super::SynthSpec;

/// `[synth]`: the user-facing fields of a [`SynthSpec`] (the rest keep their defaults).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SynthSection {
    pub subjects: usize,
    pub frames: usize,
    pub cameras: usize,
    pub size: u32,
    #[serde(default)]
    pub seed: u64,
    #[serde(default = "SynthSection::default_supersample")]
    pub supersample: u32,
    #[serde(default = "SynthSection::default_test_fraction")]
    pub test_fraction: f32,
}

impl SynthSection {
    fn default_supersample() -> u32 {
        SynthSpec::default().supersample
    }
    fn default_test_fraction() -> f32 {
        SynthSpec::default().test_fraction
    }

    /// The generator's spec.
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

    /// The `[synth]` key of a [`SynthSpec`] field name (for error messages).
    pub fn key(field: &'static str) -> &'static str {
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
}
