//! Where the source colours c_n are fetched: at every sample (the paper) or once per ray at the
//! expected surface point (not in the paper; `ModelConfig::source_colours_at`).
//!
//! The paper's colour composites the per-sample blend (NIA eq. 5 inside eq. 1):
//!
//! ```text
//! C = sum_i w_i (b0_i c0_i + sum_n b_{n,i} c_n(x_i))
//! ```
//!
//! Each sample x_i reads the source images at its own projection, so a ray whose weights w_i
//! spread over a few centimetres mixes source pixels from along the epipolar segment of that
//! spread: with source views tens of degrees away from the target, fine detail (prints,
//! stripes) is smeared before any blend weight is learned. `SourceColoursAt::Surface` keeps
//! the NeRF part and the learned weights and fetches the views' colours at one point, the
//! expected surface point x_s = o + d * (sum_i w_i t_i / sum_i w_i):
//!
//! ```text
//! C = sum_i w_i b0_i c0_i + sum_n W_n c_n(x_s),      W_n = sum_i w_i b_{n,i}
//! ```
//!
//! Both forms agree when the weights sit on one sample. The blend weights and the densities
//! keep their gradients (through W_n and the NeRF part), and the read itself is differentiable
//! in the expected depth ([`surface_colours`]): where the target pixel matches a source view
//! better a little nearer or farther, the densities along the ray are pulled there. Rays with
//! (almost) no opacity put x_s at the middle of their interval; their W_n are ~0 anyway.

use burn::prelude::*;
use glam::Vec3;
use nia_data::geometry::rays::RayBundle;
use nia_data::scene::projection_grid;

use super::blend_host::IBR_ONLY_FLOOR;
use super::fetch_source_colours_from;
use crate::error::ModelError;
use crate::scene_encoding::SceneEncoding;

/// Opacity below which a ray has no surface point of its own (x_s = middle of the interval).
pub const SURFACE_ACC_FLOOR: f32 = 1e-4;

/// The expected surface point of each ray: `o + d * depth / acc` where `acc` >=
/// [`SURFACE_ACC_FLOOR`], the middle of `[near, far]` otherwise.
///
/// # Shapes
/// - `depth`, `acc`: `[R]` (sum_i w_i t_i and sum_i w_i)
/// - output: `[R]` world points
pub fn surface_points(rays: &RayBundle, depth: &[f32], acc: &[f32]) -> Vec<Vec3> {
    (0..rays.len())
        .map(|r| {
            let t = if acc[r] >= SURFACE_ACC_FLOOR && (depth[r] / acc[r]).is_finite() {
                (depth[r] / acc[r]).clamp(rays.near[r], rays.far[r])
            } else {
                0.5 * (rays.near[r] + rays.far[r])
            };
            rays.origins[r] + rays.dirs[r] * t
        })
        .collect()
}

/// Step along the ray of the finite difference that gives d grid / d t, metres (a tenth of the
/// finest voxel; the projection is smooth at this scale).
pub const SURFACE_GRID_STEP_M: f32 = 5e-4;

/// Grid coordinates beyond this magnitude mark a projection outside the image (the reader
/// writes -4 there); such a view gets no gradient along the ray.
const GRID_INSIDE_BOUND: f32 = 2.0;

