//! Per-point fields: positional encoding, view-wise cross-attention, F_sigma / F_c0, IBR
//! sampling and colour rules, the blender F_B and the variants' colour rules.

mod common;

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use common::{assert_close, central_difference, device, tensor, values};
use nia_data::rng::Rng;
use nia_model::field::attention::ViewCrossAttentionConfig;
use nia_model::field::heads::{view_mean, ColourHeadConfig, DensityHead, DensityHeadConfig};
use nia_model::field::positional_encoding::PositionalEncodingConfig;
use nia_model::ibr::blender::{blend, mix, BlendInputs, Blender, BlenderConfig};
use nia_model::ibr::c0_weight_scale::rescale_c0_weight;
use nia_model::ibr::{
    cosine_weights, fetch_source_colours, sample_views, simple_average_weights, PixelFeatureConfig,
};
use nia_model::renderer::render_rays;
use nia_model::shape::ShapeError;
use nia_model::softmax::stable_softmax;
use nia_model::variant::Variant;

/// f32 forward values computed along two different paths (reordered sums, sin/cos of the
/// same angles): a few ulps of O(1) values.
const VALUE_TOL: f32 = 1e-5;
/// Values through a small MLP (a few hundred f32 multiply-adds per output).
const MLP_TOL: f32 = 1e-4;
/// Central finite-difference step for f32 inputs of O(1).
const FD_STEP: f32 = 1e-3;
/// Finite differences vs autodiff: O(FD_STEP^2) truncation plus f32 rounding of O(1) losses
/// divided by the step (~1e-7 / 1e-3), with margin: absolute plus relative to the gradient.
const FD_ABS_TOL: f32 = 2e-3;
const FD_REL_TOL: f32 = 2e-2;

fn random(rng: &mut Rng, n: usize, lo: f32, hi: f32) -> Vec<f32> {
    (0..n).map(|_| rng.range(lo, hi)).collect()
}

fn assert_finite(v: &[f32], what: &str) {
    assert!(!v.is_empty(), "{what}: empty");
    assert!(v.iter().all(|x| x.is_finite()), "{what}: not finite: {v:?}");
}

fn assert_fd_close(autodiff: f32, fd: f32, what: &str) {
    assert!(
        (autodiff - fd).abs() <= FD_ABS_TOL + FD_REL_TOL * fd.abs(),
        "{what}: autodiff {autodiff} vs finite difference {fd}"
    );
}

/// Asserts that autodiff's gradient `grad` of `f` at `x` matches the central differences, one
/// coordinate at a time (`what[i]`).
fn assert_gradient(what: &str, x: &[f32], grad: &[f32], f: impl Fn(Vec<f32>) -> f32) {
    assert_eq!(grad.len(), x.len(), "{what}");
    for (i, &g) in grad.iter().enumerate() {
        let fd = central_difference(x, i, FD_STEP, &f);
        assert_fd_close(g, fd, &format!("{what}[{i}]"));
    }
}

/// A linear layer with given weights `[d_in, d_out]` (row-major) and bias.
fn linear(weight: Vec<f32>, bias: Vec<f32>, d_in: usize, d_out: usize, dev: &Device) -> Linear {
    Linear {
        weight: Param::from_tensor(tensor(weight, [d_in, d_out], dev)),
        bias: Some(Param::from_tensor(tensor(bias, [d_out], dev))),
    }
}

fn identity(d: usize) -> Vec<f32> {
    (0..d * d)
        .map(|i| if i / d == i % d { 1.0 } else { 0.0 })
        .collect()
}

// ----------------------------------------------------------------------------------------------
// Positional encoding
// ----------------------------------------------------------------------------------------------

#[test]
fn positional_encoding_matches_hand_values() {
    let dev = device();
    let pe = PositionalEncodingConfig::new()
        .with_num_frequencies(2)
        .init(&dev);
    assert_eq!(pe.output_dim(), 3 + 2 * 3 * 2);
    let h = std::f32::consts::FRAC_1_SQRT_2;
    // p = (0.25, -0.5, 1): angles pi p = (pi/4, -pi/2, pi), 2 pi p = (pi/2, -pi, 2 pi).
    let expected = [
        0.25, -0.5, 1.0, // p
        h, -1.0, 0.0, // sin(pi p)
        h, 0.0, -1.0, // cos(pi p)
        1.0, 0.0, 0.0, // sin(2 pi p)
        0.0, -1.0, 1.0, // cos(2 pi p)
    ];
    let mut cpu = Vec::new();
    pe.encode_into([0.25, -0.5, 1.0], &mut cpu);
    assert_close(&cpu, &expected, VALUE_TOL, "gamma (CPU)");
    let gpu = pe
        .forward(tensor(vec![0.25, -0.5, 1.0], [1, 3], &dev))
        .unwrap();
    assert_eq!(gpu.dims(), [1, 15]);
    assert_close(&values(gpu), &expected, VALUE_TOL, "gamma (tensor)");
}

#[test]
fn positional_encoding_tensor_and_cpu_agree_for_directions() {
    let dev = device();
    let pe = PositionalEncodingConfig::new().init(&dev);
    assert_eq!(pe.output_dim(), 27, "paper: L = 4 for directions");
    let mut rng = Rng::new(7);
    let points = random(&mut rng, 5 * 3, -1.0, 1.0);
    let mut cpu = Vec::new();
    for p in points.chunks(3) {
        pe.encode_into([p[0], p[1], p[2]], &mut cpu);
    }
    let gpu = pe.forward(tensor(points, [5, 3], &dev)).unwrap();
    assert_eq!(gpu.dims(), [5, 27]);
    // Angles up to 8 pi: sin/cos of f32 arguments of ~25 differ by a few ulps of the angle.
    assert_close(&values(gpu), &cpu, 1e-5 * 32.0, "gamma tensor vs CPU");
    assert!(matches!(
        pe.forward(Tensor::zeros([2, 4], &dev)),
        Err(ShapeError::Mismatch { .. })
    ));
}

// ----------------------------------------------------------------------------------------------
// View-wise cross-attention
// ----------------------------------------------------------------------------------------------

