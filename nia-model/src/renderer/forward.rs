//! [`NiaModel::render`]: one batch of rays through sampler -> field -> renderer.
//!
//! ```text
//! sample      RaySamples::new / in_band     stratified or band t, occupancy- and hull-aware
//! evaluate    NiaModel::field (or front to back with termination / colour culling)
//! scatter     evaluated points back to their [R * S] samples (skipped ones stay zero)
//! composite   render_rays_delta             NeRF quadrature, then the IBR composites
//! ```

use burn::prelude::*;
use glam::Vec3;
use nia_data::geometry::rays::RayBundle;

use super::quadrature::{render_rays_delta, RenderOutput};
use super::shape_buckets::CallRows;
use crate::config::SourceColoursAt;
use crate::error::ModelError;
use crate::field::PointOutput;
use crate::ibr::surface::{surface_colours, surface_composite};
use crate::kernels::blocked_rows::scatter_add_rows;
use crate::model::NiaModel;
use crate::sampler::RaySamples;
use crate::scene_encoding::SceneEncoding;
use crate::timing::{Stage, StageTimes, Stopwatch};
use crate::variant::Variant;

/// The field's outputs at every sample of R rays, `[R * S]` rows (zero where not evaluated).
struct SampleFields {
    /// `[R * S]`
    sigma: Tensor<1>,
    /// `[R * S, 3]`
    colour: Tensor<2>,
    /// `[R * S, 3]`
    c0: Tensor<2>,
    /// `[R * S, N + 1]`
    blend: Tensor<2>,
    /// `[R * S, 3]`
    ibr: Tensor<2>,
    /// `[R * S, 3]` the c0 F_B blended (training with c0 shuffling).
    blend_c0: Option<Tensor<2>>,
    /// Points the field evaluated.
    evaluated: usize,
    /// Of those, points the colour half evaluated.
    colour_evaluated: usize,
}

