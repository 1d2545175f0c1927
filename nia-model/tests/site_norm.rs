//! `ReLU(SiteNorm(x))` as one host operation with its own backward
//! (`nia_model::body_volume::site_norm_op`, on flex) against the tensor form (ndarray): values
//! and the gradients of x, gamma and beta, the hard cases and the thread count; and the same
//! operation from the backend's primitives (`site_norm_device`, what training on a GPU runs) on
//! ndarray and on wgpu.

mod common;

use burn::module::Param;
use burn::prelude::*;
use common::{relative_gap, tensor, values};
use nia_data::rng::Rng;
use nia_model::body_volume::site_norm_op::site_norm_relu;
use nia_model::body_volume::{SiteNorm, SiteNormConfig};

/// A norm with scale and shift drawn from `seed`, on `device`.
fn norm(c: usize, seed: u64, device: &Device) -> SiteNorm {
    let mut rng = Rng::new(seed);
    let mut norm = SiteNormConfig::new(c).init(device);
    let gamma: Vec<f32> = (0..c).map(|_| rng.range(0.5, 2.0)).collect();
    let beta: Vec<f32> = (0..c).map(|_| rng.range(-0.5, 0.5)).collect();
    norm.gamma = Param::from_tensor(tensor(gamma, [c], device));
    norm.beta = Param::from_tensor(tensor(beta, [c], device));
    norm
}

/// `ReLU(SiteNorm(x))` and the gradients of `sum(y * R)` in x, gamma and beta, by
/// `SiteNorm::forward_relu` (the backend's own choice).
fn run(device: &Device, x: &[f32], shape: [usize; 3]) -> Vec<Vec<f32>> {
    run_with(device, x, shape, false)
}

/// [`run`], or with `by_op` by the operation whatever the backend.
fn run_with(device: &Device, x: &[f32], [n, p, c]: [usize; 3], by_op: bool) -> Vec<Vec<f32>> {
    let ad = device.clone().autodiff();
    let norm = norm(c, 3, &ad);
    let x = tensor(x.to_vec(), [n, p, c], &ad).require_grad();
    let mut rng = Rng::new(4);
    let r: Vec<f32> = (0..n * p * c).map(|_| rng.range(-1.0, 1.0)).collect();
    let y = if by_op {
        site_norm_relu(x.clone(), norm.gamma.val(), norm.beta.val(), 1e-3)
    } else {
        norm.forward_relu(x.clone()).unwrap()
    };
    let grads = (y.clone() * tensor(r, [n, p, c], &ad)).sum().backward();
    vec![
        values(y),
        values(x.grad(&grads).unwrap()),
        values(norm.gamma.val().grad(&grads).unwrap()),
        values(norm.beta.val().grad(&grads).unwrap()),
    ]
}

const WHAT: [&str; 4] = ["y", "dx", "d gamma", "d beta"];

/// Features of three views with their own scales and offsets (`offset` added to all).
fn features([n, p, c]: [usize; 3], offset: f32, seed: u64) -> Vec<f32> {
    let mut rng = Rng::new(seed);
    (0..n * p * c)
        .map(|i| rng.normal() * (1 + i / (p * c)) as f32 * 3.0 + offset)
        .collect()
}

#[test]
#[allow(deprecated)] // Device::ndarray(): the reference CPU backend the project keeps
fn host_site_norm_matches_the_tensor_form_values_and_gradients() {
    // One block of sites, several blocks with a short last one, one site (variance 0: x_hat 0,
    // y = ReLU(beta)), and features far from zero (the variance of a large mean).
    for (shape, offset, tol) in [
        ([3, 50, 4], 0.0, 2e-6),
        ([2, 1300, 8], 0.0, 2e-6),
        ([3, 1, 5], 0.0, 2e-6),
        // The tensor form's f32 statistics lose digits to the mean here (gaps of 4e-5 in y
        // and 1.6e-4 in d gamma); the host sums are f64.
        ([2, 700, 3], 1e3, 1e-3),
    ] {
        let x = features(shape, offset, 7);
        let got = run(&Device::flex(), &x, shape);
        let want = run(&Device::ndarray(), &x, shape);
        for ((what, g), w) in WHAT.iter().zip(&got).zip(&want) {
            assert!(
                g.iter().all(|v| v.is_finite()),
                "{shape:?} {what} not finite"
            );
            let gap = relative_gap(g, w);
            assert!(gap <= tol, "{shape:?} offset {offset}: {what} gap {gap}");
        }
        // The ReLU cut about half of the values to exactly 0.
        let zeros = got[0].iter().filter(|&&v| v == 0.0).count();
        assert!(zeros > 0, "{shape:?}: no value cut");
    }
}

