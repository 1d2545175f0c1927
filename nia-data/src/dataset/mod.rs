//! Dataset readers: ZJU-MoCap `CoreView_XXX` folders as they ship, MonoCap (the same layout
//! plus `lbs/`), and the synthetic set (written in the ZJU layout), all through one reader,
//! [`Subject`]. Plus the on-disk cache of per-view vertex visibility, the `inspect` summary, the
//! evaluation protocol, training ray sampling, the prefetching scene loader, and a run's opened
//! dataset ([`OpenedDataset`]).
//!
//! Typical use:
//!
//! ```no_run
//! use nia_data::dataset::{DatasetConfig, Subject};
//! let subject = Subject::open("data/CoreView_387".as_ref(), &DatasetConfig::zju()).unwrap();
//! let view = subject.load_view(0, 7).unwrap(); // undistorted, 512x512, black background
//! let vertices = subject.load_vertices(0).unwrap();
//! ```

pub mod error;
pub mod image_io;
pub mod inspect;
pub mod loader;
pub mod monocap;
pub mod opened;
pub mod protocol;
pub mod requests;
pub mod sampling;
pub mod scene_load;
pub mod smpl_jitter;
pub mod subject;
pub mod vis_cache;
pub mod zju;

pub use error::DatasetError;
pub use inspect::{inspect, InspectReport};
pub use monocap::MonoCapLbs;
pub use opened::{DataConfig, OpenError, OpenedDataset, ProtocolName};
pub use subject::{FrameFiles, Subject, ViewImage};
pub use vis_cache::{VisibilityCache, VisibilityKey, VisibilityQuery};

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// ZJU-MoCap images are 1024x1024, used at 512x512 (NHP `ratio: 0.5`).
pub const ZJU_RATIO: f32 = 0.5;
/// MonoCap images are used at full resolution.
pub const MONOCAP_RATIO: f32 = 1.0;

/// Which layout a subject folder follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DatasetFormat {
    /// ZJU-MoCap `CoreView_XXX` (also the synthetic set).
    Zju,
    /// MonoCap: the ZJU layout plus `lbs/`.
    #[serde(rename = "monocap")]
    MonoCap,
}

impl DatasetFormat {
    /// The default image resize ratio of the format.
    pub fn default_ratio(&self) -> f32 {
        match self {
            DatasetFormat::Zju => ZJU_RATIO,
            DatasetFormat::MonoCap => MONOCAP_RATIO,
        }
    }
}

impl std::str::FromStr for DatasetFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "zju" | "zju_mocap" | "zju-mocap" => Ok(DatasetFormat::Zju),
            "monocap" => Ok(DatasetFormat::MonoCap),
            other => Err(format!(
                "unknown dataset format `{other}` (expected zju or monocap)"
            )),
        }
    }
}

/// How to read a dataset. Every field has a default; a run config can override any of them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatasetConfig {
    pub format: DatasetFormat,
    /// Image resize ratio in (0, 1]; `None`: the format's default (ZJU 0.5, MonoCap 1).
    #[serde(default)]
    pub ratio: Option<f32>,
    /// The user's SMPL model (`SMPL_NEUTRAL.pkl` or a converted `.npz`). Needed for visibility
    /// (its faces) and for checking that LBS of the stored params reproduces the stored
    /// vertices.
    #[serde(default)]
    pub smpl_model: Option<PathBuf>,
    /// Override of the params folder name (default: `params/`, else `new_params/`).
    #[serde(default)]
    pub params_dir: Option<String>,
    /// Override of the vertices folder name (default: the one paired with the params folder).
    #[serde(default)]
    pub vertices_dir: Option<String>,
    /// Override of the mask folders whose union is the mask (default `mask`, `mask_cihp`).
    #[serde(default)]
    pub mask_dirs: Option<Vec<String>>,
    /// Where per-view visibility is cached (default: no cache).
    #[serde(default)]
    pub visibility_cache: Option<PathBuf>,
}

impl DatasetConfig {
    /// ZJU-MoCap defaults.
    pub fn zju() -> Self {
        Self::for_format(DatasetFormat::Zju)
    }

    /// MonoCap defaults.
    pub fn monocap() -> Self {
        Self::for_format(DatasetFormat::MonoCap)
    }

    pub fn for_format(format: DatasetFormat) -> Self {
        DatasetConfig {
            format,
            ratio: None,
            smpl_model: None,
            params_dir: None,
            vertices_dir: None,
            mask_dirs: None,
            visibility_cache: None,
        }
    }

    /// The resize ratio in effect.
    pub fn ratio(&self) -> f32 {
        self.ratio.unwrap_or(self.format.default_ratio())
    }
}

impl Default for DatasetConfig {
    fn default() -> Self {
        Self::zju()
    }
}
