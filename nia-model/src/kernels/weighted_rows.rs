//! Weighted row gathers, the bilinear and trilinear reads, as one host operation with a
//! hand-written backward (burn's backend extension): on flex, with and without autodiff.
//!
//! `out[r] = sum_j weight[r K + j] * table[index[r K + j]]` for R output rows of C values and K
//! taps a row (4 corners of a pixel-feature read, 8 of a body-volume read), the taps in order.
//! The taps are computed on the host and carry no gradient: the points' projections and their
//! voxel corners do not depend on the network. The tensor reads gather K blocks of rows, weight
//! them and sum them (K gathers, K products, K - 1 sums or a reduction, each a buffer of the
//! whole read), and under autodiff each has its own backward, the gathers' a single-threaded
//! scatter-add into a zeroed table per corner. Here the forward is one pass over the output rows
//! on rayon's threads, and the backward
//! `d table[t] = sum over taps (r, j) with index t of weight * d out[r]` gives every thread a
//! range of table rows: each walks all the taps in order and adds the ones that land in its
//! range, so every table row is summed in tap order whatever the number of threads, with no
//! atomics and no sort. Equal to the tensor reads up to float summation order
//! (`nia-model/tests/weighted_rows.rs`).

use std::sync::Arc;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{unary, Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, Flex, TensorMetadata};
use burn::prelude::*;
use rayon::prelude::*;

use crate::kernels::host_buffer::zeroed;
use crate::kernels::host_op::{contiguous_f32, dims, flex_tensor, values, FlexTensor};

/// The taps of a read: K (index, weight) pairs for each of P points, read in V views. Output
/// row `v P + p` reads table rows `index[p K + j] + v view_stride` with weights
/// `weight[p K + j]`, j = 0..K: the views' rows lie `view_stride` apart in the table, so the
/// taps are stored once, not once per view.
#[derive(Debug, Clone, PartialEq)]
pub struct Taps {
    /// K, taps per output row (at least 1).
    pub per_row: usize,
    /// `[P K]` table rows of view 0 (shared: the body volume's reads keep them per call).
    pub index: Arc<Vec<u32>>,
    /// `[P K]` weights.
    pub weight: Arc<Vec<f32>>,
    /// V, the views (at least 1).
    pub views: usize,
    /// Table rows between one view's rows and the next's.
    pub view_stride: usize,
}

impl Taps {
    /// Taps read in one view.
    pub fn new(per_row: usize, index: Vec<u32>, weight: Vec<f32>) -> Self {
        Self::shared(per_row, Arc::new(index), Arc::new(weight))
    }

    /// Taps read in one view, from index and weight vectors shared with their owner.
    pub fn shared(per_row: usize, index: Arc<Vec<u32>>, weight: Arc<Vec<f32>>) -> Self {
        Taps {
            per_row,
            index,
            weight,
            views: 1,
            view_stride: 0,
        }
    }

    /// P, the points of one view.
    pub fn points(&self) -> usize {
        self.index.len() / self.per_row.max(1)
    }

    /// R = V P, the output rows.
    pub fn rows(&self) -> usize {
        self.views * self.points()
    }
}

/// The weighted gather as a backend operation: flex, and autodiff over flex with this module's
/// backward.
#[backend_extension(Autodiff, Flex)]
pub trait WeightedRowsBackend: Backend {
    /// `table` `[T, C]` read at `taps` -> `[R, C]`.
    fn weighted_rows(table: FloatTensor<Self>, taps: Arc<Taps>) -> FloatTensor<Self>;
}

/// The host kernels on a concrete backend's buffers.
pub trait WeightedRowsKernels: Backend {
    /// The forward: `[T, C]` -> `[R, C]`.
    fn weighted_rows_forward(table: FloatTensor<Self>, taps: &Taps) -> FloatTensor<Self>;
    /// The table's gradient `[table_rows, C]` from the output's `[R, C]`.
    fn weighted_rows_backward(
        grad: FloatTensor<Self>,
        taps: &Taps,
        table_rows: usize,
    ) -> FloatTensor<Self>;
}

/// Output rows per parallel task of the forward.
const ROWS_PER_TASK: usize = 256;

/// Values from which the forward and the backward run on rayon's threads.
const PARALLEL_VALUES: usize = 64 * 1024;

/// The forward on host slices: `table` `[_, c]` row-major -> `[R, c]` row-major.
///
/// # Panics
/// On a tap past the table (every caller's taps come from its own table, so that is a bug,
/// never a read past the buffer).
pub fn gather_weighted(table: &[f32], c: usize, taps: &Taps) -> Vec<f32> {
    let (r, k, p) = (taps.rows(), taps.per_row, taps.points());
    let mut out = zeroed(r * c);
    if c == 0 {
        return out;
    }
    let table_rows = table.len() / c;
    let rows = |first: usize, block: &mut [f32]| {
        for (i, acc) in block.chunks_exact_mut(c).enumerate() {
            let (view, point) = ((first + i) / p, (first + i) % p);
            for j in point * k..(point + 1) * k {
                let t = taps.index[j] as usize + view * taps.view_stride;
                assert!(
                    t < table_rows,
                    "weighted rows: a tap of row {t} in a table of {table_rows} rows"
                );
                let w = taps.weight[j];
                for (a, &v) in acc.iter_mut().zip(&table[t * c..(t + 1) * c]) {
                    *a += v * w;
                }
            }
        }
    };
    if out.len() < PARALLEL_VALUES {
        rows(0, &mut out);
    } else {
        out.par_chunks_mut(ROWS_PER_TASK * c)
            .enumerate()
            .for_each(|(task, block)| rows(task * ROWS_PER_TASK, block));
    }
    out
}

