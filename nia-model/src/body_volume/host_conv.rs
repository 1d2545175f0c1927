//! The sparse convolution on the host, forward and backward: flex only, with and without
//! autodiff ([`ConvMethod::Host`](super::ConvMethod::Host)).
//!
//! `out[n, o] = sum_k in[n, nb(o, k)] @ W[k]` ([`super::sparse_conv`]) in blocks of output
//! rows: each block's 27 neighbours are gathered into a small buffer (a missing neighbour is a
//! zero row) and multiplied with `W` as `[27 C_in, C_out]` by `gemm`; the buffer stays in cache
//! and nothing else is allocated. Its backward is written by hand (burn's backend extension):
//! - `d in[n, i] = sum_k d out[n, inv(i, k)] @ W[k]^T`, the same blocked gather and product on
//!   the inverse neighbour map. For a fixed offset k an input site is read by at most one
//!   output (the one at `i - k`, or its stride-2 parent), so `inv` is again one slot per
//!   (site, offset): a gather, with no scatter-add (burn's backward of the tensor path's
//!   gather is a single-threaded scatter-add of `27 P_out` rows);
//! - `dW = sum_o gather(in, nb(o))^T @ d out[o]`, the forward's gather redone block by block
//!   (the `[N P_out, 27 C_in]` columns are never kept for the backward), summed over fixed
//!   chunks of rows and the chunks' sums added in order, so the result does not depend on the
//!   number of threads.
//!
//! Equal to the tensor path up to float summation order, and the same whatever the number of
//! threads (`nia-model/tests/body_volume_network.rs`).

use std::sync::Arc;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{binary, Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, Flex};
use burn::prelude::*;
use rayon::prelude::*;

use nia_data::geometry::sparse::{NeighbourMaps, Rulebook, KERNEL_VOLUME};

use crate::kernels::host_gemm::{product_into, Strided};
use crate::kernels::host_op::{contiguous_f32, dims, flex_tensor, values, FlexTensor};

/// A rulebook in host memory for the host kernels: the neighbour map and its inverse
/// ([`NeighbourMaps`], kept with the rulebook, so that the loader's workers can build them).
#[derive(Debug, Clone, PartialEq)]
pub struct HostRules {
    /// Input sites P_in.
    pub n_in: usize,
    /// Output sites P_out.
    pub n_out: usize,
    /// The maps: `neighbours` `[P_out * 27]` (`n_in` = none), `inverse` `[P_in * 27]` (`n_out`
    /// = none).
    pub maps: Arc<NeighbourMaps>,
}

impl HostRules {
    /// The maps of `rulebook` (built now unless the rulebook has them already).
    pub fn new(rulebook: &Rulebook) -> Self {
        HostRules {
            n_in: rulebook.n_in,
            n_out: rulebook.n_out,
            maps: rulebook.neighbour_maps(),
        }
    }
}

/// The host sparse convolution as a backend operation (burn's backend extension): flex, and
/// autodiff over flex with the hand-written backward of this module.
#[backend_extension(Autodiff, Flex)]
pub trait SparseConvBackend: Backend {
    /// `features` `[N, P_in, C_in]`, `weight` `[27, C_in, C_out]` -> `[N, P_out, C_out]`.
    fn sparse_conv_host(
        features: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        rules: Arc<HostRules>,
    ) -> FloatTensor<Self>;
}

/// The three host kernels on a concrete backend's buffers.
pub trait SparseConvKernels: Backend {
    /// The forward: `[N, P_in, C_in]` and `[27, C_in, C_out]` give `[N, P_out, C_out]`.
    fn conv_forward(
        features: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        rules: &HostRules,
    ) -> FloatTensor<Self>;
    /// The input gradient: `[N, P_out, C_out]` and `[27, C_in, C_out]` give `[N, P_in, C_in]`.
    fn conv_grad_input(
        grad: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        rules: &HostRules,
    ) -> FloatTensor<Self>;
    /// The weight gradient: `[N, P_in, C_in]` and `[N, P_out, C_out]` give `[27, C_in, C_out]`.
    fn conv_grad_weight(
        features: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        rules: &HostRules,
    ) -> FloatTensor<Self>;
}

impl SparseConvKernels for Flex {
    fn conv_forward(features: FlexTensor, weight: FlexTensor, rules: &HostRules) -> FlexTensor {
        let (x, w) = (contiguous_f32(features), contiguous_f32(weight));
        let [n, _, ci] = dims::<3>(&x);
        let co = dims::<3>(&w)[2];
        let gather = Gather {
            table: values(&x),
            rows_in: rules.n_in,
            c: ci,
            map: &rules.maps.neighbours,
            rows_out: rules.n_out,
        };
        let out = blocked_gather_product(&gather, n, values(&w), co);
        flex_tensor(out, [n, rules.n_out, co])
    }

