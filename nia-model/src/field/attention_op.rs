//! The view attention's weighted sum as one host operation with a hand-written backward
//! (burn's backend extension): on flex, with and without autodiff.
//!
//! Per point, over its N views: `O_i = sum_j a_ij V_j`, `a_ij = softmax_j(Q_i . K_j / sqrt(d))`
//! (the maximum subtracted, as [`crate::softmax::stable_softmax`] does), for the projections
//! Q = phi_k(S), K = phi_k(L), V = phi_v(L) of [`super::attention::ViewCrossAttention`]. The
//! tensor form broadcasts `[M, N, N, d]` products for the scores and for the weighted values and
//! sums them, and under autodiff each product and sum has its own backward (a `[M, N, N, d]`
//! buffer of ones for every sum's, the broadcast products' gradients reduced again). Here each
//! point is a few N x N dot products on rayon's threads, the weights `a` are kept for the
//! backward, and the backward is, per point,
//! - `dV_j = sum_i a_ij dO_i`, `da_ij = dO_i . V_j`,
//! - `ds_ij = a_ij (da_ij - sum_k a_ik da_ik)` (the softmax's),
//! - `dQ_i = sum_j ds_ij K_j / sqrt(d)`, `dK_j = sum_i ds_ij Q_i / sqrt(d)`.
//!
//! Every point's rows are its own, so nothing depends on the number of threads. Equal to the
//! tensor form up to float rounding, values and gradients (`nia-model/tests/view_attention.rs`).

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, Flex};
use burn::prelude::*;
use rayon::prelude::*;

use crate::host_buffer::zeroed;
use crate::host_op::{contiguous_f32, dims, flex_tensor, values, FlexTensor};

/// The weighted sum as a backend operation: flex, and autodiff over flex with this module's
/// backward.
#[backend_extension(Autodiff, Flex)]
pub trait ViewAttentionBackend: Backend {
    /// `q`, `k`, `v` `[M, N, d]` -> `O` `[M, N, d]`.
    fn view_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

/// The host kernels on a concrete backend's buffers.
pub trait ViewAttentionKernels: Backend {
    /// The output `[M, N, d]` and the attention weights `a` `[M, N, N]`.
    fn view_attention_forward(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
    /// `dQ`, `dK`, `dV` from `dO` (all `[M, N, d]`) and the forward's inputs and weights.
    fn view_attention_backward(
        grad: FloatTensor<Self>,
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
        a: FloatTensor<Self>,
    ) -> [FloatTensor<Self>; 3];
}

/// Points per parallel task.
const POINTS_PER_TASK: usize = 64;

/// Row `i` of the `[N, d]` block of a point that starts at `base`.
fn row(x: &[f32], base: usize, i: usize, d: usize) -> &[f32] {
    &x[base + i * d..base + (i + 1) * d]
}

/// The forward on host slices, `[M, N, d]` each: `O` `[M, N, d]` and `a` `[M, N, N]`.
pub fn forward(q: &[f32], k: &[f32], v: &[f32], n: usize, d: usize) -> (Vec<f32>, Vec<f32>) {
    let m = if n * d == 0 { 0 } else { q.len() / (n * d) };
    let scale = 1.0 / (d as f32).sqrt();
    let mut out = zeroed(m * n * d);
    let mut weights = zeroed(m * n * n);
    if m == 0 {
        return (out, weights);
    }
    out.par_chunks_mut(POINTS_PER_TASK * n * d)
        .zip(weights.par_chunks_mut(POINTS_PER_TASK * n * n))
        .enumerate()
        .for_each(|(task, (out, weights))| {
            for (r, (o, a)) in out
                .chunks_exact_mut(n * d)
                .zip(weights.chunks_exact_mut(n * n))
                .enumerate()
            {
                let base = (task * POINTS_PER_TASK + r) * n * d;
                for i in 0..n {
                    let a_i = &mut a[i * n..(i + 1) * n];
                    for (j, s) in a_i.iter_mut().enumerate() {
                        *s = dot(row(q, base, i, d), row(k, base, j, d)) * scale;
                    }
                    let max = a_i.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
                    let mut total = 0.0f32;
                    for s in a_i.iter_mut() {
                        *s = (*s - max).exp();
                        total += *s;
                    }
                    let o_i = &mut o[i * d..(i + 1) * d];
                    for (j, s) in a_i.iter_mut().enumerate() {
                        *s /= total;
                        for (acc, &x) in o_i.iter_mut().zip(row(v, base, j, d)) {
                            *acc += *s * x;
                        }
                    }
                }
            }
        });
    (out, weights)
}

/// The backward on host slices: `dQ`, `dK`, `dV` (`[M, N, d]`) from `dO` and the forward's
/// `q`, `k`, `v` and weights `a` `[M, N, N]`.
pub fn backward(
    grad: &[f32],
    q: &[f32],
    k: &[f32],
    v: &[f32],
    a: &[f32],
    n: usize,
    d: usize,
) -> [Vec<f32>; 3] {
    let len = q.len();
    let scale = 1.0 / (d as f32).sqrt();
    let (mut dq, mut dk, mut dv) = (zeroed(len), zeroed(len), zeroed(len));
    if len == 0 {
        return [dq, dk, dv];
    }
    let task = POINTS_PER_TASK * n * d;
    dq.par_chunks_mut(task)
        .zip(dk.par_chunks_mut(task))
        .zip(dv.par_chunks_mut(task))
        .enumerate()
        .for_each(|(t, ((dq, dk), dv))| {
            let mut ds = vec![0.0f32; n * n];
            for (r, ((dq, dk), dv)) in dq
                .chunks_exact_mut(n * d)
                .zip(dk.chunks_exact_mut(n * d))
                .zip(dv.chunks_exact_mut(n * d))
                .enumerate()
            {
                let point = t * POINTS_PER_TASK + r;
                let base = point * n * d;
                let a = &a[point * n * n..(point + 1) * n * n];
                for i in 0..n {
                    let (a_i, ds_i) = (&a[i * n..(i + 1) * n], &mut ds[i * n..(i + 1) * n]);
                    let g_i = row(grad, base, i, d);
                    // da_ij = dO_i . V_j; dV_j += a_ij dO_i.
                    for j in 0..n {
                        ds_i[j] = dot(g_i, row(v, base, j, d));
                        for (acc, &g) in dv[j * d..(j + 1) * d].iter_mut().zip(g_i) {
                            *acc += a_i[j] * g;
                        }
                    }
                    let mean: f32 = a_i.iter().zip(ds_i.iter()).map(|(x, y)| x * y).sum();
                    for (s, &w) in ds_i.iter_mut().zip(a_i) {
                        *s = w * (*s - mean) * scale;
                    }
                }
                // dQ_i = sum_j ds_ij K_j; dK_j = sum_i ds_ij Q_i (the scale is in ds).
                for i in 0..n {
                    for j in 0..n {
                        let s = ds[i * n + j];
                        for (acc, &x) in dq[i * d..(i + 1) * d].iter_mut().zip(row(k, base, j, d)) {
                            *acc += s * x;
                        }
                        for (acc, &x) in dk[j * d..(j + 1) * d].iter_mut().zip(row(q, base, i, d)) {
                            *acc += s * x;
                        }
                    }
                }
            }
        });
    [dq, dk, dv]
}

impl ViewAttentionKernels for Flex {
    fn view_attention_forward(
        q: FlexTensor,
        k: FlexTensor,
        v: FlexTensor,
    ) -> (FlexTensor, FlexTensor) {
        let (q, k, v) = (contiguous_f32(q), contiguous_f32(k), contiguous_f32(v));
        let [m, n, d] = dims::<3>(&q);
        assert!(
            dims::<3>(&k) == [m, n, d] && dims::<3>(&v) == [m, n, d],
            "view attention: q {:?}, k {:?}, v {:?}",
            [m, n, d],
            dims::<3>(&k),
            dims::<3>(&v)
        );
        let (out, a) = forward(values(&q), values(&k), values(&v), n, d);
        (flex_tensor(out, [m, n, d]), flex_tensor(a, [m, n, n]))
    }

