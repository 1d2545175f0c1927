//! Colour where the picture needs it (adaptive work, inference only; not in the paper,
//! `[render] colour_points`): the density at every kept sample, the colour at a few samples of
//! each ray.
//!
//! The paper colours every sample: F_c0, the source colours and F_B at each of the S samples,
//! then `C = sum_i w_i c_i`. Once a density field is sharp, a ray's weight sits on one or two
//! samples at the surface, and the colour half of the network (about two thirds of its
//! arithmetic per point at the paper's widths) spent anywhere else changes the pixel by
//! little. This mode walks the density half front to back (with early termination, as
//! [`crate::renderer::termination`]), computes each ray's weights `w_i` and opacity
//! `acc = sum_i w_i`, picks the `K` samples with the largest weights, evaluates the whole
//! network there only, and composites
//!
//! ```text
//! C = acc sum_(j in top K) (w_j / W_K) c_j,        W_K = sum_(j in top K) w_j
//! ```
//!
//! (the same for c0, the IBR-only colour and the blend maps). Opacity and depth are exact;
//! `C` equals the paper's where the colour is constant over the ray's weight. A ray that
//! misses, or whose weights are all (near) zero, gets no colour evaluation and stays black.
//! The composite runs on the host over the chosen points only, with the quadrature's weights
//! ([`NiaModel::render_colour_once`]; no `[R * S]` tensors). The density comes from the walk,
//! or from the grid baked for the pose ([`crate::renderer::density_grid`]), which also allows
//! the paper's per-sample colour (every sample colour culling keeps) on the baked density.

use burn::prelude::*;
use rayon::prelude::*;

use crate::error::ModelError;
use crate::field::PointOutput;
use crate::ibr::blend_host::IBR_ONLY_FLOOR;
use crate::ibr::surface::surface_colours_of;
use crate::kernels::readback::host_values;
use crate::model::NiaModel;
use crate::renderer::colour_culling::cull;
use crate::renderer::quadrature::{RenderOutput, OPTICAL_DEPTH_MAX};
use crate::renderer::shape_buckets::CallRows;
use crate::sampler::RaySamples;
use crate::scene_encoding::SceneEncoding;
use crate::timing::{Stage, Stopwatch};
use nia_data::geometry::rays::RayBundle;

/// Weight below which a ray has nothing to colour (its opacity cannot reach a visible level).
pub const MIN_RAY_WEIGHT: f32 = 1e-6;

/// A sample chosen for colour: its position among the evaluated points, and the factor
/// `acc / W_K` of its ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColourPoint {
    pub point: usize,
    pub factor: f32,
}

/// The `k` samples of each ray with the largest weights, with their rays' factors (module
/// docs). `ray_of[p]` and `weight[p]` are evaluated point `p`'s ray and weight
/// `w = T (1 - exp(-sigma delta))`; `rays` the chunk's ray count. A ray whose weights sum to
/// less than [`MIN_RAY_WEIGHT`] gets none.
pub fn colour_points(ray_of: &[usize], weight: &[f32], rays: usize, k: usize) -> Vec<ColourPoint> {
    // Each ray's points in one flat list (a counting sort by ray: no list per ray).
    let mut start = vec![0usize; rays + 1];
    for &r in ray_of {
        start[r + 1] += 1;
    }
    for r in 0..rays {
        start[r + 1] += start[r];
    }
    let mut next = start.clone();
    let mut flat = vec![0usize; ray_of.len()];
    for (p, &r) in ray_of.iter().enumerate() {
        flat[next[r]] = p;
        next[r] += 1;
    }
    let mut chosen = Vec::new();
    for r in 0..rays {
        let points = &mut flat[start[r]..start[r + 1]];
        let acc: f32 = points.iter().map(|&p| weight[p]).sum();
        if !(acc >= MIN_RAY_WEIGHT) || k == 0 {
            continue;
        }
        points.sort_unstable_by(|&a, &b| weight[b].total_cmp(&weight[a]).then(a.cmp(&b)));
        let points = &points[..k.min(points.len())];
        let top: f32 = points.iter().map(|&p| weight[p]).sum();
        if !(top > 0.0) {
            continue;
        }
        let factor = acc / top;
        chosen.extend(
            points
                .iter()
                .filter(|&&p| weight[p] > 0.0)
                .map(|&point| ColourPoint { point, factor }),
        );
    }
    chosen
}

