//! Adaptive work changes nothing it should not: on an unseen synthetic subject rendered by the
//! trained quickstart network (`tests/fixtures/quickstart_tiny.nia`), the samples that
//! empty-space skipping leaves out would have contributed under the stated tolerances, compared
//! with the full computation of the same image; it evaluates far fewer points; novel-view and
//! reposed rendering count their work.

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use burn::prelude::*;
use glam::Vec3;
use nia_data::body::reposing::Reposer;
use nia_data::body::BodyModel;
use nia_data::dataset::loader::{
    load_scene, LoaderConfig, Scene, SceneRequest, SceneSource, SceneTarget, TargetKind,
};
use nia_data::dataset::sampling::BoxPadding;
use nia_data::dataset::{DatasetConfig, Subject, ViewImage};
use nia_data::geometry::camera::Camera;
use nia_data::geometry::rays::{Aabb, RayBundle};
use nia_data::metrics::{evaluate, ImageView, SsimOptions};
use nia_data::scene::SceneInput;
use nia_data::synth::{self, BODY_MODEL_FILE};
use nia_model::render_options::RenderOptions;
use nia_model::renderer::image::{render_image, ImageRenderOptions, RenderedImage};
use nia_model::renderer::render_rays;
use nia_model::renderer::view::{prepare_scene, render_view, TargetView};
use nia_model::sampler::stratified_t;
use nia_model::scene_encoding::SceneEncoding;
use nia_model::store::model_file::ModelFile;
use nia_model::NiaModel;

// What the skipped samples carried in the full computation. The trained tiny network leaves
// faint density ("floaters") in empty space; at the default 3 cm it measured: mean opacity
// 0.020, mean colour change 0.0067, largest pixel change 0.19, and PSNR 0.29 dB *higher* with
// skipping (23.49 vs 23.20 dB): what skipping removes is error, not signal. Larger distances
// remove less (8 cm: mean opacity 0.007, largest change 0.06).
/// Largest change of any pixel's colour (max over RGB).
const MAX_PIXEL_CHANGE: f32 = 0.25;
/// Mean absolute change of the colours over the rendered pixels.
const MEAN_PIXEL_CHANGE: f32 = 0.01;
/// Mean change of the accumulated opacity: the weight the skipped samples carried.
const MEAN_OPACITY_CHANGE: f32 = 0.03;
/// PSNR may not drop by more than this (the bound).
const MAX_PSNR_LOSS_DB: f64 = 0.1;
/// Skipping against the full computation with the skipped densities zeroed: only the batch
/// composition differs (float reordering).
const EXACT_TOL: f32 = 1e-5;
/// Rays of that check.
const EXACT_CHECK_RAYS: usize = 300;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/quickstart_tiny.nia")
}

