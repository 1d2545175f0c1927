//! [`super::SiteNorm`] and the ReLU after it as one host operation with a hand-written backward
//! (burn's backend extension): on flex, with and without autodiff. The same operation on the
//! device backends (training on a GPU) is [`super::site_norm_device`].
//!
//! Per view n and channel c over the P sites: `x_hat = (x - mean) / sqrt(var + eps)` (biased
//! variance, two passes), `y = ReLU(gamma x_hat + beta)`. The tensor form is a dozen element-wise
//! operations and reductions, each a pass over `[N, P, C]` with its own backward (a buffer of
//! ones for every mean's). Here the forward is three passes and the backward three per view,
//! with `dy'` the output gradient where the ReLU passed (0 where it cut):
//! - `d beta_c = sum_{n,p} dy'`, `d gamma_c = sum_{n,p} dy' x_hat`;
//! - `dx = gamma / sqrt(var + eps) (dy' - mean_p dy' - x_hat mean_p(dy' x_hat))`, per view.
//!
//! The sums over sites run in fixed blocks of [`ROWS_PER_BLOCK`] rows on rayon's threads, in
//! f64, the blocks added in order: the same bits for any number of threads. Equal to the tensor
//! form within float rounding (`nia-model/tests/body_volume_conv.rs`).
// ndarray: the reference CPU backend of the tests, deprecated in burn 0.22.
#![allow(deprecated)]

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, ExtensionType, Flex};
use burn::prelude::*;
use rayon::prelude::*;

use crate::kernels::host_buffer::zeroed;
use crate::kernels::host_op::{contiguous_f32, dims, flex_tensor, values, FlexTensor};

/// Rows (sites) of a block of the sums over sites.
pub const ROWS_PER_BLOCK: usize = 512;

/// The operation's inputs.
#[derive(Debug, Clone, ExtensionType)]
pub struct SiteNormInputs<B: Backend> {
    /// `[N, P, C]`.
    pub x: FloatTensor<B>,
    /// `[C]`.
    pub gamma: FloatTensor<B>,
    /// `[C]`.
    pub beta: FloatTensor<B>,
    /// Added to the variance.
    pub epsilon: f64,
}

