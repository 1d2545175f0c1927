//! One subject folder opened for rendering: the ZJU-MoCap / MonoCap / synthetic reader at the
//! model's training resolution, the user's SMPL model, and scenes of chosen source views.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use nia_data::body::BodyModel;
use nia_data::dataset::loader::{
    load_scene, LoaderConfig, Scene, SceneRequest, SceneSource, TargetKind,
};
use nia_data::dataset::sampling::BoxPadding;
use nia_data::dataset::{DatasetConfig, Subject};
use nia_data::geometry::camera::Camera;
use nia_infer::run_settings::RunSettings;

use crate::model_load::smpl_path;

/// Which subject and how to read it.
#[derive(Args, Debug, Clone)]
pub struct SubjectArgs {
    /// The subject folder (`CoreView_377`, a MonoCap subject, or a synthetic subject).
    #[arg(long)]
    pub data: PathBuf,
    /// SMPL model (`SMPL_NEUTRAL.pkl` or `.npz`); default: the model's training setting, else
    /// the synthetic dataset's `body_model.npz`.
    #[arg(long)]
    pub smpl: Option<PathBuf>,
    /// Image resize ratio (default: the model's training setting).
    #[arg(long)]
    pub ratio: Option<f32>,
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
    pub source: SceneSource,
    pub body: BodyModel,
    pub loader: LoaderConfig,
}

impl OpenedSubject {
    pub fn open(args: &SubjectArgs, run: &RunSettings) -> anyhow::Result<Self> {
        let smpl = smpl_path(args.smpl.as_deref(), run, &args.data)?;
        let body =
            BodyModel::load(&smpl).with_context(|| format!("{}: SMPL model", smpl.display()))?;
        let config = DatasetConfig {
            ratio: args.ratio.or(run.data.ratio),
            smpl_model: Some(smpl),
            ..DatasetConfig::for_format(run.data.format)
        };
        let subject = Subject::open(&args.data, &config)?;
        Ok(OpenedSubject {
            source: SceneSource {
                subjects: vec![subject],
                faces: body.faces.clone(),
                cache: None,
            },
            body,
            loader: LoaderConfig {
                box_padding: BoxPadding::nhp(),
                ..LoaderConfig::default()
            },
        })
    }

    pub fn subject(&self) -> &Subject {
        &self.source.subjects[0]
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
        Ok(load_scene(&self.source, &request, 0, &self.loader)?)
    }
}
