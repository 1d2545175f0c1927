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
//! the GPU, and in training); `nia-model/tests/body_volume_trilinear.rs` checks the two agree.
//!
//! The field reduces the read at once, `s_n = W_b^T read + b` ([`HostVolume::reduce`]). The
//! trilinear read is linear, so for a scale at least as wide as the reduction the product can
//! be taken per site, once per scene (`W_s^T f_s`, [`HostVolume::read`] with the reduction's
//! weight), and the reads of those scales summed into one block of d channels: at the paper's
//! widths (scales of 32, 64, 128 and 128 channels to d = 128) the per-point product shrinks from
//! 352 to 96 input channels and the read writes 224 channels instead of 352.

use burn::nn::Linear;
use burn::prelude::*;
use rayon::prelude::*;

use super::network::BodyVolume;
use super::trilinear::{TrilinearCorners, CORNERS};
use super::BodyVolumeError;
use crate::kernels::host_buffer::zeroed;
use crate::kernels::host_mlp::HostLinear;
use crate::kernels::readback::host_values;

/// Points per parallel task.
const POINTS_PER_TASK: usize = 256;

/// One scale's site features in host memory.
#[derive(Debug, Clone)]
struct HostScale {
    /// `[N, P_s, C]`, row-major: the site features, or `W_s^T f` (C = d) for a reduced scale.
    features: Vec<f32>,
    num_sites: usize,
    channels: usize,
    /// Rows `offset..offset + C_s` of the reduction's weight belong to this scale.
    offset: usize,
    /// Whether `features` are already through the reduction's weight.
    reduced: bool,
}

/// A host copy of a [`BodyVolume`]'s site features, for [`HostVolume::sample`].
#[derive(Debug, Clone)]
pub struct HostVolume {
    scales: Vec<HostScale>,
    num_views: usize,
    /// d of the reduced scales' block (0 when none is reduced).
    reduced_width: usize,
}

impl HostVolume {
    /// Reads the site features of `volume` back to host memory (on a GPU backend this is a
    /// transfer; the renderers use it on the CPU backends only). With `reduction`
    /// (`W_b`, `[sum_s C_s, d]`) every scale with `C_s >= d` is stored through its rows of the
    /// weight (module docs).
    pub fn read(
        volume: &BodyVolume,
        reduction: Option<Tensor<2>>,
    ) -> Result<Self, BodyVolumeError> {
        let total: usize = volume.scales.iter().map(|s| s.features().dims()[2]).sum();
        let reduction = match reduction {
            Some(w) if w.dims()[0] != total => {
                return Err(BodyVolumeError::invalid(
                    "HostVolume::read reduction",
                    format!("[{total}, d] (one row per channel of the scales)"),
                    w.dims(),
                ))
            }
            other => other,
        };
        let d = reduction.as_ref().map_or(0, |w| w.dims()[1]);
        let mut num_views = 0;
        let mut offset = 0;
        let mut reduced_width = 0;
        let mut scales = Vec::with_capacity(volume.scales.len());
        for scale in &volume.scales {
            let [n, p_s, c_s] = scale.features().dims();
            num_views = n;
            let (features, c, reduced) = match &reduction {
                Some(w) if c_s >= d && d > 0 => {
                    reduced_width = d;
                    let rows = w.clone().narrow(0, offset, c_s);
                    let through = scale
                        .features()
                        .clone()
                        .reshape([n * p_s, c_s])
                        .matmul(rows);
                    (through, d, true)
                }
                _ => (scale.features().clone().reshape([n * p_s, c_s]), c_s, false),
            };
            let features = host_values(features).map_err(|e| {
                BodyVolumeError::invalid("HostVolume::read features", "f32 site features", e)
            })?;
            scales.push(HostScale {
                features,
                num_sites: p_s,
                channels: c,
                offset,
                reduced,
            });
            offset += c_s;
        }
        Ok(HostVolume {
            scales,
            num_views,
            reduced_width,
        })
    }

    /// Channels of the read: the scales kept as they are, concatenated, then the reduced
    /// scales' block of d (`sum_s C_s` when none is reduced).
    pub fn channels(&self) -> usize {
        self.raw_channels() + self.reduced_width
    }

    /// Channels of the scales kept as they are.
    fn raw_channels(&self) -> usize {
        self.scales
            .iter()
            .filter(|s| !s.reduced)
            .map(|s| s.channels)
            .sum()
    }

