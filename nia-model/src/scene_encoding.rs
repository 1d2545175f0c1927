//! The per-scene pass, done once and reused by every target view and ray chunk: the scene's
//! CPU geometry, the ResNet-18 feature maps of the N source views (reduced to the widths their
//! consumers read), the per-vertex pixel-aligned features (zero where the vertex is invisible)
//! and the sparse-convolution body volume. For pose animation the body volume is built on the
//! target pose's vertices and the encoding carries the [`Reposer`] that maps query points back
//! to the scene's pose.

use std::sync::Arc;

use burn::prelude::*;
use nia_data::body::reposing::Reposer;
use nia_data::geometry::occupancy::OccupancyGrid;
use nia_data::scene::{projection_grid, SceneError, SceneGeometry, SceneInput, VisualHull};

use crate::c0_shuffle::C0Shuffle;
use crate::device::is_host;
use crate::field::bilinear::ViewRows;
use crate::field::body_volume::{BodyVolume, BodyVolumeGeometry, HostVolume};
use crate::field::encoder_host::HostTrunk;
use crate::field::ibr::sample_rows_through;
use crate::field::pyramid_host::reduce_to_rows;
use crate::model::{ModelError, NiaModel};
use crate::timing::{Stage, StageTimes, Stopwatch};

/// Per-scene tensors and geometry.
#[derive(Debug, Clone)]
pub struct SceneEncoding {
    /// The scene's CPU geometry (cameras, SMPL frame, ray box, surface index, visibility).
    pub geometry: Arc<SceneGeometry>,
    /// [N, 3, H, W] source images in [0, 1].
    pub images: Tensor<4>,
    /// The source images laid out as rows once, for the colour reads c_n of every ray chunk.
    pub image_rows: ViewRows,
    /// [N, C_v, H/2, W/2] the encoder's feature maps through the vertex reduction's weights
    /// (`W_v^T F`, without the bias), laid out as rows: what the body volume's vertex features
    /// sample, kept for rebuilding the volume in other poses.
    pub vertex_rows: ViewRows,
    /// [N, d, H/2, W/2] the feature maps through the pixel-feature reduction's weights
    /// (`PixelFeature::reduce_maps`), laid out as rows once and sampled per point.
    pub pixel_rows: ViewRows,
    /// The body volume and its geometry (`None` for variant (a), which has no body).
    pub volume: Option<(BodyVolumeGeometry, BodyVolume)>,
    /// A host copy of the body volume's site features for the fused CPU read
    /// ([`HostVolume`], inference on the CPU backends); `None` reads with tensor operations.
    pub host_volume: Option<Arc<HostVolume>>,
    /// Pose animation: maps query points of the rendered (target) pose to the scene's pose.
    /// `None` renders the scene's own pose, with no reposing work at all.
    pub reposer: Option<Arc<Reposer>>,
    /// Empty-space skipping: the occupancy grid of the rendered pose's mesh (world frame).
    /// `None` (the default) evaluates every sample.
    pub occupancy: Option<Arc<OccupancyGrid>>,
    /// Early ray termination (`termination`): the transmittance below which a ray evaluates no
    /// more samples, at inference. `None` (the default) evaluates every kept sample.
    pub termination: Option<f32>,
    /// Colour culling (`colour_culling`): the per-ray budget of weight whose samples get no
    /// colour evaluation, at inference. `None` (the default) colours every evaluated sample.
    pub colour_culling: Option<f32>,
    /// Training augmentation: F_B blends some points' c0 from other points (`c0_shuffle`).
    /// `None` (the default, and always at inference) blends every point's own c0.
    pub c0_shuffle: Option<C0Shuffle>,
    /// Band sampling (`ModelConfig::ray_sampler`): the band's occupancy grid of the rendered
    /// pose's mesh; `None` for stratified sampling.
    pub band: Option<Arc<OccupancyGrid>>,
    /// Visual-hull carving (`[render] visual_hull`, not in the paper): the density is
    /// multiplied by how far inside every source view's dilated person mask a point projects
    /// ([`VisualHull`]), and with empty-space skipping what it carves is not evaluated. `None`
    /// (the default, and in training) is the paper's density.
    pub visual_hull: Option<Arc<VisualHull>>,
}

impl SceneEncoding {
    /// This encoding with empty-space skipping by `grid` (built on the mesh of the pose that
    /// will be rendered: the scene's own for a novel view, the target pose's when reposing).
    pub fn with_occupancy(mut self, grid: Option<Arc<OccupancyGrid>>) -> Self {
        self.occupancy = grid;
        self
    }

    /// This encoding with visual-hull carving from the person masks of `input` (the scene this
    /// encoding was made from), each grown by `dilate_px` pixels (`None`: off).
    pub fn with_visual_hull(
        mut self,
        input: &SceneInput,
        dilate_px: Option<usize>,
    ) -> Result<Self, ModelError> {
        self.visual_hull = match dilate_px {
            None => None,
            Some(px) => {
                let [h, w] = self.geometry.image_hw;
                if input.views.len() != self.num_views() {
                    return Err(ModelError::Input(format!(
                        "visual hull: {} source views, the encoding has {}",
                        input.views.len(),
                        self.num_views()
                    )));
                }
                let masks: Vec<&[f32]> = input.views.iter().map(|v| v.mask.as_slice()).collect();
                let hull = VisualHull::new(&masks, w, h, px).map_err(SceneError::from)?;
                Some(Arc::new(hull))
            }
        };
        Ok(self)
    }

