//! The `Im2col` sparse convolution's product as one operation with a hand-written backward
//! (burn's backend extension), for training on the GPU backends (and on ndarray, where the
//! tests compare it with the tensor form).
//!
//! The tensor form gathers each block of outputs' 27 neighbour rows (`[K, 27 C_in]`) and
//! multiplies by the weight `[27 C_in, C_out]`, block by block. Under autodiff every block's
//! gather has its own backward: a zeroed buffer the size of the whole input (`[R, C_in]`), a
//! scatter-add into it, and an addition to the sum of the other blocks'. Here the backward
//! zeroes one buffer and scatter-adds every block's column gradient into it; it gathers each
//! block's columns again for the weight's gradient instead of keeping them from the forward
//! (a block's columns are `27 C_in / C_out` times its output). Per block:
//! - forward: `out_b = cols_b W` with `cols_b = rows[index_b]` (reshaped to `[K_b, 27 C_in]`);
//! - backward: `dW += cols_b^T d out_b`, `d rows[index_b] += d out_b W^T`.
//!
//! The scatter-adds run as [`crate::kernels::row_scatter`] runs them (atomic adds on the GPU backends).
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

use crate::kernels::row_scatter::{blocks, range, RowScatter};
use crate::kernels::tracked_op::{self, TwoFloatOp};
use nia_data::geometry::sparse::KERNEL_VOLUME;

/// The product's inputs, which its backward keeps (the columns are gathered again).
#[derive(Debug, Clone, ExtensionType)]
pub struct Im2colInputs<B: Backend> {
    /// `[R, C_in]`.
    pub rows: FloatTensor<B>,
    /// `[27 C_in, C_out]`.
    pub weight: FloatTensor<B>,
    /// `[27 N P]` Int: rows of `rows`, 27 per output, in blocks of `chunk` outputs,
    /// view-major within a block.
    pub index: IntTensor<B>,
    /// N.
    pub views: usize,
    /// Outputs per view in a block.
    pub chunk: usize,
}

/// The product as a backend operation: ndarray and (with the `wgpu` feature) the cubecl
/// backends ([`forward`]), and autodiff over them with this module's backward.
#[backend_extension(Autodiff, NdArray, Cube: cfg(feature = "wgpu"))]
pub trait Im2colBackend: Backend {
    /// The product of `inputs`: `[N, P, C_out]`.
    fn im2col_product(#[extension_type] inputs: Im2colInputs<Self>) -> FloatTensor<Self> {
        forward::<Self>(&inputs)
    }
}

impl Im2colBackend for NdArray {}
#[cfg(feature = "wgpu")]
impl Im2colBackend for Cube {}

/// The outputs per view, P, of an index of `views` views.
fn outputs_per_view<B: Backend>(index: &IntTensor<B>, views: usize) -> usize {
    index.shape().dims::<1>()[0] / (KERNEL_VOLUME * views.max(1))
}

/// One block's columns, outputs `start..start + len` of every view: `[N len, 27 C_in]`, and
/// their `[27 N len]` rows.
fn columns<B: Backend>(
    rows: &FloatTensor<B>,
    index: &IntTensor<B>,
    views: usize,
    (start, len): (usize, usize),
    p: usize,
) -> (FloatTensor<B>, IntTensor<B>) {
    let c_in = rows.shape().dims::<2>()[1];
    let index = if len == p {
        index.clone()
    } else {
        let per_output = KERNEL_VOLUME * views;
        B::int_slice(
            index.clone(),
            &[range(per_output * start, per_output * len)],
        )
    };
    let cols = B::float_select(rows.clone(), 0, index.clone());
    (
        B::float_reshape(cols, [views * len, KERNEL_VOLUME * c_in].into()),
        index,
    )
}

/// The forward (module docs): `[N, P, C_out]`.
pub fn forward<B: Backend>(inputs: &Im2colInputs<B>) -> FloatTensor<B> {
    let (rows, weight, index) = (&inputs.rows, &inputs.weight, &inputs.index);
    let (views, chunk) = (inputs.views, inputs.chunk);
    let p = outputs_per_view::<B>(index, views);
    let c_out = weight.shape().dims::<2>()[1];
    let mut parts: Vec<FloatTensor<B>> = blocks(p, chunk)
        .map(|block| {
            let (cols, _) = columns::<B>(rows, index, views, block, p);
            B::float_reshape(
                B::float_matmul(cols, weight.clone()),
                [views, block.1, c_out].into(),
            )
        })
        .collect();
    if parts.len() == 1 {
        parts.pop().expect("one block")
    } else {
        B::float_cat(parts, 1)
    }
}

