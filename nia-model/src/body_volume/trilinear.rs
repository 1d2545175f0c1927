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
//! `[N, P_s, C] -> [N, M, C]`, differentiable in the features: one row gather from
//! `[N (P_s + 1), C]` and a batched weighted sum.

use burn::prelude::*;

use super::sparse_conv::{cat_parts, chunk_len, int_tensor, per_view_rows, rows_with_zero_row};
use super::BodyVolumeError;
use crate::blocked_rows::select_rows;
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

/// Samples every view's sparse volume at the points:
/// `out[n, m] = sum_j weight[m, j] * features[n, index[m, j]]` (index P_s reads zero).
///
/// # Shapes
/// - features: `[N, P_s, C]`
/// - output: `[N, M, C]`
pub fn sample(
    features: Tensor<3>,
    corners: &TrilinearTensors,
) -> Result<Tensor<3>, BodyVolumeError> {
    let [n, _, c] = features.dims();
    sample_in_chunks(features, corners, chunk_len(n * CORNERS * c))
}

/// [`sample`] gathering `points_per_chunk` points (at least 1) at a time; the result does not
/// depend on it (for tests and tuning).
pub fn sample_in_chunks(
    features: Tensor<3>,
    corners: &TrilinearTensors,
    points_per_chunk: usize,
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
    // Row gathers of the corners in blocks of points (`GATHER_CHUNK_BYTES`), then the 8-term
    // weighted sum of every (view, point) as one broadcast product summed over the corners
    // (`[N, M, 8, C] * [1, M, 8, 1]`). Not a batched [1, 8] x [8, C] matmul: that is N M tiny
    // GEMMs forward and again backward, which cost more than the gathers in the training step.
    let rows = rows_with_zero_row(features); // [N * (P_s + 1), C]
    let chunk = points_per_chunk.max(1);
    let mut parts = Vec::with_capacity(m.div_ceil(chunk));
    for start in (0..m).step_by(chunk) {
        let len = chunk.min(m - start);
        let index = corners
            .index
            .clone()
            .narrow(0, start * CORNERS, len * CORNERS);
        let values = select_rows(rows.clone(), per_view_rows(&index, n, p_s + 1)).reshape([
            n * len,
            CORNERS,
            c,
        ]);
        let weight = corners
            .weight
            .clone()
            .narrow(0, start, len)
            .reshape([1, len, CORNERS, 1]);
        let values = values.reshape([n, len, CORNERS, c]);
        parts.push((values * weight).sum_dim(2).reshape([n, len, c]));
    }
    Ok(cat_parts(parts, 1))
}
