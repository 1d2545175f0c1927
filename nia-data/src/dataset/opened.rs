//! A run's dataset: the `[data]` section of a run config ([`DataConfig`]) and the subjects it
//! opens ([`OpenedDataset`]): those a split protocol names under one root, with the body model,
//! the visibility cache and the loader settings. Training and evaluation both open their data
//! here; neither generates data (the trainer generates a missing synthetic set first).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::body::{BodyError, BodyModel};
use crate::dataset::loader::{LoaderConfig, SceneSource};
use crate::dataset::protocol::{EvalSplit, Protocol, ProtocolError, SubjectSplit};
use crate::dataset::sampling::{BoxPadding, RaySamplingConfig, NHP_BODY_FRACTION, NHP_BORDER_PX};
use crate::dataset::vis_cache::VisibilityCache;
use crate::dataset::{DatasetConfig, DatasetError, DatasetFormat, Subject};
use crate::fitting::SmplAlignment;
use crate::synth::{SynthSection, SynthSpec, BODY_MODEL_FILE, DESCRIPTION_FILE};

/// Which split protocol the data follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProtocolName {
    /// The split written by the synthetic generator (needs its spec: a run's `[synth]`).
    Synthetic,
    /// NHP's ZJU-MoCap protocol.
    Nhp,
    /// MonoCap evaluation.
    Monocap,
    /// The subjects `[data.split]` names ([`Protocol::subjects`]): data without a split of
    /// its own, e.g. a user's captures fitted by `nia-train prepare`.
    Subjects,
}

/// `[data]`: where the subjects are and how to read them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    /// Folder holding the `CoreView_*` subjects (relative paths: to the working directory).
    pub root: PathBuf,
    #[serde(default = "DataConfig::default_format")]
    pub format: DatasetFormat,
    /// Image resize ratio in (0, 1]; default: the format's (ZJU 0.5).
    #[serde(default)]
    pub ratio: Option<f32>,
    /// SMPL model (`.pkl`/`.npz`); default for synthetic data: `ROOT/body_model.npz`.
    #[serde(default)]
    pub smpl_model: Option<PathBuf>,
    #[serde(default = "DataConfig::default_protocol")]
    pub protocol: ProtocolName,
    /// Visibility cache folder (default `ROOT/.visibility_cache`).
    #[serde(default)]
    pub visibility_cache: Option<PathBuf>,
    /// Mask border band excluded from ray sampling, pixels (NHP 5 at 512 px).
    #[serde(default = "DataConfig::default_border_px")]
    pub border_px: usize,
    /// Share of rays drawn on the body (NHP 0.5).
    #[serde(default = "DataConfig::default_body_fraction")]
    pub body_fraction: f32,
    /// Loader worker threads.
    #[serde(default = "DataConfig::default_threads")]
    pub loader_threads: usize,
    /// Largest SMPL jitter of the training scenes, metres (0: off;
    /// [`crate::dataset::smpl_jitter`]).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub smpl_jitter_m: f32,
    /// Every scene's fitted SMPL moved rigidly onto its source masks, training and evaluation
    /// (`None`: the stored fit; [`crate::fitting::align`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smpl_alignment: Option<SmplAlignment>,
    /// `protocol = "subjects"`: the training and test subjects (`[data.split]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub split: Option<SubjectSplit>,
}

fn is_zero(x: &f32) -> bool {
    *x == 0.0
}

impl DataConfig {
    fn default_format() -> DatasetFormat {
        DatasetFormat::Zju
    }
    fn default_protocol() -> ProtocolName {
        ProtocolName::Synthetic
    }
    fn default_border_px() -> usize {
        NHP_BORDER_PX
    }
    fn default_body_fraction() -> f32 {
        NHP_BODY_FRACTION
    }
    fn default_threads() -> usize {
        2
    }

    /// The data at `root` with every other setting at its default.
    pub fn at(root: impl Into<PathBuf>) -> Self {
        DataConfig {
            root: root.into(),
            format: Self::default_format(),
            ratio: None,
            smpl_model: None,
            protocol: Self::default_protocol(),
            visibility_cache: None,
            border_px: Self::default_border_px(),
            body_fraction: Self::default_body_fraction(),
            loader_threads: Self::default_threads(),
            smpl_jitter_m: 0.0,
            smpl_alignment: None,
            split: None,
        }
    }

    /// The SMPL model file: `smpl_model`, else `ROOT/body_model.npz` (synthetic data).
    pub fn smpl_path(&self) -> PathBuf {
        self.smpl_model
            .clone()
            .unwrap_or_else(|| self.root.join(BODY_MODEL_FILE))
    }

    /// The visibility cache folder: `visibility_cache`, else `ROOT/.visibility_cache`.
    pub fn cache_dir(&self) -> PathBuf {
        self.visibility_cache
            .clone()
            .unwrap_or_else(|| self.root.join(".visibility_cache"))
    }

