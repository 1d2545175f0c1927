//! [`NiaModel::field`] and [`NiaModel::query`]: the network at M points, in two halves (density,
//! then colour) so that the renderer can colour only the points whose weight matters.

use burn::prelude::*;
use glam::Vec3;
use nia_data::scene::{InputsFor, PointInputs};
use rayon::prelude::*;

use super::heads::view_mean;
use super::{PointOutput, PointTensors};
use crate::error::ModelError;
use crate::ibr::blend_host::IBR_ONLY_FLOOR;
use crate::ibr::blender::BlendInputs;
use crate::ibr::fetch_source_colours_from;
use crate::kernels::linear_rows::linear_rows;
use crate::kernels::readback::host_view_of;
use crate::model::NiaModel;
use crate::renderer::shape_buckets::CallRows;
use crate::scene_encoding::SceneEncoding;
use crate::timing::{Stage, StageTimes, Stopwatch};

impl NiaModel {
    /// The fields at `points` / `dirs` ([M] world, unit directions, in the pose `scene`
    /// renders): the CPU point inputs (reposed into the scene's pose first when the scene was
    /// encoded for another pose) and the network. `times` charges sampling, MLPs and blending.
    pub fn field(
        &self,
        scene: &SceneEncoding,
        points: &[Vec3],
        dirs: &[Vec3],
        times: Option<&mut StageTimes>,
    ) -> Result<PointOutput, ModelError> {
        let device = scene.images.device();
        let mut watch = Stopwatch::new(times, &device);
        let inputs = self.point_tensors(scene, points, dirs, CallRows::Exact, &mut watch)?;
        self.query_with(scene, &inputs, &mut watch)
    }

    /// [`Self::field`]'s colour half alone, for points whose density is known elsewhere (a
    /// density baked for the pose): the same colours, NeRF colours, blend weights and
    /// IBR-only colours, without F_sigma and the visual hull's carving; `sigma` is zero, not a
    /// density.
    pub fn colour_field(
        &self,
        scene: &SceneEncoding,
        points: &[Vec3],
        dirs: &[Vec3],
        times: Option<&mut StageTimes>,
    ) -> Result<PointOutput, ModelError> {
        let device = scene.images.device();
        let mut watch = Stopwatch::new(times, &device);
        let inputs =
            self.point_inputs_with(scene, points, dirs, InputsFor::Network, Carving::None)?;
        let tensors = upload_padded(scene, inputs, CallRows::Exact, &mut watch)?;
        self.query_colour_half(scene, &tensors, &mut watch)
    }

    /// The point inputs of world points (in the rendered pose) on the scene's device, reposed
    /// into the scene's pose first when the scene was encoded for another pose, in
    /// `rows.of(M)` rows, the M points first ([`PointTensors::real_points`] = M; with
    /// [`CallRows::Bucket`] the network's outputs have `bucket_len(M)` rows, which
    /// [`PointOutput::first`] cuts, or a scatter sends to a spare row). `watch` charges the
    /// host part to [`Stage::PointInputs`].
    pub(crate) fn point_tensors(
        &self,
        scene: &SceneEncoding,
        points: &[Vec3],
        dirs: &[Vec3],
        rows: CallRows,
        watch: &mut Stopwatch<'_>,
    ) -> Result<PointTensors, ModelError> {
        self.point_tensors_for(scene, points, dirs, rows, InputsFor::Network, watch)
    }

    /// [`Self::point_tensors`] for the network's half `what` (the density half alone leaves
    /// the inputs only the colour half reads at zero: [`InputsFor::Density`]).
    pub(crate) fn point_tensors_for(
        &self,
        scene: &SceneEncoding,
        points: &[Vec3],
        dirs: &[Vec3],
        rows: CallRows,
        what: InputsFor,
        watch: &mut Stopwatch<'_>,
    ) -> Result<PointTensors, ModelError> {
        let inputs = self.point_inputs_for(scene, points, dirs, what)?;
        upload_padded(scene, inputs, rows, watch)
    }

    /// [`Self::point_tensors_for`]' host half: the point inputs of world points (in the
    /// rendered pose) for the network's half `what`, reposed into the scene's pose first when
    /// the scene was encoded for another pose.
    pub(crate) fn point_inputs_for(
        &self,
        scene: &SceneEncoding,
        points: &[Vec3],
        dirs: &[Vec3],
        what: InputsFor,
    ) -> Result<PointInputs, ModelError> {
        self.point_inputs_with(scene, points, dirs, what, Carving::Scene)
    }

