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
//! each in blocks of at most [`MAX_SCATTER_INDICES`] rows (which bounds the broadcast index
//! and keeps a device without float atomics, where burn falls back to a serial kernel, under
//! the 65,536 at which lavapipe's serial kernel failed). Atomic adds land in no fixed order,
//! so on a GPU these sums may differ in the last bits from run to run. On the CPU backends,
//! and for gathers no backward runs through, each stays one `select` / `select_assign`.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::device::computes_on_cpu;

/// The most rows one gather or scatter-add gets on a GPU backend (half of the 65,536 from
/// which lavapipe's serial scatter-add went wrong).
pub const MAX_SCATTER_INDICES: usize = 32_768;

/// `(start, len)` of the blocks of `len` indices.
fn blocks(len: usize) -> impl Iterator<Item = (usize, usize)> {
    (0..len)
        .step_by(MAX_SCATTER_INDICES)
        .map(move |start| (start, MAX_SCATTER_INDICES.min(len - start)))
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
    let parts: Vec<Tensor<2>> = blocks(len)
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
    let mut out = target;
    for (start, block) in blocks(len) {
        out = out.scatter(
            0,
            per_element(index.clone().narrow(0, start, block), columns),
            values.clone().narrow(0, start, block),
            IndexingUpdateOp::Add,
        );
    }
    out
}
