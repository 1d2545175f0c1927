#![allow(deprecated)] // Device::ndarray(): burn deprecates it, the user asked for it; it is the reference CPU backend.

//! The assembled network: shapes, finiteness, the variants' paths, any number of views,
//! gradients, and (with `--features wgpu`) the same numbers on wgpu as on ndarray.

mod common;

use std::sync::Arc;

use burn::prelude::*;
use nia_model::config::SourceColoursAt;
use nia_model::loss::render_loss;
use nia_model::renderer::termination::TERMINATION_SEGMENTS;
use nia_model::renderer::RenderOutput;
use nia_model::{ModelConfig, Variant};

const SAMPLES: usize = 8;

fn finite(t: &Tensor<2>) -> bool {
    t.clone()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap()
        .iter()
        .all(|x| x.is_finite())
}

#[test]
fn forward_renders_finite_colours_of_the_right_shape() {
    let device = Device::ndarray();
    device.seed(1);
    let input = common::scene(3, 32);
    let config = ModelConfig::tiny();
    let model = config.init(&device);
    let scene = model.encode(&input, None, &device, None).unwrap();
    assert_eq!(scene.pixel_rows.dims(), [3, config.d_model, 16, 16]);
    assert_eq!(
        scene.vertex_rows.dims(),
        [3, config.body_volume.vertex_channels, 16, 16]
    );
    let rays = common::target_rays(&input, 4);
    assert!(rays.len() >= 8, "most test rays hit the body box");
    let out = model.render(&scene, &rays, SAMPLES, None, None).unwrap();
    let r = rays.len();
    assert_eq!(out.rgb.dims(), [r, 3]);
    assert_eq!(out.rgb0.dims(), [r, 3]);
    assert_eq!(out.acc.dims(), [r]);
    let bw = out.blend_weights.clone().unwrap();
    assert_eq!(bw.dims(), [r, 4]);
    assert!(finite(&out.rgb) && finite(&out.rgb0) && finite(&bw));
    let rgb = out.rgb.into_data().try_to_vec::<f32>().unwrap();
    assert!(
        rgb.iter().all(|&c| (0.0..=1.0 + 1e-5).contains(&c)),
        "colours in [0, 1]"
    );
    // Accumulated blend weights equal the accumulated opacity (softmax rows sum to 1).
    let acc = out.acc.into_data().try_to_vec::<f32>().unwrap();
    let bw_sum = bw.sum_dim(1).into_data().try_to_vec::<f32>().unwrap();
    for (a, b) in acc.iter().zip(&bw_sum) {
        assert!((a - b).abs() < 1e-4, "acc {a} vs blend weight sum {b}");
    }
}

#[test]
fn variant_b_colour_is_the_nerf_colour_and_variant_a_has_no_body_volume() {
    let device = Device::ndarray();
    let input = common::scene(3, 32);
    for variant in [Variant::NoIbr, Variant::NoBody] {
        device.seed(2);
        let config = ModelConfig::tiny().with_variant(variant);
        let model = config.init(&device);
        let scene = model.encode(&input, None, &device, None).unwrap();
        assert_eq!(scene.volume.is_some(), variant.uses_body());
        let rays = common::target_rays(&input, 3);
        let out = model.render(&scene, &rays, SAMPLES, None, None).unwrap();
        if variant == Variant::NoIbr {
            let diff = (out.rgb - out.rgb0).abs().max().into_scalar::<f32>();
            assert!(
                diff < 1e-6,
                "variant (b): rgb must equal the c0 composite, max diff {diff}"
            );
        } else {
            assert!(finite(&out.rgb));
        }
    }
}

#[test]
fn any_number_of_source_views_runs_with_the_same_weights() {
    let (device, model) = common::tiny_model(3);
    for n in [1, 2, 4] {
        let input = common::scene(n, 32);
        let scene = model.encode(&input, None, &device, None).unwrap();
        let rays = common::target_rays(&input, 2);
        let out = model.render(&scene, &rays, SAMPLES, None, None).unwrap();
        assert_eq!(out.blend_weights.unwrap().dims(), [rays.len(), n + 1]);
        assert!(finite(&out.rgb));
    }
}

#[test]
fn a_training_step_has_finite_gradients_everywhere_it_should() {
    training_step_gradients(None);
}

