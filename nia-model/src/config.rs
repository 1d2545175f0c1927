//! `ModelConfig`: every size and switch of the NIA network, with the paper's defaults.

use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::body_volume::BodyVolumeNetConfig;
use crate::encoder::ImageEncoderConfig;
use crate::field::attention::ViewCrossAttentionConfig;
use crate::field::heads::{ColourHeadConfig, DensityHeadConfig};
use crate::field::positional_encoding::PositionalEncodingConfig;
use crate::ibr::blender::BlenderConfig;
use crate::ibr::PixelFeatureConfig;
use crate::sampler::RaySampler;
use crate::variant::Variant;

/// The whole network. `ModelConfig::new()` is the paper setting.
#[derive(Config, Debug, PartialEq)]
pub struct ModelConfig {
    /// Ablation variant (paper Table 3.i): `no_body`, `no_ibr`, `simple_average`,
    /// `cosine_weighted`, `full`.
    #[config(default = "Variant::Full")]
    pub variant: Variant,
    /// ResNet-18 width (64 in the paper; smaller for quick CPU runs). The pixel-aligned feature
    /// map has `8 * encoder_width` channels.
    #[config(default = 64)]
    pub encoder_width: usize,
    /// Reduced feature width d of S, L, Z and p_n.
    #[config(default = 128)]
    pub d_model: usize,
    /// Hidden width of F_sigma and F_c0 (and of h).
    #[config(default = 256)]
    pub d_hidden: usize,
    /// Hidden width of the blender F_B.
    #[config(default = 128)]
    pub d_blend: usize,
    /// Frequencies L of the view-direction encoding gamma(d).
    #[config(default = 4)]
    pub dir_frequencies: usize,
    /// The sparse-convolution body volume.
    #[config(default = "BodyVolumeNetConfig::new()")]
    pub body_volume: BodyVolumeNetConfig,
    /// Voxel edge of the body volume, metres (5 mm in the paper).
    #[config(default = 0.005)]
    pub voxel_size_m: f32,
    /// The voxel box is the SMPL bounds grown by this fraction (2.5 % in the paper).
    #[config(default = 0.025)]
    pub box_enlarge: f32,
    /// How rays are sampled (stratified over the box, as in the paper, or in the SMPL band).
    #[config(default = "RaySampler::Stratified")]
    pub ray_sampler: RaySampler,
    /// F_B's tokens carry colours and across-view statistics (not in the paper; see
    /// `field::blender`).
    #[config(default = false)]
    pub blend_view_statistics: bool,
    /// Where the source colours c_n are read: at every sample (the paper; also `None`, which
    /// model files and checkpoints written before this switch carry) or once per ray at the
    /// expected surface point (not in the paper; see `ibr::surface`).
    pub source_colours_at: Option<SourceColoursAt>,
    /// F_B reads the pixel features p_n and F_c0's hidden feature h (the paper; `None`, also
    /// what older model files carry, is on). Off, its tokens and per-point part hold only what
    /// is not the person's texture: view directions, visibility, confidence and (with view
    /// statistics) the colours and their across-view statistics (not in the paper; see
    /// `ibr::blender`).
    pub blend_reads_features: Option<bool>,
}

/// Where the source colours c_n are read (`ibr::surface`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SourceColoursAt {
    /// At every sample's projection (the paper).
    #[default]
    Samples,
    /// Once per ray, at the projection of the expected surface point.
    Surface,
}

/// Largest layer width [`ModelConfig::check`] accepts (the paper's widest is 512 channels).
const MAX_WIDTH: usize = 1 << 14;

