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
use nia_data::scene::{masks_with_body, SceneError, SceneGeometry, SceneInput, VisualHull};

pub mod cut;
mod encode;

use crate::body_volume::{BodyVolume, BodyVolumeGeometry, HostVolume};
use crate::encoder::bilinear::ViewRows;
use crate::error::ModelError;
use crate::field::network_host::HostNetwork;
use crate::ibr::c0_shuffle::C0Shuffle;
use crate::model::NiaModel;
use crate::renderer::density_grid::{DensityGrid, DensityMemo};

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
    /// F_sigma, F_c0 and F_B's weights on the host for the fused CPU MLPs ([`HostNetwork`],
    /// inference on the CPU backends); `None` runs them with tensor operations.
    pub host_network: Option<Arc<HostNetwork>>,
    /// Pose animation: maps query points of the rendered (target) pose to the scene's pose.
    /// `None` renders the scene's own pose, with no reposing work at all.
    pub reposer: Option<Arc<Reposer>>,
    /// Empty-space skipping: the occupancy grid of the rendered pose's mesh (world frame).
    /// `None` (the default) evaluates every sample.
    pub occupancy: Option<Arc<OccupancyGrid>>,
    /// Early ray termination (`renderer::termination`): the transmittance below which a ray evaluates no
    /// more samples, at inference. `None` (the default) evaluates every kept sample.
    pub termination: Option<f32>,
    /// Colour culling (`renderer::colour_culling`): the per-ray budget of weight whose samples get no
    /// colour evaluation, at inference. `None` (the default) colours every evaluated sample.
    pub colour_culling: Option<f32>,
    /// Colour once per ray (`renderer::colour_once`): the colour at this many samples of each
    /// ray, at inference. `None` (the default) colours every evaluated sample (the paper).
    pub colour_points: Option<usize>,
    /// Training augmentation: F_B blends some points' c0 from other points (`ibr::c0_shuffle`).
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
    /// c0's weight in the blend rescaled at inference (`[render] c0_weight_scale`, not in the
    /// paper; [`crate::ibr::c0_weight_scale::rescale_c0_weight`]). `None` (the default, and in training)
    /// blends with F_B's weights as they are.
    pub c0_weight_scale: Option<f32>,
    /// The most points one network call of a render gets
    /// ([`crate::renderer::call_size::MAX_POINTS_PER_CALL`] unless set): a depth segment (or a
    /// chunk without termination) of more is evaluated in several calls. Training's step is one
    /// call whatever this says.
    pub points_per_call: usize,
    /// The density baked per pose (`renderer::density_grid`) that renders of this encoding
    /// read instead of running F_sigma at every sample (with colour once per ray). `None` (the
    /// default) runs the density half at the samples.
    pub density_grid: Option<Arc<DensityGrid>>,
    /// The grid baked for this encoding's pose, occupancy and hull, shared by its clones.
    pub density_memo: DensityMemo,
}

impl SceneEncoding {
    /// This encoding with empty-space skipping by `grid` (built on the mesh of the pose that
    /// will be rendered: the scene's own for a novel view, the target pose's when reposing).
    pub fn with_occupancy(mut self, grid: Option<Arc<OccupancyGrid>>) -> Self {
        self.occupancy = grid;
        self.without_baked_density()
    }

    /// This encoding with visual-hull carving from the person masks of `input` (the scene this
    /// encoding was made from) when `carve` is set, and with `body_erode_px` the body's
    /// silhouette shrunk by that many pixels counted as person
    /// ([`nia_data::scene::masks_with_body`]).
    pub fn with_visual_hull(
        mut self,
        input: &SceneInput,
        carve: bool,
        body_erode_px: Option<usize>,
    ) -> Result<Self, ModelError> {
        self.visual_hull = match carve {
            false => None,
            true => {
                let [h, w] = self.geometry.image_hw;
                if input.views.len() != self.num_views() {
                    return Err(ModelError::Input(format!(
                        "visual hull: {} source views, the encoding has {}",
                        input.views.len(),
                        self.num_views()
                    )));
                }
                let masks: Vec<&[f32]> = input.views.iter().map(|v| v.mask.as_slice()).collect();
                // The scene's cameras are the encoding's (`SceneGeometry::new` took them).
                let with_body = body_erode_px
                    .map(|erode| {
                        let body = &input.body;
                        masks_with_body(
                            &masks,
                            &self.geometry.cameras,
                            &body.vertices,
                            &body.faces,
                            erode,
                        )
                    })
                    .transpose()
                    .map_err(SceneError::from)?;
                let masks: Vec<&[f32]> = match &with_body {
                    Some(m) => m.iter().map(Vec::as_slice).collect(),
                    None => masks,
                };
                let hull = VisualHull::new(&masks, w, h).map_err(SceneError::from)?;
                Some(Arc::new(hull))
            }
        };
        Ok(self.without_baked_density())
    }

    /// This encoding with c0's blend weight rescaled by `scale` at inference (`None`: F_B's
    /// weights as they are; [`crate::ibr::c0_weight_scale::rescale_c0_weight`]).
    pub fn with_c0_weight_scale(mut self, scale: Option<f32>) -> Self {
        self.c0_weight_scale = scale;
        self
    }

    /// This encoding with early ray termination below transmittance `epsilon` (`None`: off).
    pub fn with_termination(mut self, epsilon: Option<f32>) -> Self {
        self.termination = epsilon;
        self
    }

    /// This encoding with renders' network calls of at most `points` points (at least 1).
    pub fn with_points_per_call(mut self, points: usize) -> Self {
        self.points_per_call = points.max(1);
        self
    }

    /// This encoding with colour culling within a per-ray weight budget `epsilon` (`None`: off).
    pub fn with_colour_culling(mut self, epsilon: Option<f32>) -> Self {
        self.colour_culling = epsilon;
        self
    }

    /// This encoding coloured at `k` samples per ray at inference
    /// (`renderer::colour_once`; `None`: every evaluated sample, the paper's).
    pub fn with_colour_points(mut self, k: Option<usize>) -> Self {
        self.colour_points = k;
        self
    }

    /// This encoding with the body volume, the source images and the pixel-feature maps read
    /// on the host and the MLPs run there (`on`, for the CPU backends at inference:
    /// [`HostVolume`], [`ViewRows::with_host_copy`], [`HostNetwork`]) or with tensor operations
    /// (every backend, with gradients).
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
        self.host_network = match on {
            true => Some(Arc::new(model.host_network()?)),
            false => None,
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

    /// This encoding with the density baked by [`NiaModel::baked_density`] read at the samples
    /// (`None`: the density half runs at them).
    pub fn with_density_grid(mut self, grid: Option<Arc<DensityGrid>>) -> Self {
        self.density_grid = grid;
        self
    }

    /// This encoding with no baked density and a memo of its own (its density changed).
    fn without_baked_density(mut self) -> Self {
        self.density_grid = None;
        self.density_memo = DensityMemo::default();
        self
    }

    /// Number of source views N.
    pub fn num_views(&self) -> usize {
        self.images.dims()[0]
    }
}
