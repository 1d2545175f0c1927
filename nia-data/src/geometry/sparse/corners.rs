//! Trilinear corners of query points on a sparse grid level, on the active sites (no dense
//! grid).
//!
//! Convention: the value of site `o` sits at `origin + o * voxel_size` (voxel centres, see
//! [`super::voxelize`]); a point `p` has continuous grid coordinates
//! `u = (p - origin) / voxel_size` and reads the 8 corners `floor(u) + {0, 1}^3` with the usual
//! trilinear weights. This is `grid_sample(align_corners=True, padding_mode="zeros")` on a dense
//! grid whose corner samples are the voxel centres (grid coordinate -1 = centre of voxel 0,
//! +1 = centre of voxel D - 1): corners outside the grid or not active read zero. Points outside
//! the level-0 box read zero everywhere (all 8 weights 0).
//!
//! `index` [M * 8] holds the site per corner (P_s = the zero row the sampler appends) and
//! `weight` [M * 8] its weight, corner `j = (dx * 2 + dy) * 2 + dz`.

use rayon::prelude::*;

use super::voxelize::ScaleGeometry;

/// Corners per point.
pub const CORNERS: usize = 8;

/// Points per rayon task of [`TrilinearCorners::compute`].
const POINTS_PER_TASK: usize = 1024;

/// The 8 corner sites and weights of point `p` on `scale` into `index` and `weight` ([8] each,
/// holding P_s and 0 on entry: what a point outside the box keeps).
#[inline]
fn point_corners(p: &[f32; 3], scale: &ScaleGeometry, index: &mut [u32], weight: &mut [f32]) {
    if !scale.in_bounds(*p) {
        return;
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
        if let Some(site) = scale.sites.get(c) {
            index[j] = site;
        }
        weight[j] = w;
    }
}

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
        let mut index = vec![p_s as u32; points.len() * CORNERS];
        let mut weight = vec![0.0f32; points.len() * CORNERS];
        index
            .par_chunks_mut(CORNERS * POINTS_PER_TASK)
            .zip(weight.par_chunks_mut(CORNERS * POINTS_PER_TASK))
            .zip(points.par_chunks(POINTS_PER_TASK))
            .for_each(|((index, weight), points)| {
                let rows = index
                    .chunks_exact_mut(CORNERS)
                    .zip(weight.chunks_exact_mut(CORNERS));
                for ((index, weight), p) in rows.zip(points) {
                    point_corners(p, scale, index, weight);
                }
            });
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
}