/// The source colours c_n(x_s) of the rays' expected surface points, read where the model reads
/// them for samples (at x_s itself, or at its image in the source pose when the scene renders
/// another pose).
///
/// The read is differentiable in the surface depth t_s = depth / acc: the projection grid is
/// linearised along each ray, `grid(t_s) = grid(t0) + J (t_s - t0)` with t0 the detached value
/// and `J = d grid / d t` by a finite difference of [`SURFACE_GRID_STEP_M`] (exact values
/// forward; the slope of the source images at the projection pulls the expected depth towards
/// where the views agree with the target pixel). Rays without a surface point
/// (acc < [`SURFACE_ACC_FLOOR`]) and views whose projection leaves the image get J = 0. Off an
/// autodiff device (inference) the slope is not computed.
///
/// # Shapes
/// - `depth`, `acc`: `[R]` (sum_i w_i t_i and sum_i w_i, with their gradients)
/// - output: `[N, R, 3]`
pub fn surface_colours(
    scene: &SceneEncoding,
    rays: &RayBundle,
    depth: Tensor<1>,
    acc: Tensor<1>,
) -> Result<Tensor<3>, ModelError> {
    let read = |x: &Tensor<1>| -> Result<Vec<f32>, ModelError> {
        x.clone()
            .detach()
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| ModelError::Input(format!("reading depth: {e:?}")))
    };
    let (depth_v, acc_v) = (read(&depth)?, read(&acc)?);
    let points = surface_points(rays, &depth_v, &acc_v);
    let to_grid = |points: Vec<Vec3>| -> Result<Vec<f32>, ModelError> {
        let points = match &scene.reposer {
            None => points,
            Some(reposer) => {
                reposer
                    .map_points(&points, &rays.dirs)
                    .map_err(|e| ModelError::Input(format!("reposing: {e}")))?
                    .points
            }
        };
        Ok(projection_grid(&scene.geometry, &points))
    };
    let n = scene.num_views();
    let r = points.len();
    let device = scene.images.device();
    if !depth.is_autodiff() {
        // No gradient can flow (inference): the read alone, without the slope's second
        // projection (and reposing) of every ray.
        let grid = Tensor::<3>::from_data(TensorData::new(to_grid(points)?, [n, r, 2]), &device);
        return Ok(fetch_source_colours_from(&scene.image_rows, grid)?);
    }
    let stepped: Vec<Vec3> = points
        .iter()
        .zip(&rays.dirs)
        .map(|(&p, &d)| p + d * SURFACE_GRID_STEP_M)
        .collect();
    let (grid, grid_stepped) = (to_grid(points)?, to_grid(stepped)?);
    let inside = |g: &[f32]| g.iter().all(|v| v.abs() < GRID_INSIDE_BOUND);
    let mut slope = vec![0.0f32; n * r * 2];
    for view in 0..n {
        for (ray, &acc) in acc_v[..r].iter().enumerate() {
            let i = (view * r + ray) * 2;
            let (g0, g1) = (&grid[i..i + 2], &grid_stepped[i..i + 2]);
            if acc >= SURFACE_ACC_FLOOR && inside(g0) && inside(g1) {
                slope[i] = (g1[0] - g0[0]) / SURFACE_GRID_STEP_M;
                slope[i + 1] = (g1[1] - g0[1]) / SURFACE_GRID_STEP_M;
            }
        }
    }
    let grid = Tensor::<3>::from_data(TensorData::new(grid, [n, r, 2]), &device);
    let slope = Tensor::<3>::from_data(TensorData::new(slope, [n, r, 2]), &device);
    // t_s - t0: zero forward, the gradient of t_s backward.
    let t_s = depth / acc.clamp_min(SURFACE_ACC_FLOOR);
    let dt = (t_s.clone() - t_s.detach()).reshape([1, r, 1]);
    Ok(fetch_source_colours_from(
        &scene.image_rows,
        grid + slope * dt,
    )?)
}

