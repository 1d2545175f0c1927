//! The target view cannot reach the render: a scene is loaded from a synthetic subject on disk
//! as the evaluation loads it (sources, target image, target mask, `mask_at_box`), rendered
//! through the one render entry point with every `[render]` switch on (carving reads the
//! source masks), then the target view's image and mask files are overwritten and the scene is
//! loaded and rendered again: the prediction is bit-identical. Overwriting a source image
//! instead changes it, so the comparison can fail.

mod common;

use std::path::Path;

use burn::prelude::*;
use nia_data::body::BodyModel;
use nia_data::dataset::loader::{
    load_scene, LoaderConfig, Scene, SceneRequest, SceneSource, SceneTarget, TargetKind,
};
use nia_data::dataset::sampling::BoxPadding;
use nia_data::dataset::{DatasetConfig, Subject};
use nia_data::scene::SceneInput;
use nia_model::render_options::RenderOptions;
use nia_model::renderer::image::ImageRenderOptions;
use nia_model::renderer::view::{prepare_scene, render_view, TargetView};
use nia_model::{ModelConfig, NiaModel};

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

fn load(source: &SceneSource) -> Scene {
    let request = SceneRequest {
        subject: 0,
        frame: 0,
        input_views: SOURCES.to_vec(),
        target_view: TARGET,
        target: TargetKind::Image,
        seed: 0,
    };
    let loader = LoaderConfig {
        box_padding: BoxPadding::nhp(),
        ..LoaderConfig::default()
    };
    load_scene(source, &request, 0, &loader).unwrap()
}

/// The evaluation's render of the scene's target view: `[H * W * 3]` colours, and the target
/// image it is scored against.
fn render(model: &NiaModel, source: &SceneSource, device: &Device) -> (Vec<f32>, Vec<f32>) {
    let scene = load(source);
    let SceneTarget::Image { image, mask_at_box } = &scene.target else {
        panic!("an image target");
    };
    let options = RenderOptions {
        visual_hull: true,
        supersample: 2,
        ..RenderOptions::default()
    };
    let input = SceneInput::from_loaded(&scene, &source.faces);
    let encoding = prepare_scene(model, &input, None, &options, device, None).unwrap();
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
    let rendered = render_view(model, &encoding, &view, &options, &mut |_, _| {}).unwrap();
    (rendered.rgb, image.image.clone())
}

fn open(dir: &Path, faces: &[[u32; 3]]) -> SceneSource {
    let subject = Subject::open(dir, &DatasetConfig::zju()).unwrap();
    SceneSource {
        subjects: vec![subject],
        faces: faces.to_vec(),
        cache: None,
        body_model: None,
    }
}

#[test]
fn the_target_image_and_mask_never_reach_the_prediction() {
    let summary = common::one_subject("target-leakage", 48, 23);
    let body = BodyModel::load(&summary.body_model).unwrap();
    let dir = &summary.subjects[0].dir;

    #[allow(deprecated)] // ndarray: the reference CPU backend
    let device = Device::ndarray();
    device.seed(5);
    let model = ModelConfig::tiny().init(&device);

    let source = open(dir, &body.faces);
    let (before, target_before) = render(&model, &source, &device);
    assert!(before.iter().all(|c| c.is_finite()));

    overwrite_view(&source.subjects[0], TARGET);
    let source = open(dir, &body.faces);
    let (after, target_after) = render(&model, &source, &device);
    assert_ne!(target_before, target_after, "the target image was replaced");
    assert_eq!(before, after, "the prediction is bit-identical");

    overwrite_view(&source.subjects[0], SOURCES[1]);
    let source = open(dir, &body.faces);
    let (changed, _) = render(&model, &source, &device);
    assert_ne!(before, changed, "a source view does change the prediction");
    let _ = std::fs::remove_dir_all(&summary.out_dir);
}
