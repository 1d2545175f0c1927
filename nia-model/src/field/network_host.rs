//! F_sigma, F_c0 and F_B with their weights on the host, fused and in parallel (inference on
//! the CPU backends).
//!
//! The three MLP stacks run as [`HostMlp`]s: each task carries its rows through every layer in
//! cache, where the tensor path allocates, zeroes, copies and revisits every layer's output on
//! the calling thread ([`crate::host_mlp`]). The inputs are laid out as the tensor path lays
//! them out (F_B's tokens are still built with tensor operations, [`Blender::tokens`]), and the
//! activations after the stacks (softplus, sigmoid, the blend's softmax) stay tensor operations,
//! so only the products, biases and ReLUs move. [`crate::SceneEncoding::with_host_reads`] reads
//! the weights once per scene; the tensor path stays the reference, the path with gradients and
//! the one on the GPU (`nia-model/tests/fields.rs` and `tests/model.rs` compare them).

use burn::prelude::*;
use burn::tensor::activation::{sigmoid, softplus};

use super::heads::{ColourHead, ColourHeadOutput, DensityHead};
use crate::host_mlp::{FirstLayerAddend, HostMlp};
use crate::ibr::blender::Blender;
use crate::readback::host_values_of;
use crate::shape::ShapeError;

/// F_c0's layer whose ReLU activation is h (the third of four).
const H_LAYER: usize = 2;

/// F_sigma, F_c0 and F_B's two parts on the host.
#[derive(Debug, Clone)]
pub struct HostNetwork {
    /// F_sigma's four layers.
    density: HostMlp,
    /// F_sigma's shift before softplus.
    density_shift: f64,
    /// F_c0's four layers.
    colour: HostMlp,
    /// F_B's per-point part `W_p [h, psi]` (one layer, no bias).
    blend_point: HostMlp,
    /// F_B's token layer and layers 2..8.
    blend_tokens: HostMlp,
}

impl HostNetwork {
    /// Reads the heads' and the blender's weights back.
    pub fn read(
        density: &DensityHead,
        colour: &ColourHead,
        blender: &Blender,
    ) -> Result<Self, ShapeError> {
        let mut tokens = vec![blender.token_input.clone()];
        tokens.extend(blender.layers.iter().cloned());
        Ok(HostNetwork {
            density: HostMlp::read("host F_sigma", &density.layers)?,
            density_shift: density.density_shift,
            colour: HostMlp::read("host F_c0", &colour.layers)?,
            blend_point: HostMlp::read(
                "host F_B per-point layer",
                std::slice::from_ref(&blender.point_input),
            )?,
            blend_tokens: HostMlp::read("host F_B token layers", &tokens)?,
        })
    }

    /// [`DensityHead::forward`]: `sigma = softplus(F_sigma(mean_n z_n) + density_shift)`.
    ///
    /// # Shapes
    /// - `mean_feature`: `[M, d]`; output `[M]`
    pub fn density(&self, mean_feature: Tensor<2>) -> Result<Tensor<1>, ShapeError> {
        let [m, _] = mean_feature.dims();
        let device = mean_feature.device();
        let x = host_values_of("host F_sigma input", mean_feature)?;
        let raw = self.density.forward("host F_sigma", &x, m, None, None)?;
        let raw = Tensor::<1>::from_data(TensorData::new(raw.output, [m]), &device);
        Ok(softplus(raw.add_scalar(self.density_shift), 1.0))
    }

    /// [`ColourHead::forward`]: c0, psi and h from `[mean_n z_n ; gamma(d)]`.
    ///
    /// # Shapes
    /// - `mean_feature`: `[M, d]`; `dir_encoding`: `[M, d_direction]`
    /// - outputs: c0 `[M, 3]`, confidence `[M, 1]`, h `[M, d_h]`
    pub fn colour(
        &self,
        mean_feature: Tensor<2>,
        dir_encoding: Tensor<2>,
    ) -> Result<ColourHeadOutput, ShapeError> {
        let [m, _] = mean_feature.dims();
        ShapeError::check(
            "host F_c0 `dir_encoding` [M, 27]",
            &[dir_encoding.dims()[0]],
            &[Some(m)],
        )?;
        let device = mean_feature.device();
        let x = host_values_of(
            "host F_c0 input",
            Tensor::cat(vec![mean_feature, dir_encoding], 1),
        )?;
        let out = self
            .colour
            .forward("host F_c0", &x, m, None, Some(H_LAYER))?;
        let tapped = out.tapped.ok_or_else(|| {
            ShapeError::value("host F_c0", "h, the third layer's activation".into())
        })?;
        let d_h = self.colour.width_after(H_LAYER).unwrap_or(0);
        let h = Tensor::<2>::from_data(TensorData::new(tapped, [m, d_h]), &device);
        let out = Tensor::<2>::from_data(TensorData::new(out.output, [m, 4]), &device);
        Ok(ColourHeadOutput {
            c0: sigmoid(out.clone().slice(s![.., 0..3])),
            confidence: sigmoid(out.slice(s![.., 3..4])),
            h,
        })
    }

    /// [`Blender::forward`]'s network on its inputs: the blend logits w_0..w_N.
    ///
    /// # Shapes
    /// - `tokens`: `[N + 1, M, d_token]` (token 0 = c0's); `point`: `[M, d_point]`
    /// - output `[M, N + 1]`
    pub fn blend_logits(
        &self,
        tokens: Tensor<3>,
        point: Tensor<2>,
    ) -> Result<Tensor<2>, ShapeError> {
        let [t, m, _] = tokens.dims();
        let device = tokens.device();
        if m == 0 {
            return Ok(Tensor::zeros([0, t], &device));
        }
        let point = host_values_of("host F_B per-point input", point)?;
        let point = self
            .blend_point
            .forward("host F_B per-point layer", &point, m, None, None)?
            .output;
        let tokens = host_values_of("host F_B tokens", tokens)?;
        let logits = self.blend_tokens.forward(
            "host F_B token layers",
            &tokens,
            t * m,
            Some(FirstLayerAddend {
                values: &point,
                period: m,
            }),
            None,
        )?;
        Ok(Tensor::<2>::from_data(TensorData::new(logits.output, [t, m]), &device).transpose())
    }
}
