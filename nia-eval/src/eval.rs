//! Held-out evaluation, used by `nia-infer eval` and `sweep` and by the trainer (validation and
//! the final evaluation): whole target images rendered without autodiff
//! ([`nia_model::renderer::image`]), scored as NHP/NIA report them (PSNR over `mask_at_box`, SSIM on its
//! bounding-rectangle crop, [`nia_data::metrics::evaluate`]). The data is an
//! [`OpenedDataset`] (a run's `[data]` section, opened).
//!
//! Two tasks (the paper's):
//! - [`EvalTask::NovelView`]: the source views and the target view are of the same frame.
//! - [`EvalTask::NovelPose`]: the source views are of a reference frame (by default the first
//!   frame of the subject's range in the split); the body is reposed to the evaluated frame's
//!   SMPL parameters and rendered from the target camera, scored against that frame's image.

use crate::diagnostics::{BlendDiagnostics, DiagnosticsInput};
use crate::perceptual::lpips_masked_crop;
use crate::truth::{TruthData, TruthError};
use std::sync::Arc;
use std::time::Instant;

use burn::module::Module;
use burn::prelude::*;
use nia_data::body::reposing::Reposer;
use nia_data::dataset::loader::{
    eval_requests, load_scene, LoaderConfig, LoaderError, Scene, SceneRequest, SceneTarget,
};
use nia_data::dataset::protocol::{EvalItem, EvalSplit, ProtocolError};
use nia_data::dataset::{OpenedDataset, ViewImage};
use nia_data::metrics::{evaluate, ImageMetrics, ImageView, MetricsError, SsimOptions};
use nia_data::scene::SceneInput;
use nia_model::lpips::Lpips;
use nia_model::render_options::RenderOptions;
use nia_model::renderer::image::{ImageRenderOptions, RenderedImage};
use nia_model::renderer::view::{prepare_scene, render_view, TargetView};
use nia_model::timing::StageTimes;
use nia_model::{ModelError, NiaModel};
use serde::Serialize;

/// An evaluation error, naming the image (subject, frame, target view) where there is one.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("loader: {0}")]
    Loader(#[from] LoaderError),
    #[error("protocol: {0}")]
    Protocol(#[from] ProtocolError),
    #[error("evaluating {subject}, frame {frame}, view {view}: {message}")]
    Image {
        subject: String,
        frame: usize,
        view: usize,
        message: String,
    },
    #[error(transparent)]
    Truth(#[from] TruthError),
    /// A writer of results (pictures, tables) failed.
    #[error("{0}")]
    Output(String),
}

/// Mean metrics over a set of images.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalSummary {
    pub images: usize,
    /// Mean per-image PSNR, dB.
    pub psnr: f64,
    /// Mean per-image SSIM (NHP's data range 2).
    pub ssim: f64,
    /// Mean per-image LPIPS, when it was computed ([`EvalOptions::lpips`]).
    pub lpips: Option<f64>,
    /// Mean instruments.
    pub diagnostics: BlendDiagnostics,
}

impl EvalSummary {
    /// The mean of `results`; `None` when empty.
    pub fn of(results: &[ImageResult]) -> Option<Self> {
        if results.is_empty() {
            return None;
        }
        let n = results.len() as f64;
        Some(EvalSummary {
            images: results.len(),
            psnr: results.iter().map(|r| r.psnr).sum::<f64>() / n,
            ssim: results.iter().map(|r| r.ssim).sum::<f64>() / n,
            lpips: results
                .iter()
                .map(|r| r.lpips)
                .sum::<Option<f64>>()
                .map(|s| s / n),
            diagnostics: BlendDiagnostics::mean_of(results.iter().map(|r| &r.diagnostics)),
        })
    }
}

/// The paper's two evaluation tasks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EvalTask {
    NovelView,
    /// `reference_frame`: the frame whose images are the sources (`None`: the first frame of
    /// the subject's range in the split). Items of the reference frame itself are skipped.
    NovelPose {
        reference_frame: Option<usize>,
    },
}

/// How to evaluate.
#[derive(Debug, Clone)]
pub struct EvalOptions {
    pub task: EvalTask,
    /// Samples per ray.
    pub samples: usize,
    /// Rays per network call.
    pub chunk: usize,
    /// Collect per-stage timings (synchronises the device after each stage).
    pub timed: bool,
    /// The `[render]` options (skipping, termination, culling, carving, supersampling).
    pub render: RenderOptions,
    /// Also score LPIPS with this network (on the evaluation device), on SSIM's crop.
    pub lpips: Option<Arc<Lpips>>,
    /// Also score every image against this set's image of the same view
    /// ([`crate::truth`]).
    pub truth: Option<Arc<TruthData>>,
}

