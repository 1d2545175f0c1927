//! The body-volume network: Neural Body / NHP's `SparseConvNet` on the active sites.
//!
//! Per-vertex features are scatter-averaged into their level-0 sites, then
//! - full resolution: `full_convs` submanifold blocks (`C_v -> full_channels`);
//! - for each scale s = 1..4 (1/2, 1/4, 1/8, 1/16 resolution): one strided block
//!   (stride 2, kernel 3, padding 1) then `scale_convs[s]` submanifold blocks, all with
//!   `scale_channels[s]` channels; the output of every scale is read back.
//!
//! A block is `ReLU(SiteNorm(SparseConv3d(x)))` with a bias-free convolution (Neural Body:
//! `SubMConv3d/SparseConv3d(bias=False) -> BatchNorm1d(eps=1e-3) -> ReLU`; see
//! [`super::site_norm`] for the norm). Defaults follow Neural Body's channel plan
//! (32, 64, 128, 128 read back; 352 channels in total).
//!
//! The geometry of a frame (voxels, every rulebook, uploaded index tensors) is built once by
//! [`BodyVolumeGeometry::build`] and serves every forward and every view.

use std::sync::Arc;

use nia_data::geometry::sparse::{
    shared_pyramid, ScaleGeometry, SitePyramid, TrilinearCorners, VoxelBox,
};

use burn::prelude::*;

use super::site_norm::{SiteNorm, SiteNormConfig};
use super::sparse_conv::{ConvMethod, RulebookTensors, SparseConv3d, SparseConv3dConfig};
use super::trilinear::{self, CornerRead, SiteRows, TrilinearTensors};
use super::view_rows::ViewRows;
use super::BodyVolumeError;
use crate::kernels::blocked_rows::scatter_add_rows;

/// Scales read back (1/2, 1/4, 1/8, 1/16 resolution).
pub const NUM_SCALES: usize = 4;

/// Configuration of [`BodyVolumeNet`].
#[derive(Config, Debug, PartialEq)]
pub struct BodyVolumeNetConfig {
    /// Channels C_v of the per-vertex input features.
    #[config(default = 32)]
    pub vertex_channels: usize,
    /// Channels of the full-resolution stage.
    #[config(default = 32)]
    pub full_channels: usize,
    /// Submanifold blocks at full resolution.
    #[config(default = 2)]
    pub full_convs: usize,
    /// Channels C_s of the scales 1/2, 1/4, 1/8, 1/16.
    #[config(default = "[32, 64, 128, 128]")]
    pub scale_channels: [usize; NUM_SCALES],
    /// Submanifold blocks after each scale's strided block.
    #[config(default = "[2, 3, 3, 3]")]
    pub scale_convs: [usize; NUM_SCALES],
    /// Epsilon of every [`SiteNorm`].
    #[config(default = 1e-3)]
    pub norm_epsilon: f64,
}

impl BodyVolumeNetConfig {
    /// Total channels of the sampled volume, `sum_s C_s`.
    pub fn output_channels(&self) -> usize {
        self.scale_channels.iter().sum()
    }

    /// The network with PyTorch-style initialisation.
    pub fn init(&self, device: &Device) -> BodyVolumeNet {
        let block = |c_in: usize, c_out: usize| SparseConvBlock {
            conv: SparseConv3dConfig::new(c_in, c_out)
                .with_bias(false)
                .init(device),
            norm: SiteNormConfig::new(c_out)
                .with_epsilon(self.norm_epsilon)
                .init(device),
        };
        let mut channels = self.vertex_channels;
        let mut full = Vec::with_capacity(self.full_convs);
        for _ in 0..self.full_convs {
            full.push(block(channels, self.full_channels));
            channels = self.full_channels;
        }
        let mut scales = Vec::with_capacity(NUM_SCALES);
        for s in 0..NUM_SCALES {
            let c = self.scale_channels[s];
            let down = block(channels, c);
            let convs = (0..self.scale_convs[s]).map(|_| block(c, c)).collect();
            scales.push(ScaleStage { down, convs });
            channels = c;
        }
        BodyVolumeNet { full, scales }
    }
}

/// `ReLU(SiteNorm(SparseConv3d(x)))`.
#[derive(Module, Debug)]
pub struct SparseConvBlock {
    pub conv: SparseConv3d,
    pub norm: SiteNorm,
}

impl SparseConvBlock {
    /// `[N, P_in, C_in] -> [N, P_out, C_out]`.
    pub fn forward(
        &self,
        features: Tensor<3>,
        rulebook: &RulebookTensors,
    ) -> Result<Tensor<3>, BodyVolumeError> {
        self.norm
            .forward_relu(self.conv.forward(features, rulebook)?)
    }
}

/// One scale: a strided block to the coarser level, then submanifold blocks on it.
#[derive(Module, Debug)]
pub struct ScaleStage {
    pub down: SparseConvBlock,
    pub convs: Vec<SparseConvBlock>,
}

