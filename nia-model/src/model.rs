//! `NiaModel`: the NIA network's module tree, built from a [`ModelConfig`]. Its forward pass is
//! written by stage, each in its own folder:
//!
//! ```text
//! NiaModel::encode (once per scene)   -> SceneEncoding        scene_encoding/encode.rs
//! NiaModel::render (per batch of rays):                        renderer/forward.rs
//!     sampler   RaySamples::new        stratified t, occupancy-aware       sampler/
//!     field     NiaModel::field        sigma, c0, blend weights, c         field/query.rs
//!     renderer  render_rays_delta      NeRF quadrature                     renderer/quadrature.rs
//! ```
//!
//! Timing is an observer: every stage method takes `Option<&mut StageTimes>` and charges its
//! stages there when given (synchronising the device), and does nothing extra otherwise.

use burn::module::{ModuleVisitor, Param};
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use nia_data::geometry::sparse::VoxelGridSpec;

use crate::body_volume::BodyVolumeNet;
use crate::config::ModelConfig;
use crate::config::SourceColoursAt;
use crate::encoder::ImageEncoder;
use crate::field::attention::ViewCrossAttention;
use crate::field::heads::{ColourHead, DensityHead};
use crate::field::positional_encoding::PositionalEncoding;
use crate::ibr::blender::Blender;
use crate::ibr::PixelFeature;
use crate::sampler::RaySampler;
use crate::variant::Variant;

/// The NIA network.
#[derive(Module, Debug)]
pub struct NiaModel {
    /// ResNet-18 trunk -> [N, C_img, H/2, W/2].
    pub encoder: ImageEncoder,
    /// Per-vertex feature reduction C_img -> C_v before the body volume.
    pub vertex_reduce: Linear,
    /// Sparse-convolution body volume.
    pub body_volume: BodyVolumeNet,
    /// Body feature s_n reduction sum_s C_s -> d.
    pub body_reduce: Linear,
    /// Pixel-aligned feature l_n (= p_n): grid sample + C_img -> d.
    pub pixel_feature: PixelFeature,
    /// View-wise cross-attention.
    pub attention: ViewCrossAttention,
    /// gamma(d).
    pub direction_encoding: PositionalEncoding,
    /// F_sigma.
    pub density: DensityHead,
    /// F_c0.
    pub colour: ColourHead,
    /// F_B.
    pub blender: Blender,
    #[module(skip)]
    pub variant: Variant,
    /// Voxel edge of the body volume, metres.
    #[module(skip)]
    pub voxel_size_m: f32,
    /// Growth of the SMPL bounds for the voxel box.
    #[module(skip)]
    pub box_enlarge: f32,
    /// How rays are sampled.
    #[module(skip)]
    pub ray_sampler: RaySampler,
    /// Where the source colours are read.
    #[module(skip)]
    pub source_colours_at: SourceColoursAt,
}

impl ModelConfig {
    /// A freshly initialised network on `device` (use an autodiff device for training).
    ///
    /// Every parameter is drawn here, on the calling thread: burn 0.22 initialises parameters
    /// lazily, from the random stream of whichever thread reads them first, so a model
    /// first used on worker threads (one per device in data-parallel training) would
    /// otherwise start from other weights than the same seed gives on one thread.
    pub fn init(&self, device: &Device) -> NiaModel {
        let model = self.init_lazily(device);
        model.visit(&mut DrawParameters);
        model
    }

    fn init_lazily(&self, device: &Device) -> NiaModel {
        let c_img = self.image_channels();
        NiaModel {
            encoder: self.encoder().init(device),
            vertex_reduce: LinearConfig::new(c_img, self.body_volume.vertex_channels).init(device),
            body_volume: self.body_volume.init(device),
            body_reduce: LinearConfig::new(self.body_volume.output_channels(), self.d_model)
                .init(device),
            pixel_feature: self.pixel_feature().init(device),
            attention: self.attention().init(device),
            direction_encoding: self.direction_encoding().init(device),
            density: self.density().init(device),
            colour: self.colour().init(device),
            blender: self.blender().init(device),
            variant: self.variant,
            voxel_size_m: self.voxel_size_m,
            box_enlarge: self.box_enlarge,
            ray_sampler: self.ray_sampler,
            source_colours_at: self.source_colours_at.unwrap_or_default(),
        }
    }
}

/// Reads every float parameter once, which draws the ones still uninitialised.
struct DrawParameters;

impl ModuleVisitor for DrawParameters {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let _ = param.val();
    }
}

impl NiaModel {
    /// The body volume's voxel grid.
    pub fn voxel_grid(&self) -> VoxelGridSpec {
        VoxelGridSpec {
            voxel_size_m: self.voxel_size_m,
            box_enlarge: self.box_enlarge,
        }
    }
}
