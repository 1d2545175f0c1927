//! The NIA network and its forward pass, which reads like any NeRF pipeline:
//!
//! ```text
//! NiaModel::encode (once per scene)        -> SceneEncoding     (scene_encoding.rs)
//! NiaModel::render (per batch of rays):
//!     sampler   RaySamples::new            stratified t, occupancy-aware   (sampler.rs)
//!     field     NiaModel::field            sigma, c0, blend weights, c     (field/)
//!     renderer  render_rays                NeRF quadrature                 (renderer.rs)
//! ```
//!
//! Timing is an observer: every stage method takes `Option<&mut StageTimes>` and charges its
//! stages there when given (synchronising the device), and does nothing extra otherwise.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use nia_data::geometry::rays::RayBundle;
use nia_data::geometry::sparse::{SparseGridError, VoxelGridSpec};
use nia_data::scene::SceneError;

use crate::config::ModelConfig;
use crate::field::attention::ViewCrossAttention;
use crate::field::blender::Blender;
use crate::field::body_volume::{BodyVolumeError, BodyVolumeNet};
use crate::field::encoder::ImageEncoder;
use crate::field::heads::{ColourHead, DensityHead};
use crate::field::ibr::PixelFeature;
use crate::field::positional_encoding::PositionalEncoding;
use crate::renderer::{render_rays_delta, RenderOutput};
use crate::sampler::{RaySampler, RaySamples, SamplerError};
use crate::scene_encoding::SceneEncoding;
use crate::shape::ShapeError;
use crate::surface_ibr::{surface_colours, surface_composite, SourceColoursAt};
use crate::timing::{Stage, StageTimes, Stopwatch};
use crate::variant::Variant;

