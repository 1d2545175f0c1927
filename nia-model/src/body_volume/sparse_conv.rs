//! A 3x3x3 sparse 3D convolution on active sites, shared sites for a batch of N views:
//! `out[n, o] = sum_k sum_{(i, o) in rules_k} in[n, i] @ W[k] (+ b)`.
//!
//! Two equivalent ways to run a rulebook on tensors (chosen per rulebook, see
//! [`ConvMethod`]):
//! - `Im2col`: a gather of the 27 neighbours of every output (a missing neighbour reads an
//!   appended zero row) into `[N, P_out, 27 C_in]` and a matmul with `W` as `[27 C_in, C_out]`,
//!   in blocks of outputs ([`GATHER_CHUNK_BYTES`], [`GPU_IM2COL_BLOCK_BYTES`]). No scatter; its
//!   cost grows with `27 P_out` whatever the number of active neighbours. In training on a GPU
//!   backend the blocks run as one operation, [`super::im2col_op`], whose backward zeroes one
//!   input-sized buffer for all blocks and keeps no columns.
//! - `Pairs`: one matmul of every input with all 27 offsets' weights (`[N P_in, 27 C_out]`),
//!   one gather of the T pairs' products and one scatter-add (`select_assign(.., Add)`) into
//!   `[N, P_out, C_out]`. The matmul costs as much as `Im2col`'s, but only T rows move through
//!   the gather / scatter; best when few neighbours are active.
//! - `Host` (flex, with or without autodiff): [`super::host_conv`], the `Im2col` product in
//!   cache-sized blocks on the host, with a hand-written backward that gathers instead of
//!   scatter-adding and keeps no columns for the backward.

use burn::module::Param;
use burn::nn::Initializer;
use burn::prelude::*;

use std::sync::Arc;

use super::host_conv::{sparse_conv_host, HostRules};
use super::im2col_op::im2col_product;
use super::view_rows::ViewRows;
use super::BodyVolumeError;
use crate::device::computes_on_cpu;
use crate::kernels::blocked_rows::{scatter_add_rows, select_rows};
use crate::kernels::host_op::runs_on_host;
use nia_data::geometry::sparse::{Rulebook, RulebookKind, KERNEL_VOLUME};

/// PyTorch's (and spconv's) default convolution init: Kaiming uniform with `a = sqrt(5)`, i.e.
/// `U(-k, k)`, `k = 1 / sqrt(fan_in)`, `fan_in = 27 C_in`; burn's `KaimingUniform` reaches the
/// same bound with gain `1 / sqrt(3)`.
const TORCH_CONV_INIT_GAIN: f64 = 0.577_350_269_189_625_8;

/// Rulebooks whose fill ratio (active (output, offset) slots / `27 P_out`) is at least this
/// run as `Im2col` under [`ConvMethod::Auto`], sparser ones as `Pairs`. Measured at paper size
/// (6890 vertices, 5 mm, 3 views, 2 busy cores; `cargo bench -p nia-model --bench body_volume`): on ndarray
/// `Pairs` is 2-3.5x faster on the two full-resolution rulebooks (fill 0.06-0.08: 78 vs 156 ms,
/// 102 vs 371 ms) and slower from fill ~0.2 up; on flex blocked `Im2col` is faster at every
/// fill (40 vs 90 ms, 58 vs 97 ms there; its missing neighbours all read one cached zero
/// row). `Auto` picks by this ratio on ndarray and GPUs (where a gather + matmul avoids
/// atomics, [`ConvMethod::Im2col`] is the better choice there), and [`ConvMethod::Host`] on flex.
pub const IM2COL_MIN_FILL: f64 = 0.1;

/// How a rulebook is run on tensors (the results are equal up to float summation order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConvMethod {
    /// `Host` on flex (with or without autodiff), elsewhere by fill ratio ([`IM2COL_MIN_FILL`]).
    Auto,
    /// Gather all 27 neighbours per output, one matmul.
    Im2col,
    /// Gather the pairs, one matmul per offset, scatter-add.
    Pairs,
    /// The host kernels of [`super::host_conv`] (flex only: on another backend this runs as
    /// `Im2col`, its tensor equivalent).
    Host,
}

#[derive(Debug, Clone)]
enum RulebookIndices {
    Im2col {
        /// [P_out * 27] input site per (output, offset), `n_in` = missing (zero row), rows of
        /// `[N * (P_in + 1), C_in]`.
        neighbours: ViewRows,
    },
    Pairs {
        /// [T] row `in * 27 + k` of the per-offset products `[N * P_in * 27, C_out]` of every
        /// pair.
        product_row: ViewRows,
        /// [T] output site of every pair, rows of `[N * P_out, C_out]`.
        out_index: ViewRows,
    },
    Host {
        rules: Arc<HostRules>,
    },
}

