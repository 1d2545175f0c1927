//! Weighted row gathers, the bilinear and trilinear reads, as one operation with a hand-written
//! backward (burn's backend extension), for training on the GPU backends (and on ndarray, where
//! the tests compare it with the tensor form). [`crate::kernels::weighted_rows`] is the same read on
//! flex, as a host loop.
//!
//! `out[l] = sum_j weight[j, l] * rows[index[j, l]]` for L output rows and K taps (4 corners of
//! a pixel-feature read, 8 of a body-volume read). The tensor form gathers each tap's rows,
//! weights them and sums them; under autodiff each tap's gather has its own backward: a zeroed
//! buffer the size of the whole table, a scatter-add into it, and an addition to the other
//! taps' buffers. Here the backward zeroes one table-sized buffer and scatter-adds the
//! weighted output gradient of all K taps of a block of rows into it at once:
//! - forward, per block of outputs: `out_b = sum_j weight[j, b] * rows[index[j, b]]`;
//! - backward: `d rows[index[j, l]] += weight[j, l] * d out[l]`: where the device adds floats
//!   atomically, one [`crate::kernels::tap_scatter`] kernel for all taps and outputs; else one
//!   scatter-add per [`RowScatter::scatter_rows`] taps
//!   ([`crate::kernels::blocked_rows::MAX_SCATTER_INDICES`] rows on a GPU without float atomics). Where
//!   the weights carry a gradient (the surface read's bilinear weights depend on the expected
//!   depth), `d weight[j, l] = d out[l] . rows[index[j, l]]` from each block's rows gathered
//!   again.
//!
//! The scatter-adds run as [`crate::kernels::row_scatter`] runs them (atomic adds on the GPU backends,
//! in no fixed order).
// ndarray: the reference CPU backend of the tests, deprecated in burn 0.22.
#![allow(deprecated)]

use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::tensor::{FloatTensor, IntTensor};
#[cfg(feature = "wgpu")]
use burn::backend::Cube;
use burn::backend::{
    backend_extension, Autodiff, Backend, Dispatch, ExtensionType, NdArray, TensorMetadata,
};
use burn::prelude::*;
use burn::tensor::Slice;

use crate::kernels::row_scatter::{blocks, range, RowScatter, Taps};
use crate::kernels::tracked_op::{self, TwoFloatOp};

/// The read's inputs, which its backward keeps.
#[derive(Debug, Clone, ExtensionType)]
pub struct TapGatherInputs<B: Backend> {
    /// `[R, C]`.
    pub rows: FloatTensor<B>,
    /// `[K, L]` Int in `0..R`.
    pub index: IntTensor<B>,
    /// `[K, L]`.
    pub weight: FloatTensor<B>,
    /// Outputs read at a time in the forward.
    pub block: usize,
}

/// The read as a backend operation: ndarray and (with the `wgpu` feature) the cubecl backends
/// ([`forward`]), and autodiff over them with this module's backward.
#[backend_extension(Autodiff, NdArray, Cube: cfg(feature = "wgpu"))]
pub trait TapGatherBackend: Backend {
    /// The read of `inputs`: `[L, C]`.
    fn tap_gather(#[extension_type] inputs: TapGatherInputs<Self>) -> FloatTensor<Self> {
        forward::<Self>(&inputs)
    }
}

impl TapGatherBackend for NdArray {}
#[cfg(feature = "wgpu")]
impl TapGatherBackend for Cube {}

/// Tap `j`'s index `[len]` and weight `[len, 1]` for outputs `start..start + len` of `l`.
fn tap<B: Backend>(
    index: &IntTensor<B>,
    weight: &FloatTensor<B>,
    j: usize,
    (start, len): (usize, usize),
) -> (IntTensor<B>, FloatTensor<B>) {
    let at = [range(j, 1), range(start, len)];
    (
        B::int_reshape(B::int_slice(index.clone(), &at), [len].into()),
        B::float_reshape(B::float_slice(weight.clone(), &at), [len, 1].into()),
    )
}

/// Every tap of outputs `start..start + len`, tap-major: index `[K len]` and weight
/// `[K, len, 1]`.
fn taps<B: Backend>(
    index: &IntTensor<B>,
    weight: &FloatTensor<B>,
    (start, len): (usize, usize),
) -> (IntTensor<B>, FloatTensor<B>) {
    let [k, l] = index.shape().dims::<2>();
    let (index, weight) = if len == l {
        (index.clone(), weight.clone())
    } else {
        let at = [Slice::full(), range(start, len)];
        (
            B::int_slice(index.clone(), &at),
            B::float_slice(weight.clone(), &at),
        )
    };
    (
        B::int_reshape(index, [k * len].into()),
        B::float_reshape(weight, [k, len, 1].into()),
    )
}