    fn conv_grad_input(grad: FlexTensor, weight: FlexTensor, rules: &HostRules) -> FlexTensor {
        let (g, w) = (contiguous_f32(grad), contiguous_f32(weight));
        let [n, _, co] = dims::<3>(&g);
        let ci = dims::<3>(&w)[1];
        // W'[k * C_out + c_out, c_in] = W[k, c_in, c_out]: every offset's block transposed.
        let w = values(&w);
        let mut wt = vec![0.0f32; w.len()];
        for k in 0..KERNEL_VOLUME {
            let (src, dst) = (
                &w[k * ci * co..(k + 1) * ci * co],
                &mut wt[k * ci * co..(k + 1) * ci * co],
            );
            for c_in in 0..ci {
                for c_out in 0..co {
                    dst[c_out * ci + c_in] = src[c_in * co + c_out];
                }
            }
        }
        let gather = Gather {
            table: values(&g),
            rows_in: rules.n_out,
            c: co,
            map: &rules.maps.inverse,
            rows_out: rules.n_in,
        };
        let out = blocked_gather_product(&gather, n, &wt, ci);
        flex_tensor(out, [n, rules.n_in, ci])
    }

    fn conv_grad_weight(features: FlexTensor, grad: FlexTensor, rules: &HostRules) -> FlexTensor {
        let (x, g) = (contiguous_f32(features), contiguous_f32(grad));
        let [n, _, ci] = dims::<3>(&x);
        let co = dims::<3>(&g)[2];
        let out = gathered_outer_sum(values(&x), rules, n, ci, values(&g), co);
        flex_tensor(out, [KERNEL_VOLUME, ci, co])
    }
}

impl SparseConvBackend for Flex {
    fn sparse_conv_host(
        features: FlexTensor,
        weight: FlexTensor,
        rules: Arc<HostRules>,
    ) -> FlexTensor {
        <Flex as SparseConvKernels>::conv_forward(features, weight, &rules)
    }
}

/// The backward of [`SparseConvBackend::sparse_conv_host`] under autodiff.
#[derive(Debug)]
struct SparseConvHostBackward;

impl<B: Backend + SparseConvKernels> Backward<B, 2> for SparseConvHostBackward {
    /// The features, the weight and the maps.
    type State = (FloatTensor<B>, FloatTensor<B>, Arc<HostRules>);

    fn backward(
        self,
        ops: Ops<Self::State, 2>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let (features, weight, rules) = ops.state;
        let rules_w = rules.clone();
        binary::<B, _, _>(
            ops.parents,
            ops.node,
            grads,
            |grad| B::conv_grad_input(grad, weight, &rules),
            |grad| B::conv_grad_weight(features, grad, &rules_w),
        );
    }
}

impl<B: Backend + SparseConvKernels, C: CheckpointStrategy> SparseConvBackend for Autodiff<B, C> {
    fn sparse_conv_host(
        features: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        rules: Arc<HostRules>,
    ) -> FloatTensor<Self> {
        match SparseConvHostBackward
            .prepare::<C>([features.node(), weight.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (x, w) = (features.into_primitive(), weight.into_primitive());
                let out = B::conv_forward(x.clone(), w.clone(), &rules);
                prep.finish((x, w, rules), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::conv_forward(
                features.into_primitive(),
                weight.into_primitive(),
                &rules,
            )),
        }
    }
}

/// The sparse convolution by the host kernels of this module (the device must be flex, with or
/// without autodiff: [`crate::kernels::host_op::runs_on_host`]).
///
/// # Shapes
/// - features: `[N, P_in, C_in]`
/// - weight: `[27, C_in, C_out]`
/// - output: `[N, P_out, C_out]`
pub fn sparse_conv_host(
    features: Tensor<3>,
    weight: Tensor<3>,
    rules: &Arc<HostRules>,
) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as SparseConvBackend>::sparse_conv_host(
        features.into_dispatch(),
        weight.into_dispatch(),
        rules.clone(),
    ))
}

/// Size of a gathered block in f32 values (64 KiB): it stays in the core's cache.
const BLOCK_VALUES: usize = 16 * 1024;

/// Rows per gathered block when a row holds `width` values (8..=512).
fn block_rows(width: usize) -> usize {
    (BLOCK_VALUES / width.max(1)).clamp(8, 512)
}

