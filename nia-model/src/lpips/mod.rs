//! LPIPS, the Learned Perceptual Image Patch Similarity of Zhang et al. 2018 ("The
//! Unreasonable Effectiveness of Deep Features as a Perceptual Metric"), as computed by the
//! `lpips` PyPI package, version 0.1 of the metric (`lpips.LPIPS(net=..., version="0.1")`,
//! `lpips=True`, `spatial=False`, called with `normalize=True`):
//!
//! 1. images in [0, 1] are mapped to [-1, 1] (`2 x - 1`), then scaled per channel by the
//!    package's `ScalingLayer`: `(x - shift) / scale` with [`SCALING_SHIFT`], [`SCALING_SCALE`];
//! 2. the trunk ([`trunk::Trunk`], AlexNet or VGG16 `features`) gives five ReLU feature maps
//!    y^l for each image;
//! 3. each is unit-normalised over channels, `ŷ^l = y^l / (sqrt(sum_c (y^l_c)^2) + 1e-10)`;
//! 4. eq. 1: `d(x, x0) = sum_l 1 / (H_l W_l) sum_{h,w} w_l · (ŷ^l_hw - ŷ0^l_hw)^2`, with the
//!    learned non-negative weights w_l ([`heads::LinearHeads`], 1x1 convs without bias).
//!
//! Weights are the user's files, never downloaded ([`Lpips::load`]): the trunk from a
//! torchvision state dict (`alexnet-owt-7be5be79.pth`, `vgg16-397923af.pth`), the heads from
//! the package's `weights/v0.1/alex.pth` / `vgg.pth`. Checked against the package itself in
//! nia-model/tests/lpips.rs (fixtures from scripts/fixtures/make_lpips_fixture.py).

pub mod heads;
pub mod load;
pub mod net;
pub mod trunk;

use burn::prelude::*;

pub use heads::LinearHeads;
pub use load::LpipsLoadError;
pub use net::{LpipsNet, UnknownLpipsNet, LPIPS_LAYERS};
pub use trunk::Trunk;

/// The package's `ScalingLayer.shift` (per RGB channel, applied to inputs in [-1, 1]).
pub const SCALING_SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
/// The package's `ScalingLayer.scale`.
pub const SCALING_SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// The `eps` of the package's `normalize_tensor`, added to the channel norm.
pub const NORMALIZE_EPS: f32 = 1e-10;

/// Which trunk, and how wide. The published weights need the default widths; narrower ones
/// exist for small test networks.
#[derive(Config, Debug)]
pub struct LpipsConfig {
    /// The trunk: `alex` or `vgg`.
    pub net: LpipsNet,
    /// Output channels of every trunk conv in torchvision order (5 for AlexNet, 13 for
    /// VGG16); `None` means torchvision's ([`LpipsNet::torchvision_widths`]).
    pub widths: Option<Vec<usize>>,
}

/// A configuration that describes no network.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LpipsConfigError {
    #[error("the {net} trunk has {expected} convolutions but {found} widths were given")]
    WidthCount {
        net: LpipsNet,
        expected: usize,
        found: usize,
    },
    #[error("width of conv {conv} of the {net} trunk is 0")]
    ZeroWidth { net: LpipsNet, conv: usize },
}

impl LpipsConfig {
    /// The output channels of every trunk conv, validated.
    ///
    /// # Errors
    /// [`LpipsConfigError`]: a width count other than the trunk's conv count, or a zero width.
    pub fn conv_widths(&self) -> Result<Vec<usize>, LpipsConfigError> {
        let net = self.net;
        let widths = self
            .widths
            .clone()
            .unwrap_or_else(|| net.torchvision_widths());
        let expected = net.layers().len();
        if widths.len() != expected {
            return Err(LpipsConfigError::WidthCount {
                net,
                expected,
                found: widths.len(),
            });
        }
        if let Some(conv) = widths.iter().position(|&w| w == 0) {
            return Err(LpipsConfigError::ZeroWidth { net, conv });
        }
        Ok(widths)
    }

