//! [`NiaModel::encode`] and [`NiaModel::encode_pose`]: the per-scene pass (the parent module's
//! docs) and its rebuild for another pose.

use std::sync::Arc;

use burn::prelude::*;
use nia_data::body::reposing::Reposer;
use nia_data::geometry::occupancy::OccupancyGrid;
use nia_data::scene::{projection_grid, SceneGeometry, SceneInput};

use super::SceneEncoding;
use crate::body_volume::{BodyVolume, BodyVolumeGeometry, HostVolume};
use crate::device::is_host;
use crate::encoder::bilinear::ViewRows;
use crate::encoder::host::HostTrunk;
use crate::encoder::pyramid_host::reduce_to_rows;
use crate::error::ModelError;
use crate::field::network_host::HostNetwork;
use crate::ibr::sample_rows_through;
use crate::model::NiaModel;
use crate::renderer::call_size::MAX_POINTS_PER_CALL;
use crate::timing::{Stage, StageTimes, Stopwatch};

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
        let geometry = Arc::new(SceneGeometry::new(input, self.voxel_grid())?);
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
            host_network: None,
            reposer,
            occupancy: None,
            termination: None,
            colour_culling: None,
            colour_points: None,
            c0_shuffle: None,
            band,
            visual_hull: None,
            c0_weight_scale: None,
            points_per_call: MAX_POINTS_PER_CALL,
            density_grid: None,
            density_memo: Default::default(),
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
            host_network: scene.host_network.clone(),
            reposer,
            occupancy: None,
            termination: scene.termination,
            colour_culling: scene.colour_culling,
            colour_points: scene.colour_points,
            c0_shuffle: scene.c0_shuffle,
            band,
            visual_hull: scene.visual_hull.clone(),
            c0_weight_scale: scene.c0_weight_scale,
            points_per_call: scene.points_per_call,
            density_grid: None,
            density_memo: Default::default(),
        })
    }

    /// F_sigma, F_c0 and F_B's weights read back for [`HostNetwork`].
    pub(super) fn host_network(&self) -> Result<HostNetwork, ModelError> {
        Ok(HostNetwork::read(
            &self.density,
            &self.colour,
            &self.blender,
        )?)
    }

    /// The host copy of `volume` for the fused read, its wide scales through the body
    /// reduction's weight ([`HostVolume::read`]).
    pub(super) fn host_volume(&self, volume: &BodyVolume) -> Result<HostVolume, ModelError> {
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