impl NiaModel {
    /// Renders `rays` of `scene` with `samples` samples each: sampler -> field -> renderer.
    /// `jitter` ([R * S] in [0, 1]) is the training-time offset inside each bin; `None` samples
    /// bin centres. Samples the occupancy grid of `scene` marks empty keep zero density without
    /// reaching the field, and so do, without jitter, the samples behind what a ray has made
    /// opaque when `scene` terminates rays early (`renderer::termination`). With
    /// `source_colours_at = surface` the source views' part of the colour is read once per ray
    /// at the expected surface point (`ibr::surface`). `times` charges sampling, MLPs, blending
    /// and compositing.
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
        let ray_samples = sample(scene, rays, samples, jitter)?;
        // Colour at a few points per ray, or the baked density: composited on the host from
        // the points that have a colour (`colour_once`); with the source colours read at the
        // surface, from the composited weights as `composite` does.
        let once = scene.colour_points.is_some() || scene.density_grid.is_some();
        if once && jitter.is_none() && ray_samples.evaluated() > 0 {
            let rendered = self.render_colour_once(scene, rays, &ray_samples, &mut watch)?;
            watch.mark(Stage::Compositing);
            return Ok(rendered);
        }
        let fields = self.evaluate(scene, &ray_samples, jitter, &mut watch)?;
        let rendered = self.composite(scene, rays, &ray_samples, fields)?;
        watch.mark(Stage::Compositing);
        Ok(rendered)
    }

    /// The field at the samples that need it, scattered back to all `[R * S]` samples.
    /// Early ray termination and colour culling (inference: no jitter) evaluate front to
    /// back; otherwise every kept sample is evaluated in one call.
    fn evaluate(
        &self,
        scene: &SceneEncoding,
        ray_samples: &RaySamples,
        jitter: Option<&[f32]>,
        watch: &mut Stopwatch<'_>,
    ) -> Result<SampleFields, ModelError> {
        let total = ray_samples.total();
        let device = scene.images.device();
        if ray_samples.evaluated() == 0 {
            let n1 = scene.num_views() + 1;
            let zeros = |width: usize| Tensor::<2>::zeros([total, width], &device);
            return Ok(SampleFields {
                sigma: Tensor::zeros([total], &device),
                colour: zeros(3),
                c0: zeros(3),
                blend: zeros(n1),
                ibr: zeros(3),
                blend_c0: None,
                evaluated: 0,
                colour_evaluated: 0,
            });
        }
        // (Colour once and the baked density never come here: `render` composites them.)
        let adaptive = scene.termination.is_some() || scene.colour_culling.is_some();
        let (out, kept, evaluated, colour_evaluated) = if adaptive && jitter.is_none() {
            let (out, index, coloured) = self.field_front_to_back(
                scene,
                ray_samples,
                scene.termination,
                scene.colour_culling,
                watch,
            )?;
            let all_in_order =
                index.len() == total && index.iter().enumerate().all(|(i, &f)| i == f);
            let evaluated = index.len();
            (out, (!all_in_order).then_some(index), evaluated, coloured)
        } else {
            let (points, dirs) = (&ray_samples.points, &ray_samples.dirs);
            // On a GPU backend (training too) the call is padded to its shape bucket; the
            // scatter drops the padding. At inference a chunk of more points than a call
            // takes goes in several calls (training's step is one call, as its rays are).
            let out = if jitter.is_none() && points.len() > scene.points_per_call {
                self.field_in_calls(scene, points, dirs, watch)?
            } else {
                let inputs =
                    self.point_tensors(scene, points, dirs, CallRows::on(&device), watch)?;
                self.query_with(scene, &inputs, watch)?
            };
            let evaluated = ray_samples.evaluated();
            (out, ray_samples.kept.clone(), evaluated, evaluated)
        };
        Ok(scatter(
            out,
            kept.as_deref(),
            total,
            evaluated,
            colour_evaluated,
        ))
    }

    /// The field at `points` / `dirs` ([M] each) in calls of at most the scene's
    /// `points_per_call` points, the outputs in order. On a GPU backend each call is padded to
    /// its bucket and the last call's padding kept (as [`Self::point_tensors`] says: more than
    /// M rows, which the scatter sends to its spare row, so its shapes stay bucketed).
    fn field_in_calls(
        &self,
        scene: &SceneEncoding,
        points: &[Vec3],
        dirs: &[Vec3],
        watch: &mut Stopwatch<'_>,
    ) -> Result<PointOutput, ModelError> {
        let rows = CallRows::on(&scene.images.device());
        let call = scene.points_per_call.max(1);
        let calls = points.len().div_ceil(call);
        let mut parts = Vec::new();
        for (k, (points, dirs)) in points.chunks(call).zip(dirs.chunks(call)).enumerate() {
            let inputs = self.point_tensors(scene, points, dirs, rows, watch)?;
            let out = self.query_with(scene, &inputs, watch)?;
            // Every padded call but the last drops its padding.
            parts.push(if rows == CallRows::Bucket && k + 1 < calls {
                out.first(points.len())
            } else {
                out
            });
        }
        PointOutput::cat(parts).ok_or_else(|| ModelError::Input("no point to evaluate".into()))
    }

    /// NeRF quadrature of the sample fields, then the IBR composites: the per-sample IBR
    /// colour under the weights, or (`source_colours_at = surface`) the source colours read
    /// once at the expected surface point.
    fn composite(
        &self,
        scene: &SceneEncoding,
        rays: &RayBundle,
        ray_samples: &RaySamples,
        fields: SampleFields,
    ) -> Result<RenderOutput, ModelError> {
        let device = scene.images.device();
        let (r, s) = (rays.len(), ray_samples.per_ray);
        let n1 = scene.num_views() + 1;
        // The NeRF part of the colour, kept for the surface form (sum_i w_i b0_i c0_i); with
        // c0 shuffling (training) made of the c0 that F_B blended.
        let surface = self.reads_source_colours_at_surface() && fields.evaluated > 0;
        let nerf_colour = surface.then(|| {
            fields.blend.clone().slice(s![.., 0..1])
                * fields.blend_c0.unwrap_or_else(|| fields.c0.clone())
        });
        let per_ray = |values: &[f32]| {
            Tensor::<2>::from_data(TensorData::new(values.to_vec(), [r, s]), &device)
        };
        let mut rendered = render_rays_delta(
            fields.sigma.reshape([r, s]),
            fields.colour.reshape([r, s, 3]),
            fields.c0.reshape([r, s, 3]),
            per_ray(&ray_samples.t),
            per_ray(&ray_samples.delta),
            Some(fields.blend.reshape([r, s, n1])),
        )?;
        // sum_i w_i x_i of a per-sample colour [R * S, 3] -> [R, 3].
        let weights = rendered.weights.clone().reshape([r, s, 1]);
        let composite = |x: Tensor<2>| {
            (x.reshape([r, s, 3]) * weights.clone())
                .sum_dim(1)
                .reshape([r, 3])
        };
        match nerf_colour {
            None => rendered.rgb_ibr = Some(composite(fields.ibr)),
            Some(nerf_colour) => {
                surface_form(scene, rays, &mut rendered, composite(nerf_colour))?;
            }
        }
        rendered.point_evaluations = fields.evaluated;
        rendered.colour_evaluations = fields.colour_evaluated;
        Ok(rendered)
    }
}