/// The norm and ReLU as a backend operation: flex, ndarray and (with the `wgpu` feature) the
/// cubecl backends, and autodiff over them with this module's backward.
#[backend_extension(Autodiff, Flex, NdArray, Cube: cfg(feature = "wgpu"))]
pub trait SiteNormBackend: Backend {
    /// `ReLU(gamma x_hat + beta)` `[N, P, C]` of `inputs`.
    fn site_norm_relu(#[extension_type] inputs: SiteNormInputs<Self>) -> FloatTensor<Self>;
}

/// What the forward keeps for the backward.
#[derive(Debug, Clone)]
pub struct Saved<T> {
    /// `[N, P, C]` the normalised input x_hat.
    pub x_hat: T,
    /// `[N, C]` `1 / sqrt(var + eps)`.
    pub inv_std: T,
    /// `[N, P, C]` the output (its zeros are where the ReLU cut).
    pub y: T,
    /// `[C]` gamma.
    pub gamma: T,
}

/// The host kernels on a concrete backend's buffers.
pub trait SiteNormKernels: Backend {
    /// The output and what the backward needs.
    fn site_norm_forward(inputs: SiteNormInputs<Self>) -> Saved<FloatTensor<Self>>;
    /// `dx` `[N, P, C]`, `d gamma` and `d beta` `[C]` from `dy`.
    fn site_norm_backward(
        grad: FloatTensor<Self>,
        saved: Saved<FloatTensor<Self>>,
    ) -> [FloatTensor<Self>; 3];
}

/// Sums over the P rows of a view: `add_row(row, acc)` adds row `row`'s terms into `acc`
/// (`width` values), in blocks of [`ROWS_PER_BLOCK`] rows on rayon's threads, in f64, the blocks
/// added in order.
fn block_sums(p: usize, width: usize, add_row: impl Fn(usize, &mut [f64]) + Sync) -> Vec<f64> {
    let blocks: Vec<Vec<f64>> = (0..p.div_ceil(ROWS_PER_BLOCK))
        .into_par_iter()
        .map(|b| {
            let mut acc = vec![0.0f64; width];
            for row in b * ROWS_PER_BLOCK..((b + 1) * ROWS_PER_BLOCK).min(p) {
                add_row(row, &mut acc);
            }
            acc
        })
        .collect();
    let mut total = vec![0.0f64; width];
    for block in blocks {
        for (t, b) in total.iter_mut().zip(block) {
            *t += b;
        }
    }
    total
}

/// The forward on host slices, `x` `[N, P, C]` row-major: `(y, x_hat, inv_std)`, `y` and
/// `x_hat` `[N, P, C]`, `inv_std` `[N, C]`.
pub fn forward(
    x: &[f32],
    gamma: &[f32],
    beta: &[f32],
    [n, p, c]: [usize; 3],
    epsilon: f64,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let (mut y, mut x_hat) = (zeroed(n * p * c), zeroed(n * p * c));
    let mut inv_std = vec![0.0f32; n * c];
    if n * p * c == 0 {
        return (y, x_hat, inv_std);
    }
    let count = p as f64;
    for view in 0..n {
        let rows = &x[view * p * c..(view + 1) * p * c];
        let row = |r: usize| &rows[r * c..(r + 1) * c];
        let mean: Vec<f64> = block_sums(p, c, |r, acc| {
            for (a, &v) in acc.iter_mut().zip(row(r)) {
                *a += v as f64;
            }
        })
        .into_iter()
        .map(|s| s / count)
        .collect();
        let var = block_sums(p, c, |r, acc| {
            for ((a, &v), m) in acc.iter_mut().zip(row(r)).zip(&mean) {
                let d = v as f64 - m;
                *a += d * d;
            }
        });
        let inv: Vec<f32> = var
            .iter()
            .map(|v| (1.0 / (v / count + epsilon).sqrt()) as f32)
            .collect();
        let mean: Vec<f32> = mean.iter().map(|&m| m as f32).collect();
        let at = view * p * c..(view + 1) * p * c;
        y[at.clone()]
            .par_chunks_mut(ROWS_PER_BLOCK * c)
            .zip(x_hat[at].par_chunks_mut(ROWS_PER_BLOCK * c))
            .zip(rows.par_chunks(ROWS_PER_BLOCK * c))
            .for_each(|((y, x_hat), x)| {
                for ((y, h), x) in y
                    .chunks_exact_mut(c)
                    .zip(x_hat.chunks_exact_mut(c))
                    .zip(x.chunks_exact(c))
                {
                    for ch in 0..c {
                        h[ch] = (x[ch] - mean[ch]) * inv[ch];
                        let v = gamma[ch] * h[ch] + beta[ch];
                        // As burn's ReLU: a NaN passes as NaN, never as 0.
                        y[ch] = if v <= 0.0 { 0.0 } else { v };
                    }
                }
            });
        inv_std[view * c..(view + 1) * c].copy_from_slice(&inv);
    }
    (y, x_hat, inv_std)
}

/// The backward on host slices: `dx` `[N, P, C]`, `d gamma` and `d beta` `[C]` from `dy` and
/// the forward's `y`, `x_hat`, `inv_std` and `gamma`.
pub fn backward(
    dy: &[f32],
    y: &[f32],
    x_hat: &[f32],
    inv_std: &[f32],
    gamma: &[f32],
    [n, p, c]: [usize; 3],
) -> [Vec<f32>; 3] {
    let mut dx = zeroed(n * p * c);
    let (mut d_gamma, mut d_beta) = (vec![0.0f64; c], vec![0.0f64; c]);
    // The gradient where the ReLU passed (its output positive).
    let passed = |g: f32, y: f32| if y > 0.0 { g } else { 0.0 };
    for view in 0..n {
        let at = view * p * c..(view + 1) * p * c;
        let (dy, y, x_hat) = (&dy[at.clone()], &y[at.clone()], &x_hat[at.clone()]);
        // [sum dy' | sum dy' x_hat] per channel.
        let sums = block_sums(p, 2 * c, |r, acc| {
            let rows = r * c..(r + 1) * c;
            let (s1, s2) = acc.split_at_mut(c);
            for ch in 0..c {
                let g = passed(dy[rows.start + ch], y[rows.start + ch]);
                s1[ch] += g as f64;
                s2[ch] += (g * x_hat[rows.start + ch]) as f64;
            }
        });
        let (s1, s2) = sums.split_at(c);
        for ch in 0..c {
            d_beta[ch] += s1[ch];
            d_gamma[ch] += s2[ch];
        }
        let mean1: Vec<f32> = s1.iter().map(|s| (s / p as f64) as f32).collect();
        let mean2: Vec<f32> = s2.iter().map(|s| (s / p as f64) as f32).collect();
        let scale: Vec<f32> = (0..c)
            .map(|ch| gamma[ch] * inv_std[view * c + ch])
            .collect();
        if c > 0 {
            dx[at]
                .par_chunks_mut(ROWS_PER_BLOCK * c)
                .zip(dy.par_chunks(ROWS_PER_BLOCK * c))
                .zip(y.par_chunks(ROWS_PER_BLOCK * c))
                .zip(x_hat.par_chunks(ROWS_PER_BLOCK * c))
                .for_each(|(((dx, dy), y), x_hat)| {
                    for (((dx, dy), y), h) in dx
                        .chunks_exact_mut(c)
                        .zip(dy.chunks_exact(c))
                        .zip(y.chunks_exact(c))
                        .zip(x_hat.chunks_exact(c))
                    {
                        for ch in 0..c {
                            let g = passed(dy[ch], y[ch]);
                            dx[ch] = scale[ch] * (g - mean1[ch] - h[ch] * mean2[ch]);
                        }
                    }
                });
        }
    }
    let to_f32 = |v: Vec<f64>| v.into_iter().map(|s| s as f32).collect();
    [dx, to_f32(d_gamma), to_f32(d_beta)]
}

impl SiteNormKernels for Flex {
    fn site_norm_forward(inputs: SiteNormInputs<Self>) -> Saved<FlexTensor> {
        let SiteNormInputs {
            x,
            gamma,
            beta,
            epsilon,
        } = inputs;
        let (x, gamma, beta) = (
            contiguous_f32(x),
            contiguous_f32(gamma),
            contiguous_f32(beta),
        );
        let [n, p, c] = dims::<3>(&x);
        assert!(
            dims::<1>(&gamma) == [c] && dims::<1>(&beta) == [c],
            "site norm: gamma {:?} and beta {:?} for {c} channels",
            dims::<1>(&gamma),
            dims::<1>(&beta)
        );
        let (y, x_hat, inv_std) = forward(
            values(&x),
            values(&gamma),
            values(&beta),
            [n, p, c],
            epsilon,
        );
        Saved {
            x_hat: flex_tensor(x_hat, [n, p, c]),
            inv_std: flex_tensor(inv_std, [n, c]),
            y: flex_tensor(y, [n, p, c]),
            gamma,
        }
    }

