//! Volume rendering, the stratified sampler and the loss: hand-computed cases, finite-difference
//! gradients and the numerical hard cases of docs/method.md "Numerics".

mod common;

use burn::prelude::*;
use common::{assert_close, central_difference, device, tensor, values};
use nia_data::rng::Rng;
use nia_model::loss::{
    colour_matched_target, distortion_loss, patch_ssim_loss, psnr_from_mse, render_loss,
};
use nia_model::renderer::{render_rays, sample_weights};
use nia_model::sampler::{stratified_t, SamplerError};

/// f32 forward values along two different evaluation orders: a few ulps of O(1) values.
const VALUE_TOL: f32 = 1e-5;
/// Central finite-difference step (sigma in 1/m and colours of O(1), deltas of O(0.1) m).
const FD_STEP: f32 = 1e-2;
/// Finite differences vs autodiff: O(FD_STEP^2) truncation with O(1) third derivatives plus
/// f32 rounding of the loss over the step (~1e-7 / 1e-2); absolute plus relative part.
const FD_ABS_TOL: f32 = 1e-3;
const FD_REL_TOL: f32 = 1e-2;

fn assert_finite(v: &[f32], what: &str) {
    assert!(!v.is_empty(), "{what}: empty");
    assert!(v.iter().all(|x| x.is_finite()), "{what}: not finite: {v:?}");
}

/// One ray from per-sample values.
struct Ray {
    sigma: Vec<f32>,
    colour: Vec<f32>,
    t: Vec<f32>,
    far: f32,
}

fn render_one(ray: &Ray, dev: &Device) -> nia_model::renderer::RenderOutput {
    let s = ray.sigma.len();
    let colour = tensor(ray.colour.clone(), [1, s, 3], dev);
    render_rays(
        tensor(ray.sigma.clone(), [1, s], dev),
        colour.clone(),
        colour,
        tensor(ray.t.clone(), [1, s], dev),
        tensor(vec![ray.far], [1], dev),
        None,
    )
    .unwrap()
}

// ----------------------------------------------------------------------------------------------
// Hand-computed cases
// ----------------------------------------------------------------------------------------------

#[test]
fn single_opaque_sample_gives_its_colour() {
    let dev = device();
    let out = render_one(
        &Ray {
            sigma: vec![1e4],
            colour: vec![0.2, 0.5, 0.9],
            t: vec![0.5],
            far: 1.5,
        },
        &dev,
    );
    assert_close(&values(out.rgb), &[0.2, 0.5, 0.9], VALUE_TOL, "rgb");
    assert_close(&values(out.rgb0), &[0.2, 0.5, 0.9], VALUE_TOL, "rgb0");
    assert_close(&values(out.acc), &[1.0], VALUE_TOL, "acc");
    assert_close(&values(out.depth), &[0.5], VALUE_TOL, "depth");
    assert!(out.blend_weights.is_none());
}

#[test]
fn transparent_ray_is_black() {
    let dev = device();
    let out = render_one(
        &Ray {
            sigma: vec![0.0; 4],
            colour: vec![1.0; 12],
            t: vec![0.1, 0.2, 0.3, 0.4],
            far: 0.5,
        },
        &dev,
    );
    assert_close(&values(out.rgb), &[0.0; 3], 0.0, "rgb");
    assert_close(&values(out.acc), &[0.0], 0.0, "acc");
    assert_close(&values(out.depth), &[0.0], 0.0, "depth");
}

#[test]
fn two_samples_analytic_weights_and_blend() {
    let dev = device();
    // t = (1, 2), far = 4: deltas (1, 2). w0 = 1 - e^-a, w1 = e^-a (1 - e^-2b).
    let (a, b) = (0.7f32, 0.3f32);
    let w0 = 1.0 - (-a).exp();
    let w1 = (-a).exp() * (1.0 - (-2.0 * b).exp());
    let colour = vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let colour0 = vec![0.0, 0.0, 1.0, 0.0, 0.0, 1.0];
    // N + 1 = 2 per-sample blend weights.
    let blend = vec![0.25, 0.75, 1.0, 0.0];
    let out = render_rays(
        tensor(vec![a, b], [1, 2], &dev),
        tensor(colour, [1, 2, 3], &dev),
        tensor(colour0, [1, 2, 3], &dev),
        tensor(vec![1.0, 2.0], [1, 2], &dev),
        tensor(vec![4.0], [1], &dev),
        Some(tensor(blend, [1, 2, 2], &dev)),
    )
    .unwrap();
    assert_close(&values(out.rgb), &[w0, w1, 0.0], VALUE_TOL, "rgb");
    assert_close(&values(out.rgb0), &[0.0, 0.0, w0 + w1], VALUE_TOL, "rgb0");
    assert_close(&values(out.acc), &[w0 + w1], VALUE_TOL, "acc");
    assert_close(&values(out.depth), &[w0 + 2.0 * w1], VALUE_TOL, "depth");
    assert_close(
        &values(out.blend_weights.unwrap()),
        &[0.25 * w0 + w1, 0.75 * w0],
        VALUE_TOL,
        "blend weights",
    );
}

