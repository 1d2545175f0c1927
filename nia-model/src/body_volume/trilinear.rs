//! Trilinear sampling of a sparse volume at query points, on the active sites (no dense grid).
//!
//! Convention: the value of site `o` sits at `origin + o * voxel_size` (voxel centres, see
//! [`nia_data::geometry::sparse::voxelize`]); a point `p` has continuous grid coordinates
//! `u = (p - origin) / voxel_size` and reads the 8 corners `floor(u) + {0, 1}^3` with the usual
//! trilinear weights. This is `grid_sample(align_corners=True, padding_mode="zeros")` on a dense
//! grid whose corner samples are the voxel centres (grid coordinate -1 = centre of voxel 0,
//! +1 = centre of voxel D - 1): corners outside the grid or not active read zero. Points outside
//! the level-0 box read zero everywhere (all 8 weights 0).
//!
//! The corners and weights are computed on the CPU
//! ([`nia_data::geometry::sparse::TrilinearCorners`]); here they are uploaded in the layout of
//! the backend's read ([`CornerRead`]) and used: `[N, P_s, C] -> [N, M, C]`, differentiable in
//! the features: row gathers from the features with a zero row appended ([`SiteRows`]) and a
//! weighted sum over the corners. On flex that read is one weighted gather with its own
//! backward from corners kept in host memory ([`crate::kernels::weighted_rows`]); in training on a GPU
//! backend it is one operation with its own backward ([`crate::kernels::tap_gather`]).

use std::sync::Arc;

use burn::prelude::*;

use super::sparse_conv::{
    cat_parts, int_tensor, rows_per_block, rows_with_zero_row, GATHER_CHUNK_BYTES,
};
use super::view_rows::per_view_rows;
use super::BodyVolumeError;
use crate::device::computes_on_cpu;
use crate::kernels::blocked_rows::select_rows;
use crate::kernels::host_op::runs_on_host;
use crate::kernels::tap_gather::tap_gather;
use crate::kernels::weighted_rows::{weighted_rows, Taps};
pub use nia_data::geometry::sparse::{TrilinearCorners, CORNERS};

/// How [`sample`] reads the 8 corners of a block of points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CornerRead {
    /// One row gather of all 8 corners (`[N, len, 8, C]`) from the view-major rows, then the
    /// weighted sum over the corners as one broadcast product summed along them. The CPU
    /// backends' read: few operations per block, and blocks small enough for the allocator to
    /// reuse.
    Stacked,
    /// One row gather per corner from the site-major rows (`[len, N * C]`: every view of a
    /// site in one row, so no per-view index), weighted and added to the sum. The GPU
    /// backends' read: no `[N, len, 8, C]` intermediate, and blocks of 64 MiB, so a block
    /// holds 32 times the points of a stacked one and a read has far fewer blocks of a few
    /// kernel launches each (at 4096 rays x 64 samples and the paper's scales, 20 blocks
    /// instead of 532). The corners are uploaded corner-major, so a corner's indices and
    /// weights are a row of their tensors: a view, not a copy, when the row starts on the
    /// device's alignment (docs/speed.md, "Slices that are views").
    ByCorner,
}

impl CornerRead {
    /// The read the backend of `device` uses.
    pub fn for_device(device: &Device) -> Self {
        if computes_on_cpu(device) {
            CornerRead::Stacked
        } else {
            CornerRead::ByCorner
        }
    }

    /// Points per block for `n` views of `c` channels: the gathered tensor of one block fills
    /// [`GATHER_CHUNK_BYTES`] (stacked) or [`BY_CORNER_BLOCK_BYTES`] (by corner; a multiple of
    /// [`BY_CORNER_BLOCK_ALIGN`] points where it holds more).
    pub fn points_per_block(self, n: usize, c: usize) -> usize {
        match self {
            CornerRead::Stacked => rows_per_block(GATHER_CHUNK_BYTES, n * CORNERS * c),
            CornerRead::ByCorner => {
                let rows = rows_per_block(BY_CORNER_BLOCK_BYTES, n * c);
                if rows >= BY_CORNER_BLOCK_ALIGN {
                    rows / BY_CORNER_BLOCK_ALIGN * BY_CORNER_BLOCK_ALIGN
                } else {
                    rows
                }
            }
        }
    }
}

/// Size of one corner's gather in [`CornerRead::ByCorner`], bytes. On a GPU every block costs
/// kernel launches and burn's per-operation work on the host, so blocks are larger than the
/// CPU's; but one tensor must fit in one storage-buffer binding, and cubecl-wgpu 0.11 caps
/// its allocations at the device's `maxStorageBufferRange` where the driver has no 64-bit
/// indexing: 128 MiB on Mesa's lavapipe, where 256 MiB blocks read wrong values
/// (docs/speed.md, "Training on a GPU"). Half of that leaves room on every device this project
/// has met.
pub const BY_CORNER_BLOCK_BYTES: usize = 64 << 20;

