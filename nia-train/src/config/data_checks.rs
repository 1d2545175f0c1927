//! The `[data]` checks of [`TrainConfig::validate`] that depend on whether `[synth]` generates
//! the data: without it the root must exist, the split must come from somewhere (NHP's or
//! MonoCap's names, or `[data.split]` for the subjects of a user's own root) and the SMPL model
//! must be found.

use std::path::Path;

use nia_data::dataset::ProtocolName;
use nia_data::synth::BODY_MODEL_FILE;

use super::{ConfigError, TrainConfig};

impl TrainConfig {
    /// The data root, the protocol and its split, and the SMPL model (module docs).
    pub(super) fn check_data(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, expected: &str, got: String| ConfigError::Invalid {
            path: path.to_path_buf(),
            key: key.to_string(),
            expected: expected.to_string(),
            got,
        };
        let d = &self.data;
        let subjects = d.protocol == ProtocolName::Subjects;
        if self.synth.is_some() && subjects {
            return Err(bad(
                "data.protocol",
                "synthetic with a [synth] section (\"subjects\" is for data of your own: \
                 remove [synth], as configs/own_capture.toml does)",
                "subjects".into(),
            ));
        }
        if d.split.is_some() && !subjects {
            return Err(bad(
                "data.split",
                "only with data.protocol = \"subjects\"",
                format!(
                    "data.protocol = \"{}\"",
                    match d.protocol {
                        ProtocolName::Synthetic => "synthetic",
                        ProtocolName::Nhp => "nhp",
                        ProtocolName::Monocap => "monocap",
                        ProtocolName::Subjects => "subjects",
                    }
                ),
            ));
        }
        if let Some(split) = &d.split {
            if split.train.is_empty() {
                return Err(bad(
                    "data.split.train",
                    "at least one training subject folder",
                    "[]".into(),
                ));
            }
            if let Some(views) = &split.input_views {
                if views.is_empty() {
                    return Err(bad(
                        "data.split.input_views",
                        "camera indices (or no key: 3 spread evenly)",
                        "[]".into(),
                    ));
                }
            }
            if split.test_frame_stride == 0 {
                return Err(bad("data.split.test_frame_stride", ">= 1", "0".into()));
            }
            if split.train_frames == Some(0) {
                return Err(bad("data.split.train_frames", ">= 1", "0".into()));
            }
        } else if subjects {
            return Err(bad(
                "data.split",
                "the subject folders under data.root: [data.split] train = [...], test = [...]",
                "nothing".into(),
            ));
        }
        if self.synth.is_some() {
            return Ok(());
        }
        if !d.root.is_dir() {
            return Err(bad(
                "data.root",
                "an existing folder (or a [synth] section to generate it)",
                d.root.display().to_string(),
            ));
        }
        if d.protocol == ProtocolName::Synthetic {
            return Err(bad(
                "data.protocol",
                "nhp, monocap, or subjects with a [data.split] naming the subject folders \
                 (your own data: configs/own_capture.toml) when there is no [synth] section",
                "synthetic".into(),
            ));
        }
        if d.smpl_model.is_none() && !d.root.join(BODY_MODEL_FILE).is_file() {
            return Err(bad(
                "data.smpl_model",
                &format!(
                    "the path of the SMPL model file (SMPL_NEUTRAL.pkl or .npz; needed for \
                     visibility), or the model at {}",
                    d.root.join(BODY_MODEL_FILE).display()
                ),
                "nothing".into(),
            ));
        }
        Ok(())
    }
}