/// The same with source colours read at the expected surface point.
#[test]
fn a_surface_training_step_has_finite_gradients() {
    training_step_gradients(Some(SourceColoursAt::Surface));
}

fn training_step_gradients(at: Option<SourceColoursAt>) {
    let device = Device::ndarray().autodiff();
    device.seed(4);
    let config = ModelConfig::tiny().with_source_colours_at(at);
    let model = config.init(&device);
    let input = common::scene(3, 32);
    let scene = model.encode(&input, None, &device, None).unwrap();
    let rays = common::target_rays(&input, 3);
    let jitter: Vec<f32> = (0..rays.len() * SAMPLES)
        .map(|i| ((i * 37) % 100) as f32 / 100.0)
        .collect();
    let out = model
        .render(&scene, &rays, SAMPLES, Some(&jitter), None)
        .unwrap();
    let gt = Tensor::<2>::ones([rays.len(), 3], &device).mul_scalar(0.5);
    let loss = render_loss(out.rgb, out.rgb0, gt).unwrap().total;
    let grads = loss.backward();
    fn check<const D: usize>(name: &str, w: Tensor<D>, grads: &burn::tensor::Gradients) {
        let g = w
            .grad(grads)
            .unwrap_or_else(|| panic!("{name} has no gradient"));
        let g = g.into_data().try_to_vec::<f32>().unwrap();
        assert!(
            g.iter().all(|x| x.is_finite()),
            "{name}: non-finite gradient"
        );
        assert!(g.iter().any(|&x| x != 0.0), "{name}: gradient is all zero");
    }
    check("encoder.conv1", model.encoder.conv1.weight.val(), &grads);
    check("vertex_reduce", model.vertex_reduce.weight.val(), &grads);
    check("body_reduce", model.body_reduce.weight.val(), &grads);
    check(
        "blender.token_input",
        model.blender.token_input.weight.val(),
        &grads,
    );
    check("density", model.density.layers[0].weight.val(), &grads);
}

/// ndarray and wgpu agree on the same weights and inputs. Values pass through ~30 layers in
/// f32 with different reduction orders: 1e-3 absolute on colours in [0, 1].
#[cfg(feature = "wgpu")]
const BACKEND_TOLERANCE: f32 = 1e-3;