/// The sparse convolution network of the body volume.
#[derive(Module, Debug)]
pub struct BodyVolumeNet {
    /// Submanifold blocks at full resolution.
    pub full: Vec<SparseConvBlock>,
    /// [4] the stages of the scales 1/2 .. 1/16.
    pub scales: Vec<ScaleStage>,
}

impl BodyVolumeNet {
    /// Diffuses per-vertex features into the body volume of every view.
    ///
    /// `geometry` must live on the features' device.
    ///
    /// # Shapes
    /// - vertex_features: `[N, V, C_v]` (V = the vertices the geometry was built from)
    /// - output: per scale s, features `[N, P_s, C_s]`
    pub fn forward(
        &self,
        geometry: &BodyVolumeGeometry,
        vertex_features: Tensor<3>,
    ) -> Result<BodyVolume, BodyVolumeError> {
        let mut x = geometry.site_features(vertex_features)?;
        for block in &self.full {
            x = block.forward(x, &geometry.submanifold[0])?;
        }
        let mut scales = Vec::with_capacity(NUM_SCALES);
        for (s, stage) in self.scales.iter().enumerate() {
            x = stage.down.forward(x, &geometry.strided[s])?;
            for block in &stage.convs {
                x = block.forward(x, &geometry.submanifold[s + 1])?;
            }
            scales.push(ScaleVolume::new(x.clone(), geometry.levels[s + 1].clone()));
        }
        Ok(BodyVolume { scales })
    }
}

/// Everything about a frame's body volume that does not depend on the view features: the
/// voxelisation, the sites of every level and the rulebooks (CPU and uploaded).
#[derive(Debug, Clone)]
pub struct BodyVolumeGeometry {
    /// The level-0 grid.
    pub voxel_box: VoxelBox,
    /// The host geometry of levels 0 (full) .. 4 (1/16; scale s is level s + 1): the voxelised
    /// vertices, every level's sites and the rulebooks ([`SitePyramid`]), shared with the
    /// loader's workers that build it ahead (also reachable as fields: `geometry.levels`).
    pub pyramid: Arc<SitePyramid>,
    /// [5] `submanifold_rules` on the device.
    pub submanifold: Vec<RulebookTensors>,
    /// [4] `strided_rules` on the device.
    pub strided: Vec<RulebookTensors>,
    /// [V] level-0 site of every vertex (rows of `[N * P_0, C_v]`).
    vertex_site: ViewRows,
    /// [1, P_0, 1] 1 / (vertices in the site).
    pub inverse_count: Tensor<3>,
}

impl std::ops::Deref for BodyVolumeGeometry {
    type Target = SitePyramid;

    fn deref(&self) -> &SitePyramid {
        &self.pyramid
    }
}

impl BodyVolumeGeometry {
    /// Voxelises `vertices_smpl` ([V, 3] metres, SMPL frame) in `voxel_box`, builds the sites
    /// and rulebooks of every level and uploads them to `device`.
    pub fn build(
        vertices_smpl: &[[f32; 3]],
        voxel_box: &VoxelBox,
        device: &Device,
    ) -> Result<Self, BodyVolumeError> {
        Self::build_with_method(vertices_smpl, voxel_box, ConvMethod::Auto, device)
    }

    /// [`Self::build`] with the sparse convolution method of every rulebook chosen by the
    /// caller (`Auto`: the host kernels on flex, elsewhere by fill ratio, see
    /// [`super::sparse_conv::IM2COL_MIN_FILL`]).
    pub fn build_with_method(
        vertices_smpl: &[[f32; 3]],
        voxel_box: &VoxelBox,
        method: ConvMethod,
        device: &Device,
    ) -> Result<Self, BodyVolumeError> {
        let pyramid = shared_pyramid(vertices_smpl, voxel_box, NUM_SCALES)?;
        let submanifold = pyramid
            .submanifold_rules
            .iter()
            .map(|r| RulebookTensors::with_method(r, method, device))
            .collect();
        let strided = pyramid
            .strided_rules
            .iter()
            .map(|r| RulebookTensors::with_method(r, method, device))
            .collect();
        let inverse: Vec<f32> = pyramid
            .voxels
            .site_vertex_count
            .iter()
            .map(|&c| 1.0 / c as f32)
            .collect();
        let p0 = inverse.len();
        Ok(BodyVolumeGeometry {
            voxel_box: *voxel_box,
            vertex_site: ViewRows::new(pyramid.voxels.vertex_site.clone(), 1, p0, device),
            inverse_count: Tensor::from_data(TensorData::new(inverse, [1, p0, 1]), device),
            pyramid,
            submanifold,
            strided,
        })
    }