    /// [`Self::point_inputs_for`] with the scene's visual-hull carving or without it (the
    /// colour half at a baked density, which holds the carving already).
    pub(crate) fn point_inputs_with(
        &self,
        scene: &SceneEncoding,
        points: &[Vec3],
        dirs: &[Vec3],
        what: InputsFor,
        carving: Carving,
    ) -> Result<PointInputs, ModelError> {
        let geometry = &scene.geometry;
        let scales = scene.volume.as_ref().map(|(vg, _)| &vg.levels[1..]);
        // The visual hull is read where the source views are: at x, or x' when reposed.
        let hull = scene
            .visual_hull
            .as_ref()
            .filter(|_| carving == Carving::Scene);
        let carve = |inputs: PointInputs, image_points: &[Vec3]| match hull {
            Some(hull) => inputs.carved(hull, &geometry.cameras, image_points),
            None => inputs,
        };
        let inputs = match &scene.reposer {
            None => {
                let volume_points: Option<Vec<[f32; 3]>> =
                    scales.map(|_| points.par_iter().map(|&p| geometry.to_smpl(p)).collect());
                let volume = scales.zip(volume_points.as_deref());
                carve(
                    PointInputs::compute_for(geometry, points, dirs, volume, what),
                    points,
                )
            }
            Some(reposer) => {
                // The body volume lives in the target pose (SMPL frame of the target); pixel
                // features, colours and visibility are read at x' in the reference views.
                let volume_points: Option<Vec<[f32; 3]>> = scales.map(|_| {
                    points
                        .par_iter()
                        .map(|&p| reposer.target_to_smpl(p).to_array())
                        .collect()
                });
                let mapped = reposer
                    .map_points(points, dirs)
                    .map_err(|e| ModelError::Input(format!("reposing: {e}")))?;
                let volume = scales.zip(volume_points.as_deref());
                let inputs =
                    PointInputs::compute_for(geometry, &mapped.points, &mapped.dirs, volume, what);
                carve(inputs, &mapped.points)
            }
        };
        Ok(inputs)
    }

    /// The network at M points whose inputs are already on the device: pixel features and
    /// colours, body features, attention, F_sigma, F_c0 and the blend.
    pub fn query(
        &self,
        scene: &SceneEncoding,
        points: &PointTensors,
        times: Option<&mut StageTimes>,
    ) -> Result<PointOutput, ModelError> {
        let device = scene.images.device();
        self.query_with(scene, points, &mut Stopwatch::new(times, &device))
    }

    pub(crate) fn query_with(
        &self,
        scene: &SceneEncoding,
        points: &PointTensors,
        watch: &mut Stopwatch<'_>,
    ) -> Result<PointOutput, ModelError> {
        let density = self.query_density(scene, points, watch)?;
        self.query_colour(scene, density, watch)
    }

    /// The density half of the network at M points: pixel features l_n, body features s_n,
    /// attention and F_sigma. What the colour half reads is kept with sigma, so a caller can
    /// run [`Self::query_colour`] on all points or on a subset ([`DensityPass::select`]).
    pub(crate) fn query_density(
        &self,
        scene: &SceneEncoding,
        points: &PointTensors,
        watch: &mut Stopwatch<'_>,
    ) -> Result<DensityPass, ModelError> {
        let (mean_z, l) = self.shared_features(scene, points, watch)?;
        let sigma = match scene.host_network.as_deref() {
            Some(host) if !mean_z.is_autodiff() => host.density(mean_z.clone())?,
            _ => self.density.forward(mean_z.clone())?,
        };
        // Visual-hull carving (a switch): no density where a source mask says empty space.
        let sigma = match &points.hull {
            Some(hull) => sigma * hull.clone(),
            None => sigma,
        };
        watch.mark(Stage::Mlps);
        Ok(DensityPass::at(points, sigma, mean_z, l))
    }

    /// The colour half of the network alone at M points whose density is known elsewhere (a
    /// density baked for the pose): [`Self::query_with`] without F_sigma and the carving. The
    /// output's `sigma` is zero, not a density.
    pub(crate) fn query_colour_half(
        &self,
        scene: &SceneEncoding,
        points: &PointTensors,
        watch: &mut Stopwatch<'_>,
    ) -> Result<PointOutput, ModelError> {
        let (mean_z, l) = self.shared_features(scene, points, watch)?;
        let sigma = Tensor::zeros([mean_z.dims()[0]], &mean_z.device());
        self.query_colour(scene, DensityPass::at(points, sigma, mean_z, l), watch)
    }