    /// Channels C_l of the five compared layers (the heads' input widths): with torchvision's
    /// widths 64, 192, 384, 256, 256 (AlexNet) or 64, 128, 256, 512, 512 (VGG16).
    pub fn feature_channels(&self) -> Result<Vec<usize>, LpipsConfigError> {
        let widths = self.conv_widths()?;
        Ok(self
            .net
            .layers()
            .iter()
            .zip(widths)
            .filter(|(layer, _)| layer.tapped)
            .map(|(_, w)| w)
            .collect())
    }

    /// A randomly initialised metric (burn's default init) of this shape; [`Lpips::load`]
    /// fills it with real weights.
    pub fn init(&self, device: &Device) -> Result<Lpips, LpipsConfigError> {
        let widths = self.conv_widths()?;
        let channels = self.feature_channels()?;
        Ok(Lpips {
            trunk: Trunk::init(self.net, &widths, device),
            heads: LinearHeads::init(&channels, device),
        })
    }
}

/// Why two image batches cannot be compared.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LpipsError {
    #[error("LPIPS compares images of equal shape, got {a:?} and {b:?}")]
    ShapeMismatch { a: [usize; 4], b: [usize; 4] },
    #[error("LPIPS needs RGB images [N, 3, H, W], got shape {shape:?}")]
    NotRgb { shape: [usize; 4] },
    #[error("LPIPS got an empty batch (shape {shape:?})")]
    EmptyBatch { shape: [usize; 4] },
    #[error(
        "images of shape {shape:?} are too small for the LPIPS {net} trunk: height and width \
         must be at least {min} pixels"
    )]
    TooSmall {
        net: LpipsNet,
        shape: [usize; 4],
        /// [`LpipsNet::min_image_size`].
        min: usize,
    },
}

/// The LPIPS metric: trunk + linear heads.
#[derive(Module, Debug)]
pub struct Lpips {
    pub trunk: Trunk,
    pub heads: LinearHeads,
}

impl Lpips {
    /// The trunk this metric runs on.
    pub fn net(&self) -> LpipsNet {
        self.trunk.net
    }

    /// The LPIPS distance of every image pair (v0.1, `normalize=True`): 0 for identical
    /// images, symmetric, larger for perceptually more different images.
    ///
    /// Differentiable with respect to the images on an autodiff device.
    ///
    /// # Shapes
    /// - a, b: [N, 3, H, W], RGB in [0, 1], H and W at least [`LpipsNet::min_image_size`]
    ///   (31 for AlexNet, 16 for VGG16)
    /// - returns: [N]
    ///
    /// # Errors
    /// [`LpipsError`]: shapes differing, not 3 channels, N = 0, or images too small.
    pub fn distance(&self, a: Tensor<4>, b: Tensor<4>) -> Result<Tensor<1>, LpipsError> {
        let layers = self.layer_distances(a, b)?; // [N, 5]
        let [n, _] = layers.dims();
        Ok(layers.sum_dim(1).reshape([n]))
    }

    /// The five per-layer terms of [`Self::distance`] (the package's `retPerLayer=True`).
    ///
    /// # Shapes
    /// - a, b: [N, 3, H, W] as in [`Self::distance`]
    /// - returns: [N, 5], column l the term of layer l
    pub fn layer_distances(&self, a: Tensor<4>, b: Tensor<4>) -> Result<Tensor<2>, LpipsError> {
        self.check_shapes(a.dims(), b.dims())?;
        let n = a.dims()[0];
        // Both batches through the trunk at once: [2N, 3, H, W].
        let x = scaling_layer(Tensor::cat(vec![a, b], 0) * 2.0 - 1.0);
        let terms = self
            .trunk
            .forward(x)
            .into_iter()
            .enumerate()
            .map(|(l, y)| {
                let y = normalize_channels(y);
                let y0 = y.clone().narrow(0, 0, n);
                let y1 = y.narrow(0, n, n);
                self.heads.layer_distance(l, (y0 - y1).powi_scalar(2))
            })
            .collect();
        Ok(Tensor::cat(terms, 1))
    }

    fn check_shapes(&self, a: [usize; 4], b: [usize; 4]) -> Result<(), LpipsError> {
        if a != b {
            return Err(LpipsError::ShapeMismatch { a, b });
        }
        let [n, c, h, w] = a;
        if c != 3 {
            return Err(LpipsError::NotRgb { shape: a });
        }
        if n == 0 {
            return Err(LpipsError::EmptyBatch { shape: a });
        }
        let net = self.net();
        let min = net.min_image_size();
        if h < min || w < min {
            return Err(LpipsError::TooSmall { net, shape: a, min });
        }
        Ok(())
    }
}