/// Errors of a forward pass, naming the stage.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error("body volume: {0}")]
    Volume(#[from] BodyVolumeError),
    #[error("{0}")]
    Shape(#[from] ShapeError),
    #[error("sampler: {0}")]
    Sampler(#[from] SamplerError),
    #[error("rays: {0}")]
    Rays(String),
    /// The band sampler's occupancy grid could not be built.
    #[error("band sampler: {0}")]
    Band(#[from] nia_data::geometry::occupancy::OccupancyError),
    /// Inputs that do not fit together (vertex counts, an encoding without a volume, reposing).
    #[error("{0}")]
    Input(String),
}

impl From<SparseGridError> for ModelError {
    fn from(e: SparseGridError) -> Self {
        ModelError::Volume(e.into())
    }
}

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
    /// Tolerance of o_n's depth test, metres (`None`: the paper's o_n).
    #[module(skip)]
    pub visibility_depth_tol_m: Option<f32>,
}

impl ModelConfig {
    /// A freshly initialised network on `device` (use an autodiff device for training).
    pub fn init(&self, device: &Device) -> NiaModel {
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
            visibility_depth_tol_m: self.visibility_depth_tol_m,
        }
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

    /// Renders `rays` of `scene` with `samples` stratified samples each: sampler -> field ->
    /// renderer. `jitter` ([R * S] in [0, 1]) is the training-time offset inside each bin;
    /// `None` samples bin centres. Samples the occupancy grid of `scene` marks empty keep zero
    /// density without reaching the field, and so do, without jitter, the samples behind what
    /// a ray has made opaque when `scene` terminates rays early (`termination`). With
    /// `source_colours_at = surface` the source views' part of the colour is read once per ray
    /// at the expected surface point (`surface_ibr`).
    /// `times` charges sampling, MLPs, blending and compositing.
    pub fn render(
        &self,
        scene: &SceneEncoding,
        rays: &RayBundle,
        samples: usize,
        jitter: Option<&[f32]>,
        times: Option<&mut StageTimes>,
    ) -> Result<RenderOutput, ModelError> {
        let device = scene.images.device();
        let mut watch = Stopwatch::new(times, &device);
        rays.check().map_err(ModelError::Rays)?;
        let r = rays.len();
        let mut ray_samples = match &scene.band {
            Some(band) => {
                RaySamples::in_band(rays, samples, jitter, band, scene.occupancy.as_deref())?
            }
            None => RaySamples::new(rays, samples, jitter, scene.occupancy.as_deref())?,
        };
        // With empty-space skipping, what the visual hull carves is empty space too: its
        // density is exactly 0 whatever the network says, so it is not evaluated. (A reposed
        // scene reads the hull at the mapped points, inside the field; nothing is skipped.) The
        // kept points read it once more in the field (three projections and bilinear reads
        // each, next to a network evaluation).
        if let (Some(_), Some(hull), None) = (&scene.occupancy, &scene.visual_hull, &scene.reposer)
        {
            let cameras = &scene.geometry.cameras;
            ray_samples.retain(|x| hull.carving(cameras, x) > 0.0);
        }
        let total = ray_samples.total();
        let mut evaluated = ray_samples.evaluated();
        let mut colour_evaluated = evaluated;
        let n1 = scene.num_views() + 1;
        let (sigma, colour, c0, blend, ibr, blend_c0) = if ray_samples.evaluated() == 0 {
            (
                Tensor::<1>::zeros([total], &device),
                Tensor::<2>::zeros([total, 3], &device),
                Tensor::<2>::zeros([total, 3], &device),
                Tensor::<2>::zeros([total, n1], &device),
                Tensor::<2>::zeros([total, 3], &device),
                None,
            )
        } else {
            // Early ray termination (inference: no jitter) evaluates front to back and skips
            // what the front has hidden; otherwise every kept sample in one call.
            let adaptive = scene.termination.is_some() || scene.colour_culling.is_some();
            let (out, kept) = match (adaptive, jitter) {
                (true, None) => {
                    let (out, index, coloured) = self.field_front_to_back(
                        scene,
                        &ray_samples,
                        scene.termination,
                        scene.colour_culling,
                        &mut watch,
                    )?;
                    evaluated = index.len();
                    colour_evaluated = coloured;
                    let all_in_order =
                        index.len() == total && index.iter().enumerate().all(|(i, &f)| i == f);
                    (out, (!all_in_order).then_some(index))
                }
                _ => (
                    self.field_with(scene, &ray_samples.points, &ray_samples.dirs, &mut watch)?,
                    ray_samples.kept.clone(),
                ),
            };
            match &kept {
                None => (
                    out.sigma,
                    out.colour,
                    out.c0,
                    out.blend_weights,
                    out.ibr_colour,
                    out.blend_c0,
                ),
                // Skipped samples keep zero density (and zero colour and weights).
                Some(kept) => {
                    let index: Vec<i64> = kept.iter().map(|&i| i as i64).collect();
                    let index =
                        Tensor::<1, Int>::from_data(TensorData::new(index, [kept.len()]), &device);
                    let scatter1 = |values: Tensor<1>| {
                        Tensor::<1>::zeros([total], &device).select_assign(
                            0,
                            index.clone(),
                            values,
                            IndexingUpdateOp::Add,
                        )
                    };
                    let scatter2 = |values: Tensor<2>, width: usize| {
                        Tensor::<2>::zeros([total, width], &device).select_assign(
                            0,
                            index.clone(),
                            values,
                            IndexingUpdateOp::Add,
                        )
                    };
                    (
                        scatter1(out.sigma),
                        scatter2(out.colour, 3),
                        scatter2(out.c0, 3),
                        scatter2(out.blend_weights, n1),
                        scatter2(out.ibr_colour, 3),
                        out.blend_c0.map(|c| scatter2(c, 3)),
                    )
                }
            }
        };
        // The NeRF part of the colour, kept for the surface form (sum_i w_i b0_i c0_i).
        let surface = self.source_colours_at == SourceColoursAt::Surface
            && self.variant != Variant::NoIbr
            && ray_samples.evaluated() > 0;
        // With c0 shuffling (training) the part is made of the c0 that F_B blended.
        let nerf_colour = surface
            .then(|| blend.clone().slice(s![.., 0..1]) * blend_c0.unwrap_or_else(|| c0.clone()));
        let t = Tensor::<2>::from_data(
            TensorData::new(ray_samples.t.clone(), [r, samples]),
            &device,
        );
        let delta = Tensor::<2>::from_data(
            TensorData::new(ray_samples.delta.clone(), [r, samples]),
            &device,
        );
        let mut rendered = render_rays_delta(
            sigma.reshape([r, samples]),
            colour.reshape([r, samples, 3]),
            c0.reshape([r, samples, 3]),
            t,
            delta,
            Some(blend.reshape([r, samples, n1])),
        )?;
        // sum_i w_i x_i of a per-sample colour [R * S, 3] -> [R, 3].
        let composite = |x: Tensor<2>| {
            (x.reshape([r, samples, 3]) * rendered.weights.clone().reshape([r, samples, 1]))
                .sum_dim(1)
                .reshape([r, 3])
        };
        match nerf_colour {
            None => rendered.rgb_ibr = Some(composite(ibr)),
            Some(nerf_colour) => {
                let nerf_part = composite(nerf_colour);
                let view_weights = rendered
                    .blend_weights
                    .clone()
                    .map(|b| b.slice(s![.., 1..n1]))
                    .ok_or_else(|| ModelError::Input("render without blend weights".into()))?;
                let colours =
                    surface_colours(scene, rays, rendered.depth.clone(), rendered.acc.clone())?;
                let (rgb, rgb_ibr) =
                    surface_composite(nerf_part, view_weights, colours, rendered.acc.clone());
                rendered.rgb = rgb;
                rendered.rgb_ibr = Some(rgb_ibr);
            }
        }
        rendered.point_evaluations = evaluated;
        rendered.colour_evaluations = colour_evaluated;
        watch.mark(Stage::Compositing);
        Ok(rendered)
    }
}