/// The score and cost of one evaluated image.
#[derive(Debug, Clone, Serialize)]
pub struct ImageResult {
    pub subject: String,
    /// The frame whose image is the ground truth (and whose pose is rendered).
    pub frame: usize,
    /// The frame of the source images (equal to `frame` for novel views).
    pub reference_frame: usize,
    pub input_views: Vec<usize>,
    pub target_view: usize,
    pub psnr: f64,
    pub ssim: f64,
    /// LPIPS on the `mask_at_box` crop, when [`EvalOptions::lpips`] is set.
    pub lpips: Option<f64>,
    /// Rays sent to the network.
    pub rays: usize,
    /// Points evaluated by the network.
    pub point_evaluations: u64,
    /// Of those, the points whose colour was evaluated (colour culling skips the rest).
    pub colour_evaluations: u64,
    /// Wall time of the image (encoding, reposing set-up and rendering; not loading).
    pub seconds: f64,
    /// The hybrid's instruments ([`BlendDiagnostics`]).
    pub diagnostics: BlendDiagnostics,
    /// How the sources' SMPL fit was moved onto their masks (`[data] smpl_alignment`; absent
    /// when off).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub smpl_alignment: Option<AlignmentReport>,
    #[serde(skip)]
    pub times: StageTimes,
}

/// A scene's SMPL alignment ([`nia_data::fitting::align`]) as `metrics.json` lists
/// it: the fit moved by `x -> R (x - centre) + centre + translation`.
#[derive(Debug, Clone, Serialize)]
pub struct AlignmentReport {
    pub translation_m: [f32; 3],
    /// `R` as an axis-angle vector, radians.
    pub rotation: [f32; 3],
    pub rotation_deg: f32,
    pub centre_m: [f32; 3],
    /// The silhouette energy before and after.
    pub energy_before: f32,
    pub energy_after: f32,
    /// Source views whose mask took part.
    pub views_used: usize,
    /// The pose refinement after the rigid motion (absent when off).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pose: Option<PoseReport>,
}

/// A scene's SMPL pose refinement ([`nia_data::fitting::align::refine_pose`]).
#[derive(Debug, Clone, Serialize)]
pub struct PoseReport {
    /// Mean and largest rotation of the body joints away from the fit, degrees.
    pub mean_joint_deg: f32,
    pub max_joint_deg: f32,
    /// The objective (silhouette energy plus pose prior) before and after.
    pub energy_before: f32,
    pub energy_after: f32,
    /// Accepted steps.
    pub steps: usize,
}

impl AlignmentReport {
    /// The scene's rigid correction and pose refinement; `None` when the alignment was off.
    pub fn of(scene: &Scene) -> Option<Self> {
        let c = scene.alignment.as_ref()?;
        Some(AlignmentReport {
            translation_m: c.motion.translation.to_array(),
            rotation: c.motion.rotation.to_scaled_axis().to_array(),
            rotation_deg: c.motion.rotation_deg(),
            centre_m: c.motion.centre.to_array(),
            energy_before: c.energy_before,
            energy_after: c.energy_after,
            views_used: c.views_used,
            pose: scene.pose_refinement.as_ref().map(|p| PoseReport {
                mean_joint_deg: p.mean_joint_deg,
                max_joint_deg: p.max_joint_deg,
                energy_before: p.energy_before,
                energy_after: p.energy_after,
                steps: p.steps,
            }),
        })
    }
}

/// Everything about one evaluated image, for writers of pictures.
pub struct EvaluatedImage<'a> {
    pub result: &'a ImageResult,
    /// The scene the sources came from (the reference frame for novel poses).
    pub sources: &'a Scene,
    /// Ground-truth image of the target view.
    pub ground_truth: &'a nia_data::dataset::ViewImage,
    /// [H * W] the scored region.
    pub mask_at_box: &'a [bool],
    pub rendered: &'a RenderedImage,
}

/// The evaluation images of `split` among the opened subjects for `task`, at most `limit` of
/// them. A novel pose leaves out the images of each subject's reference frame (the sources
/// themselves) before the limit, so `limit` counts images that are evaluated.
pub fn eval_items(
    data: &OpenedDataset,
    split: EvalSplit,
    task: EvalTask,
    limit: Option<usize>,
) -> Result<Vec<EvalItem>, EvalError> {
    let subjects = &data.source.subjects;
    let opened: Vec<_> = data
        .protocol
        .split(split)
        .iter()
        .filter(|s| subjects.iter().any(|o| o.name == s.subject))
        .cloned()
        .collect();
    let mut protocol = data.protocol.clone();
    match split {
        EvalSplit::UnseenSubjects => protocol.unseen_subjects = opened,
        EvalSplit::SeenSubjectsUnseenPoses => protocol.seen_subjects_unseen_poses = opened,
        EvalSplit::SeenSubjectsSeenPoses => protocol.seen_subjects_seen_poses = opened,
    }
    let items = protocol.eval_items(split, |name| {
        subjects
            .iter()
            .find(|s| s.name == name)
            .map(|s| (s.num_cameras(), s.num_frames()))
            .unwrap_or((0, 0))
    })?;
    let evaluated = items.into_iter().filter(|item| match task {
        EvalTask::NovelView => true,
        EvalTask::NovelPose { .. } => {
            reference_frame(data, split, &item.subject, task) != item.frame
        }
    });
    Ok(evaluated.take(limit.unwrap_or(usize::MAX)).collect())
}

