//! View-wise cross-attention between body features and pixel features (NIA appendix).
//!
//! For one query point x with N source views, S = [s_1..s_N] (body features) and
//! L = [l_1..l_N] (reduced pixel-aligned features), both `[N, d]`:
//!
//! `Z = softmax(phi_k(S) phi_k(L)^T / sqrt(d)) phi_v(L) + S`
//!
//! The body feature of view n queries the pixel features of all views; the residual `+ S` keeps
//! the body feature. As in the paper's equation, the same projection phi_k maps both the
//! queries (S) and the keys (L). Weights are shared across views, so any N >= 1 works, and the
//! output is equivariant to a permutation of the views. With N = 1 the softmax over a single key
//! is 1 and `Z = phi_v(L) + S`.
//!
//! The field reads Z only through its mean over the views, `mean_i z_i` (F_sigma's and F_c0's
//! input), and [`ViewCrossAttention::view_mean`] computes that mean without Z: every row of
//! softmax weights sums to one, so with `abar_j = mean_i a_ij`
//!
//! `mean_i z_i = mean_i sum_j a_ij (l_j W_v + b_v) + mean_i s_i = phi_v(sum_j abar_j l_j) + mean_i s_i`
//!
//! the same value up to float rounding, with phi_v on M rows instead of N M and no `[N, N, M, d]`
//! product of the weights and the values. [`ViewCrossAttention::forward`] keeps the paper's
//! form (the reference the tests hold the mean to).
//!
//! Variant (a) `NoBody` does not use this module: there Z = L (the glue in `model.rs`).

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use super::attention_op::view_attention;
use crate::kernels::host_op::runs_on_host;
use crate::kernels::linear_host::linear;
use crate::kernels::linear_rows::linear_rows;
use crate::shape::ShapeError;
use crate::softmax::stable_softmax;

/// Configuration of [`ViewCrossAttention`].
#[derive(Config, Debug)]
pub struct ViewCrossAttentionConfig {
    /// Feature width d of S, L and Z (the paper's reduced feature size).
    #[config(default = 128)]
    pub d_model: usize,
}

/// `Z = softmax(phi_k(S) phi_k(L)^T / sqrt(d)) phi_v(L) + S`, per point, over the N views.
#[derive(Module, Debug)]
pub struct ViewCrossAttention {
    /// phi_k: the shared query/key projection, d -> d.
    pub phi_k: Linear,
    /// phi_v: the value projection, d -> d.
    pub phi_v: Linear,
    /// Feature width d.
    pub d_model: usize,
}

impl ViewCrossAttentionConfig {
    /// A freshly initialised attention block on `device`.
    pub fn init(&self, device: &Device) -> ViewCrossAttention {
        ViewCrossAttention {
            phi_k: LinearConfig::new(self.d_model, self.d_model).init(device),
            phi_v: LinearConfig::new(self.d_model, self.d_model).init(device),
            d_model: self.d_model,
        }
    }
}

impl ViewCrossAttention {
    /// Fuses body and pixel features across the views of each point.
    ///
    /// Views first, as the per-view reads come: the projections are then products on
    /// contiguous rows, and no gradient meets a transposed layout.
    ///
    /// # Shapes
    /// - `body_feature` S: `[N, M, d]`
    /// - `pixel_feature` L: `[N, M, d]`
    /// - output Z: `[N, M, d]`
    pub fn forward(
        &self,
        body_feature: Tensor<3>,
        pixel_feature: Tensor<3>,
    ) -> Result<Tensor<3>, ShapeError> {
        let [n, m, d] = self.check(&body_feature, &pixel_feature)?;
        let queries = linear_rows(&self.phi_k, body_feature.clone());
        let keys = linear_rows(&self.phi_k, pixel_feature.clone());
        let values = linear_rows(&self.phi_v, pixel_feature);
        if runs_on_host(&body_feature.device()) {
            // flex: the weighted sum as one host operation with its own backward.
            return Ok(view_attention(queries, keys, values) + body_feature);
        }
        let attention = self.weights(queries, keys);
        // Z_i = sum_j a_ij V_j + S_i: [N_i, N_j, M, 1] * [1, N_j, M, d] summed over j.
        let fused = (attention.unsqueeze_dim::<4>(3) * values.unsqueeze_dim::<4>(0))
            .sum_dim(1)
            .reshape([n, m, d]);
        Ok(fused + body_feature)
    }