/// A [`Rulebook`] uploaded once as Int tensors on a device, reused by every forward of every
/// view and every layer with the same sites.
#[derive(Debug, Clone)]
pub struct RulebookTensors {
    pub kind: RulebookKind,
    /// Input sites P_in.
    pub n_in: usize,
    /// Output sites P_out.
    pub n_out: usize,
    indices: RulebookIndices,
    /// Outputs per `Im2col` block; `None` = from `im2col_block_bytes`.
    outputs_per_chunk: Option<usize>,
}

impl RulebookTensors {
    /// Uploads `rulebook` with the method picked by its fill ratio.
    pub fn new(rulebook: &Rulebook, device: &Device) -> Self {
        Self::with_method(rulebook, ConvMethod::Auto, device)
    }

    /// Uploads `rulebook` for the given method.
    pub fn with_method(rulebook: &Rulebook, method: ConvMethod, device: &Device) -> Self {
        let host = runs_on_host(device);
        let method = match method {
            ConvMethod::Auto if host => ConvMethod::Host,
            ConvMethod::Auto if rulebook.fill_ratio() >= IM2COL_MIN_FILL => ConvMethod::Im2col,
            ConvMethod::Auto => ConvMethod::Pairs,
            ConvMethod::Host if !host => ConvMethod::Im2col,
            m => m,
        };
        let indices = match method {
            ConvMethod::Host => RulebookIndices::Host {
                rules: Arc::new(HostRules::new(rulebook)),
            },
            ConvMethod::Im2col => RulebookIndices::Im2col {
                neighbours: ViewRows::new(
                    rulebook.neighbour_map(),
                    KERNEL_VOLUME,
                    rulebook.n_in + 1,
                    device,
                ),
            },
            ConvMethod::Auto | ConvMethod::Pairs => {
                let mut product_row = Vec::with_capacity(rulebook.num_pairs());
                for k in 0..KERNEL_VOLUME {
                    product_row.extend(
                        rulebook
                            .pairs(k)
                            .map(|(i, _)| i * KERNEL_VOLUME as u32 + k as u32),
                    );
                }
                RulebookIndices::Pairs {
                    product_row: ViewRows::new(
                        product_row,
                        1,
                        rulebook.n_in * KERNEL_VOLUME,
                        device,
                    ),
                    out_index: ViewRows::new(rulebook.out_index.clone(), 1, rulebook.n_out, device),
                }
            }
        };
        RulebookTensors {
            kind: rulebook.kind,
            n_in: rulebook.n_in,
            n_out: rulebook.n_out,
            indices,
            outputs_per_chunk: None,
        }
    }

    /// Runs `Im2col` in blocks of `outputs` output sites (at least 1) instead of the
    /// default block ([`GATHER_CHUNK_BYTES`], or [`GPU_IM2COL_BLOCK_BYTES`] on a GPU backend);
    /// the result is the same (for tests and tuning).
    pub fn with_outputs_per_chunk(mut self, outputs: usize) -> Self {
        self.outputs_per_chunk = Some(outputs.max(1));
        self
    }

    /// The method these tensors run with (`Im2col` or `Pairs`).
    pub fn method(&self) -> ConvMethod {
        match self.indices {
            RulebookIndices::Im2col { .. } => ConvMethod::Im2col,
            RulebookIndices::Pairs { .. } => ConvMethod::Pairs,
            RulebookIndices::Host { .. } => ConvMethod::Host,
        }
    }
}

/// Size of one gathered block of `Im2col` columns (and of the CPU backends' trilinear read),
/// bytes. Gathering in blocks this small instead of all at once keeps the allocator reusing
/// memory instead of mapping fresh pages for every block: on flex at paper size 1.5-2x faster
/// per `Im2col` convolution and ~4x faster trilinear sampling (64 MiB blocks gain nothing;
/// 1-4 MiB are as fast). Results do not depend on it.
pub const GATHER_CHUNK_BYTES: usize = 16 << 20;

/// Size of one gathered block of `Im2col` columns on a GPU backend, bytes: fewer blocks, fewer
/// kernel launches (on lavapipe the paper forward's launches at 256 rays fell from 1,220 to
/// 761). Under the 128 MiB storage-buffer binding range of Mesa's lavapipe (see
/// [`super::trilinear::BY_CORNER_BLOCK_BYTES`]). Training used [`GATHER_CHUNK_BYTES`] while
/// its tracked gathers had a backward each (64 MiB blocks were slower then, docs/speed.md,
/// "Kernel launches"); it now runs [`super::im2col_op`], whose backward gathers each block
/// again and scatter-adds its column gradient in one kernel where the device adds floats
/// atomically ([`crate::kernels::blocked_rows::ATOMIC_SCATTER_VALUES`]), else in blocks of
/// [`crate::kernels::blocked_rows::MAX_SCATTER_INDICES`] rows.
pub const GPU_IM2COL_BLOCK_BYTES: usize = 64 << 20;

