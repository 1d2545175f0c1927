//! The blender F_B (token layout, any view count, extreme logits, gradients against finite
//! differences, invisible views) and the variants' colour rules.

mod common;

use burn::prelude::*;
use common::{
    assert_close, assert_finite, assert_gradient, device, random, tensor, values, MLP_TOL,
    VALUE_TOL,
};
use nia_data::rng::Rng;
use nia_model::ibr::blender::{blend, BlendInputs, Blender, BlenderConfig};
use nia_model::renderer::render_rays;
use nia_model::softmax::stable_softmax;
use nia_model::variant::Variant;

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