    /// This encoding with early ray termination below transmittance `epsilon` (`None`: off).
    pub fn with_termination(mut self, epsilon: Option<f32>) -> Self {
        self.termination = epsilon;
        self
    }

    /// This encoding with colour culling within a per-ray weight budget `epsilon` (`None`: off).
    pub fn with_colour_culling(mut self, epsilon: Option<f32>) -> Self {
        self.colour_culling = epsilon;
        self
    }

    /// This encoding with the body volume, the source images and the pixel-feature maps read
    /// on the host (`on`, for the CPU backends at inference: [`HostVolume`],
    /// [`ViewRows::with_host_copy`]) or with tensor operations (every backend, with gradients).
    /// [`NiaModel::encode`] turns it on for a CPU device without autodiff; off is the
    /// reference path the host read is tested against.
    pub fn with_host_reads(mut self, model: &NiaModel, on: bool) -> Result<Self, ModelError> {
        self.host_volume = match (&self.volume, on) {
            (Some((_, volume)), true) => Some(Arc::new(model.host_volume(volume)?)),
            _ => None,
        };
        let host_copy = |rows: ViewRows| match (on, rows.has_host_copy()) {
            (true, false) => rows.with_host_copy(),
            (true, true) => Ok(rows),
            (false, _) => Ok(rows.without_host_copy()),
        };
        self.image_rows = host_copy(self.image_rows)?;
        self.pixel_rows = host_copy(self.pixel_rows)?;
        Ok(self)
    }

    /// This encoding with c0 shuffling in the blend (training only; `None`: off).
    pub fn with_c0_shuffle(mut self, shuffle: Option<C0Shuffle>) -> Self {
        self.c0_shuffle = shuffle;
        self
    }

    /// Number of source views N.
    pub fn num_views(&self) -> usize {
        self.images.dims()[0]
    }
}

impl NiaModel {
    /// The per-scene pass on `device`: geometry, feature maps and the body volume. With
    /// `reposer` (pose animation) the body volume is built on the target pose's vertices and
    /// renders show the body in that pose; an identity reposer is dropped (no reposing work).
    /// `times` charges the encoder and body-volume stages.
    pub fn encode(
        &self,
        input: &SceneInput,
        reposer: Option<Arc<Reposer>>,
        device: &Device,
        times: Option<&mut StageTimes>,
    ) -> Result<SceneEncoding, ModelError> {
        let mut watch = Stopwatch::new(times, device);
        let mut geometry = SceneGeometry::new(input, self.voxel_grid())?;
        if let Some(tol) = self.visibility_depth_tol_m {
            geometry = geometry.with_depth_test(tol)?;
        }
        let geometry = Arc::new(geometry);
        let n = input.views.len();
        let [h, w] = geometry.image_hw;
        let mut pixels = Vec::with_capacity(n * 3 * h * w);
        for view in &input.views {
            pixels.extend_from_slice(&view.image);
        }
        let images = Tensor::<4>::from_data(TensorData::new(pixels, [n, 3, h, w]), device);
        // The encoder's pyramid is reduced level by level before upsampling, once per
        // consumer (pixel features, vertex features): the 512-channel map F is never built.
        // On a CPU backend without autodiff the reductions run on the host, into rows.
        let on_host = is_host(device);
        let pixel_weight = self.pixel_feature.reduce.weight.val();
        let vertex_weight = self.vertex_reduce.weight.val();
        let (pixel_rows, vertex_rows) = if on_host {
            let pyramid = HostTrunk::new(&self.encoder)?.forward(images.clone())?;
            (
                reduce_to_rows(&pyramid, pixel_weight)?,
                reduce_to_rows(&pyramid, vertex_weight)?,
            )
        } else {
            let pyramid = self.encoder.forward_pyramid(images.clone());
            (
                ViewRows::new(pyramid.reduce(pixel_weight)?)?,
                ViewRows::new(pyramid.reduce(vertex_weight)?)?,
            )
        };
        watch.mark(Stage::Encoder);
        let reposer = reposer.filter(|r| !r.is_identity());
        let volume = self.body_volume_of(&vertex_rows, &geometry, reposer.as_deref(), device)?;
        if volume.is_some() {
            watch.mark(Stage::BodyVolume);
        }
        let band = self.band_of(&geometry, reposer.as_deref())?;
        let encoding = SceneEncoding {
            geometry,
            image_rows: ViewRows::new(images.clone())?,
            images,
            vertex_rows,
            pixel_rows,
            volume,
            host_volume: None,
            reposer,
            occupancy: None,
            termination: None,
            colour_culling: None,
            c0_shuffle: None,
            band,
            visual_hull: None,
        };
        // Inference on a CPU backend reads the body volume on the host (fused).
        encoding.with_host_reads(self, on_host)
    }