    /// `s = W^T read + b` from a read of [`Self::sample`]: the kept scales through their rows
    /// of `linear`'s weight, plus the reduced block, plus the bias, in parallel tasks of
    /// 256 rows (each starts from the bias and the reduced block and lets the
    /// product of the kept channels accumulate into it). Without reduced scales this is
    /// `linear` applied to the read.
    ///
    /// # Shapes
    /// - `read`: `[N, M, Self::channels()]` row-major
    /// - output: `[N, M, d]` row-major
    pub fn reduce(&self, read: &[f32], linear: &Linear) -> Result<Vec<f32>, BodyVolumeError> {
        let invalid = |field: &'static str, expected: String, got: String| {
            BodyVolumeError::invalid(field, expected, got)
        };
        let channels = self.channels();
        let raw = self.raw_channels();
        let [d_total, d] = linear.weight.dims();
        if !read.len().is_multiple_of(channels.max(1)) {
            return Err(invalid(
                "HostVolume::reduce read",
                format!("rows of {channels} channels"),
                format!("{} values", read.len()),
            ));
        }
        if self.reduced_width > 0 && self.reduced_width != d {
            return Err(invalid(
                "HostVolume::reduce weight",
                format!("[_, {}] (the reduced block's width)", self.reduced_width),
                format!("{:?}", [d_total, d]),
            ));
        }
        let rows = read.len() / channels.max(1);
        let weight = host_values(linear.weight.val())
            .map_err(|e| invalid("HostVolume::reduce weight", "f32 values".into(), e))?;
        let bias = match &linear.bias {
            Some(b) => host_values(b.val())
                .map_err(|e| invalid("HostVolume::reduce bias", "f32 values".into(), e))?,
            None => vec![0.0; d],
        };
        // The kept scales' rows of the weight, in the read's channel order.
        let mut kept = Vec::with_capacity(raw * d);
        for scale in self.scales.iter().filter(|s| !s.reduced) {
            let (from, to) = (scale.offset * d, (scale.offset + scale.channels) * d);
            let rows_of_scale = weight.get(from..to).ok_or_else(|| {
                invalid(
                    "HostVolume::reduce weight",
                    format!("at least {} rows", scale.offset + scale.channels),
                    format!("{d_total}"),
                )
            })?;
            kept.extend_from_slice(rows_of_scale);
        }
        let kept =
            HostLinear::new("HostVolume::reduce weight", kept, bias, raw, d).map_err(|e| {
                invalid(
                    "HostVolume::reduce weight",
                    "a kept-channel product".into(),
                    e.to_string(),
                )
            })?;
        let reduced_width = self.reduced_width;
        let mut out = zeroed(rows * d);
        out.par_chunks_mut(POINTS_PER_TASK * d)
            .enumerate()
            .for_each(|(task, block)| {
                let r0 = task * POINTS_PER_TASK;
                let n = block.len() / d;
                for (r, row) in block.chunks_mut(d).enumerate() {
                    row.copy_from_slice(kept.bias());
                    if reduced_width > 0 {
                        let from = (r0 + r) * channels + raw;
                        for (v, x) in row.iter_mut().zip(&read[from..from + d]) {
                            *v += x;
                        }
                    }
                }
                if raw > 0 {
                    kept.accumulate(
                        &read[r0 * channels..(r0 + n) * channels],
                        channels,
                        n,
                        block,
                    );
                }
            });
        Ok(out)
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
        let raw = self.raw_channels();
        let mut out = zeroed(n * m * total);
        // Rows of `total` channels: (view, point) pairs, in tasks of consecutive points.
        out.par_chunks_mut(POINTS_PER_TASK * total)
            .enumerate()
            .for_each(|(task, block)| {
                let rows = block.len() / total;
                for r in 0..rows {
                    let flat = task * POINTS_PER_TASK + r; // view * M + point
                    let (view, point) = (flat / m, flat % m);
                    let row = &mut block[r * total..(r + 1) * total];
                    // Kept scales side by side, reduced ones summed into the last block.
                    let mut offset = 0;
                    for (scale, corner) in self.scales.iter().zip(corners) {
                        let c = scale.channels;
                        let start = if scale.reduced { raw } else { offset };
                        let acc = &mut row[start..start + c];
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
                        if !scale.reduced {
                            offset += c;
                        }
                    }
                }
            });
        Ok(out)
    }
}
