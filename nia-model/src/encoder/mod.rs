//! Image encoder (docs/method.md "Method", step 2; paper appendix): a ResNet-18 trunk whose four feature maps
//! (64 x H/2 after the stem, 64 x H/4 after `layer1`, 128 x H/8 after `layer2`, 256 x H/16 after
//! `layer3`) are bilinearly upsampled to H/2 x W/2 and concatenated: 512 channels. The model
//! never builds that map: every consumer reduces its channels first, and the reduction is taken
//! level by level before upsampling ([`FeaturePyramid::reduce`]).
//!
//! Field names follow torchvision's `resnet18` so its state dict loads by name
//! ([`ImageEncoder::load_torchvision`]); `layer4` and `fc` are not part of the trunk.

pub mod bilinear;
pub mod channels_last;
pub mod host;
pub mod import;
pub mod pyramid_host;

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, PaddingConfig2d};
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::shape::ShapeError;

/// ImageNet normalisation torchvision's weights expect (applied inside the encoder).
pub(crate) const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
pub(crate) const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

/// Channels of the concatenated pyramid: 64 + 64 + 128 + 256.
pub const ENCODER_CHANNELS: usize = 512;

#[derive(Config, Debug)]
pub struct ImageEncoderConfig {
    /// Width of the stem and `layer1` (64 in ResNet-18); later stages double it.
    #[config(default = 64)]
    pub base_width: usize,
}

/// torchvision's `downsample` branch: 1x1 strided conv + BN (keys `downsample.0/1` are remapped
/// to `downsample.conv/bn` on import).
#[derive(Module, Debug)]
pub struct Downsample {
    pub conv: Conv2d,
    pub bn: BatchNorm,
}

/// ResNet BasicBlock: conv3x3-BN-ReLU-conv3x3-BN + identity (or downsample), ReLU.
#[derive(Module, Debug)]
pub struct BasicBlock {
    pub conv1: Conv2d,
    pub bn1: BatchNorm,
    pub conv2: Conv2d,
    pub bn2: BatchNorm,
    pub downsample: Option<Downsample>,
}

impl BasicBlock {
    fn new(c_in: usize, c_out: usize, stride: usize, device: &Device) -> Self {
        let conv3 = |ci, co, s| {
            Conv2dConfig::new([ci, co], [3, 3])
                .with_stride([s, s])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .with_bias(false)
                .init(device)
        };
        let downsample = (stride != 1 || c_in != c_out).then(|| Downsample {
            conv: Conv2dConfig::new([c_in, c_out], [1, 1])
                .with_stride([stride, stride])
                .with_bias(false)
                .init(device),
            bn: BatchNormConfig::new(c_out).init(device),
        });
        Self {
            conv1: conv3(c_in, c_out, stride),
            bn1: BatchNormConfig::new(c_out).init(device),
            conv2: conv3(c_out, c_out, 1),
            bn2: BatchNormConfig::new(c_out).init(device),
            downsample,
        }
    }

    /// # Shapes
    /// - x: [N, C_in, H, W] -> [N, C_out, H / stride, W / stride]
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let identity = match &self.downsample {
            Some(d) => d.bn.forward(d.conv.forward(x.clone())),
            None => x.clone(),
        };
        let y = relu(self.bn1.forward(self.conv1.forward(x)));
        let y = self.bn2.forward(self.conv2.forward(y));
        relu(y + identity)
    }
}

/// The ResNet-18 trunk producing the 512-channel pixel-aligned feature map at half resolution.
#[derive(Module, Debug)]
pub struct ImageEncoder {
    pub conv1: Conv2d,
    pub bn1: BatchNorm,
    pub maxpool: MaxPool2d,
    pub layer1: Vec<BasicBlock>,
    pub layer2: Vec<BasicBlock>,
    pub layer3: Vec<BasicBlock>,
}

