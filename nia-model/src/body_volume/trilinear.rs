//! Trilinear sampling of a sparse volume at query points, on the active sites (no dense grid).
//!
//! Convention: the value of site `o` sits at `origin + o * voxel_size` (voxel centres, see
//! [`super::voxelize`]); a point `p` has continuous grid coordinates
//! `u = (p - origin) / voxel_size` and reads the 8 corners `floor(u) + {0, 1}^3` with the usual
//! trilinear weights. This is `grid_sample(align_corners=True, padding_mode="zeros")` on a dense
//! grid whose corner samples are the voxel centres (grid coordinate -1 = centre of voxel 0,
//! +1 = centre of voxel D - 1): corners outside the grid or not active read zero. Points outside
//! the level-0 box read zero everywhere (all 8 weights 0).
//!
//! CPU side ([`TrilinearCorners::compute`]): `index` [M * 8] site per corner (P_s = the zero
//! row appended at sampling time) and `weight` [M * 8], corner `j = (dx * 2 + dy) * 2 + dz`.
//! Tensor side ([`sample`]): `[N, P_s, C] -> [N, M, C]`, differentiable in the features: one
//! row gather from `[N (P_s + 1), C]` and a batched weighted sum.

use burn::prelude::*;

use super::sparse_conv::{cat_parts, chunk_len, int_tensor, per_view_rows, rows_with_zero_row};
use super::voxelize::ScaleGeometry;
use super::BodyVolumeError;

/// Corners per point.
pub const CORNERS: usize = 8;

/// The 8 corner sites and weights of M points on one scale.
#[derive(Debug, Clone, PartialEq)]
pub struct TrilinearCorners {
    /// [M * 8] site of every corner; `num_sites` (P_s) where the corner is inactive or outside.
    pub index: Vec<u32>,
    /// [M * 8] trilinear weights; a point's 8 weights sum to 1 inside the box, 0 outside.
    pub weight: Vec<f32>,
    /// P_s, the index of the zero row.
    pub num_sites: usize,
}

impl TrilinearCorners {
    /// Corners of `points` ([M, 3] metres, SMPL frame) on `scale`. Non-finite points count as
    /// outside.
    pub fn compute(points: &[[f32; 3]], scale: &ScaleGeometry) -> Self {
        let p_s = scale.num_sites();
        let mut index = Vec::with_capacity(points.len() * CORNERS);
        let mut weight = Vec::with_capacity(points.len() * CORNERS);
        for p in points {
            if !scale.in_bounds(*p) {
                index.extend([p_s as u32; CORNERS]);
                weight.extend([0.0f32; CORNERS]);
                continue;
            }
            let mut base = [0i32; 3];
            let mut frac = [0.0f32; 3];
            for a in 0..3 {
                let u = (p[a] - scale.origin_m[a]) / scale.voxel_size_m;
                let f = u.floor();
                base[a] = f as i32;
                frac[a] = u - f;
            }
            for j in 0..CORNERS {
                let d = [(j >> 2) & 1, (j >> 1) & 1, j & 1];
                let mut w = 1.0f32;
                let mut c = [0i32; 3];
                for a in 0..3 {
                    c[a] = base[a] + d[a] as i32;
                    w *= if d[a] == 1 { frac[a] } else { 1.0 - frac[a] };
                }
                index.push(scale.sites.get(c).unwrap_or(p_s as u32));
                weight.push(w);
            }
        }
        TrilinearCorners {
            index,
            weight,
            num_sites: p_s,
        }
    }

    /// Number of points M.
    pub fn num_points(&self) -> usize {
        self.index.len() / CORNERS
    }

    /// Uploads the corners to `device`.
    pub fn to_tensors(&self, device: &Device) -> TrilinearTensors {
        let m = self.num_points();
        TrilinearTensors {
            index: int_tensor(&self.index, device),
            weight: Tensor::from_data(TensorData::new(self.weight.clone(), [m, CORNERS]), device),
            num_points: m,
            num_sites: self.num_sites,
        }
    }
}

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
    let rows = rows_with_zero_row(features); // [N * (P_s + 1), C]
                                             // Row gathers of the corners in blocks of points (`GATHER_CHUNK_BYTES`), then the 8-term
                                             // weighted sum of every (view, point) as a batched [1, 8] x [8, C] matmul (on flex ~4x
                                             // faster than 8 separate multiply-adds over [N M, C]).
    let chunk = points_per_chunk.max(1);
    let mut parts = Vec::with_capacity(m.div_ceil(chunk));
    for start in (0..m).step_by(chunk) {
        let len = chunk.min(m - start);
        let index = corners
            .index
            .clone()
            .narrow(0, start * CORNERS, len * CORNERS);
        let values = rows
            .clone()
            .select(0, per_view_rows(&index, n, p_s + 1))
            .reshape([n * len, CORNERS, c]);
        let weight = corners
            .weight
            .clone()
            .narrow(0, start, len)
            .reshape([1, len, CORNERS])
            .expand([n, len, CORNERS])
            .reshape([n * len, 1, CORNERS]);
        parts.push(weight.matmul(values).reshape([n, len, c]));
    }
    Ok(cat_parts(parts, 1))
}