#[cfg(feature = "wgpu")]
#[test]
fn wgpu_matches_ndarray() {
    let Some(gpu) = common::wgpu_device() else {
        return;
    };
    let cpu = Device::ndarray();
    cpu.seed(5);
    let config = ModelConfig::tiny();
    let mut model = config.init(&cpu);
    let mut model_gpu = model.clone().to_device(&gpu);
    let input = common::scene(3, 32);
    let rays = common::target_rays(&input, 3);
    // Plain, and front to back with termination and colour culling (the renderer's two
    // paths; on wgpu both pad their network calls to shape buckets), in one network call or
    // in calls of `call` points (`SceneEncoding::points_per_call`; on wgpu each call padded).
    let run = |m: &nia_model::NiaModel, d: &Device, adaptive: bool, call: Option<usize>| {
        let mut scene = m.encode(&input, None, d, None).unwrap();
        if let Some(call) = call {
            scene = scene.with_points_per_call(call);
        }
        if adaptive {
            scene = scene
                .with_termination(Some(1e-3))
                .with_colour_culling(Some(0.05));
        }
        let out = m.render(&scene, &rays, SAMPLES, None, None).unwrap();
        // The adaptive run culls colours (the padded selection path on wgpu).
        assert_eq!(
            out.colour_evaluations < out.point_evaluations,
            adaptive,
            "{} colour evaluations of {} points",
            out.colour_evaluations,
            out.point_evaluations
        );
        (
            out.rgb.into_data().try_to_vec::<f32>().unwrap(),
            out.acc.into_data().try_to_vec::<f32>().unwrap(),
            out.point_evaluations,
        )
    };
    // Source colours per sample (the paper) and at the expected surface point.
    for (at, adaptive) in [
        (SourceColoursAt::Samples, false),
        (SourceColoursAt::Surface, false),
        (SourceColoursAt::Surface, true),
    ] {
        model.source_colours_at = at;
        model_gpu.source_colours_at = at;
        let (rgb_cpu, acc_cpu, points) = run(&model, &cpu, adaptive, None);
        // The points depend on the random weights (other tests draw from the same seed):
        // calls of a quarter of them, so that the render takes at least four calls.
        assert!(points >= 4, "{points} points");
        for call in [None, Some(points / 4)] {
            let (rgb_gpu, acc_gpu, _) = run(&model_gpu, &gpu, adaptive, call);
            let max_diff = max_abs_diff(&rgb_cpu, &rgb_gpu).max(max_abs_diff(&acc_cpu, &acc_gpu));
            assert!(
                max_diff <= BACKEND_TOLERANCE,
                "{at:?} (adaptive: {adaptive}, calls of {call:?} points): ndarray vs wgpu \
                 max difference {max_diff}"
            );
        }
    }
    // Colour once per ray on the density baked per pose (the bake's density calls, the
    // trilinear reads and the host composite), per-sample and surface source colours.
    let body_box = nia_data::dataset::sampling::BoxPadding::nhp()
        .body_box(&input.body.vertices)
        .unwrap();
    let baked = |m: &nia_model::NiaModel, d: &Device| {
        let scene = m.encode(&input, None, d, None).unwrap();
        let grid = m.bake_density(&scene, &body_box, 0.05).unwrap();
        assert!(grid.evaluated() > 0);
        let scene = scene
            .with_density_grid(Some(grid))
            .with_colour_points(Some(1));
        let out = m.render(&scene, &rays, SAMPLES, None, None).unwrap();
        assert!(out.colour_evaluations <= rays.len());
        [out.rgb, out.rgb0]
            .map(|t| t.into_data().try_to_vec::<f32>().unwrap())
            .into_iter()
            .chain([out.acc.into_data().try_to_vec::<f32>().unwrap()])
            .collect::<Vec<_>>()
    };
    for at in [SourceColoursAt::Samples, SourceColoursAt::Surface] {
        model.source_colours_at = at;
        model_gpu.source_colours_at = at;
        let (a, b) = (baked(&model, &cpu), baked(&model_gpu, &gpu));
        for (x, y) in a.iter().zip(&b) {
            let max_diff = max_abs_diff(x, y);
            assert!(
                max_diff <= BACKEND_TOLERANCE,
                "{at:?}, baked density: ndarray vs wgpu max difference {max_diff}"
            );
        }
    }
    // Whole images through `render_image`: on the GPU in its default chunk
    // (`renderer::call_size`, far more rays than the CPU's), on the CPU in chunks of 2 rays;
    // each chunk's columns come back in one read.
    use nia_model::render_options::RenderOptions;
    use nia_model::renderer::call_size::{gpu_rays_per_chunk, rays_per_chunk, MIN_RAYS_PER_CHUNK};
    use nia_model::renderer::image::{render_image, ImageRenderOptions};
    let gpu_chunk = rays_per_chunk(&gpu, SAMPLES, &RenderOptions::default());
    assert_eq!(gpu_chunk, gpu_rays_per_chunk(SAMPLES));
    assert!(gpu_chunk > MIN_RAYS_PER_CHUNK && gpu_chunk > rays.len());
    let image = |m: &nia_model::NiaModel, d: &Device, chunk: usize| {
        let scene = m
            .encode(&input, None, d, None)
            .unwrap()
            .with_termination(Some(1e-3))
            .with_colour_culling(Some(0.05));
        let options = ImageRenderOptions {
            samples: SAMPLES,
            chunk,
            timed: false,
        };
        render_image(m, &scene, &rays, [64, 64], options, &mut |_, _| {}).unwrap()
    };
    let (a, b) = (image(&model, &cpu, 2), image(&model_gpu, &gpu, gpu_chunk));
    assert_eq!(a.point_evaluations, b.point_evaluations);
    for (x, y, what) in [
        (&a.rgb, &b.rgb, "colour"),
        (&a.rgb0, &b.rgb0, "NeRF colour"),
        (&a.rgb_ibr, &b.rgb_ibr, "IBR-only colour"),
        (&a.acc, &b.acc, "opacity"),
        (&a.blend_weights, &b.blend_weights, "blend weights"),
    ] {
        let max_diff = max_abs_diff(x, y);
        assert!(
            max_diff <= BACKEND_TOLERANCE,
            "image {what}: ndarray vs wgpu max difference {max_diff}"
        );
    }
}

/// The largest |a - b| over the pairs of `a` and `b`.
fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max)
}

/// The gradient of `w` in `grads`, flattened to host values.
#[cfg(feature = "wgpu")]
fn grad_values<const D: usize>(w: Tensor<D>, grads: &burn::tensor::Gradients) -> Vec<f32> {
    w.grad(grads)
        .unwrap()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap()
}

