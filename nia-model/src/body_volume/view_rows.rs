//! Row indices of N views stacked along the rows, laid out on the host once per view count
//! and block size: the gathers and scatter-adds of [`super::sparse_conv`] read rows
//! `v * rows + index[l]` of `[N * rows, C]` features.
//!
//! Made on the device, every block of every layer paid an `arange` (burn's fusion builds it
//! from a fill and a cumulative sum), a product, a broadcast sum and a slice of the index:
//! four to five kernel launches per block, about a hundred per training step
//! (docs/speed.md, "Indices laid out on the host"). The host already holds every index (the
//! rulebook), so it writes the stacked indices out once per (views, block) and uploads them;
//! each block is then one slice of that tensor (a view of it on a GPU when the block starts
//! and ends on the device's alignment). The values are the same integers either way.

use std::sync::{Arc, Mutex};

use burn::prelude::*;

/// How many (views, block) layouts a rulebook keeps: its layers share one rulebook with
/// at most two block sizes (the first layer's input channels may differ).
const CACHED_LAYOUTS: usize = 4;

/// The stacked layouts made so far, oldest first: `(views, groups per block)` and the stacked
/// indices `[N * G * group]`.
type Layouts = Vec<((usize, usize), Tensor<1, Int>)>;

/// The host's row indices of one view, grouped (`group` indices per output of a block), and
/// the stacked layouts made from them so far.
#[derive(Debug, Clone)]
pub(crate) struct ViewRows {
    /// `[G * group]` rows of one view, `< rows`.
    index: Arc<[u32]>,
    /// Indices per group (27 for an `Im2col` output, 1 for a pair).
    group: usize,
    /// Rows per view of the indexed tensor (the view stride).
    rows: usize,
    device: Device,
    /// `(views, groups per block)` -> the stacked indices `[N * G * group]` on `device`.
    layouts: Arc<Mutex<Layouts>>,
}

impl ViewRows {
    /// `index` `[G * group]`: rows `< rows` of one view of the indexed tensor.
    pub(crate) fn new(index: Vec<u32>, group: usize, rows: usize, device: &Device) -> Self {
        debug_assert!(group > 0 && index.len().is_multiple_of(group));
        ViewRows {
            index: index.into(),
            group,
            rows,
            device: device.clone(),
            layouts: Arc::new(Mutex::new(Vec::new())),
        }
    }

    /// Groups G (outputs of an `Im2col` rulebook, pairs of a `Pairs` one).
    pub(crate) fn groups(&self) -> usize {
        self.index.len() / self.group
    }

    /// The rows of `views` stacked views, block by block: for each block of `block` groups
    /// (the last one shorter), view 0's rows of the block, then view 1's, and so on, each
    /// `v * rows + index[l]`. The rows of the groups `start..start + len` of a block are then
    /// [`Self::block_range`]`(views, start, len)` of it.
    ///
    /// # Shapes
    /// - output: `[views * G * group]` Int
    pub(crate) fn stacked(&self, views: usize, block: usize) -> Tensor<1, Int> {
        let block = block.clamp(1, self.groups().max(1));
        let key = (views, block);
        // A poisoned lock only means another thread panicked while inserting; the entries are
        // whole tensors either way.
        let mut layouts = self.layouts.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, t)) = layouts.iter().find(|(k, _)| *k == key) {
            return t.clone();
        }
        let per_block = block * self.group;
        let mut out: Vec<i64> = Vec::with_capacity(views * self.index.len());
        for part in self.index.chunks(per_block) {
            for v in 0..views {
                let base = (v * self.rows) as i64;
                out.extend(part.iter().map(|&i| base + i as i64));
            }
        }
        let n = out.len();
        let tensor = Tensor::<1, Int>::from_data(TensorData::new(out, [n]), &self.device);
        if layouts.len() == CACHED_LAYOUTS {
            layouts.remove(0);
        }
        layouts.push((key, tensor.clone()));
        tensor
    }

    /// The element range of [`Self::stacked`]`(views, ..)` that holds the block of groups
    /// `start..start + len` (`start` a multiple of the block size).
    pub(crate) fn block_range(
        &self,
        views: usize,
        start: usize,
        len: usize,
    ) -> std::ops::Range<usize> {
        let first = views * start * self.group;
        first..first + views * len * self.group
    }
}

/// The same rows made on the device, for indices that arrive with every call (the CPU
/// backends' stacked trilinear read): `[N * L]`, view-major, `v * rows + index[l]`.
pub(crate) fn per_view_rows(index: &Tensor<1, Int>, views: usize, rows: usize) -> Tensor<1, Int> {
    if views == 1 {
        return index.clone();
    }
    let [len] = index.dims();
    let offsets = Tensor::<1, Int>::arange(0..views as i64, &index.device())
        .mul_scalar(rows as i64)
        .reshape([views, 1]);
    (offsets + index.clone().reshape([1, len])).reshape([views * len])
}