/// The `Im2col` block size for gathering from `rows` (module docs).
fn im2col_block_bytes(rows: &Tensor<2>) -> usize {
    if computes_on_cpu(&rows.device()) {
        GATHER_CHUNK_BYTES
    } else {
        GPU_IM2COL_BLOCK_BYTES
    }
}

/// Outputs per `Im2col` block when a row of gathered columns holds `floats_per_row` f32
/// values: [`im2col_block_bytes`] worth, and on the GPU backends a multiple of
/// [`GPU_IM2COL_BLOCK_ALIGN`] (when at least that many), so that every block's slice of the
/// stacked indices starts on the device's alignment and is a view, not a copy.
fn im2col_outputs_per_block(rows: &Tensor<2>, floats_per_row: usize) -> usize {
    let outputs = rows_per_block(im2col_block_bytes(rows), floats_per_row);
    if computes_on_cpu(&rows.device()) || outputs < GPU_IM2COL_BLOCK_ALIGN {
        outputs
    } else {
        outputs / GPU_IM2COL_BLOCK_ALIGN * GPU_IM2COL_BLOCK_ALIGN
    }
}

/// `Im2col` blocks on the GPU backends hold a multiple of this many outputs: a block's slice
/// of the stacked Int indices then starts at a multiple of `N * 64 * 27` integers, a multiple
/// of 256 bytes whether they are 4 or 8 bytes wide.
pub const GPU_IM2COL_BLOCK_ALIGN: usize = 64;

/// Rows per gathered block of `block_bytes` when a row holds `floats_per_row` f32 values (at
/// least 1).
pub(crate) fn rows_per_block(block_bytes: usize, floats_per_row: usize) -> usize {
    (block_bytes / (floats_per_row.max(1) * std::mem::size_of::<f32>())).max(1)
}

/// Concatenates chunk results along `dim` (no copy for a single chunk).
pub(crate) fn cat_parts<const D: usize>(mut parts: Vec<Tensor<D>>, dim: usize) -> Tensor<D> {
    if parts.len() == 1 {
        parts.remove(0)
    } else {
        Tensor::cat(parts, dim)
    }
}

/// [L] Int tensor of site indices.
pub(crate) fn int_tensor(values: &[u32], device: &Device) -> Tensor<1, Int> {
    let data: Vec<i64> = values.iter().map(|&v| v as i64).collect();
    let n = data.len();
    Tensor::from_data(TensorData::new(data, [n]), device)
}

/// `[N, P, C]` -> `[N * (P + 1), C]`: every view's rows followed by one zero row (index P).
pub(crate) fn rows_with_zero_row(features: Tensor<3>) -> Tensor<2> {
    let [n, p, c] = features.dims();
    let device = features.device();
    Tensor::cat(vec![features, Tensor::zeros([n, 1, c], &device)], 1).reshape([n * (p + 1), c])
}

/// Configuration of [`SparseConv3d`] (kernel 3x3x3; stride and padding come with the rulebook).
#[derive(Config, Debug)]
pub struct SparseConv3dConfig {
    /// Input channels C_in.
    pub channels_in: usize,
    /// Output channels C_out.
    pub channels_out: usize,
    /// Whether to add a bias (off when a normalisation follows, as in Neural Body).
    #[config(default = true)]
    pub bias: bool,
    /// Weight and bias init; PyTorch's default convolution init.
    #[config(
        default = "Initializer::KaimingUniform { gain: TORCH_CONV_INIT_GAIN, fan_out_only: false }"
    )]
    pub initializer: Initializer,
}

impl SparseConv3dConfig {
    /// Weights `[27, C_in, C_out]` and bias `[C_out]`, both `U(-1/sqrt(27 C_in), ..)` by default.
    pub fn init(&self, device: &Device) -> SparseConv3d {
        let fan_in = KERNEL_VOLUME * self.channels_in;
        let fan_out = KERNEL_VOLUME * self.channels_out;
        let weight = self.initializer.init_with(
            [KERNEL_VOLUME, self.channels_in, self.channels_out],
            Some(fan_in),
            Some(fan_out),
            device,
        );
        let bias = self.bias.then(|| {
            self.initializer
                .init_with([self.channels_out], Some(fan_in), Some(fan_out), device)
        });
        SparseConv3d { weight, bias }
    }
}