/// A training forward and backward on wgpu against ndarray: with empty-space skipping the
/// field's points are padded to a shape bucket there and the scatter sends the padding to a
/// spare row (`renderer::shape_buckets`), and with c0 shuffling the points draw the same
/// donors as unpadded. The loss and the gradients of the encoder, the body volume, F_sigma and
/// F_B agree.
#[cfg(feature = "wgpu")]
#[test]
fn wgpu_training_gradients_match_ndarray() {
    use nia_data::geometry::occupancy::OccupancyGrid;
    use nia_model::ibr::c0_shuffle::C0Shuffle;
    use nia_model::renderer::shape_buckets::bucket_len;
    let Some(gpu) = common::wgpu_device() else {
        return;
    };
    let cpu = Device::ndarray().autodiff();
    cpu.seed(6);
    let config = ModelConfig::tiny().with_source_colours_at(Some(SourceColoursAt::Surface));
    let model = config.init(&cpu);
    let input = common::scene(3, 32);
    let rays = common::target_rays(&input, 3);
    let grid = Arc::new(
        OccupancyGrid::build(&input.body.vertices, &input.body.faces, 0.02, 0.02).unwrap(),
    );
    let jitter: Vec<f32> = (0..rays.len() * SAMPLES)
        .map(|i| ((i * 37) % 100) as f32 / 100.0)
        .collect();
    let gt = |d: &Device| Tensor::<2>::ones([rays.len(), 3], d).mul_scalar(0.5);
    let run = |model: &nia_model::NiaModel, d: &Device| {
        let scene = model
            .encode(&input, None, d, None)
            .unwrap()
            .with_occupancy(Some(grid.clone()))
            .with_c0_shuffle(Some(C0Shuffle {
                fraction: 0.5,
                seed: 7,
                seen_only: false,
                noise_std: 0.0,
            }));
        let out = model
            .render(&scene, &rays, SAMPLES, Some(&jitter), None)
            .unwrap();
        let evaluated = out.point_evaluations;
        let loss = render_loss(out.rgb, out.rgb0, gt(d)).unwrap().total;
        let value = loss.clone().into_scalar::<f32>();
        let grads = loss.backward();
        let named = vec![
            (
                "encoder.conv1",
                grad_values(model.encoder.conv1.weight.val(), &grads),
            ),
            (
                "body volume, first conv",
                grad_values(model.body_volume.full[0].conv.weight.val(), &grads),
            ),
            (
                "density",
                grad_values(model.density.layers[0].weight.val(), &grads),
            ),
            (
                "blender.token_input",
                grad_values(model.blender.token_input.weight.val(), &grads),
            ),
        ];
        (value, evaluated, named)
    };
    let (loss_cpu, evaluated, grads_cpu) = run(&model, &cpu);
    let total = rays.len() * SAMPLES;
    assert!(
        evaluated > 0 && evaluated < total && bucket_len(evaluated) > evaluated,
        "{evaluated} of {total} samples evaluated: the test needs skipping and a count to pad"
    );
    let gpu_ad = gpu.autodiff();
    let (loss_gpu, evaluated_gpu, grads_gpu) = run(&model.clone().fork(&gpu_ad), &gpu_ad);
    assert_eq!(evaluated_gpu, evaluated);
    assert!(
        (loss_cpu - loss_gpu).abs() <= 1e-4 * loss_cpu.abs().max(1.0),
        "loss: ndarray {loss_cpu}, wgpu {loss_gpu}"
    );
    for ((name, a), (_, b)) in grads_cpu.iter().zip(&grads_gpu) {
        let scale = a.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        let diff = a
            .iter()
            .zip(b)
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(scale > 0.0, "{name}: zero gradient");
        assert!(
            diff <= 2e-3 * scale,
            "{name}: ndarray vs wgpu gradients differ by {diff} (largest {scale})"
        );
    }
}

