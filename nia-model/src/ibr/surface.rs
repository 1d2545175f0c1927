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
use nia_data::geometry::camera::PROJECT_MIN_DEPTH_M;
use nia_data::geometry::rays::RayBundle;
use nia_data::scene::{projection_grid, OUTSIDE_GRID};

use super::blend_host::IBR_ONLY_FLOOR;
use super::fetch_source_colours_from;
use crate::error::ModelError;
use crate::kernels::readback::host_values;
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

/// The source colours c_n(x_s) of the rays' expected surface points, read where the model reads
/// them for samples (at x_s itself, or at its image in the source pose when the scene renders
/// another pose).
///
/// In training (an autodiff device) the read is differentiable in the surface depth
/// t_s = depth / acc: the projection is computed on the device ([`surface_grid`]), exactly and
/// without reading the depth back, so the slope of the source images at the projection pulls
/// the expected depth towards where the views agree with the target pixel. Rays without a
/// surface point (acc < [`SURFACE_ACC_FLOOR`]) read at the middle of their interval, with no
/// gradient. Off an autodiff device (inference) the depth is read back once and x_s projected
/// on the host, through the reposing where the scene renders another pose; a differentiable
/// read of a reposed scene is refused (training never reposes).
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
    check_per_ray("surface colours", rays, &depth, &acc)?;
    if depth.is_autodiff() {
        if scene.reposer.is_some() {
            return Err(ModelError::Input(
                "surface colours: a differentiable read of a reposed scene (training renders \
                 the scene's own pose)"
                    .into(),
            ));
        }
        let grid = surface_grid(scene, rays, depth, acc)?;
        return Ok(fetch_source_colours_from(&scene.image_rows, grid)?);
    }
    // One read of both (on a GPU each read waits for the device).
    let r = rays.len();
    let mut depth_v = host_values(Tensor::cat(vec![depth.detach(), acc.detach()], 0))
        .map_err(|e| ModelError::Input(format!("reading depth and opacity: {e}")))?;
    let acc_v = depth_v.split_off(r);
    surface_colours_of(scene, rays, &depth_v, &acc_v)
}

/// [`surface_colours`] at inference from host values: the source colours c_n(x_s) of the rays'
/// expected surface points, through the reposing where the scene renders another pose.
///
/// # Shapes
/// - `depth`, `acc`: `[R]` (sum_i w_i t_i and sum_i w_i)
/// - output: `[N, R, 3]`
pub fn surface_colours_of(
    scene: &SceneEncoding,
    rays: &RayBundle,
    depth: &[f32],
    acc: &[f32],
) -> Result<Tensor<3>, ModelError> {
    let r = rays.len();
    let points = surface_points(rays, depth, acc);
    let points = match &scene.reposer {
        None => points,
        Some(reposer) => {
            reposer
                .map_points(&points, &rays.dirs)
                .map_err(|e| ModelError::Input(format!("reposing: {e}")))?
                .points
        }
    };
    let grid = projection_grid(&scene.geometry, &points);
    let grid = Tensor::<3>::from_data(
        TensorData::new(grid, [scene.num_views(), r, 2]),
        &scene.images.device(),
    );
    Ok(fetch_source_colours_from(&scene.image_rows, grid)?)
}