/// An unseen synthetic subject (not one the network was trained on): 2 frames, 4 cameras,
/// 96 px.
fn subject_dir(name: &str) -> PathBuf {
    let root = std::env::temp_dir().join(format!("nia-adaptive-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    synth::generate(&common::unseen_spec(50, 2, 4, 96, 99), &root, &mut |_| {}).unwrap();
    root
}

/// An unseen subject with the trained fixture on the CPU and frame 0 loaded.
struct Case {
    root: PathBuf,
    source: SceneSource,
    body: BodyModel,
    device: Device,
    /// The trained test fixture.
    model: NiaModel,
    /// Frame 0: sources 0, 1, 2, the whole image of camera 3 as target.
    scene: Scene,
}

fn case(name: &str) -> Case {
    let root = subject_dir(name);
    let body = BodyModel::load(&root.join(BODY_MODEL_FILE)).unwrap();
    let subject = Subject::open(
        &root.join("CoreView_50"),
        &DatasetConfig {
            ratio: Some(1.0),
            ..DatasetConfig::zju()
        },
    )
    .unwrap();
    let source = SceneSource {
        subjects: vec![subject],
        faces: body.faces.clone(),
        cache: None,
        body_model: None,
    };
    let request = SceneRequest {
        subject: 0,
        frame: 0,
        input_views: vec![0, 1, 2],
        target_view: 3,
        target: TargetKind::Image,
        seed: 0,
    };
    let loader = LoaderConfig {
        box_padding: BoxPadding::nhp(),
        ..LoaderConfig::default()
    };
    let scene = load_scene(&source, &request, 0, &loader).unwrap();
    #[allow(deprecated)] // burn 0.22 spells the CPU device this way.
    let device = Device::ndarray();
    let model = ModelFile::read(&fixture())
        .unwrap()
        .load(&fixture(), &device)
        .unwrap();
    Case {
        root,
        source,
        body,
        device,
        model,
        scene,
    }
}

impl Case {
    /// The scene's input to the network.
    fn input(&self) -> SceneInput {
        SceneInput::from_loaded(&self.scene, &self.source.faces)
    }

    /// The target image, its pixels whose ray hits the body box, and the rays through those.
    fn target(&self) -> (&ViewImage, &[bool], RayBundle) {
        let SceneTarget::Image { image, mask_at_box } = &self.scene.target else {
            unreachable!()
        };
        let box_ = &self.scene.body_box;
        let rays = RayBundle::through_pixels(&image.camera, box_, Some(mask_at_box));
        (image, mask_at_box, rays)
    }

    /// `encoding` with the occupancy grid `adaptive` builds around `vertices`, rendered through
    /// `rays` into a `size` image, `samples` per ray, in chunks of 512.
    fn render(
        &self,
        encoding: SceneEncoding,
        adaptive: RenderOptions,
        vertices: &[Vec3],
        rays: &RayBundle,
        size: [usize; 2],
        samples: usize,
    ) -> RenderedImage {
        let grid = adaptive.occupancy(vertices, &self.source.faces).unwrap();
        render_image(
            &self.model,
            &encoding.with_occupancy(grid),
            rays,
            size,
            ImageRenderOptions {
                samples,
                chunk: 512,
                timed: false,
            },
            &mut |_, _| {},
        )
        .unwrap()
    }
}

#[test]
fn skipped_samples_would_have_contributed_under_the_tolerance() {
    let c = case("novel-view");
    let (device, model, scene) = (&c.device, &c.model, &c.scene);
    let (image, mask_at_box, rays) = c.target();
    let full_encoding = model.encode(&c.input(), None, device, None).unwrap();
    let size = [image.width() as usize, image.height() as usize];
    let pixels: Vec<usize> = rays.pixels.iter().map(|&p| p as usize).collect();
    // Skipping as `adaptive` says; early termination only when asked (the exactness checks
    // below are of skipping alone).
    let render_with = |adaptive: RenderOptions, termination: Option<f32>| -> RenderedImage {
        let encoding = full_encoding.clone().with_termination(termination);
        c.render(encoding, adaptive, &scene.vertices, &rays, size, 32)
    };
    let render = |adaptive: RenderOptions| render_with(adaptive, None);
    let full = render(RenderOptions::exhaustive());
    let skip = render(RenderOptions::default());
    assert_eq!(full.point_evaluations, (rays.len() * 32) as u64);
    let ratio = full.point_evaluations as f64 / skip.point_evaluations as f64;
    assert!(ratio > 2.0, "skipping evaluates {ratio:.2}x fewer points");

    let n = rays.len() as f32;
    let (mut max_change, mut sum_change, mut sum_acc) = (0.0f32, 0.0f32, 0.0f32);
    for &p in &pixels {
        let d = (0..3)
            .map(|k| (full.rgb[3 * p + k] - skip.rgb[3 * p + k]).abs())
            .fold(0.0f32, f32::max);
        max_change = max_change.max(d);
        sum_change += d;
        sum_acc += (full.acc[p] - skip.acc[p]).abs();
    }
    let (mean_change, mean_acc) = (sum_change / n, sum_acc / n);
    eprintln!(
        "{ratio:.2}x fewer points; colour change max {max_change:.4} mean {mean_change:.5}; opacity change mean {mean_acc:.5}"
    );
    // Skipping is exactly the full computation with the skipped samples' density set to zero:
    // the full per-sample fields of the first rays, masked by the grid, composited.
    let grid = RenderOptions::default()
        .occupancy(&scene.vertices, &c.source.faces)
        .unwrap()
        .unwrap();
    let r = EXACT_CHECK_RAYS.min(rays.len());
    let t = stratified_t(&rays.near[..r], &rays.far[..r], 32, None).unwrap();
    let mut points = Vec::with_capacity(r * 32);
    let mut dirs = Vec::with_capacity(r * 32);
    for i in 0..r {
        for k in 0..32 {
            points.push(rays.origins[i] + rays.dirs[i] * t[i * 32 + k]);
            dirs.push(rays.dirs[i]);
        }
    }
    let fields = model.field(&full_encoding, &points, &dirs, None).unwrap();
    let keep: Vec<f32> = points
        .iter()
        .map(|&p| grid.occupied(p) as u8 as f32)
        .collect();
    assert!(keep.contains(&0.0) && keep.contains(&1.0));
    let keep = Tensor::<1>::from_data(TensorData::new(keep, [r * 32]), device);
    let n1 = fields.blend_weights.dims()[1];
    let masked = render_rays(
        (fields.sigma * keep).reshape([r, 32]),
        fields.colour.reshape([r, 32, 3]),
        fields.c0.reshape([r, 32, 3]),
        Tensor::<2>::from_data(TensorData::new(t, [r, 32]), device),
        Tensor::<1>::from_data(TensorData::new(rays.far[..r].to_vec(), [r]), device),
        Some(fields.blend_weights.reshape([r, 32, n1])),
    )
    .unwrap();
    let masked_rgb = masked
        .rgb
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .unwrap();
    for (i, &p) in pixels[..r].iter().enumerate() {
        for k in 0..3 {
            let diff = (masked_rgb[3 * i + k] - skip.rgb[3 * p + k]).abs();
            assert!(
                diff <= EXACT_TOL,
                "ray {i}: skipping differs from masking by {diff}"
            );
        }
    }
    assert!(max_change <= MAX_PIXEL_CHANGE, "max change {max_change}");
    assert!(
        mean_change <= MEAN_PIXEL_CHANGE,
        "mean change {mean_change}"
    );
    assert!(
        mean_acc <= MEAN_OPACITY_CHANGE,
        "mean opacity change {mean_acc}"
    );

    let (w, h) = (full.width, full.height);
    let gt = ImageView::new("gt", &image.image, w, h, 3).unwrap();
    let psnr = |img: &RenderedImage| {
        let v = ImageView::new("pred", &img.rgb, w, h, 3).unwrap();
        evaluate(&v, &gt, mask_at_box, SsimOptions::nhp())
            .unwrap()
            .psnr
    };
    let (p_full, p_skip) = (psnr(&full), psnr(&skip));
    eprintln!("PSNR full {p_full:.3} dB, skipping {p_skip:.3} dB");
    assert!(p_skip >= p_full - MAX_PSNR_LOSS_DB, "{p_skip} vs {p_full}");

    // Early ray termination on top of skipping (the default `[render]`): the trained model's
    // colours and opacities move by at most the transmittance threshold, with no more points.
    let adaptive = RenderOptions::default();
    let epsilon = adaptive.termination().expect("on by default");
    let terminated = render_with(adaptive, Some(epsilon));
    assert!(terminated.point_evaluations <= skip.point_evaluations);
    eprintln!(
        "early termination: {} of {} points",
        terminated.point_evaluations, skip.point_evaluations
    );
    for &p in &pixels {
        for k in 0..3 {
            let d = (terminated.rgb[3 * p + k] - skip.rgb[3 * p + k]).abs();
            assert!(d <= epsilon + EXACT_TOL, "pixel {p}: colour moved by {d}");
        }
        let d = (terminated.acc[p] - skip.acc[p]).abs();
        assert!(d <= epsilon + EXACT_TOL, "pixel {p}: opacity moved by {d}");
    }
    // Pixels without a ray are black and empty in both.
    let no_ray = (0..w * h).find(|p| !pixels.contains(p)).unwrap();
    assert_eq!(full.rgb[3 * no_ray..3 * no_ray + 3], [0.0; 3]);
    assert_eq!(skip.acc[no_ray], 0.0);
    let _ = std::fs::remove_dir_all(&c.root);
}

#[test]
fn reposed_rendering_skips_and_counts_like_novel_views() {
    let c = case("reposed");
    let scene = &c.scene;
    let target_params = c.source.subjects[0].load_params(1).unwrap();
    let reposer = Arc::new(Reposer::new(&c.body, &scene.params, &target_params).unwrap());
    assert!(!reposer.is_identity(), "frame 1 has another pose");
    let encoding = c
        .model
        .encode(&c.input(), Some(reposer.clone()), &c.device, None)
        .unwrap();
    let body_box = BoxPadding::nhp()
        .body_box(reposer.target_vertices())
        .unwrap();
    let camera = c.source.subjects[0].cameras[3];
    let rays = RayBundle::through_pixels(&camera, &body_box, None);
    let size = [camera.width as usize, camera.height as usize];
    let render = |adaptive: RenderOptions| {
        let vertices = reposer.target_vertices();
        c.render(encoding.clone(), adaptive, vertices, &rays, size, 16)
    };
    let full = render(RenderOptions::exhaustive());
    let skip = render(RenderOptions::default());
    assert_eq!(full.point_evaluations, (rays.len() * 16) as u64);
    assert!(skip.point_evaluations * 2 < full.point_evaluations);
    let mean_change = rays
        .pixels
        .iter()
        .map(|&p| {
            let p = p as usize;
            (0..3)
                .map(|k| (full.rgb[3 * p + k] - skip.rgb[3 * p + k]).abs())
                .sum::<f32>()
                / 3.0
        })
        .sum::<f32>()
        / rays.len() as f32;
    assert!(
        mean_change <= MEAN_PIXEL_CHANGE,
        "mean change {mean_change}"
    );
    let _ = std::fs::remove_dir_all(&c.root);
}

/// With visual-hull carving (the default `[render]`), skipping also leaves out what the hull
/// carves: exactly the samples whose density the hull sets to 0, so the image is the one
/// rendered without any skipping (float reordering aside) from fewer point evaluations.
#[test]
fn the_visual_hull_skips_exactly_what_it_zeroes() {
    let c = case("hull");
    let (image, _, rays) = c.target();
    let input = c.input();
    let encoding = c
        .model
        .encode(&input, None, &c.device, None)
        .unwrap()
        .with_visual_hull(&input, true, None)
        .unwrap();
    let size = [image.width() as usize, image.height() as usize];
    let render = |adaptive: RenderOptions| {
        c.render(
            encoding.clone(),
            adaptive,
            &c.scene.vertices,
            &rays,
            size,
            16,
        )
    };
    // Every sample evaluated (the hull still multiplies the density) against an occupancy
    // grid that keeps the whole box (1 m from the body), so the hull is all that skips.
    let full = render(RenderOptions::exhaustive());
    let hull_only = render(RenderOptions {
        skip_empty_space: true,
        empty_space_m: 1.0,
        ..RenderOptions::exhaustive()
    });
    assert_eq!(full.point_evaluations, (rays.len() * 16) as u64);
    eprintln!(
        "points: every sample {}, hull skipping {}",
        full.point_evaluations, hull_only.point_evaluations
    );
    assert!(
        hull_only.point_evaluations * 2 < full.point_evaluations,
        "the hull leaves out most of the box"
    );
    for &p in &rays.pixels {
        let p = p as usize;
        for k in 0..3 {
            let d = (hull_only.rgb[3 * p + k] - full.rgb[3 * p + k]).abs();
            assert!(d <= EXACT_TOL, "pixel {p}: colour moved by {d}");
        }
        let d = (hull_only.acc[p] - full.acc[p]).abs();
        assert!(d <= EXACT_TOL, "pixel {p}: opacity moved by {d}");
    }
    let _ = std::fs::remove_dir_all(&c.root);
}

/// Colour once per ray (`[render] colour_points`) on the trained fixture: opacity the
/// per-sample reference's (the same density walk, to float reordering), at most K colour evaluations
/// per ray, far fewer than the reference's, and the picture within a stated PSNR of the
/// reference's on the same image; K = 2 at least as close as K = 1.
#[test]
fn colour_once_per_ray_keeps_the_picture_for_a_fraction_of_the_colour_work() {
    let c = case("colour-once");
    let (image, mask_at_box, rays) = c.target();
    let encoding = c.model.encode(&c.input(), None, &c.device, None).unwrap();
    let size = [image.width() as usize, image.height() as usize];
    let adaptive = RenderOptions::default();
    let render = |points: Option<usize>| {
        let e = encoding
            .clone()
            .with_termination(adaptive.termination())
            .with_colour_culling(adaptive.culling())
            .with_colour_points(points);
        c.render(e, adaptive, &c.scene.vertices, &rays, size, 32)
    };
    let reference = render(None);
    let (w, h) = (reference.width, reference.height);
    let gt = ImageView::new("gt", &image.image, w, h, 3).unwrap();
    let psnr_against = |a: &RenderedImage, b: &[f32]| {
        let v = ImageView::new("pred", &a.rgb, w, h, 3).unwrap();
        let t = ImageView::new("ref", b, w, h, 3).unwrap();
        evaluate(&v, &t, mask_at_box, SsimOptions::nhp())
            .unwrap()
            .psnr
    };
    let mut closeness = Vec::new();
    for k in [1, 2] {
        let once = render(Some(k));
        // Opacity is the density walk's (composited on the host: float reordering aside).
        let opacity_gap = once
            .acc
            .iter()
            .zip(&reference.acc)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(
            opacity_gap <= EXACT_TOL,
            "K = {k}: opacity differs by {opacity_gap}"
        );
        assert!(once.colour_evaluations <= (k * rays.len()) as u64);
        assert!(
            once.colour_evaluations * 3 < reference.colour_evaluations,
            "K = {k}: {} of {} colour evaluations",
            once.colour_evaluations,
            reference.colour_evaluations
        );
        assert!(once.rgb.iter().all(|x| x.is_finite()));
        let to_reference = psnr_against(&once, &reference.rgb);
        let gt_once = psnr_against(&once, gt.data);
        let gt_ref = psnr_against(&reference, gt.data);
        eprintln!(
            "K = {k}: {} of {} colour evaluations; PSNR against the reference {to_reference:.2} dB; \
             against the truth {gt_once:.3} dB (reference {gt_ref:.3})",
            once.colour_evaluations, reference.colour_evaluations
        );
        assert!(
            gt_once >= gt_ref - MAX_COLOUR_ONCE_LOSS_DB,
            "K = {k}: {gt_once} against the reference's {gt_ref}"
        );
        closeness.push(to_reference);
    }
    assert!(closeness[1] >= closeness[0] - 0.05, "{closeness:?}");
    // Pixels without a ray stay black and empty.
    let once = render(Some(1));
    let no_ray = (0..w * h)
        .find(|p| !rays.pixels.contains(&(*p as u32)))
        .unwrap();
    assert_eq!(once.rgb[3 * no_ray..3 * no_ray + 3], [0.0; 3]);
    let _ = std::fs::remove_dir_all(&c.root);
}

/// The colour-once render may lose at most this against the truth, next to the per-sample
/// reference's PSNR on the same image (measured on this fixture: K = 1 23.30 against 23.49 dB,
/// K = 2 23.41; 38.3 and 40.6 dB against the reference's picture).
const MAX_COLOUR_ONCE_LOSS_DB: f64 = 0.4;

/// The density baked per pose (`[render] density_grid_m`) on the trained fixture, through the
/// one entry point every command renders through: baked once for the scene and reused by its
/// clones for every view (the same grid), then read at the samples. Against the per-sample
/// reference of the same image: opacity within a stated mean change, PSNR against the truth
/// within a stated loss, for the paper's per-sample colour and for colour once per ray; the
/// network runs only where colour is wanted; pixels without a ray stay black and empty.
#[test]
fn the_density_baked_per_pose_keeps_the_picture_and_is_baked_once() {
    let c = case("density-grid");
    let (image, mask_at_box, _) = c.target();
    let camera = image.camera;
    let input = c.input();
    let reference_options = RenderOptions::default();
    let prepare = |options: &RenderOptions| {
        prepare_scene(&c.model, &input, None, options, &c.device, None).unwrap()
    };
    fn view<'a>(
        camera: &'a Camera,
        body_box: &'a Aabb,
        pixels: Option<&'a [bool]>,
    ) -> TargetView<'a> {
        TargetView {
            camera,
            body_box,
            pixels,
            image: ImageRenderOptions {
                samples: 32,
                chunk: 512,
                timed: false,
            },
            cancelled: None,
        }
    }
    let body_box = c.scene.body_box;
    let render = |encoding: &SceneEncoding, options: &RenderOptions| {
        render_view(
            &c.model,
            encoding,
            &view(&camera, &body_box, Some(mask_at_box)),
            options,
            &mut |_, _| {},
        )
        .unwrap()
    };
    let reference = render(&prepare(&reference_options), &reference_options);
    let (w, h) = (reference.width, reference.height);
    let psnr = |a: &RenderedImage| {
        let v = ImageView::new("pred", &a.rgb, w, h, 3).unwrap();
        let t = ImageView::new("gt", &image.image, w, h, 3).unwrap();
        evaluate(&v, &t, mask_at_box, SsimOptions::nhp())
            .unwrap()
            .psnr
    };
    let gt_ref = psnr(&reference);
    for colour_points in [0, 1] {
        let options = RenderOptions {
            density_grid_m: DENSITY_GRID_M,
            colour_points,
            ..reference_options
        };
        let encoding = prepare(&options);
        assert!(
            encoding.density_memo.baked().is_none(),
            "nothing baked before a render"
        );
        let baked = render(&encoding, &options);
        let grid = encoding
            .density_memo
            .baked()
            .expect("the first render bakes the grid");
        // Another view of the same pose, from a clone (the viewer's pose cache, an orbit):
        // the same grid, not a new bake.
        let other = render_view(
            &c.model,
            &encoding.clone(),
            &view(&camera, &body_box, None),
            &options,
            &mut |_, _| {},
        )
        .unwrap();
        let again = encoding.density_memo.baked().unwrap();
        assert!(Arc::ptr_eq(&grid, &again), "one bake per pose");
        assert!(grid.evaluated() > 0 && grid.cell_m() == DENSITY_GRID_M);
        if colour_points == 0 {
            baked_visibility_is_close_to_the_nearest_face(&encoding, &grid, &input);
        }
        assert!(other.rgb.iter().chain(&baked.rgb).all(|x| x.is_finite()));
        let opacity_change = baked
            .acc
            .iter()
            .zip(&reference.acc)
            .map(|(a, b)| (a - b).abs())
            .sum::<f32>()
            / (w * h) as f32;
        let gt_baked = psnr(&baked);
        eprintln!(
            "colour points {colour_points}: PSNR {gt_baked:.3} dB against the reference's \
             {gt_ref:.3}; mean opacity change {opacity_change:.4}; {} network points against \
             {}; {} grid nodes",
            baked.point_evaluations,
            reference.point_evaluations,
            grid.evaluated()
        );
        assert!(
            opacity_change <= MAX_GRID_OPACITY_CHANGE,
            "{opacity_change}"
        );
        assert!(
            gt_baked >= gt_ref - MAX_DENSITY_GRID_LOSS_DB,
            "colour points {colour_points}: {gt_baked} against the reference's {gt_ref}"
        );
        // The network ran at the coloured points only: none of the density walk's.
        assert_eq!(baked.point_evaluations, baked.colour_evaluations);
        assert!(baked.point_evaluations < reference.point_evaluations);
        if colour_points == 1 {
            assert!(baked.colour_evaluations <= reference.rays as u64);
        }
        // Pixels without a ray stay black and empty.
        let no_ray = mask_at_box.iter().position(|&m| !m).unwrap();
        assert_eq!(baked.rgb[3 * no_ray..3 * no_ray + 3], [0.0; 3]);
        assert_eq!(baked.acc[no_ray], 0.0);
    }
    // A new occupancy grid (another pose's) starts a new memo.
    let moved = prepare(&reference_options).with_occupancy(None);
    assert!(moved.density_memo.baked().is_none());
    let _ = std::fs::remove_dir_all(&c.root);
}