/// The backward (module docs): the gradients of `rows` `[R, C_in]` and `weight`
/// `[27 C_in, C_out]` from the output's `grad` `[N, P, C_out]`.
pub fn backward<B: RowScatter>(
    grad: FloatTensor<B>,
    inputs: Im2colInputs<B>,
) -> [FloatTensor<B>; 2] {
    let Im2colInputs {
        rows,
        weight,
        index,
        views,
        chunk,
    } = inputs;
    let [r, c_in] = rows.shape().dims::<2>();
    let [_, p, c_out] = grad.shape().dims::<3>();
    let weight_t = B::float_transpose(weight);
    let mut d_rows = B::float_zeros([r, c_in].into(), &rows.device(), rows.dtype().into());
    let mut d_weight: Option<FloatTensor<B>> = None;
    for (start, len) in blocks(p, chunk) {
        let g = if len == p {
            grad.clone()
        } else {
            B::float_slice(
                grad.clone(),
                &[Slice::full(), range(start, len), Slice::full()],
            )
        };
        let g = B::float_reshape(g, [views * len, c_out].into());
        let (cols, index) = columns::<B>(&rows, &index, views, (start, len), p);
        let dw = B::float_matmul(B::float_transpose(cols), g.clone());
        d_weight = Some(match d_weight {
            Some(acc) => B::float_add(acc, dw),
            None => dw,
        });
        let d_cols = B::float_reshape(
            B::float_matmul(g, weight_t.clone()),
            [KERNEL_VOLUME * views * len, c_in].into(),
        );
        d_rows = B::scatter_add_rows(d_rows, index, d_cols);
    }
    let d_weight = d_weight.expect("at least one output");
    [d_rows, d_weight]
}

/// The product under autodiff: [`forward`] and [`backward`].
struct Im2col;

impl<B: RowScatter> TwoFloatOp<B> for Im2col {
    type Inputs = Im2colInputs<B>;

    fn forward(inputs: &Self::Inputs) -> FloatTensor<B> {
        forward::<B>(inputs)
    }

    fn backward(
        grad: FloatTensor<B>,
        inputs: Self::Inputs,
        _wants: [bool; 2],
    ) -> [Option<FloatTensor<B>>; 2] {
        backward::<B>(grad, inputs).map(Some)
    }
}

impl<B: RowScatter, C: CheckpointStrategy> Im2colBackend for Autodiff<B, C> {
    fn im2col_product(inputs: Im2colInputs<Self>) -> FloatTensor<Self> {
        // The float inputs under autodiff, then the product's inputs on the inner backend.
        tracked_op::run::<B, C, Im2col>([inputs.rows, inputs.weight], |[rows, weight]| {
            Im2colInputs {
                rows,
                weight,
                index: inputs.index,
                views: inputs.views,
                chunk: inputs.chunk,
            }
        })
    }
}

/// The `Im2col` product of `views` views by the operation with the one-buffer backward
/// (module docs): each block of `chunk` outputs per view gathers its rows of `index`
/// (view-major within the block), reshapes them to `[N len, 27 C_in]` and multiplies by
/// `weight`. The device must be ndarray or (with the `wgpu` feature) a cubecl one, with or
/// without autodiff.
///
/// # Shapes
/// - `rows`: `[R, C_in]`; `weight`: `[27 C_in, C_out]`; `index`: `[27 N P]` Int in `0..R`;
///   output `[N, P, C_out]`
pub fn im2col_product(
    rows: Tensor<2>,
    weight: Tensor<2>,
    index: Tensor<1, Int>,
    views: usize,
    chunk: usize,
) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as Im2colBackend>::im2col_product(Im2colInputs {
        rows: rows.into_dispatch(),
        weight: weight.into_dispatch(),
        index: index.into_dispatch(),
        views,
        chunk,
    }))
}
