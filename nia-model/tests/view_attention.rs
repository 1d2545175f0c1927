//! The view attention's weighted sum as one host operation with its own backward
//! (`nia_model::field::attention_op`, on flex) against the tensor form (ndarray): values and
//! the gradients of S, L, phi_k and phi_v, the hard cases and the thread count. And the view
//! mean with phi_v after the weights' mean (`ViewCrossAttention::view_mean`) against the mean
//! of Z, on both forms.

mod common;

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use common::{relative_gap, tensor, values};
use nia_data::rng::Rng;
use nia_model::field::attention::ViewCrossAttention;
use nia_model::field::heads::view_mean;

fn random(rng: &mut Rng, n: usize, scale: f32) -> Vec<f32> {
    (0..n).map(|_| rng.range(-scale, scale)).collect()
}

/// The attention with the weights `seed` draws, on `device`.
fn attention(d: usize, seed: u64, device: &Device) -> ViewCrossAttention {
    let mut rng = Rng::new(seed);
    let mut layer = || Linear {
        weight: Param::from_tensor(tensor(random(&mut rng, d * d, 0.5), [d, d], device)),
        bias: Some(Param::from_tensor(tensor(
            random(&mut rng, d, 0.1),
            [d],
            device,
        ))),
    };
    ViewCrossAttention {
        phi_k: layer(),
        phi_v: layer(),
        d_model: d,
    }
}

/// Z and the gradients of `sum(Z * R)` in S, L, phi_k's and phi_v's weights and biases.
fn run(device: &Device, shape: (usize, usize, usize), scale: f32) -> Vec<Vec<f32>> {
    run_with(device, shape, scale, |attention, s, l| {
        attention.forward(s, l).unwrap()
    })
}

/// How the output is computed from S and L.
type Output = fn(&ViewCrossAttention, Tensor<3>, Tensor<3>) -> Tensor<3>;

/// `mean_i z_i` by `ViewCrossAttention::view_mean` (phi_v after the weights' mean), as
/// `[1, M, d]`.
fn folded_mean(attention: &ViewCrossAttention, s: Tensor<3>, l: Tensor<3>) -> Tensor<3> {
    attention.view_mean(s, l).unwrap().unsqueeze_dim(0)
}

/// `mean_i z_i` as the mean of [`ViewCrossAttention::forward`]'s Z, as `[1, M, d]`.
fn mean_of_z(attention: &ViewCrossAttention, s: Tensor<3>, l: Tensor<3>) -> Tensor<3> {
    view_mean(attention.forward(s, l).unwrap()).unsqueeze_dim(0)
}

/// `output(S, L)` and the gradients of `sum(output * R)` in S, L, phi_k's and phi_v's weights
/// and biases.
fn run_with(
    device: &Device,
    (m, n, d): (usize, usize, usize),
    scale: f32,
    output: Output,
) -> Vec<Vec<f32>> {
    let ad = device.clone().autodiff();
    let attention = attention(d, 4, &ad);
    let mut rng = Rng::new(5);
    let s = tensor(random(&mut rng, m * n * d, scale), [n, m, d], &ad).require_grad();
    let l = tensor(random(&mut rng, m * n * d, scale), [n, m, d], &ad).require_grad();
    let z = output(&attention, s.clone(), l.clone());
    let shape = z.dims();
    let r = tensor(random(&mut rng, shape.iter().product(), 1.0), shape, &ad);
    let grads = (z.clone() * r).sum().backward();
    let bias = |layer: &Linear| layer.bias.as_ref().unwrap().val();
    vec![
        values(z),
        values(s.grad(&grads).unwrap()),
        values(l.grad(&grads).unwrap()),
        values(attention.phi_k.weight.val().grad(&grads).unwrap()),
        values(bias(&attention.phi_k).grad(&grads).unwrap()),
        values(attention.phi_v.weight.val().grad(&grads).unwrap()),
        values(bias(&attention.phi_v).grad(&grads).unwrap()),
    ]
}

const WHAT: [&str; 7] = [
    "Z",
    "dS",
    "dL",
    "d phi_k W",
    "d phi_k b",
    "d phi_v W",
    "d phi_v b",
];

#[test]
#[allow(deprecated)] // Device::ndarray(): the reference CPU backend the project keeps
fn host_attention_matches_the_tensor_form_values_and_gradients() {
    for shape in [(1, 1, 4), (37, 3, 8), (500, 4, 16)] {
        let got = run(&Device::flex(), shape, 2.0);
        let want = run(&Device::ndarray(), shape, 2.0);
        for ((what, g), w) in WHAT.iter().zip(&got).zip(&want) {
            assert!(
                g.iter().all(|v| v.is_finite()),
                "{shape:?} {what} not finite"
            );
            let gap = relative_gap(g, w);
            assert!(gap <= 2e-5, "{shape:?} {what}: gap {gap}");
        }
        // With one view the softmax is 1: Z = phi_v(L) + S and no gradient reaches phi_k.
        if shape.1 == 1 {
            assert!(got[3].iter().chain(&got[4]).all(|v| *v == 0.0));
        }
    }
}

#[test]
#[allow(deprecated)]
fn huge_scores_saturate_the_softmax_without_overflow() {
    // Features of 1e3 give scores of about 1e6 / sqrt(d): exp of the unshifted scores would be
    // infinite; the shifted softmax puts all the weight on the largest and stays finite.
    let shape = (50, 3, 8);
    let got = run(&Device::flex(), shape, 1e3);
    let want = run(&Device::ndarray(), shape, 1e3);
    for ((what, g), w) in WHAT.iter().zip(&got).zip(&want) {
        assert!(g.iter().all(|v| v.is_finite()), "{what} not finite");
        let gap = relative_gap(g, w);
        assert!(gap <= 1e-4, "{what}: gap {gap}");
    }
}

#[test]
fn host_attention_is_the_same_whatever_the_number_of_threads() {
    let shape = (3000, 3, 16);
    let reference = run(&Device::flex(), shape, 2.0);
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let got = pool.install(|| run(&Device::flex(), shape, 2.0));
        assert_eq!(got, reference, "{threads} threads");
    }
}

/// The view mean with phi_v after the weights' mean equals the mean of Z, values and every
/// gradient, on the tensor form (ndarray) and on flex's host operation, for one view (the
/// softmax is 1), three and four views, and scores of about 1e6 (the softmax saturates).
#[test]
#[allow(deprecated)]
fn the_view_mean_with_phi_v_after_the_weights_equals_the_mean_of_z() {
    for (shape, scale, tol) in [
        ((1, 1, 4), 2.0, 2e-5),
        ((37, 3, 8), 2.0, 2e-5),
        ((500, 4, 16), 2.0, 2e-5),
        ((50, 3, 8), 1e3, 1e-4),
    ] {
        let want = run_with(&Device::ndarray(), shape, scale, mean_of_z);
        for (backend, device) in [("ndarray", Device::ndarray()), ("flex", Device::flex())] {
            let got = run_with(&device, shape, scale, folded_mean);
            for ((what, g), w) in WHAT.iter().zip(&got).zip(&want) {
                assert_eq!(g.len(), w.len(), "{backend} {shape:?} {what}");
                assert!(
                    g.iter().all(|v| v.is_finite()),
                    "{backend} {shape:?} {what} not finite"
                );
                let gap = relative_gap(g, w);
                assert!(gap <= tol, "{backend} {shape:?} {what}: gap {gap}");
            }
            // One view: no gradient reaches phi_k.
            if shape.1 == 1 {
                assert!(got[3].iter().chain(&got[4]).all(|v| *v == 0.0), "{backend}");
            }
        }
    }
}