/// The attention's view mean fused on the host (inference on the CPU backends) against the
/// tensor form and `view_mean`, for 1 and 3 views and 300 points (tasks of 128, the last one
/// short), with features large enough that the scores reach +-1e4 (the softmax must subtract
/// its maximum), and a shape error.
#[test]
fn host_attention_view_mean_matches_the_tensor_form() {
    let (dev, d) = (device(), 8);
    let attention = ViewCrossAttentionConfig::new().with_d_model(d).init(&dev);
    let mut rng = Rng::new(77);
    for (n, amplitude) in [(1usize, 1.0f32), (3, 1.0), (3, 60.0)] {
        let m = 300; // three tasks of points, the last one short
        let mut draw = |k: usize| -> Vec<f32> {
            (0..k)
                .map(|_| (rng.uniform() * 2.0 - 1.0) * amplitude)
                .collect()
        };
        let s = tensor(draw(n * m * d), [n, m, d], &dev); // [N, M, d]
        let l = tensor(draw(n * m * d), [n, m, d], &dev);
        let reference = values(view_mean(attention.forward(s.clone(), l.clone()).unwrap()));
        let host = values(attention.view_mean_on_host(s, l).unwrap());
        assert_eq!(host.len(), m * d);
        let tol = 1e-5 * amplitude.max(1.0) * amplitude.max(1.0);
        for (i, (r, h)) in reference.iter().zip(&host).enumerate() {
            assert!(h.is_finite(), "N {n} amplitude {amplitude}: [{i}] {h}");
            assert!(
                (r - h).abs() <= tol,
                "N {n} amplitude {amplitude}: [{i}] tensor {r} vs host {h}"
            );
        }
    }
    let s = tensor(vec![0.0; 2 * 3 * 5], [2, 3, 5], &dev);
    assert!(attention.view_mean_on_host(s.clone(), s).is_err());
}

#[test]
fn attention_with_one_view_is_value_plus_residual() {
    let dev = device();
    let d = 8;
    let attention = ViewCrossAttentionConfig::new().with_d_model(d).init(&dev);
    let mut rng = Rng::new(1);
    let s = tensor(random(&mut rng, 4 * d, -1.0, 1.0), [1, 4, d], &dev);
    let l = tensor(random(&mut rng, 4 * d, -1.0, 1.0), [1, 4, d], &dev);
    let z = attention.forward(s.clone(), l.clone()).unwrap();
    assert_eq!(z.dims(), [1, 4, d]);
    let expected = attention.phi_v.forward(l) + s;
    assert_close(&values(z), &values(expected), VALUE_TOL, "Z = phi_v(L) + S");
}

#[test]
fn attention_matches_plain_reference_and_is_view_equivariant() {
    let dev = device();
    let (m, n, d) = (3, 3, 4);
    let attention = ViewCrossAttentionConfig::new().with_d_model(d).init(&dev);
    let mut rng = Rng::new(2);
    let s_vals = random(&mut rng, m * n * d, -2.0, 2.0);
    let l_vals = random(&mut rng, m * n * d, -2.0, 2.0);
    let s = tensor(s_vals.clone(), [n, m, d], &dev);
    let l = tensor(l_vals, [n, m, d], &dev);
    let z = values(attention.forward(s.clone(), l.clone()).unwrap());

    // Plain reference from the projections.
    let q = values(attention.phi_k.forward(s.clone()));
    let k = values(attention.phi_k.forward(l.clone()));
    let v = values(attention.phi_v.forward(l.clone()));
    let idx = |p: usize, view: usize, c: usize| (view * m + p) * d + c;
    let mut expected = vec![0.0f32; m * n * d];
    for p in 0..m {
        for i in 0..n {
            let scores: Vec<f32> = (0..n)
                .map(|j| {
                    (0..d)
                        .map(|c| q[idx(p, i, c)] * k[idx(p, j, c)])
                        .sum::<f32>()
                        / (d as f32).sqrt()
                })
                .collect();
            let max = scores.iter().cloned().fold(f32::MIN, f32::max);
            let e: Vec<f32> = scores.iter().map(|x| (x - max).exp()).collect();
            let sum: f32 = e.iter().sum();
            for c in 0..d {
                let attended: f32 = (0..n).map(|j| e[j] / sum * v[idx(p, j, c)]).sum();
                expected[idx(p, i, c)] = attended + s_vals[idx(p, i, c)];
            }
        }
    }
    assert_close(&z, &expected, VALUE_TOL, "attention vs reference");

    // Swapping views 0 and 2 swaps the outputs.
    let perm = Tensor::<1, Int>::from_data(TensorData::new(vec![2i64, 1, 0], [3]), &dev);
    let z_perm = attention
        .forward(s.select(0, perm.clone()), l.select(0, perm.clone()))
        .unwrap();
    let z_back = values(z_perm.select(0, perm));
    assert_close(&z_back, &z, VALUE_TOL, "view permutation equivariance");

    assert!(matches!(
        attention.forward(
            Tensor::zeros([3, 3, d], &dev),
            Tensor::zeros([2, 3, d], &dev)
        ),
        Err(ShapeError::Mismatch { .. })
    ));
}

// ----------------------------------------------------------------------------------------------
// Heads
// ----------------------------------------------------------------------------------------------

#[test]
fn density_head_hand_weights_give_shifted_softplus() {
    let dev = device();
    // d = 2, hidden 2: three identity layers, the last sums the two channels.
    let head = DensityHead {
        layers: vec![
            linear(identity(2), vec![0.0; 2], 2, 2, &dev),
            linear(identity(2), vec![0.0; 2], 2, 2, &dev),
            linear(identity(2), vec![0.0; 2], 2, 2, &dev),
            linear(vec![1.0, 1.0], vec![0.5], 2, 1, &dev),
        ],
        density_shift: -1.0,
    };
    // Point 0: relu keeps (1, 2): raw = 3.5. Point 1: relu zeroes (-1, -3): raw = 0.5.
    let sigma = head
        .forward(tensor(vec![1.0, 2.0, -1.0, -3.0], [2, 2], &dev))
        .unwrap();
    assert_eq!(sigma.dims(), [2]);
    let softplus = |x: f32| (1.0 + x.exp()).ln();
    assert_close(
        &values(sigma),
        &[softplus(3.5 - 1.0), softplus(0.5 - 1.0)],
        VALUE_TOL,
        "sigma = softplus(raw - 1)",
    );
}

