//! The scatter-add of gradient rows on a backend's primitives, for the hand-written backwards
//! of the GPU training operations ([`crate::body_volume::im2col_op`], [`crate::kernels::tap_gather`]).
//!
//! As [`crate::kernels::blocked_rows`] runs it at the tensor level: an element-wise `scatter` with `Add`
//! in blocks of [`RowScatter::scatter_rows`] rows on the cubecl backends (atomic adds, no fixed
//! order; [`MAX_SCATTER_INDICES`] rows where the device has no float atomics), one
//! `select_assign` on ndarray (the tests' reference, whose callers block their rows as a device
//! without float atomics would).
// ndarray: the reference CPU backend of the tests, deprecated in burn 0.22.
#![allow(deprecated)]

use burn::backend::ops::FloatTensorOps;
#[cfg(feature = "wgpu")]
use burn::backend::ops::IntTensorOps;
use burn::backend::tensor::{FloatTensor, IntTensor};
#[cfg(feature = "wgpu")]
use burn::backend::Cube;
use burn::backend::{Backend, NdArray, TensorMetadata};
use burn::tensor::{IndexingUpdateOp, Slice};

#[cfg(feature = "wgpu")]
use crate::device::cube_adds_floats_atomically;
use crate::kernels::blocked_rows::scatter_block_rows;
use crate::kernels::blocked_rows::MAX_SCATTER_INDICES;

/// `(start, len)` of the blocks of `step` (at least 1) among `k`.
pub fn blocks(k: usize, step: usize) -> impl Iterator<Item = (usize, usize)> {
    let step = step.max(1);
    (0..k)
        .step_by(step)
        .map(move |start| (start, step.min(k - start)))
}

/// The slice `start..start + len` of one dimension.
pub fn range(start: usize, len: usize) -> Slice {
    Slice::with_step(start as isize, Some((start + len) as isize), 1)
}

/// The K taps of L outputs of a weighted row read ([`crate::kernels::tap_gather`]): the rows
/// they read and their weights.
#[derive(Debug, Clone)]
pub struct Taps<B: Backend> {
    /// `[K, L]` Int.
    pub index: IntTensor<B>,
    /// `[K, L]`.
    pub weight: FloatTensor<B>,
}

/// The scatter-add of gradient rows, per backend (module docs).
pub trait RowScatter: Backend {
    /// The most rows of `columns` values a caller should hand one [`Self::scatter_add_rows`]
    /// on `device` (it bounds the callers' intermediate buffers too):
    /// [`crate::kernels::blocked_rows::scatter_block_rows`] on the cubecl backends,
    /// [`MAX_SCATTER_INDICES`] on ndarray.
    fn scatter_rows(device: &Self::Device, columns: usize) -> usize;

    /// Whether [`Self::weighted_scatter_add`] on `device` is one operation of its own rather
    /// than [`weighted_scatter_tensor_form`] (which callers may as well run in blocks).
    fn scatters_weighted_taps(_device: &Self::Device) -> bool {
        false
    }

    /// `rows` `[R, C]` with `weight[j, l] * grad[l]` added at row `index[j, l]` for every tap j
    /// and output l of `taps` (`grad` `[L, C]`): the rows' gradient of
    /// [`crate::kernels::tap_gather`] ([`crate::kernels::tap_scatter`]).
    fn weighted_scatter_add(
        rows: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        taps: Taps<Self>,
    ) -> FloatTensor<Self> {
        weighted_scatter_tensor_form::<Self>(rows, grad, taps)
    }

    /// `target` `[R, C]` with every row of `values` `[L, C]` added at the row `index` `[L]`
    /// names.
    fn scatter_add_rows(
        target: FloatTensor<Self>,
        index: IntTensor<Self>,
        values: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

impl RowScatter for NdArray {
    fn scatter_rows(_device: &Self::Device, _columns: usize) -> usize {
        MAX_SCATTER_INDICES
    }

    fn scatter_add_rows(
        target: FloatTensor<Self>,
        index: IntTensor<Self>,
        values: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        Self::float_select_assign(target, 0, index, values, IndexingUpdateOp::Add)
    }
}

#[cfg(feature = "wgpu")]
impl RowScatter for Cube {
    fn scatter_rows(device: &Self::Device, columns: usize) -> usize {
        scatter_block_rows(cube_adds_floats_atomically(device), columns)
    }

    fn scatters_weighted_taps(device: &Self::Device) -> bool {
        cube_adds_floats_atomically(device)
    }

    fn weighted_scatter_add(
        rows: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        taps: Taps<Self>,
    ) -> FloatTensor<Self> {
        if cube_adds_floats_atomically(&rows.device()) {
            crate::kernels::tap_scatter::cube::fused(rows, grad, taps.index, taps.weight)
        } else {
            weighted_scatter_tensor_form::<Self>(rows, grad, taps)
        }
    }

    fn scatter_add_rows(
        target: FloatTensor<Self>,
        index: IntTensor<Self>,
        values: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let len = index.shape().dims::<1>()[0];
        let columns = values.shape().dims::<2>()[1];
        let step = Self::scatter_rows(&values.device(), columns);
        let mut out = target;
        for (start, block) in blocks(len, step) {
            let index = Self::int_slice(index.clone(), &[range(start, block)]);
            let index = Self::int_expand(
                Self::int_reshape(index, [block, 1].into()),
                [block, columns].into(),
            );
            let values = if block == len {
                values.clone()
            } else {
                Self::float_slice(values.clone(), &[range(start, block)])
            };
            out = Self::float_scatter(0, out, index, values, IndexingUpdateOp::Add);
        }
        out
    }
}

/// [`RowScatter::weighted_scatter_add`] by tensor operations, on any [`RowScatter`] backend:
/// the output gradient weighted by every tap into a `[K L, C]` buffer, then one
/// [`RowScatter::scatter_add_rows`] ([`crate::kernels::tap_scatter`] is the GPU kernel without the buffer).
///
/// # Shapes
/// - `rows`: `[R, C]`; `grad`: `[L, C]`; `taps`: `[K, L]` each, the index in `0..R`; output
///   `[R, C]`
pub fn weighted_scatter_tensor_form<B: RowScatter>(
    rows: FloatTensor<B>,
    grad: FloatTensor<B>,
    taps: Taps<B>,
) -> FloatTensor<B> {
    let Taps { index, weight } = taps;
    let [k, l] = index.shape().dims::<2>();
    let c = grad.shape().dims::<2>()[1];
    let values = B::float_mul(
        B::float_reshape(grad, [1, l, c].into()),
        B::float_reshape(weight, [k, l, 1].into()),
    );
    B::scatter_add_rows(
        rows,
        B::int_reshape(index, [k * l].into()),
        B::float_reshape(values, [k * l, c].into()),
    )
}
