//! The field, the middle stage of the forward pass: what NIA computes for a point x seen by N
//! source views (paper section 3), from the per-scene encoding (`crate::encoder`,
//! `crate::body_volume`) and the IBR inputs (`crate::ibr`):
//!
//! - [`attention`]: the view-wise cross-attention `Z = softmax(phi_k(S) phi_k(L)^T / sqrt(d))
//!   phi_v(L) + S` over the body features s_n and pixel-aligned features l_n;
//! - [`heads`]: `sigma = F_sigma(mean_n z_n)`, `(c0, psi, h) = F_c0([mean_n z_n ; gamma(d)])`
//!   with [`positional_encoding`] gamma;
//! - then F_B blends `[c0, c_1..c_N]` (`crate::ibr::blender`).
//!
//! At inference on the CPU backends the attention's view mean ([`attention_host`]) and the
//! three MLPs ([`network_host`]) run fused on the host; the tensor forms are the reference.
//!
//! [`NiaModel::field`](crate::NiaModel::field) takes world points (in the rendered pose),
//! computes their CPU inputs ([`PointInputs`]: projections, d_hat_n, o_n, trilinear corners;
//! reposed into the scene's pose first when the scene renders another pose) and runs
//! [`NiaModel::query`](crate::NiaModel::query), the network proper ([`query`]).

pub mod attention;
pub mod attention_host;
pub mod attention_op;
pub mod heads;
pub mod network_host;
pub mod positional_encoding;
pub mod query;

use burn::prelude::*;
use nia_data::scene::{PointInputs, VIEW_DIR_FEATURE_DIM};

use crate::body_volume::{HostVolume, TrilinearTensors};
use crate::error::ModelError;

/// The fields of M points.
#[derive(Debug, Clone)]
pub struct PointOutput {
    /// [M] density sigma, per metre.
    pub sigma: Tensor<1>,
    /// [M, 3] blended colour c.
    pub colour: Tensor<2>,
    /// [M, 3] NeRF colour c0.
    pub c0: Tensor<2>,
    /// [M, 3] the c0 F_B blended where it is not c0 itself (training with c0 shuffling,
    /// `SceneEncoding::c0_shuffle`); `None` otherwise.
    pub blend_c0: Option<Tensor<2>>,
    /// [M, N + 1] blend weights (index 0 = c0).
    pub blend_weights: Tensor<2>,
    /// [M, 3] the image-based part of the colour alone: the source colours under the blend
    /// weights renormalised over the views (the plain mean where they are all ~0). An
    /// instrument (what the source views say at the point).
    pub ibr_colour: Tensor<2>,
}

impl PointOutput {
    /// The outputs of several calls, one after the other (`None` for no parts). `blend_c0`
    /// is kept only when every part has it.
    ///
    /// # Shapes
    /// parts of `[M_i, ..]` rows each -> `[sum_i M_i, ..]`
    pub fn cat(parts: Vec<PointOutput>) -> Option<PointOutput> {
        if parts.len() <= 1 {
            return parts.into_iter().next();
        }
        let cat2 = |f: fn(&PointOutput) -> Tensor<2>| Tensor::cat(parts.iter().map(f).collect(), 0);
        let blend_c0 = parts
            .iter()
            .map(|p| p.blend_c0.clone())
            .collect::<Option<Vec<_>>>()
            .map(|b| Tensor::cat(b, 0));
        Some(PointOutput {
            sigma: Tensor::cat(parts.iter().map(|p| p.sigma.clone()).collect(), 0),
            colour: cat2(|p| p.colour.clone()),
            c0: cat2(|p| p.c0.clone()),
            blend_c0,
            blend_weights: cat2(|p| p.blend_weights.clone()),
            ibr_colour: cat2(|p| p.ibr_colour.clone()),
        })
    }
}

/// [`PointInputs`] on a device.
#[derive(Debug, Clone)]
pub struct PointTensors {
    pub num_points: usize,
    /// Points before shape-bucket padding (`renderer::shape_buckets`): the rows from here on
    /// repeat the last point, and their outputs are dropped. `num_points` unless padded.
    pub real_points: usize,
    /// [N, M, 2]
    pub proj_grid: Tensor<3>,
    /// [N, M, 4]
    pub view_dir_features: Tensor<3>,
    /// [N, M]
    pub visibility: Tensor<2>,
    /// [M, 3]
    pub dirs: Tensor<2>,
    /// [M] the visual hull's carving of the density (`None`: no hull).
    pub hull: Option<Tensor<1>>,
    /// Per scale of the body volume (empty without one, or when `body` holds the read).
    pub corners: Vec<TrilinearTensors>,
    /// [N, M, sum_s C_s] the body volume already read at the points (the fused host read,
    /// [`HostVolume`]); `None` reads it from `corners` with tensor operations.
    pub body: Option<Tensor<3>>,
}

impl PointTensors {
    /// Uploads `inputs` to `device`.
    pub fn upload(inputs: &PointInputs, device: &Device) -> Self {
        let (n, m) = (inputs.num_views, inputs.num_points);
        let tensor3 = |values: &[f32], shape: [usize; 3]| {
            Tensor::<3>::from_data(TensorData::new(values.to_vec(), shape), device)
        };
        PointTensors {
            num_points: m,
            real_points: m,
            proj_grid: tensor3(&inputs.proj_grid, [n, m, 2]),
            view_dir_features: tensor3(&inputs.view_dir_features, [n, m, VIEW_DIR_FEATURE_DIM]),
            visibility: Tensor::from_data(
                TensorData::new(inputs.visibility.clone(), [n, m]),
                device,
            ),
            dirs: Tensor::from_data(TensorData::new(inputs.dirs.clone(), [m, 3]), device),
            hull: inputs
                .hull
                .as_ref()
                .map(|h| Tensor::from_data(TensorData::new(h.clone(), [m]), device)),
            corners: inputs
                .corners
                .iter()
                .map(|c| TrilinearTensors::upload(c, device))
                .collect(),
            body: None,
        }
    }

    /// Uploads `inputs` to `device` with the body volume read on the host by `host` at the
    /// inputs' corners (which are then not uploaded).
    pub fn upload_read(
        inputs: PointInputs,
        host: &HostVolume,
        device: &Device,
    ) -> Result<Self, ModelError> {
        let (n, m) = (inputs.num_views, inputs.num_points);
        let body = host.sample(&inputs.corners)?;
        let body = Tensor::<3>::from_data(TensorData::new(body, [n, m, host.channels()]), device);
        let without_corners = PointInputs {
            corners: Vec::new(),
            ..inputs
        };
        let mut tensors = Self::upload(&without_corners, device);
        tensors.body = Some(body);
        Ok(tensors)
    }
}
