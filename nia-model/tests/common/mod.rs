//! What nia-model's tests share: the reference device and tensor helpers, and a small scene
//! (the procedural body, a ring of source cameras, patterned images and real rasterised vertex
//! visibility) with target rays.
#![allow(dead_code)]

use burn::prelude::*;
use glam::Vec3;
use nia_data::body::{ProceduralBody, ProceduralSpec, SmplParams};
use nia_data::geometry::camera::Camera;
use nia_data::geometry::raster::rasterize;
use nia_data::geometry::rays::{near_far, pixel_ray, Aabb, RayBundle};
use nia_data::geometry::visibility::visibility;
use nia_data::scene::{SceneBody, SceneInput, SourceView, RAY_BOX_PADDING_M};

pub mod volume;

/// Depth tolerance of the test visibility (2 cm, as NHP-style implementations use).
pub const VIS_TOL_M: f32 = 0.02;

/// A camera on a ring of radius 2.5 m around the body centre, at `angle` radians.
pub fn ring_camera(centre: Vec3, angle: f32, size: u32) -> Camera {
    let eye = centre + Vec3::new(2.5 * angle.sin(), 0.1, 2.5 * angle.cos());
    Camera::look_at(
        eye,
        centre,
        Vec3::Y,
        size as f32 * 1.4,
        size as f32 * 1.4,
        size,
        size,
    )
    .unwrap()
}

/// `views` source views of size `size` around the procedural body in its rest pose.
pub fn scene(views: usize, size: u32) -> SceneInput {
    let spec = ProceduralSpec {
        target_vertices: 1500,
        ..ProceduralSpec::default()
    };
    let model = ProceduralBody::generate(&spec).unwrap();
    let posed = model.lbs(&SmplParams::default());
    let vertices = posed.vertices;
    let faces = model.faces.clone();
    let centre = body_centre(&vertices);
    let views = (0..views)
        .map(|i| {
            let camera = ring_camera(centre, i as f32 * std::f32::consts::TAU / 3.0, size);
            let vis = visibility(&camera, &vertices, &faces, VIS_TOL_M).unwrap();
            let s = size as usize;
            let mut image = vec![0.0f32; 3 * s * s];
            for c in 0..3 {
                for y in 0..s {
                    for x in 0..s {
                        image[(c * s + y) * s + x] = 0.5
                            + 0.4
                                * ((x as f32 * 0.7 + y as f32 * 0.3 + c as f32 * 2.0 + i as f32)
                                    .sin());
                    }
                }
            }
            // The body's silhouette as the person's mask.
            let mask = rasterize(&camera, &vertices, &faces)
                .unwrap()
                .mask()
                .iter()
                .map(|&m| m as u8 as f32)
                .collect();
            SourceView {
                camera,
                image,
                mask,
                vertex_visibility: vis.iter().map(|&b| b as f32).collect(),
            }
        })
        .collect();
    SceneInput {
        views,
        body: SceneBody {
            vertices,
            faces,
            rh: Vec3::ZERO,
            th: Vec3::ZERO,
        },
    }
}

pub fn body_centre(vertices: &[Vec3]) -> Vec3 {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for v in vertices {
        lo = lo.min(*v);
        hi = hi.max(*v);
    }
    (lo + hi) * 0.5
}

/// Rays of a 64 x 64 target camera through a `k x k` grid of pixels around the image centre
/// that hit the scene's ray box.
pub fn target_rays(input: &SceneInput, k: usize) -> RayBundle {
    let centre = body_centre(&input.body.vertices);
    let camera = ring_camera(centre, 0.9, 64);
    let ray_box = Aabb::from_points(&input.body.vertices)
        .unwrap()
        .padded(RAY_BOX_PADDING_M);
    let mut rays = RayBundle::default();
    for j in 0..k {
        for i in 0..k {
            let px = glam::Vec2::new(
                24.0 + 16.0 * i as f32 / k as f32,
                12.0 + 40.0 * j as f32 / k as f32,
            );
            let ray = pixel_ray(&camera, px);
            if let Some((near, far)) = near_far(&ray, &ray_box) {
                rays.push(ray, near, far, px.y as u32 * 64 + px.x as u32);
            }
        }
    }
    rays
}

/// The wgpu device if a fast adapter works here: on Linux only with a Vulkan driver (not the
/// OpenGL fallback). Without one the test is skipped with a message naming what to install,
/// unless `NIA_REQUIRE_WGPU=1` (CI), where the missing adapter fails the test.
#[cfg(feature = "wgpu")]
pub fn wgpu_device() -> Option<burn::tensor::Device> {
    use burn::prelude::*;
    let required = std::env::var("NIA_REQUIRE_WGPU").as_deref() == Ok("1");
    if !nia_model::device::vulkan_driver_installed() {
        let message = "no Vulkan driver (wgpu would fall back to OpenGL/llvmpipe, far too slow \
                       for tests): install mesa-vulkan-drivers (Debian/Ubuntu) or your GPU's \
                       Vulkan driver";
        if required {
            panic!("NIA_REQUIRE_WGPU=1 but {message}");
        }
        eprintln!("skipped: {message}");
        return None;
    }
    let probe = std::panic::catch_unwind(|| {
        let device = nia_model::device::Backend::Wgpu
            .device()
            .expect("wgpu compiled in");
        let x = Tensor::<1>::from_floats([1.0, 2.0], &device)
            .sum()
            .into_scalar::<f32>();
        (device, x)
    });
    match probe {
        Ok((device, 3.0)) => Some(device),
        _ if required => {
            panic!("NIA_REQUIRE_WGPU=1 but no working wgpu adapter (install mesa-vulkan-drivers)")
        }
        _ => {
            eprintln!("skipped: no working wgpu adapter (install mesa-vulkan-drivers)");
            None
        }
    }
}