    fn view_attention_backward(
        grad: FlexTensor,
        q: FlexTensor,
        k: FlexTensor,
        v: FlexTensor,
        a: FlexTensor,
    ) -> [FlexTensor; 3] {
        let g = contiguous_f32(grad);
        let (q, k, v) = (contiguous_f32(q), contiguous_f32(k), contiguous_f32(v));
        let [m, n, d] = dims::<3>(&q);
        assert_eq!(dims::<3>(&g), [m, n, d], "view attention: gradient shape");
        let a = contiguous_f32(a);
        backward(
            values(&g),
            values(&q),
            values(&k),
            values(&v),
            values(&a),
            n,
            d,
        )
        .map(|x| flex_tensor(x, [m, n, d]))
    }
}

impl ViewAttentionBackend for Flex {
    fn view_attention(q: FlexTensor, k: FlexTensor, v: FlexTensor) -> FlexTensor {
        <Flex as ViewAttentionKernels>::view_attention_forward(q, k, v).0
    }
}

/// The backward of [`ViewAttentionBackend::view_attention`] under autodiff.
#[derive(Debug)]
struct ViewAttentionBackward;

impl<B: Backend + ViewAttentionKernels> Backward<B, 3> for ViewAttentionBackward {
    /// q, k, v and the attention weights.
    type State = [FloatTensor<B>; 4];

    fn backward(
        self,
        ops: Ops<Self::State, 3>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let [q, k, v, a] = ops.state;
        let grad = grads.consume::<B>(&ops.node);
        let got = B::view_attention_backward(grad, q, k, v, a);
        for (node, g) in ops.parents.into_iter().zip(got) {
            if let Some(node) = node {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

impl<B: Backend + ViewAttentionKernels, C: CheckpointStrategy> ViewAttentionBackend
    for Autodiff<B, C>
{
    fn view_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        match ViewAttentionBackward
            .prepare::<C>([q.node(), k.node(), v.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (q, k, v) = (q.into_primitive(), k.into_primitive(), v.into_primitive());
                let (out, a) = B::view_attention_forward(q.clone(), k.clone(), v.clone());
                prep.finish([q, k, v, a], out)
            }
            OpsKind::UnTracked(prep) => prep.finish(
                B::view_attention_forward(
                    q.into_primitive(),
                    k.into_primitive(),
                    v.into_primitive(),
                )
                .0,
            ),
        }
    }
}

/// `O_i = sum_j softmax_j(Q_i . K_j / sqrt(d)) V_j` by the host operation (the device must be
/// flex, with or without autodiff: [`crate::host_op::runs_on_host`]).
///
/// # Shapes
/// - `q`, `k`, `v`: `[M, N, d]`; output `[M, N, d]`
pub fn view_attention(q: Tensor<3>, k: Tensor<3>, v: Tensor<3>) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as ViewAttentionBackend>::view_attention(
        q.into_dispatch(),
        k.into_dispatch(),
        v.into_dispatch(),
    ))
}

/// `sum_i a_i b_i` in eight independent lanes (a sequential f32 sum does not vectorise).
pub(super) fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0.0f32; 8];
    let (a8, b8) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = a8
        .remainder()
        .iter()
        .zip(b8.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in a8.zip(b8) {
        for k in 0..8 {
            lanes[k] += x[k] * y[k];
        }
    }
    lanes.iter().sum::<f32>() + tail
}