#[test]
fn heads_shapes_and_ranges() {
    let dev = device();
    let (m, n, d, d_h) = (5, 3, 16, 12);
    let density = DensityHeadConfig::new()
        .with_d_input(d)
        .with_d_hidden(d_h)
        .init(&dev);
    let colour = ColourHeadConfig::new()
        .with_d_input(d)
        .with_d_hidden(d_h)
        .init(&dev);
    let mut rng = Rng::new(3);
    let z = tensor(random(&mut rng, m * n * d, -3.0, 3.0), [n, m, d], &dev);
    let mean = view_mean(z.clone());
    assert_close(
        &values(mean.clone()),
        &values(z.mean_dim(0).reshape([m, d])),
        VALUE_TOL,
        "view mean",
    );
    let sigma = values(density.forward(mean.clone()).unwrap());
    assert_eq!(sigma.len(), m);
    assert!(
        sigma.iter().all(|s| s.is_finite() && *s >= 0.0),
        "{sigma:?}"
    );

    let gamma = tensor(random(&mut rng, m * 27, -1.0, 1.0), [m, 27], &dev);
    let out = colour.forward(mean, gamma).unwrap();
    assert_eq!(out.c0.dims(), [m, 3]);
    assert_eq!(out.confidence.dims(), [m, 1]);
    assert_eq!(out.h.dims(), [m, d_h]);
    let in_unit = |v: Vec<f32>| v.iter().all(|x| (0.0..=1.0).contains(x));
    assert!(in_unit(values(out.c0.clone())) && in_unit(values(out.confidence.clone())));
    assert!(
        values(out.h.clone()).iter().all(|x| *x >= 0.0),
        "h is a ReLU output"
    );
    // c0 and psi are the sigmoid of the last layer applied to h.
    let logits = colour.layers[3].forward(out.h);
    let sig = |v: Vec<f32>| {
        v.into_iter()
            .map(|x| 1.0 / (1.0 + (-x).exp()))
            .collect::<Vec<_>>()
    };
    let expected = sig(values(logits));
    let got: Vec<f32> = values(out.c0)
        .chunks(3)
        .zip(values(out.confidence))
        .flat_map(|(c, p)| [c[0], c[1], c[2], p])
        .collect();
    assert_close(&got, &expected, VALUE_TOL, "(c0, psi) = sigmoid(layer4(h))");
    assert!(colour
        .forward(Tensor::zeros([m, d], &dev), Tensor::zeros([m, 26], &dev))
        .is_err());
}

// ----------------------------------------------------------------------------------------------
// IBR
// ----------------------------------------------------------------------------------------------

#[test]
fn sample_views_reads_pixel_centres_and_zero_outside() {
    let dev = device();
    // Two views of a 2 x 2 single-channel map; view 1 = view 0 + 10.
    let maps = tensor(
        vec![1.0, 2.0, 3.0, 4.0, 11.0, 12.0, 13.0, 14.0],
        [2, 1, 2, 2],
        &dev,
    );
    // Pixel (x, y) centre at u = x + 0.5 -> u_norm = u - 1 for W = 2.
    let grid = tensor(
        vec![
            -0.5, -0.5, // pixel (0, 0)
            0.5, -0.5, // pixel (1, 0)
            -0.5, 0.5, // pixel (0, 1)
            0.0, 0.0, // centre of the image: mean of the 4 pixels
            5.0, 5.0, // outside: zero
        ],
        [1, 5, 2],
        &dev,
    )
    .repeat_dim(0, 2);
    let sampled = sample_views(maps, grid).unwrap();
    assert_eq!(sampled.dims(), [2, 5, 1]);
    assert_close(
        &values(sampled),
        &[1.0, 2.0, 3.0, 2.5, 0.0, 11.0, 12.0, 13.0, 12.5, 0.0],
        VALUE_TOL,
        "grid_sample at pixel centres",
    );
}

#[test]
fn source_colours_and_pixel_features_layout() {
    let dev = device();
    // One view, 1 x 1 image of colour (0.1, 0.2, 0.3): its centre is (0, 0).
    let images = tensor(vec![0.1, 0.2, 0.3], [1, 3, 1, 1], &dev);
    let grid = tensor(vec![0.0, 0.0, 3.0, 0.0], [1, 2, 2], &dev);
    let c = fetch_source_colours(images, grid.clone()).unwrap();
    assert_eq!(c.dims(), [1, 2, 3]);
    assert_close(
        &values(c),
        &[0.1, 0.2, 0.3, 0.0, 0.0, 0.0],
        VALUE_TOL,
        "c_n",
    );
    assert!(fetch_source_colours(Tensor::zeros([1, 4, 2, 2], &dev), grid.clone()).is_err());

    let pixel = PixelFeatureConfig::new()
        .with_d_image(6)
        .with_d_model(4)
        .init(&dev);
    let maps = tensor(
        (0..6 * 4).map(|i| i as f32 / 10.0).collect(),
        [1, 6, 2, 2],
        &dev,
    );
    let p = pixel.forward(maps.clone(), grid.clone()).unwrap();
    assert_eq!(p.dims(), [1, 2, 4]);
    let expected = pixel.reduce.forward(sample_views(maps, grid).unwrap());
    assert_close(
        &values(p),
        &values(expected),
        VALUE_TOL,
        "l_n = Linear(sample)",
    );
}

#[test]
fn fixed_colour_rules() {
    let dev = device();
    // N = 2 views, M = 1 point: (c) weighs c0 and both views 1/3 each.
    let average = simple_average_weights(1, 2, &dev).unwrap();
    assert_close(
        &values(average),
        &[1.0 / 3.0; 3],
        VALUE_TOL,
        "simple average",
    );
    assert!(simple_average_weights(1, 0, &dev).is_err());
    // (d): cos = (1, 0.5) -> raw (1, 1, 0.5) / 2.5; a view facing away (cos -1) weighs 0.
    let d_hat = tensor(
        vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.5],
        [2, 1, 4],
        &dev,
    );
    let weights = cosine_weights(d_hat).unwrap();
    assert_close(
        &values(weights),
        &[0.4, 0.4, 0.2],
        VALUE_TOL,
        "cosine weighted",
    );
    let away = tensor(vec![0.0, 0.0, 0.0, -1.0], [1, 1, 4], &dev);
    assert_close(
        &values(cosine_weights(away).unwrap()),
        &[1.0, 0.0],
        VALUE_TOL,
        "facing away",
    );
    assert!(matches!(
        cosine_weights(Tensor::zeros([2, 1, 3], &dev)),
        Err(ShapeError::Mismatch { .. })
    ));
}

// ----------------------------------------------------------------------------------------------
// Blender
// ----------------------------------------------------------------------------------------------

const D_PIXEL: usize = 6;
const D_H: usize = 5;

fn small_blender(dev: &Device) -> Blender {
    BlenderConfig::new()
        .with_d_pixel(D_PIXEL)
        .with_d_h(D_H)
        .with_d_hidden(16)
        .init(dev)
}