/// The visibility baked with the density, read at points 5 mm off the posed body's vertices
/// (where the colour points lie), against the nearest-face visibility the colour half reads
/// without a grid: within [0, 1], and off by at most [`MAX_BAKED_VISIBILITY_ERROR`] on the
/// mean over views and points.
fn baked_visibility_is_close_to_the_nearest_face(
    encoding: &SceneEncoding,
    grid: &nia_model::renderer::density_grid::DensityGrid,
    input: &SceneInput,
) {
    let geometry = &encoding.geometry;
    let n = geometry.num_views();
    assert_eq!(grid.visibility_views(), n);
    let vertices = &input.body.vertices;
    let centre = vertices.iter().copied().sum::<Vec3>() / vertices.len() as f32;
    let points: Vec<Vec3> = vertices
        .iter()
        .step_by(5)
        .map(|&v| v + 0.005 * (v - centre).normalize_or_zero())
        .collect();
    let dirs = vec![Vec3::Z; points.len()];
    let exact = nia_data::scene::PointInputs::compute(geometry, &points, &dirs, None);
    let m = points.len();
    let mut o = vec![0.0f32; n];
    let mut error = 0.0f64;
    for (p, &x) in points.iter().enumerate() {
        grid.visibility_at(x, &mut o);
        for (view, &baked) in o.iter().enumerate() {
            assert!(
                (-1e-6..=1.0 + 1e-6).contains(&baked),
                "o_{view} = {baked} at {x}"
            );
            error += f64::from((baked - exact.visibility[view * m + p]).abs());
        }
    }
    let error = error / (m * n) as f64;
    eprintln!("baked visibility: mean |error| {error:.4} over {m} points and {n} views");
    assert!(error <= MAX_BAKED_VISIBILITY_ERROR, "{error}");
}

/// Mean |o_n| error of the baked visibility near the surface (measured: TBD).
const MAX_BAKED_VISIBILITY_ERROR: f64 = 0.1;

/// The baked density's node spacing in that test (the viewer's drag frames use 1 cm).
const DENSITY_GRID_M: f32 = 0.01;
/// Mean change of the opacity over the image with the baked density (measured: 0.0003).
const MAX_GRID_OPACITY_CHANGE: f32 = 0.005;
/// The baked-density render may lose at most this against the truth, next to the per-sample
/// reference's PSNR on the same image (measured: 23.49 dB with every sample coloured, 23.30 at
/// K = 1, against the reference's 23.49).
const MAX_DENSITY_GRID_LOSS_DB: f64 = 0.4;