/// A multiple of which the points of a [`CornerRead::ByCorner`] block are (when a block holds
/// that many): 2,048 points of 4-byte indices or weights are 8 KiB, a multiple of any
/// storage-buffer alignment, so a block's slice of a corner's row is a view when the row's
/// length is one too (the GPU renders' point counts are multiples of 2,048,
/// [`crate::renderer::shape_buckets::bucket_len`]).
pub const BY_CORNER_BLOCK_ALIGN: usize = 2048;

/// The corners' sites and weights in host memory, `[M * 8]` each.
pub type HostCorners = (Arc<Vec<u32>>, Arc<Vec<f32>>);

/// [`TrilinearCorners`] on a device, in the layout of one [`CornerRead`].
#[derive(Debug, Clone)]
pub struct TrilinearTensors {
    /// Site of each corner (P_s = the zero row): `[M, 8]` point-major for
    /// [`CornerRead::Stacked`], `[8, M]` corner-major for [`CornerRead::ByCorner`].
    pub index: Tensor<2, Int>,
    /// The weights, laid out as `index`.
    pub weight: Tensor<2>,
    /// The read the layout is for.
    pub read: CornerRead,
    /// On flex, for [`CornerRead::Stacked`]: the corners' sites and weights in host memory
    /// (`[M * 8]` each), which [`sample`] reads as one weighted gather with its own backward
    /// ([`crate::kernels::weighted_rows`]); every read shares them.
    pub host: Option<HostCorners>,
    /// M.
    pub num_points: usize,
    /// P_s.
    pub num_sites: usize,
}

impl TrilinearTensors {
    /// Uploads `corners` to `device` for its backend's read ([`CornerRead::for_device`]).
    pub fn upload(corners: &TrilinearCorners, device: &Device) -> Self {
        Self::upload_for(corners, CornerRead::for_device(device), device)
    }

    /// Uploads `corners` to `device` laid out for `read` (for tests and tuning).
    pub fn upload_for(corners: &TrilinearCorners, read: CornerRead, device: &Device) -> Self {
        let m = corners.num_points();
        let (index, weight, shape) = match read {
            CornerRead::Stacked => (
                int_tensor(&corners.index, device),
                corners.weight.clone(),
                [m, CORNERS],
            ),
            CornerRead::ByCorner => (
                int_tensor(&corner_major(&corners.index), device),
                corner_major(&corners.weight),
                [CORNERS, m],
            ),
        };
        TrilinearTensors {
            index: index.reshape(shape),
            weight: Tensor::from_data(TensorData::new(weight, shape), device),
            read,
            host: (read == CornerRead::Stacked && runs_on_host(device)).then(|| {
                (
                    Arc::new(corners.index.clone()),
                    Arc::new(corners.weight.clone()),
                )
            }),
            num_points: m,
            num_sites: corners.num_sites,
        }
    }
}

/// `[M, 8]` point-major values as `[8, M]` corner-major.
fn corner_major<T: Copy>(values: &[T]) -> Vec<T> {
    let m = values.len() / CORNERS;
    (0..CORNERS)
        .flat_map(|j| (0..m).map(move |p| values[p * CORNERS + j]))
        .collect()
}

/// A volume's features as [`sample_rows`] gathers them: every view's rows and a zero row (the
/// read of an inactive or outside corner, index P_s), laid out for one [`CornerRead`]. Built
/// once per scene and read by every call ([`super::ScaleVolume`]).
#[derive(Debug, Clone)]
pub struct SiteRows {
    /// [`CornerRead::Stacked`]: `[N * (P_s + 1), C]`, view-major (row `n (P_s + 1) + p`).
    /// [`CornerRead::ByCorner`]: `[P_s + 1, N * C]`, site-major (row `p` holds every view).
    pub rows: Tensor<2>,
    /// The layout.
    pub read: CornerRead,
    /// N.
    pub num_views: usize,
    /// P_s.
    pub num_sites: usize,
    /// C.
    pub channels: usize,
}

impl SiteRows {
    /// The rows of `features` for `read`.
    ///
    /// # Shapes
    /// - features: `[N, P_s, C]`
    pub fn new(features: Tensor<3>, read: CornerRead) -> Self {
        let [n, p_s, c] = features.dims();
        let rows = match read {
            CornerRead::Stacked => rows_with_zero_row(features),
            CornerRead::ByCorner => {
                let device = features.device();
                Tensor::cat(vec![features, Tensor::zeros([n, 1, c], &device)], 1)
                    .swap_dims(0, 1)
                    .reshape([p_s + 1, n * c])
            }
        };
        SiteRows {
            rows,
            read,
            num_views: n,
            num_sites: p_s,
            channels: c,
        }
    }