/// The frame novel-pose items of `subject` take their sources from.
fn reference_frame(data: &OpenedDataset, split: EvalSplit, subject: &str, task: EvalTask) -> usize {
    match task {
        EvalTask::NovelPose {
            reference_frame: Some(f),
        } => f,
        _ => data
            .protocol
            .split(split)
            .iter()
            .find(|s| s.subject == subject)
            .map_or(0, |s| s.frames.begin),
    }
}

/// Renders and scores `items` of `split` on the plain (non-autodiff) version of `device`,
/// calling `on_image` for each; returns the per-image results in item order.
pub fn evaluate_images(
    model: &NiaModel,
    data: &OpenedDataset,
    split: EvalSplit,
    items: &[EvalItem],
    options: EvalOptions,
    device: &Device,
    on_image: &mut dyn FnMut(EvaluatedImage<'_>) -> Result<(), EvalError>,
) -> Result<Vec<ImageResult>, EvalError> {
    let plain = device.clone().inner();
    let model = model.valid();
    let requests = eval_requests(items, &data.source.subjects)?;
    let mut results = Vec::with_capacity(requests.len());
    for (i, request) in requests.iter().enumerate() {
        let Some(scenes) = EvalScenes::load(data, split, options.task, request, i)? else {
            continue;
        };
        let SceneTarget::Image { image, mask_at_box } = &scenes.target.target else {
            continue;
        };
        let target = ScoredTarget {
            request,
            image,
            mask_at_box,
        };
        let (result, rendered) = evaluate_image(&model, data, &scenes, &target, &options, &plain)?;
        on_image(EvaluatedImage {
            result: &result,
            sources: scenes.sources(),
            ground_truth: image,
            mask_at_box,
            rendered: &rendered,
        })?;
        results.push(result);
    }
    Ok(results)
}

/// The scenes of one evaluated image: the target (ground truth, body box, pose: always the
/// evaluated frame), and for a novel pose the reference frame the sources come from.
struct EvalScenes {
    /// The frame of the source images (the evaluated frame for novel views).
    reference: usize,
    target: Scene,
    /// The reference frame's scene, for a novel pose (`None`: the target's sources).
    source: Option<Scene>,
}

impl EvalScenes {
    /// The scenes of `request` (the `index`-th) for `task`; `None` for a novel pose of the
    /// reference frame itself.
    fn load(
        data: &OpenedDataset,
        split: EvalSplit,
        task: EvalTask,
        request: &SceneRequest,
        index: usize,
    ) -> Result<Option<Self>, EvalError> {
        let reference = match task {
            EvalTask::NovelView => request.frame,
            EvalTask::NovelPose { .. } => {
                let subject = &data.source.subjects[request.subject].name;
                let r = reference_frame(data, split, subject, task);
                if r == request.frame {
                    return Ok(None);
                }
                r
            }
        };
        let target = load_scene(
            &data.source,
            &SceneRequest {
                input_views: if reference == request.frame {
                    request.input_views.clone()
                } else {
                    Vec::new()
                },
                ..request.clone()
            },
            index,
            &data.loader,
        )?;
        // A novel pose's reference keeps its stored fit: the evaluated frame's fit has no
        // images to be aligned to, and aligning the reference alone lost on every set
        // measured (docs/robustness.md).
        let source = if reference == request.frame {
            None
        } else {
            Some(load_scene(
                &data.source,
                &SceneRequest {
                    frame: reference,
                    ..request.clone()
                },
                index,
                &LoaderConfig {
                    smpl_alignment: None,
                    ..data.loader
                },
            )?)
        };
        Ok(Some(EvalScenes {
            reference,
            target,
            source,
        }))
    }

    /// The scene the source views come from.
    fn sources(&self) -> &Scene {
        self.source.as_ref().unwrap_or(&self.target)
    }
}

/// The ground truth one image is scored against.
struct ScoredTarget<'a> {
    request: &'a SceneRequest,
    /// The target view's image.
    image: &'a ViewImage,
    /// `[H * W]` the scored region.
    mask_at_box: &'a [bool],
}

