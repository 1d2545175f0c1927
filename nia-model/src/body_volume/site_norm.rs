//! Channel normalisation over the active sites, per view.
//!
//! Neural Body's `SparseConvNet` follows every sparse convolution with `BatchNorm1d`
//! (eps 1e-3) over the active sites of its one scene per batch. Here the N source views of a
//! scene are the batch; a BatchNorm over all views would mix them and its running averages
//! would make evaluation differ from training. So the statistics are taken per view and
//! channel over that view's P active sites (an instance norm on the sparse sites, i.e.
//! Neural Body's training-time BatchNorm applied to each view on its own), with a learned
//! per-channel scale and shift. It works for any N >= 1, keeps views independent, has no
//! running state, and training and evaluation compute the same thing.

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::activation::relu;

use super::site_norm_op::site_norm_relu;
use super::BodyVolumeError;
use crate::device::computes_on_cpu;
use crate::kernels::host_op::runs_on_host;

/// Configuration of [`SiteNorm`].
#[derive(Config, Debug)]
pub struct SiteNormConfig {
    /// Channels C.
    pub channels: usize,
    /// Added to the variance (Neural Body's BatchNorm uses 1e-3).
    #[config(default = 1e-3)]
    pub epsilon: f64,
}

impl SiteNormConfig {
    /// A norm with scale 1 and shift 0.
    pub fn init(&self, device: &Device) -> SiteNorm {
        SiteNorm {
            gamma: burn::nn::Initializer::Ones.init([self.channels], device),
            beta: burn::nn::Initializer::Zeros.init([self.channels], device),
            epsilon: self.epsilon,
        }
    }
}

/// `y = (x - mean_P x) / sqrt(var_P x + eps) * gamma + beta`, statistics per view and channel
/// over the active sites (biased variance).
#[derive(Module, Debug)]
pub struct SiteNorm {
    /// [C] scale.
    pub gamma: Param<Tensor<1>>,
    /// [C] shift.
    pub beta: Param<Tensor<1>>,
    epsilon: f64,
}

impl SiteNorm {
    /// # Shapes
    /// - features: `[N, P, C]`
    /// - output: `[N, P, C]`
    pub fn forward(&self, features: Tensor<3>) -> Result<Tensor<3>, BodyVolumeError> {
        self.check(&features)?;
        if features.dims()[1] == 0 {
            return Ok(features);
        }
        Ok(self.normalise(features))
    }

    /// `ReLU(self.forward(features))`; on flex one host operation with its own backward
    /// ([`super::site_norm_op`]), and in training on a GPU backend the same operation from the
    /// backend's primitives ([`super::site_norm_device`]).
    ///
    /// # Shapes
    /// - features: `[N, P, C]`
    /// - output: `[N, P, C]`
    pub fn forward_relu(&self, features: Tensor<3>) -> Result<Tensor<3>, BodyVolumeError> {
        self.check(&features)?;
        if features.dims()[1] == 0 {
            return Ok(features);
        }
        let device = features.device();
        let training_on_gpu =
            !computes_on_cpu(&device) && (features.is_tracked() || self.gamma.val().is_tracked());
        if runs_on_host(&device) || training_on_gpu {
            return Ok(site_norm_relu(
                features,
                self.gamma.val(),
                self.beta.val(),
                self.epsilon,
            ));
        }
        Ok(relu(self.normalise(features)))
    }

    /// The features' channel count against gamma's.
    fn check(&self, features: &Tensor<3>) -> Result<(), BodyVolumeError> {
        let [channels] = self.gamma.dims();
        let dims = features.dims();
        if dims[2] != channels {
            return Err(BodyVolumeError::shape(
                "SiteNorm features",
                format!("[N, P, {channels}]"),
                &dims,
            ));
        }
        Ok(())
    }

    /// The tensor form of the norm, `P > 0`.
    fn normalise(&self, features: Tensor<3>) -> Tensor<3> {
        let [channels] = self.gamma.dims();
        let (var, mean) = features.clone().var_mean_bias(1);
        let normalised = (features - mean) / (var + self.epsilon).sqrt();
        let gamma = self.gamma.val().reshape([1, 1, channels]);
        let beta = self.beta.val().reshape([1, 1, channels]);
        normalised * gamma + beta
    }
}