/// The backward on host slices: `grad` `[R, c]` -> the table's gradient `[table_rows, c]`
/// (taps past the table, which [`gather_weighted`] refuses, add nothing).
pub fn scatter_weighted(grad: &[f32], c: usize, taps: &Taps, table_rows: usize) -> Vec<f32> {
    let (k, p) = (taps.per_row, taps.points());
    let mut out = zeroed(table_rows * c);
    if c == 0 || table_rows == 0 {
        return out;
    }
    // Table rows [first, first + len) of the gradient, from every tap in order.
    let range = |first: usize, block: &mut [f32]| {
        let end = first + block.len() / c;
        for view in 0..taps.views {
            let offset = view * taps.view_stride;
            for (j, (&t, &w)) in taps.index.iter().zip(taps.weight.iter()).enumerate() {
                let t = t as usize + offset;
                if t < first || t >= end {
                    continue;
                }
                let row = view * p + j / k;
                let dst = &mut block[(t - first) * c..(t - first + 1) * c];
                for (d, &g) in dst.iter_mut().zip(&grad[row * c..(row + 1) * c]) {
                    *d += g * w;
                }
            }
        }
    };
    let threads = rayon::current_num_threads();
    if grad.len() < PARALLEL_VALUES || threads == 1 {
        range(0, &mut out);
    } else {
        // Twice as many ranges as threads, for balance; any split gives the same sums.
        let per_range = table_rows.div_ceil(2 * threads).max(1);
        out.par_chunks_mut(per_range * c)
            .enumerate()
            .for_each(|(i, block)| range(i * per_range, block));
    }
    out
}

/// Checks that `taps` are laid out as [`Taps`] says (the forward checks every tap's row).
fn check_taps(taps: &Taps) {
    assert!(
        taps.per_row > 0
            && taps.views > 0
            && taps.index.len() == taps.weight.len()
            && taps.index.len().is_multiple_of(taps.per_row),
        "weighted rows: {} indices and {} weights, {} per row, {} views",
        taps.index.len(),
        taps.weight.len(),
        taps.per_row,
        taps.views
    );
}

impl WeightedRowsKernels for Flex {
    fn weighted_rows_forward(table: FlexTensor, taps: &Taps) -> FlexTensor {
        let table = contiguous_f32(table);
        let c = dims::<2>(&table)[1];
        check_taps(taps);
        flex_tensor(gather_weighted(values(&table), c, taps), [taps.rows(), c])
    }

    fn weighted_rows_backward(grad: FlexTensor, taps: &Taps, table_rows: usize) -> FlexTensor {
        let grad = contiguous_f32(grad);
        let [r, c] = dims::<2>(&grad);
        check_taps(taps);
        assert_eq!(r, taps.rows(), "weighted rows: gradient rows");
        flex_tensor(
            scatter_weighted(values(&grad), c, taps, table_rows),
            [table_rows, c],
        )
    }
}

impl WeightedRowsBackend for Flex {
    fn weighted_rows(table: FlexTensor, taps: Arc<Taps>) -> FlexTensor {
        <Flex as WeightedRowsKernels>::weighted_rows_forward(table, &taps)
    }
}

/// The backward of [`WeightedRowsBackend::weighted_rows`] under autodiff.
#[derive(Debug)]
struct WeightedRowsBackward;

impl<B: Backend + WeightedRowsKernels> Backward<B, 1> for WeightedRowsBackward {
    /// The taps and the table's row count.
    type State = (Arc<Taps>, usize);

    fn backward(
        self,
        ops: Ops<Self::State, 1>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let (taps, table_rows) = ops.state;
        unary::<B, _>(ops.parents, ops.node, grads, |grad| {
            B::weighted_rows_backward(grad, &taps, table_rows)
        });
    }
}

impl<B: Backend + WeightedRowsKernels, C: CheckpointStrategy> WeightedRowsBackend
    for Autodiff<B, C>
{
    fn weighted_rows(table: FloatTensor<Self>, taps: Arc<Taps>) -> FloatTensor<Self> {
        match WeightedRowsBackward
            .prepare::<C>([table.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let table = table.into_primitive();
                let table_rows = table.shape().dims::<2>()[0];
                let out = B::weighted_rows_forward(table, &taps);
                prep.finish((taps, table_rows), out)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::weighted_rows_forward(table.into_primitive(), &taps))
            }
        }
    }
}

/// `table` read at `taps` by the host operation (the device must be flex, with or without
/// autodiff: [`crate::kernels::host_op::runs_on_host`]).
///
/// # Shapes
/// - `table`: `[T, C]`; output `[R, C]`
pub fn weighted_rows(table: Tensor<2>, taps: Taps) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as WeightedRowsBackend>::weighted_rows(
        table.into_dispatch(),
        Arc::new(taps),
    ))
}
