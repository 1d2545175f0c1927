//! The two LPIPS trunks ("pnet" in the `lpips` package): torchvision's AlexNet and VGG16
//! `features`, each described as its list of convolutions in torchvision order with the max
//! pooling in front of a conv and whether its ReLU output is one of the five LPIPS layers.
//!
//! - AlexNet (`features` = Conv(3,64,k11,s4,p2) ReLU MaxPool(3,2) Conv(64,192,k5,p2) ReLU
//!   MaxPool(3,2) Conv(192,384,k3,p1) ReLU Conv(384,256,k3,p1) ReLU Conv(256,256,k3,p1) ReLU
//!   MaxPool(3,2)): the package's slices `[0:2] [2:5] [5:8] [8:10] [10:12]` end after the ReLU
//!   of every conv (features 1, 4, 7, 9, 11); the final MaxPool (12) is unused.
//! - VGG16 (13 convs k3 p1, MaxPool(2,2) after conv 2, 4, 7, 10, 13): the slices `[0:4] [4:9]
//!   [9:16] [16:23] [23:30]` end at relu1_2, relu2_2, relu3_3, relu4_3, relu5_3; the final
//!   MaxPool (30) is unused.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// Number of trunk layers LPIPS compares (L in Zhang et al. 2018, eq. 1) for both trunks.
pub const LPIPS_LAYERS: usize = 5;

/// Which trunk the metric runs on (the package's `net=` argument).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LpipsNet {
    /// torchvision `alexnet` (the package's default, `weights/v0.1/alex.pth`).
    Alex,
    /// torchvision `vgg16` (`weights/v0.1/vgg.pth`); `"vgg16"` is accepted as in the package.
    #[serde(alias = "vgg16")]
    Vgg,
}

/// One max pooling of the trunk (no padding, floor rounding, as torchvision's).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pool {
    pub kernel: usize,
    pub stride: usize,
}

/// One convolution of a torchvision `features` Sequential, always followed by a ReLU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConvLayer {
    /// Index of the conv in torchvision's `features` (`features.{index}.weight` in a state
    /// dict; lpips keeps the same index as the module name inside its slices).
    pub index: usize,
    /// Square kernel size.
    pub kernel: usize,
    pub stride: usize,
    /// Zero padding on every side.
    pub padding: usize,
    /// Max pooling applied to the input of this conv.
    pub pool_before: Option<Pool>,
    /// Whether the ReLU output of this conv is one of the [`LPIPS_LAYERS`] compared layers.
    pub tapped: bool,
}

const fn conv(index: usize, kernel: usize, stride: usize, padding: usize) -> ConvLayer {
    ConvLayer {
        index,
        kernel,
        stride,
        padding,
        pool_before: None,
        tapped: false,
    }
}

const fn pooled(layer: ConvLayer, kernel: usize, stride: usize) -> ConvLayer {
    ConvLayer {
        pool_before: Some(Pool { kernel, stride }),
        ..layer
    }
}

const fn tapped(layer: ConvLayer) -> ConvLayer {
    ConvLayer {
        tapped: true,
        ..layer
    }
}

/// torchvision `alexnet().features` up to its fifth ReLU.
const ALEX_LAYERS: [ConvLayer; 5] = [
    tapped(conv(0, 11, 4, 2)),
    tapped(pooled(conv(3, 5, 1, 2), 3, 2)),
    tapped(pooled(conv(6, 3, 1, 1), 3, 2)),
    tapped(conv(8, 3, 1, 1)),
    tapped(conv(10, 3, 1, 1)),
];

/// torchvision `vgg16().features` up to relu5_3.
const VGG16_LAYERS: [ConvLayer; 13] = [
    conv(0, 3, 1, 1),
    tapped(conv(2, 3, 1, 1)),
    pooled(conv(5, 3, 1, 1), 2, 2),
    tapped(conv(7, 3, 1, 1)),
    pooled(conv(10, 3, 1, 1), 2, 2),
    conv(12, 3, 1, 1),
    tapped(conv(14, 3, 1, 1)),
    pooled(conv(17, 3, 1, 1), 2, 2),
    conv(19, 3, 1, 1),
    tapped(conv(21, 3, 1, 1)),
    pooled(conv(24, 3, 1, 1), 2, 2),
    conv(26, 3, 1, 1),
    tapped(conv(28, 3, 1, 1)),
];

/// torchvision's output channels per conv.
const ALEX_WIDTHS: [usize; 5] = [64, 192, 384, 256, 256];
const VGG16_WIDTHS: [usize; 13] = [
    64, 64, 128, 128, 256, 256, 256, 512, 512, 512, 512, 512, 512,
];