#[test]
fn reposed_rendering_is_the_plain_path_for_the_same_pose_and_finite_for_another() {
    use nia_data::body::reposing::Reposer;
    use nia_data::body::{pose_for_motion, MotionKind, ProceduralBody, ProceduralSpec, SmplParams};
    let (device, model) = common::tiny_model(6);
    let input = common::scene(3, 32);
    let spec = ProceduralSpec {
        target_vertices: 1500,
        ..ProceduralSpec::default()
    };
    let body = ProceduralBody::generate(&spec).unwrap();
    let reference = SmplParams::default();
    let rays = common::target_rays(&input, 3);

    // Same pose: identical numbers to the novel-view path.
    let same = Reposer::new(&body, &reference, &reference).unwrap();
    assert!(same.is_identity() && !Reposer::needed(&reference, &reference));
    let scene = model.encode(&input, None, &device, None).unwrap();
    let plain = model.render(&scene, &rays, SAMPLES, None, None).unwrap();
    let same_scene = model
        .encode(&input, Some(Arc::new(same)), &device, None)
        .unwrap();
    assert!(
        same_scene.reposer.is_none(),
        "an identity reposer is dropped"
    );
    let reposed = model
        .render(&same_scene, &rays, SAMPLES, None, None)
        .unwrap();
    let diff = (plain.rgb - reposed.rgb).abs().max().into_scalar::<f32>();
    assert_eq!(diff, 0.0, "the identity reposing must be the plain path");

    // Another pose: the body volume moves to the target vertices, the images stay.
    let target = SmplParams {
        poses: pose_for_motion(0.4, MotionKind::Walk),
        ..SmplParams::default()
    };
    assert!(Reposer::needed(&reference, &target));
    let reposer = Arc::new(Reposer::new(&body, &reference, &target).unwrap());
    let scene = model
        .encode(&input, Some(reposer.clone()), &device, None)
        .unwrap();
    assert!(scene.reposer.is_some());
    // The same pose reached from the plain encoding (animation's path) renders the same.
    let from_plain = model
        .encode_pose(
            &model.encode(&input, None, &device, None).unwrap(),
            reposer,
            None,
        )
        .unwrap();
    let out = model.render(&scene, &rays, SAMPLES, None, None).unwrap();
    let again = model
        .render(&from_plain, &rays, SAMPLES, None, None)
        .unwrap();
    let diff = (out.rgb.clone() - again.rgb)
        .abs()
        .max()
        .into_scalar::<f32>();
    assert_eq!(
        diff, 0.0,
        "encode with a reposer == encode_pose of the plain encoding"
    );
    assert_eq!(out.rgb.dims(), [rays.len(), 3]);
    assert!(finite(&out.rgb) && finite(&out.rgb0));
}

#[test]
fn model_config_round_trips_through_json_with_paper_defaults() {
    let config = ModelConfig::new().with_variant(Variant::CosineWeighted);
    let json = serde_json::to_string(&config).unwrap();
    assert!(
        json.contains("\"cosine_weighted\""),
        "variants serialise by their config names: {json}"
    );
    let back: ModelConfig = serde_json::from_str(&json).unwrap();
    assert_eq!(back.variant, Variant::CosineWeighted);
    assert_eq!(back.d_model, 128);
    assert_eq!(back.voxel_size_m, 0.005, "paper voxel size");
    assert_eq!(back.box_enlarge, 0.025, "paper box growth");
    assert_eq!(
        back.image_channels(),
        512,
        "ResNet-18 pyramid: 64 + 64 + 128 + 256"
    );
}

/// Model files and checkpoints written before `source_colours_at` existed have no such key:
/// they still load, reading source colours per sample (the paper's form).
#[test]
fn configs_without_the_surface_switch_load_as_the_papers_per_sample_form() {
    let config = ModelConfig::tiny().with_source_colours_at(Some(SourceColoursAt::Surface));
    let mut value = serde_json::to_value(&config).unwrap();
    assert_eq!(value["source_colours_at"], "surface");
    value.as_object_mut().unwrap().remove("source_colours_at");
    let old: ModelConfig = serde_json::from_value(value).unwrap();
    assert_eq!(old.source_colours_at, None);
    let model = old.init(&common::device());
    assert_eq!(model.source_colours_at, SourceColoursAt::Samples);
}

/// One output of a render as a flat list: `rgb`, `rgb0`, `blend` (the blend weights), `acc` or
/// `depth`.
fn channel(r: &RenderOutput, name: &str) -> Vec<f32> {
    let flat = |data: TensorData| data.try_to_vec::<f32>().unwrap();
    match name {
        "rgb" => flat(r.rgb.to_data()),
        "rgb0" => flat(r.rgb0.to_data()),
        "blend" => flat(r.blend_weights.as_ref().unwrap().to_data()),
        "acc" => flat(r.acc.to_data()),
        "depth" => flat(r.depth.to_data()),
        other => panic!("no output {other}"),
    }
}