#[test]
fn opaque_sample_hides_the_rest_and_weights_match_alpha() {
    let dev = device();
    let ray = Ray {
        sigma: vec![0.0, 1e4, 5.0],
        colour: vec![1.0, 1.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0],
        t: vec![0.0, 0.2, 0.4],
        far: 0.6,
    };
    let out = render_one(&ray, &dev);
    assert_close(&values(out.rgb), &[0.0, 1.0, 0.0], VALUE_TOL, "rgb");
    assert_close(&values(out.depth), &[0.2], VALUE_TOL, "depth");
    // Last delta: t past far clamps to 0 (no negative alpha).
    let w = values(
        sample_weights(
            tensor(vec![3.0, 3.0], [1, 2], &dev),
            tensor(vec![0.1, 0.9], [1, 2], &dev),
            tensor(vec![0.5], [1], &dev),
        )
        .unwrap(),
    );
    let w0 = 1.0 - (-3.0f32 * 0.8).exp();
    assert_close(&w, &[w0, 0.0], VALUE_TOL, "t_last > far gives delta 0");
}

#[test]
fn shape_errors_are_reported() {
    let dev = device();
    // Zeros for 2 rays of 4 samples, but the colour0 and far shapes given.
    let render = |colour0: [usize; 3], far: usize| {
        render_rays(
            Tensor::zeros([2, 4], &dev),
            Tensor::zeros([2, 4, 3], &dev),
            Tensor::zeros(colour0, &dev),
            Tensor::zeros([2, 4], &dev),
            Tensor::zeros([far], &dev),
            None,
        )
    };
    let err = render([2, 3, 3], 2).unwrap_err();
    assert!(err.to_string().contains("colour0"), "{err}");
    assert!(render([2, 4, 3], 3).is_err());
}

// ----------------------------------------------------------------------------------------------
// Gradients
// ----------------------------------------------------------------------------------------------

#[test]
fn gradients_match_finite_differences() {
    let dev = device().autodiff();
    let mut rng = Rng::new(11);
    let (r, s) = (2, 5);
    let sigma_vals: Vec<f32> = (0..r * s).map(|_| rng.range(0.1, 4.0)).collect();
    let colour_vals: Vec<f32> = (0..r * s * 3).map(|_| rng.range(0.0, 1.0)).collect();
    let near = [0.5, 1.0];
    let far = [1.5, 1.6];
    let jitter: Vec<f32> = (0..r * s).map(|_| rng.uniform()).collect();
    let t = tensor(
        stratified_t(&near, &far, s, Some(&jitter)).unwrap(),
        [r, s],
        &dev,
    );
    let far_t = tensor(far.to_vec(), [r], &dev);
    let probe_rgb = tensor(
        (0..r * 3).map(|_| rng.range(-1.0, 1.0)).collect(),
        [r, 3],
        &dev,
    );
    let probe_depth = tensor(vec![0.3, -0.7], [r], &dev);
    let loss = |sigma: Tensor<2>, colour: Tensor<3>| {
        let out = render_rays(
            sigma,
            colour.clone(),
            colour,
            t.clone(),
            far_t.clone(),
            None,
        )
        .unwrap();
        (out.rgb * probe_rgb.clone()).sum()
            + (out.depth * probe_depth.clone()).sum()
            + out.acc.sum()
    };
    let sigma = tensor(sigma_vals.clone(), [r, s], &dev).require_grad();
    let colour = tensor(colour_vals.clone(), [r, s, 3], &dev).require_grad();
    let grads = loss(sigma.clone(), colour.clone()).backward();
    let g_sigma = values(sigma.grad(&grads).unwrap());
    let g_colour = values(colour.grad(&grads).unwrap());
    let scalar = |t: Tensor<1>| values(t)[0];
    let check = |autodiff: f32, fd: f32, what: String| {
        assert!(
            (autodiff - fd).abs() <= FD_ABS_TOL + FD_REL_TOL * fd.abs(),
            "{what}: autodiff {autodiff} vs finite difference {fd}"
        );
    };
    let colour_t = |v: &Vec<f32>| tensor(v.clone(), [r, s, 3], &dev);
    let sigma_t = |v: &Vec<f32>| tensor(v.clone(), [r, s], &dev);
    assert_eq!(g_sigma.len(), sigma_vals.len());
    for (i, &g) in g_sigma.iter().enumerate() {
        let fd = central_difference(&sigma_vals, i, FD_STEP, |v| {
            scalar(loss(sigma_t(&v), colour_t(&colour_vals)))
        });
        check(g, fd, format!("d/dsigma[{i}]"));
    }
    assert_eq!(g_colour.len(), colour_vals.len());
    for (i, &g) in g_colour.iter().enumerate() {
        let fd = central_difference(&colour_vals, i, FD_STEP, |v| {
            scalar(loss(sigma_t(&sigma_vals), colour_t(&v)))
        });
        check(g, fd, format!("d/dcolour[{i}]"));
    }
}

