//! The NIA network: features -> body volume -> fields -> blend -> render.
//!
//! Per scene ([`NiaModel::encode_scene`], once): the ResNet-18 feature maps of the N source
//! views, the per-vertex pixel-aligned features (zero where the vertex is invisible), and the
//! sparse-convolution body volume. Per point batch ([`NiaModel::query`]): pixel features l_n
//! and colours c_n at the projections, body features s_n sampled trilinearly, the view-wise
//! cross-attention, F_sigma and F_c0, and the blend. [`NiaModel::render`] puts it together for
//! a batch of rays with stratified samples and volume rendering.

use std::sync::Arc;

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use glam::Vec3;
use nia_data::occupancy::OccupancyGrid;

use crate::attention::ViewCrossAttention;
use crate::blender::{BlendInputs, Blender, ShapeError};
use crate::body_volume::{
    BodyVolume, BodyVolumeError, BodyVolumeGeometry, BodyVolumeNet, VoxelBox,
};
use crate::config::ModelConfig;
use crate::encoder::ImageEncoder;
use crate::encoding::PositionalEncoding;
use crate::heads::{view_mean, ColourHead, DensityHead};
use crate::ibr::{fetch_source_colours, sample_views, PixelFeature};
use crate::query::{projection_grid, PointInputs, PointTensors};
use crate::renderer::{render_rays, stratified_t, RenderError, RenderOutput};
use crate::reposing::Reposer;
use crate::scene::{SceneError, SceneGeometry, SceneInput};
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
    #[error("renderer: {0}")]
    Render(#[from] RenderError),
    #[error("rays: {0}")]
    Rays(String),
    /// Inputs that do not fit together (vertex counts, an encoding without a volume, reposing).
    #[error("{0}")]
    Input(String),
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
    #[module(skip)]
    pub cosine_temperature: f32,
    /// Voxel edge of the body volume, metres.
    #[module(skip)]
    pub voxel_size_m: f32,
    /// Growth of the SMPL bounds for the voxel box.
    #[module(skip)]
    pub box_enlarge: f32,
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
            cosine_temperature: self.cosine_temperature,
            voxel_size_m: self.voxel_size_m,
            box_enlarge: self.box_enlarge,
        }
    }
}

/// Per-scene tensors, computed once and reused by every target view and ray chunk.
#[derive(Debug, Clone)]
pub struct SceneEncoding {
    /// [N, 3, H, W] source images in [0, 1].
    pub images: Tensor<4>,
    /// [N, C_img, H/2, W/2] encoder features.
    pub feature_maps: Tensor<4>,
    /// The body volume and its geometry (`None` for variant (a), which has no body).
    pub volume: Option<(BodyVolumeGeometry, BodyVolume)>,
    /// Empty-space skipping: the occupancy grid of the rendered pose's mesh (world frame).
    /// `None` (the default) evaluates every sample.
    pub occupancy: Option<Arc<OccupancyGrid>>,
}

impl SceneEncoding {
    /// This encoding with empty-space skipping by `grid` (built on the mesh of the pose that
    /// will be rendered: the scene's own for a novel view, the target pose's when reposing).
    pub fn with_occupancy(mut self, grid: Option<Arc<OccupancyGrid>>) -> Self {
        self.occupancy = grid;
        self
    }
}

/// Fields of M points.
#[derive(Debug, Clone)]
pub struct PointOutput {
    /// [M] density sigma, per metre.
    pub sigma: Tensor<1>,
    /// [M, 3] blended colour c.
    pub colour: Tensor<2>,
    /// [M, 3] NeRF colour c0.
    pub c0: Tensor<2>,
    /// [M, N + 1] blend weights (index 0 = c0).
    pub blend_weights: Tensor<2>,
}

/// Rays of a target camera that hit the ray box, clipped to it.
#[derive(Debug, Clone, Default)]
pub struct RayBatch {
    /// [R] world origins.
    pub origins: Vec<Vec3>,
    /// [R] unit world directions.
    pub dirs: Vec<Vec3>,
    /// [R] metres.
    pub near: Vec<f32>,
    /// [R] metres.
    pub far: Vec<f32>,
}