/// Each evaluated point's weight along its ray, `w_i = exp(-tau_i) (1 - exp(-sigma_i
/// delta_i))`, from its density and interval, the points of one ray in front-to-back order
/// (other rays' points may come between them), as the quadrature computes it. A non-finite
/// density makes the point opaque.
pub fn point_weights(ray_of: &[usize], steps: &[f32], rays: usize) -> Vec<f32> {
    let mut tau = vec![0.0f32; rays];
    ray_of
        .iter()
        .zip(steps)
        .map(|(&r, &step)| {
            // The quadrature's optical depth: clamped to [0, OPTICAL_DEPTH_MAX], NaN opaque.
            let step = match step.is_nan() {
                true => OPTICAL_DEPTH_MAX,
                false => step.clamp(0.0, OPTICAL_DEPTH_MAX),
            };
            let w = (-tau[r]).exp() * (1.0 - (-step).exp());
            tau[r] += step;
            w
        })
        .collect()
}

/// What the colour-once pass decided and computed ([`NiaModel::colour_once_pass`]).
pub(crate) struct OncePass {
    /// The evaluated points' flat `[R * S]` sample indices, each ray's front to back.
    index: Vec<usize>,
    /// Their weights `w_i`, as the quadrature computes them.
    weights: Vec<f32>,
    /// The points given a colour (positions in `index`) with their rays' factors.
    chosen: Vec<ColourPoint>,
    /// The whole network at the chosen points, `[chosen]` rows; `None` when none was chosen.
    coloured: Option<PointOutput>,
}

