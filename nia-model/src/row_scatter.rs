//! The scatter-add of gradient rows on a backend's primitives, for the hand-written backwards
//! of the GPU training operations ([`crate::body_volume::im2col_op`], [`crate::tap_gather`]).
//!
//! As [`crate::blocked_rows`] runs it at the tensor level: an element-wise `scatter` with `Add`
//! in blocks of [`RowScatter::scatter_rows`] rows on the cubecl backends (atomic adds, no fixed
//! order; [`MAX_SCATTER_INDICES`] rows where the device has no float atomics), one
//! `select_assign` on ndarray (the tests' reference, whose callers block their rows as a device
//! without float atomics would).
// ndarray: the reference CPU backend of the tests, deprecated in burn 0.22.
#![allow(deprecated)]

use burn::backend::ops::{FloatTensorOps, IntTensorOps};
use burn::backend::tensor::{FloatTensor, IntTensor};
#[cfg(feature = "wgpu")]
use burn::backend::Cube;
use burn::backend::{Backend, NdArray, TensorMetadata};
use burn::tensor::{IndexingUpdateOp, Slice};

use crate::blocked_rows::MAX_SCATTER_INDICES;
#[cfg(feature = "wgpu")]
use crate::{blocked_rows::scatter_block_rows, device::cube_adds_floats_atomically};

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

/// The scatter-add of gradient rows, per backend (module docs).
pub trait RowScatter: Backend {
    /// The most rows of `columns` values a caller should hand one [`Self::scatter_add_rows`]
    /// on `device` (it bounds the callers' intermediate buffers too):
    /// [`crate::blocked_rows::scatter_block_rows`] on the cubecl backends,
    /// [`MAX_SCATTER_INDICES`] on ndarray.
    fn scatter_rows(device: &Self::Device, columns: usize) -> usize;

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
