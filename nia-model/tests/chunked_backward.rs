//! The chunked backward (`nia_model::scene_encoding::cut`): the rays of a scene in chunks,
//! each with its own backward, and the encoder's share through the cut, give the gradient of
//! one backward over all rays, for every parameter (the encoder's, the body volume's and the
//! render side's), on ndarray and flex; bad jitter is an error. Burn's gradient checkpointing
//! (`Device::gradient_checkpointing`, `train.gradient_checkpointing`) gives the same gradient,
//! with and without chunks.

mod common;

use std::collections::HashMap;

use burn::module::{Module, ModuleVisitor, Param, ParamId};
use burn::optim::GradientsParams;
use burn::prelude::*;
use nia_model::loss::render_loss;
use nia_model::scene_encoding::cut::chunked_gradients;
use nia_model::{ModelConfig, ModelError, NiaModel};

const SAMPLES: usize = 8;

/// Every parameter's gradient, read back, by parameter id.
struct Collect<'a> {
    grads: &'a GradientsParams,
    out: HashMap<ParamId, Vec<f32>>,
}

impl ModuleVisitor for Collect<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.get::<D>(param.id) {
            self.out
                .insert(param.id, g.into_data().try_to_vec::<f32>().unwrap());
        }
    }
}

fn collect(model: &NiaModel, grads: &GradientsParams) -> HashMap<ParamId, Vec<f32>> {
    let mut c = Collect {
        grads,
        out: HashMap::new(),
    };
    model.visit(&mut c);
    c.out
}

/// The gradient of `model`'s mean loss over 9 rays, taken in chunks of `chunk` (0: all at
/// once).
fn gradients(model: &NiaModel, device: &Device, chunk: usize) -> HashMap<ParamId, Vec<f32>> {
    let input = common::scene(3, 32);
    let scene = model.encode(&input, None, device, None).unwrap();
    let rays = common::target_rays(&input, 3);
    let n = rays.len();
    assert_eq!(n, 9, "every ray of the 3 x 3 grid hits the box");
    let jitter: Vec<f32> = (0..n * SAMPLES)
        .map(|i| ((i * 37) % 100) as f32 / 100.0)
        .collect();
    let gt: Vec<f32> = (0..n * 3).map(|i| (i % 7) as f32 / 7.0).collect();
    let gt = common::tensor(gt, [n, 3], device);
    let grads = chunked_gradients::<ModelError, _>(
        model,
        &scene,
        &rays,
        SAMPLES,
        Some(&jitter),
        chunk,
        |out, range| {
            let share = range.len() as f32 / n as f32;
            let gt = gt.clone().slice([range, 0..3]);
            Ok(render_loss(out.rgb, out.rgb0, gt)
                .map_err(ModelError::Shape)?
                .total
                .mul_scalar(share))
        },
    )
    .unwrap();
    collect(model, &grads)
}

/// Asserts that every parameter's gradient in `got` is finite and within `tolerance` of
/// `expected`'s, on the scale of that parameter's largest entry (or of 1e-3 of the largest
/// gradient of all, for parameters whose whole gradient is rounding noise).
fn assert_gradients_match(
    got: &HashMap<ParamId, Vec<f32>>,
    expected: &HashMap<ParamId, Vec<f32>>,
    tolerance: f32,
    what: &str,
) {
    assert_eq!(
        got.len(),
        expected.len(),
        "{what}: every parameter with a gradient has one"
    );
    let global = expected
        .values()
        .flatten()
        .fold(0.0f32, |m, x| m.max(x.abs()));
    for (id, want) in expected {
        let scale = want
            .iter()
            .fold(0.0f32, |m, x| m.max(x.abs()))
            .max(1e-3 * global);
        for (i, (g, e)) in got[id].iter().zip(want).enumerate() {
            assert!(g.is_finite(), "{what}: non-finite gradient");
            assert!(
                (g - e).abs() <= tolerance * scale,
                "{what}: parameter {id}, entry {i}: {g} against {e} (largest {scale})"
            );
        }
    }
}

#[allow(deprecated)] // Device::ndarray(): the reference CPU backend the project keeps
fn devices() -> Vec<Device> {
    vec![Device::ndarray().autodiff(), Device::flex().autodiff()]
}