/// Asserts that two renders of the same rays agree: every value of each named output finite
/// in both and within the output's bound (plus 1e-5 of float slack).
fn assert_renders_agree(a: &RenderOutput, b: &RenderOutput, bounds: &[(&str, f32)], case: &str) {
    for &(what, bound) in bounds {
        let (a, b) = (channel(a, what), channel(b, what));
        assert_eq!(a.len(), b.len(), "{case}: {what}");
        for (i, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!(x.is_finite() && y.is_finite(), "{case}: {what}[{i}]");
            assert!(
                (x - y).abs() <= bound + 1e-5,
                "{case}: {what}[{i}] {x} vs {y}"
            );
        }
    }
}

/// Early ray termination: with densities that make rays opaque part-way (a density shift of
/// the tiny network's F_sigma), rays stop evaluating once their transmittance is below epsilon;
/// colour, opacity and depth change by at most about epsilon (times the largest colour or
/// depth), and a jittered (training) render evaluates every sample.
#[test]
fn early_termination_skips_what_the_front_hides_within_epsilon() {
    let (device, mut model) = common::tiny_model(6);
    let input = common::scene(3, 32);
    let rays = common::target_rays(&input, 4);
    let samples = 32;
    for (shift, expect_cut) in [(-1.0, false), (30.0, true), (2000.0, true)] {
        model.density.density_shift = shift;
        let scene = model.encode(&input, None, &device, None).unwrap();
        let full = model.render(&scene, &rays, samples, None, None).unwrap();
        let epsilon = 1e-3;
        let terminated = scene.clone().with_termination(Some(epsilon));
        let cut = model
            .render(&terminated, &rays, samples, None, None)
            .unwrap();
        let all = rays.len() * samples;
        assert_eq!(full.point_evaluations, all);
        assert!(cut.point_evaluations <= all);
        if expect_cut {
            assert!(
                cut.point_evaluations < all,
                "shift {shift}: nothing skipped ({} of {all})",
                cut.point_evaluations
            );
        }
        if shift > 1000.0 {
            // Opaque at the first sample: only the first segment is evaluated.
            assert_eq!(
                cut.point_evaluations,
                all / TERMINATION_SEGMENTS,
                "shift {shift}"
            );
        }
        let far = rays.far.iter().cloned().fold(0.0f32, f32::max);
        let bounds = [("rgb", epsilon), ("acc", epsilon), ("depth", epsilon * far)];
        assert_renders_agree(&full, &cut, &bounds, &format!("shift {shift}"));
        // Training renders (jittered) never terminate early.
        let jitter = vec![0.5f32; all];
        let trained = model
            .render(&terminated, &rays, samples, Some(&jitter), None)
            .unwrap();
        assert_eq!(trained.point_evaluations, all);
    }
}