impl LpipsNet {
    /// The trunk's convolutions in order.
    pub fn layers(self) -> &'static [ConvLayer] {
        match self {
            LpipsNet::Alex => &ALEX_LAYERS,
            LpipsNet::Vgg => &VGG16_LAYERS,
        }
    }

    /// torchvision's output channels of each conv of [`Self::layers`] (the widths the
    /// published weights have).
    pub fn torchvision_widths(self) -> Vec<usize> {
        match self {
            LpipsNet::Alex => ALEX_WIDTHS.to_vec(),
            LpipsNet::Vgg => VGG16_WIDTHS.to_vec(),
        }
    }

    /// Name as in the package (`net="alex"` / `net="vgg"`).
    pub fn name(self) -> &'static str {
        match self {
            LpipsNet::Alex => "alex",
            LpipsNet::Vgg => "vgg",
        }
    }

    /// Size along one image axis of the last compared feature map for an input of `input`
    /// pixels, or `None` if a conv or pooling window no longer fits (torch would fail).
    pub fn feature_size(self, input: usize) -> Option<usize> {
        let mut size = input;
        for layer in self.layers() {
            if let Some(pool) = layer.pool_before {
                size = size.checked_sub(pool.kernel)? / pool.stride + 1;
            }
            size = (size + 2 * layer.padding).checked_sub(layer.kernel)? / layer.stride + 1;
        }
        Some(size)
    }

    /// Smallest image side the trunk accepts: 31 pixels for AlexNet, 16 for VGG16.
    pub fn min_image_size(self) -> usize {
        (1..)
            .find(|&side| self.feature_size(side).is_some())
            .expect("every trunk accepts some image size")
    }
}

impl fmt::Display for LpipsNet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A trunk name other than `alex`, `vgg` or `vgg16`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown LPIPS network `{0}` (expected `alex` or `vgg`)")]
pub struct UnknownLpipsNet(pub String);

impl FromStr for LpipsNet {
    type Err = UnknownLpipsNet;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "alex" => Ok(LpipsNet::Alex),
            "vgg" | "vgg16" => Ok(LpipsNet::Vgg),
            other => Err(UnknownLpipsNet(other.to_string())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn five_tapped_layers_and_widths_per_conv() {
        for net in [LpipsNet::Alex, LpipsNet::Vgg] {
            let taps = net.layers().iter().filter(|l| l.tapped).count();
            assert_eq!(taps, LPIPS_LAYERS, "{net}");
            assert_eq!(net.layers().len(), net.torchvision_widths().len(), "{net}");
            assert!(net.layers().last().unwrap().tapped, "{net}");
        }
    }

    #[test]
    fn minimum_sizes_follow_torch_shape_arithmetic() {
        // AlexNet: conv1 (H - 7) / 4 + 1 >= 7 so that two 3/2 poolings leave >= 1 pixel.
        assert_eq!(LpipsNet::Alex.min_image_size(), 31);
        assert_eq!(LpipsNet::Alex.feature_size(31), Some(1));
        assert_eq!(LpipsNet::Alex.feature_size(30), None);
        assert_eq!(LpipsNet::Alex.feature_size(64), Some(3));
        assert_eq!(LpipsNet::Alex.feature_size(224), Some(13));
        // VGG16: four 2/2 poolings.
        assert_eq!(LpipsNet::Vgg.min_image_size(), 16);
        assert_eq!(LpipsNet::Vgg.feature_size(15), None);
        assert_eq!(LpipsNet::Vgg.feature_size(64), Some(4));
        assert_eq!(LpipsNet::Vgg.feature_size(224), Some(14));
    }

    #[test]
    fn names_parse_and_print_as_in_the_package() {
        assert_eq!("alex".parse::<LpipsNet>(), Ok(LpipsNet::Alex));
        assert_eq!("vgg".parse::<LpipsNet>(), Ok(LpipsNet::Vgg));
        assert_eq!("vgg16".parse::<LpipsNet>(), Ok(LpipsNet::Vgg));
        assert!("squeeze".parse::<LpipsNet>().is_err());
        assert_eq!(LpipsNet::Vgg.to_string(), "vgg");
        assert_eq!(serde_json::to_string(&LpipsNet::Alex).unwrap(), "\"alex\"");
        assert_eq!(
            serde_json::from_str::<LpipsNet>("\"vgg16\"").unwrap(),
            LpipsNet::Vgg
        );
    }
}