/// Random blender inputs for M points and N views.
/// A small blender on `dev` and the inputs of `m` points from `n` views, drawn from a generator
/// seeded with `seed`: (device, blender, the generator, inputs).
fn blend_case(dev: Device, seed: u64, m: usize, n: usize) -> (Device, Blender, Rng, BlendInputs) {
    let blender = small_blender(&dev);
    let mut rng = Rng::new(seed);
    let x = blend_inputs(&mut rng, m, n, &dev);
    (dev, blender, rng, x)
}

fn blend_inputs(rng: &mut Rng, m: usize, n: usize, dev: &Device) -> BlendInputs {
    BlendInputs {
        c0: tensor(random(rng, m * 3, 0.0, 1.0), [m, 3], dev),
        confidence: tensor(random(rng, m, 0.0, 1.0), [m, 1], dev),
        h: tensor(random(rng, m * D_H, 0.0, 2.0), [m, D_H], dev),
        source_colours: tensor(random(rng, n * m * 3, 0.0, 1.0), [n, m, 3], dev),
        pixel_feature: tensor(
            random(rng, n * m * D_PIXEL, -1.0, 1.0),
            [n, m, D_PIXEL],
            dev,
        ),
        view_dir_features: tensor(random(rng, n * m * 4, -1.0, 1.0), [n, m, 4], dev),
        visibility: tensor(random(rng, n * m, 0.0, 1.0), [n, m], dev),
    }
}

fn logits_of(blender: &Blender, x: &BlendInputs) -> Tensor<2> {
    blender.forward(x).unwrap()
}

/// F_B's logits `[M, N + 1]` as the paper writes them: every token `[p_n, d_hat_n, o_n, 0 (,
/// c_n) ; h, psi (, mean p, var p, mean c, var c)]` and the NeRF token `[mean p, (0,0,0,1),
/// mean o, 1 (, c0) ; ...]` concatenated in full, one linear layer with the two first-layer
/// weights stacked, then the remaining layers.
fn concatenated_token_logits(blender: &Blender, x: &BlendInputs) -> Vec<f32> {
    use burn::tensor::activation::relu;
    use nia_model::ibr::view_statistics::{mean_and_variance, view_weights};
    let [n, m, _] = x.pixel_feature.dims();
    let dev = x.c0.device();
    let weight = Tensor::cat(
        vec![
            blender.token_input.weight.val(),
            blender.point_input.weight.val(),
        ],
        0,
    );
    let bias = blender.token_input.bias.as_ref().unwrap().val();
    let mut point_parts = vec![x.h.clone(), x.confidence.clone()];
    let mut view_colour = vec![];
    let mut nerf_colour = vec![];
    if blender.view_statistics {
        let omega = view_weights(x.visibility.clone());
        let (mean_p, var_p) = mean_and_variance(x.pixel_feature.clone(), omega.clone()).unwrap();
        let (mean_c, var_c) = mean_and_variance(x.source_colours.clone(), omega).unwrap();
        point_parts.extend([mean_p, var_p, mean_c, var_c]);
        view_colour.push(x.source_colours.clone());
        nerf_colour.push(x.c0.clone().unsqueeze_dim::<3>(0));
    }
    let point = Tensor::cat(point_parts, 1).unsqueeze_dim::<3>(0);
    let mut views = vec![
        x.pixel_feature.clone(),
        x.view_dir_features.clone(),
        x.visibility.clone().reshape([n, m, 1]),
        Tensor::zeros([n, m, 1], &dev),
    ];
    views.extend(view_colour);
    views.push(point.clone().repeat_dim(0, n));
    let mut nerf = vec![
        x.pixel_feature.clone().mean_dim(0),
        tensor(vec![0.0, 0.0, 0.0, 1.0], [1, 1, 4], &dev).repeat_dim(1, m),
        x.visibility.clone().reshape([n, m, 1]).mean_dim(0),
        Tensor::ones([1, m, 1], &dev),
    ];
    nerf.extend(nerf_colour);
    nerf.push(point);
    let tokens = Tensor::cat(vec![Tensor::cat(nerf, 2), Tensor::cat(views, 2)], 0);
    let hidden = bias.dims()[0];
    let mut y = relu(tokens.matmul(weight.unsqueeze_dim::<3>(0)) + bias.reshape([1, 1, hidden]));
    for (i, layer) in blender.layers.iter().enumerate() {
        y = layer.forward(y);
        if i + 1 < blender.layers.len() {
            y = relu(y);
        }
    }
    values(y.reshape([n + 1, m]).transpose())
}

#[test]
fn blender_any_view_count_and_token_layout() {
    let dev = device();
    let blender = small_blender(&dev);
    let mut rng = Rng::new(4);
    for n in 1..=4 {
        let x = blend_inputs(&mut rng, 3, n, &dev);
        assert_eq!(logits_of(&blender, &x).dims(), [3, n + 1], "N = {n}");
    }

    // Reference: one linear layer on the full concatenated token, then the rest of the MLP.
    let (m, n) = (2, 3);
    let x = blend_inputs(&mut rng, m, n, &dev);
    let logits = values(logits_of(&blender, &x));
    assert_close(
        &logits,
        &concatenated_token_logits(&blender, &x),
        MLP_TOL,
        "F_B vs concatenated-token reference",
    );
    // The same with the tokens' colours and the across-view statistics.
    let with_statistics = BlenderConfig::new()
        .with_d_pixel(D_PIXEL)
        .with_d_h(D_H)
        .with_d_hidden(16)
        .with_view_statistics(true)
        .init(&dev);
    assert_close(
        &values(logits_of(&with_statistics, &x)),
        &concatenated_token_logits(&with_statistics, &x),
        MLP_TOL,
        "F_B with view statistics vs concatenated-token reference",
    );

    // Permuting the views permutes logits 1..N and keeps logit 0.
    let perm = Tensor::<1, Int>::from_data(TensorData::new(vec![1i64, 2, 0], [3]), &dev);
    let permuted = BlendInputs {
        pixel_feature: x.pixel_feature.clone().select(0, perm.clone()),
        view_dir_features: x.view_dir_features.clone().select(0, perm.clone()),
        visibility: x.visibility.clone().select(0, perm),
        ..x.clone()
    };
    let lp = values(logits_of(&blender, &permuted));
    for p in 0..m {
        let row = &logits[p * 4..p * 4 + 4];
        let prow = &lp[p * 4..p * 4 + 4];
        assert_close(
            &[prow[0], prow[1], prow[2], prow[3]],
            &[row[0], row[2], row[3], row[1]],
            MLP_TOL,
            "permuted logits",
        );
    }
}