/// One image rendered from `scenes` and scored against `target`: its result and the render.
fn evaluate_image(
    model: &NiaModel,
    data: &OpenedDataset,
    scenes: &EvalScenes,
    target: &ScoredTarget<'_>,
    options: &EvalOptions,
    plain: &Device,
) -> Result<(ImageResult, RenderedImage), EvalError> {
    let (scene, sources, image) = (&scenes.target, scenes.sources(), target.image);
    let eval_err = |message: String| EvalError::Image {
        subject: scene.subject.clone(),
        frame: scene.frame,
        view: scene.target_view,
        message,
    };
    let model_err = |e: ModelError| eval_err(e.to_string());
    let started = Instant::now();
    let mut times = StageTimes::default();
    let input = SceneInput::from_loaded(sources, &data.source.faces);
    let reposer = match &scenes.source {
        None => None,
        Some(reference_scene) => Some(Arc::new(
            Reposer::new(&data.body_model, &reference_scene.params, &scene.params)
                .map_err(|e| eval_err(format!("reposing from frame {}: {e}", scenes.reference)))?,
        )),
    };
    let encoding = prepare_scene(
        model,
        &input,
        reposer,
        &options.render,
        plain,
        options.timed.then_some(&mut times),
    )
    .map_err(model_err)?;
    let view = TargetView {
        camera: &image.camera,
        body_box: &scene.body_box,
        pixels: Some(target.mask_at_box),
        image: ImageRenderOptions {
            samples: options.samples,
            chunk: options.chunk,
            timed: options.timed,
        },
        cancelled: None,
    };
    let mut rendered =
        render_view(model, &encoding, &view, &options.render, &mut |_, _| {}).map_err(model_err)?;
    times.merge(&rendered.times);
    rendered.times = times.clone();
    let seconds = started.elapsed().as_secs_f64();
    let (w, h) = (rendered.width, rendered.height);
    let metrics_err = |e: MetricsError| eval_err(e.to_string());
    let pv = ImageView::new("prediction", &rendered.rgb, w, h, 3).map_err(metrics_err)?;
    let gv = ImageView::new("ground truth", &image.image, w, h, 3).map_err(metrics_err)?;
    let ImageMetrics { psnr, ssim } =
        evaluate(&pv, &gv, target.mask_at_box, SsimOptions::nhp()).map_err(metrics_err)?;
    let lpips = match &options.lpips {
        Some(net) => Some(
            lpips_masked_crop(net, &pv, &gv, target.mask_at_box, plain)
                .map_err(|e| eval_err(e.to_string()))?,
        ),
        None => None,
    };
    let truth = match &options.truth {
        Some(t) => Some(t.view(
            &scene.subject,
            scene.frame,
            target.request.target_view,
            &image.camera,
        )?),
        None => None,
    };
    // The clothed surface the target image shows, where the data holds it (synthetic sets).
    let true_surface = data
        .subject_index(&scene.subject)
        .map(|i| data.source.subjects[i].load_clothed_vertices(scene.frame))
        .transpose()
        .map_err(|e| eval_err(e.to_string()))?
        .flatten();
    let diagnostics = BlendDiagnostics::measure(&DiagnosticsInput {
        rendered: &rendered,
        camera: &image.camera,
        ground_truth: &image.image,
        person_mask: &image.mask,
        mask_at_box: target.mask_at_box,
        posed_vertices: encoding
            .reposer
            .as_ref()
            .map_or(&scene.vertices[..], |r| r.target_vertices()),
        faces: &data.source.faces,
        sources,
        truth: truth.as_ref().map(|t| t.image.as_slice()),
        true_surface: true_surface.as_deref(),
    })
    .map_err(metrics_err)?;
    let result = ImageResult {
        subject: scene.subject.clone(),
        frame: scene.frame,
        reference_frame: scenes.reference,
        input_views: target.request.input_views.clone(),
        target_view: target.request.target_view,
        psnr,
        ssim,
        lpips,
        rays: rendered.rays,
        point_evaluations: rendered.point_evaluations,
        colour_evaluations: rendered.colour_evaluations,
        smpl_alignment: AlignmentReport::of(sources),
        seconds,
        diagnostics,
        times,
    };
    Ok((result, rendered))
}

/// Evaluation of `items` of the unseen-subject split with `options` (what training reports);
/// `on_done(k, image)` after the k-th image; `None` when there is nothing to evaluate.
pub fn evaluate_items(
    model: &NiaModel,
    data: &OpenedDataset,
    items: &[EvalItem],
    options: EvalOptions,
    device: &Device,
    on_done: &mut dyn FnMut(usize, &EvaluatedImage<'_>),
) -> Result<Option<EvalSummary>, EvalError> {
    let mut done = 0;
    let results = evaluate_images(
        model,
        data,
        EvalSplit::UnseenSubjects,
        items,
        options,
        device,
        &mut |image| {
            done += 1;
            on_done(done, &image);
            Ok(())
        },
    )?;
    Ok(EvalSummary::of(&results))
}