/// The geometry of a neighbour gather: the rows of a table, read through a map of 27 slots per
/// output row, views stacked.
#[derive(Clone, Copy)]
struct Gather<'a> {
    /// `[N, rows_in, c]`.
    table: &'a [f32],
    /// Rows per view of `table`; a slot that holds `rows_in` reads a zero row (no neighbour).
    rows_in: usize,
    /// Values per row.
    c: usize,
    /// `[rows_out * 27]`: slot k of output row r at `r * 27 + k`.
    map: &'a [u32],
    /// Output rows per view.
    rows_out: usize,
}

/// The 27 neighbours of rows `first .. first + len` (views stacked: row `v * rows_out + r`)
/// into `buf` as `[len, 27 c]`: `table[v, map[r * 27 + k]]`, a zero row where the slot holds
/// `rows_in` (no neighbour).
fn gather_columns(buf: &mut [f32], gather: &Gather<'_>, first: usize, len: usize) {
    // Narrow rows as constants: a row of 8-32 values is then a few vector moves instead of a
    // `memcpy` call per slot (the tiny network's stages are 8 and 16 wide). Wider rows keep
    // `memcpy`, which is as fast there (docs/speed.md).
    match gather.c {
        8 => gather_rows(buf, gather, Fixed::<8>, first, len),
        16 => gather_rows(buf, gather, Fixed::<16>, first, len),
        32 => gather_rows(buf, gather, Fixed::<32>, first, len),
        c => gather_rows(buf, gather, Any(c), first, len),
    }
}

/// A row width: a constant the compiler sees ([`Fixed`]) or any ([`Any`]).
trait RowWidth: Copy {
    fn get(self) -> usize;
}

/// Rows of `C` values.
#[derive(Clone, Copy)]
struct Fixed<const C: usize>;

impl<const C: usize> RowWidth for Fixed<C> {
    #[inline(always)]
    fn get(self) -> usize {
        C
    }
}

/// Rows of any width.
#[derive(Clone, Copy)]
struct Any(usize);

impl RowWidth for Any {
    #[inline(always)]
    fn get(self) -> usize {
        self.0
    }
}

/// [`gather_columns`] for rows of `width` values (`gather.c`).
fn gather_rows(
    buf: &mut [f32],
    gather: &Gather<'_>,
    width: impl RowWidth,
    first: usize,
    len: usize,
) {
    let Gather {
        table,
        rows_in,
        map,
        rows_out,
        ..
    } = *gather;
    let c = width.get();
    let k_len = KERNEL_VOLUME * c;
    for (r, cols) in buf.chunks_exact_mut(k_len).take(len).enumerate() {
        let (view, row) = ((first + r) / rows_out, (first + r) % rows_out);
        let src = &table[view * rows_in * c..(view + 1) * rows_in * c];
        let slots = &map[row * KERNEL_VOLUME..(row + 1) * KERNEL_VOLUME];
        for (slot, col) in slots.iter().zip(cols.chunks_exact_mut(c)) {
            let i = *slot as usize;
            if i < rows_in {
                col.copy_from_slice(&src[i * c..(i + 1) * c]);
            } else {
                col.fill(0.0);
            }
        }
    }
}

/// `out[n, r] = sum_k table[n, map[r * 27 + k]] @ weight[k]` for every view n and row r of
/// `gather` (`views` views), `weight` `[27 c, c_out]` row-major; returns
/// `[N, rows_out, c_out]`.
fn blocked_gather_product(
    gather: &Gather<'_>,
    views: usize,
    weight: &[f32],
    c_out: usize,
) -> Vec<f32> {
    let (c, rows_out) = (gather.c, gather.rows_out);
    let k_len = KERNEL_VOLUME * c;
    assert!(
        gather.table.len() == views * gather.rows_in * c
            && gather.map.len() == rows_out * KERNEL_VOLUME
            && weight.len() == k_len * c_out,
        "host sparse convolution: {} table values for [{views}, {}, {c}], {} map entries for \
         {rows_out} rows, {} weights for [{k_len}, {c_out}]",
        gather.table.len(),
        gather.rows_in,
        gather.map.len(),
        weight.len()
    );
    let mut out = vec![0.0f32; views * rows_out * c_out];
    if c_out == 0 || rows_out == 0 {
        return out;
    }
    let block = block_rows(k_len);
    out.par_chunks_mut(block * c_out).enumerate().for_each_init(
        || vec![0.0f32; block * k_len],
        |buf, (b, dst)| {
            let first = b * block;
            let len = dst.len() / c_out;
            gather_columns(buf, gather, first, len);
            // dst [len, c_out] = columns [len, k_len] x weight [k_len, c_out].
            product_into(
                dst,
                [len, c_out, k_len],
                Strided::rows(&buf[..len * k_len], k_len),
                Strided::rows(weight, c_out),
                false,
                gemm::Parallelism::None,
            );
        },
    );
    out
}