/// Colour culling: the colour half of the network runs only on samples whose weight matters.
/// With densities that make rays opaque part-way or at once, fewer samples get a colour;
/// opacity and depth do not move (the densities are the same), the colour, the NeRF colour and
/// the blend maps move by at most the budget per ray, in both colour forms (per sample and at
/// the surface) and together with early termination. A jittered (training) render colours
/// every sample.
#[test]
fn colour_culling_colours_only_samples_that_carry_weight_within_the_budget() {
    let device = common::device();
    device.seed(11);
    let input = common::scene(3, 32);
    let rays = common::target_rays(&input, 4);
    let samples = 32;
    let all = rays.len() * samples;
    let budget = 1e-3;
    for at in [SourceColoursAt::Samples, SourceColoursAt::Surface] {
        let mut model = ModelConfig::tiny()
            .with_source_colours_at(Some(at))
            .init(&device);
        for (shift, expect_cut) in [(-1.0, false), (30.0, true), (2000.0, true)] {
            model.density.density_shift = shift;
            let scene = model.encode(&input, None, &device, None).unwrap();
            let full = model.render(&scene, &rays, samples, None, None).unwrap();
            assert_eq!(full.colour_evaluations, all);
            for termination in [None, Some(1e-3)] {
                let culled_scene = scene
                    .clone()
                    .with_termination(termination)
                    .with_colour_culling(Some(budget));
                let culled = model
                    .render(&culled_scene, &rays, samples, None, None)
                    .unwrap();
                let case = format!("{at:?}, shift {shift}, termination {termination:?}");
                assert!(
                    culled.colour_evaluations <= culled.point_evaluations,
                    "{case}"
                );
                if termination.is_none() {
                    assert_eq!(culled.point_evaluations, all, "{case}");
                }
                if expect_cut {
                    assert!(
                        culled.colour_evaluations < culled.point_evaluations,
                        "{case}: nothing culled ({} of {})",
                        culled.colour_evaluations,
                        culled.point_evaluations
                    );
                }
                if shift > 1000.0 {
                    // Opaque at the first sample: about one colour per ray.
                    assert!(culled.colour_evaluations <= 2 * rays.len(), "{case}");
                }
                // Early termination moves colour and opacity by up to its epsilon as well.
                let slack = termination.unwrap_or(0.0);
                let far = rays.far.iter().cloned().fold(0.0f32, f32::max);
                let colour = budget + slack;
                let bounds = [
                    ("rgb", colour),
                    ("rgb0", colour),
                    ("blend", colour),
                    ("acc", slack),
                    ("depth", slack * far),
                ];
                assert_renders_agree(&full, &culled, &bounds, &case);
            }
            // Training renders (jittered) colour every sample.
            let jitter = vec![0.5f32; all];
            let trained = model
                .render(
                    &scene.clone().with_colour_culling(Some(budget)),
                    &rays,
                    samples,
                    Some(&jitter),
                    None,
                )
                .unwrap();
            assert_eq!(trained.colour_evaluations, all);
        }
    }
}

/// The body volume read on the host (the CPU backends' inference default) renders what the
/// tensor read renders, in the scene's own pose and reposed (the host copy follows the pose's
/// rebuilt volume).
#[test]
fn host_body_reads_render_what_the_tensor_reads_render() {
    use nia_data::body::reposing::Reposer;
    use nia_data::body::{pose_for_motion, MotionKind, ProceduralBody, ProceduralSpec, SmplParams};
    let (device, model) = common::tiny_model(12);
    let input = common::scene(3, 32);
    let rays = common::target_rays(&input, 4);
    let to_vec2 = |t: Tensor<2>| t.into_data().try_to_vec::<f32>().unwrap();
    let scene = model.encode(&input, None, &device, None).unwrap();
    assert!(
        scene.host_volume.is_some(),
        "a CPU device reads on the host"
    );
    let tensor_scene = scene.clone().with_host_reads(&model, false).unwrap();
    assert!(tensor_scene.host_volume.is_none());
    let compare = |a: &nia_model::SceneEncoding, b: &nia_model::SceneEncoding, what: &str| {
        let x = model.render(a, &rays, SAMPLES, None, None).unwrap();
        let y = model.render(b, &rays, SAMPLES, None, None).unwrap();
        for (i, (p, q)) in to_vec2(x.rgb).iter().zip(&to_vec2(y.rgb)).enumerate() {
            assert!(
                p.is_finite() && (p - q).abs() <= 1e-5,
                "{what}: rgb[{i}] {p} vs {q}"
            );
        }
    };
    compare(&scene, &tensor_scene, "own pose");
    let body = ProceduralBody::generate(&ProceduralSpec {
        target_vertices: 1500,
        ..ProceduralSpec::default()
    })
    .unwrap();
    let target = SmplParams {
        poses: pose_for_motion(0.4, MotionKind::Walk),
        ..SmplParams::default()
    };
    let reposer = Arc::new(Reposer::new(&body, &SmplParams::default(), &target).unwrap());
    let reposed = model.encode_pose(&scene, reposer.clone(), None).unwrap();
    assert!(reposed.host_volume.is_some());
    let reposed_tensor = model.encode_pose(&tensor_scene, reposer, None).unwrap();
    assert!(reposed_tensor.host_volume.is_none());
    compare(&reposed, &reposed_tensor, "reposed");
}

