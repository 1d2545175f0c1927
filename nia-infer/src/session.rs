//! What `render`, `orbit`, `animate` and `view` share: a model file opened with the command
//! line's overrides, one subject of a dataset, and the render entry point of nia-model
//! ([`nia_model::renderer::view`]) called with them. Each command keeps only its own concern
//! (which cameras, which poses, what it writes).

use std::path::PathBuf;
use std::sync::Arc;

use clap::Args;
use nia_data::body::reposing::Reposer;
use nia_data::dataset::loader::Scene;
use nia_data::geometry::camera::Camera;
use nia_data::geometry::rays::Aabb;
use nia_data::scene::SceneInput;
use nia_model::render_options::RenderOptions;
use nia_model::renderer::image::{ImageRenderOptions, RenderedImage};
use nia_model::renderer::view::{prepare_pose, prepare_scene, render_view, TargetView};
use nia_model::scene_encoding::SceneEncoding;
use nia_model::timing::StageTimes;
use nia_model::ModelError;

use crate::model_load::{LoadedModel, ModelArgs};
use serde::Serialize;

use crate::subject_scene::{parse_views, OpenedSubject, SubjectArgs, ViewList};

/// The model, the subject and its source views: the arguments of every command that renders
/// a subject.
#[derive(Args, Debug)]
pub struct SessionArgs {
    #[command(flatten)]
    pub model: ModelArgs,
    #[command(flatten)]
    pub subject: SubjectArgs,
    /// Source cameras, e.g. 0,7,15 (default: the input views of the split protocol of the
    /// subject's dataset, as `eval` uses).
    #[arg(long, value_parser = parse_views)]
    pub views: Option<ViewList>,
    #[command(flatten)]
    pub stage_times: StageTimesArgs,
}

/// `--no-stage-times`, for every command that reports per-stage timings (`eval` and the
/// commands of [`SessionArgs`]).
#[derive(Args, Debug)]
pub struct StageTimesArgs {
    /// Leaves out the per-stage timings of the report (`stage_ms`). Timing a stage waits for
    /// the device at its end, six times per network call; on a GPU those waits add time and
    /// keep the host's work for the next call from overlapping the device's. On the CPU
    /// backends it changes only the report (`orbit` never times its stages).
    #[arg(long)]
    pub no_stage_times: bool,
}

impl StageTimesArgs {
    /// Whether to time the stages.
    pub fn timed(&self) -> bool {
        !self.no_stage_times
    }
}

/// What every rendering command's report starts with.
#[derive(Serialize)]
pub struct SessionReport {
    pub model: PathBuf,
    pub subject: PathBuf,
    pub views: Vec<usize>,
    pub samples: usize,
}

/// A model and a subject, ready to render.
pub struct RenderSession {
    pub loaded: LoadedModel,
    pub opened: OpenedSubject,
    /// The source views.
    pub views: Vec<usize>,
    /// The model's `[render]` settings with the command line's overrides.
    pub options: RenderOptions,
    /// Samples per ray.
    pub samples: usize,
    /// `--chunk`, when given (else each sample count gets the device's default: [`Self::chunk`]).
    chunk_arg: Option<usize>,
    /// Whether the commands time their stages (not with `--no-stage-times`).
    pub timed: bool,
}

impl RenderSession {
    /// Opens the model file and the subject, checks the render flags and the source views.
    pub fn open(args: &SessionArgs) -> anyhow::Result<Self> {
        let loaded = LoadedModel::open(&args.model)?;
        let options = loaded.render_options(&args.model)?;
        let opened = OpenedSubject::open(&args.subject, &loaded.run)?;
        let views = opened.views_or_protocol(args.views.as_ref(), &loaded.run)?;
        let samples = loaded.samples(&args.model);
        Ok(RenderSession {
            samples,
            chunk_arg: args.model.chunk,
            loaded,
            opened,
            views,
            options,
            timed: args.stage_times.timed(),
        })
    }

