//! Row gathers and scatter-adds on the GPU backends: element-wise `gather` / `scatter` in
//! blocks of indices, instead of `select` / `select_assign`.
//!
//! burn-cubecl 0.22.1 runs `select_assign` (a scatter-add, and the backward of every
//! `select`) as one serial loop over the indices per column: a few dozen threads walking
//! hundreds of thousands of rows. On Mesa's software Vulkan (lavapipe) it also returned wrong
//! sums from 65,536 indices on: 65,535 were right, 65,536 were not (docs/testing.md). The
//! forward passes were right, but the gradients of the body volume and of the image encoder
//! on wgpu were 26-78 % off, which
//! `nia-model/tests/model.rs::wgpu_training_gradients_match_ndarray` now checks. Whether an
//! NVIDIA driver does the same is not known: the one GPU run checked forwards only.
//!
//! Its element-wise `scatter` with `Add` runs one thread per value with an atomic add where the
//! device adds floats atomically (lavapipe does), and `gather`'s backward is that scatter. So on
//! the GPU backends:
//! - [`select_rows`] of a tracked tensor (one a backward will run through) is a `gather` with
//!   the row index broadcast over the columns;
//! - [`scatter_add_rows`] is a `scatter` with `Add`;
//!
//! each in blocks of at most [`MAX_SCATTER_INDICES`] rows on a device without float atomics,
//! where burn falls back to a serial kernel (under the 65,536 at which lavapipe's serial kernel
//! failed), and of [`ATOMIC_SCATTER_VALUES`] values where the device adds floats atomically
//! ([`crate::device::adds_floats_atomically`]; which bounds the broadcast index). Atomic adds land in no fixed order,
//! so on a GPU these sums may differ in the last bits from run to run. On the CPU backends,
//! and for gathers no backward runs through, each stays one `select` / `select_assign`.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::device::{adds_floats_atomically, computes_on_cpu};

/// The most rows one gather or scatter-add gets on a GPU backend without float atomics (half
/// of the 65,536 from which lavapipe's serial scatter-add went wrong).
pub const MAX_SCATTER_INDICES: usize = 32_768;

/// The most values (rows x columns) one gather or scatter-add gets on a device that adds floats
/// atomically: 64 MiB of `f32`, so that an `Im2col` block's column gradient
/// ([`crate::body_volume::sparse_conv::GPU_IM2COL_BLOCK_BYTES`]) is one kernel, and under the
/// 128 MiB storage-buffer binding of Mesa's software Vulkan even if the broadcast index were
/// laid out in memory.
pub const ATOMIC_SCATTER_VALUES: usize = 1 << 24;

/// Rows per gather or scatter-add of `columns`-wide rows on a GPU backend:
/// [`MAX_SCATTER_INDICES`], or where the device adds floats atomically the power of two at
/// most [`ATOMIC_SCATTER_VALUES`] / `columns` when that is more. Powers of two keep the
/// blocks' slices on the device's alignment (views, not copies), also when a caller divides
/// them by its 4 or 8 taps.
pub fn scatter_block_rows(atomic: bool, columns: usize) -> usize {
    if atomic {
        let rows = ATOMIC_SCATTER_VALUES / columns.max(1);
        let power_of_two = 1usize << (usize::BITS - 1 - rows.max(1).leading_zeros());
        power_of_two.max(MAX_SCATTER_INDICES)
    } else {
        MAX_SCATTER_INDICES
    }
}

/// `(start, len)` of the blocks of `step` among `len` indices.
fn blocks(len: usize, step: usize) -> impl Iterator<Item = (usize, usize)> {
    (0..len)
        .step_by(step)
        .map(move |start| (start, step.min(len - start)))
}

/// `[L]` row indices as the `[L, C]` element indices of `gather` / `scatter` along dim 0.
fn per_element(index: Tensor<1, Int>, columns: usize) -> Tensor<2, Int> {
    let [len] = index.dims();
    index.reshape([len, 1]).expand([len, columns])
}

/// `rows.select(0, index)`; on a GPU backend with a tracked `rows`, gathered in blocks
/// (module docs).
///
/// # Shapes
/// - `rows`: `[R, C]`; `index`: `[L]` Int in `0..R`; output `[L, C]`
pub fn select_rows(rows: Tensor<2>, index: Tensor<1, Int>) -> Tensor<2> {
    let [len] = index.dims();
    if len == 0 || computes_on_cpu(&rows.device()) || !rows.is_tracked() {
        return rows.select(0, index);
    }
    let columns = rows.dims()[1];
    let step = scatter_block_rows(adds_floats_atomically(&rows.device()), columns);
    let parts: Vec<Tensor<2>> = blocks(len, step)
        .map(|(start, block)| {
            let index = per_element(index.clone().narrow(0, start, block), columns);
            rows.clone().gather(0, index)
        })
        .collect();
    Tensor::cat(parts, 0)
}

/// `target.select_assign(0, index, values, Add)`: every row of `values` added to the row of
/// `target` its index names. On a GPU backend a blocked `scatter` (module docs).
///
/// # Shapes
/// - `target`: `[R, C]`; `index`: `[L]` Int in `0..R`; `values`: `[L, C]`; output `[R, C]`
pub fn scatter_add_rows(target: Tensor<2>, index: Tensor<1, Int>, values: Tensor<2>) -> Tensor<2> {
    if computes_on_cpu(&target.device()) {
        return target.select_assign(0, index, values, IndexingUpdateOp::Add);
    }
    let [len] = index.dims();
    let columns = target.dims()[1];
    let step = scatter_block_rows(adds_floats_atomically(&target.device()), columns);
    let mut out = target;
    for (start, block) in blocks(len, step) {
        out = out.scatter(
            0,
            per_element(index.clone().narrow(0, start, block), columns),
            values.clone().narrow(0, start, block),
            IndexingUpdateOp::Add,
        );
    }
    out
}
