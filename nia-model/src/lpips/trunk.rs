//! The LPIPS trunk: torchvision AlexNet or VGG16 `features` up to the fifth compared ReLU,
//! returning the five feature maps y^l of Zhang et al. 2018 (the package's `pnet` outputs
//! `relu1` ... `relu5`).
//!
//! The convolutions sit in one list in torchvision order; [`super::net::ConvLayer::index`]
//! maps each to its `features.{index}` key ([`super::load`]).

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::MaxPool2dConfig;
use burn::nn::PaddingConfig2d;
use burn::prelude::*;
use burn::tensor::activation::relu;

use super::net::LpipsNet;

/// AlexNet or VGG16 `features` (without the final max pooling).
#[derive(Module, Debug)]
pub struct Trunk {
    /// The convolutions of [`LpipsNet::layers`], in order; `convs[i]` is torchvision's
    /// `features.{layers[i].index}`, weight [C_i, C_{i-1}, k, k] and bias [C_i] (C_{-1} = 3).
    pub convs: Vec<Conv2d>,
    #[module(skip)]
    pub net: LpipsNet,
}

impl Trunk {
    /// A randomly initialised trunk with `widths[i]` output channels for conv `i`.
    ///
    /// `widths` must have one entry per conv of `net` (checked by
    /// [`super::LpipsConfig::conv_widths`]).
    pub fn init(net: LpipsNet, widths: &[usize], device: &Device) -> Self {
        debug_assert_eq!(widths.len(), net.layers().len());
        let mut c_in = 3;
        let convs = net
            .layers()
            .iter()
            .zip(widths)
            .map(|(layer, &c_out)| {
                let (k, s, p) = (layer.kernel, layer.stride, layer.padding);
                let conv = Conv2dConfig::new([c_in, c_out], [k, k])
                    .with_stride([s, s])
                    .with_padding(PaddingConfig2d::Explicit(p, p, p, p))
                    .init(device);
                c_in = c_out;
                conv
            })
            .collect();
        Self { convs, net }
    }

    /// The five compared feature maps (after ReLU).
    ///
    /// # Shapes
    /// - x: [N, 3, H, W], already scaled (the package's `ScalingLayer` output); H and W at
    ///   least [`LpipsNet::min_image_size`]
    /// - returns: 5 tensors [N, C_l, H_l, W_l]; with torchvision's widths C_l is
    ///   64, 192, 384, 256, 256 (AlexNet; H_l = H/4, H/8, H/16, H/16, H/16 roughly) or
    ///   64, 128, 256, 512, 512 (VGG16; H_l = H, H/2, H/4, H/8, H/16)
    pub fn forward(&self, x: Tensor<4>) -> Vec<Tensor<4>> {
        let mut features = Vec::with_capacity(super::net::LPIPS_LAYERS);
        let mut x = x;
        for (layer, conv) in self.net.layers().iter().zip(&self.convs) {
            if let Some(pool) = layer.pool_before {
                x = MaxPool2dConfig::new([pool.kernel, pool.kernel])
                    .with_strides([pool.stride, pool.stride])
                    .init()
                    .forward(x);
            }
            x = relu(conv.forward(x));
            if layer.tapped {
                features.push(x.clone());
            }
        }
        features
    }

    /// Output channels of the five compared layers (C_l).
    pub fn feature_channels(&self) -> Vec<usize> {
        self.net
            .layers()
            .iter()
            .zip(&self.convs)
            .filter(|(layer, _)| layer.tapped)
            .map(|(_, conv)| conv.weight.dims()[0])
            .collect()
    }
}