    /// The same scene rendered in another pose: the body volume rebuilt on `reposer`'s target
    /// vertices, reusing the source images' feature maps (per-pose work only, for animating one
    /// scene through many poses). The occupancy grid is not carried over (it belongs to a pose);
    /// the visual hull is (it belongs to the source views).
    pub fn encode_pose(
        &self,
        scene: &SceneEncoding,
        reposer: Arc<Reposer>,
        times: Option<&mut StageTimes>,
    ) -> Result<SceneEncoding, ModelError> {
        let reposer = Some(reposer).filter(|r| !r.is_identity());
        if reposer.is_none() && scene.reposer.is_none() {
            // The scene's own pose: its body volume serves as it is.
            return Ok(scene.clone().with_occupancy(None));
        }
        let device = scene.images.device();
        let mut watch = Stopwatch::new(times, &device);
        let volume = self.body_volume_of(
            &scene.vertex_rows,
            &scene.geometry,
            reposer.as_deref(),
            &device,
        )?;
        if volume.is_some() {
            watch.mark(Stage::BodyVolume);
        }
        let band = self.band_of(&scene.geometry, reposer.as_deref())?;
        let host_volume = match (&volume, &scene.host_volume) {
            (Some((_, v)), Some(_)) => Some(Arc::new(self.host_volume(v)?)),
            _ => None,
        };
        Ok(SceneEncoding {
            geometry: scene.geometry.clone(),
            images: scene.images.clone(),
            vertex_rows: scene.vertex_rows.clone(),
            image_rows: scene.image_rows.clone(),
            pixel_rows: scene.pixel_rows.clone(),
            volume,
            host_volume,
            reposer,
            occupancy: None,
            termination: scene.termination,
            colour_culling: scene.colour_culling,
            c0_shuffle: scene.c0_shuffle,
            band,
            visual_hull: scene.visual_hull.clone(),
        })
    }

    /// The host copy of `volume` for the fused read, its wide scales through the body
    /// reduction's weight ([`HostVolume::read`]).
    fn host_volume(&self, volume: &BodyVolume) -> Result<HostVolume, ModelError> {
        Ok(HostVolume::read(
            volume,
            Some(self.body_reduce.weight.val()),
        )?)
    }

    /// The band sampler's grid on the mesh of the rendered pose: the scene's own, or
    /// `reposer`'s target vertices; `None` for stratified sampling.
    fn band_of(
        &self,
        geometry: &SceneGeometry,
        reposer: Option<&Reposer>,
    ) -> Result<Option<Arc<OccupancyGrid>>, ModelError> {
        let vertices = match reposer {
            None => &geometry.vertices_world,
            Some(reposer) => reposer.target_vertices(),
        };
        Ok(self.ray_sampler.band(vertices, &geometry.faces)?)
    }

    /// Vertex features from the vertex maps (`W_v^T F`) and the sparse-convolution body volume,
    /// built on the scene's own vertices or, with `reposer`, on the target pose's (with the
    /// features of the scene's vertices of the same index); `None` for variant (a).
    fn body_volume_of(
        &self,
        vertex_rows: &ViewRows,
        geometry: &SceneGeometry,
        reposer: Option<&Reposer>,
        device: &Device,
    ) -> Result<Option<(BodyVolumeGeometry, BodyVolume)>, ModelError> {
        if !self.variant.uses_body() {
            return Ok(None);
        }
        let n = vertex_rows.dims()[0];
        let v = geometry.vertices_world.len();
        // Vertex projections: the same projection rule as the query points.
        let grid = projection_grid(geometry, &geometry.vertices_world);
        let grid = Tensor::<3>::from_data(TensorData::new(grid, [n, v, 2]), device);
        // Linear(sample(F)) = sample(W_v^T F) + b: [N, V, C_v].
        let features = sample_rows_through(&self.vertex_reduce, vertex_rows, grid)?;
        let vis: Vec<f32> = geometry
            .vertex_visibility
            .iter()
            .flatten()
            .copied()
            .collect();
        let vis = Tensor::<3>::from_data(TensorData::new(vis, [n, v, 1]), device);
        // Zero where the vertex is invisible in that view (after the bias).
        let vertex_features = features * vis;
        let (at, voxel_box) = match reposer {
            None => (geometry.vertices_smpl.clone(), geometry.voxel_box),
            Some(reposer) => {
                let at = reposer.target_vertices_smpl();
                if at.len() != v {
                    return Err(ModelError::Input(format!(
                        "reposing target vertices: expected {v} (one per scene vertex), got {}",
                        at.len()
                    )));
                }
                let voxel_box = self.voxel_grid().enclosing(&at)?;
                (at, voxel_box)
            }
        };
        let vg = BodyVolumeGeometry::build(&at, &voxel_box, device)?;
        let volume = self.body_volume.forward(&vg, vertex_features)?;
        Ok(Some((vg, volume)))
    }
}
