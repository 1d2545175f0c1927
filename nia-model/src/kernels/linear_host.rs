//! A linear layer, with or without the ReLU after it, as one host operation with a
//! hand-written backward (burn's backend extension): on flex, with and without autodiff.
//!
//! `y = act(x W + b)`, `x` `[M, d_in]`, `W` `[d_in, d_out]` (burn's input-major weight), `b`
//! `[d_out]`, act the ReLU or none. burn's `Linear::forward` on flex is a matrix product whose
//! output buffer is zero-filled and then copied again to the runtime's alignment (burn-flex's
//! `FlexTensor::empty`, on the calling thread), then a broadcast addition of the bias and a
//! separate ReLU, and under autodiff each of them has its own backward: the products' outputs
//! allocated the same way, the bias's a reduction, the ReLU's a mask and a masked fill. Here
//! one `gemm` writes the output into a fresh buffer, one pass adds the bias and applies the
//! ReLU, and the backward is
//! - `g' = g * [y > 0]` with the ReLU (burn's rule: no gradient where the output is 0), `g`
//!   without;
//! - `dx = g' W^T`, `dW = x^T g'`, `db = sum over rows of g'`, each only for an input that needs
//!   a gradient.
//!
//! The products run on `gemm` as burn-flex's do (rayon's threads from 192^3 multiply-adds),
//! except `dW`, a small output of a long product that `gemm` runs on one thread: it and `db`
//! sum fixed blocks of rows in parallel and add the blocks' sums in order, so no result
//! depends on the number of threads. Equal to `Linear::forward` (and `relu`) up to float
//! summation order, values and gradients (`nia-model/tests/linear_host.rs`). Other backends
//! run burn's `Linear::forward`.

use std::mem::MaybeUninit;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, Flex};
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation::relu;
use rayon::prelude::*;

use crate::kernels::host_gemm::{self, Strided};
use crate::kernels::host_op::{
    contiguous_f32, dims, flex_tensor, runs_on_host, values, FlexTensor,
};

/// The linear layer as a backend operation: flex, and autodiff over flex with this module's
/// backward.
#[backend_extension(Autodiff, Flex)]
pub trait LinearHostBackend: Backend {
    /// `x` `[M, d_in]`, `weight` `[d_in, d_out]`, `bias` `[d_out]` -> `[M, d_out]`, with the
    /// ReLU applied when `relu`.
    fn linear_host(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        relu: bool,
    ) -> FloatTensor<Self>;
}

/// Which gradients a backward computes.
#[derive(Debug, Clone, Copy)]
pub struct Wanted {
    pub x: bool,
    pub weight: bool,
    pub bias: bool,
}

/// The gradients of [`LinearKernels::linear_backward`], each `None` when not wanted.
pub struct LinearGradients<T> {
    pub x: Option<T>,
    pub weight: Option<T>,
    pub bias: Option<T>,
}

/// The host kernels on a concrete backend's buffers.
pub trait LinearKernels: Backend {
    /// The forward, shapes as in [`LinearHostBackend::linear_host`].
    fn linear_forward(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        relu: bool,
    ) -> FloatTensor<Self>;
    /// The backward of the output gradient `grad` `[M, d_out]`; `output` is the forward's
    /// output when the ReLU was applied.
    fn linear_backward(
        grad: FloatTensor<Self>,
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        output: Option<FloatTensor<Self>>,
        wanted: Wanted,
    ) -> LinearGradients<FloatTensor<Self>>;
}

/// Multiply-adds from which a product runs on rayon's threads (burn-flex's threshold).
const PARALLEL_PRODUCT: usize = 192 * 192 * 192;

/// Rows per task of the element-wise passes and of the bias gradient's block sums.
const ROWS_PER_TASK: usize = 1024;

/// Values from which the element-wise passes run on rayon's threads (below, handing the work
/// to the pool costs more than it saves).
const PARALLEL_VALUES: usize = 64 * 1024;

/// `gemm`'s threads for an `[m, k] x [k, n]` product.
fn parallelism(m: usize, n: usize, k: usize) -> gemm::Parallelism {
    if m.saturating_mul(n).saturating_mul(k) >= PARALLEL_PRODUCT {
        gemm::Parallelism::Rayon(0)
    } else {
        gemm::Parallelism::None
    }
}

/// `lhs [m, k] x rhs [k, n]` into a new row-major `[m, n]` buffer, on rayon's threads from
/// [`PARALLEL_PRODUCT`] multiply-adds.
fn product(m: usize, n: usize, k: usize, lhs: Strided<'_>, rhs: Strided<'_>) -> Vec<f32> {
    host_gemm::product([m, n, k], lhs, rhs, parallelism(m, n, k))
}