/// Rows of one weight-gradient chunk: a fixed share of the rows (so the chunks, and the sum,
/// do not depend on the number of threads), at least one block.
fn weight_chunk_rows(total_rows: usize, block: usize) -> usize {
    total_rows.div_ceil(16).max(block).div_ceil(block) * block
}

/// `dW[k] = sum_{n, o} x[n, nb(o, k)]^T dy[n, o]`: `x` `[N, P_in, ci]`, `dy` `[N, P_out, co]`;
/// returns `[27 ci, co]` row-major.
fn gathered_outer_sum(
    x: &[f32],
    rules: &HostRules,
    views: usize,
    ci: usize,
    dy: &[f32],
    co: usize,
) -> Vec<f32> {
    let (rows_in, rows_out) = (rules.n_in, rules.n_out);
    let k_len = KERNEL_VOLUME * ci;
    assert!(
        x.len() == views * rows_in * ci
            && dy.len() == views * rows_out * co
            && rules.maps.neighbours.len() == rows_out * KERNEL_VOLUME,
        "host sparse convolution backward: {} input values for [{views}, {rows_in}, {ci}], \
         {} gradient values for [{views}, {rows_out}, {co}]",
        x.len(),
        dy.len()
    );
    let total = views * rows_out;
    let mut dw = vec![0.0f32; k_len * co];
    if total == 0 || co == 0 || ci == 0 {
        return dw;
    }
    let block = block_rows(k_len);
    let chunk = weight_chunk_rows(total, block);
    let gather = Gather {
        table: x,
        rows_in,
        c: ci,
        map: &rules.maps.neighbours,
        rows_out,
    };
    let partials: Vec<Vec<f32>> = (0..total.div_ceil(chunk))
        .into_par_iter()
        .map(|c| {
            let mut acc = vec![0.0f32; k_len * co];
            let mut buf = vec![0.0f32; block * k_len];
            let end = ((c + 1) * chunk).min(total);
            for first in (c * chunk..end).step_by(block) {
                let len = block.min(end - first);
                gather_columns(&mut buf, &gather, first, len);
                // acc [k_len, co] += columns^T [k_len, len] x dy [len, co].
                product_into(
                    &mut acc,
                    [k_len, co, len],
                    Strided::transposed(&buf[..len * k_len], k_len),
                    Strided::rows(&dy[first * co..(first + len) * co], co),
                    true,
                    gemm::Parallelism::None,
                );
            }
            acc
        })
        .collect();
    for partial in &partials {
        for (d, p) in dw.iter_mut().zip(partial) {
            *d += p;
        }
    }
    dw
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The narrow rows' constant-width gathers write what the general one writes, value for
    /// value: over several views, from an offset row, with empty slots (`rows_in`) among them.
    #[test]
    fn gathers_of_every_width_equal_the_general_gather() {
        let (views, rows_in, rows_out) = (2, 5, 4);
        // Slot k of output row r: input row (r + k) % 6, where 5 is "no neighbour".
        let map: Vec<u32> = (0..rows_out * KERNEL_VOLUME)
            .map(|s| ((s / KERNEL_VOLUME + s % KERNEL_VOLUME) % (rows_in + 1)) as u32)
            .collect();
        assert!(map.iter().any(|&i| i as usize == rows_in));
        for c in [1, 7, 8, 16, 31, 32, 33] {
            let table: Vec<f32> = (0..views * rows_in * c).map(|i| i as f32 + 0.5).collect();
            let (first, len) = (1, views * rows_out - 2);
            let k_len = KERNEL_VOLUME * c;
            let mut general = vec![-1.0f32; (len + 1) * k_len];
            let mut fast = general.clone();
            let gather = Gather {
                table: &table,
                rows_in,
                c,
                map: &map,
                rows_out,
            };
            gather_rows(&mut general, &gather, Any(c), first, len);
            gather_columns(&mut fast, &gather, first, len);
            assert_eq!(fast, general, "rows of {c} values");
            // Row 0 of the block is output row 1 of view 0; its slot 4 reads input row 5: empty.
            assert!(general[4 * c..5 * c].iter().all(|&v| v == 0.0), "c = {c}");
            // Slot 0 reads input row 1 of view 0.
            assert_eq!(&general[..c], &table[c..2 * c], "c = {c}");
            // The spare row past `len` is not written.
            assert!(general[len * k_len..].iter().all(|&v| v == -1.0), "c = {c}");
        }
    }
}