impl NiaModel {
    /// The colour-once pass over the kept samples of `samples` (module docs): the density walk
    /// (with `termination`) or the scene's baked density ([`crate::renderer::density_grid`]),
    /// each ray's weights, then the whole network at the `k` chosen samples of each ray
    /// (`None`: at every sample with a density that colour culling keeps, the paper's
    /// per-sample colour).
    fn colour_once_pass(
        &self,
        scene: &SceneEncoding,
        samples: &RaySamples,
        termination: Option<f32>,
        k: Option<usize>,
        watch: &mut Stopwatch<'_>,
    ) -> Result<OncePass, ModelError> {
        let s = samples.per_ray.max(1);
        let rays = samples.t.len() / s;
        let (index, sigma) = match &scene.density_grid {
            // The density baked for this pose, read at every kept sample (`density_grid`).
            Some(grid) => {
                let sigma: Vec<f32> = samples
                    .points
                    .par_iter()
                    .map(|&x| grid.sigma_at(x))
                    .collect();
                let index: Vec<usize> = match &samples.kept {
                    Some(kept) => kept.clone(),
                    None => (0..samples.total()).collect(),
                };
                watch.mark(Stage::PointInputs);
                (index, sigma)
            }
            None => {
                // The density walk: a budget no ray can spend culls every colour evaluation.
                let (density, index, _) = self.field_front_to_back(
                    scene,
                    samples,
                    termination,
                    Some(f32::INFINITY),
                    watch,
                )?;
                let sigma = host_values(density.sigma)
                    .map_err(|e| ModelError::Input(format!("reading densities: {e}")))?;
                (index, sigma)
            }
        };
        // Front to back per ray: the walk returns points segment by segment, each ray's in
        // order, and the kept samples are in flat order, so within every ray the points are
        // front to back.
        let ray_of: Vec<usize> = index.iter().map(|&f| f / s).collect();
        let steps: Vec<f32> = index
            .iter()
            .zip(&sigma)
            .map(|(&f, &sigma)| sigma * samples.delta[f].max(0.0))
            .collect();
        let weights = point_weights(&ray_of, &steps, rays);
        let chosen = match k {
            Some(k) => colour_points(&ray_of, &weights, rays, k),
            // Every sample but those colour culling leaves out (all of them without it), each
            // with its own weight: the paper's per-sample colour on the baked density.
            None => {
                let (mut tau, mut spent) = (vec![0.0f32; rays], vec![0.0f32; rays]);
                let epsilon = scene.colour_culling.unwrap_or(f32::NEG_INFINITY);
                cull(&ray_of, &steps, &mut tau, &mut spent, epsilon)
                    .into_iter()
                    .enumerate()
                    .filter(|&(p, coloured)| coloured && weights[p] > 0.0)
                    .map(|(point, _)| ColourPoint { point, factor: 1.0 })
                    .collect()
            }
        };
        if chosen.is_empty() {
            return Ok(OncePass {
                index,
                weights,
                chosen,
                coloured: None,
            });
        }
        // The walk names samples by their flat [R * S] index; the sample points are the kept
        // ones, in the kept list's order.
        let position: Option<Vec<u32>> = samples.kept.as_ref().map(|kept| {
            let mut position = vec![u32::MAX; samples.total()];
            for (p, &flat) in kept.iter().enumerate() {
                position[flat] = p as u32;
            }
            position
        });
        let kept_position = |flat: usize| match &position {
            Some(position) => position
                .get(flat)
                .filter(|&&p| p != u32::MAX)
                .map(|&p| p as usize),
            None => Some(flat),
        };
        let mut points = Vec::with_capacity(chosen.len());
        let mut dirs = Vec::with_capacity(chosen.len());
        for c in &chosen {
            let p = kept_position(index[c.point]).ok_or_else(|| {
                ModelError::Input(format!(
                    "colour once: sample {} is not kept",
                    index[c.point]
                ))
            })?;
            points.push(samples.points[p]);
            dirs.push(samples.dirs[p]);
        }
        // The whole network at the chosen points, padded to a bucket on a GPU.
        let rows = CallRows::on(&scene.images.device());
        let coloured = match &scene.density_grid {
            // The visibility baked with the density, read at the points, and the colour half
            // alone (the density is the grid's).
            Some(grid) => {
                let inputs =
                    self.point_tensors_on_grid(scene, grid, &points, &dirs, rows, watch)?;
                self.query_colour_half(scene, &inputs, watch)?
            }
            None => {
                let inputs = self.point_tensors(scene, &points, &dirs, rows, watch)?;
                self.query_with(scene, &inputs, watch)?
            }
        }
        .first(points.len());
        Ok(OncePass {
            index,
            weights,
            chosen,
            coloured: Some(coloured),
        })
    }