impl ImageEncoderConfig {
    pub fn init(&self, device: &Device) -> ImageEncoder {
        let w = self.base_width;
        ImageEncoder {
            conv1: Conv2dConfig::new([3, w], [7, 7])
                .with_stride([2, 2])
                .with_padding(PaddingConfig2d::Explicit(3, 3, 3, 3))
                .with_bias(false)
                .init(device),
            bn1: BatchNormConfig::new(w).init(device),
            maxpool: MaxPool2dConfig::new([3, 3])
                .with_strides([2, 2])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(),
            layer1: vec![
                BasicBlock::new(w, w, 1, device),
                BasicBlock::new(w, w, 1, device),
            ],
            layer2: vec![
                BasicBlock::new(w, 2 * w, 2, device),
                BasicBlock::new(2 * w, 2 * w, 1, device),
            ],
            layer3: vec![
                BasicBlock::new(2 * w, 4 * w, 2, device),
                BasicBlock::new(4 * w, 4 * w, 1, device),
            ],
        }
    }

    /// Channels of the output feature map (8 x base_width; 512 for ResNet-18).
    pub fn out_channels(&self) -> usize {
        8 * self.base_width
    }
}

impl ImageEncoder {
    /// The concatenated feature map (the reference form; the model itself reduces the
    /// pyramid's levels before upsampling, [`FeaturePyramid::reduce`]).
    ///
    /// # Shapes
    /// - images: [N, 3, H, W], RGB in [0, 1] (H, W multiples of 16 give exact scales)
    /// - returns: [N, 8 * base_width, ceil(H/2), ceil(W/2)]
    pub fn forward(&self, images: Tensor<4>) -> Tensor<4> {
        self.forward_pyramid(images).concatenated()
    }

    /// The trunk's four feature maps at their own resolutions.
    ///
    /// # Shapes
    /// - images: [N, 3, H, W], RGB in [0, 1]
    /// - levels: [N, w, H/2, W/2], [N, w, H/4, W/4], [N, 2w, H/8, W/8], [N, 4w, H/16, W/16]
    ///   (w = base_width)
    pub fn forward_pyramid(&self, images: Tensor<4>) -> FeaturePyramid {
        let device = images.device();
        let mean = Tensor::<1>::from_floats(IMAGENET_MEAN, &device).reshape([1, 3, 1, 1]);
        let std = Tensor::<1>::from_floats(IMAGENET_STD, &device).reshape([1, 3, 1, 1]);
        let x = (images - mean) / std;

        let f1 = relu(self.bn1.forward(self.conv1.forward(x))); // [N, 64, H/2, W/2]
        let mut x = self.maxpool.forward(f1.clone());
        for block in &self.layer1 {
            x = block.forward(x);
        }
        let f2 = x.clone(); // [N, 64, H/4, W/4]
        for block in &self.layer2 {
            x = block.forward(x);
        }
        let f3 = x.clone(); // [N, 128, H/8, W/8]
        for block in &self.layer3 {
            x = block.forward(x);
        }
        let f4 = x; // [N, 256, H/16, W/16]
        FeaturePyramid {
            levels: [f1, f2, f3, f4],
        }
    }
}

/// The encoder's four feature maps before upsampling (finest first, at H/2).
#[derive(Debug, Clone)]
pub struct FeaturePyramid {
    /// `[N, C_l, H_l, W_l]`, l = 0..4; level 0 sets the output resolution H/2 x W/2.
    pub levels: [Tensor<4>; 4],
}

impl FeaturePyramid {
    /// Channels of the concatenated map, `sum_l C_l`.
    pub fn channels(&self) -> usize {
        self.levels.iter().map(|f| f.dims()[1]).sum()
    }

    /// Every level bilinearly upsampled to level 0's size and concatenated: the encoder's
    /// feature map F.
    ///
    /// # Shapes
    /// - output: `[N, sum_l C_l, H/2, W/2]`
    pub fn concatenated(self) -> Tensor<4> {
        let [_, _, h2, w2] = self.levels[0].dims();
        let up = |f: Tensor<4>| upsample_bilinear(f, [h2, w2]);
        let [f1, f2, f3, f4] = self.levels;
        Tensor::cat(vec![f1, up(f2), up(f3), up(f4)], 1)
    }