    /// Scatter-mean of per-vertex features into their level-0 sites.
    ///
    /// # Shapes
    /// - vertex_features: `[N, V, C_v]`
    /// - output: `[N, P_0, C_v]`
    pub fn site_features(&self, vertex_features: Tensor<3>) -> Result<Tensor<3>, BodyVolumeError> {
        let dims = vertex_features.dims();
        let v = self.voxels.vertex_site.len();
        if dims[0] == 0 || dims[1] != v {
            return Err(BodyVolumeError::shape(
                "vertex_features",
                format!("[N >= 1, {v}, C_v] (V of the body volume geometry)"),
                &dims,
            ));
        }
        let [n, _, c_v] = dims;
        let p0 = self.levels[0].num_sites();
        // Views stacked along the rows: on the GPU backends an atomic scatter-add, not burn's
        // `select_assign`, one serial loop over the V vertices per column (`blocked_rows`).
        let summed = scatter_add_rows(
            Tensor::zeros([n * p0, c_v], &vertex_features.device()),
            self.vertex_site.stacked(n, usize::MAX),
            vertex_features.reshape([n * v, c_v]),
        )
        .reshape([n, p0, c_v]);
        Ok(summed * self.inverse_count.clone())
    }

    /// The geometry of scale `s` (0..4 = 1/2 .. 1/16), `None` past the last.
    pub fn scale(&self, s: usize) -> Option<&Arc<ScaleGeometry>> {
        self.levels.get(s + 1)
    }

    /// The trilinear corners of `points` ([M, 3] metres, SMPL frame) on every scale.
    pub fn corners(&self, points: &[[f32; 3]]) -> Vec<TrilinearCorners> {
        self.levels[1..]
            .iter()
            .map(|g| TrilinearCorners::compute(points, g))
            .collect()
    }
}

/// One scale of the body volume: the features and, on the GPU backends, their rows as the
/// read gathers them, always made together ([`ScaleVolume::new`]) so they cannot disagree.
#[derive(Debug, Clone)]
pub struct ScaleVolume {
    /// [N, P_s, C_s] features of the active sites, per view.
    features: Tensor<3>,
    /// The sites and placement of this scale.
    pub geometry: Arc<ScaleGeometry>,
    /// On the GPU backends at inference, `features` laid out for their read, once for every
    /// call that reads the scene ([`trilinear::SiteRows`]); `None` on the CPU backends, whose
    /// inference reads on the host ([`super::HostVolume`]), and in training: those reads lay
    /// the rows out per call.
    rows: Option<SiteRows>,
}

impl ScaleVolume {
    /// A scale of `features` on `geometry`, with its rows laid out on a GPU backend when no
    /// backward runs through the features. Tracked features lay them out in every read: rows
    /// made once would be one graph node that each chunk's backward of the chunked training
    /// step ([`crate::scene_encoding::cut`]) consumes, and the second chunk's would fail.
    ///
    /// # Shapes
    /// - features: `[N, P_s, C_s]`
    pub fn new(features: Tensor<3>, geometry: Arc<ScaleGeometry>) -> Self {
        let read = CornerRead::for_device(&features.device());
        let rows = (read == CornerRead::ByCorner && !features.is_tracked())
            .then(|| SiteRows::new(features.clone(), read));
        ScaleVolume {
            features,
            geometry,
            rows,
        }
    }

    /// `[N, P_s, C_s]` features of the active sites, per view.
    pub fn features(&self) -> &Tensor<3> {
        &self.features
    }

    /// The rows laid out for the GPU read (`None` on the CPU backends).
    pub fn rows(&self) -> Option<&SiteRows> {
        self.rows.as_ref()
    }

    /// Reads the scale at `corners` ([`trilinear::sample`]).
    ///
    /// # Shapes
    /// - output: `[N, M, C_s]`
    pub fn sample(&self, corners: &TrilinearTensors) -> Result<Tensor<3>, BodyVolumeError> {
        match &self.rows {
            Some(rows) if rows.read == corners.read => trilinear::sample_rows(rows, corners),
            _ => trilinear::sample(self.features.clone(), corners),
        }
    }
}

/// The body volume of every view at the four scales.
#[derive(Debug, Clone)]
pub struct BodyVolume {
    /// [4] scales 1/2, 1/4, 1/8, 1/16.
    pub scales: Vec<ScaleVolume>,
}

impl BodyVolume {
    /// Samples every scale and concatenates the channels: s_n of the paper before its
    /// channel reduction. `corners[s]` from [`BodyVolumeGeometry::corners`] (same points on
    /// every scale), uploaded.
    ///
    /// # Shapes
    /// - output: `[N, M, sum_s C_s]`
    pub fn sample(&self, corners: &[TrilinearTensors]) -> Result<Tensor<3>, BodyVolumeError> {
        if corners.len() != self.scales.len()
            || corners
                .iter()
                .any(|c| c.num_points != corners[0].num_points)
        {
            return Err(BodyVolumeError::invalid(
                "BodyVolume::sample corners",
                format!(
                    "{} corner sets (one per scale) for the same points",
                    self.scales.len()
                ),
                corners.iter().map(|c| c.num_points).collect::<Vec<_>>(),
            ));
        }
        let parts = self
            .scales
            .iter()
            .zip(corners)
            .map(|(scale, c)| scale.sample(c))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Tensor::cat(parts, 2))
    }
}
