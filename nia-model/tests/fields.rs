//! Per-point fields: positional encoding, view-wise cross-attention, F_sigma / F_c0, and the
//! IBR sampling and fixed colour rules. The blender F_B and the variants' colour rules are in
//! `blender.rs`, the host network in `host_network.rs`.

mod common;

use burn::prelude::*;
use common::{assert_close, device, identity, linear, random, tensor, values, VALUE_TOL};
use nia_data::rng::Rng;
use nia_model::field::attention::ViewCrossAttentionConfig;
use nia_model::field::heads::{view_mean, ColourHeadConfig, DensityHead, DensityHeadConfig};
use nia_model::field::positional_encoding::PositionalEncodingConfig;
use nia_model::ibr::{
    cosine_weights, fetch_source_colours, sample_views, simple_average_weights, PixelFeatureConfig,
};
use nia_model::shape::ShapeError;

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