impl RayBatch {
    pub fn len(&self) -> usize {
        self.origins.len()
    }

    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }
}

impl NiaModel {
    /// The per-scene pass: feature maps, vertex features and the body volume.
    ///
    /// The body volume is built on `volume_vertices_smpl` ([V] SMPL frame; the scene's own
    /// vertices for a novel view, the target-pose vertices for animation, with the features of
    /// the scene's vertices of the same index).
    pub fn encode_scene(
        &self,
        input: &SceneInput,
        geometry: &SceneGeometry,
        volume_vertices_smpl: Option<&[[f32; 3]]>,
        device: &Device,
    ) -> Result<SceneEncoding, ModelError> {
        self.encode_scene_timed(input, geometry, volume_vertices_smpl, device, None)
    }

    /// [`NiaModel::encode_scene`], charging the encoder and body-volume stages to `times`.
    pub fn encode_scene_timed(
        &self,
        input: &SceneInput,
        geometry: &SceneGeometry,
        volume_vertices_smpl: Option<&[[f32; 3]]>,
        device: &Device,
        times: Option<&mut StageTimes>,
    ) -> Result<SceneEncoding, ModelError> {
        let mut watch = Stopwatch::new(times, device);
        let n = input.views.len();
        let [h, w] = geometry.image_hw;
        let mut pixels = Vec::with_capacity(n * 3 * h * w);
        for view in &input.views {
            pixels.extend_from_slice(&view.image);
        }
        let images = Tensor::<4>::from_data(TensorData::new(pixels, [n, 3, h, w]), device);
        let feature_maps = self.encoder.forward(images.clone());
        watch.mark(Stage::Encoder);
        let volume = self.body_volume_of(&feature_maps, geometry, volume_vertices_smpl, device)?;
        if volume.is_some() {
            watch.mark(Stage::BodyVolume);
        }
        Ok(SceneEncoding {
            images,
            feature_maps,
            volume,
            occupancy: None,
        })
    }

    /// The same scene's encoding with the body volume rebuilt on other vertices
    /// (`volume_vertices_smpl`, [V] SMPL frame: a new target pose), reusing the source images'
    /// feature maps: per-pose work only, for animating one scene through many poses.
    pub fn encode_pose_timed(
        &self,
        scene: &SceneEncoding,
        geometry: &SceneGeometry,
        volume_vertices_smpl: &[[f32; 3]],
        device: &Device,
        times: Option<&mut StageTimes>,
    ) -> Result<SceneEncoding, ModelError> {
        let mut watch = Stopwatch::new(times, device);
        let volume = self.body_volume_of(
            &scene.feature_maps,
            geometry,
            Some(volume_vertices_smpl),
            device,
        )?;
        if volume.is_some() {
            watch.mark(Stage::BodyVolume);
        }
        Ok(SceneEncoding {
            images: scene.images.clone(),
            feature_maps: scene.feature_maps.clone(),
            volume,
            occupancy: None,
        })
    }