// ----------------------------------------------------------------------------------------------
// Numerical hard cases
// ----------------------------------------------------------------------------------------------

#[test]
fn optical_depth_from_zero_to_1e4_is_finite_with_exact_gradients() {
    let dev = device().autodiff();
    // One sample per ray with delta = far - t = 1 m, so tau = sigma.
    let taus = [0.0f32, 1e-3, 0.5, 1.0, 10.0, 100.0, 1e3, 1e4];
    let r = taus.len();
    let sigma = tensor(taus.to_vec(), [r, 1], &dev).require_grad();
    let colour = tensor(vec![0.5; r * 3], [r, 1, 3], &dev).require_grad();
    let out = render_rays(
        sigma.clone(),
        colour.clone(),
        colour.clone(),
        Tensor::zeros([r, 1], &dev),
        Tensor::ones([r], &dev),
        None,
    )
    .unwrap();
    let acc = values(out.acc.clone());
    let expected_acc: Vec<f32> = taus.iter().map(|tau| 1.0 - (-tau).exp()).collect();
    assert_close(&acc, &expected_acc, VALUE_TOL, "acc = 1 - exp(-tau)");
    let grads = out.acc.sum().backward();
    let g_sigma = values(sigma.grad(&grads).unwrap());
    assert_finite(&g_sigma, "d acc / d sigma");
    // d acc / d sigma = delta exp(-tau): 1 at tau = 0, exactly 0 at tau = 1e4.
    let expected: Vec<f32> = taus.iter().map(|tau| (-tau).exp()).collect();
    assert_close(&g_sigma, &expected, VALUE_TOL, "d acc / d sigma");

    // Several opaque samples in a row: later ones get T = exp(-2e4) = 0, all finite.
    let sigma = tensor(vec![1e4, 1e4, 1e4, 0.5], [1, 4], &dev).require_grad();
    let colour = tensor(
        vec![0.1, 0.2, 0.3, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9],
        [1, 4, 3],
        &dev,
    )
    .require_grad();
    let out = render_rays(
        sigma.clone(),
        colour.clone(),
        colour.clone(),
        tensor(vec![0.0, 1.0, 2.0, 3.0], [1, 4], &dev),
        tensor(vec![4.0], [1], &dev),
        None,
    )
    .unwrap();
    assert_close(
        &values(out.rgb.clone()),
        &[0.1, 0.2, 0.3],
        VALUE_TOL,
        "first opaque wins",
    );
    let grads = (out.rgb.sum() + out.depth.sum()).backward();
    let g_sigma = values(sigma.grad(&grads).unwrap());
    assert_close(&g_sigma, &[0.0; 4], VALUE_TOL, "saturated: zero gradients");
    let g_colour = values(colour.grad(&grads).unwrap());
    let mut expected = vec![0.0f32; 12];
    expected[..3].fill(1.0);
    assert_close(&g_colour, &expected, VALUE_TOL, "d rgb / d c = w");
}