#[test]
fn blend_hand_values_and_extreme_logits() {
    let dev = device();
    // N = 1: logits (0, ln 3) -> weights (1/4, 3/4).
    let out = blend(
        tensor(vec![0.0, 3f32.ln()], [1, 2], &dev),
        tensor(vec![1.0, 0.0, 0.0], [1, 3], &dev),
        tensor(vec![0.0, 0.0, 1.0], [1, 1, 3], &dev),
    )
    .unwrap();
    assert_close(
        &values(out.blend_weights),
        &[0.25, 0.75],
        VALUE_TOL,
        "weights",
    );
    assert_close(&values(out.colour), &[0.25, 0.0, 0.75], VALUE_TOL, "colour");

    // Logits of +-1e4 (a naive exp overflows to inf and gives NaN): exact one-hot weights,
    // finite gradients (zero where the softmax saturates).
    let ad = dev.autodiff();
    let logits = tensor(vec![1e4, -1e4, 0.0, -1e4, 0.0, 1e4], [2, 3], &ad).require_grad();
    let c0 = tensor(vec![0.2, 0.4, 0.6, 0.1, 0.1, 0.1], [2, 3], &ad).require_grad();
    let colours = tensor((0..12).map(|i| i as f32 / 12.0).collect(), [2, 2, 3], &ad).require_grad();
    let out = blend(logits.clone(), c0.clone(), colours.clone()).unwrap();
    let w = values(out.blend_weights.clone());
    assert_close(
        &w,
        &[1.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        0.0,
        "saturated weights",
    );
    // Point 0 takes c0, point 1 takes view 2's colour c_2[point 1] = colours[1, 1].
    assert_close(
        &values(out.colour.clone()),
        &[0.2, 0.4, 0.6, 9.0 / 12.0, 10.0 / 12.0, 11.0 / 12.0],
        VALUE_TOL,
        "saturated colour",
    );
    let grads = out.colour.sum().backward();
    let g_logits = values(logits.grad(&grads).unwrap());
    assert_finite(&g_logits, "d/dlogits at +-1e4");
    assert_close(&g_logits, &[0.0; 6], 0.0, "d/dlogits at +-1e4");
    let g_c0 = values(c0.grad(&grads).unwrap());
    assert_close(&g_c0, &[1.0, 1.0, 1.0, 0.0, 0.0, 0.0], 0.0, "d/dc0");
    assert_finite(&values(colours.grad(&grads).unwrap()), "d/dc_n");
}

#[test]
fn blend_gradient_matches_finite_differences() {
    let dev = device().autodiff();
    let mut rng = Rng::new(5);
    let (m, n) = (2, 3);
    let logit_vals = random(&mut rng, m * (n + 1), -2.0, 2.0);
    let c0_vals = random(&mut rng, m * 3, 0.0, 1.0);
    let colours = tensor(random(&mut rng, n * m * 3, 0.0, 1.0), [n, m, 3], &dev);
    let probe = tensor(random(&mut rng, m * 3, -1.0, 1.0), [m, 3], &dev);
    let loss = |logits: Vec<f32>, c0: Vec<f32>| {
        let out = blend(
            tensor(logits, [m, n + 1], &dev),
            tensor(c0, [m, 3], &dev),
            colours.clone(),
        )
        .unwrap();
        (out.colour * probe.clone()).sum()
    };
    let logits = tensor(logit_vals.clone(), [m, n + 1], &dev).require_grad();
    let c0 = tensor(c0_vals.clone(), [m, 3], &dev).require_grad();
    let out = blend(logits.clone(), c0.clone(), colours.clone()).unwrap();
    let grads = (out.colour * probe.clone()).sum().backward();
    let g_logits = values(logits.grad(&grads).unwrap());
    let g_c0 = values(c0.grad(&grads).unwrap());
    let scalar = |t: Tensor<1>| values(t)[0];
    assert_gradient("d/dlogit", &logit_vals, &g_logits, |v| {
        scalar(loss(v, c0_vals.clone()))
    });
    assert_gradient("d/dc0", &c0_vals, &g_c0, |v| {
        scalar(loss(logit_vals.clone(), v))
    });
}

#[test]
fn blender_gradient_wrt_inputs_matches_finite_differences() {
    let (m, n) = (2, 2);
    let (dev, blender, mut rng, x) = blend_case(device().autodiff(), 6, m, n);
    let vis_vals = values(x.visibility.clone());
    let psi_vals = values(x.confidence.clone());
    let probe = tensor(random(&mut rng, m * 3, -1.0, 1.0), [m, 3], &dev);
    let loss = |vis: Tensor<2>, psi: Tensor<2>| {
        let inputs = BlendInputs {
            visibility: vis,
            confidence: psi,
            ..x.clone()
        };
        let out = blender.colour(Variant::Full, inputs).unwrap();
        (out.colour * probe.clone()).sum()
    };
    let vis = tensor(vis_vals.clone(), [n, m], &dev).require_grad();
    let psi = tensor(psi_vals.clone(), [m, 1], &dev).require_grad();
    let grads = loss(vis.clone(), psi.clone()).backward();
    let g_vis = values(vis.grad(&grads).unwrap());
    let g_psi = values(psi.grad(&grads).unwrap());
    let scalar = |t: Tensor<1>| values(t)[0];
    let vis_t = |v: Vec<f32>| tensor(v, [n, m], &dev);
    let psi_t = |v: Vec<f32>| tensor(v, [m, 1], &dev);
    assert_gradient("d/do", &vis_vals, &g_vis, |v| {
        scalar(loss(vis_t(v), psi_t(psi_vals.clone())))
    });
    assert_gradient("d/dpsi", &psi_vals, &g_psi, |v| {
        scalar(loss(vis_t(vis_vals.clone()), psi_t(v)))
    });
}

#[test]
fn invisible_views_stay_finite() {
    let (m, n) = (3, 3);
    let (dev, blender, _, x) = blend_case(device().autodiff(), 8, m, n);
    // Case 1: view 1 has o_n = 0 everywhere. Case 2: every view is invisible.
    let mut one_view = values(x.visibility.clone());
    one_view[m..2 * m].iter_mut().for_each(|o| *o = 0.0);
    for (case, vis) in [
        ("one view invisible", one_view),
        ("all invisible", vec![0.0; n * m]),
    ] {
        let vis = tensor(vis, [n, m], &dev).require_grad();
        let h = x.h.clone().require_grad();
        let inputs = BlendInputs {
            visibility: vis.clone(),
            h: h.clone(),
            ..x.clone()
        };
        let out = blender.colour(Variant::Full, inputs).unwrap();
        let w = values(out.blend_weights.clone());
        assert_finite(&w, case);
        for row in w.chunks(n + 1) {
            assert!(
                (row.iter().sum::<f32>() - 1.0).abs() < VALUE_TOL,
                "{case}: rows sum to 1"
            );
        }
        let colour = values(out.colour.clone());
        assert_finite(&colour, case);
        assert!(
            colour.iter().all(|c| (0.0..=1.0 + VALUE_TOL).contains(c)),
            "{case}: convex mix"
        );
        let grads = out.colour.sum().backward();
        assert_finite(&values(vis.grad(&grads).unwrap()), case);
        assert_finite(&values(h.grad(&grads).unwrap()), case);
        let g_w = blender.token_input.weight.val().grad(&grads).unwrap();
        assert_finite(&values(g_w), case);
    }
}

#[test]
fn stable_softmax_matches_definition() {
    let dev = device();
    let x = tensor(vec![1.0, 2.0, 3.0, -1e4, 1e4, 0.0], [2, 3], &dev);
    let y = values(stable_softmax(x, 1));
    let e = [1f32.exp(), 2f32.exp(), 3f32.exp()];
    let s: f32 = e.iter().sum();
    assert_close(
        &y,
        &[e[0] / s, e[1] / s, e[2] / s, 0.0, 1.0, 0.0],
        VALUE_TOL,
        "softmax",
    );
}

// ----------------------------------------------------------------------------------------------
// Variants
// ----------------------------------------------------------------------------------------------

#[test]
fn variant_colour_rules() {
    let (m, n) = (4, 3);
    let (dev, blender, _, x) = blend_case(device(), 9, m, n);

    // (b) NoIbr: c = c0, weights one-hot on token 0.
    let no_ibr = blender.colour(Variant::NoIbr, x.clone()).unwrap();
    assert_close(
        &values(no_ibr.colour.clone()),
        &values(x.c0.clone()),
        0.0,
        "NoIbr c = c0",
    );
    let one_hot: Vec<f32> = (0..m).flat_map(|_| [1.0, 0.0, 0.0, 0.0]).collect();
    assert_close(
        &values(no_ibr.blend_weights.clone()),
        &one_hot,
        0.0,
        "NoIbr weights",
    );

    // (c) SimpleAverage: the mean of c0 and the source colours.
    let avg = blender.colour(Variant::SimpleAverage, x.clone()).unwrap();
    let c = values(x.source_colours.clone());
    let c0 = values(x.c0.clone());
    let mean: Vec<f32> = (0..m * 3)
        .map(|i| (c0[i] + (0..n).map(|v| c[v * m * 3 + i]).sum::<f32>()) / (n + 1) as f32)
        .collect();
    assert_close(&values(avg.colour), &mean, VALUE_TOL, "SimpleAverage");
    assert_close(
        &values(avg.blend_weights),
        &vec![0.25; m * (n + 1)],
        VALUE_TOL,
        "SimpleAverage weights",
    );

    // (d) CosineWeighted: weights ∝ (1, max(cos_n, 0)) over [c0, c_n].
    let cos = values(x.view_dir_features.clone().slice(s![.., .., 3..4]));
    let weighted = blender.colour(Variant::CosineWeighted, x.clone()).unwrap();
    let mut expected = vec![0.0f32; m * 3];
    for p in 0..m {
        let raw: Vec<f32> = (0..n).map(|v| cos[v * m + p].max(0.0)).collect();
        let total = 1.0 + raw.iter().sum::<f32>();
        for ch in 0..3 {
            expected[p * 3 + ch] = (c0[p * 3 + ch]
                + (0..n)
                    .map(|v| raw[v] * c[(v * m + p) * 3 + ch])
                    .sum::<f32>())
                / total;
        }
    }
    assert_close(
        &values(weighted.colour),
        &expected,
        VALUE_TOL,
        "CosineWeighted",
    );

    // (a) NoBody and (e) Full: softmax(F_B) . [c0, c_n].
    let logits = logits_of(&blender, &x);
    let expected = blend(logits, x.c0.clone(), x.source_colours.clone()).unwrap();
    for variant in [Variant::NoBody, Variant::Full] {
        let got = blender.colour(variant, x.clone()).unwrap();
        assert_close(
            &values(got.colour),
            &values(expected.colour.clone()),
            0.0,
            "blend",
        );
    }

    // NoIbr renders exactly the c0 composite: rgb == rgb0.
    let (r, s_per_ray) = (2, 2);
    let sigma = tensor(vec![0.5, 2.0, 1.0, 3.0], [r, s_per_ray], &dev);
    let t = tensor(vec![0.0, 0.5, 0.1, 0.4], [r, s_per_ray], &dev);
    let far = tensor(vec![1.0, 1.0], [r], &dev);
    let c_rays = no_ibr.colour.reshape([r, s_per_ray, 3]);
    let c0_rays = x.c0.reshape([r, s_per_ray, 3]);
    let out = render_rays(sigma, c_rays, c0_rays, t, far, None).unwrap();
    assert_close(&values(out.rgb), &values(out.rgb0), 0.0, "NoIbr rgb = rgb0");

    assert_eq!(
        Variant::ALL.map(Variant::name),
        [
            "no_body",
            "no_ibr",
            "simple_average",
            "cosine_weighted",
            "full"
        ]
    );
    assert_eq!(Variant::default(), Variant::Full);
    assert!(!Variant::NoBody.uses_body() && Variant::Full.uses_body());
    assert!(Variant::NoBody.uses_blender() && !Variant::SimpleAverage.uses_blender());
}

/// F_sigma, F_c0 and F_B on the host ([`HostNetwork`], the CPU backends' inference path)
/// against their tensor forms: M across several row tasks with a remainder, and one point;
/// N of 1 and 3; F_B with and without view statistics; inputs large enough that the ReLUs
/// switch many units off.
#[test]
fn host_network_matches_the_tensor_heads_and_blender() {
    use nia_model::field::network_host::HostNetwork;
    let dev = device();
    let (d, d_dir, d_hidden) = (12, 27, 24);
    let mut rng = Rng::new(91);
    for (statistics, n) in [(false, 3usize), (true, 3), (false, 1)] {
        dev.seed(17);
        let density = DensityHeadConfig::new()
            .with_d_input(d)
            .with_d_hidden(d_hidden)
            .init(&dev);
        let colour = ColourHeadConfig::new()
            .with_d_input(d)
            .with_d_direction(d_dir)
            .with_d_hidden(d_hidden)
            .init(&dev);
        let blender = BlenderConfig::new()
            .with_d_pixel(d)
            .with_d_h(d_hidden)
            .with_d_hidden(16)
            .with_view_statistics(statistics)
            .init(&dev);
        let host = HostNetwork::read(&density, &colour, &blender).unwrap();
        for m in [600usize, 1] {
            let case = format!("statistics {statistics}, N {n}, M {m}");
            let mean_z = tensor(random(&mut rng, m * d, -3.0, 3.0), [m, d], &dev);
            let gamma = tensor(random(&mut rng, m * d_dir, -1.0, 1.0), [m, d_dir], &dev);
            let sigma = values(host.density(mean_z.clone()).unwrap());
            let sigma_ref = values(density.forward(mean_z.clone()).unwrap());
            assert_eq!(sigma.len(), m, "{case}");
            assert_finite(&sigma, &case);
            assert_close(&sigma, &sigma_ref, VALUE_TOL, &format!("{case}: sigma"));
            // gamma(d) written on the host into F_c0's input rows, against the tensor encoding.
            let pe = PositionalEncodingConfig::new().init(&dev);
            let dirs: Vec<f32> = (0..m)
                .flat_map(|_| {
                    let v = random(&mut rng, 3, -1.0, 1.0);
                    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-3);
                    [v[0] / n, v[1] / n, v[2] / n]
                })
                .collect();
            let dirs = tensor(dirs, [m, 3], &dev);
            let of_dirs = host
                .colour_of_directions(mean_z.clone(), dirs.clone(), &pe)
                .unwrap();
            let of_dirs_ref = colour
                .forward(mean_z.clone(), pe.forward(dirs).unwrap())
                .unwrap();
            for (what, got, want) in [
                ("c0", of_dirs.c0, of_dirs_ref.c0),
                ("psi", of_dirs.confidence, of_dirs_ref.confidence),
                ("h", of_dirs.h, of_dirs_ref.h),
            ] {
                assert_close(
                    &values(got),
                    &values(want),
                    VALUE_TOL,
                    &format!("{case}: {what} from directions"),
                );
            }
            let heads = host.colour(mean_z.clone(), gamma.clone()).unwrap();
            let heads_ref = colour.forward(mean_z, gamma).unwrap();
            assert_eq!(heads.h.dims(), [m, d_hidden], "{case}");
            for (what, got, want) in [
                ("c0", heads.c0.clone(), heads_ref.c0.clone()),
                (
                    "psi",
                    heads.confidence.clone(),
                    heads_ref.confidence.clone(),
                ),
                ("h", heads.h.clone(), heads_ref.h.clone()),
            ] {
                assert_close(
                    &values(got),
                    &values(want),
                    VALUE_TOL,
                    &format!("{case}: {what}"),
                );
            }
            let x = BlendInputs {
                c0: heads_ref.c0,
                confidence: heads_ref.confidence,
                h: heads_ref.h,
                source_colours: tensor(random(&mut rng, n * m * 3, 0.0, 1.0), [n, m, 3], &dev),
                pixel_feature: tensor(random(&mut rng, n * m * d, -2.0, 2.0), [n, m, d], &dev),
                view_dir_features: tensor(random(&mut rng, n * m * 4, -1.0, 1.0), [n, m, 4], &dev),
                visibility: tensor(random(&mut rng, n * m, 0.0, 1.0), [n, m], &dev),
            };
            // Without and with c0's odds rescaled (`[render] c0_weight_scale`): the host pass
            // and the tensor path's one mix against the tensor blend, rescaling, second mix
            // and IBR-only colour written out.
            for scale in [None, Some(0.25f32)] {
                let case = format!("{case}, c0 scale {scale:?}");
                let (got, got_ibr) = host.blend_colour(&blender, x.clone(), scale).unwrap();
                let mut want = blender.colour(Variant::Full, x.clone()).unwrap();
                if let Some(scale) = scale {
                    let weights = rescale_c0_weight(want.blend_weights, scale).unwrap();
                    want = mix(weights, x.c0.clone(), x.source_colours.clone()).unwrap();
                }
                assert_eq!(got.blend_weights.dims(), [m, n + 1], "{case}");
                let weights = values(got.blend_weights);
                assert_finite(&weights, &case);
                let want_ibr = ibr_only_reference(
                    &values(want.blend_weights.clone()),
                    &values(x.source_colours.clone()),
                    n,
                    m,
                );
                assert_close(
                    &weights,
                    &values(want.blend_weights.clone()),
                    VALUE_TOL,
                    &format!("{case}: blend weights"),
                );
                assert_close(
                    &values(got.colour),
                    &values(want.colour.clone()),
                    VALUE_TOL,
                    &format!("{case}: colour"),
                );
                assert_close(
                    &values(got_ibr),
                    &want_ibr,
                    VALUE_TOL,
                    &format!("{case}: IBR-only colour"),
                );
                // The tensor path's one-mix form (the GPU's) against the same reference.
                let tensor = blender
                    .colour_with_c0_scale(Variant::Full, x.clone(), scale)
                    .unwrap();
                for (what, got, want) in [
                    ("weights", &tensor.blend_weights, &want.blend_weights),
                    ("colour", &tensor.colour, &want.colour),
                ] {
                    assert_close(
                        &values(got.clone()),
                        &values(want.clone()),
                        VALUE_TOL,
                        &format!("{case}: tensor one-mix {what}"),
                    );
                }
            }
        }
    }
}