    /// The colour-once pass composited on the host: the rays' colours, NeRF colours, IBR-only
    /// colours and blend maps summed over their chosen points only (`w_j` times the ray's
    /// factor), opacity and depth over every evaluated point, with the weights the pass
    /// computed (the quadrature's). The same output as the pass scattered to `[R * S]` samples
    /// and composited with [`crate::renderer::render_rays_delta`] (float reordering aside),
    /// without the `[R * S]` tensors' scatters and products. `point_evaluations` counts the
    /// network's points (the coloured ones alone with a baked density). With the source colours
    /// read at the surface (`ibr::surface`), the surface form too, on the host, for the rays
    /// with any opacity (a ray without has colour and IBR-only colour zero in that form).
    pub(crate) fn render_colour_once(
        &self,
        scene: &SceneEncoding,
        rays: &RayBundle,
        samples: &RaySamples,
        watch: &mut Stopwatch<'_>,
    ) -> Result<RenderOutput, ModelError> {
        let k = scene.colour_points;
        let pass = self.colour_once_pass(scene, samples, scene.termination, k, watch)?;
        let s = samples.per_ray.max(1);
        let r = samples.t.len() / s;
        let n1 = scene.num_views() + 1;
        let mut acc = vec![0.0f32; r];
        let mut depth = vec![0.0f32; r];
        let mut weights = vec![0.0f32; r * s];
        for (&flat, &w) in pass.index.iter().zip(&pass.weights) {
            acc[flat / s] += w;
            depth[flat / s] += w * samples.t[flat];
            weights[flat] = w;
        }
        // [R, 3 + 3 + 3 + N + 1 + 3]: colour, c0, IBR-only colour, blend weights, and the
        // NeRF part of the surface form, sum_j w_j b0_j c0_j.
        let read = 9 + n1;
        let width = read + 3;
        let mut sums = vec![0.0f32; r * width];
        if let Some(coloured) = pass.coloured {
            let columns = Tensor::cat(
                vec![
                    coloured.colour,
                    coloured.c0,
                    coloured.ibr_colour,
                    coloured.blend_weights,
                ],
                1,
            );
            let values = host_values(columns)
                .map_err(|e| ModelError::Input(format!("reading the coloured points: {e}")))?;
            for (c, row) in pass.chosen.iter().zip(values.chunks_exact(read)) {
                let ray = pass.index[c.point] / s;
                let wf = pass.weights[c.point] * c.factor;
                let to = &mut sums[ray * width..(ray + 1) * width];
                to.iter_mut().zip(row).for_each(|(t, v)| *t += wf * v);
                let b0 = row[9];
                for (t, c0) in to[read..].iter_mut().zip(&row[3..6]) {
                    *t += wf * b0 * c0;
                }
            }
        }
        if self.reads_source_colours_at_surface() {
            surface_form_on_host(scene, rays, &mut sums, width, read, &acc, &depth)?;
        }
        let device = scene.images.device();
        let tensor2 = |values: Vec<f32>, width: usize| {
            Tensor::<2>::from_data(TensorData::new(values, [r, width]), &device)
        };
        let columns = tensor2(sums, width);
        let delta: Vec<f32> = samples.delta.iter().map(|d| d.max(0.0)).collect();
        let evaluated = match scene.density_grid {
            Some(_) => pass.chosen.len(),
            None => pass.index.len(),
        };
        let rendered = RenderOutput {
            rgb: columns.clone().slice(s![.., 0..3]),
            rgb0: columns.clone().slice(s![.., 3..6]),
            rgb_ibr: Some(columns.clone().slice(s![.., 6..9])),
            blend_weights: Some(columns.slice(s![.., 9..read])),
            acc: Tensor::<1>::from_data(TensorData::new(acc, [r]), &device),
            depth: Tensor::<1>::from_data(TensorData::new(depth, [r]), &device),
            weights: tensor2(weights, s),
            t: tensor2(samples.t.clone(), s),
            delta: tensor2(delta, s),
            point_evaluations: evaluated,
            colour_evaluations: pass.chosen.len(),
        };
        Ok(rendered)
    }
}