    /// Vertex features from the feature maps and the sparse-convolution body volume built on
    /// `volume_vertices_smpl` (default: the scene's own vertices); `None` for variant (a).
    fn body_volume_of(
        &self,
        feature_maps: &Tensor<4>,
        geometry: &SceneGeometry,
        volume_vertices_smpl: Option<&[[f32; 3]]>,
        device: &Device,
    ) -> Result<Option<(BodyVolumeGeometry, BodyVolume)>, ModelError> {
        if !self.variant.uses_body() {
            return Ok(None);
        }
        let n = feature_maps.dims()[0];
        let v = geometry.vertices_world.len();
        // Vertex projections: the same projection rule as the query points.
        let grid = projection_grid(geometry, &geometry.vertices_world);
        let grid = Tensor::<3>::from_data(TensorData::new(grid, [n, v, 2]), device);
        let raw = sample_views(feature_maps.clone(), grid)?; // [N, V, C_img]
        let vis: Vec<f32> = geometry
            .vertex_visibility
            .iter()
            .flatten()
            .copied()
            .collect();
        let vis = Tensor::<3>::from_data(TensorData::new(vis, [n, v, 1]), device);
        // Zero where the vertex is invisible in that view (after the bias).
        let vertex_features = self.vertex_reduce.forward(raw) * vis;
        let at = volume_vertices_smpl.unwrap_or(&geometry.vertices_smpl);
        if at.len() != v {
            return Err(ModelError::Input(format!(
                "volume vertices: expected {v} (one per scene vertex), got {}",
                at.len()
            )));
        }
        let voxel_box = match volume_vertices_smpl {
            Some(at) => VoxelBox::enclosing(at, self.box_enlarge, self.voxel_size_m)?,
            None => geometry.voxel_box,
        };
        let vg = BodyVolumeGeometry::build(at, &voxel_box, device)?;
        let volume = self.body_volume.forward(&vg, vertex_features)?;
        Ok(Some((vg, volume)))
    }

    /// The fields of M points.
    pub fn query(
        &self,
        scene: &SceneEncoding,
        points: &PointTensors,
    ) -> Result<PointOutput, ModelError> {
        let device = scene.images.device();
        self.query_timed(scene, points, &mut Stopwatch::new(None, &device))
    }

    fn query_timed(
        &self,
        scene: &SceneEncoding,
        points: &PointTensors,
        watch: &mut Stopwatch<'_>,
    ) -> Result<PointOutput, ModelError> {
        let l = self
            .pixel_feature
            .forward(scene.feature_maps.clone(), points.proj_grid.clone())?; // [N, M, d]
        let source_colours = fetch_source_colours(scene.images.clone(), points.proj_grid.clone())?; // [N, M, 3]
        let body = match (&scene.volume, self.variant.uses_body()) {
            (Some((_, volume)), true) => Some(volume.sample(&points.corners)?),
            _ => None,
        };
        watch.mark(Stage::Sampling);
        let z = match (body, self.variant.uses_body()) {
            (Some(body), true) => {
                let s = self.body_reduce.forward(body); // [N, M, d]
                self.attention
                    .forward(s.swap_dims(0, 1), l.clone().swap_dims(0, 1))? // [M, N, d]
            }
            (None, true) => {
                return Err(ModelError::Input(
                    "the scene was encoded without a body volume".into(),
                ))
            }
            (_, false) => l.clone().swap_dims(0, 1),
        };
        let mean_z = view_mean(z); // [M, d]
        let sigma = self.density.forward(mean_z.clone())?;
        let gamma = self.direction_encoding.forward(points.dirs.clone())?;
        let heads = self.colour.forward(mean_z, gamma)?;
        let c0 = heads.c0.clone();
        watch.mark(Stage::Mlps);
        let blended = self.blender.colour(
            self.variant,
            BlendInputs {
                c0: heads.c0,
                confidence: heads.confidence,
                h: heads.h,
                source_colours,
                pixel_feature: l,
                view_dir_features: points.view_dir_features.clone(),
                visibility: points.visibility.clone(),
            },
            self.cosine_temperature,
        )?;
        watch.mark(Stage::Blending);
        Ok(PointOutput {
            sigma,
            colour: blended.colour,
            c0,
            blend_weights: blended.blend_weights,
        })
    }

    /// Renders `rays` with `samples` stratified samples each. `jitter` ([R * S] in [0, 1]) is
    /// the training-time offset inside each bin; `None` samples bin centres.
    pub fn render(
        &self,
        scene: &SceneEncoding,
        geometry: &SceneGeometry,
        rays: &RayBatch,
        samples: usize,
        jitter: Option<&[f32]>,
        device: &Device,
    ) -> Result<RenderOutput, ModelError> {
        self.render_timed(scene, geometry, rays, samples, jitter, device, None)
    }