#[test]
fn near_equals_far_rays_give_zeros_and_finite_gradients() {
    let dev = device().autodiff();
    let (r, s) = (3, 4);
    let near = [1.0, 2.0, 0.5];
    let t_vals = stratified_t(&near, &near, s, None).unwrap();
    assert!(t_vals
        .chunks(s)
        .zip(near)
        .all(|(row, n)| row.iter().all(|t| *t == n)));
    let sigma = tensor(vec![5.0; r * s], [r, s], &dev).require_grad();
    let colour = tensor(vec![0.7; r * s * 3], [r, s, 3], &dev).require_grad();
    let blend = tensor(vec![0.5; r * s * 2], [r, s, 2], &dev).require_grad();
    let out = render_rays(
        sigma.clone(),
        colour.clone(),
        colour.clone(),
        tensor(t_vals, [r, s], &dev),
        tensor(near.to_vec(), [r], &dev),
        Some(blend.clone()),
    )
    .unwrap();
    let bw = out.blend_weights.clone().unwrap();
    assert_close(&values(out.rgb.clone()), &[0.0; 9], 0.0, "rgb");
    assert_close(&values(out.acc.clone()), &[0.0; 3], 0.0, "acc");
    assert_close(&values(out.depth.clone()), &[0.0; 3], 0.0, "depth");
    assert_close(&values(bw.clone()), &[0.0; 6], 0.0, "blend weights");
    let grads =
        (out.rgb.sum() + out.rgb0.sum() + out.acc.sum() + out.depth.sum() + bw.sum()).backward();
    for (what, g) in [
        ("sigma", values(sigma.grad(&grads).unwrap())),
        ("colour", values(colour.grad(&grads).unwrap())),
    ] {
        assert_finite(&g, what);
        assert!(
            g.iter().all(|x| *x == 0.0),
            "{what}: zero-length rays have zero gradient"
        );
    }
    assert_finite(&values(blend.grad(&grads).unwrap()), "blend");
}

// ----------------------------------------------------------------------------------------------
// Sampler
// ----------------------------------------------------------------------------------------------

#[test]
fn stratified_t_bins_and_errors() {
    let mid = stratified_t(&[0.0, 1.0], &[1.0, 3.0], 4, None).unwrap();
    assert_close(
        &mid,
        &[0.125, 0.375, 0.625, 0.875, 1.25, 1.75, 2.25, 2.75],
        VALUE_TOL,
        "bin centres",
    );
    let jitter = [0.0, 1.0, 0.5, 0.25];
    let t = stratified_t(&[2.0], &[4.0], 4, Some(&jitter)).unwrap();
    assert_close(&t, &[2.0, 3.0, 3.25, 3.625], VALUE_TOL, "jittered");
    assert!(t.windows(2).all(|w| w[0] <= w[1]), "sorted");

    let mut rng = Rng::new(12);
    let jitter: Vec<f32> = (0..64).map(|_| rng.uniform()).collect();
    let t = stratified_t(&[0.3], &[2.9], 64, Some(&jitter)).unwrap();
    assert!(t.windows(2).all(|w| w[0] <= w[1]));
    assert!(t.iter().all(|x| (0.3..=2.9).contains(x)));

    assert!(matches!(
        stratified_t(&[0.0, 1.0], &[1.0], 4, None),
        Err(SamplerError::Length { field: "far", .. })
    ));
    assert!(matches!(
        stratified_t(&[0.0], &[1.0], 2, Some(&[0.5])),
        Err(SamplerError::Length {
            field: "jitter",
            ..
        })
    ));
    assert!(matches!(
        stratified_t(&[0.0], &[1.0], 2, Some(&[0.5, 1.5])),
        Err(SamplerError::Jitter { index: 1, .. })
    ));
    assert!(matches!(
        stratified_t(&[2.0], &[1.0], 2, None),
        Err(SamplerError::Interval { ray: 0, .. })
    ));
    assert!(matches!(
        stratified_t(&[f32::NAN], &[1.0], 2, None),
        Err(SamplerError::Interval { .. })
    ));
    assert!(matches!(
        stratified_t(&[0.0], &[1.0], 0, None),
        Err(SamplerError::NoSamples)
    ));
    assert_eq!(stratified_t(&[], &[], 3, None).unwrap(), Vec::<f32>::new());
}

// ----------------------------------------------------------------------------------------------
// Loss
// ----------------------------------------------------------------------------------------------

