//! One subject folder opened for rendering: the ZJU-MoCap / MonoCap / synthetic reader at the
//! model's training resolution, the user's SMPL model, and scenes of chosen source views.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use clap::Args;
use nia_data::body::BodyModel;
use nia_data::dataset::loader::{
    load_scene, LoaderConfig, Scene, SceneRequest, SceneSource, TargetKind,
};
use nia_data::dataset::sampling::BoxPadding;
use nia_data::dataset::{DatasetConfig, Subject};
use nia_data::geometry::camera::Camera;
use nia_eval::run_settings::RunSettings;

use crate::model_load::smpl_path;

/// Which subject and how to read it. `--data` is the dataset root, as in `eval` and `sweep`.
#[derive(Args, Debug, Clone)]
pub struct SubjectArgs {
    /// Dataset root holding the subject folders (default: the model's training data root).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// The subject: a folder name under the dataset root (`CoreView_377`, `subject_0003`), or
    /// the path of a subject folder.
    #[arg(long)]
    pub subject: String,
    /// SMPL model (`SMPL_NEUTRAL.pkl` or `.npz`); default: the model's training setting, else
    /// the synthetic dataset's `body_model.npz`.
    #[arg(long)]
    pub smpl: Option<PathBuf>,
    /// Image resize ratio (default: the model's training setting).
    #[arg(long)]
    pub ratio: Option<f32>,
}

/// The subject folder of `args`: `ROOT/SUBJECT` (ROOT: `--data`, else the model's training
/// root), else `SUBJECT` as a path; a folder holding `annots.npy`.
pub fn subject_dir(args: &SubjectArgs, run: &RunSettings) -> anyhow::Result<PathBuf> {
    let root = args.data.clone().unwrap_or_else(|| run.data.root.clone());
    let annots = |dir: &Path| dir.join("annots.npy").is_file();
    let under_root = root.join(&args.subject);
    if annots(&under_root) {
        return Ok(under_root);
    }
    let as_path = PathBuf::from(&args.subject);
    if annots(&as_path) {
        return Ok(as_path);
    }
    if annots(&root) {
        anyhow::bail!(
            "--data {}: a subject folder, not a dataset root; pass --data {} --subject {}",
            root.display(),
            root.parent().unwrap_or(Path::new(".")).display(),
            root.file_name().unwrap_or_default().to_string_lossy()
        );
    }
    anyhow::bail!(
        "--subject {}: no subject folder (holding annots.npy) at {} or {}",
        args.subject,
        under_root.display(),
        as_path.display()
    )
}

/// Camera indices given as `0,7,15`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewList(pub Vec<usize>);

/// Parses `0,7,15`.
pub fn parse_views(s: &str) -> Result<ViewList, String> {
    let views: Result<Vec<usize>, _> = s.split(',').map(|v| v.trim().parse::<usize>()).collect();
    match views {
        Ok(v) if !v.is_empty() => Ok(ViewList(v)),
        _ => Err(format!(
            "`{s}`: expected camera indices separated by commas, e.g. 0,7,15"
        )),
    }
}

pub struct OpenedSubject {
    /// The subject folder.
    pub dir: PathBuf,
    pub source: SceneSource,
    pub body: Arc<BodyModel>,
    pub loader: LoaderConfig,
}

impl OpenedSubject {
    pub fn open(args: &SubjectArgs, run: &RunSettings) -> anyhow::Result<Self> {
        let dir = subject_dir(args, run)?;
        let smpl = smpl_path(args.smpl.as_deref(), run, &dir)?;
        let body = Arc::new(
            BodyModel::load(&smpl).with_context(|| format!("{}: SMPL model", smpl.display()))?,
        );
        let config = DatasetConfig {
            ratio: args.ratio.or(run.data.ratio),
            smpl_model: Some(smpl),
            ..DatasetConfig::for_format(run.data.format)
        };
        let subject = Subject::open(&dir, &config)?;
        Ok(OpenedSubject {
            dir,
            source: SceneSource {
                subjects: vec![subject],
                faces: body.faces.clone(),
                cache: None,
                body_model: Some(body.clone()),
            },
            body,
            loader: LoaderConfig {
                box_padding: BoxPadding::nhp(),
                smpl_alignment: run.data.smpl_alignment,
                ..LoaderConfig::default()
            },
        })
    }

    pub fn subject(&self) -> &Subject {
        &self.source.subjects[0]
    }

    /// Source views: `given`, else the test-time input views of the split protocol of the
    /// dataset the subject is in (NHP: 0,7,15; a synthetic set: its own `synth.json`, whether
    /// it is the model's training set or another), checked against the subject.
    pub fn views_or_protocol(
        &self,
        given: Option<&ViewList>,
        run: &RunSettings,
    ) -> anyhow::Result<Vec<usize>> {
        let views = match given {
            Some(v) => v.0.clone(),
            None => {
                // The dataset the subject is in (`--data`, else the model's training root).
                let mut data = run.data.clone();
                if let Some(root) = self.dir.parent() {
                    data.root = root.to_path_buf();
                }
                let protocol = run.protocol_for(&data).with_context(|| {
                    format!(
                        "the split protocol of {} gives the default source views; pass --views",
                        data.root.display()
                    )
                })?;
                protocol
                    .input_views
                    .resolve(self.subject().num_cameras(), &[])
            }
        };
        self.check_views("--views", &views)?;
        Ok(views)
    }

    /// Checks camera indices against the subject.
    pub fn check_views(&self, flag: &str, views: &[usize]) -> anyhow::Result<()> {
        let s = self.subject();
        if let Some(&bad) = views.iter().find(|&&v| v >= s.num_cameras()) {
            anyhow::bail!(
                "{flag} {bad}: {} has {} cameras (0..{})",
                s.root.display(),
                s.num_cameras(),
                s.num_cameras().saturating_sub(1)
            );
        }
        Ok(())
    }

    pub fn check_frame(&self, flag: &str, frame: usize) -> anyhow::Result<()> {
        let s = self.subject();
        if frame >= s.num_frames() {
            anyhow::bail!(
                "{flag} {frame}: {} has {} frames (0..{})",
                s.root.display(),
                s.num_frames(),
                s.num_frames().saturating_sub(1)
            );
        }
        Ok(())
    }

    /// The camera of `view` at the loaded resolution.
    pub fn camera(&self, view: usize) -> Camera {
        self.subject().cameras[view]
    }

    /// The scene of `frame` with `views` as sources (images, masks, visibility, SMPL).
    pub fn scene(&self, frame: usize, views: &[usize]) -> anyhow::Result<Scene> {
        self.scene_with(frame, views, true)
    }

    /// As [`OpenedSubject::scene`]; `aligned` false skips the run's `[data] smpl_alignment`.
    pub fn scene_with(
        &self,
        frame: usize,
        views: &[usize],
        aligned: bool,
    ) -> anyhow::Result<Scene> {
        self.check_frame("--frame", frame)?;
        self.check_views("--views", views)?;
        let request = SceneRequest {
            subject: 0,
            frame,
            input_views: views.to_vec(),
            target_view: views[0],
            target: TargetKind::Image,
            seed: 0,
        };
        let loader = LoaderConfig {
            smpl_alignment: self.loader.smpl_alignment.filter(|_| aligned),
            ..self.loader
        };
        Ok(load_scene(&self.source, &request, 0, &loader)?)
    }
}
