//! The body volume's trilinear read on the CPU, fused (inference on the CPU backends).
//!
//! [`super::trilinear::sample`] is tensor operations that run on every backend and carry
//! gradients: a row gather of the 8 corners, `[N, M, 8, C]`, times the weights, summed over
//! the corners. On a CPU backend at inference that materialises and re-reads 8 rows per point
//! and view (a 512x512 image at the paper's widths: ~50 GB written, three passes over it, about
//! a fifth of the render). [`HostVolume`] keeps a copy of the site features in host memory (read
//! back once per scene and pose) and [`HostVolume::sample`] computes
//! `out[n, m] = sum_j weight[m, j] * features[n, index[m, j]]` in one pass from the corners
//! the CPU already computed, writing only `[N, M, C]`: same arithmetic, the corners summed in
//! the same order. The tensor path stays the reference (and the only path with gradients, on
//! the GPU, and in training); `nia-model/tests/body_volume.rs` checks the two agree.

use rayon::prelude::*;

use super::network::BodyVolume;
use super::trilinear::{TrilinearCorners, CORNERS};
use super::BodyVolumeError;

/// Points per parallel task.
const POINTS_PER_TASK: usize = 256;

/// One scale's site features in host memory.
#[derive(Debug, Clone)]
struct HostScale {
    /// `[N, P_s, C]`, row-major.
    features: Vec<f32>,
    num_sites: usize,
    channels: usize,
}

/// A host copy of a [`BodyVolume`]'s site features, for [`HostVolume::sample`].
#[derive(Debug, Clone)]
pub struct HostVolume {
    scales: Vec<HostScale>,
    num_views: usize,
}

impl HostVolume {
    /// Reads the site features of `volume` back to host memory (on a GPU backend this is a
    /// transfer; the renderers use it on the CPU backends only).
    pub fn read(volume: &BodyVolume) -> Result<Self, BodyVolumeError> {
        let mut num_views = 0;
        let mut scales = Vec::with_capacity(volume.scales.len());
        for scale in &volume.scales {
            let [n, p_s, c] = scale.features.dims();
            num_views = n;
            let features = scale
                .features
                .clone()
                .into_data()
                .convert::<f32>()
                .try_into_vec::<f32>()
                .map_err(|e| {
                    BodyVolumeError::invalid("HostVolume::read features", "f32 site features", e)
                })?;
            scales.push(HostScale {
                features,
                num_sites: p_s,
                channels: c,
            });
        }
        Ok(HostVolume { scales, num_views })
    }

    /// Channels of the read, `sum_s C_s`.
    pub fn channels(&self) -> usize {
        self.scales.iter().map(|s| s.channels).sum()
    }

    /// Number of views N.
    pub fn num_views(&self) -> usize {
        self.num_views
    }

    /// Samples every scale at M points and concatenates the channels, as
    /// [`BodyVolume::sample`] does. `corners[s]` for scale s (same points on every scale).
    ///
    /// # Shapes
    /// - output: `[N, M, sum_s C_s]`, row-major
    pub fn sample(&self, corners: &[TrilinearCorners]) -> Result<Vec<f32>, BodyVolumeError> {
        let m = corners.first().map_or(0, |c| c.num_points());
        if corners.len() != self.scales.len()
            || corners.iter().zip(&self.scales).any(|(c, s)| {
                c.num_points() != m
                    || c.num_sites != s.num_sites
                    || c.index.len() != m * CORNERS
                    || c.weight.len() != m * CORNERS
            })
        {
            return Err(BodyVolumeError::invalid(
                "HostVolume::sample corners",
                format!(
                    "{} corner sets (one per scale, for its sites) for the same points",
                    self.scales.len()
                ),
                corners
                    .iter()
                    .map(|c| (c.num_points(), c.num_sites))
                    .collect::<Vec<_>>(),
            ));
        }
        let n = self.num_views;
        let total = self.channels();
        let mut out = vec![0.0f32; n * m * total];
        // Rows of `total` channels: (view, point) pairs, in tasks of consecutive points.
        out.par_chunks_mut(POINTS_PER_TASK * total)
            .enumerate()
            .for_each(|(task, block)| {
                let rows = block.len() / total;
                for r in 0..rows {
                    let flat = task * POINTS_PER_TASK + r; // view * M + point
                    let (view, point) = (flat / m, flat % m);
                    let row = &mut block[r * total..(r + 1) * total];
                    let mut offset = 0;
                    for (scale, corner) in self.scales.iter().zip(corners) {
                        let c = scale.channels;
                        let acc = &mut row[offset..offset + c];
                        let view_base = view * scale.num_sites * c;
                        for j in 0..CORNERS {
                            let site = corner.index[point * CORNERS + j] as usize;
                            let w = corner.weight[point * CORNERS + j];
                            // The zero row (inactive or outside) and zero weights add nothing.
                            if site >= scale.num_sites || w == 0.0 {
                                continue;
                            }
                            let src =
                                &scale.features[view_base + site * c..view_base + (site + 1) * c];
                            for (a, &f) in acc.iter_mut().zip(src) {
                                *a += w * f;
                            }
                        }
                        offset += c;
                    }
                }
            });
        Ok(out)
    }
}