/// The reference CPU backend (deprecated upstream in favour of flex; the project keeps it).
#[allow(deprecated)]
pub fn device() -> Device {
    Device::ndarray()
}

/// The tiny network on the reference CPU device, its weights drawn after seeding it with
/// `seed`: (device, model).
pub fn tiny_model(seed: u64) -> (Device, nia_model::NiaModel) {
    let device = device();
    device.seed(seed);
    let model = nia_model::ModelConfig::tiny().init(&device);
    (device, model)
}

pub fn tensor<const D: usize>(values: Vec<f32>, shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::from_data(TensorData::new(values, shape), device)
}

pub fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32 tensor")
}

pub fn assert_close(got: &[f32], expected: &[f32], tol: f32, what: &str) {
    assert_eq!(got.len(), expected.len(), "{what}: length");
    for (i, (g, e)) in got.iter().zip(expected).enumerate() {
        assert!(
            (g - e).abs() <= tol * (1.0 + e.abs()),
            "{what}[{i}]: got {g}, expected {e} (tol {tol})"
        );
    }
}

/// `max |a - b| / max(1e-6, max |b|)`: how far `a` is from `b` relative to `b`'s largest value.
pub fn relative_gap(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
    a.iter()
        .zip(b)
        .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()))
        / scale
}

/// Asserts that `text` (an error message) names every one of `parts`.
pub fn assert_mentions(text: &str, parts: &[&str]) {
    for part in parts {
        assert!(text.contains(part), "{part} not in {text}");
    }
}

/// The central difference `(f(x + h e_i) - f(x - h e_i)) / 2h` of `f` at `x` along coordinate
/// `i`, with step `h`.
pub fn central_difference(x: &[f32], i: usize, h: f32, f: impl Fn(Vec<f32>) -> f32) -> f32 {
    let (mut up, mut down) = (x.to_vec(), x.to_vec());
    up[i] += h;
    down[i] -= h;
    (f(up) - f(down)) / (2.0 * h)
}

/// f32 forward values computed along two different paths (reordered sums, sin/cos of the
/// same angles): a few ulps of O(1) values.
pub const VALUE_TOL: f32 = 1e-5;
/// Values through a small MLP (a few hundred f32 multiply-adds per output).
pub const MLP_TOL: f32 = 1e-4;
/// Central finite-difference step for f32 inputs of O(1).
pub const FD_STEP: f32 = 1e-3;
/// Finite differences vs autodiff: O(FD_STEP^2) truncation plus f32 rounding of O(1) losses
/// divided by the step (~1e-7 / 1e-3), with margin: absolute plus relative to the gradient.
pub const FD_ABS_TOL: f32 = 2e-3;
pub const FD_REL_TOL: f32 = 2e-2;

/// `n` values drawn uniformly in `[lo, hi)`.
pub fn random(rng: &mut nia_data::rng::Rng, n: usize, lo: f32, hi: f32) -> Vec<f32> {
    (0..n).map(|_| rng.range(lo, hi)).collect()
}

/// Asserts that `v` is not empty and every value is finite.
pub fn assert_finite(v: &[f32], what: &str) {
    assert!(!v.is_empty(), "{what}: empty");
    assert!(v.iter().all(|x| x.is_finite()), "{what}: not finite: {v:?}");
}

/// Asserts that an autodiff gradient is within [`FD_ABS_TOL`] plus [`FD_REL_TOL`] of the
/// finite difference `fd`.
pub fn assert_fd_close(autodiff: f32, fd: f32, what: &str) {
    assert!(
        (autodiff - fd).abs() <= FD_ABS_TOL + FD_REL_TOL * fd.abs(),
        "{what}: autodiff {autodiff} vs finite difference {fd}"
    );
}

/// Asserts that autodiff's gradient `grad` of `f` at `x` matches the central differences, one
/// coordinate at a time (`what[i]`).
pub fn assert_gradient(what: &str, x: &[f32], grad: &[f32], f: impl Fn(Vec<f32>) -> f32) {
    assert_eq!(grad.len(), x.len(), "{what}");
    for (i, &g) in grad.iter().enumerate() {
        let fd = central_difference(x, i, FD_STEP, &f);
        assert_fd_close(g, fd, &format!("{what}[{i}]"));
    }
}

/// A linear layer with given weights `[d_in, d_out]` (row-major) and bias.
pub fn linear(
    weight: Vec<f32>,
    bias: Vec<f32>,
    d_in: usize,
    d_out: usize,
    dev: &Device,
) -> burn::nn::Linear {
    burn::nn::Linear {
        weight: burn::module::Param::from_tensor(tensor(weight, [d_in, d_out], dev)),
        bias: Some(burn::module::Param::from_tensor(tensor(bias, [d_out], dev))),
    }
}

/// The `d x d` identity matrix, row-major.
pub fn identity(d: usize) -> Vec<f32> {
    (0..d * d)
        .map(|i| if i / d == i % d { 1.0 } else { 0.0 })
        .collect()
}
