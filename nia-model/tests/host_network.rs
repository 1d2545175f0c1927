//! F_sigma, F_c0 and F_B on the host ([`HostNetwork`], the CPU backends' inference path)
//! against their tensor forms, and the host blend at extreme logits.
//!
//! [`HostNetwork`]: nia_model::field::network_host::HostNetwork

mod common;

use common::{assert_close, assert_finite, device, linear, random, tensor, values, VALUE_TOL};
use nia_data::rng::Rng;
use nia_model::field::heads::{ColourHeadConfig, DensityHeadConfig};
use nia_model::field::positional_encoding::PositionalEncodingConfig;
use nia_model::ibr::blender::{mix, BlendInputs, BlenderConfig};
use nia_model::ibr::c0_weight_scale::rescale_c0_weight;
use nia_model::shape::ShapeError;
use nia_model::variant::Variant;

/// F_sigma, F_c0 and F_B on the host ([`HostNetwork`], the CPU backends' inference path)
/// against their tensor forms: M across several row tasks with a remainder, and one point;
/// N of 1 and 3; F_B with and without view statistics, with and without features; inputs
/// large enough that the ReLUs switch many units off.
#[test]
fn host_network_matches_the_tensor_heads_and_blender() {
    use nia_model::field::network_host::HostNetwork;
    let dev = device();
    let (d, d_dir, d_hidden) = (12, 27, 24);
    let mut rng = Rng::new(91);
    for (statistics, features, n) in [
        (false, true, 3usize),
        (true, true, 3),
        (false, true, 1),
        (true, false, 3),
        (false, false, 1),
    ] {
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
            .with_reads_features(features)
            .init(&dev);
        let host = HostNetwork::read(&density, &colour, &blender).unwrap();
        for m in [600usize, 1] {
            let case = format!("statistics {statistics}, features {features}, N {n}, M {m}");
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

/// F_B without features reads neither p_n nor h: its logits, on the tensor path and on the
/// host, are the same whatever they hold (and whatever their widths), and they still follow
/// what it does read (a view's colour); its first layer is `d_hat, o, flag, c` wide per token
/// and `psi, mean c, var c` per point.
#[test]
fn blender_without_features_ignores_pixel_features_and_h() {
    use nia_model::field::heads::ColourHeadConfig;
    use nia_model::field::network_host::HostNetwork;
    let dev = device();
    let (n, m) = (3usize, 40usize);
    let mut rng = Rng::new(5);
    dev.seed(3);
    let blender = BlenderConfig::new()
        .with_d_pixel(12)
        .with_d_h(24)
        .with_d_hidden(16)
        .with_view_statistics(true)
        .with_reads_features(false)
        .init(&dev);
    assert_eq!(blender.token_input.weight.dims(), [4 + 2 + 3, 16]);
    assert_eq!(blender.point_input.weight.dims(), [1 + 6, 16]);
    let density = DensityHeadConfig::new().with_d_input(12).init(&dev);
    let colour = ColourHeadConfig::new().with_d_input(12).init(&dev);
    let host = HostNetwork::read(&density, &colour, &blender).unwrap();
    let inputs = |d: usize, d_h: usize, rng: &mut Rng| BlendInputs {
        c0: tensor(vec![0.3; m * 3], [m, 3], &dev),
        confidence: tensor(vec![0.5; m], [m, 1], &dev),
        h: tensor(random(rng, m * d_h, -5.0, 5.0), [m, d_h], &dev),
        source_colours: tensor(
            (0..n * m * 3).map(|i| (i % 7) as f32 / 7.0).collect(),
            [n, m, 3],
            &dev,
        ),
        pixel_feature: tensor(random(rng, n * m * d, -5.0, 5.0), [n, m, d], &dev),
        view_dir_features: tensor(
            (0..n * m * 4).map(|i| (i % 5) as f32 / 5.0).collect(),
            [n, m, 4],
            &dev,
        ),
        visibility: tensor(vec![1.0; n * m], [n, m], &dev),
    };
    let a = inputs(12, 24, &mut rng);
    let b = inputs(7, 3, &mut rng);
    let logits = |x: &BlendInputs| values(blender.forward(x).unwrap());
    let host_weights = |x: &BlendInputs| {
        values(
            host.blend_colour(&blender, x.clone(), None)
                .unwrap()
                .0
                .blend_weights,
        )
    };
    assert_eq!(logits(&a), logits(&b));
    assert_eq!(host_weights(&a), host_weights(&b));
    assert_finite(&logits(&a), "logits without features");
    let mut c = a.clone();
    c.source_colours = c.source_colours.clone().mul_scalar(0.5);
    assert_ne!(
        logits(&a),
        logits(&c),
        "a view's colour must move the logits"
    );
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
