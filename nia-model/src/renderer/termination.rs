//! Early ray termination (adaptive work, inference only): samples behind what a ray has
//! already made opaque are not evaluated.
//!
//! With empty-space skipping alone, a ray through the body still evaluates the band around the
//! back of the body, which the front has hidden. [`NiaModel::field_front_to_back`] evaluates
//! the kept samples in [`TERMINATION_SEGMENTS`] depth segments of the S bins, front to back;
//! after each segment it adds `sigma_i delta_i` to each ray's optical depth tau, and a ray whose
//! transmittance `exp(-tau)` has fallen below `epsilon` evaluates nothing more. The samples it
//! skips keep zero density, so the rendered colour changes by at most `epsilon` times the
//! largest colour (1) per ray, and opacity and depth by as little. Training never terminates
//! early (its rays are jittered and need every sample's gradient), and the benchmark's forward
//! measures the network on every sample.
//!
//! Cost: one network call per non-empty segment instead of one per ray chunk, and the density
//! read back to the CPU between segments.
//!
//! The same walk culls colour evaluations ([`crate::renderer::colour_culling`]): the density half of the
//! network runs on a segment's samples, then the colour half on those whose weight matters.

use burn::prelude::*;
use glam::Vec3;

use crate::error::ModelError;
use crate::field::PointOutput;
use crate::model::NiaModel;
use crate::readback::host_values;
use crate::renderer::colour_culling::cull;
use crate::renderer::shape_buckets::{bucket_len, pad_to, pads_to_buckets};
use crate::sampler::RaySamples;
use crate::scene_encoding::SceneEncoding;
use crate::timing::Stopwatch;

/// Depth segments of the S bins that [`NiaModel::field_front_to_back`] evaluates one after the
/// other.
pub const TERMINATION_SEGMENTS: usize = 8;