/// Rows per block of the weight gradient's partial products.
const WEIGHT_GRADIENT_ROWS: usize = 2048;

/// `dW = x^T g'` for `x` `[M, k]` and `g'` `[M, n]` row-major. The output is small and the
/// product long (M rows), which `gemm` cannot spread over threads, so fixed blocks of
/// [`WEIGHT_GRADIENT_ROWS`] rows give partial products on rayon's threads, added in order: the
/// result does not depend on the number of threads.
fn weight_gradient(x: &[f32], g: &[f32], k: usize, n: usize) -> Vec<f32> {
    let m = x.len().checked_div(k).unwrap_or(g.len() / n.max(1));
    let block = |first: usize| {
        let rows = WEIGHT_GRADIENT_ROWS.min(m - first);
        host_gemm::product(
            [k, n, rows],
            Strided::transposed(&x[first * k..(first + rows) * k], k),
            Strided::rows(&g[first * n..(first + rows) * n], n),
            gemm::Parallelism::None,
        )
    };
    if m <= WEIGHT_GRADIENT_ROWS {
        return block(0);
    }
    let partials: Vec<Vec<f32>> = (0..m)
        .step_by(WEIGHT_GRADIENT_ROWS)
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(block)
        .collect();
    let mut total = partials[0].clone();
    for p in &partials[1..] {
        for (a, v) in total.iter_mut().zip(p) {
            *a += v;
        }
    }
    total
}

/// `y[i, :] = act(y[i, :] + b)` for the rows of a row-major `[_, b.len()]` buffer.
fn add_bias_and_activate(y: &mut [f32], bias: &[f32], relu: bool) {
    let n = bias.len();
    if n == 0 {
        return;
    }
    let rows = |block: &mut [f32]| {
        for row in block.chunks_exact_mut(n) {
            for (v, b) in row.iter_mut().zip(bias) {
                let s = *v + b;
                *v = if relu && !(s > 0.0) { 0.0 } else { s };
            }
        }
    };
    if y.len() < PARALLEL_VALUES {
        rows(y);
    } else {
        y.par_chunks_mut(n * ROWS_PER_TASK).for_each(rows);
    }
}

/// `g * [y > 0]`, element by element.
fn relu_gradient(grad: &[f32], output: &[f32]) -> Vec<f32> {
    assert_eq!(
        grad.len(),
        output.len(),
        "host linear: gradient and output sizes"
    );
    fn mask(o: &mut [MaybeUninit<f32>], g: &[f32], y: &[f32]) {
        for ((o, &g), &y) in o.iter_mut().zip(g).zip(y) {
            o.write(if y > 0.0 { g } else { 0.0 });
        }
    }
    let mut out: Vec<f32> = Vec::with_capacity(grad.len());
    let dst = &mut out.spare_capacity_mut()[..grad.len()];
    if grad.len() < PARALLEL_VALUES {
        mask(dst, grad, output);
    } else {
        dst.par_chunks_mut(PARALLEL_VALUES)
            .zip(
                grad.par_chunks(PARALLEL_VALUES)
                    .zip(output.par_chunks(PARALLEL_VALUES)),
            )
            .for_each(|(o, (g, y))| mask(o, g, y));
    }
    // SAFETY: `mask` wrote every one of the first `grad.len()` values.
    unsafe { out.set_len(grad.len()) };
    out
}

/// The column sums of a row-major `[_, n]` buffer: blocks of rows summed in parallel, the
/// blocks' sums added in order.
fn column_sums(g: &[f32], n: usize) -> Vec<f32> {
    let mut total = vec![0.0f32; n];
    if n == 0 {
        return total;
    }
    let block_sum = |block: &[f32]| {
        let mut s = vec![0.0f32; n];
        for row in block.chunks_exact(n) {
            for (a, v) in s.iter_mut().zip(row) {
                *a += v;
            }
        }
        s
    };
    // The same blocks either way, so the sum does not depend on the threads.
    let blocks: Vec<Vec<f32>> = if g.len() < PARALLEL_VALUES {
        g.chunks(n * ROWS_PER_TASK).map(block_sum).collect()
    } else {
        g.par_chunks(n * ROWS_PER_TASK).map(block_sum).collect()
    };
    for s in blocks {
        for (a, v) in total.iter_mut().zip(&s) {
            *a += v;
        }
    }
    total
}