/// A 3x3x3 sparse convolution (submanifold or strided, as its rulebook says).
#[derive(Module, Debug)]
pub struct SparseConv3d {
    /// [27, C_in, C_out], offset `k = (a * 3 + b) * 3 + c` (see [`nia_data::geometry::sparse::rulebook`]); equals a
    /// dense `Conv3d` weight `w[c_out, c_in, a, b, c]` on a `[.., X, Y, Z]` grid.
    pub weight: Param<Tensor<3>>,
    /// [C_out].
    pub bias: Option<Param<Tensor<1>>>,
}

impl SparseConv3d {
    /// # Shapes
    /// - features: `[N, P_in, C_in]` (N views sharing the sites)
    /// - output: `[N, P_out, C_out]`
    pub fn forward(
        &self,
        features: Tensor<3>,
        rulebook: &RulebookTensors,
    ) -> Result<Tensor<3>, BodyVolumeError> {
        let weight = self.weight.val();
        let [_, c_in, c_out] = weight.dims();
        let dims = features.dims();
        if dims[0] == 0 || dims[1] != rulebook.n_in || dims[2] != c_in {
            return Err(BodyVolumeError::shape(
                "SparseConv3d features",
                format!(
                    "[N >= 1, {}, {c_in}] (P_in of the rulebook, C_in)",
                    rulebook.n_in
                ),
                &dims,
            ));
        }
        let n = dims[0];
        let p_out = rulebook.n_out;
        if rulebook.n_in == 0 || p_out == 0 {
            return Err(BodyVolumeError::invalid(
                "SparseConv3d rulebook",
                "at least one input and one output site",
                (rulebook.n_in, p_out),
            ));
        }
        // All gathers and scatters are row operations on 2D [rows, C] tensors (the fast path
        // of the CPU backends), the N views stacked along the rows.
        let out = match &rulebook.indices {
            RulebookIndices::Host { rules } => sparse_conv_host(features, weight, rules),
            RulebookIndices::Im2col { neighbours } => {
                let rows = rows_with_zero_row(features); // [N * (P_in + 1), C_in]
                let w = weight.reshape([KERNEL_VOLUME * c_in, c_out]);
                let chunk = rulebook
                    .outputs_per_chunk
                    .unwrap_or_else(|| im2col_outputs_per_block(&rows, n * KERNEL_VOLUME * c_in));
                // [N * P_out * 27], block by block and view-major within a block.
                let stacked = neighbours.stacked(n, chunk);
                if rows.is_tracked() && !computes_on_cpu(&rows.device()) {
                    // Training on a GPU backend: one operation whose backward zeroes one
                    // input-sized buffer for all blocks, not one per block.
                    return Ok(add_bias(
                        im2col_product(rows, w, stacked, n, chunk),
                        &self.bias,
                    ));
                }
                let mut parts = Vec::with_capacity(p_out.div_ceil(chunk));
                for start in (0..p_out).step_by(chunk) {
                    let len = chunk.min(p_out - start);
                    let index = if len == p_out {
                        stacked.clone()
                    } else {
                        stacked.clone().slice(neighbours.block_range(n, start, len))
                    };
                    parts.push(
                        select_rows(rows.clone(), index)
                            .reshape([n * len, KERNEL_VOLUME * c_in])
                            .matmul(w.clone())
                            .reshape([n, len, c_out]),
                    );
                }
                cat_parts(parts, 1)
            }
            RulebookIndices::Pairs {
                product_row,
                out_index,
            } => {
                let device = features.device();
                let out = Tensor::zeros([n * p_out, c_out], &device);
                if product_row.groups() == 0 {
                    out.reshape([n, p_out, c_out])
                } else {
                    // Every input times every offset's weight: [N * P_in * 27, C_out].
                    let w_all = weight
                        .swap_dims(0, 1)
                        .reshape([c_in, KERNEL_VOLUME * c_out]);
                    let products = features
                        .reshape([n * rulebook.n_in, c_in])
                        .matmul(w_all)
                        .reshape([n * rulebook.n_in * KERNEL_VOLUME, c_out]);
                    // One block: [N * T], view-major.
                    let gathered = select_rows(products, product_row.stacked(n, usize::MAX));
                    scatter_add_rows(out, out_index.stacked(n, usize::MAX), gathered)
                        .reshape([n, p_out, c_out])
                }
            }
        };
        Ok(add_bias(out, &self.bias))
    }
}

/// `out` `[N, P, C_out]` plus the bias `[C_out]`, if there is one.
fn add_bias(out: Tensor<3>, bias: &Option<Param<Tensor<1>>>) -> Tensor<3> {
    match bias {
        Some(bias) => {
            let c_out = out.dims()[2];
            out + bias.val().reshape([1, 1, c_out])
        }
        None => out,
    }
}
