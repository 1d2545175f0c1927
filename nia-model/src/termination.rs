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

use burn::prelude::*;
use glam::Vec3;

use crate::field::PointOutput;
use crate::model::{ModelError, NiaModel};
use crate::sampler::RaySamples;
use crate::scene_encoding::SceneEncoding;
use crate::timing::Stopwatch;

/// Depth segments of the S bins that [`NiaModel::field_front_to_back`] evaluates one after the
/// other.
pub const TERMINATION_SEGMENTS: usize = 8;

/// Default transmittance below which a ray stops (`[render] early_termination`).
pub const DEFAULT_TERMINATION: f32 = 1e-3;

impl NiaModel {
    /// The field at the kept samples of `samples`, front to back, skipping the samples of rays
    /// whose transmittance fell below `epsilon` (module docs). Returns the outputs of the
    /// evaluated points and their flat `[R * S]` sample indices, in the same order.
    pub(crate) fn field_front_to_back(
        &self,
        scene: &SceneEncoding,
        samples: &RaySamples,
        epsilon: f32,
        watch: &mut Stopwatch<'_>,
    ) -> Result<(PointOutput, Vec<usize>), ModelError> {
        let s = samples.per_ray.max(1);
        let rays = samples.t.len() / s;
        let flat: Vec<usize> = match &samples.kept {
            Some(kept) => kept.clone(),
            None => (0..samples.points.len()).collect(),
        };
        // exp(-tau) < epsilon  <=>  tau > -ln(epsilon); epsilon <= 0 never stops a ray.
        let tau_stop = if epsilon > 0.0 {
            -epsilon.ln()
        } else {
            f32::INFINITY
        };
        let segment_of = |f: usize| (f % s) * TERMINATION_SEGMENTS / s;
        let mut tau = vec![0.0f32; rays];
        let mut outputs = Vec::new();
        let mut index = Vec::new();
        for segment in 0..TERMINATION_SEGMENTS {
            let chosen: Vec<usize> = (0..flat.len())
                .filter(|&p| segment_of(flat[p]) == segment && tau[flat[p] / s] <= tau_stop)
                .collect();
            if chosen.is_empty() {
                continue;
            }
            let points: Vec<Vec3> = chosen.iter().map(|&p| samples.points[p]).collect();
            let dirs: Vec<Vec3> = chosen.iter().map(|&p| samples.dirs[p]).collect();
            let out = self.field_with(scene, &points, &dirs, watch)?;
            let sigma = out
                .sigma
                .clone()
                .into_data()
                .try_to_vec::<f32>()
                .map_err(|e| ModelError::Input(format!("reading densities: {e:?}")))?;
            for (k, &p) in chosen.iter().enumerate() {
                let f = flat[p];
                // A non-finite density stops the ray (the renderer reports what it does).
                let step = sigma[k] * samples.delta[f];
                tau[f / s] += if step.is_finite() {
                    step
                } else {
                    f32::INFINITY
                };
            }
            index.extend(chosen.iter().map(|&p| flat[p]));
            outputs.push(out);
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
            // c0 shuffling is a training augmentation; early termination runs at inference.
            blend_c0: None,
            blend_weights: cat2(|o| o.blend_weights.clone()),
            ibr_colour: cat2(|o| o.ibr_colour.clone()),
        };
        Ok((out, index))
    }
}
