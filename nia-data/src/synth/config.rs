//! `[synth]` of a run config: the synthetic dataset a run generates into `data.root` when it is
//! missing, and whose split protocol it follows.

use serde::{Deserialize, Serialize};

use super::capture::{CaptureFlaws, CapturePreset};
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
    /// The capture's flaws as a preset (`"none"`, the default, or `"zju_like"`).
    #[serde(default, skip_serializing_if = "is_default")]
    pub capture: CapturePreset,
    /// Level of the SMPL fit's error over the preset's (0: off, 1: zju_like).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smpl_fit_level: Option<f32>,
    /// Level of the calibration's error over the preset's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_level: Option<f32>,
    /// Level of the per-camera colour response over the preset's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colour_level: Option<f32>,
    /// Level of the mask flaws over the preset's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask_level: Option<f32>,
    /// Level of the geometry off SMPL (hair volume, loose swinging garments) over the preset's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry_level: Option<f32>,
    /// Also write the 2D keypoints a detector would report (OpenPose BODY_25, 2 px noise,
    /// 10% dropped, 2% outliers: [`super::keypoints`]).
    #[serde(default, skip_serializing_if = "is_false")]
    pub keypoints: bool,
}

fn is_false(b: &bool) -> bool {
    !*b
}

fn is_default(preset: &CapturePreset) -> bool {
    *preset == CapturePreset::default()
}

impl SynthSection {
    fn default_supersample() -> u32 {
        SynthSpec::default().supersample
    }
    fn default_test_fraction() -> f32 {
        SynthSpec::default().test_fraction
    }

    /// The capture flaws: the preset's levels with the single levels given over them.
    pub fn capture(&self) -> CaptureFlaws {
        Self::capture_levels(
            self.capture,
            [
                self.smpl_fit_level,
                self.calibration_level,
                self.colour_level,
                self.mask_level,
                self.geometry_level,
            ],
        )
    }

    /// `preset`'s levels with `[smpl_fit, calibration, colour, masks, geometry]` given over
    /// them (the config's keys and `nia-train synth`'s flags).
    pub fn capture_levels(preset: CapturePreset, levels: [Option<f32>; 5]) -> CaptureFlaws {
        let base = preset.flaws();
        let [smpl_fit, calibration, colour, masks, geometry] = levels;
        CaptureFlaws {
            smpl_fit: smpl_fit.unwrap_or(base.smpl_fit),
            calibration: calibration.unwrap_or(base.calibration),
            colour: colour.unwrap_or(base.colour),
            masks: masks.unwrap_or(base.masks),
            geometry: geometry.unwrap_or(base.geometry),
        }
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
            capture: self.capture(),
            keypoints: self.keypoints.then(super::KeypointSpec::default),
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
            "capture.smpl_fit" => "synth.smpl_fit_level",
            "capture.calibration" => "synth.calibration_level",
            "capture.colour" => "synth.colour_level",
            "capture.masks" => "synth.mask_level",
            "capture.geometry" => "synth.geometry_level",
            "keypoints.noise_px"
            | "keypoints.drop"
            | "keypoints.outliers"
            | "keypoints.lost_runs" => "synth.keypoints",
            _ => "synth",
        }
    }
}