/// The IBR-only colour written out: `sum_n v_n c_n / sum_n v_n`, `v_n = w_n + IBR_ONLY_FLOOR`
/// (weights `[M, N + 1]`, colours `[N, M, 3]`; output `[M, 3]`).
fn ibr_only_reference(weights: &[f32], colours: &[f32], n: usize, m: usize) -> Vec<f32> {
    use nia_model::ibr::blend_host::IBR_ONLY_FLOOR;
    let mut out = vec![0.0f32; m * 3];
    for i in 0..m {
        let mut total = 0.0f64;
        let mut sum = [0.0f64; 3];
        for view in 0..n {
            let v = (weights[i * (n + 1) + view + 1] + IBR_ONLY_FLOOR) as f64;
            total += v;
            for ch in 0..3 {
                sum[ch] += v * colours[(view * m + i) * 3 + ch] as f64;
            }
        }
        for ch in 0..3 {
            out[i * 3 + ch] = (sum[ch] / total) as f32;
        }
    }
    out
}

/// The host blend at extreme logits: weights stay finite and sum to 1, a logit far above the
/// others takes all the weight, c0's rescaling keeps a c0-only point mostly on c0, the IBR-only
/// colour of a c0-only point is the plain mean of the views, and bad scales and shapes are
/// errors. NaN logits stay NaN (never hidden).
#[test]
fn host_blend_survives_extreme_logits_and_refuses_bad_input() {
    use nia_model::ibr::blend_host::blend_on_host;
    let (n, m) = (2usize, 4usize);
    // Token-major [N + 1, M]: point 0 all on c0 (1e30 against -1e30), point 1 all on view 2,
    // point 2 equal huge logits, point 3 zeros.
    let logits = vec![
        1e30, -1e30, 3e38, 0.0, // c0
        -1e30, -1e30, 3e38, 0.0, // view 1
        -1e30, 1e30, 3e38, 0.0, // view 2
    ];
    let c0 = vec![0.5f32; m * 3];
    let mut colours = vec![0.0f32; n * m * 3];
    for i in 0..m {
        for ch in 0..3 {
            colours[i * 3 + ch] = 0.2; // view 1
            colours[(m + i) * 3 + ch] = 0.8; // view 2
        }
    }
    for scale in [None, Some(1e-3f32), Some(0.25), Some(1e3)] {
        let out = blend_on_host(&logits, &c0, &colours, n, m, scale).unwrap();
        let case = format!("scale {scale:?}");
        assert_finite(&out.blend_weights, &case);
        assert_finite(&out.colour, &case);
        assert_finite(&out.ibr_colour, &case);
        for w in out.blend_weights.chunks(n + 1) {
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6, "{case}: {w:?}");
        }
        // Point 1 puts everything on view 2 whatever the scale (c0's weight is 0).
        assert!(
            (out.blend_weights[(n + 1) + 2] - 1.0).abs() < 1e-6,
            "{case}"
        );
        assert!((out.colour[3] - 0.8).abs() < 1e-6, "{case}");
        // Point 0 is c0-only: its IBR-only colour is the plain mean of the views.
        assert!((out.ibr_colour[0] - 0.5).abs() < 1e-6, "{case}");
        // Without rescaling, point 0 is all c0 and point 2's equal logits split evenly.
        if scale.is_none() {
            assert!((out.blend_weights[0] - 1.0).abs() < 1e-6, "{case}");
            for k in 0..3 {
                assert!(
                    (out.blend_weights[2 * (n + 1) + k] - 1.0 / 3.0).abs() < 1e-6,
                    "{case}"
                );
            }
        }
    }
    // A c0 weight of 1 stays 1 under any scale: s / (s + 0).
    let out = blend_on_host(&logits, &c0, &colours, n, m, Some(1e-3)).unwrap();
    assert!((out.blend_weights[0] - 1.0).abs() < 1e-6);
    // Point 3 (zeros): w = 1/3 each; at s = 0.25, w_0' = (1/12) / (1/12 + 2/3) = 1/9.
    let out = blend_on_host(&logits, &c0, &colours, n, m, Some(0.25)).unwrap();
    assert!((out.blend_weights[3 * (n + 1)] - 1.0 / 9.0).abs() < 1e-6);
    let mut nan = logits.clone();
    nan[3] = f32::NAN;
    let out = blend_on_host(&nan, &c0, &colours, n, m, None).unwrap();
    assert!(out.blend_weights[3 * (n + 1)].is_nan() && out.colour[9].is_nan());
    for bad in [0.0f32, 1e4, f32::NAN] {
        let err = blend_on_host(&logits, &c0, &colours, n, m, Some(bad)).unwrap_err();
        assert!(err.to_string().contains("scale"), "{err}");
    }
    let err = blend_on_host(&logits[1..], &c0, &colours, n, m, None).unwrap_err();
    assert!(err.to_string().contains("logits"), "{err}");
    let err = blend_on_host(&logits, &c0, &colours[3..], n, m, None).unwrap_err();
    assert!(err.to_string().contains("source_colours"), "{err}");
}

