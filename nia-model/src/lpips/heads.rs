//! The learned linear layers w_l of LPIPS (Zhang et al. 2018, eq. 1; the package's
//! `lin0` ... `lin4`, `NetLinLayer`): one 1x1 convolution without bias from C_l channels to 1
//! per compared layer, applied to the squared difference of the unit-normalised features.
//!
//! The package's `NetLinLayer` is `Sequential(Dropout, Conv2d)`, hence the weight-file keys
//! `lin{l}.model.1.weight` of shape [1, C_l, 1, 1]; dropout is inactive in eval mode and is
//! not part of the metric.

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::prelude::*;

/// The five heads w_l.
#[derive(Module, Debug)]
pub struct LinearHeads {
    /// `lins[l]`: weight [1, C_l, 1, 1], no bias.
    pub lins: Vec<Conv2d>,
}

impl LinearHeads {
    /// Randomly initialised heads for layers of `channels[l]` channels.
    pub fn init(channels: &[usize], device: &Device) -> Self {
        let lins = channels
            .iter()
            .map(|&c| {
                Conv2dConfig::new([c, 1], [1, 1])
                    .with_bias(false)
                    .init(device)
            })
            .collect();
        Self { lins }
    }

    /// Layer `l`'s distance: the spatial mean of w_l applied to the squared feature
    /// difference, `1 / (H_l W_l) sum_{h,w} sum_c w_{l,c} (y^l_hwc - y0^l_hwc)^2`.
    ///
    /// # Shapes
    /// - squared_difference: [N, C_l, H_l, W_l]
    /// - returns: [N, 1]
    pub fn layer_distance(&self, l: usize, squared_difference: Tensor<4>) -> Tensor<2> {
        let weighted = self.lins[l].forward(squared_difference); // [N, 1, H_l, W_l]
        let [n, _, h, w] = weighted.dims();
        weighted.reshape([n, h * w]).mean_dim(1)
    }

    /// Input channels C_l of each head.
    pub fn channels(&self) -> Vec<usize> {
        self.lins.iter().map(|lin| lin.weight.dims()[1]).collect()
    }
}