    /// [`NiaModel::render`], charging sampling, MLPs, blending and compositing to `times`.
    #[allow(clippy::too_many_arguments)]
    pub fn render_timed(
        &self,
        scene: &SceneEncoding,
        geometry: &SceneGeometry,
        rays: &RayBatch,
        samples: usize,
        jitter: Option<&[f32]>,
        device: &Device,
        times: Option<&mut StageTimes>,
    ) -> Result<RenderOutput, ModelError> {
        self.render_posed(
            scene,
            geometry,
            rays,
            samples,
            jitter,
            device,
            times,
            QueryPose::Scene,
        )
    }

    /// Renders `rays` of a target camera with the body in another pose (pose animation,
    /// DESIGN step 9): `reposer` maps query points and directions from the target pose to the
    /// scene's (reference) pose; `scene` must have been encoded with its body volume on the
    /// target-pose vertices (`volume_vertices_smpl` of [`NiaModel::encode_scene`]:
    /// [`Reposer::target_vertices_smpl`]). When the target pose equals the
    /// reference pose this is exactly [`NiaModel::render`]: no deformation work at all.
    #[allow(clippy::too_many_arguments)]
    pub fn render_reposed(
        &self,
        scene: &SceneEncoding,
        geometry: &SceneGeometry,
        reposer: &Reposer,
        rays: &RayBatch,
        samples: usize,
        jitter: Option<&[f32]>,
        device: &Device,
        times: Option<&mut StageTimes>,
    ) -> Result<RenderOutput, ModelError> {
        let pose = if reposer.is_identity() {
            QueryPose::Scene
        } else {
            QueryPose::Reposed(reposer)
        };
        self.render_posed(scene, geometry, rays, samples, jitter, device, times, pose)
    }

