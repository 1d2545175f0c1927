//! Capture flaws: what a real multi-view capture gets wrong that the clean generator does not.
//! Each flaw has a level: 0 is off (the clean output, byte for byte), 1 the magnitudes of the
//! `zju_like` preset, 2 twice as far from the truth. The images always show the true body; the
//! flaws are in what the dataset *says* about them, as with a real capture:
//!
//! - [`smpl_fit`]: the written SMPL fit (`params/`, `vertices/`) is off the rendered body, as
//!   EasyMocap's fits of ZJU-MoCap are (slowly varying joint rotation errors, a global offset,
//!   a shape error);
//! - [`calibration`]: the written extrinsics (`annots.npy`) are off the cameras that rendered;
//! - [`colour`]: each camera has its own colour response (gain, white balance, gamma,
//!   vignetting);
//! - [`masks`]: the written masks are degraded as a segmentation network gets them wrong;
//! - [`loose_geometry`]: the images show hair volume and loose, swinging garments that stand
//!   off the body the written SMPL describes (the one flaw that changes the images' geometry:
//!   what the set says about the body, SMPL, stays the naked body).
//!
//! The magnitudes and their sources are in docs/data.md, "Capture flaws".

pub mod calibration;
pub mod colour;
pub mod loose_geometry;
pub mod masks;
pub mod smpl_fit;

use serde::{Deserialize, Serialize};

/// Largest level accepted for any flaw.
pub const MAX_LEVEL: f32 = 4.0;

/// The flaws of a capture, each a level (module docs). The default is none.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CaptureFlaws {
    /// The written SMPL fit differs from the rendered body.
    pub smpl_fit: f32,
    /// The written extrinsics differ from the rendering cameras.
    pub calibration: f32,
    /// Each camera has its own colour response.
    pub colour: f32,
    /// The written masks are degraded.
    pub masks: f32,
    /// Hair and loose garments stand off the body the written SMPL describes.
    pub geometry: f32,
}

/// A named set of levels (`synth.capture`, `nia-train synth --capture`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CapturePreset {
    /// The clean generator.
    #[default]
    None,
    /// Every flaw at level 1: the magnitudes measured or reported for ZJU-MoCap.
    ZjuLike,
}

impl CapturePreset {
    /// The preset's levels.
    pub fn flaws(self) -> CaptureFlaws {
        match self {
            CapturePreset::None => CaptureFlaws::default(),
            CapturePreset::ZjuLike => CaptureFlaws {
                smpl_fit: 1.0,
                calibration: 1.0,
                colour: 1.0,
                masks: 1.0,
                geometry: 1.0,
            },
        }
    }
}

impl std::str::FromStr for CapturePreset {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "none" => Ok(CapturePreset::None),
            "zju_like" => Ok(CapturePreset::ZjuLike),
            other => Err(format!("`{other}`: expected none or zju_like")),
        }
    }
}

impl CaptureFlaws {
    /// True when every flaw is off (the clean generator).
    pub fn is_none(&self) -> bool {
        *self == CaptureFlaws::default()
    }

    /// The flaws as spec fields (`capture.<name>`) and levels, in a fixed order.
    pub fn levels(&self) -> [(&'static str, f32); 5] {
        [
            ("capture.smpl_fit", self.smpl_fit),
            ("capture.calibration", self.calibration),
            ("capture.colour", self.colour),
            ("capture.masks", self.masks),
            ("capture.geometry", self.geometry),
        ]
    }

    /// The first flaw whose level is not finite in `[0, MAX_LEVEL]`, with its value.
    pub fn invalid(&self) -> Option<(&'static str, f32)> {
        self.levels()
            .into_iter()
            .find(|(_, level)| !(level.is_finite() && (0.0..=MAX_LEVEL).contains(level)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_and_levels() {
        assert!(CapturePreset::None.flaws().is_none());
        let zju = CapturePreset::ZjuLike.flaws();
        assert!(!zju.is_none());
        assert!(zju.levels().iter().all(|&(_, l)| l == 1.0));
        assert_eq!(
            "zju_like".parse::<CapturePreset>(),
            Ok(CapturePreset::ZjuLike)
        );
        assert!("zju"
            .parse::<CapturePreset>()
            .unwrap_err()
            .contains("zju_like"));
        let bad = CaptureFlaws {
            masks: f32::NAN,
            ..zju
        };
        assert_eq!(bad.invalid().map(|(name, _)| name), Some("capture.masks"));
        let too_far = CaptureFlaws {
            smpl_fit: MAX_LEVEL + 1.0,
            ..zju
        };
        assert_eq!(
            too_far.invalid().map(|(name, _)| name),
            Some("capture.smpl_fit")
        );
        assert_eq!(zju.invalid(), None);
        for geometry in [
            f32::NAN,
            f32::INFINITY,
            -f32::INFINITY,
            -0.5,
            MAX_LEVEL + 0.1,
        ] {
            let bad = CaptureFlaws { geometry, ..zju };
            assert_eq!(
                bad.invalid().map(|(name, _)| name),
                Some("capture.geometry"),
                "{geometry}"
            );
        }
        let only = CaptureFlaws {
            geometry: 1.0,
            ..CaptureFlaws::default()
        };
        assert!(!only.is_none());
    }

    /// With no flaw on, a spec serialises without `capture` (the clean `synth.json`, byte for
    /// byte); with the geometry flaw alone, `capture.geometry` is written.
    #[test]
    fn a_clean_spec_serialises_without_capture() {
        let clean = serde_json::to_string(&crate::synth::SynthSpec::default()).unwrap();
        assert!(!clean.contains("capture"), "{clean}");
        let geometry = crate::synth::SynthSpec {
            capture: CaptureFlaws {
                geometry: 1.5,
                ..CaptureFlaws::default()
            },
            ..Default::default()
        };
        let json = serde_json::to_value(&geometry).unwrap();
        assert_eq!(json["capture"]["geometry"], 1.5);
        let back: crate::synth::SynthSpec = serde_json::from_value(json).unwrap();
        assert_eq!(back, geometry);
    }
}