    /// `W^T F` per pixel, the channel reduction of the concatenated map by `weight`, computed
    /// level by level before upsampling: `sum_l up(W_l^T f_l)`, with `W_l` the rows of `weight`
    /// that meet level l's channels. Upsampling acts on space and the reduction on channels,
    /// so the two commute and this equals `W^T concatenated()` to float rounding (a test checks
    /// it), without the 512-channel map at H/2: at the paper's sizes (3 views of 512 x 512, d =
    /// 128) the products shrink from 12.9 to 2.3 GMAC and only d-channel maps are upsampled.
    ///
    /// # Shapes
    /// - `weight`: `[sum_l C_l, d]` (a `Linear`'s weight, input-major)
    /// - output: `[N, d, H/2, W/2]`
    pub fn reduce(&self, weight: Tensor<2>) -> Result<Tensor<4>, ShapeError> {
        check_reduction_weight(&weight, self.channels())?;
        let [_, _, h2, w2] = self.levels[0].dims();
        let mut offset = 0;
        let mut total: Option<Tensor<4>> = None;
        for f in &self.levels {
            let up = upsample_bilinear(reduce_level(&weight, offset, f), [h2, w2]);
            offset += f.dims()[1];
            total = Some(match total {
                None => up,
                Some(t) => t + up,
            });
        }
        total.ok_or_else(|| ShapeError::empty("feature pyramid levels"))
    }
}

/// Level l's part of [`FeaturePyramid::reduce`] before upsampling: `W_l^T f_l`, with `W_l` the
/// `C_l` rows of `weight` from `offset`.
///
/// # Shapes
/// - `weight`: `[sum_l C_l, d]`; `level` f_l: `[N, C_l, h, w]`; output `[N, d, h, w]`
pub fn reduce_level(weight: &Tensor<2>, offset: usize, level: &Tensor<4>) -> Tensor<4> {
    let [n, c, h, w] = level.dims();
    let d = weight.dims()[1];
    // [1, d, C_l] x [N, C_l, h w] -> [N, d, h w]: no permute of the maps.
    let w_l = weight
        .clone()
        .narrow(0, offset, c)
        .transpose()
        .unsqueeze::<3>();
    w_l.matmul(level.clone().reshape([n, c, h * w]))
        .reshape([n, d, h, w])
}

/// The width d of a pyramid reduction's `weight` `[C_img, d]`, checked against the pyramid's
/// `channels` (shared by the tensor and host reductions).
pub(crate) fn check_reduction_weight(
    weight: &Tensor<2>,
    channels: usize,
) -> Result<usize, ShapeError> {
    let [c_total, d] = weight.dims();
    ShapeError::check(
        "feature pyramid reduction `weight` [C_img, d]",
        &[c_total, d],
        &[Some(channels), None],
    )?;
    Ok(d)
}

/// The [out, in] matrix of 1-D bilinear resampling with `align_corners = false` (PyTorch's
/// `F.interpolate(..., mode="bilinear")`): output i reads source `max((i + 0.5) in/out - 0.5, 0)`.
pub fn bilinear_matrix(input: usize, output: usize) -> Vec<f32> {
    let mut m = vec![0.0f32; output * input];
    let scale = input as f32 / output as f32;
    for i in 0..output {
        let src = ((i as f32 + 0.5) * scale - 0.5).max(0.0);
        let i0 = (src.floor() as usize).min(input - 1);
        let i1 = (i0 + 1).min(input - 1);
        let lambda = src - i0 as f32;
        m[i * input + i0] += 1.0 - lambda;
        m[i * input + i1] += lambda;
    }
    m
}

/// Bilinear upsampling as two matrix products (`A_h f A_w^T`), so it is differentiable on every
/// backend (burn-ndarray has no backward for `interpolate`).
///
/// # Shapes
/// - f: [N, C, h, w] -> [N, C, H, W] with `[H, W] = size`
pub fn upsample_bilinear(f: Tensor<4>, size: [usize; 2]) -> Tensor<4> {
    let [n, c, h, w] = f.dims();
    let [oh, ow] = size;
    if (h, w) == (oh, ow) {
        return f;
    }
    let device = f.device();
    let a_w = Tensor::<2>::from_data(TensorData::new(bilinear_matrix(w, ow), [ow, w]), &device);
    let a_h = Tensor::<2>::from_data(TensorData::new(bilinear_matrix(h, oh), [oh, h]), &device);
    // Along W: [N*C*h, w] x [w, W].
    let x = f
        .reshape([n * c * h, w])
        .matmul(a_w.transpose())
        .reshape([n * c, h, ow]);
    // Along H: [N*C, H, h] x [N*C, h, W].
    let a_h = a_h.unsqueeze_dim::<3>(0).expand([n * c, oh, h]);
    a_h.matmul(x).reshape([n, c, oh, ow])
}
