//! The view attention's mean over the views, fused on the host (inference on the CPU
//! backends).
//!
//! The field reads only `mean_n z_n` of the attention's output. The tensor form
//! ([`ViewCrossAttention::view_mean`]) materialises the `[N, N, M, d]` products of the scores
//! and sums them, one element-wise kernel after the other. Here
//! everything runs on the host in tasks of [`POINTS_PER_TASK`] points: the task's projections
//! phi_k(S), phi_k(L) (one matrix product per view, [`HostLinear::apply`]), then per point the
//! N x N scores, the stable softmax (maximum subtracted), `abar_j = mean_i a_ij`,
//! `sum_j abar_j l_j` and `mean_i s_i`, and last phi_v of the task's weighted sums (one product
//! on its points' rows, not one per view: [`ViewCrossAttention::view_mean`]'s form), writing
//! only `[M, d]`. The tensor form stays the reference (and the path with gradients and on the
//! GPU), `nia-model/tests/fields.rs` checks the two agree.

use burn::prelude::*;
use rayon::prelude::*;

use super::attention::ViewCrossAttention;
use super::attention_op::dot;
use crate::kernels::host_buffer::zeroed;
use crate::kernels::host_mlp::HostLinear;
use crate::kernels::readback::host_view_of;
use crate::shape::ShapeError;

/// Points per parallel task (its two projections of N x 128 rows stay in cache).
const POINTS_PER_TASK: usize = 128;

impl ViewCrossAttention {
    /// `mean_n z_n` of [`Self::forward`], computed on the host (projections included).
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
        let s = host_view_of("attention `body_feature`", body_feature)?;
        let l = host_view_of("attention `pixel_feature`", pixel_feature)?;
        let out = self.view_mean_of_values(&s, &l, n, m)?;
        Ok(Tensor::from_data(TensorData::new(out, [m, d]), &device))
    }

    /// [`Self::view_mean_on_host`] on host values.
    ///
    /// # Shapes
    /// - `s` (S) and `l` (L): `[N, M, d]` row-major (views first)
    /// - output: `[M, d]` row-major
    pub fn view_mean_of_values(
        &self,
        s: &[f32],
        l: &[f32],
        n: usize,
        m: usize,
    ) -> Result<Vec<f32>, ShapeError> {
        let d = self.d_model;
        for (what, values) in [("attention S values", s), ("attention L values", l)] {
            if values.len() != n * m * d {
                return Err(ShapeError::value(
                    what,
                    format!("{n} x {m} x {d} values, got {}", values.len()),
                ));
            }
        }
        if n == 0 {
            return Err(ShapeError::empty("attention views N"));
        }
        let phi_k = HostLinear::read("attention phi_k", &self.phi_k)?;
        let phi_v = HostLinear::read("attention phi_v", &self.phi_v)?;
        let scale = 1.0 / (self.d_model as f32).sqrt();
        let mut out = zeroed(m * d);
        out.par_chunks_mut(POINTS_PER_TASK * d)
            .enumerate()
            .for_each(|(task, block)| {
                let p0 = task * POINTS_PER_TASK;
                let points = block.len() / d;
                // The task's projections phi_k(S), phi_k(L), [N, points, d] each: one product
                // per view and map (a view's rows of the task are contiguous in [N, M, d]).
                let mut q = vec![0.0f32; n * points * d];
                let mut k = vec![0.0f32; n * points * d];
                for view in 0..n {
                    let rows = (view * m + p0) * d..(view * m + p0 + points) * d;
                    let at = view * points * d..(view + 1) * points * d;
                    phi_k.apply(&s[rows.clone()], points, &mut q[at.clone()]);
                    phi_k.apply(&l[rows], points, &mut k[at]);
                }
                let at = |view: usize, r: usize| (view * points + r) * d;
                // Row (view, point r of the task) of S or L.
                let row =
                    |view: usize, r: usize| (view * m + p0 + r) * d..(view * m + p0 + r + 1) * d;
                // Per point sum_j abar_j l_j and mean_i s_i, [points, d] each.
                let mut attended = vec![0.0f32; points * d];
                let mut body_mean = vec![0.0f32; points * d];
                let mut scores = vec![0.0f32; n];
                let mut abar = vec![0.0f32; n];
                let inv = 1.0 / n as f32;
                for (r, (lbar, smean)) in attended
                    .chunks_mut(d)
                    .zip(body_mean.chunks_mut(d))
                    .enumerate()
                {
                    abar.fill(0.0);
                    for i in 0..n {
                        let qi = &q[at(i, r)..at(i, r) + d];
                        for (j, score) in scores.iter_mut().enumerate() {
                            let kj = &k[at(j, r)..at(j, r) + d];
                            *score = dot(qi, kj) * scale;
                        }
                        let max = scores.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
                        let mut total = 0.0f32;
                        for score in scores.iter_mut() {
                            *score = (*score - max).exp();
                            total += *score;
                        }
                        for (a, &e) in abar.iter_mut().zip(&scores) {
                            *a += e / total;
                        }
                        for (acc, &x) in smean.iter_mut().zip(&s[row(i, r)]) {
                            *acc += x;
                        }
                    }
                    for (j, &a) in abar.iter().enumerate() {
                        let w = a * inv;
                        for (acc, &x) in lbar.iter_mut().zip(&l[row(j, r)]) {
                            *acc += w * x;
                        }
                    }
                    for acc in smean.iter_mut() {
                        *acc *= inv;
                    }
                }
                // phi_v once per point, then the residual's mean.
                phi_v.apply(&attended, points, block);
                for (o, &x) in block.iter_mut().zip(&body_mean) {
                    *o += x;
                }
            });
        Ok(out)
    }
}