    #[allow(clippy::too_many_arguments)]
    fn render_posed(
        &self,
        scene: &SceneEncoding,
        geometry: &SceneGeometry,
        rays: &RayBatch,
        samples: usize,
        jitter: Option<&[f32]>,
        device: &Device,
        times: Option<&mut StageTimes>,
        pose: QueryPose<'_>,
    ) -> Result<RenderOutput, ModelError> {
        let mut watch = Stopwatch::new(times, device);
        let r = rays.len();
        if r == 0 || rays.dirs.len() != r || rays.near.len() != r || rays.far.len() != r {
            return Err(ModelError::Rays(format!(
                "expected a non-empty batch with equal lengths, got origins {r}, dirs {}, near {}, far {}",
                rays.dirs.len(),
                rays.near.len(),
                rays.far.len()
            )));
        }
        let t = stratified_t(&rays.near, &rays.far, samples, jitter)?;
        let (points, dirs) = sample_points(rays, &t, samples);
        let total = points.len();
        // Empty-space skipping: only samples in occupied cells reach the network (and, when
        // reposing, the reposing transform); the others keep zero density.
        let kept: Option<Vec<usize>> = scene.occupancy.as_ref().and_then(|grid| {
            let kept: Vec<usize> = (0..total).filter(|&i| grid.occupied(points[i])).collect();
            (kept.len() < total).then_some(kept)
        });
        let (points, dirs) = match &kept {
            Some(k) => (
                k.iter().map(|&i| points[i]).collect(),
                k.iter().map(|&i| dirs[i]).collect(),
            ),
            None => (points, dirs),
        };
        let evaluated = points.len();
        let (sigma, colour, c0, blend) = if evaluated == 0 {
            let n1 = scene.images.dims()[0] + 1;
            (
                Tensor::<1>::zeros([total], device),
                Tensor::<2>::zeros([total, 3], device),
                Tensor::<2>::zeros([total, 3], device),
                Tensor::<2>::zeros([total, n1], device),
            )
        } else {
            let out =
                self.query_points(scene, geometry, &points, &dirs, pose, device, &mut watch)?;
            match &kept {
                None => (out.sigma, out.colour, out.c0, out.blend_weights),
                Some(k) => {
                    let index: Vec<i64> = k.iter().map(|&i| i as i64).collect();
                    let index =
                        Tensor::<1, Int>::from_data(TensorData::new(index, [evaluated]), device);
                    let n1 = out.blend_weights.dims()[1];
                    let scatter1 = |values: Tensor<1>| {
                        Tensor::<1>::zeros([total], device).select_assign(
                            0,
                            index.clone(),
                            values,
                            IndexingUpdateOp::Add,
                        )
                    };
                    let scatter2 = |values: Tensor<2>, width: usize| {
                        Tensor::<2>::zeros([total, width], device).select_assign(
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
                    )
                }
            }
        };
        let n1 = blend.dims()[1];
        let t = Tensor::<2>::from_data(TensorData::new(t, [r, samples]), device);
        let far = Tensor::<1>::from_data(TensorData::new(rays.far.clone(), [r]), device);
        let mut rendered = render_rays(
            sigma.reshape([r, samples]),
            colour.reshape([r, samples, 3]),
            c0.reshape([r, samples, 3]),
            t,
            far,
            Some(blend.reshape([r, samples, n1])),
        )?;
        rendered.point_evaluations = evaluated;
        watch.mark(Stage::Compositing);
        Ok(rendered)
    }
}

impl NiaModel {
    /// The fields at `points` / `dirs` ([M] world, in the rendered pose): the query inputs
    /// (reposed into the scene's pose first when `pose` says so) and the network.
    #[allow(clippy::too_many_arguments)]
    fn query_points(
        &self,
        scene: &SceneEncoding,
        geometry: &SceneGeometry,
        points: &[Vec3],
        dirs: &[Vec3],
        pose: QueryPose<'_>,
        device: &Device,
        watch: &mut Stopwatch<'_>,
    ) -> Result<PointOutput, ModelError> {
        let inputs = match pose {
            QueryPose::Scene => {
                let volume_points: Option<Vec<[f32; 3]>> = scene
                    .volume
                    .as_ref()
                    .map(|_| points.iter().map(|&p| geometry.to_smpl(p)).collect());
                let volume = match (&scene.volume, &volume_points) {
                    (Some((vg, _)), Some(vp)) => Some((vg, vp.as_slice())),
                    _ => None,
                };
                PointInputs::compute(geometry, points, dirs, volume)
            }
            QueryPose::Reposed(reposer) => {
                // The body volume lives in the target pose (SMPL frame of the target); pixel
                // features, colours and visibility are read at x' in the reference views.
                let volume_points: Vec<[f32; 3]> = points
                    .iter()
                    .map(|&p| reposer.target_to_smpl(p).to_array())
                    .collect();
                let mapped = reposer
                    .map_points(points, dirs)
                    .map_err(|e| ModelError::Input(format!("reposing: {e}")))?;
                let volume = scene
                    .volume
                    .as_ref()
                    .map(|(vg, _)| (vg, volume_points.as_slice()));
                PointInputs::compute(geometry, &mapped.points, &mapped.dirs, volume)
            }
        }
        .to_tensors(device);
        self.query_timed(scene, &inputs, watch)
    }
}

/// Where the query points are evaluated.
enum QueryPose<'a> {
    /// In the scene's own pose (novel view): no reposing work.
    Scene,
    /// In a target pose mapped to the scene's pose by `reposer`.
    Reposed(&'a Reposer),
}

/// Sample points `o + t d` and their directions, ray-major.
///
/// # Shapes
/// - t: [R * S]; outputs [R * S]
fn sample_points(rays: &RayBatch, t: &[f32], samples: usize) -> (Vec<Vec3>, Vec<Vec3>) {
    let mut points = Vec::with_capacity(t.len());
    let mut dirs = Vec::with_capacity(t.len());
    for (i, (o, d)) in rays.origins.iter().zip(&rays.dirs).enumerate() {
        for s in 0..samples {
            points.push(*o + *d * t[i * samples + s]);
            dirs.push(*d);
        }
    }
    (points, dirs)
}