impl NiaModel {
    /// The field at the kept samples of `samples`, front to back: with `termination`
    /// (transmittance epsilon) in [`TERMINATION_SEGMENTS`] depth segments, skipping the samples
    /// of rays whose transmittance fell below it (module docs); with `culling` (a per-ray weight
    /// budget, [`crate::renderer::colour_culling`]) the colour half of the network runs only on the
    /// samples whose weight matters. Returns the outputs of the evaluated points, their flat
    /// `[R * S]` sample indices in the same order, and how many got a colour evaluation
    /// (culled samples come with zero colour, c0, IBR colour and blend weights).
    pub(crate) fn field_front_to_back(
        &self,
        scene: &SceneEncoding,
        samples: &RaySamples,
        termination: Option<f32>,
        culling: Option<f32>,
        watch: &mut Stopwatch<'_>,
    ) -> Result<(PointOutput, Vec<usize>, usize), ModelError> {
        let s = samples.per_ray.max(1);
        let rays = samples.t.len() / s;
        let flat: Vec<usize> = match &samples.kept {
            Some(kept) => kept.clone(),
            None => (0..samples.points.len()).collect(),
        };
        // exp(-tau) < epsilon  <=>  tau > -ln(epsilon); epsilon <= 0 never stops a ray.
        let tau_stop = match termination {
            Some(epsilon) if epsilon > 0.0 => -epsilon.ln(),
            _ => f32::INFINITY,
        };
        let segments = if termination.is_some() {
            TERMINATION_SEGMENTS
        } else {
            1
        };
        let segment_of = |f: usize| (f % s) * segments / s;
        let device = scene.images.device();
        let pad = pads_to_buckets(&device);
        let n1 = scene.num_views() + 1;
        let mut tau = vec![0.0f32; rays];
        let mut spent = vec![0.0f32; rays];
        let mut outputs = Vec::new();
        let mut index = Vec::new();
        let mut coloured = 0;
        for segment in 0..segments {
            let chosen: Vec<usize> = (0..flat.len())
                .filter(|&p| segment_of(flat[p]) == segment && tau[flat[p] / s] <= tau_stop)
                .collect();
            if chosen.is_empty() {
                continue;
            }
            let points: Vec<Vec3> = chosen.iter().map(|&p| samples.points[p]).collect();
            let dirs: Vec<Vec3> = chosen.iter().map(|&p| samples.dirs[p]).collect();
            // With padding, the density pass has bucket_len(chosen) points, the chosen first.
            let density = if pad {
                let inputs = self.point_tensors_in_bucket(scene, &points, &dirs, watch)?;
                self.query_density(scene, &inputs, watch)?
            } else {
                self.field_density(scene, &points, &dirs, watch)?
            };
            let mut sigma = host_values(density.sigma.clone())
                .map_err(|e| ModelError::Input(format!("reading densities: {e}")))?;
            sigma.truncate(chosen.len());
            let ray_of: Vec<usize> = chosen.iter().map(|&p| flat[p] / s).collect();
            let steps: Vec<f32> = chosen
                .iter()
                .zip(&sigma)
                .map(|(&p, &sigma)| sigma * samples.delta[flat[p]])
                .collect();
            // Advances tau as well (a non-finite density stops the ray); without culling the
            // budget is -inf and every sample is evaluated.
            let budget = culling.unwrap_or(f32::NEG_INFINITY);
            let evaluate = cull(&ray_of, &steps, &mut tau, &mut spent, budget);
            let (colour_at, culled): (Vec<usize>, Vec<usize>) =
                (0..chosen.len()).partition(|&k| evaluate[k]);
            coloured += colour_at.len();
            let to_index = |ks: &[usize]| {
                let ks: Vec<i64> = ks.iter().map(|&k| k as i64).collect();
                let len = ks.len();
                Tensor::<1, Int>::from_data(TensorData::new(ks, [len]), &device)
            };
            // The evaluated points first, then the culled ones with zero colour.
            let mut parts = Vec::new();
            if !colour_at.is_empty() {
                let len = colour_at.len();
                let pass = if culled.is_empty() {
                    // Every chosen point, in order (padded: then the padding).
                    density.clone()
                } else if pad {
                    density.select(to_index(&pad_to(&colour_at, bucket_len(len))), len)
                } else {
                    density.select(to_index(&colour_at), len)
                };
                let out = self.query_colour(scene, pass, watch)?;
                parts.push(if pad { out.first(len) } else { out });
            }
            if !culled.is_empty() {
                let k = culled.len();
                parts.push(PointOutput {
                    sigma: density.sigma.clone().select(0, to_index(&culled)),
                    colour: Tensor::zeros([k, 3], &device),
                    c0: Tensor::zeros([k, 3], &device),
                    blend_c0: None,
                    blend_weights: Tensor::zeros([k, n1], &device),
                    ibr_colour: Tensor::zeros([k, 3], &device),
                });
            }
            index.extend(colour_at.iter().chain(&culled).map(|&k| flat[chosen[k]]));
            outputs.extend(parts);
        }
        let cat1 =
            |f: fn(&PointOutput) -> Tensor<1>| Tensor::cat(outputs.iter().map(f).collect(), 0);
        let cat2 =
            |f: fn(&PointOutput) -> Tensor<2>| Tensor::cat(outputs.iter().map(f).collect(), 0);
        if outputs.is_empty() {
            return Err(ModelError::Input(
                "early termination: no sample to evaluate".into(),
            ));
        }
        let out = PointOutput {
            sigma: cat1(|o| o.sigma.clone()),
            colour: cat2(|o| o.colour.clone()),
            c0: cat2(|o| o.c0.clone()),
            // c0 shuffling is a training augmentation; this runs at inference.
            blend_c0: None,
            blend_weights: cat2(|o| o.blend_weights.clone()),
            ibr_colour: cat2(|o| o.ibr_colour.clone()),
        };
        Ok((out, index, coloured))
    }
}