    fn site_norm_backward(grad: FlexTensor, saved: Saved<FlexTensor>) -> [FlexTensor; 3] {
        let dy = contiguous_f32(grad);
        let [n, p, c] = dims::<3>(&saved.x_hat);
        assert_eq!(dims::<3>(&dy), [n, p, c], "site norm: gradient shape");
        let [dx, d_gamma, d_beta] = backward(
            values(&dy),
            values(&saved.y),
            values(&saved.x_hat),
            values(&saved.inv_std),
            values(&saved.gamma),
            [n, p, c],
        );
        [
            flex_tensor(dx, [n, p, c]),
            flex_tensor(d_gamma, [c]),
            flex_tensor(d_beta, [c]),
        ]
    }
}

impl SiteNormBackend for Flex {
    fn site_norm_relu(inputs: SiteNormInputs<Self>) -> FlexTensor {
        <Flex as SiteNormKernels>::site_norm_forward(inputs).y
    }
}

/// The backward of [`SiteNormBackend::site_norm_relu`] under autodiff.
#[derive(Debug)]
struct SiteNormBackward;

impl<B: Backend + SiteNormKernels> Backward<B, 3> for SiteNormBackward {
    type State = Saved<FloatTensor<B>>;

    fn backward(
        self,
        ops: Ops<Self::State, 3>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let grad = grads.consume::<B>(&ops.node);
        let got = B::site_norm_backward(grad, ops.state);
        for (node, g) in ops.parents.into_iter().zip(got) {
            if let Some(node) = node {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

impl<B: Backend + SiteNormKernels, C: CheckpointStrategy> SiteNormBackend for Autodiff<B, C> {
    fn site_norm_relu(inputs: SiteNormInputs<Self>) -> FloatTensor<Self> {
        let SiteNormInputs {
            x,
            gamma,
            beta,
            epsilon,
        } = inputs;
        let [(x, x_node), (gamma, gamma_node), (beta, beta_node)] =
            [x, gamma, beta].map(|t| t.into_parts());
        let inner = SiteNormInputs {
            x,
            gamma,
            beta,
            epsilon,
        };
        match SiteNormBackward
            .prepare::<C>([x_node, gamma_node, beta_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let saved = B::site_norm_forward(inner);
                let y = saved.y.clone();
                prep.finish(saved, y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::site_norm_forward(inner).y),
        }
    }
}

/// `ReLU(SiteNorm(x))` by the operation: on flex the host's, on ndarray or a cubecl backend
/// [`super::site_norm_device`]'s (with or without autodiff).
///
/// # Shapes
/// - `x`: `[N, P, C]`; `gamma`, `beta`: `[C]`; output `[N, P, C]`
pub fn site_norm_relu(x: Tensor<3>, gamma: Tensor<1>, beta: Tensor<1>, epsilon: f64) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as SiteNormBackend>::site_norm_relu(
        SiteNormInputs {
            x: x.into_dispatch(),
            gamma: gamma.into_dispatch(),
            beta: beta.into_dispatch(),
            epsilon,
        },
    ))
}