/// The surface form of the colour and of the IBR-only composite.
///
/// # Shapes
/// - `nerf_part`: `[R, 3]` sum_i w_i b0_i c0_i
/// - `view_weights` W_n: `[R, N]` sum_i w_i b_{n,i}
/// - `colours` c_n(x_s): `[N, R, 3]`
/// - `acc`: `[R]` sum_i w_i
/// - output: (C `[R, 3]`, IBR-only `[R, 3]` = acc sum_n W_n c_n / sum_n W_n over a black
///   background like every composite, with its gradients for `loss::ibr_loss`)
pub fn surface_composite(
    nerf_part: Tensor<2>,
    view_weights: Tensor<2>,
    colours: Tensor<3>,
    acc: Tensor<1>,
) -> (Tensor<2>, Tensor<2>) {
    let [n, r, _] = colours.dims();
    let w = view_weights.transpose().reshape([n, r, 1]); // [N, R, 1]
    let rgb = nerf_part + (colours.clone() * w.clone()).sum_dim(0).reshape([r, 3]);
    let w_ibr = w.add_scalar(IBR_ONLY_FLOOR);
    let total = w_ibr.clone().sum_dim(0);
    let ibr = ((colours * w_ibr).sum_dim(0) / total).reshape([r, 3]) * acc.reshape([r, 1]);
    (rgb, ibr)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bundle() -> RayBundle {
        RayBundle {
            origins: vec![Vec3::ZERO; 3],
            dirs: vec![Vec3::X, Vec3::Y, Vec3::Z],
            near: vec![1.0, 1.0, 2.0],
            far: vec![3.0, 3.0, 4.0],
            pixels: vec![0, 1, 2],
        }
    }

    #[test]
    fn surface_points_are_the_normalised_expected_depth_or_the_interval_middle() {
        // Ray 0: depth 1.0 at acc 0.5 -> t = 2. Ray 1: no opacity -> middle 2. Ray 2: a
        // normalised depth beyond far (rounding) is clamped to far.
        let points = surface_points(&bundle(), &[1.0, 0.0, 4.5], &[0.5, 0.0, 1.0]);
        assert_eq!(points, vec![Vec3::X * 2.0, Vec3::Y * 2.0, Vec3::Z * 4.0]);
        // Infinite depth (a NaN guard upstream failed) never gives a non-finite point.
        let points = surface_points(&bundle(), &[f32::INFINITY, 1.0, 1.0], &[1.0, 1e-9, 1.0]);
        assert!(points.iter().all(|p| p.is_finite()), "{points:?}");
        assert_eq!(points[1], Vec3::Y * 2.0);
    }

    #[test]
    #[allow(deprecated)] // Device::ndarray(): the reference CPU backend.
    fn surface_composite_adds_the_weighted_view_colours_to_the_nerf_part() {
        let dev = Device::ndarray();
        let t2 = |v: Vec<f32>, s: [usize; 2]| Tensor::<2>::from_data(TensorData::new(v, s), &dev);
        // R = 2 rays, N = 2 views.
        let nerf = t2(vec![0.1, 0.2, 0.3, 0.0, 0.0, 0.0], [2, 3]);
        let w = t2(vec![0.5, 0.25, 0.0, 0.0], [2, 2]);
        let colours = Tensor::<3>::from_data(
            TensorData::new(
                vec![
                    0.2, 0.4, 0.6, /* view 0 ray 1 */ 1.0, 1.0, 1.0, //
                    0.8, 0.0, 0.4, /* view 1 ray 1 */ 0.0, 0.5, 1.0,
                ],
                [2, 2, 3],
            ),
            &dev,
        );
        let acc = Tensor::<1>::from_data(TensorData::new(vec![1.0f32, 0.5], [2]), &dev);
        let (rgb, ibr) = surface_composite(nerf, w, colours, acc);
        let rgb = rgb.into_data().to_vec::<f32>().unwrap();
        let ibr = ibr.into_data().to_vec::<f32>().unwrap();
        let expected_rgb = [0.1 + 0.1 + 0.2, 0.2 + 0.2, 0.3 + 0.3 + 0.1, 0.0, 0.0, 0.0];
        // Ray 0 (acc 1): (0.5 c_0 + 0.25 c_1) / 0.75; ray 1 (no view weight, acc 0.5): half
        // the plain mean.
        let expected_ibr = [
            (0.1 + 0.2) / 0.75,
            0.2 / 0.75,
            (0.3 + 0.1) / 0.75,
            0.25,
            0.375,
            0.5,
        ];
        for (got, want) in rgb
            .iter()
            .zip(expected_rgb)
            .chain(ibr.iter().zip(expected_ibr))
        {
            assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        }
    }
}