/// One scene's render without and with c0 shuffling of every point (fraction 1, seed 5).
fn render_plain_and_shuffled(
    model: &nia_model::NiaModel,
    device: &Device,
) -> (RenderOutput, RenderOutput, usize) {
    use nia_model::ibr::c0_shuffle::C0Shuffle;
    let input = common::scene(3, 32);
    let scene = model.encode(&input, None, device, None).unwrap();
    let rays = common::target_rays(&input, 3);
    let jitter = vec![0.5f32; rays.len() * SAMPLES];
    let plain = model
        .render(&scene, &rays, SAMPLES, Some(&jitter), None)
        .unwrap();
    let shuffled_scene = scene.with_c0_shuffle(Some(C0Shuffle {
        fraction: 1.0,
        seed: 5,
        seen_only: false,
        noise_std: 0.0,
    }));
    let shuffled = model
        .render(&shuffled_scene, &rays, SAMPLES, Some(&jitter), None)
        .unwrap();
    (plain, shuffled, rays.len())
}

/// c0 shuffling is F_B's augmentation: the variants that mix c0 by a fixed rule or show it as
/// it is ((b), (c), (d)) render exactly the same with it on.
#[test]
fn c0_shuffling_leaves_the_fixed_rule_variants_alone() {
    let device = Device::ndarray();
    for variant in [
        Variant::NoIbr,
        Variant::SimpleAverage,
        Variant::CosineWeighted,
    ] {
        device.seed(8);
        let model = ModelConfig::tiny().with_variant(variant).init(&device);
        let (plain, shuffled, _) = render_plain_and_shuffled(&model, &device);
        let v = |t: Tensor<2>| t.into_data().try_to_vec::<f32>().unwrap();
        let plain = v(plain.rgb);
        assert!(plain.iter().all(|x| x.is_finite()), "{variant:?}");
        assert!(plain.iter().any(|&x| x > 0.0), "{variant:?}: black render");
        assert_eq!(plain, v(shuffled.rgb), "{variant:?}");
    }
}

/// c0 shuffling (training augmentation): the blend reads other points' c0, so the colour
/// changes while the NeRF-only composite (the true c0) does not, and gradients stay finite and
/// reach F_c0 and F_B.
#[test]
fn c0_shuffling_changes_the_blend_but_not_the_nerf_composite() {
    let device = Device::ndarray().autodiff();
    device.seed(8);
    let config = ModelConfig::tiny().with_source_colours_at(Some(SourceColoursAt::Surface));
    let model = config.init(&device);
    let (plain, shuffled, n_rays) = render_plain_and_shuffled(&model, &device);
    let v = |t: Tensor<2>| t.into_data().try_to_vec::<f32>().unwrap();
    assert_eq!(v(plain.rgb0.clone()), v(shuffled.rgb0.clone()));
    let moved = max_abs_diff(&v(plain.rgb.clone()), &v(shuffled.rgb.clone()));
    assert!(moved > 1e-6, "shuffling did not change the blend");
    let gt = Tensor::<2>::ones([n_rays, 3], &device).mul_scalar(0.5);
    let grads = render_loss(shuffled.rgb, shuffled.rgb0, gt)
        .unwrap()
        .total
        .backward();
    for (name, w) in [
        ("colour head", model.colour.layers[0].weight.val()),
        ("blender", model.blender.token_input.weight.val()),
    ] {
        let g = w
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert!(g.iter().all(|x| x.is_finite()), "{name}");
        assert!(g.iter().any(|&x| x != 0.0), "{name}: no gradient");
    }
}

/// The person masks the visual hull reads are checked with the rest of the scene: a mask of
/// the wrong size or with a value outside [0, 1] is an error naming the view, and a hull
/// built from another scene's views is refused.
#[test]
fn bad_person_masks_are_errors_naming_the_view() {
    let device = Device::ndarray();
    let model = ModelConfig::tiny().init(&device);
    let good = common::scene(3, 16);
    let mut short = good.clone();
    short.views[1].mask.pop();
    let mut nan = good.clone();
    nan.views[2].mask[5] = f32::NAN;
    for (input, field) in [(short, "views[1].mask"), (nan, "views[2].mask")] {
        let err = model.encode(&input, None, &device, None).unwrap_err();
        assert!(err.to_string().contains(field), "{err}");
    }
    let encoded = model.encode(&good, None, &device, None).unwrap();
    let mut fewer = good.clone();
    fewer.views.pop();
    let err = encoded
        .clone()
        .with_visual_hull(&fewer, true, None)
        .unwrap_err();
    assert!(err.to_string().contains("visual hull"), "{err}");
    assert!(encoded
        .with_visual_hull(&good, false, None)
        .unwrap()
        .visual_hull
        .is_none());
}