#[test]
fn loss_and_psnr_hand_values() {
    let dev = device();
    let gt = tensor(vec![0.0, 0.5, 1.0, 1.0, 1.0, 1.0], [2, 3], &dev);
    let rgb = tensor(vec![0.1, 0.5, 1.0, 1.0, 1.0, 0.7], [2, 3], &dev);
    let rgb0 = tensor(vec![0.0, 0.5, 0.8, 1.0, 1.0, 1.0], [2, 3], &dev);
    let loss = render_loss(rgb, rgb0, gt).unwrap();
    let mse = (0.01 + 0.09) / 6.0;
    let mse0 = 0.04 / 6.0;
    assert_close(&values(loss.mse), &[mse], VALUE_TOL, "mse");
    assert_close(&values(loss.mse0), &[mse0], VALUE_TOL, "mse0");
    assert_close(&values(loss.total), &[mse + mse0], VALUE_TOL, "total");
    assert!(render_loss(
        Tensor::zeros([2, 3], &dev),
        Tensor::zeros([2, 3], &dev),
        Tensor::zeros([3, 3], &dev)
    )
    .is_err());

    assert!((psnr_from_mse(0.01) - 20.0).abs() < 1e-12);
    assert!((psnr_from_mse(1.0)).abs() < 1e-12);
    assert_eq!(psnr_from_mse(0.0), f64::INFINITY);
}

/// The colour-matched target by hand: a target whose red is the prediction's / 1.1 and whose
/// green is twice the prediction's gets red x 1.1 (within a tolerance of 0.15) and green x 1/1.15
/// (clamped); a black channel stays black and finite; tolerance 0 and NaN change nothing; the
/// prediction gets no gradient through the gain.
#[test]
fn colour_matched_target_hand_values() {
    let dev = device();
    let rgb = tensor(vec![0.55, 0.2, 0.3, 0.22, 0.4, 0.6], [2, 3], &dev);
    let gt = tensor(vec![0.5, 0.4, 0.0, 0.2, 0.8, 0.0], [2, 3], &dev);
    let matched = values(colour_matched_target(&rgb, gt.clone(), 0.15).unwrap());
    let g = 1.0 / 1.15;
    assert_close(
        &matched,
        &[0.55, 0.4 * g, 0.0, 0.22, 0.8 * g, 0.0],
        1e-5,
        "matched target",
    );
    for tolerance in [0.0, f32::NAN] {
        let same = values(colour_matched_target(&rgb, gt.clone(), tolerance).unwrap());
        assert_eq!(same, values(gt.clone()));
    }
    assert!(colour_matched_target(&rgb, Tensor::zeros([3, 3], &dev), 0.1).is_err());

    // No gradient reaches the prediction through the gain: d/d rgb of sum(matched) is 0.
    let ad = dev.autodiff();
    let rgb = tensor(vec![0.55, 0.2, 0.3, 0.22, 0.4, 0.6], [2, 3], &ad).require_grad();
    let gt = tensor(vec![0.5, 0.4, 0.1, 0.2, 0.8, 0.1], [2, 3], &ad);
    let grads = colour_matched_target(&rgb, gt, 0.15)
        .unwrap()
        .sum()
        .backward();
    assert!(rgb
        .grad(&grads)
        .is_none_or(|g| values(g).iter().all(|v| *v == 0.0)));
}

/// mip-NeRF 360's distortion loss by hand: all weight on one sample costs only its own interval
/// (w^2 delta / 3), weight split between two samples 0.5 m apart costs 2 * 0.25 * 0.5 more; a
/// compact ray costs less than a spread one, and empty rays cost nothing.
#[test]
fn distortion_loss_hand_values() {
    let dev = device();
    let t = tensor(
        vec![1.0, 1.5, 2.0, 1.0, 1.5, 2.0, 1.0, 1.5, 2.0],
        [3, 3],
        &dev,
    );
    let delta = tensor(
        vec![0.1, 0.2, 0.3, 0.1, 0.2, 0.3, 0.1, 0.2, 0.3],
        [3, 3],
        &dev,
    );
    // ray 0: one opaque sample; ray 1: split over the first two; ray 2: empty.
    let w = tensor(
        vec![0.0, 1.0, 0.0, 0.5, 0.5, 0.0, 0.0, 0.0, 0.0],
        [3, 3],
        &dev,
    );
    let ray0 = 0.2 / 3.0;
    let ray1 = 2.0 * 0.25 * 0.5 + (0.25 * 0.1 + 0.25 * 0.2) / 3.0;
    let loss = distortion_loss(w, t.clone(), delta.clone()).unwrap();
    assert_close(
        &values(loss),
        &[(ray0 + ray1) / 3.0],
        VALUE_TOL,
        "distortion",
    );
    // Weights in [0, 1] with a huge gap stay finite.
    let far = tensor(vec![0.0, 1e3, 2e3], [1, 3], &dev);
    let w = tensor(vec![0.5, 0.0, 0.5], [1, 3], &dev);
    let d = tensor(vec![0.0, 0.0, 0.0], [1, 3], &dev);
    assert_close(
        &values(distortion_loss(w, far, d).unwrap()),
        &[1000.0],
        1e-3,
        "far gap",
    );
    assert!(distortion_loss(Tensor::zeros([3, 2], &dev), t, delta).is_err());
}

