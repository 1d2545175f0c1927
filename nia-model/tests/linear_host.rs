//! The linear layer as one host operation with its own backward (`nia_model::kernels::linear_host`)
//! against burn's `Linear::forward` and `relu`: values and the gradients of the input, the
//! weight and the bias, on flex with and without autodiff.

mod common;

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation::relu;
use common::{relative_gap, tensor, values as read};
use nia_data::rng::Rng;
use nia_model::kernels::linear_host::linear;

/// `n` values in [-1, 1) drawn from `seed`.
fn values(n: usize, seed: u64) -> Vec<f32> {
    let mut rng = Rng::new(seed);
    (0..n).map(|_| rng.range(-1.0, 1.0)).collect()
}

/// A layer with the given weights on `device`.
fn layer(d_in: usize, d_out: usize, bias: bool, seed: u64, device: &Device) -> Linear {
    Linear {
        weight: Param::from_tensor(tensor(values(d_in * d_out, seed), [d_in, d_out], device)),
        bias: bias.then(|| Param::from_tensor(tensor(values(d_out, seed + 1), [d_out], device))),
    }
}

/// The output and the gradients of `sum(y * r)` for x, W and b (b empty without a bias),
/// through the host operation or burn's layer.
fn run(
    device: &Device,
    shape: (usize, usize, usize),
    bias: bool,
    relu_after: bool,
    host: bool,
) -> [Vec<f32>; 4] {
    let (m, d_in, d_out) = shape;
    let layer = layer(d_in, d_out, bias, 7, device);
    let x = tensor(values(m * d_in, 3), [m, d_in], device).require_grad();
    let y = if host {
        linear(&layer, x.clone(), relu_after)
    } else {
        let y = layer.forward(x.clone());
        if relu_after {
            relu(y)
        } else {
            y
        }
    };
    let r = tensor(values(m * d_out, 11), [m, d_out], device);
    let grads = (y.clone() * r).sum().backward();
    let grad = |t: Tensor<2>| t.grad(&grads).map(read).unwrap_or_default();
    [
        read(y),
        grad(x),
        grad(layer.weight.val()),
        layer
            .bias
            .as_ref()
            .and_then(|b| b.val().grad(&grads))
            .map(read)
            .unwrap_or_default(),
    ]
}

#[test]
fn host_linear_matches_burns_layer_values_and_gradients() {
    let device = Device::flex().autodiff();
    // Row counts below and above the parallel thresholds, widths from 1 to 70.
    for &(m, d_in, d_out) in &[(1, 3, 1), (37, 5, 16), (300, 27, 4), (5000, 70, 33)] {
        for bias in [true, false] {
            for relu_after in [false, true] {
                let got = run(&device, (m, d_in, d_out), bias, relu_after, true);
                let want = run(&device, (m, d_in, d_out), bias, relu_after, false);
                for (what, (g, w)) in ["y", "dx", "dW", "db"].iter().zip(got.iter().zip(&want)) {
                    assert!(g.iter().all(|v| v.is_finite()), "{what} not finite");
                    let gap = relative_gap(g, w);
                    assert!(
                        gap <= 1e-5,
                        "[{m}, {d_in}] -> {d_out}, bias {bias}, relu {relu_after}: {what} gap {gap}"
                    );
                }
                assert_eq!(got[3].is_empty(), !bias);
                // Something flows: the input's gradient is not all zero.
                if m > 1 {
                    assert!(got[1].iter().any(|v| *v != 0.0));
                }
            }
        }
    }
}

#[test]
fn host_linear_without_autodiff_and_on_strided_input() {
    let flex = Device::flex();
    let layer = layer(6, 5, true, 1, &flex);
    // x as the transpose of a [6, 40] tensor: a strided view.
    let xt = tensor(values(6 * 40, 2), [6, 40], &flex);
    let x = xt.clone().transpose();
    let got = read(linear(&layer, x.clone(), true));
    let want = read(relu(layer.forward(x)));
    assert!(relative_gap(&got, &want) <= 1e-6);
    // No rows: an empty output of the layer's width.
    let empty = linear(&layer, Tensor::<2>::zeros([0, 6], &flex), false);
    assert_eq!(empty.dims(), [0, 5]);
}

#[test]
fn relu_passes_no_gradient_where_the_output_is_zero() {
    // Rows of zeros with a zero bias give outputs of exactly 0: burn's ReLU passes no gradient
    // there, and neither does the host operation; a negative pre-activation passes none either.
    let device = Device::flex().autodiff();
    let layer = Linear {
        weight: Param::from_tensor(tensor(vec![1.0, -1.0, 2.0, 0.5], [2, 2], &device)),
        bias: Some(Param::from_tensor(tensor(vec![0.0, 0.0], [2], &device))),
    };
    let x = tensor(vec![0.0, 0.0, 1.0, 0.0, -1.0, 0.0], [3, 2], &device).require_grad();
    let y = linear(&layer, x.clone(), true);
    assert_eq!(read(y.clone()), vec![0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
    let grads = y.sum().backward();
    // Row 0 (y = 0, 0): nothing; row 1 (y = 1, 0): W[:, 0]; row 2 (y = 0, 1): W[:, 1].
    assert_eq!(
        read(x.grad(&grads).unwrap()),
        vec![0.0, 0.0, 1.0, 2.0, -1.0, 0.5]
    );
    assert_eq!(
        read(layer.bias.as_ref().unwrap().val().grad(&grads).unwrap()),
        vec![1.0, 1.0]
    );
}

#[test]
fn host_linear_is_the_same_whatever_the_number_of_threads() {
    let device = Device::flex().autodiff();
    let reference = run(&device, (20_000, 40, 24), true, true, true);
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let got = pool.install(|| run(&device, (20_000, 40, 24), true, true, true));
        assert_eq!(got, reference, "{threads} threads");
    }
}

#[test]
#[allow(deprecated)] // Device::ndarray(): the reference CPU backend the project keeps
fn other_backends_run_burns_layer() {
    let nd = Device::ndarray().autodiff();
    let got = run(&nd, (50, 9, 7), true, true, true);
    let want = run(&nd, (50, 9, 7), true, true, false);
    assert_eq!(got, want);
}