/// The forward (module docs): `[L, C]`.
pub fn forward<B: Backend>(inputs: &TapGatherInputs<B>) -> FloatTensor<B> {
    let (rows, index, weight) = (&inputs.rows, &inputs.index, &inputs.weight);
    let [k, l] = index.shape().dims::<2>();
    let c = rows.shape().dims::<2>()[1];
    if l == 0 || k == 0 {
        return B::float_zeros([l, c].into(), &rows.device(), rows.dtype().into());
    }
    let mut parts: Vec<FloatTensor<B>> = blocks(l, inputs.block)
        .map(|outputs| {
            (0..k)
                .map(|j| {
                    let (index, weight) = tap::<B>(index, weight, j, outputs);
                    B::float_mul(B::float_select(rows.clone(), 0, index), weight)
                })
                .reduce(B::float_add)
                .expect("at least one tap")
        })
        .collect();
    if parts.len() == 1 {
        parts.pop().expect("one block")
    } else {
        B::float_cat(parts, 0)
    }
}

/// The backward (module docs): the gradients of `rows` `[R, C]` (when `wants[0]`) and `weight`
/// `[K, L]` (when `wants[1]`) from the output's `grad` `[L, C]`.
pub fn backward<B: RowScatter>(
    grad: FloatTensor<B>,
    inputs: &TapGatherInputs<B>,
    wants: [bool; 2],
) -> [Option<FloatTensor<B>>; 2] {
    let (rows, index, weight) = (&inputs.rows, &inputs.index, &inputs.weight);
    let [r, c] = rows.shape().dims::<2>();
    let [k, l] = index.shape().dims::<2>();
    let mut d_rows =
        wants[0].then(|| B::float_zeros([r, c].into(), &rows.device(), rows.dtype().into()));
    // Where the backend has the scatter-add of weighted taps as one operation (a GPU kernel),
    // the rows' gradient is that, whole; else one scatter-add for all K taps of each block.
    let fused = wants[0] && B::scatters_weighted_taps(&rows.device());
    if fused {
        d_rows = d_rows.map(|acc| {
            let taps = Taps {
                index: index.clone(),
                weight: weight.clone(),
            };
            B::weighted_scatter_add(acc, grad.clone(), taps)
        });
        if !wants[1] {
            return [d_rows, None];
        }
    }
    let mut d_weight = Vec::new();
    let step = B::scatter_rows(&rows.device(), c) / k.max(1);
    for outputs @ (start, len) in blocks(l, step) {
        let g = if len == l {
            grad.clone()
        } else {
            B::float_slice(grad.clone(), &[range(start, len)])
        };
        let g = B::float_reshape(g, [1, len, c].into());
        let (index, weight) = taps::<B>(index, weight, outputs);
        // With `fused`, d rows is already whole.
        if let Some(acc) = d_rows.take_if(|_| !fused) {
            let values = B::float_mul(g.clone(), weight);
            d_rows = Some(B::scatter_add_rows(
                acc,
                index.clone(),
                B::float_reshape(values, [k * len, c].into()),
            ));
        }
        if wants[1] {
            let read =
                B::float_reshape(B::float_select(rows.clone(), 0, index), [k, len, c].into());
            let dot = B::float_sum_dim(B::float_mul(read, g), 2);
            d_weight.push(B::float_reshape(dot, [k, len].into()));
        }
    }
    let d_weight = match d_weight.len() {
        0 => None,
        1 => d_weight.pop(),
        _ => Some(B::float_cat(d_weight, 1)),
    };
    [d_rows, d_weight]
}

/// The read under autodiff: [`forward`] and [`backward`].
struct TapGather;

impl<B: RowScatter> TwoFloatOp<B> for TapGather {
    type Inputs = TapGatherInputs<B>;

    fn forward(inputs: &Self::Inputs) -> FloatTensor<B> {
        forward::<B>(inputs)
    }

    fn backward(
        grad: FloatTensor<B>,
        inputs: Self::Inputs,
        wants: [bool; 2],
    ) -> [Option<FloatTensor<B>>; 2] {
        backward::<B>(grad, &inputs, wants)
    }
}

impl<B: RowScatter, C: CheckpointStrategy> TapGatherBackend for Autodiff<B, C> {
    fn tap_gather(inputs: TapGatherInputs<Self>) -> FloatTensor<Self> {
        // The float inputs under autodiff, then the read's inputs on the inner backend.
        tracked_op::run::<B, C, TapGather>([inputs.rows, inputs.weight], |[rows, weight]| {
            TapGatherInputs {
                rows,
                index: inputs.index,
                weight,
                block: inputs.block,
            }
        })
    }
}

/// The read by the operation with the one-buffer backward (module docs), `block` outputs at a
/// time in the forward. The device must be ndarray or (with the `wgpu` feature) a cubecl one,
/// with or without autodiff; `rows` and `weight` may each carry a gradient or not.
///
/// # Shapes
/// - `rows`: `[R, C]`; `index`: `[K, L]` Int in `0..R`; `weight`: `[K, L]`; output `[L, C]`
pub fn tap_gather(
    rows: Tensor<2>,
    index: Tensor<2, Int>,
    weight: Tensor<2>,
    block: usize,
) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as TapGatherBackend>::tap_gather(
        TapGatherInputs {
            rows: rows.into_dispatch(),
            index: index.into_dispatch(),
            weight: weight.into_dispatch(),
            block,
        },
    ))
}