    /// Loader settings: `rays_per_image` training rays per scene (unused for whole images).
    pub fn loader(&self, rays_per_image: usize) -> LoaderConfig {
        LoaderConfig {
            threads: self.loader_threads,
            prefetch: 2 * self.loader_threads,
            sampling: RaySamplingConfig {
                rays_per_image,
                body_fraction: self.body_fraction,
                border_px: self.border_px,
                patch_px: 0,
            },
            box_padding: BoxPadding::nhp(),
            smpl_jitter_m: self.smpl_jitter_m,
            smpl_alignment: self.smpl_alignment,
            ..LoaderConfig::default()
        }
    }

    /// The spec a synthetic set under `root` was generated with (its `synth.json`), `None`
    /// where `root` holds no such description (real data). A model evaluated on another
    /// synthetic set than its own uses that set's split, whatever the run's `[synth]` says.
    pub fn own_synth_spec(&self) -> Result<Option<SynthSpec>, OpenError> {
        let path = self.root.join(DESCRIPTION_FILE);
        if !path.is_file() {
            return Ok(None);
        }
        let spec = read_description(&path)?;
        let spec: SynthSpec = serde_json::from_value(spec).map_err(|e| OpenError::Description {
            path: path.clone(),
            message: format!("`spec`: {e}"),
        })?;
        Ok(Some(spec))
    }

    /// The split protocol: the synthetic set's own (`synth`: the spec it was generated with,
    /// checked against its `synth.json`), NHP's or MonoCap's.
    pub fn protocol(&self, synth: Option<&SynthSpec>) -> Result<Protocol, OpenError> {
        let protocol = match (synth, self.protocol) {
            (Some(spec), _) => {
                let description = self.root.join(DESCRIPTION_FILE);
                if !description.is_file() {
                    return Err(OpenError::NoDataset {
                        root: self.root.clone(),
                        protocol: "synthetic".into(),
                        example: DESCRIPTION_FILE.into(),
                    });
                }
                check_description(&description, spec)?;
                Protocol::synthetic(spec, 1)
            }
            (None, ProtocolName::Nhp | ProtocolName::Synthetic) => Protocol::nhp(),
            (None, ProtocolName::Monocap) => Protocol::monocap(),
            (None, ProtocolName::Subjects) => match &self.split {
                Some(split) => Protocol::subjects(split),
                None => return Err(OpenError::NoSplit),
            },
        };
        protocol.validate()?;
        Ok(protocol)
    }
}

/// An error opening a run's dataset, naming the file or the setting.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{}: SMPL model: {source}", path.display())]
    Body { path: PathBuf, source: BodyError },
    #[error("protocol: {0}")]
    Protocol(#[from] ProtocolError),
    #[error("{}: subject `{subject}` is missing (no folder {}: a training subject, or one named by `[data.split]` or `--subjects`)", root.display(), root.join(subject).display())]
    MissingSubject { root: PathBuf, subject: String },
    #[error("{}: `{key}` is {data} in this dataset, but the config's `[synth]` says {config} (point data.root at the dataset the config describes, fix the config, or delete the folder so that training generates it again)", description.display())]
    SynthMismatch {
        description: PathBuf,
        key: &'static str,
        config: String,
        data: String,
    },
    #[error("`data.protocol` is \"subjects\" but the config has no `[data.split]` (name the subject folders: `train = [...]`, `test = [...]`; see configs/own_capture.toml)")]
    NoSplit,
    #[error("{}: not a synthetic dataset description: {message}", path.display())]
    Description { path: PathBuf, message: String },
    #[error("{}: no dataset here (expected the `{protocol}` protocol's files, e.g. {})", root.display(), root.join(example).display())]
    NoDataset {
        root: PathBuf,
        protocol: String,
        example: String,
    },
    #[error("{}: the `{split}` split has no subject folder here (expected one of: {expected})", root.display())]
    NoSplitSubjects {
        root: PathBuf,
        split: String,
        expected: String,
    },
}

/// The subjects of a run, opened.
#[derive(Debug)]
pub struct OpenedDataset {
    /// What the loader reads: every opened subject, the body model's faces and the cache.
    pub source: Arc<SceneSource>,
    pub protocol: Protocol,
    pub loader: LoaderConfig,
    /// The body model (its faces drive visibility; reposing poses it).
    pub body_model: Arc<BodyModel>,
}