#[test]
fn a_constant_channel_normalises_to_zero_and_stays_finite() {
    // Every site equal: variance 0, x_hat 0 (not 0/0), y = ReLU(beta), finite gradients.
    let (n, p, c) = (2, 40, 3);
    let x = vec![7.5f32; n * p * c];
    let got = run(&Device::flex(), &x, [n, p, c]);
    let beta = values(norm(c, 3, &Device::flex()).beta.val());
    for (i, &y) in got[0].iter().enumerate() {
        assert_eq!(y, beta[i % c].max(0.0), "y[{i}]");
    }
    for (what, g) in WHAT.iter().zip(&got).skip(1) {
        assert!(g.iter().all(|v| v.is_finite()), "{what} not finite");
    }
}

#[test]
fn a_nan_feature_comes_out_as_nan() {
    // The ReLU keeps NaN as burn's does (never a silent 0): every value of its view and channel
    // depends on the mean.
    let (n, p, c) = (1, 10, 2);
    let mut x = features([n, p, c], 0.0, 8);
    x[4] = f32::NAN;
    let dev = Device::flex();
    let y = values(
        norm(c, 3, &dev)
            .forward_relu(tensor(x, [n, p, c], &dev))
            .unwrap(),
    );
    assert!((0..p).all(|s| y[s * c].is_nan()), "channel 0: {y:?}");
}

#[test]
fn host_site_norm_is_the_same_whatever_the_number_of_threads() {
    let shape = [3, 2000, 8];
    let x = features(shape, 0.5, 9);
    let reference = run(&Device::flex(), &x, shape);
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let got = pool.install(|| run(&Device::flex(), &x, shape));
        assert_eq!(got, reference, "{threads} threads");
    }
}

/// Got against want within `tol` (relative to the largest), all finite.
fn assert_close(got: &[Vec<f32>], want: &[Vec<f32>], tol: f32, case: &str) {
    for ((what, g), w) in WHAT.iter().zip(got).zip(want) {
        assert!(g.iter().all(|v| v.is_finite()), "{case}: {what} not finite");
        let gap = relative_gap(g, w);
        assert!(gap <= tol, "{case}: {what} gap {gap}");
    }
}

#[test]
#[allow(deprecated)] // Device::ndarray(): the reference CPU backend the project keeps
fn device_site_norm_matches_the_tensor_form_on_ndarray() {
    // Several views, one site (variance 0), a constant channel everywhere (x_hat 0, not 0/0).
    let constant = vec![7.5f32; 2 * 40 * 3];
    for (shape, x) in [
        ([3, 50, 4], features([3, 50, 4], 0.0, 7)),
        ([2, 1300, 8], features([2, 1300, 8], 0.0, 8)),
        ([3, 1, 5], features([3, 1, 5], 0.0, 9)),
        ([2, 40, 3], constant),
    ] {
        let got = run_with(&Device::ndarray(), &x, shape, true);
        let want = run_with(&Device::ndarray(), &x, shape, false);
        assert_close(&got, &want, 2e-6, &format!("{shape:?}"));
        assert!(got[0].contains(&0.0), "{shape:?}: no value cut");
    }
}

#[cfg(feature = "wgpu")]
#[test]
#[allow(deprecated)] // Device::ndarray(): the reference CPU backend the project keeps
fn training_on_wgpu_runs_the_operation_and_matches_ndarray() {
    let Some(wgpu) = common::wgpu_device() else {
        return;
    };
    let shape = [3, 300, 8];
    let x = features(shape, 0.5, 10);
    // forward_relu on wgpu in training takes the operation; on ndarray the tensor form.
    let got = run(&wgpu, &x, shape);
    let want = run(&Device::ndarray(), &x, shape);
    assert_close(&got, &want, 1e-5, "wgpu");
}