/// [`HostMlp`]'s contract: the tapped activation is the ReLU after the asked layer, the
/// first-layer addend repeats with its period, and bad shapes are errors that name the stack.
#[test]
fn host_mlp_taps_adds_and_refuses_bad_shapes() {
    use nia_model::kernels::host_mlp::{FirstLayerAddend, HostLinear, HostMlp};
    let dev = device();
    // x -> 2x - 1 (ReLU) -> y + 3: the tap is relu(2x - 1 + addend), the output that plus 3.
    let first = linear(vec![2.0], vec![-1.0], 1, 1, &dev);
    let second = linear(vec![1.0], vec![3.0], 1, 1, &dev);
    let layers = vec![
        HostLinear::read("first", &first).unwrap(),
        HostLinear::read("second", &second).unwrap(),
    ];
    let mlp = HostMlp::new("toy", layers.clone()).unwrap();
    // 600 rows: three tasks, the last one short.
    let rows = 600;
    let x: Vec<f32> = (0..rows).map(|r| (r % 7) as f32 * 0.25 - 0.5).collect();
    let addend = [0.5f32, -10.0];
    let out = mlp
        .forward(
            "toy",
            &x,
            rows,
            Some(FirstLayerAddend {
                values: &addend,
                period: 2,
            }),
            Some(0),
        )
        .unwrap();
    let tapped = out.tapped.unwrap();
    for r in 0..rows {
        let hidden = (2.0 * x[r] - 1.0 + addend[r % 2]).max(0.0);
        assert_eq!(tapped[r], hidden, "row {r}: tap");
        assert_eq!(out.output[r], hidden + 3.0, "row {r}: output");
    }
    let err = |r: Result<(), ShapeError>| r.err().map(|e| e.to_string()).unwrap_or_default();
    assert!(err(mlp.forward("toy", &x[..5], rows, None, None).map(|_| ())).contains("toy"));
    assert!(
        err(mlp.forward("toy", &x, rows, None, Some(1)).map(|_| ())).contains("before the last")
    );
    let bad_period = FirstLayerAddend {
        values: &addend,
        period: 3,
    };
    assert!(err(mlp
        .forward("toy", &x, rows, Some(bad_period), None)
        .map(|_| ()))
    .contains("addend"));
    let wide = linear(vec![1.0, 1.0], vec![0.0, 0.0], 1, 2, &dev);
    let mismatched = vec![
        HostLinear::read("wide", &wide).unwrap(),
        HostLinear::read("wide", &wide).unwrap(),
    ];
    assert!(err(HostMlp::new("mismatched", mismatched).map(|_| ())).contains("mismatched"));
    assert!(err(HostMlp::new("none", Vec::new()).map(|_| ())).contains("none"));
    let empty = HostLinear::new("zero", Vec::new(), Vec::new(), 1, 0).unwrap();
    assert!(err(HostMlp::new("zero wide", vec![empty]).map(|_| ())).contains("at least 1 wide"));
}