    /// `mean_i z_i` of [`Self::forward`], as `phi_v(sum_j abar_j l_j) + mean_i s_i` (module
    /// docs): the same value up to float rounding, phi_v on M rows.
    ///
    /// # Shapes
    /// - `body_feature` S: `[N, M, d]`
    /// - `pixel_feature` L: `[N, M, d]`
    /// - output: `[M, d]`
    pub fn view_mean(
        &self,
        body_feature: Tensor<3>,
        pixel_feature: Tensor<3>,
    ) -> Result<Tensor<2>, ShapeError> {
        let [n, m, d] = self.check(&body_feature, &pixel_feature)?;
        let queries = linear_rows(&self.phi_k, body_feature.clone());
        let keys = linear_rows(&self.phi_k, pixel_feature.clone());
        // sum_j abar_j l_j, [M, d].
        let attended = if runs_on_host(&body_feature.device()) {
            // flex: the host operation's weighted sum, of the pixel features themselves.
            view_attention(queries, keys, pixel_feature).mean_dim(0)
        } else {
            // abar [1, N_j, M] -> [N_j, M, 1], times l_j and summed over j.
            let abar = self.weights(queries, keys).mean_dim(0).reshape([n, m, 1]);
            (abar * pixel_feature).sum_dim(0)
        }
        .reshape([m, d]);
        let body_mean = body_feature.mean_dim(0).reshape([m, d]);
        Ok(linear(&self.phi_v, attended, false) + body_mean)
    }

    /// The shapes of S and L checked: `[N, M, d]` each, N >= 1, d the model's width.
    fn check(
        &self,
        body_feature: &Tensor<3>,
        pixel_feature: &Tensor<3>,
    ) -> Result<[usize; 3], ShapeError> {
        let [n, m, d] = body_feature.dims();
        let d_model = Some(self.d_model);
        ShapeError::check(
            "attention `body_feature` S [N, M, d]",
            &[n, m, d],
            &[None, None, d_model],
        )?;
        ShapeError::check(
            "attention `pixel_feature` L [N, M, d]",
            &pixel_feature.dims(),
            &[Some(n), Some(m), d_model],
        )?;
        if n == 0 {
            return Err(ShapeError::empty("attention views N"));
        }
        Ok([n, m, d])
    }

    /// The attention weights `a_ij = softmax_j(phi_k(s_i) . phi_k(l_j) / sqrt(d))` of the
    /// tensor form.
    ///
    /// # Shapes
    /// - `queries` phi_k(S), `keys` phi_k(L): `[N, M, d]`
    /// - output: `[N_i, N_j, M]`
    fn weights(&self, queries: Tensor<3>, keys: Tensor<3>) -> Tensor<3> {
        let [n, m, _] = queries.dims();
        // [N_i, N_j, M]: view i's body feature against every view j's pixel feature. Written
        // as broadcast products and sums over d, not as a batched matmul: with M batches of
        // N x d x N (N = 3) the CPU backends run M tiny GEMMs forward and twice that backward,
        // which took more of the training step than all of the MLPs' GEMMs.
        let scores = (queries.unsqueeze_dim::<4>(1) * keys.unsqueeze_dim::<4>(0)) // [N, N, M, d]
            .sum_dim(3)
            .reshape([n, n, m])
            .div_scalar((self.d_model as f64).sqrt());
        stable_softmax(scores, 1)
    }
}