    /// What both halves read at M points: the attention's view mean `[M, d]` (of the body
    /// features s_n and the pixel features l_n) and the pixel features `[N, M, d]` (F_B's p_n).
    fn shared_features(
        &self,
        scene: &SceneEncoding,
        points: &PointTensors,
        watch: &mut Stopwatch<'_>,
    ) -> Result<(Tensor<2>, Tensor<3>), ModelError> {
        // The body volume read (on the host: a layout whose wide scales are already reduced,
        // with the host copy that reads it), then s_n = W_b^T read + b, [N, M, d]. Read before
        // the pixel features: on wgpu, queued after them, its first scale's gathers ran as 23
        // unfused kernels instead of two fused ones (docs/speed.md, "Slices that are views").
        let read = match (&scene.volume, self.variant.uses_body(), &points.body) {
            (Some(_), true, Some(read)) => match scene.host_volume.as_deref() {
                Some(host) => Some((read.clone(), Some(host))),
                None => {
                    return Err(ModelError::Input(
                        "points carry a host body-volume read but the scene has no host copy"
                            .into(),
                    ))
                }
            },
            (Some((_, volume)), true, None) => Some((volume.sample(&points.corners)?, None)),
            _ => None,
        };
        // The pixel features l_n, [N, M, d].
        let l = self
            .pixel_feature
            .sample_reduced(&scene.pixel_rows, points.proj_grid.clone())?;
        watch.mark(Stage::Sampling);
        let l_device = l.device();
        let mean_z = match (read, self.variant.uses_body()) {
            // Inference with host reads: the reduction and the attention's view mean fused on
            // the host, on host values.
            (Some((read, Some(_))), true) if read.is_autodiff() => {
                return Err(ModelError::Input(
                    "a host body-volume read carries no gradients; train on the tensor read".into(),
                ))
            }
            (Some((read, Some(host))), true) => {
                let [n, m, _] = read.dims();
                let read = host_view_of("body volume read", read)?;
                let s = host.reduce(&read, &self.body_reduce)?; // [N, M, d]
                let l = host_view_of("pixel features l_n", l.clone())?;
                let mean = self.attention.view_mean_of_values(&s, &l, n, m)?;
                let d = mean.len() / m.max(1);
                Tensor::from_data(TensorData::new(mean, [m, d]), &l_device)
            }
            (Some((read, None)), true) => self
                .attention
                .view_mean(linear_rows(&self.body_reduce, read), l.clone())?,
            (None, true) => {
                return Err(ModelError::Input(
                    "the scene was encoded without a body volume".into(),
                ))
            }
            (_, false) => view_mean(l.clone()),
        }; // [M, d]
        watch.mark(Stage::Mlps);
        Ok((mean_z, l))
    }

    /// The colour half of the network at the points of `density`: source colours c_n, F_c0 and
    /// the blend.
    pub(crate) fn query_colour(
        &self,
        scene: &SceneEncoding,
        density: DensityPass,
        watch: &mut Stopwatch<'_>,
    ) -> Result<PointOutput, ModelError> {
        let DensityPass {
            sigma,
            mean_z,
            l,
            proj_grid,
            view_dir_features,
            visibility,
            dirs,
            real_points,
        } = density;
        let source_colours = fetch_source_colours_from(&scene.image_rows, proj_grid)?; // [N, M, 3]
        watch.mark(Stage::Sampling);
        let host = scene.host_network.as_deref();
        let heads = match host {
            Some(host) if !mean_z.is_autodiff() => {
                host.colour_of_directions(mean_z, dirs, &self.direction_encoding)?
            }
            _ => self
                .colour
                .forward(mean_z, self.direction_encoding.forward(dirs)?)?,
        };
        let c0 = heads.c0.clone();
        // Shuffling is F_B's augmentation: the fixed rules of (b)-(d) would only average noise.
        let blend_c0 = scene
            .c0_shuffle
            .filter(|_| self.variant.uses_blender())
            .map(|s| s.apply(heads.c0.clone(), visibility.clone(), real_points));
        watch.mark(Stage::Mlps);
        let inputs = BlendInputs {
            c0: blend_c0.clone().unwrap_or(heads.c0),
            confidence: heads.confidence,
            h: heads.h,
            source_colours: source_colours.clone(),
            pixel_feature: l,
            view_dir_features,
            visibility,
        };
        // F_B on the host at inference on the CPU backends, with everything after its logits
        // in one host pass; the fixed rules as they are.
        let (blended, ibr_colour) = match host {
            Some(host) if self.variant.uses_blender() && !inputs.h.is_autodiff() => {
                host.blend_colour(&self.blender, inputs, scene.c0_weight_scale)?
            }
            _ => {
                // `[render] c0_weight_scale` (inference only): c0's odds in F_B's blend
                // rescaled before its one mix.
                let scale = scene.c0_weight_scale.filter(|_| !inputs.h.is_autodiff());
                let blended = self
                    .blender
                    .colour_with_c0_scale(self.variant, inputs, scale)?;
                let ibr_colour = ibr_only_colour(blended.blend_weights.clone(), source_colours);
                (blended, ibr_colour)
            }
        };
        watch.mark(Stage::Blending);
        Ok(PointOutput {
            sigma,
            colour: blended.colour,
            c0,
            blend_c0,
            blend_weights: blended.blend_weights,
            ibr_colour,
        })
    }
}

