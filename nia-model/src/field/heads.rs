//! The implicit body NeRF heads (NIA section 3 / appendix): density F_sigma and colour F_c0.
//!
//! - `sigma = F_sigma(mean_n z_n)`
//! - `(c0, psi, h) = F_c0(mean_n [z_n ; gamma(d)]) = F_c0([mean_n z_n ; gamma(d)])`
//!   (gamma(d) is the same for every view, so the mean of the concatenation is the
//!   concatenation of the means).
//!
//! Both are four linear layers with ReLU between them. The paper gives the layer count, not the
//! widths: the hidden width defaults to 256 (`d_hidden`).
//!
//! Density activation: `sigma = softplus(raw + density_shift)` with `density_shift = -1`
//! (units: per metre, since ray parameters t are metres). NeRF uses ReLU, which has a zero
//! gradient for every point it switches off; softplus keeps a gradient everywhere and is never
//! negative, and the shift makes a freshly initialised field nearly transparent
//! (softplus(-1) ~ 0.31 per metre) instead of a grey fog.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::{sigmoid, softplus};

use crate::kernels::linear_host::linear;
use crate::shape::ShapeError;

/// Number of linear layers of F_sigma and F_c0 (paper).
pub const HEAD_LAYERS: usize = 4;

/// Mean over the views of per-view features: `mean_n z_n`.
///
/// # Shapes
/// - `z`: `[N, M, d]` (views first)
/// - output: `[M, d]`
pub fn view_mean(z: Tensor<3>) -> Tensor<2> {
    z.mean_dim(0).squeeze_dim(0)
}

/// Four linear layers `d_input -> d_hidden -> d_hidden -> d_hidden -> d_output`.
fn four_layers(d_input: usize, d_hidden: usize, d_output: usize, device: &Device) -> Vec<Linear> {
    let widths = [d_input, d_hidden, d_hidden, d_hidden, d_output];
    widths
        .windows(2)
        .map(|w| LinearConfig::new(w[0], w[1]).init(device))
        .collect()
}

/// Configuration of [`DensityHead`] (F_sigma).
#[derive(Config, Debug)]
pub struct DensityHeadConfig {
    /// Width d of the fused feature z.
    #[config(default = 128)]
    pub d_input: usize,
    /// Hidden width.
    #[config(default = 256)]
    pub d_hidden: usize,
    /// Shift added to the raw output before softplus (see the module docs).
    #[config(default = -1.0)]
    pub density_shift: f64,
}

/// F_sigma: the density of the implicit body NeRF.
#[derive(Module, Debug)]
pub struct DensityHead {
    /// The four linear layers; the last maps to 1 channel.
    pub layers: Vec<Linear>,
    /// Shift added to the raw output before softplus.
    pub density_shift: f64,
}

impl DensityHeadConfig {
    /// A freshly initialised F_sigma on `device`.
    pub fn init(&self, device: &Device) -> DensityHead {
        DensityHead {
            layers: four_layers(self.d_input, self.d_hidden, 1, device),
            density_shift: self.density_shift,
        }
    }
}

impl DensityHead {
    /// `sigma = softplus(F_sigma(mean_n z_n) + density_shift)`, per metre, >= 0.
    ///
    /// # Shapes
    /// - `mean_feature` (mean_n z_n): `[M, d]`
    /// - output sigma: `[M]`
    pub fn forward(&self, mean_feature: Tensor<2>) -> Result<Tensor<1>, ShapeError> {
        let d_input = self.layers[0].weight.dims()[0];
        let [m, d] = mean_feature.dims();
        ShapeError::check(
            "F_sigma input `mean_feature` [M, d]",
            &[m, d],
            &[None, Some(d_input)],
        )?;
        let last = self.layers.len() - 1;
        let mut x = mean_feature;
        for (i, layer) in self.layers.iter().enumerate() {
            x = linear(layer, x, i < last);
        }
        let sigma = softplus(x.add_scalar(self.density_shift), 1.0);
        Ok(sigma.reshape([m]))
    }
}

/// Configuration of [`ColourHead`] (F_c0).
#[derive(Config, Debug)]
pub struct ColourHeadConfig {
    /// Width d of the fused feature z.
    #[config(default = 128)]
    pub d_input: usize,
    /// Width of the direction encoding gamma(d) (27 for L = 4).
    #[config(default = 27)]
    pub d_direction: usize,
    /// Hidden width d_h (also the width of h).
    #[config(default = 256)]
    pub d_hidden: usize,
}

/// F_c0: NeRF colour c0, confidence psi and the hidden feature h for the blender.
#[derive(Module, Debug)]
pub struct ColourHead {
    /// The four linear layers; the last maps to 4 channels (c0 logits, psi logit).
    pub layers: Vec<Linear>,
}

/// The outputs of F_c0 for M points.
#[derive(Debug, Clone)]
pub struct ColourHeadOutput {
    /// NeRF colour c0 = sigmoid(out[0..3]), `[M, 3]` in [0, 1].
    pub c0: Tensor<2>,
    /// Confidence psi = sigmoid(out[3]), `[M, 1]` in [0, 1].
    pub confidence: Tensor<2>,
    /// h: the ReLU activation of the third (second-to-last) layer, `[M, d_h]`.
    pub h: Tensor<2>,
}

impl ColourHeadConfig {
    /// A freshly initialised F_c0 on `device`.
    pub fn init(&self, device: &Device) -> ColourHead {
        ColourHead {
            layers: four_layers(self.d_input + self.d_direction, self.d_hidden, 4, device),
        }
    }
}

impl ColourHead {
    /// `(c0, psi, h) = F_c0([mean_n z_n ; gamma(d)])`.
    ///
    /// # Shapes
    /// - `mean_feature` (mean_n z_n): `[M, d]`
    /// - `dir_encoding` (gamma(d)): `[M, d_direction]`
    /// - outputs: c0 `[M, 3]`, confidence `[M, 1]`, h `[M, d_h]`
    pub fn forward(
        &self,
        mean_feature: Tensor<2>,
        dir_encoding: Tensor<2>,
    ) -> Result<ColourHeadOutput, ShapeError> {
        let d_in = self.layers[0].weight.dims()[0];
        let [m, d] = mean_feature.dims();
        let [m_dir, d_dir] = dir_encoding.dims();
        ShapeError::check("F_c0 `dir_encoding` [M, 27]", &[m_dir], &[Some(m)])?;
        ShapeError::check(
            "F_c0 `mean_feature` ++ `dir_encoding` widths",
            &[d + d_dir],
            &[Some(d_in)],
        )?;
        let x = Tensor::cat(vec![mean_feature, dir_encoding], 1);
        let x = linear(&self.layers[0], x, true);
        let x = linear(&self.layers[1], x, true);
        let h = linear(&self.layers[2], x, true);
        let out = linear(&self.layers[3], h.clone(), false);
        let c0 = sigmoid(out.clone().slice(s![.., 0..3]));
        let confidence = sigmoid(out.slice(s![.., 3..4]));
        Ok(ColourHeadOutput { c0, confidence, h })
    }
}
