//! Cross-crate: a synthetic subject written in the ZJU-MoCap layout, read back through the
//! dataset reader (cameras, images, masks, params, vertices), with rasterised visibility, feeds
//! the network, which renders a whole target view: every pixel of `mask_at_box` gets a finite
//! colour in [0, 1] and the metrics of the protocol are computable on it.

mod common;

use burn::prelude::*;
use nia_data::body::BodyModel;
use nia_data::dataset::{DatasetConfig, Subject};
use nia_data::geometry::rays::{image_rays, mask_at_box, near_far, RayBundle};
use nia_data::geometry::visibility::visibility;
use nia_data::metrics::{psnr_masked, ImageView};
use nia_data::scene::{SceneBody, SceneInput, SourceView};
use nia_model::ModelConfig;

/// Depth tolerance of vertex visibility, metres.
const VIS_TOL_M: f32 = 0.02;

/// [H * W * 3] (HWC, the reader's layout) to [3, H, W] (CHW, the network's).
fn hwc_to_chw(hwc: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut chw = vec![0.0; hwc.len()];
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                chw[(c * h + y) * w + x] = hwc[(y * w + x) * 3 + c];
            }
        }
    }
    chw
}

#[test]
fn a_synthetic_subject_renders_through_reader_and_network() {
    let summary = common::one_subject("synth-to-model", 64, 11);
    let body = BodyModel::load(&summary.body_model).unwrap();
    let subject = Subject::open(&summary.subjects[0].dir, &DatasetConfig::zju()).unwrap();

    let params = subject.load_params(0).unwrap();
    let scene_body = SceneBody {
        vertices: subject.load_vertices(0).unwrap(),
        faces: body.faces.clone(),
        rh: params.rh,
        th: params.th,
    };
    let mut views = Vec::new();
    for view in 0..3 {
        let v = subject.load_view(0, view).unwrap();
        let (w, h) = (v.camera.width as usize, v.camera.height as usize);
        let vis = visibility(&v.camera, &scene_body.vertices, &body.faces, VIS_TOL_M).unwrap();
        assert!(vis.contains(&1), "view {view}: some vertices are visible");
        views.push(SourceView {
            image: hwc_to_chw(&v.image, w, h),
            mask: v.mask.iter().map(|&m| m as u8 as f32).collect(),
            camera: v.camera,
            vertex_visibility: vis.iter().map(|&b| b as f32).collect(),
        });
    }
    let input = SceneInput {
        views,
        body: scene_body,
    };

    #[allow(deprecated)] // ndarray: the reference CPU backend the user asked for
    let device = Device::ndarray();
    device.seed(0);
    let config = ModelConfig::tiny();
    let model = config.init(&device);
    let scene = model.encode(&input, None, &device, None).unwrap();
    let ray_box = scene.geometry.ray_box;

    // The whole target view: rays of mask_at_box only (the others are background, no network).
    let target = subject.load_view(0, 3).unwrap();
    let (w, h) = (target.camera.width as usize, target.camera.height as usize);
    let in_box = mask_at_box(&target.camera, &ray_box);
    let mut rays = RayBundle::default();
    for (p, ray) in image_rays(&target.camera).into_iter().enumerate() {
        if let (true, Some((near, far))) = (in_box[p], near_far(&ray, &ray_box)) {
            rays.push(ray, near, far, p as u32);
        }
    }
    assert!(
        rays.len() > 100,
        "the body box covers part of the target view"
    );
    let rendered = model.render(&scene, &rays, 8, None, None).unwrap();
    let rgb = rendered.rgb.into_data().try_to_vec::<f32>().unwrap();
    assert!(rgb
        .iter()
        .all(|c| c.is_finite() && (0.0..=1.0 + 1e-5).contains(c)));

    let mut image = vec![0.0f32; w * h * 3];
    for (k, &p) in rays.pixels.iter().enumerate() {
        let p = p as usize;
        image[p * 3..p * 3 + 3].copy_from_slice(&rgb[k * 3..k * 3 + 3]);
    }
    let pred = ImageView::new("prediction", &image, w, h, 3).unwrap();
    let gt = ImageView::new("ground truth", &target.image, w, h, 3).unwrap();
    let psnr = psnr_masked(&pred, &gt, &in_box).unwrap();
    assert!(
        psnr.is_finite() && psnr > 0.0,
        "PSNR of an untrained model is finite: {psnr}"
    );
    let _ = std::fs::remove_dir_all(&summary.out_dir);
}