/// Whether point inputs carry the scene's visual-hull carving ([`NiaModel::point_inputs_with`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Carving {
    /// The scene's (none when it has no hull).
    Scene,
    /// None: the density comes from where the carving was applied already.
    None,
}

/// The density half of the network at M points ([`NiaModel::query_density`]) and the inputs
/// of the colour half.
#[derive(Debug, Clone)]
pub(crate) struct DensityPass {
    /// [M] density sigma, per metre.
    pub sigma: Tensor<1>,
    /// [M, d] the view mean of the attention's output, read by F_c0.
    mean_z: Tensor<2>,
    /// [N, M, d] pixel features l_n (F_B's p_n).
    l: Tensor<3>,
    /// [N, M, 2]
    proj_grid: Tensor<3>,
    /// [N, M, 4]
    view_dir_features: Tensor<3>,
    /// [N, M]
    visibility: Tensor<2>,
    /// [M, 3]
    dirs: Tensor<2>,
    /// Points before shape-bucket padding ([`PointTensors::real_points`]).
    real_points: usize,
}

impl DensityPass {
    /// The pass at `points` with their density, view mean and pixel features.
    fn at(points: &PointTensors, sigma: Tensor<1>, mean_z: Tensor<2>, l: Tensor<3>) -> Self {
        DensityPass {
            sigma,
            mean_z,
            l,
            proj_grid: points.proj_grid.clone(),
            view_dir_features: points.view_dir_features.clone(),
            visibility: points.visibility.clone(),
            dirs: points.dirs.clone(),
            real_points: points.real_points,
        }
    }

    /// The points at `index` ([K] Int, into M), in that order; the first `real_points` of
    /// them are points, the rest shape-bucket padding.
    pub fn select(&self, index: Tensor<1, Int>, real_points: usize) -> Self {
        DensityPass {
            real_points,
            sigma: self.sigma.clone().select(0, index.clone()),
            mean_z: self.mean_z.clone().select(0, index.clone()),
            l: self.l.clone().select(1, index.clone()),
            proj_grid: self.proj_grid.clone().select(1, index.clone()),
            view_dir_features: self.view_dir_features.clone().select(1, index.clone()),
            visibility: self.visibility.clone().select(1, index.clone()),
            dirs: self.dirs.clone().select(0, index),
        }
    }
}

/// The point inputs of M points padded to `rows.of(M)` rows and uploaded
/// ([`upload_point_inputs`]), the M points first ([`PointTensors::real_points`] = M); `watch`
/// charges the host part to [`Stage::PointInputs`].
pub(crate) fn upload_padded(
    scene: &SceneEncoding,
    inputs: PointInputs,
    rows: CallRows,
    watch: &mut Stopwatch<'_>,
) -> Result<PointTensors, ModelError> {
    let m = inputs.num_points;
    let inputs = inputs.padded(rows.of(m));
    watch.mark(Stage::PointInputs);
    let mut tensors = upload_point_inputs(scene, inputs)?;
    tensors.real_points = m;
    Ok(tensors)
}

/// [`NiaModel::point_tensors`]' upload: `inputs` on the scene's device, with the body volume
/// read on the host where the scene keeps a host copy of it.
pub(crate) fn upload_point_inputs(
    scene: &SceneEncoding,
    inputs: PointInputs,
) -> Result<PointTensors, ModelError> {
    let device = scene.images.device();
    match (&scene.host_volume, inputs.corners.is_empty()) {
        (Some(host), false) => PointTensors::upload_read(inputs, host, &device),
        _ => Ok(PointTensors::upload(&inputs, &device)),
    }
}

/// The source colours under the blend weights of the views, renormalised over the views.
///
/// # Shapes
/// - `blend_weights`: `[M, N + 1]` (index 0 = c0); `source_colours`: `[N, M, 3]`
/// - output: `[M, 3]`
fn ibr_only_colour(blend_weights: Tensor<2>, source_colours: Tensor<3>) -> Tensor<2> {
    let [n, m, _] = source_colours.dims();
    let views = blend_weights
        .slice(s![.., 1..n + 1])
        .add_scalar(IBR_ONLY_FLOOR)
        .transpose()
        .reshape([n, m, 1]);
    let total = views.clone().sum_dim(0);
    ((source_colours * views).sum_dim(0) / total).reshape([m, 3])
}
