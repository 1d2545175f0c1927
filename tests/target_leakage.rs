//! The target view cannot reach the render: a scene is loaded from a synthetic subject on disk
//! as the main command's evaluation loads it (`configs/quickstart.toml`: its network, its
//! `[data]` loader with the fitted SMPL aligned and its joints bent onto the source masks, its
//! `[render]` section with the body in the visual hull and 2 x 2 rays a
//! pixel; data with a real capture's flaws), rendered through the one render entry point, then
//! the target view's image and mask files are overwritten and the scene is loaded and rendered
//! again: the prediction is bit-identical. Overwriting a source image instead changes it, so
//! the comparison can fail.

mod common;

use std::path::Path;
use std::sync::Arc;

use burn::prelude::*;
use nia_data::body::BodyModel;
use nia_data::dataset::loader::{
    load_scene, LoaderConfig, Scene, SceneRequest, SceneSource, SceneTarget, TargetKind,
};
use nia_data::dataset::{DatasetConfig, Subject};
use nia_data::scene::SceneInput;
use nia_data::synth::capture::CapturePreset;
use nia_model::renderer::image::ImageRenderOptions;
use nia_model::renderer::view::{prepare_scene, render_view, TargetView};
use nia_model::NiaModel;
use nia_train::config::TrainConfig;

const TARGET: usize = 3;
const SOURCES: [usize; 3] = [0, 1, 2];

/// Writes noise over the image and mask files of `view` of frame 0.
fn overwrite_view(subject: &Subject, view: usize) {
    let image = &subject.frames[0].images[view];
    let (w, h) = (
        subject.raw_cameras[view].width,
        subject.raw_cameras[view].height,
    );
    let noise = image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([
            (x * 37 % 251) as u8,
            (y * 91 % 241) as u8,
            ((x + y) * 13) as u8,
        ])
    });
    noise.save(image).unwrap();
    for mask in subject.mask_paths(0, view).unwrap() {
        let mask_noise =
            image::GrayImage::from_fn(w, h, |x, y| image::Luma([((x ^ y) & 1) as u8 * 255]));
        mask_noise.save(&mask).unwrap();
    }
}

/// The main command's run config.
fn main_command() -> TrainConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/quickstart.toml");
    TrainConfig::load(&path).unwrap()
}

fn load(source: &SceneSource, loader: &LoaderConfig) -> Scene {
    let request = SceneRequest {
        subject: 0,
        frame: 0,
        input_views: SOURCES.to_vec(),
        target_view: TARGET,
        target: TargetKind::Image,
        seed: 0,
    };
    load_scene(source, &request, 0, loader).unwrap()
}

/// The evaluation's render of the scene's target view: `[H * W * 3]` colours, and the target
/// image it is scored against.
fn render(
    model: &NiaModel,
    config: &TrainConfig,
    source: &SceneSource,
    device: &Device,
) -> (Vec<f32>, Vec<f32>) {
    let scene = load(source, &config.data.loader(0));
    let SceneTarget::Image { image, mask_at_box } = &scene.target else {
        panic!("an image target");
    };
    let options = &config.render;
    let input = SceneInput::from_loaded(&scene, &source.faces);
    let encoding = prepare_scene(model, &input, None, options, device, None).unwrap();
    let view = TargetView {
        camera: &image.camera,
        body_box: &scene.body_box,
        pixels: Some(mask_at_box),
        image: ImageRenderOptions {
            samples: 12,
            chunk: 512,
            timed: false,
        },
        cancelled: None,
    };
    let rendered = render_view(model, &encoding, &view, options, &mut |_, _| {}).unwrap();
    (rendered.rgb, image.image.clone())
}

fn open(dir: &Path, body: &Arc<BodyModel>) -> SceneSource {
    let subject = Subject::open(dir, &DatasetConfig::zju()).unwrap();
    SceneSource {
        subjects: vec![subject],
        faces: body.faces.clone(),
        cache: None,
        body_model: Some(body.clone()),
    }
}

#[test]
fn the_target_image_and_mask_never_reach_the_prediction() {
    let config = main_command();
    let alignment = config
        .data
        .smpl_alignment
        .expect("the main command aligns the fit");
    assert!(alignment.pose_iterations > 0, "and bends its joints");
    assert!(config.render.visual_hull && config.render.hull_body_erode_px.is_some());
    assert!(config.render.supersample > 1);
    assert!(config.model.blend_view_statistics);
    let summary = common::one_subject_with("target-leakage", 48, 23, CapturePreset::ZjuLike);
    let body = Arc::new(BodyModel::load(&summary.body_model).unwrap());
    let dir = &summary.subjects[0].dir;

    #[allow(deprecated)] // ndarray: the reference CPU backend
    let device = Device::ndarray();
    device.seed(5);
    let model = config.model.init(&device);

    let source = open(dir, &body);
    let (before, target_before) = render(&model, &config, &source, &device);
    assert!(before.iter().all(|c| c.is_finite()));

    overwrite_view(&source.subjects[0], TARGET);
    let source = open(dir, &body);
    let (after, target_after) = render(&model, &config, &source, &device);
    assert_ne!(target_before, target_after, "the target image was replaced");
    assert_eq!(before, after, "the prediction is bit-identical");

    overwrite_view(&source.subjects[0], SOURCES[1]);
    let source = open(dir, &body);
    let (changed, _) = render(&model, &config, &source, &device);
    assert_ne!(before, changed, "a source view does change the prediction");
    let _ = std::fs::remove_dir_all(&summary.out_dir);
}
