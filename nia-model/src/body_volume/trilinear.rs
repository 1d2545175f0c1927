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
//! ([`nia_data::geometry::sparse::TrilinearCorners`]); here they are uploaded and used:
//! `[N, P_s, C] -> [N, M, C]`, differentiable in the features: row gathers from
//! `[N (P_s + 1), C]` and a weighted sum over the corners, read as the backend suits
//! ([`CornerRead`]).

use burn::prelude::*;

use super::sparse_conv::{
    cat_parts, int_tensor, per_view_rows, rows_per_block, rows_with_zero_row, GATHER_CHUNK_BYTES,
};
use super::BodyVolumeError;
use crate::blocked_rows::select_rows;
use crate::device::computes_on_cpu;
pub use nia_data::geometry::sparse::{TrilinearCorners, CORNERS};

/// [`TrilinearCorners`] on a device.
#[derive(Debug, Clone)]
pub struct TrilinearTensors {
    /// [M * 8] Int, site of corner j of point m at `m * 8 + j` (P_s = zero row).
    pub index: Tensor<1, Int>,
    /// [M, 8] weights.
    pub weight: Tensor<2>,
    /// M.
    pub num_points: usize,
    /// P_s.
    pub num_sites: usize,
}

impl TrilinearTensors {
    /// Uploads `corners` to `device`.
    pub fn upload(corners: &TrilinearCorners, device: &Device) -> Self {
        let m = corners.num_points();
        TrilinearTensors {
            index: int_tensor(&corners.index, device),
            weight: Tensor::from_data(
                TensorData::new(corners.weight.clone(), [m, CORNERS]),
                device,
            ),
            num_points: m,
            num_sites: corners.num_sites,
        }
    }
}

/// How [`sample_with`] reads the 8 corners of a block of points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CornerRead {
    /// One row gather of all 8 corners (`[N, len, 8, C]`), then the weighted sum over the
    /// corners as one broadcast product summed along them. The CPU backends' read: few
    /// operations per block, and blocks small enough for the allocator to reuse.
    Stacked,
    /// One row gather per corner (`[N, len, C]`), weighted and added to the sum. The GPU
    /// backends' read: no `[N, len, 8, C]` intermediate, and blocks of 64 MiB, so a block
    /// holds 32 times the points of a stacked one and a read has far fewer blocks of a few
    /// kernel launches each (at 4096 rays x 64 samples and the paper's scales, 20 blocks
    /// instead of 532).
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
    /// [`GATHER_CHUNK_BYTES`] (stacked) or [`BY_CORNER_BLOCK_BYTES`] (by corner).
    pub fn points_per_block(self, n: usize, c: usize) -> usize {
        match self {
            CornerRead::Stacked => rows_per_block(GATHER_CHUNK_BYTES, n * CORNERS * c),
            CornerRead::ByCorner => rows_per_block(BY_CORNER_BLOCK_BYTES, n * c),
        }
    }

    /// Reads one block of `len` points. Stacked: one gather of all corners, then the weighted
    /// sum as a broadcast product summed over the corners (not a batched [1, 8] x [8, C]
    /// matmul: that is N M tiny GEMMs forward and again backward, which cost more than the
    /// gathers in the training step). By corner: the row indices of all corners and views in
    /// one tensor, then per corner one gather, weighted and summed.
    ///
    /// # Shapes
    /// - `rows`: `[N * (P_s + 1), C]`; `index`: `[len * 8]`; `weight`: `[len, 8]`
    /// - output: `[N, len, C]`
    fn read_block(
        self,
        rows: &Tensor<2>,
        index: Tensor<1, Int>,
        weight: Tensor<2>,
        n: usize,
        p_s: usize,
    ) -> Tensor<3> {
        let [len, _] = weight.dims();
        let c = rows.dims()[1];
        match self {
            CornerRead::Stacked => {
                let values = select_rows(rows.clone(), per_view_rows(&index, n, p_s + 1))
                    .reshape([n, len, CORNERS, c]);
                (values * weight.reshape([1, len, CORNERS, 1]))
                    .sum_dim(2)
                    .reshape([n, len, c])
            }
            CornerRead::ByCorner => {
                // [8, N * len]: row j holds corner j of every (view, point), view-major.
                let by_corner = index
                    .reshape([len, CORNERS])
                    .swap_dims(0, 1)
                    .reshape([CORNERS * len]);
                let index = per_view_rows(&by_corner, n, p_s + 1)
                    .reshape([n, CORNERS, len])
                    .swap_dims(0, 1)
                    .reshape([CORNERS, n * len]);
                let term = |j: usize| {
                    let corner_index = index.clone().narrow(0, j, 1).reshape([n * len]);
                    let w = weight.clone().narrow(1, j, 1).reshape([1, len, 1]);
                    select_rows(rows.clone(), corner_index).reshape([n, len, c]) * w
                };
                (1..CORNERS).fold(term(0), |sum, j| sum + term(j))
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

/// Samples every view's sparse volume at the points:
/// `out[n, m] = sum_j weight[m, j] * features[n, index[m, j]]` (index P_s reads zero), with
/// the read and block size of the features' backend ([`CornerRead::for_device`]).
///
/// # Shapes
/// - features: `[N, P_s, C]`
/// - output: `[N, M, C]`
pub fn sample(
    features: Tensor<3>,
    corners: &TrilinearTensors,
) -> Result<Tensor<3>, BodyVolumeError> {
    let [n, _, c] = features.dims();
    let read = CornerRead::for_device(&features.device());
    sample_with(features, corners, read, read.points_per_block(n, c))
}

/// [`sample`] reading the corners as `read` says, `points_per_block` points (at least 1) at a
/// time; the result does not depend on either beyond rounding (for tests and tuning).
pub fn sample_with(
    features: Tensor<3>,
    corners: &TrilinearTensors,
    read: CornerRead,
    points_per_block: usize,
) -> Result<Tensor<3>, BodyVolumeError> {
    let [n, p_s, c] = features.dims();
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
    let m = corners.num_points;
    if m == 0 {
        return Ok(Tensor::zeros([n, 0, c], &features.device()));
    }
    let rows = rows_with_zero_row(features); // [N * (P_s + 1), C]
    let block = points_per_block.max(1);
    let parts = (0..m)
        .step_by(block)
        .map(|start| {
            let len = block.min(m - start);
            let index = corners
                .index
                .clone()
                .narrow(0, start * CORNERS, len * CORNERS); // [len * 8]
            let weight = corners.weight.clone().narrow(0, start, len); // [len, 8]
            read.read_block(&rows, index, weight, n, p_s)
        })
        .collect();
    Ok(cat_parts(parts, 1))
}