/// The patch SSIM loss: 0 for a patch equal to its target, the hand value of one patch
/// against its target (global means, sample variances, C1 = 1e-4, C2 = 9e-4), finite at a
/// flat patch (zero variances), its gradient the central difference's, and a ray count that
/// is no multiple of the patch refused.
#[test]
fn patch_ssim_loss_hand_values() {
    let dev = device();
    // Two 2 x 2 patches, three channels.
    let gt: Vec<f32> = (0..24).map(|i| ((i * 7) % 11) as f32 / 11.0).collect();
    let loss = |rgb: Vec<f32>| {
        values(
            patch_ssim_loss(
                tensor(rgb, [8, 3], &dev),
                tensor(gt.clone(), [8, 3], &dev),
                2,
            )
            .unwrap(),
        )[0]
    };
    assert!(loss(gt.clone()).abs() < VALUE_TOL, "a perfect prediction");
    // One patch, one channel by hand: x = (0.1, 0.2, 0.3, 0.4), y = (0.4, 0.3, 0.2, 0.1).
    let x = [0.1f32, 0.2, 0.3, 0.4];
    let y = [0.4f32, 0.3, 0.2, 0.1];
    let rgb: Vec<f32> = x.iter().flat_map(|&v| [v, v, v]).collect();
    let target: Vec<f32> = y.iter().flat_map(|&v| [v, v, v]).collect();
    let got = values(
        patch_ssim_loss(tensor(rgb, [4, 3], &dev), tensor(target, [4, 3], &dev), 2).unwrap(),
    )[0];
    let (mu, var, cov) = (0.25f32, 0.05f32 / 3.0, -0.05f32 / 3.0);
    let ssim = ((2.0 * mu * mu + 1e-4) * (2.0 * cov + 9e-4))
        / ((2.0 * mu * mu + 1e-4) * (2.0 * var + 9e-4));
    assert!(
        (got - (1.0 - ssim)).abs() < 1e-4,
        "{got} against {}",
        1.0 - ssim
    );
    // A flat patch and a flat target: finite, and 0 where they agree.
    let flat = vec![0.5f32; 12];
    let flat_loss = values(
        patch_ssim_loss(
            tensor(flat.clone(), [4, 3], &dev),
            tensor(flat, [4, 3], &dev),
            2,
        )
        .unwrap(),
    )[0];
    assert!(flat_loss.is_finite() && flat_loss.abs() < VALUE_TOL);
    // Gradient against central differences.
    let start: Vec<f32> = (0..24).map(|i| ((i * 5) % 13) as f32 / 13.0).collect();
    let ad = device().autodiff();
    let rgb = Tensor::<2>::from_data(TensorData::new(start.clone(), [8, 3]), &ad).require_grad();
    let l = patch_ssim_loss(
        rgb.clone(),
        Tensor::from_data(TensorData::new(gt.clone(), [8, 3]), &ad),
        2,
    )
    .unwrap();
    let grads = l.backward();
    let g = values(rgb.grad(&grads).unwrap());
    for i in [0, 5, 13, 22] {
        let fd = central_difference(&start, i, FD_STEP, loss);
        assert!(
            (g[i] - fd).abs() <= FD_ABS_TOL + FD_REL_TOL * fd.abs(),
            "d/d rgb[{i}]: {} against {fd}",
            g[i]
        );
    }
    let err = patch_ssim_loss(
        tensor(vec![0.0; 9], [3, 3], &dev),
        tensor(vec![0.0; 9], [3, 3], &dev),
        2,
    )
    .unwrap_err();
    assert!(err.to_string().contains("patch_px"), "{err}");
}
