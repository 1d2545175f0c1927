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
//! Cost: one network call per non-empty segment instead of one per ray chunk (several for a
//! segment of more than `SceneEncoding::points_per_call` points), and the density read back to
//! the CPU after each call.
//!
//! The same walk culls colour evaluations ([`crate::renderer::colour_culling`]): the density half of the
//! network runs on a segment's samples, then the colour half on those whose weight matters.

use burn::prelude::*;
use glam::Vec3;

use nia_data::scene::InputsFor;

use crate::error::ModelError;
use crate::field::PointOutput;
use crate::kernels::readback::host_values;
use crate::model::NiaModel;
use crate::renderer::colour_culling::cull;
use crate::renderer::shape_buckets::{bucket_len, pad_to, CallRows};
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
        let mut walk = Walk {
            samples,
            flat: match &samples.kept {
                Some(kept) => kept.clone(),
                None => (0..samples.points.len()).collect(),
            },
            tau: vec![0.0; rays],
            spent: vec![0.0; rays],
            // Without culling the budget is -inf and every sample is evaluated.
            budget: culling.unwrap_or(f32::NEG_INFINITY),
            outputs: Vec::new(),
            index: Vec::new(),
            coloured: 0,
        };
        for segment in 0..segments {
            let flat = &walk.flat;
            let in_segment: Vec<usize> = (0..flat.len())
                .filter(|&p| segment_of(flat[p]) == segment && walk.tau[flat[p] / s] <= tau_stop)
                .collect();
            // A segment of more points than a call takes goes in several calls, front to back
            // (each ray's samples stay in order, so the walk decides as in one call).
            for chosen in in_segment.chunks(scene.points_per_call.max(1)) {
                self.walk_call(scene, &mut walk, chosen, watch)?;
            }
        }
        // c0 shuffling is a training augmentation; this runs at inference, so no part has it.
        let out = PointOutput::cat(walk.outputs)
            .ok_or_else(|| ModelError::Input("early termination: no sample to evaluate".into()))?;
        Ok((out, walk.index, walk.coloured))
    }

    /// One network call of [`Self::field_front_to_back`]: the density half at the `chosen`
    /// kept points (positions in `walk.flat`, front to back per ray), their densities read
    /// back and walked ([`cull`], which advances each ray's optical depth), then the colour
    /// half at the points whose weight matters. Appends the outputs (the coloured points, then
    /// the culled ones with zero colour) and their flat sample indices to `walk`.
    fn walk_call(
        &self,
        scene: &SceneEncoding,
        walk: &mut Walk<'_>,
        chosen: &[usize],
        watch: &mut Stopwatch<'_>,
    ) -> Result<(), ModelError> {
        let samples = walk.samples;
        let s = samples.per_ray.max(1);
        let device = scene.images.device();
        let rows = CallRows::on(&device);
        let pad = rows == CallRows::Bucket;
        let points: Vec<Vec3> = chosen.iter().map(|&p| samples.points[p]).collect();
        let dirs: Vec<Vec3> = chosen.iter().map(|&p| samples.dirs[p]).collect();
        // With padding, the density pass has bucket_len(chosen) points, the chosen first. A
        // walk that colours nothing (the colour-once mode's density walk) computes only the
        // density half's inputs.
        let what = if walk.budget == f32::INFINITY {
            InputsFor::Density
        } else {
            InputsFor::Network
        };
        let inputs = self.point_tensors_for(scene, &points, &dirs, rows, what, watch)?;
        let density = self.query_density(scene, &inputs, watch)?;
        let mut sigma = host_values(density.sigma.clone())
            .map_err(|e| ModelError::Input(format!("reading densities: {e}")))?;
        sigma.truncate(chosen.len());
        let flat = &walk.flat;
        let ray_of: Vec<usize> = chosen.iter().map(|&p| flat[p] / s).collect();
        let steps: Vec<f32> = chosen
            .iter()
            .zip(&sigma)
            .map(|(&p, &sigma)| sigma * samples.delta[flat[p]])
            .collect();
        // Advances tau as well (a non-finite density stops the ray).
        let evaluate = cull(&ray_of, &steps, &mut walk.tau, &mut walk.spent, walk.budget);
        let (colour_at, culled): (Vec<usize>, Vec<usize>) =
            (0..chosen.len()).partition(|&k| evaluate[k]);
        walk.coloured += colour_at.len();
        let to_index = |ks: &[usize]| {
            let ks: Vec<i64> = ks.iter().map(|&k| k as i64).collect();
            let len = ks.len();
            Tensor::<1, Int>::from_data(TensorData::new(ks, [len]), &device)
        };
        // The evaluated points first, then the culled ones with zero colour.
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
            walk.outputs.push(if pad { out.first(len) } else { out });
        }
        if !culled.is_empty() {
            let k = culled.len();
            let n1 = scene.num_views() + 1;
            walk.outputs.push(PointOutput {
                sigma: density.sigma.clone().select(0, to_index(&culled)),
                colour: Tensor::zeros([k, 3], &device),
                c0: Tensor::zeros([k, 3], &device),
                blend_c0: None,
                blend_weights: Tensor::zeros([k, n1], &device),
                ibr_colour: Tensor::zeros([k, 3], &device),
            });
        }
        let flat = &walk.flat;
        walk.index
            .extend(colour_at.iter().chain(&culled).map(|&k| flat[chosen[k]]));
        Ok(())
    }
}

/// The state of [`NiaModel::field_front_to_back`]'s walk over one chunk's rays.
struct Walk<'a> {
    samples: &'a RaySamples,
    /// [M] the flat `[R * S]` sample index of each kept point.
    flat: Vec<usize>,
    /// [R] each ray's optical depth in front of the samples not yet walked.
    tau: Vec<f32>,
    /// [R] the weight each ray has culled so far.
    spent: Vec<f32>,
    /// Colour culling's weight budget per ray (`-inf`: every sample is coloured).
    budget: f32,
    /// The outputs of the evaluated points, call after call.
    outputs: Vec<PointOutput>,
    /// Their flat sample indices, in the same order.
    index: Vec<usize>,
    /// Of those, the points the colour half evaluated.
    coloured: usize,
}
