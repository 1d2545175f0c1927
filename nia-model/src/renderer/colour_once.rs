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
//! It runs as a rescaling of the chosen samples' outputs by `acc / W_K`, so the renderer's
//! compositing is the paper's quadrature unchanged.

use burn::prelude::*;

use crate::error::ModelError;
use crate::field::PointOutput;
use crate::kernels::blocked_rows::scatter_add_rows;
use crate::kernels::readback::host_values;
use crate::model::NiaModel;
use crate::renderer::shape_buckets::CallRows;
use crate::sampler::RaySamples;
use crate::scene_encoding::SceneEncoding;
use crate::timing::Stopwatch;

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
    let mut per_ray: Vec<Vec<usize>> = vec![Vec::new(); rays];
    for (p, &r) in ray_of.iter().enumerate() {
        per_ray[r].push(p);
    }
    let mut chosen = Vec::new();
    for points in &mut per_ray {
        let acc: f32 = points.iter().map(|&p| weight[p]).sum();
        if !(acc >= MIN_RAY_WEIGHT) || k == 0 {
            continue;
        }
        points.sort_by(|&a, &b| weight[b].total_cmp(&weight[a]));
        points.truncate(k);
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
            let (alpha, step) = if step.is_finite() && step >= 0.0 {
                (1.0 - (-step).exp(), step)
            } else {
                (1.0, f32::INFINITY)
            };
            let w = (-tau[r]).exp() * alpha;
            tau[r] += step;
            w
        })
        .collect()
}

impl NiaModel {
    /// The field at the kept samples of `samples` in the colour-once mode (module docs): the
    /// density walk (with `termination`), then the whole network at the `k` chosen samples of
    /// each ray. Returns the outputs of the evaluated points (zero colour but at the chosen
    /// ones, rescaled), their flat `[R * S]` sample indices in the same order, and how many
    /// got a colour evaluation.
    pub(crate) fn field_colour_once(
        &self,
        scene: &SceneEncoding,
        samples: &RaySamples,
        termination: Option<f32>,
        k: usize,
        watch: &mut Stopwatch<'_>,
    ) -> Result<(PointOutput, Vec<usize>, usize), ModelError> {
        // The density walk: a budget no ray can spend culls every colour evaluation.
        let (density, index, _) =
            self.field_front_to_back(scene, samples, termination, Some(f32::INFINITY), watch)?;
        let s = samples.per_ray.max(1);
        let rays = samples.t.len() / s;
        // Front to back per ray: the walk returns points segment by segment, each ray's in
        // order, so its order already is front to back within every ray.
        let sigma = host_values(density.sigma.clone())
            .map_err(|e| ModelError::Input(format!("reading densities: {e}")))?;
        let ray_of: Vec<usize> = index.iter().map(|&f| f / s).collect();
        let steps: Vec<f32> = index
            .iter()
            .zip(&sigma)
            .map(|(&f, &sigma)| sigma * samples.delta[f])
            .collect();
        let weights = point_weights(&ray_of, &steps, rays);
        let chosen = colour_points(&ray_of, &weights, rays, k);
        if chosen.is_empty() {
            return Ok((density, index, 0));
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
        let inputs = self.point_tensors(scene, &points, &dirs, rows, watch)?;
        let coloured = self.query_with(scene, &inputs, watch)?.first(points.len());
        let device = scene.images.device();
        let m = index.len();
        let factor = Tensor::<1>::from_data(
            TensorData::new(
                chosen.iter().map(|c| c.factor).collect::<Vec<_>>(),
                [chosen.len()],
            ),
            &device,
        )
        .unsqueeze_dim::<2>(1);
        let rows = Tensor::<1, Int>::from_data(
            TensorData::new(
                chosen.iter().map(|c| c.point as i64).collect::<Vec<_>>(),
                [chosen.len()],
            ),
            &device,
        );
        // The chosen rows, rescaled, into zeros of the evaluated points' shape.
        let place = |values: Tensor<2>| {
            let width = values.dims()[1];
            scatter_add_rows(
                Tensor::<2>::zeros([m, width], &device),
                rows.clone(),
                values * factor.clone(),
            )
        };
        let out = PointOutput {
            sigma: density.sigma,
            colour: place(coloured.colour),
            c0: place(coloured.c0),
            blend_c0: None,
            blend_weights: place(coloured.blend_weights),
            ibr_colour: place(coloured.ibr_colour),
        };
        Ok((out, index, chosen.len()))
    }
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