/// The source-image grid of each ray's expected surface point x_s, computed on the device: the
/// training form of [`surface_colours`]'s projection, with no read back (on a GPU a read waits
/// for the device) and the exact derivative in the expected depth.
///
/// In each view's camera frame the ray is the line `a + b t` (`a = R o + T`, `b = R d`, made
/// on the host from the rays alone); `t_s = clamp(depth / acc, near, far)`, or the middle of
/// the interval where `acc < SURFACE_ACC_FLOOR` (or the quotient is NaN), as
/// [`surface_points`]; the pinhole projection of `a + b t_s` and the pixel-to-grid map follow
/// `Camera::project` and `projection_grid` (a point behind a camera reads `OUTSIDE_GRID`).
///
/// # Shapes
/// - `depth`, `acc`: `[R]`
/// - output: `[N, R, 2]` grid coordinates in `[-1, 1]` inside the images
pub fn surface_grid(
    scene: &SceneEncoding,
    rays: &RayBundle,
    depth: Tensor<1>,
    acc: Tensor<1>,
) -> Result<Tensor<3>, ModelError> {
    check_per_ray("surface grid", rays, &depth, &acc)?;
    let r = rays.len();
    let geometry = &scene.geometry;
    let n = geometry.num_views();
    let [h, w] = geometry.image_hw;
    let device = depth.device();
    let mut line = Vec::with_capacity(n * r * 6);
    let mut affine = Vec::with_capacity(n * 5);
    for camera in &geometry.cameras {
        for (&o, &d) in rays.origins.iter().zip(&rays.dirs) {
            let (a, b) = (camera.world_to_camera(o), camera.r * d);
            line.extend_from_slice(&[a.x, a.y, a.z, b.x, b.y, b.z]);
        }
        // grid = (2 pixel + 1) / size - 1, pixel = (fx nx + skew ny + cx, fy ny + cy).
        let (sx, sy) = (2.0 / w as f32, 2.0 / h as f32);
        affine.extend_from_slice(&[
            sx * camera.fx(),
            sx * camera.skew(),
            sx * camera.cx() + 1.0 / w as f32 - 1.0,
            sy * camera.fy(),
            sy * camera.cy() + 1.0 / h as f32 - 1.0,
        ]);
    }
    let line = Tensor::<3>::from_data(TensorData::new(line, [n, r, 6]), &device);
    let affine = Tensor::<3>::from_data(TensorData::new(affine, [n, 1, 5]), &device);
    let per_ray = |v: Vec<f32>| Tensor::<1>::from_data(TensorData::new(v, [r]), &device);
    let (near, far) = (per_ray(rays.near.clone()), per_ray(rays.far.clone()));
    let middle = (near.clone() + far.clone()).mul_scalar(0.5);
    let t = (depth / acc.clone().clamp_min(SURFACE_ACC_FLOOR))
        .max_pair(near)
        .min_pair(far);
    let t = middle
        .clone()
        .mask_where(acc.greater_equal_elem(SURFACE_ACC_FLOOR), t);
    let t = t.clone().mask_where(t.is_nan(), middle).reshape([1, r, 1]);
    let c = line.clone().slice(s![.., .., 0..3]) + line.slice(s![.., .., 3..6]) * t; // [N, R, 3]
    let z = c.clone().slice(s![.., .., 2..3]);
    let behind = z.clone().lower_equal_elem(PROJECT_MIN_DEPTH_M); // [N, R, 1]
    let z = z.clamp_min(PROJECT_MIN_DEPTH_M);
    let nx = c.clone().slice(s![.., .., 0..1]) / z.clone();
    let ny = c.slice(s![.., .., 1..2]) / z;
    let coefficient = |i: usize| affine.clone().slice(s![.., .., i..i + 1]); // [N, 1, 1]
    let gx = nx * coefficient(0) + ny.clone() * coefficient(1) + coefficient(2);
    let gy = ny * coefficient(3) + coefficient(4);
    let grid = Tensor::cat(vec![gx, gy], 2); // [N, R, 2]
    Ok(grid.mask_fill(behind.repeat_dim(2, 2), OUTSIDE_GRID))
}

/// Refuses `depth` and `acc` unless both are `[R]` for the `R` rays of `rays`.
fn check_per_ray(
    what: &str,
    rays: &RayBundle,
    depth: &Tensor<1>,
    acc: &Tensor<1>,
) -> Result<(), ModelError> {
    let r = rays.len();
    if depth.dims() != [r] || acc.dims() != [r] {
        return Err(ModelError::Input(format!(
            "{what}: depth {:?} and opacity {:?} for {r} rays",
            depth.dims(),
            acc.dims()
        )));
    }
    Ok(())
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
