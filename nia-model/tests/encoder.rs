#![allow(deprecated)] // Device::ndarray(): burn deprecates it, the user asked for it; it is the reference CPU backend.

//! The ResNet-18 pyramid encoder: output shape, and the matrix-product bilinear upsampling
//! against burn's own `interpolate` (align_corners = false), its gradient against the
//! transposed resampling.

use burn::prelude::*;
use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use nia_model::encoder::{bilinear_matrix, upsample_bilinear, ImageEncoderConfig};

/// Both compute the same 4-tap weighted sums in f32, in different orders.
const UPSAMPLE_TOLERANCE: f32 = 1e-5;

#[test]
fn upsampling_matches_burn_interpolate() {
    let device = Device::ndarray();
    device.seed(0);
    for (h, w, oh, ow) in [(4, 6, 16, 24), (3, 5, 7, 11), (8, 8, 8, 8), (2, 2, 32, 32)] {
        let f = Tensor::<4>::random(
            [2, 3, h, w],
            burn::tensor::Distribution::Uniform(-1.0, 1.0),
            &device,
        );
        let ours = upsample_bilinear(f.clone(), [oh, ow]);
        let reference = interpolate(
            f,
            InterpolateOptions::new(InterpolateMode::Bilinear)
                .with_align_corners(false)
                .with_output_size([oh, ow]),
        );
        let diff = (ours - reference).abs().max().into_scalar::<f32>();
        assert!(
            diff <= UPSAMPLE_TOLERANCE,
            "{h}x{w} -> {oh}x{ow}: max diff {diff}"
        );
    }
}

/// The upsampling's gradient: for `L = sum(up(f) * g)`, `dL/df = A_h^T g A_w` with the dense
/// resampling matrices of [`bilinear_matrix`], on ndarray and flex, for factors of two, odd
/// ratios, one axis unchanged and a 1-pixel source.
#[test]
fn upsampling_gradient_is_the_transposed_resampling() {
    for device in [Device::ndarray(), Device::flex()] {
        let device = device.autodiff();
        device.seed(7);
        for (h, w, oh, ow) in [(4, 6, 8, 12), (3, 5, 7, 11), (5, 4, 5, 9), (1, 2, 4, 8)] {
            let (n, c) = (2, 3);
            let f = Tensor::<4>::random(
                [n, c, h, w],
                burn::tensor::Distribution::Uniform(-1.0, 1.0),
                &device,
            )
            .require_grad();
            let g = Tensor::<4>::random(
                [n, c, oh, ow],
                burn::tensor::Distribution::Uniform(-1.0, 1.0),
                &device,
            );
            let grads = (upsample_bilinear(f.clone(), [oh, ow]) * g.clone())
                .sum()
                .backward();
            let ours = f.grad(&grads).expect("f takes part in the loss");
            let g = g.inner();
            let inner = g.device();
            let a_h =
                Tensor::<2>::from_data(TensorData::new(bilinear_matrix(h, oh), [oh, h]), &inner);
            let a_w =
                Tensor::<2>::from_data(TensorData::new(bilinear_matrix(w, ow), [ow, w]), &inner);
            // [n c, oh, ow] x [ow, w] -> [n c, oh, w]; then A_h^T [h, oh] x that -> [n c, h, w].
            let gw = g
                .reshape([n * c * oh, ow])
                .matmul(a_w)
                .reshape([n * c, oh, w]);
            let expected = a_h
                .transpose()
                .unsqueeze_dim::<3>(0)
                .expand([n * c, h, oh])
                .matmul(gw)
                .reshape([n, c, h, w]);
            let diff = (ours - expected).abs().max().into_scalar::<f32>();
            assert!(
                diff <= UPSAMPLE_TOLERANCE,
                "{h}x{w} -> {oh}x{ow}: gradient max diff {diff}"
            );
        }
    }
}

#[test]
fn encoder_gives_the_four_scale_pyramid_at_half_resolution() {
    let device = Device::ndarray();
    let config = ImageEncoderConfig::new().with_base_width(8);
    let encoder = config.init(&device);
    let images = Tensor::<4>::ones([2, 3, 64, 48], &device).mul_scalar(0.5);
    let out = encoder.forward(images);
    assert_eq!(out.dims(), [2, config.out_channels(), 32, 24]);
    assert_eq!(
        config.out_channels(),
        64,
        "8 + 8 + 16 + 32 channels at base width 8"
    );
    let values = out.into_data().try_to_vec::<f32>().unwrap();
    assert!(values.iter().all(|x| x.is_finite()));
    assert!(
        values.iter().any(|&x| x > 0.0),
        "ReLU features are not all zero"
    );
}

/// The model's reduction of the pyramid, level by level before upsampling, equals the channel
/// reduction of the concatenated map `W^T F` (upsampling and the reduction commute), on
/// patterned images (not constants) and sizes whose levels do not divide evenly.
#[test]
fn pyramid_reduction_equals_reducing_the_concatenated_map() {
    let device = Device::ndarray();
    device.seed(4);
    let config = ImageEncoderConfig::new().with_base_width(8);
    let encoder = config.init(&device);
    let images = Tensor::<4>::random(
        [2, 3, 40, 56],
        burn::tensor::Distribution::Uniform(0.0, 1.0),
        &device,
    );
    let pyramid = encoder.forward_pyramid(images.clone());
    assert_eq!(pyramid.channels(), config.out_channels());
    let d = 5;
    let weight = Tensor::<2>::random(
        [config.out_channels(), d],
        burn::tensor::Distribution::Uniform(-1.0, 1.0),
        &device,
    );
    let ours = pyramid.reduce(weight.clone()).unwrap();
    let f = encoder.forward(images);
    let [n, c, h, w] = f.dims();
    // W^T F per pixel: [N, H W, C] x [C, d] -> [N, d, H, W].
    let reference = f
        .reshape([n, c, h * w])
        .swap_dims(1, 2)
        .matmul(weight.unsqueeze::<3>())
        .swap_dims(1, 2)
        .reshape([n, d, h, w]);
    assert_eq!(ours.dims(), [n, d, h, w]);
    let scale = reference.clone().abs().max().into_scalar::<f32>();
    assert!(scale > 0.1, "the reduction is not trivially zero ({scale})");
    let diff = (ours - reference).abs().max().into_scalar::<f32>();
    assert!(
        // f32 sums over up to 32 channels and 4 levels in another order.
        diff <= 1e-4 * scale.max(1.0),
        "max difference {diff} against a magnitude of {scale}"
    );
    // A weight of the wrong height is refused with the input named.
    let err = pyramid
        .reduce(Tensor::<2>::zeros([c + 1, d], &device))
        .unwrap_err()
        .to_string();
    assert!(err.contains("feature pyramid"), "{err}");
}
