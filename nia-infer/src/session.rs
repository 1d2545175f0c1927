//! What `render`, `orbit`, `animate` and `view` share: a model file opened with the command
//! line's overrides, one subject of a dataset, and the render entry point of nia-model
//! ([`nia_model::renderer::view`]) called with them. Each command keeps only its own concern
//! (which cameras, which poses, what it writes).

use std::sync::Arc;

use nia_data::body::reposing::Reposer;
use nia_data::dataset::loader::Scene;
use nia_data::geometry::camera::Camera;
use nia_data::geometry::rays::Aabb;
use nia_data::scene::SceneInput;
use nia_model::render_options::RenderOptions;
use nia_model::renderer::image::{ImageRenderOptions, RenderedImage};
use nia_model::renderer::view::{prepare_pose, prepare_scene, render_view_cancellable, TargetView};
use nia_model::scene_encoding::SceneEncoding;
use nia_model::timing::StageTimes;

use crate::model_load::{LoadedModel, ModelArgs};
use crate::subject_scene::{OpenedSubject, SubjectArgs, ViewList};

/// A model and a subject, ready to render.
pub struct RenderSession {
    pub loaded: LoadedModel,
    pub opened: OpenedSubject,
    /// The model's `[render]` settings with the command line's overrides.
    pub options: RenderOptions,
    /// Samples per ray.
    pub samples: usize,
    /// Rays per network call.
    pub chunk: usize,
}

impl RenderSession {
    /// Opens the model file and the subject, and checks the render flags.
    pub fn open(model: &ModelArgs, subject: &SubjectArgs) -> anyhow::Result<Self> {
        let loaded = LoadedModel::open(model)?;
        let options = loaded.render_options(model)?;
        let opened = OpenedSubject::open(subject, &loaded.run)?;
        Ok(RenderSession {
            samples: loaded.samples(model),
            chunk: model.chunk,
            loaded,
            opened,
            options,
        })
    }

    /// The source views: `given`, else the input views of the subject's dataset protocol.
    pub fn views(&self, given: Option<&ViewList>) -> anyhow::Result<Vec<usize>> {
        self.opened.views_or_protocol(given, &self.loaded.run)
    }

    /// The scene of `frame` from `views`, encoded for rendering its own pose.
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

    /// `camera`'s image of `encoding` (whose body lies in `body_box`), with `options` (the
    /// session's, or a variant of them); `None` when `cancelled` said so before it was done.
    #[allow(clippy::too_many_arguments)]
    pub fn render_with(
        &self,
        encoding: &SceneEncoding,
        camera: &Camera,
        body_box: &Aabb,
        options: &RenderOptions,
        timed: bool,
        progress: &mut dyn FnMut(usize, usize),
        cancelled: &dyn Fn() -> bool,
    ) -> anyhow::Result<Option<RenderedImage>> {
        let view = TargetView {
            camera,
            body_box,
            pixels: None,
            image: ImageRenderOptions {
                samples: self.samples,
                chunk: self.chunk,
                timed,
            },
        };
        Ok(render_view_cancellable(
            &self.loaded.model,
            encoding,
            &view,
            options,
            progress,
            cancelled,
        )?)
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
        let options = self.options;
        self.render_with(
            encoding,
            camera,
            body_box,
            &options,
            timed,
            progress,
            &|| false,
        )?
        .ok_or_else(|| anyhow::anyhow!("rendering was cancelled"))
    }
}
