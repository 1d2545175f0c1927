//! Row gathers and scatter-adds in blocks of indices on the GPU backends.
//!
//! burn-cubecl 0.22.1 runs `select_assign` (a scatter-add, and the backward of every
//! `select`) as one serial loop over the indices per column. On Mesa's software Vulkan
//! (lavapipe) it returned wrong sums from 65,536 indices on: 65,535 were right, 65,536 were
//! not (docs/testing.md, "wgpu"). The forward passes were right, but the gradients of the
//! body volume and of the image encoder on wgpu were 30-80 % off, which
//! `nia-model/tests/model.rs::wgpu_training_gradients_match_ndarray` now checks. Whether an
//! NVIDIA driver does the same is not known: the one GPU run checked forwards only.
//!
//! On the GPU backends these helpers keep every such call under the limit:
//! - [`select_rows`] gathers a tracked tensor (one whose backward will run) block by block,
//!   so its backward scatters each block by itself;
//! - [`scatter_add_rows`] adds block by block.
//!
//! On the CPU backends, and for gathers no backward runs through, each stays one call.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::device::computes_on_cpu;

/// The most indices one `select_assign` gets on a GPU backend (half of the 65,536 from which
/// lavapipe went wrong).
pub const MAX_SCATTER_INDICES: usize = 32_768;

/// Whether calls with `len` indices on `device` are split into blocks.
fn in_blocks(len: usize, device: &Device) -> bool {
    len > MAX_SCATTER_INDICES && !computes_on_cpu(device)
}

/// `rows.select(0, index)`; on a GPU backend with a tracked `rows` and more than
/// [`MAX_SCATTER_INDICES`] indices, gathered in blocks of at most that many.
///
/// # Shapes
/// - `rows`: `[R, C]`; `index`: `[L]` Int in `0..R`; output `[L, C]`
pub fn select_rows(rows: Tensor<2>, index: Tensor<1, Int>) -> Tensor<2> {
    let [len] = index.dims();
    if !in_blocks(len, &rows.device()) || !rows.is_tracked() {
        return rows.select(0, index);
    }
    let parts = (0..len)
        .step_by(MAX_SCATTER_INDICES)
        .map(|start| {
            let block = MAX_SCATTER_INDICES.min(len - start);
            rows.clone()
                .select(0, index.clone().narrow(0, start, block))
        })
        .collect();
    Tensor::cat(parts, 0)
}

/// `target.select_assign(0, index, values, Add)`: every row of `values` added to the row of
/// `target` its index names. On a GPU backend, in blocks of at most [`MAX_SCATTER_INDICES`].
///
/// # Shapes
/// - `target`: `[R, C]`; `index`: `[L]` Int in `0..R`; `values`: `[L, C]`; output `[R, C]`
pub fn scatter_add_rows(target: Tensor<2>, index: Tensor<1, Int>, values: Tensor<2>) -> Tensor<2> {
    let [len] = index.dims();
    if !in_blocks(len, &target.device()) {
        return target.select_assign(0, index, values, IndexingUpdateOp::Add);
    }
    let mut out = target;
    for start in (0..len).step_by(MAX_SCATTER_INDICES) {
        let block = MAX_SCATTER_INDICES.min(len - start);
        out = out.select_assign(
            0,
            index.clone().narrow(0, start, block),
            values.clone().narrow(0, start, block),
            IndexingUpdateOp::Add,
        );
    }
    out
}