#[test]
fn chunked_gradients_equal_one_backward_over_all_rays() {
    for device in devices() {
        device.seed(11);
        let model = ModelConfig::tiny().init(&device);
        let whole = gradients(&model, &device, 0);
        // The encoder's first convolution and the body volume's first layer get their
        // gradient only through the cut; the heads' directly.
        let through_cut = [
            model.encoder.conv1.weight.id,
            model.pixel_feature.reduce.weight.id,
        ];
        for id in through_cut {
            let g = whole.get(&id).expect("a gradient without chunks");
            assert!(
                g.iter().any(|&x| x != 0.0),
                "an all-zero reference gradient"
            );
        }
        // Parameters whose whole gradient is rounding noise (1e-11 where others are 1e-2) are
        // compared on the scale of the largest gradient.
        for chunk in [2, 4, 8] {
            let chunked = gradients(&model, &device, chunk);
            assert_gradients_match(&chunked, &whole, 1e-4, &format!("chunks of {chunk}"));
        }
    }
}

#[test]
fn gradient_checkpointing_gives_the_same_gradient_whole_and_chunked() {
    for device in devices() {
        device.seed(5);
        let model = ModelConfig::tiny().init(&device);
        let checkpointed = device.clone().gradient_checkpointing();
        // The same weights on the checkpointing device (a record holds values, not tensors).
        let model_ck = ModelConfig::tiny()
            .init(&checkpointed)
            .load_record(model.clone().into_record());
        for chunk in [0, 4] {
            let plain = gradients(&model, &device, chunk);
            let ck = gradients(&model_ck, &checkpointed, chunk);
            assert_eq!(
                plain.len(),
                ck.len(),
                "chunks of {chunk}: the same parameters"
            );
            let global = plain.values().flatten().fold(0.0f32, |m, x| m.max(x.abs()));
            assert!(global > 0.0, "chunks of {chunk}: an all-zero gradient");
            for (id, expected) in &plain {
                for (g, e) in ck[id].iter().zip(expected) {
                    assert!(g.is_finite(), "chunks of {chunk}: non-finite gradient");
                    assert!(
                        (g - e).abs() <= 1e-5 * global,
                        "chunks of {chunk}, parameter {id}: checkpointed {g} against {e} \
                         (largest {global})"
                    );
                }
            }
        }
    }
}

#[test]
fn chunked_backward_refuses_jitter_of_the_wrong_length() {
    #[allow(deprecated)]
    let device = Device::ndarray().autodiff();
    let model = ModelConfig::tiny().init(&device);
    let input = common::scene(3, 32);
    let scene = model.encode(&input, None, &device, None).unwrap();
    let rays = common::target_rays(&input, 3);
    let jitter = vec![0.5f32; rays.len() * SAMPLES - 1];
    let err = chunked_gradients::<ModelError, _>(
        &model,
        &scene,
        &rays,
        SAMPLES,
        Some(&jitter),
        2,
        |out, _| Ok(out.rgb.sum()),
    )
    .unwrap_err();
    common::assert_mentions(&err.to_string(), &["jitter", "9 rays", "8 samples"]);
}

/// On wgpu too (where inference lays the body volume's gather rows out once per scene, and
/// rows shared by the chunks' backwards would be consumed by the first), chunks give the
/// gradient of one backward, the body volume's through the cut included. Atomic adds on a GPU
/// sum in no fixed order, hence the looser tolerance.
#[cfg(feature = "wgpu")]
#[test]
fn chunked_gradients_on_wgpu_equal_one_backward() {
    let Some(gpu) = common::wgpu_device() else {
        return;
    };
    let device = gpu.autodiff();
    device.seed(11);
    let model = ModelConfig::tiny().init(&device);
    let whole = gradients(&model, &device, 0);
    // The vertex features feed only the body volume: their layer learns through its cut.
    let body = whole
        .get(&model.vertex_reduce.weight.id)
        .expect("the body volume's first layer has a gradient");
    assert!(body.iter().any(|&x| x != 0.0), "no body-volume gradient");
    let chunked = gradients(&model, &device, 4);
    assert_gradients_match(&chunked, &whole, 1e-3, "chunks of 4 on wgpu");
}