    /// Reads one block of `len` points.
    ///
    /// # Shapes
    /// - Stacked: `index` `[len, 8]`, `weight` `[len, 8]`; output `[N, len, C]`
    /// - ByCorner: `index` `[8, len]`, `weight` `[8, len]`; output `[len, N * C]`
    fn read_block(&self, index: Tensor<2, Int>, weight: Tensor<2>) -> Tensor<3> {
        let (n, c, p_s) = (self.num_views, self.channels, self.num_sites);
        match self.read {
            CornerRead::Stacked => {
                let [len, _] = weight.dims();
                let index = index.reshape([len * CORNERS]);
                let values = select_rows(self.rows.clone(), per_view_rows(&index, n, p_s + 1))
                    .reshape([n, len, CORNERS, c]);
                (values * weight.reshape([1, len, CORNERS, 1]))
                    .sum_dim(2)
                    .reshape([n, len, c])
            }
            CornerRead::ByCorner => {
                let [_, len] = weight.dims();
                let term = |j: usize| {
                    let corner_index = index.clone().narrow(0, j, 1).reshape([len]);
                    let w = weight.clone().narrow(0, j, 1).reshape([len, 1]);
                    select_rows(self.rows.clone(), corner_index) * w
                };
                (1..CORNERS)
                    .fold(term(0), |sum, j| sum + term(j))
                    .reshape([1, len, n * c])
            }
        }
    }
}

/// Samples every view's sparse volume at the points:
/// `out[n, m] = sum_j weight[m, j] * features[n, index[m, j]]` (index P_s reads zero), with
/// the read the corners were uploaded for and its block size.
///
/// # Shapes
/// - features: `[N, P_s, C]`
/// - output: `[N, M, C]`
pub fn sample(
    features: Tensor<3>,
    corners: &TrilinearTensors,
) -> Result<Tensor<3>, BodyVolumeError> {
    sample_rows(&SiteRows::new(features, corners.read), corners)
}

/// [`sample`] from rows already laid out ([`SiteRows`], made once for many calls).
pub fn sample_rows(
    rows: &SiteRows,
    corners: &TrilinearTensors,
) -> Result<Tensor<3>, BodyVolumeError> {
    let block = corners.read.points_per_block(rows.num_views, rows.channels);
    sample_with(rows, corners, block)
}

/// [`sample_rows`] `points_per_block` points (at least 1) at a time; the result does not depend
/// on it beyond rounding (for tests and tuning).
///
/// # Shapes
/// - output: `[N, M, C]`
pub fn sample_with(
    rows: &SiteRows,
    corners: &TrilinearTensors,
    points_per_block: usize,
) -> Result<Tensor<3>, BodyVolumeError> {
    let (n, p_s, c) = (rows.num_views, rows.num_sites, rows.channels);
    if n == 0 || p_s != corners.num_sites {
        return Err(BodyVolumeError::shape(
            "trilinear::sample features",
            format!(
                "[N >= 1, {}, C] (the P_s the corners were computed for)",
                corners.num_sites
            ),
            &[n, p_s, c],
        ));
    }
    if rows.read != corners.read {
        return Err(BodyVolumeError::invalid(
            "trilinear::sample corners",
            format!("corners uploaded for the rows' read {:?}", rows.read),
            corners.read,
        ));
    }
    let m = corners.num_points;
    let device = rows.rows.device();
    if m == 0 {
        return Ok(Tensor::zeros([n, 0, c], &device));
    }
    if let (Some((index, weight)), true) = (&corners.host, runs_on_host(&device)) {
        // Stacked rows (the reads agree, checked above): row `v (P_s + 1) + site`.
        let taps = Taps {
            views: n,
            view_stride: p_s + 1,
            ..Taps::shared(CORNERS, index.clone(), weight.clone())
        };
        return Ok(weighted_rows(rows.rows.clone(), taps).reshape([n, m, c]));
    }
    let block = points_per_block.max(1);
    if corners.read == CornerRead::ByCorner && rows.rows.is_tracked() && !computes_on_cpu(&device) {
        // Training on a GPU backend: one operation whose backward zeroes one table-sized
        // buffer for all corners and blocks, not one per corner and block.
        let out = tap_gather(
            rows.rows.clone(),
            corners.index.clone(),
            corners.weight.clone(),
            block,
        );
        // [M, N * C] -> [N, M, C]
        return Ok(out.reshape([m, n, c]).swap_dims(0, 1));
    }
    let parts = (0..m)
        .step_by(block)
        .map(|start| {
            let len = block.min(m - start);
            let (index, weight) = match corners.read {
                CornerRead::Stacked => (
                    corners.index.clone().narrow(0, start, len),
                    corners.weight.clone().narrow(0, start, len),
                ),
                CornerRead::ByCorner => (
                    corners.index.clone().narrow(1, start, len),
                    corners.weight.clone().narrow(1, start, len),
                ),
            };
            rows.read_block(index, weight)
        })
        .collect();
    Ok(match corners.read {
        CornerRead::Stacked => cat_parts(parts, 1),
        // [1, M, N * C] -> [N, M, C]
        CornerRead::ByCorner => cat_parts(parts, 1).reshape([m, n, c]).swap_dims(0, 1),
    })
}