impl OpenedDataset {
    /// Opens `subjects` (folder names under `data.root`) with `protocol`; a missing folder is
    /// skipped unless `required`. `rays_per_image`: training rays per scene. The protocol is
    /// checked first ([`Protocol::validate`]), then against each opened subject
    /// ([`Protocol::check_subject`]: its views exist and no target view is an input view).
    pub fn open(
        data: &DataConfig,
        protocol: Protocol,
        subjects: &[(String, bool)],
        rays_per_image: usize,
    ) -> Result<Self, OpenError> {
        protocol.validate()?;
        let smpl = data.smpl_path();
        let model = BodyModel::load(&smpl).map_err(|source| OpenError::Body {
            path: smpl.clone(),
            source,
        })?;
        let reader = DatasetConfig {
            ratio: data.ratio,
            smpl_model: Some(smpl.clone()),
            ..DatasetConfig::for_format(data.format)
        };
        let mut opened: Vec<Subject> = Vec::new();
        for (name, required) in subjects {
            let dir = data.root.join(name);
            if !dir.is_dir() {
                if *required {
                    return Err(OpenError::MissingSubject {
                        root: data.root.clone(),
                        subject: name.clone(),
                    });
                }
                continue;
            }
            if opened.iter().any(|s| &s.name == name) {
                continue;
            }
            let subject = open_subject(&dir, &reader, &smpl, &model)?;
            protocol.check_subject(&subject.name, subject.num_cameras(), subject.num_frames())?;
            opened.push(subject);
        }
        let model = Arc::new(model);
        Ok(OpenedDataset {
            source: Arc::new(SceneSource {
                subjects: opened,
                faces: model.faces.clone(),
                cache: Some(VisibilityCache::new(data.cache_dir())),
                body_model: Some(model.clone()),
            }),
            protocol,
            loader: data.loader(rays_per_image),
            body_model: model,
        })
    }

    /// The subjects of `split` that are present under the data root (at least one; all of
    /// them for [`ProtocolName::Subjects`]).
    pub fn open_split(
        data: &DataConfig,
        protocol: Protocol,
        split: EvalSplit,
    ) -> Result<Self, OpenError> {
        // Subjects the config or the command line names must be there (a typo is an error).
        let required = data.protocol == ProtocolName::Subjects;
        let names: Vec<(String, bool)> = protocol
            .split(split)
            .iter()
            .map(|s| (s.subject.clone(), required))
            .collect();
        let opened = Self::open(data, protocol, &names, 1)?;
        if opened.source.subjects.is_empty() {
            return Err(OpenError::NoSplitSubjects {
                root: data.root.clone(),
                split: split.name().into(),
                expected: names
                    .iter()
                    .map(|(s, _)| s.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        }
        Ok(opened)
    }

    /// Index of the opened subject `name`.
    pub fn subject_index(&self, name: &str) -> Option<usize> {
        self.source.subjects.iter().position(|s| s.name == name)
    }
}

/// Checks that the dataset's `synth.json` agrees with `spec` on what the split protocol
/// depends on (subjects, frames, cameras, test fraction); the image size may differ (the same
/// subjects rendered at another resolution).
fn check_description(path: &Path, spec: &SynthSpec) -> Result<(), OpenError> {
    let data = &read_description(path)?;
    let fields: [(&'static str, serde_json::Value); 4] = [
        ("synth.subjects", spec.subjects.into()),
        ("synth.frames", spec.frames.into()),
        ("synth.cameras", spec.cameras.into()),
        ("synth.test_fraction", spec.test_fraction.into()),
    ];
    for (key, config) in fields {
        let name = key.trim_start_matches("synth.");
        let found = &data[name];
        let equal = match (found.as_f64(), config.as_f64()) {
            (Some(a), Some(b)) => (a - b).abs() < 1e-6,
            _ => false,
        };
        if !equal {
            return Err(OpenError::SynthMismatch {
                description: path.to_path_buf(),
                key,
                config: config.to_string(),
                data: found.to_string(),
            });
        }
    }
    // A clean description has no `capture` (written only when some flaw is on).
    let flaws = spec.capture;
    for (field, level) in flaws.levels() {
        let name = field.trim_start_matches("capture.");
        let found = data["capture"][name].as_f64().unwrap_or(0.0);
        if (found - level as f64).abs() > 1e-6 {
            return Err(OpenError::SynthMismatch {
                description: path.to_path_buf(),
                key: SynthSection::key(field),
                config: level.to_string(),
                data: found.to_string(),
            });
        }
    }
    Ok(())
}

/// The `spec` object of a synthetic set's `synth.json`.
fn read_description(path: &Path) -> Result<serde_json::Value, OpenError> {
    let bad = |message: String| OpenError::Description {
        path: path.to_path_buf(),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
    let mut json: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?;
    match json.get_mut("spec") {
        Some(spec) if spec.is_object() => Ok(spec.take()),
        _ => Err(bad(
            "no `spec` object (expected the generator's settings)".into()
        )),
    }
}

/// Opens a subject and checks that its stored vertices (frame 0) fit the SMPL model.
fn open_subject(
    dir: &Path,
    reader: &DatasetConfig,
    smpl: &Path,
    model: &BodyModel,
) -> Result<Subject, OpenError> {
    let subject = Subject::open(dir, reader)?;
    if subject.num_frames() > 0 {
        let stored = subject.load_vertices(0)?.len();
        if stored != model.v_template.len() {
            return Err(DatasetError::VertexCount {
                model: smpl.to_path_buf(),
                vertices: subject.vertices_path(0)?,
                model_vertices: model.v_template.len(),
                stored_vertices: stored,
            }
            .into());
        }
    }
    Ok(subject)
}
