//! Held-out evaluation during and after training: whole target images rendered without
//! autodiff, scored as NHP/NIA report them (PSNR over `mask_at_box`, SSIM on its
//! bounding-rectangle crop, [`nia_data::metrics::evaluate`]), averaged over the images.

use nia_data::loader::{eval_requests, load_scene, SceneTarget};
use nia_data::metrics::{evaluate, ImageMetrics, ImageView, MetricsError, SsimOptions};
use nia_data::protocol::{EvalItem, EvalSplit};
use nia_data::rays::{near_far, pixel_centre, pixel_ray};
use nia_model::model::ModelError;
use nia_model::scene::SceneGeometry;
use nia_model::{ModelConfig, NiaModel, RayBatch};

use burn::module::Module;
use burn::prelude::*;

use crate::data::TrainData;
use crate::train_loop::{scene_input, TrainError};

/// Mean metrics over a set of images.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalSummary {
    pub images: usize,
    /// Mean per-image PSNR, dB.
    pub psnr: f64,
    /// Mean per-image SSIM (NHP's data range 2).
    pub ssim: f64,
}

/// The evaluation images of `split` among the opened subjects, at most `limit` of them.
pub fn eval_items(
    data: &TrainData,
    split: EvalSplit,
    limit: Option<usize>,
) -> Result<Vec<EvalItem>, TrainError> {
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
    Ok(match limit {
        Some(n) => items.into_iter().take(n).collect(),
        None => items,
    })
}

/// Renders `items` with `samples` samples per ray in chunks of `chunk` rays on the plain
/// (non-autodiff) version of `device`; `None` when there is nothing to evaluate.
pub fn evaluate_items(
    model: &NiaModel,
    model_config: &ModelConfig,
    data: &TrainData,
    items: &[EvalItem],
    samples: usize,
    chunk: usize,
    device: &Device,
) -> Result<Option<EvalSummary>, TrainError> {
    if items.is_empty() {
        return Ok(None);
    }
    let plain = device.clone().inner();
    let model = model.valid();
    let requests = eval_requests(items, &data.source.subjects)?;
    let (mut psnr, mut ssim) = (0.0, 0.0);
    for (i, request) in requests.iter().enumerate() {
        let scene = load_scene(&data.source, request, i, &data.loader)?;
        let SceneTarget::Image { image, mask_at_box } = &scene.target else {
            continue;
        };
        let model_err = |source| TrainError::Eval {
            subject: scene.subject.clone(),
            frame: scene.frame,
            view: scene.target_view,
            message: format!("{source}"),
        };
        let input = scene_input(&scene, &data.source.faces);
        let geometry = SceneGeometry::new(&input, model_config)
            .map_err(|e| model_err(ModelError::Scene(e)))?;
        let encoded = model
            .encode_scene(&input, &geometry, None, &plain)
            .map_err(model_err)?;
        let (w, h) = (image.width() as usize, image.height() as usize);
        let mut pixels = Vec::new();
        let mut batch = RayBatch::default();
        for p in (0..w * h).filter(|&p| mask_at_box[p]) {
            let ray = pixel_ray(&image.camera, pixel_centre(p % w, p / w));
            if let Some((near, far)) = near_far(&ray, &scene.body_box) {
                if far > near {
                    batch.origins.push(ray.origin);
                    batch.dirs.push(ray.dir);
                    batch.near.push(near);
                    batch.far.push(far);
                    pixels.push(p);
                }
            }
        }
        // Pixels without a ray render the black background.
        let mut pred = vec![0.0f32; w * h * 3];
        for start in (0..batch.len()).step_by(chunk.max(1)) {
            let end = (start + chunk.max(1)).min(batch.len());
            let part = RayBatch {
                origins: batch.origins[start..end].to_vec(),
                dirs: batch.dirs[start..end].to_vec(),
                near: batch.near[start..end].to_vec(),
                far: batch.far[start..end].to_vec(),
            };
            let out = model
                .render(&encoded, &geometry, &part, samples, None, &plain)
                .map_err(model_err)?;
            let rgb = out
                .rgb
                .into_data()
                .convert::<f32>()
                .try_to_vec::<f32>()
                .unwrap_or_default();
            for (k, &p) in pixels[start..end].iter().enumerate() {
                for c in 0..3 {
                    pred[3 * p + c] = rgb.get(3 * k + c).copied().unwrap_or(f32::NAN);
                }
            }
        }
        let metrics_err = |e: MetricsError| TrainError::Eval {
            subject: scene.subject.clone(),
            frame: scene.frame,
            view: scene.target_view,
            message: e.to_string(),
        };
        let pv = ImageView::new("prediction", &pred, w, h, 3).map_err(metrics_err)?;
        let gv = ImageView::new("ground truth", &image.image, w, h, 3).map_err(metrics_err)?;
        let ImageMetrics { psnr: p, ssim: s } =
            evaluate(&pv, &gv, mask_at_box, SsimOptions::nhp()).map_err(metrics_err)?;
        psnr += p;
        ssim += s;
    }
    let n = requests.len() as f64;
    Ok(Some(EvalSummary {
        images: requests.len(),
        psnr: psnr / n,
        ssim: ssim / n,
    }))
}