impl ModelConfig {
    /// Checks that the config describes a buildable network: every width in 1..=16384, at
    /// least one convolution per stage where one is required, and finite positive voxel size,
    /// and box growth. Model files are checked with it before any allocation.
    pub fn check(&self) -> Result<(), String> {
        let bv = &self.body_volume;
        let widths = [
            ("encoder_width", self.encoder_width),
            ("d_model", self.d_model),
            ("d_hidden", self.d_hidden),
            ("d_blend", self.d_blend),
            ("body_volume.vertex_channels", bv.vertex_channels),
            ("body_volume.full_channels", bv.full_channels),
        ]
        .into_iter()
        .chain(
            bv.scale_channels
                .iter()
                .map(|&c| ("body_volume.scale_channels", c)),
        );
        for (name, value) in widths {
            if value == 0 || value > MAX_WIDTH {
                return Err(format!("`{name}` = {value}, expected 1..={MAX_WIDTH}"));
            }
        }
        if self.dir_frequencies > 32 {
            return Err(format!(
                "`dir_frequencies` = {}, expected at most 32",
                self.dir_frequencies
            ));
        }
        if bv.full_convs > 64 || bv.scale_convs.iter().any(|&n| n > 64) {
            return Err("`body_volume` convolution counts must be at most 64".into());
        }
        if !(self.voxel_size_m.is_finite() && self.voxel_size_m > 0.0) {
            return Err(format!(
                "`voxel_size_m` = {}, expected a finite value > 0",
                self.voxel_size_m
            ));
        }
        if !(self.box_enlarge.is_finite() && self.box_enlarge >= 0.0) {
            return Err(format!(
                "`box_enlarge` = {}, expected a finite value >= 0",
                self.box_enlarge
            ));
        }
        self.ray_sampler.check()?;
        if !(bv.norm_epsilon.is_finite() && bv.norm_epsilon > 0.0) {
            return Err(format!(
                "`body_volume.norm_epsilon` = {}, expected a finite value > 0",
                bv.norm_epsilon
            ));
        }
        Ok(())
    }

    /// Channels of the encoder's feature map.
    pub fn image_channels(&self) -> usize {
        ImageEncoderConfig::new()
            .with_base_width(self.encoder_width)
            .out_channels()
    }

    pub(crate) fn encoder(&self) -> ImageEncoderConfig {
        ImageEncoderConfig::new().with_base_width(self.encoder_width)
    }

    pub(crate) fn pixel_feature(&self) -> PixelFeatureConfig {
        PixelFeatureConfig::new()
            .with_d_image(self.image_channels())
            .with_d_model(self.d_model)
    }

    pub(crate) fn attention(&self) -> ViewCrossAttentionConfig {
        ViewCrossAttentionConfig::new().with_d_model(self.d_model)
    }

    pub(crate) fn direction_encoding(&self) -> PositionalEncodingConfig {
        PositionalEncodingConfig::new().with_num_frequencies(self.dir_frequencies)
    }

    pub(crate) fn density(&self) -> DensityHeadConfig {
        DensityHeadConfig::new()
            .with_d_input(self.d_model)
            .with_d_hidden(self.d_hidden)
    }

    pub(crate) fn colour(&self) -> ColourHeadConfig {
        let pe = self.direction_encoding();
        let d_direction = 3 * (pe.include_input as usize + 2 * pe.num_frequencies);
        ColourHeadConfig::new()
            .with_d_input(self.d_model)
            .with_d_direction(d_direction)
            .with_d_hidden(self.d_hidden)
    }

    pub(crate) fn blender(&self) -> BlenderConfig {
        BlenderConfig::new()
            .with_d_pixel(self.d_model)
            .with_d_h(self.d_hidden)
            .with_d_hidden(self.d_blend)
            .with_view_statistics(self.blend_view_statistics)
            .with_reads_features(self.blend_reads_features.unwrap_or(true))
    }

    /// A small network for tests and quick CPU runs (same structure, narrow layers).
    pub fn tiny() -> Self {
        ModelConfig::new()
            .with_encoder_width(8)
            .with_d_model(16)
            .with_d_hidden(32)
            .with_d_blend(16)
            .with_body_volume(
                BodyVolumeNetConfig::new()
                    .with_vertex_channels(8)
                    .with_full_channels(8)
                    .with_full_convs(1)
                    .with_scale_channels([8, 8, 16, 16])
                    .with_scale_convs([1, 1, 1, 1]),
            )
            .with_voxel_size_m(0.02)
    }
}