/// The package's `ScalingLayer`: `(x - shift) / scale` per channel.
///
/// # Shapes
/// - x: [N, 3, H, W] in [-1, 1] -> [N, 3, H, W]
pub fn scaling_layer(x: Tensor<4>) -> Tensor<4> {
    let device = x.device();
    let shift = Tensor::<1>::from_floats(SCALING_SHIFT, &device).reshape([1, 3, 1, 1]);
    let scale = Tensor::<1>::from_floats(SCALING_SCALE, &device).reshape([1, 3, 1, 1]);
    (x - shift) / scale
}

/// The package's `normalize_tensor`: unit length over channels at every pixel,
/// `y / (sqrt(sum_c y_c^2) + 1e-10)` (all-zero features stay zero).
///
/// # Shapes
/// - y: [N, C, H, W] -> [N, C, H, W]
pub fn normalize_channels(y: Tensor<4>) -> Tensor<4> {
    let norm = y.clone().powi_scalar(2).sum_dim(1).sqrt() + NORMALIZE_EPS; // [N, 1, H, W]
    y / norm
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Module;

    #[test]
    fn default_widths_have_torchvision_parameter_counts() {
        #[allow(deprecated)]
        let device = Device::ndarray();
        // sum(p.numel() for p in torchvision.models.alexnet().features.parameters()) etc.
        for (net, trunk_params, heads_params) in [
            (LpipsNet::Alex, 2_469_696, 64 + 192 + 384 + 256 + 256),
            (LpipsNet::Vgg, 14_714_688, 64 + 128 + 256 + 512 + 512),
        ] {
            let lpips = LpipsConfig::new(net).init(&device).unwrap();
            assert_eq!(lpips.trunk.num_params(), trunk_params, "{net}");
            assert_eq!(lpips.heads.num_params(), heads_params, "{net}");
            assert_eq!(
                lpips.trunk.feature_channels(),
                lpips.heads.channels(),
                "{net}"
            );
        }
    }

    #[test]
    fn alexnet_conv_shapes_are_torchvision_s() {
        #[allow(deprecated)]
        let device = Device::ndarray();
        let lpips = LpipsConfig::new(LpipsNet::Alex).init(&device).unwrap();
        let shapes: Vec<[usize; 4]> = lpips.trunk.convs.iter().map(|c| c.weight.dims()).collect();
        assert_eq!(
            shapes,
            vec![
                [64, 3, 11, 11],
                [192, 64, 5, 5],
                [384, 192, 3, 3],
                [256, 384, 3, 3],
                [256, 256, 3, 3],
            ]
        );
        assert_eq!(
            lpips.heads.channels(),
            LpipsConfig::new(LpipsNet::Alex).feature_channels().unwrap()
        );
    }

    #[test]
    fn widths_are_validated() {
        let config = LpipsConfig::new(LpipsNet::Vgg).with_widths(Some(vec![8; 5]));
        assert_eq!(
            config.conv_widths(),
            Err(LpipsConfigError::WidthCount {
                net: LpipsNet::Vgg,
                expected: 13,
                found: 5
            })
        );
        let config = LpipsConfig::new(LpipsNet::Alex).with_widths(Some(vec![8, 8, 0, 8, 8]));
        assert_eq!(
            config.conv_widths(),
            Err(LpipsConfigError::ZeroWidth {
                net: LpipsNet::Alex,
                conv: 2
            })
        );
        assert_eq!(
            LpipsConfig::new(LpipsNet::Vgg).feature_channels(),
            Ok(vec![64, 128, 256, 512, 512])
        );
    }

    #[test]
    fn normalized_features_have_unit_length_or_stay_zero() {
        #[allow(deprecated)]
        let device = Device::ndarray();
        let y = Tensor::<1>::from_floats([3.0, 0.0, 4.0, 0.0], &device).reshape([1, 2, 1, 2]);
        let out = normalize_channels(y)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert_eq!(out, vec![0.6, 0.0, 0.8, 0.0]);
    }
}
