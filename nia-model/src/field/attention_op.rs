//! The view attention's weighted sum as one host operation with a hand-written backward
//! (burn's backend extension): on flex, with and without autodiff.
//!
//! Per point, over its N views: `O_i = sum_j a_ij V_j`, `a_ij = softmax_j(Q_i . K_j / sqrt(d))`
//! (the maximum subtracted, as [`crate::softmax::stable_softmax`] does), for the projections
//! Q = phi_k(S), K = phi_k(L), V = phi_v(L) of [`super::attention::ViewCrossAttention`]. The
//! tensor form broadcasts `[N, N, M, d]` products for the scores and for the weighted values and
//! sums them, and under autodiff each product and sum has its own backward (a `[N, N, M, d]`
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

use crate::kernels::host_buffer::zeroed;
use crate::kernels::host_op::{contiguous_f32, dims, flex_tensor, values, FlexTensor};

/// The weighted sum as a backend operation: flex, and autodiff over flex with this module's
/// backward.
#[backend_extension(Autodiff, Flex)]
pub trait ViewAttentionBackend: Backend {
    /// `q`, `k`, `v` `[N, M, d]` -> `O` `[N, M, d]`.
    fn view_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

/// The host kernels on a concrete backend's buffers.
pub trait ViewAttentionKernels: Backend {
    /// The output `[N, M, d]` and the attention weights `a` `[M, N, N]`.
    fn view_attention_forward(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
    /// `dQ`, `dK`, `dV` from `dO` (all `[N, M, d]`) and the forward's inputs and weights.
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

/// Row `(view, point)` of a `[N, M, d]` buffer.
fn row(x: &[f32], m: usize, d: usize, view: usize, point: usize) -> &[f32] {
    let at = (view * m + point) * d;
    &x[at..at + d]
}

/// A `[N, M, d]` buffer cut into tasks of [`POINTS_PER_TASK`] points: task `t` holds the rows
/// of its points in each of the N views (N slices of up to `POINTS_PER_TASK * d` values).
fn tasks_mut(x: &mut [f32], m: usize, d: usize) -> Vec<Vec<&mut [f32]>> {
    let mut tasks: Vec<Vec<&mut [f32]>> = (0..m.div_ceil(POINTS_PER_TASK))
        .map(|_| Vec::new())
        .collect();
    for view in x.chunks_mut(m * d) {
        for (task, rows) in tasks.iter_mut().zip(view.chunks_mut(POINTS_PER_TASK * d)) {
            task.push(rows);
        }
    }
    tasks
}

/// The forward on host slices, `[N, M, d]` each: `O` `[N, M, d]` and `a` `[M, N, N]`.
pub fn forward(q: &[f32], k: &[f32], v: &[f32], n: usize, d: usize) -> (Vec<f32>, Vec<f32>) {
    let m = q.len().checked_div(n * d).unwrap_or(0);
    let scale = 1.0 / (d as f32).sqrt();
    let mut out = zeroed(m * n * d);
    let mut weights = zeroed(m * n * n);
    if m == 0 {
        return (out, weights);
    }
    tasks_mut(&mut out, m, d)
        .into_par_iter()
        .zip(weights.par_chunks_mut(POINTS_PER_TASK * n * n))
        .enumerate()
        .for_each(|(task, (mut out, weights))| {
            for (r, a) in weights.chunks_exact_mut(n * n).enumerate() {
                let point = task * POINTS_PER_TASK + r;
                for i in 0..n {
                    let a_i = &mut a[i * n..(i + 1) * n];
                    for (j, s) in a_i.iter_mut().enumerate() {
                        *s = dot(row(q, m, d, i, point), row(k, m, d, j, point)) * scale;
                    }
                    let max = a_i.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
                    let mut total = 0.0f32;
                    for s in a_i.iter_mut() {
                        *s = (*s - max).exp();
                        total += *s;
                    }
                    let o_i = &mut out[i][r * d..(r + 1) * d];
                    for (j, s) in a_i.iter_mut().enumerate() {
                        *s /= total;
                        for (acc, &x) in o_i.iter_mut().zip(row(v, m, d, j, point)) {
                            *acc += *s * x;
                        }
                    }
                }
            }
        });
    (out, weights)
}

/// The backward on host slices: `dQ`, `dK`, `dV` (`[N, M, d]`) from `dO` and the forward's
/// `q`, `k`, `v` (all `[N, M, d]`) and weights `a` `[M, N, N]`.
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
    let m = len.checked_div(n * d).unwrap_or(0);
    let scale = 1.0 / (d as f32).sqrt();
    let (mut dq, mut dk, mut dv) = (zeroed(len), zeroed(len), zeroed(len));
    if m == 0 {
        return [dq, dk, dv];
    }
    tasks_mut(&mut dq, m, d)
        .into_par_iter()
        .zip(tasks_mut(&mut dk, m, d))
        .zip(tasks_mut(&mut dv, m, d))
        .enumerate()
        .for_each(|(t, ((mut dq, mut dk), mut dv))| {
            let mut ds = vec![0.0f32; n * n];
            let points = dq[0].len() / d;
            for r in 0..points {
                let point = t * POINTS_PER_TASK + r;
                let a = &a[point * n * n..(point + 1) * n * n];
                let at = r * d..(r + 1) * d;
                for i in 0..n {
                    let (a_i, ds_i) = (&a[i * n..(i + 1) * n], &mut ds[i * n..(i + 1) * n]);
                    let g_i = row(grad, m, d, i, point);
                    // da_ij = dO_i . V_j; dV_j += a_ij dO_i.
                    for j in 0..n {
                        ds_i[j] = dot(g_i, row(v, m, d, j, point));
                        for (acc, &g) in dv[j][at.clone()].iter_mut().zip(g_i) {
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
                        for (acc, &x) in dq[i][at.clone()].iter_mut().zip(row(k, m, d, j, point)) {
                            *acc += s * x;
                        }
                        for (acc, &x) in dk[j][at.clone()].iter_mut().zip(row(q, m, d, i, point)) {
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
        let [n, m, d] = dims::<3>(&q);
        assert!(
            dims::<3>(&k) == [n, m, d] && dims::<3>(&v) == [n, m, d],
            "view attention: q {:?}, k {:?}, v {:?}",
            [n, m, d],
            dims::<3>(&k),
            dims::<3>(&v)
        );
        let (out, a) = forward(values(&q), values(&k), values(&v), n, d);
        (flex_tensor(out, [n, m, d]), flex_tensor(a, [m, n, n]))
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
        let [n, m, d] = dims::<3>(&q);
        assert_eq!(dims::<3>(&g), [n, m, d], "view attention: gradient shape");
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
        .map(|x| flex_tensor(x, [n, m, d]))
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
/// flex, with or without autodiff: [`crate::kernels::host_op::runs_on_host`]).
///
/// # Shapes
/// - `q`, `k`, `v`: `[N, M, d]` (views first); output `[N, M, d]`
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