impl LinearKernels for Flex {
    fn linear_forward(
        x: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        relu: bool,
    ) -> FlexTensor {
        let (x, w, b) = (
            contiguous_f32(x),
            contiguous_f32(weight),
            contiguous_f32(bias),
        );
        let [m, k] = dims::<2>(&x);
        let n = dims::<2>(&w)[1];
        let mut y = product(
            m,
            n,
            k,
            Strided::rows(values(&x), k),
            Strided::rows(values(&w), n),
        );
        add_bias_and_activate(&mut y, values(&b), relu);
        flex_tensor(y, [m, n])
    }

    fn linear_backward(
        grad: FlexTensor,
        x: FlexTensor,
        weight: FlexTensor,
        output: Option<FlexTensor>,
        wanted: Wanted,
    ) -> LinearGradients<FlexTensor> {
        let (g, x, w) = (
            contiguous_f32(grad),
            contiguous_f32(x),
            contiguous_f32(weight),
        );
        let [m, n] = dims::<2>(&g);
        let k = dims::<2>(&x)[1];
        let masked = output.map(|y| relu_gradient(values(&g), values(&contiguous_f32(y))));
        let g = masked.as_deref().unwrap_or(values(&g));
        let dx = wanted.x.then(|| {
            let dx = product(
                m,
                k,
                n,
                Strided::rows(g, n),
                Strided::transposed(values(&w), n),
            );
            flex_tensor(dx, [m, k])
        });
        let dw = wanted
            .weight
            .then(|| flex_tensor(weight_gradient(values(&x), g, k, n), [k, n]));
        let db = wanted.bias.then(|| flex_tensor(column_sums(g, n), [n]));
        LinearGradients {
            x: dx,
            weight: dw,
            bias: db,
        }
    }
}

impl LinearHostBackend for Flex {
    fn linear_host(x: FlexTensor, weight: FlexTensor, bias: FlexTensor, relu: bool) -> FlexTensor {
        <Flex as LinearKernels>::linear_forward(x, weight, bias, relu)
    }
}

/// The backward of [`LinearHostBackend::linear_host`] under autodiff.
#[derive(Debug)]
struct LinearHostBackward;

impl<B: Backend + LinearKernels> Backward<B, 3> for LinearHostBackward {
    /// `x`, the weight, and the output when the ReLU was applied.
    type State = (FloatTensor<B>, FloatTensor<B>, Option<FloatTensor<B>>);

    fn backward(
        self,
        ops: Ops<Self::State, 3>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let (x, weight, output) = ops.state;
        let [node_x, node_w, node_b] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let wanted = Wanted {
            x: node_x.is_some(),
            weight: node_w.is_some(),
            bias: node_b.is_some(),
        };
        let got = B::linear_backward(grad, x, weight, output, wanted);
        for (node, g) in [(node_x, got.x), (node_w, got.weight), (node_b, got.bias)] {
            if let (Some(node), Some(g)) = (node, g) {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

impl<B: Backend + LinearKernels, C: CheckpointStrategy> LinearHostBackend for Autodiff<B, C> {
    fn linear_host(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        relu: bool,
    ) -> FloatTensor<Self> {
        match LinearHostBackward
            .prepare::<C>([x.node(), weight.node(), bias.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (x, w, b) = (
                    x.into_primitive(),
                    weight.into_primitive(),
                    bias.into_primitive(),
                );
                let y = B::linear_forward(x.clone(), w.clone(), b, relu);
                prep.finish((x, w, relu.then(|| y.clone())), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::linear_forward(
                x.into_primitive(),
                weight.into_primitive(),
                bias.into_primitive(),
                relu,
            )),
        }
    }
}

/// `layer` applied to the rows of `x`, then the ReLU when `relu`: the host operation above on
/// flex (with or without autodiff), burn's `Linear::forward` (and `relu`) elsewhere.
///
/// # Shapes
/// - `x`: `[M, d_in]`
/// - output: `[M, d_out]`
pub fn linear(layer: &Linear, x: Tensor<2>, relu_after: bool) -> Tensor<2> {
    let device = x.device();
    if !runs_on_host(&device) {
        let y = layer.forward(x);
        return if relu_after { relu(y) } else { y };
    }
    let weight = layer.weight.val();
    let bias = match &layer.bias {
        Some(b) => b.val(),
        None => Tensor::zeros([weight.dims()[1]], &device),
    };
    Tensor::from_dispatch(<Dispatch as LinearHostBackend>::linear_host(
        x.into_dispatch(),
        weight.into_dispatch(),
        bias.into_dispatch(),
        relu_after,
    ))
}