impl NiaModel {
    /// Whether this model reads the source colours once per ray at the expected surface point
    /// (`source_colours_at = surface`, a variant with source colours).
    pub(crate) fn reads_source_colours_at_surface(&self) -> bool {
        self.source_colours_at == SourceColoursAt::Surface && self.variant != Variant::NoIbr
    }
}

/// The surface form of `rendered`'s colour and IBR-only composite (`ibr::surface`): the source
/// colours read at each ray's expected surface point, blended with its composited view weights
/// and `nerf_part` (`[R, 3]` sum_i w_i b0_i c0_i).
fn surface_form(
    scene: &SceneEncoding,
    rays: &RayBundle,
    rendered: &mut RenderOutput,
    nerf_part: Tensor<2>,
) -> Result<(), ModelError> {
    let n1 = scene.num_views() + 1;
    let view_weights = rendered
        .blend_weights
        .clone()
        .map(|b| b.slice(s![.., 1..n1]))
        .ok_or_else(|| ModelError::Input("render without blend weights".into()))?;
    let colours = surface_colours(scene, rays, rendered.depth.clone(), rendered.acc.clone())?;
    let (rgb, rgb_ibr) = surface_composite(nerf_part, view_weights, colours, rendered.acc.clone());
    rendered.rgb = rgb;
    rendered.rgb_ibr = Some(rgb_ibr);
    Ok(())
}

/// The samples of `rays` that the scene needs evaluated: stratified (or in the band), less
/// empty space and, with skipping, what the visual hull carves. A reposed scene reads the hull
/// at the mapped points, inside the field, and skips nothing for it.
fn sample(
    scene: &SceneEncoding,
    rays: &RayBundle,
    samples: usize,
    jitter: Option<&[f32]>,
) -> Result<RaySamples, ModelError> {
    let occupancy = scene.occupancy.as_deref();
    let mut ray_samples = match &scene.band {
        Some(band) => RaySamples::in_band(rays, samples, jitter, band, occupancy)?,
        None => RaySamples::new(rays, samples, jitter, occupancy)?,
    };
    // What the hull carves has density exactly 0 whatever the network says. The kept points
    // read it once more in the field (three projections and bilinear reads each, next to a
    // network evaluation). A baked density already holds the carving (its nodes were carved
    // when baked), so its samples are not carved again.
    if let (Some(_), Some(hull), None, None) = (
        &scene.occupancy,
        &scene.visual_hull,
        &scene.reposer,
        &scene.density_grid,
    ) {
        let cameras = &scene.geometry.cameras;
        ray_samples.retain(|x| hull.carving(cameras, x) > 0.0);
    }
    Ok(ray_samples)
}

/// The outputs of the evaluated points placed at their flat `[R * S]` indices `kept` (all
/// samples in order when `None`); the others keep zero density, colour and weights. `out` may
/// have more rows than points, shape-bucket padding (`renderer::shape_buckets`): with `kept`
/// their outputs go to a spare row after the `[R * S]`, cut off after the scatter, so the
/// index, like the outputs, is a bucket long and the scatter's shapes repeat from call to
/// call.
fn scatter(
    out: PointOutput,
    kept: Option<&[usize]>,
    total: usize,
    evaluated: usize,
    colour_evaluated: usize,
) -> SampleFields {
    let rows = out.sigma.dims()[0];
    let Some(kept) = kept else {
        let out = if rows > total { out.first(total) } else { out };
        return SampleFields {
            sigma: out.sigma,
            colour: out.colour,
            c0: out.c0,
            blend: out.blend_weights,
            ibr: out.ibr_colour,
            blend_c0: out.blend_c0,
            evaluated,
            colour_evaluated,
        };
    };
    let device = out.sigma.device();
    let mut index: Vec<i64> = kept.iter().map(|&i| i as i64).collect();
    index.resize(rows.max(kept.len()), total as i64);
    let spare = usize::from(index.len() > kept.len());
    let len = index.len();
    let index = Tensor::<1, Int>::from_data(TensorData::new(index, [len]), &device);
    let scatter2 = |values: Tensor<2>| {
        let width = values.dims()[1];
        let zeros = Tensor::<2>::zeros([total + spare, width], &device);
        scatter_add_rows(zeros, index.clone(), values).narrow(0, 0, total)
    };
    SampleFields {
        sigma: scatter2(out.sigma.reshape([len, 1])).reshape([total]),
        colour: scatter2(out.colour),
        c0: scatter2(out.c0),
        blend: scatter2(out.blend_weights),
        ibr: scatter2(out.ibr_colour),
        blend_c0: out.blend_c0.map(scatter2),
        evaluated,
        colour_evaluated,
    }
}