    /// Rays per chunk at the session's samples and options ([`Self::chunk_for`]).
    pub fn chunk(&self) -> usize {
        self.chunk_for(self.samples, &self.options)
    }

    /// Rays per chunk at `samples` samples per ray with `options`: `--chunk`, else the
    /// device's default ([`LoadedModel::chunk`]; on the CPU more rays at fewer samples, as in
    /// a viewer's drag frames).
    pub fn chunk_for(&self, samples: usize, options: &RenderOptions) -> usize {
        self.loaded
            .chunk_or_default(self.chunk_arg, samples, options)
    }

    /// The scene of `frame` from the session's source views.
    pub fn scene(&self, frame: usize) -> anyhow::Result<Scene> {
        self.opened.scene(frame, &self.views)
    }

    /// The scene of a reference frame that other poses are reposed from: its fit as stored,
    /// not aligned to the masks (`[data] smpl_alignment` skipped). The target poses' fits have
    /// no images to be aligned to, and aligning the reference alone lost on every set
    /// measured (docs/robustness.md).
    pub fn reference_scene(&self, frame: usize) -> anyhow::Result<Scene> {
        self.opened.scene_with(frame, &self.views, false)
    }

    /// The part of a command's report that names the model, the subject and the views.
    pub fn report(&self) -> SessionReport {
        SessionReport {
            model: self.loaded.path.clone(),
            subject: self.opened.dir.clone(),
            views: self.views.clone(),
            samples: self.samples,
        }
    }

    /// `scene` encoded for rendering its own pose.
    pub fn prepare(
        &self,
        scene: &Scene,
        times: Option<&mut StageTimes>,
    ) -> anyhow::Result<SceneEncoding> {
        let input = SceneInput::from_loaded(scene, &self.opened.source.faces);
        Ok(prepare_scene(
            &self.loaded.model,
            &input,
            None,
            &self.options,
            &self.loaded.device,
            times,
        )?)
    }

    /// `base` (a [`Self::prepare`]d scene) encoded for `reposer`'s target pose.
    pub fn prepare_pose(
        &self,
        base: &SceneEncoding,
        reposer: Arc<Reposer>,
        times: Option<&mut StageTimes>,
    ) -> anyhow::Result<SceneEncoding> {
        Ok(prepare_pose(
            &self.loaded.model,
            base,
            reposer,
            &self.options,
            times,
        )?)
    }

    /// The whole image of `camera` of a scene whose body lies in `body_box`, at the session's
    /// samples and chunk (`timed`: with stage timings), asking `cancelled` before every chunk.
    pub fn target_view<'a>(
        &self,
        camera: &'a Camera,
        body_box: &'a Aabb,
        timed: bool,
        cancelled: Option<&'a dyn Fn() -> bool>,
    ) -> TargetView<'a> {
        TargetView {
            camera,
            body_box,
            pixels: None,
            image: ImageRenderOptions {
                samples: self.samples,
                chunk: self.chunk(),
                timed,
            },
            cancelled,
        }
    }

    /// `view`'s image of `encoding` with `options` (the session's, or a variant of them);
    /// `None` when the view's `cancelled` said so before it was done.
    pub fn render_with(
        &self,
        encoding: &SceneEncoding,
        view: &TargetView<'_>,
        options: &RenderOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> anyhow::Result<Option<RenderedImage>> {
        match render_view(&self.loaded.model, encoding, view, options, progress) {
            Ok(image) => Ok(Some(image)),
            Err(ModelError::Cancelled) => Ok(None),
            Err(e) => Err(e.into()),
        }
    }

    /// `camera`'s image of `encoding` with the session's options.
    pub fn render(
        &self,
        encoding: &SceneEncoding,
        camera: &Camera,
        body_box: &Aabb,
        timed: bool,
        progress: &mut dyn FnMut(usize, usize),
    ) -> anyhow::Result<RenderedImage> {
        let view = self.target_view(camera, body_box, timed, None);
        self.render_with(encoding, &view, &self.options, progress)?
            .ok_or_else(|| anyhow::anyhow!("rendering was cancelled"))
    }
}
