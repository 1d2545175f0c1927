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

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::{FloatTensor, IntTensor};
#[cfg(feature = "wgpu")]
use burn::backend::Cube;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, NdArray, TensorMetadata};
use burn::prelude::*;
use burn::tensor::Slice;

use crate::kernels::row_scatter::{blocks, range, RowScatter};
use nia_data::geometry::sparse::KERNEL_VOLUME;

/// The product as a backend operation: ndarray and (with the `wgpu` feature) the cubecl
/// backends, and autodiff over them with this module's backward.
#[backend_extension(Autodiff, NdArray, Cube: cfg(feature = "wgpu"))]
pub trait Im2colBackend: Backend {
    /// `rows` `[R, C_in]`, `weight` `[27 C_in, C_out]`, `index` `[27 N P]` Int (rows of
    /// `rows`, 27 per output: blocks of `chunk` outputs, view-major within a block) ->
    /// `[N, P, C_out]`.
    fn im2col_product(
        rows: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        index: IntTensor<Self>,
        views: usize,
        chunk: usize,
    ) -> FloatTensor<Self>;
}

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
pub fn forward<B: Backend>(
    rows: &FloatTensor<B>,
    weight: &FloatTensor<B>,
    index: &IntTensor<B>,
    views: usize,
    chunk: usize,
) -> FloatTensor<B> {
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
pub fn backward<B: RowScatter>(grad: FloatTensor<B>, saved: Saved<B>) -> [FloatTensor<B>; 2] {
    let Saved {
        rows,
        weight,
        index,
        views,
        chunk,
    } = saved;
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

/// What the backward keeps: the inputs (the columns are gathered again).
#[derive(Debug, Clone)]
pub struct Saved<B: Backend> {
    /// `[R, C_in]`.
    pub rows: FloatTensor<B>,
    /// `[27 C_in, C_out]`.
    pub weight: FloatTensor<B>,
    /// `[27 N P]`.
    pub index: IntTensor<B>,
    /// N.
    pub views: usize,
    /// Outputs per view in a block.
    pub chunk: usize,
}

/// The operation on a device backend: [`forward`].
macro_rules! on_device_backend {
    ($backend:ty) => {
        impl Im2colBackend for $backend {
            fn im2col_product(
                rows: FloatTensor<Self>,
                weight: FloatTensor<Self>,
                index: IntTensor<Self>,
                views: usize,
                chunk: usize,
            ) -> FloatTensor<Self> {
                forward::<Self>(&rows, &weight, &index, views, chunk)
            }
        }
    };
}

on_device_backend!(NdArray);
#[cfg(feature = "wgpu")]
on_device_backend!(Cube);

/// The backward of [`Im2colBackend::im2col_product`] under autodiff.
#[derive(Debug)]
struct Im2colBackward;

impl<B: RowScatter> Backward<B, 2> for Im2colBackward {
    type State = Saved<B>;

    fn backward(
        self,
        ops: Ops<Self::State, 2>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let grad = grads.consume::<B>(&ops.node);
        let got = backward::<B>(grad, ops.state);
        for (node, g) in ops.parents.into_iter().zip(got) {
            if let Some(node) = node {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

impl<B: RowScatter, C: CheckpointStrategy> Im2colBackend for Autodiff<B, C> {
    fn im2col_product(
        rows: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        index: IntTensor<Self>,
        views: usize,
        chunk: usize,
    ) -> FloatTensor<Self> {
        match Im2colBackward
            .prepare::<C>([rows.node(), weight.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let rows = rows.into_primitive();
                let weight = weight.into_primitive();
                let out = forward::<B>(&rows, &weight, &index, views, chunk);
                prep.finish(
                    Saved {
                        rows,
                        weight,
                        index,
                        views,
                        chunk,
                    },
                    out,
                )
            }
            OpsKind::UnTracked(prep) => prep.finish(forward::<B>(
                &rows.into_primitive(),
                &weight.into_primitive(),
                &index,
                views,
                chunk,
            )),
        }
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
    Tensor::from_dispatch(<Dispatch as Im2colBackend>::im2col_product(
        rows.into_dispatch(),
        weight.into_dispatch(),
        index.into_dispatch(),
        views,
        chunk,
    ))
}
