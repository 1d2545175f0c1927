//! The view attention's mean over the views, fused on the host (inference on the CPU
//! backends).
//!
//! The field reads only `mean_n z_n` of the attention's output. The tensor form
//! ([`ViewCrossAttention::forward`] then [`super::heads::view_mean`]) materialises the
//! `[M, N, N, d]` products of the scores and of the weighted values and sums them, one
//! element-wise kernel after the other. Here the projections stay matrix products on the device
//! and the rest runs per point on the host, in parallel: the N x N scores, the stable softmax
//! (maximum subtracted), `z_i = sum_j a_ij v_j + s_i` and the mean over i, writing only
//! `[M, d]`. Same formula; the tensor form stays the reference (and the path with gradients
//! and on the GPU), `nia-model/tests/fields.rs` checks the two agree.

use burn::prelude::*;
use rayon::prelude::*;

use super::attention::ViewCrossAttention;
use crate::linear_rows::linear_rows;
use crate::readback::host_values_of;
use crate::shape::ShapeError;

/// Points per parallel task.
const POINTS_PER_TASK: usize = 64;

impl ViewCrossAttention {
    /// `mean_n z_n` of [`Self::forward`], computed on the host after the projections.
    ///
    /// # Shapes
    /// - `body_feature` S and `pixel_feature` L: `[N, M, d]` (views first)
    /// - output: `[M, d]`
    pub fn view_mean_on_host(
        &self,
        body_feature: Tensor<3>,
        pixel_feature: Tensor<3>,
    ) -> Result<Tensor<2>, ShapeError> {
        let [n, m, d] = body_feature.dims();
        ShapeError::check(
            "attention `body_feature` S [N, M, d]",
            &[n, m, d],
            &[None, None, Some(self.d_model)],
        )?;
        ShapeError::check(
            "attention `pixel_feature` L [N, M, d]",
            &pixel_feature.dims(),
            &[Some(n), Some(m), Some(self.d_model)],
        )?;
        if n == 0 {
            return Err(ShapeError::empty("attention views N"));
        }
        let device = body_feature.device();
        let host = |t: Tensor<3>, what: &str| host_values_of(what, t);
        let q = host(
            linear_rows(&self.phi_k, body_feature.clone()),
            "attention queries",
        )?;
        let k = host(
            linear_rows(&self.phi_k, pixel_feature.clone()),
            "attention keys",
        )?;
        let v = host(linear_rows(&self.phi_v, pixel_feature), "attention values")?;
        let s = host(body_feature, "attention `body_feature`")?;
        let scale = 1.0 / (self.d_model as f32).sqrt();
        let at = |view: usize, point: usize| (view * m + point) * d;
        let mut out = vec![0.0f32; m * d];
        out.par_chunks_mut(POINTS_PER_TASK * d)
            .enumerate()
            .for_each(|(task, block)| {
                let mut scores = vec![0.0f32; n];
                for (r, mean) in block.chunks_mut(d).enumerate() {
                    let point = task * POINTS_PER_TASK + r;
                    for i in 0..n {
                        let qi = &q[at(i, point)..at(i, point) + d];
                        for (j, score) in scores.iter_mut().enumerate() {
                            let kj = &k[at(j, point)..at(j, point) + d];
                            let dot: f32 = qi.iter().zip(kj).map(|(a, b)| a * b).sum();
                            *score = dot * scale;
                        }
                        let max = scores.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
                        let mut total = 0.0f32;
                        for score in scores.iter_mut() {
                            *score = (*score - max).exp();
                            total += *score;
                        }
                        // z_i = sum_j a_ij v_j + s_i, summed into the mean.
                        for (j, &e) in scores.iter().enumerate() {
                            let a = e / total;
                            let vj = &v[at(j, point)..at(j, point) + d];
                            for (acc, &x) in mean.iter_mut().zip(vj) {
                                *acc += a * x;
                            }
                        }
                        let si = &s[at(i, point)..at(i, point) + d];
                        for (acc, &x) in mean.iter_mut().zip(si) {
                            *acc += x;
                        }
                    }
                    let inv = 1.0 / n as f32;
                    for acc in mean.iter_mut() {
                        *acc *= inv;
                    }
                }
            });
        Ok(Tensor::from_data(TensorData::new(out, [m, d]), &device))
    }
}