/// The surface form (`ibr::surface`) of the colour-once composite, on the host: for each ray
/// with any opacity, `C = nerf_part + sum_n W_n c_n(x_s)` and the IBR-only colour
/// `acc sum_n (W_n + floor) c_n(x_s) / sum_n (W_n + floor)`, written over columns 0..3 and
/// 6..9 of its row of `sums` (`[R, width]`: colour, c0, IBR-only colour, the blend weights
/// `W` in `9..read` with c0's first, the NeRF part in `read..read + 3`). A ray without
/// opacity keeps zero in both, as [`surface_composite`](crate::ibr::surface::surface_composite)
/// gives it (its `W_n` and NeRF part are zero).
fn surface_form_on_host(
    scene: &SceneEncoding,
    rays: &RayBundle,
    sums: &mut [f32],
    width: usize,
    read: usize,
    acc: &[f32],
    depth: &[f32],
) -> Result<(), ModelError> {
    let lit: Vec<usize> = (0..acc.len()).filter(|&r| acc[r] > 0.0).collect();
    if lit.is_empty() {
        return Ok(());
    }
    let pick = |values: &[f32]| lit.iter().map(|&r| values[r]).collect::<Vec<f32>>();
    let colours = surface_colours_of(scene, &rays.select(&lit), &pick(depth), &pick(acc))?;
    let colours = host_values(colours)
        .map_err(|e| ModelError::Input(format!("reading surface colours: {e}")))?; // [N, L, 3]
    let (n, l) = (scene.num_views(), lit.len());
    for (j, &r) in lit.iter().enumerate() {
        let row = &mut sums[r * width..(r + 1) * width];
        let (mut rgb, mut ibr, mut total) = ([0.0f32; 3], [0.0f32; 3], 0.0f32);
        for view in 0..n {
            let w = row[10 + view];
            let c = &colours[(view * l + j) * 3..][..3];
            let w_ibr = w + IBR_ONLY_FLOOR;
            total += w_ibr;
            for ch in 0..3 {
                rgb[ch] += w * c[ch];
                ibr[ch] += w_ibr * c[ch];
            }
        }
        for ch in 0..3 {
            row[ch] = row[read + ch] + rgb[ch];
            row[6 + ch] = ibr[ch] / total * acc[r];
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOL: f32 = 1e-6;

    #[test]
    fn each_ray_colours_its_heaviest_samples_scaled_to_its_opacity() {
        // Ray 0: two surfaces (0.4 then 0.5 of weight, 0.1 spread elsewhere); ray 1: all
        // transparent; ray 2: no sample at all (it missed); ray 3: one opaque sample.
        let ray_of = [0, 0, 0, 0, 1, 1, 3];
        let weight = [0.05, 0.4, 0.05, 0.5, 0.0, 1e-9, 1.0];
        let one = colour_points(&ray_of, &weight, 4, 1);
        assert_eq!(one.len(), 2, "{one:?}");
        assert_eq!(one[0].point, 3);
        assert!((one[0].factor - 1.0 / 0.5).abs() < TOL);
        assert_eq!((one[1].point, one[1].factor), (6, 1.0));
        let two = colour_points(&ray_of, &weight, 4, 2);
        let ray0: Vec<usize> = two
            .iter()
            .filter(|c| ray_of[c.point] == 0)
            .map(|c| c.point)
            .collect();
        assert_eq!(ray0, vec![3, 1]);
        for c in two.iter().filter(|c| ray_of[c.point] == 0) {
            assert!((c.factor - 1.0 / 0.9).abs() < TOL);
        }
        // Composited: the chosen weights times their factors give back the ray's opacity.
        let acc0: f32 = two
            .iter()
            .filter(|c| ray_of[c.point] == 0)
            .map(|c| weight[c.point] * c.factor)
            .sum();
        assert!((acc0 - 1.0).abs() < TOL);
        assert!(colour_points(&ray_of, &weight, 4, 0).is_empty());
    }

    #[test]
    fn weights_follow_the_quadrature_and_survive_infinite_density() {
        // One ray: alpha 0.5 twice, then an infinite density; another ray interleaved.
        let half = 2f32.ln();
        let ray_of = [0, 1, 0, 0];
        let steps = [half, 0.0, half, f32::INFINITY];
        let w = point_weights(&ray_of, &steps, 2);
        for (got, want) in w.iter().zip([0.5, 0.0, 0.25, 0.25]) {
            assert!((got - want).abs() < TOL, "{w:?}");
        }
        let nan = point_weights(&[0, 0], &[f32::NAN, 1.0], 1);
        assert!(nan.iter().all(|x| x.is_finite()) && (nan[0] - 1.0).abs() < TOL && nan[1] == 0.0);
    }
}
