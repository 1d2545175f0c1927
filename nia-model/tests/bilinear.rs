//! The bilinear read as four row gathers against burn's `grid_sample_2d` (bilinear, zero
//! padding, `align_corners = false`): values and gradients (in the maps and in the grid) on
//! ndarray, flex and (where a Vulkan driver is installed) wgpu, plus the hard cases.

mod common;

use burn::prelude::*;
use common::{assert_close, device, tensor, values};
use nia_data::rng::Rng;
use nia_model::encoder::bilinear::{grid_sample_reference, sample, ViewRows};

const N: usize = 2;
const C: usize = 3;
const H: usize = 5;
const W: usize = 7;

fn maps_values() -> Vec<f32> {
    let mut rng = Rng::new(11);
    (0..N * C * H * W)
        .map(|_| rng.uniform() * 2.0 - 1.0)
        .collect()
}

/// Points all over each map, and the cases at its edge: inside, on pixel centres, within half
/// a pixel of the border (one or two corners outside), just outside, far outside.
fn grid_values() -> (Vec<f32>, usize) {
    let mut rng = Rng::new(12);
    let mut per_view: Vec<[f32; 2]> = (0..40)
        .map(|_| [rng.uniform() * 2.6 - 1.3, rng.uniform() * 2.6 - 1.3])
        .collect();
    per_view.extend([
        [0.0, 0.0],
        [-1.0, -1.0],
        [1.0, 1.0],
        [-0.95, 0.3],
        [0.97, -0.99],
        [1.2, 0.0],
        [0.0, -1.4],
        [1e6, 1e6],
        [-3e5, 0.5],
    ]);
    let m = per_view.len();
    let mut grid = Vec::with_capacity(N * m * 2);
    for view in 0..N {
        for p in &per_view {
            // Views read different places.
            grid.extend([p[0] * (1.0 - 0.1 * view as f32), p[1]]);
        }
    }
    (grid, m)
}

fn check_on(dev: &Device, what: &str) {
    let (grid, m) = grid_values();
    let maps = tensor(maps_values(), [N, C, H, W], dev);
    let proj = tensor(grid.clone(), [N, m, 2], dev);
    let got = values(sample(maps.clone(), proj.clone()).unwrap());
    let expected = values(grid_sample_reference(maps, proj).unwrap());
    assert_close(&got, &expected, 1e-5, &format!("{what}: values"));
    // A read far outside is exactly zero.
    for view in 0..N {
        for k in [m - 2, m - 1] {
            let i = (view * m + k) * C;
            assert_eq!(&got[i..i + C], &[0.0; C], "{what}: far outside");
        }
    }

    // Gradients in the maps and in the grid: a random weighting of the output.
    let ad = dev.clone().autodiff();
    let mut rng = Rng::new(13);
    let upstream: Vec<f32> = (0..N * m * C).map(|_| rng.uniform() - 0.5).collect();
    let grads_of = |reference: bool| {
        let maps = tensor(maps_values(), [N, C, H, W], &ad).require_grad();
        let proj = tensor(grid.clone(), [N, m, 2], &ad).require_grad();
        let out = if reference {
            grid_sample_reference(maps.clone(), proj.clone()).unwrap()
        } else {
            sample(maps.clone(), proj.clone()).unwrap()
        };
        let g = (out * tensor(upstream.clone(), [N, m, C], &ad))
            .sum()
            .backward();
        (
            values(maps.grad(&g).unwrap()),
            values(proj.grad(&g).unwrap()),
        )
    };
    let (maps_got, grid_got) = grads_of(false);
    let (maps_ref, grid_ref) = grads_of(true);
    assert_close(&maps_got, &maps_ref, 1e-5, &format!("{what}: d/d maps"));
    // With a grid that carries no gradient, as the network's reads have (on flex: the weighted
    // gather of `nia_model::kernels::weighted_rows`, its own backward), the same d/d maps.
    let maps = tensor(maps_values(), [N, C, H, W], &ad).require_grad();
    let proj = tensor(grid.clone(), [N, m, 2], &ad);
    let g = (sample(maps.clone(), proj).unwrap() * tensor(upstream.clone(), [N, m, C], &ad))
        .sum()
        .backward();
    let maps_untracked = values(maps.grad(&g).unwrap());
    assert_close(
        &maps_untracked,
        &maps_ref,
        1e-5,
        &format!("{what}: d/d maps, grid without gradient"),
    );
    assert!(grid_got.iter().all(|g| g.is_finite()), "{what}: d/d grid");
    // d/d grid agrees wherever the reference is defined the same way: burn's reference
    // differentiates the corners that fall outside as well (their zero value), so compare
    // points whose four corners are all inside the map.
    let inside = |gx: f32, gy: f32| {
        let x = (gx + 1.0) * W as f32 / 2.0 - 0.5;
        let y = (gy + 1.0) * H as f32 / 2.0 - 0.5;
        x >= 0.0 && x < (W - 1) as f32 && y >= 0.0 && y < (H - 1) as f32
    };
    let mut compared = 0;
    for p in 0..N * m {
        if inside(grid[2 * p], grid[2 * p + 1]) {
            assert_close(
                &grid_got[2 * p..2 * p + 2],
                &grid_ref[2 * p..2 * p + 2],
                1e-4,
                &format!("{what}: d/d grid of point {p}"),
            );
            compared += 1;
        }
    }
    assert!(compared > 20, "{what}: only {compared} points compared");
}

/// The maps' channels-last rows (`ViewRows::rows`): on flex the host operation of
/// `nia_model::encoder::channels_last`, on ndarray the tensor form (permute, reshape, a zero
/// row). Pure data movement, so values and the maps' gradient agree to the bit, for maps that
/// arrive as a transposed view too; the zero row's gradient reaches nothing.
#[test]
#[allow(deprecated)] // Device::ndarray(): the reference CPU backend the project keeps
fn channels_last_rows_are_the_tensor_layout_to_the_bit() {
    let rows_and_grad = |dev: &Device, transposed: bool| {
        let ad = dev.clone().autodiff();
        let maps = if transposed {
            // [N, C, W, H] swapped to [N, C, H, W]: a strided view.
            let mut rng = Rng::new(21);
            let v: Vec<f32> = (0..N * C * H * W).map(|_| rng.uniform() - 0.5).collect();
            tensor(v, [N, C, W, H], &ad).require_grad()
        } else {
            tensor(maps_values(), [N, C, H, W], &ad).require_grad()
        };
        let input = if transposed {
            maps.clone().swap_dims(2, 3)
        } else {
            maps.clone()
        };
        let rows = ViewRows::new(input).unwrap().rows();
        assert_eq!(rows.dims(), [N * H * W + 1, C]);
        let mut rng = Rng::new(22);
        let upstream: Vec<f32> = (0..(N * H * W + 1) * C)
            .map(|_| rng.uniform() - 0.5)
            .collect();
        let g = (rows.clone() * tensor(upstream, [N * H * W + 1, C], &ad))
            .sum()
            .backward();
        (values(rows), values(maps.grad(&g).unwrap()))
    };
    for transposed in [false, true] {
        let (rows, grad) = rows_and_grad(&Device::flex(), transposed);
        let (rows_ref, grad_ref) = rows_and_grad(&Device::ndarray(), transposed);
        assert_eq!(rows, rows_ref, "rows, transposed input {transposed}");
        assert_eq!(&rows[N * H * W * C..], &[0.0; C], "the zero row");
        assert_eq!(grad, grad_ref, "d/d maps, transposed input {transposed}");
    }
}

#[test]
fn matches_grid_sample_on_ndarray_and_flex() {
    check_on(&device(), "ndarray");
    check_on(&Device::flex(), "flex");
}

#[cfg(feature = "wgpu")]
#[test]
fn matches_grid_sample_on_wgpu() {
    if let Some(dev) = common::wgpu_device() {
        check_on(&dev, "wgpu");
    }
}

/// d/d grid by central finite differences of the read itself, away from the kinks at pixel
/// centres, including points with corners outside the map (where the read falls to zero).
#[test]
fn grid_gradient_is_the_finite_difference() {
    let dev = device();
    let ad = dev.clone().autodiff();
    let maps_v = maps_values();
    let points: Vec<[f32; 2]> = vec![[0.13, -0.21], [-0.97, 0.44], [0.93, 0.91], [0.31, 0.62]];
    let m = points.len();
    let grid: Vec<f32> = (0..N)
        .flat_map(|_| points.iter().flat_map(|p| *p))
        .collect();
    let upstream: Vec<f32> = (0..N * m * C).map(|i| 0.3 + 0.1 * (i % 5) as f32).collect();
    let read = |g: &[f32]| -> f32 {
        let out = sample(
            tensor(maps_v.clone(), [N, C, H, W], &dev),
            tensor(g.to_vec(), [N, m, 2], &dev),
        )
        .unwrap();
        values(out).iter().zip(&upstream).map(|(a, b)| a * b).sum()
    };
    let proj = tensor(grid.clone(), [N, m, 2], &ad).require_grad();
    let out = sample(tensor(maps_v.clone(), [N, C, H, W], &ad), proj.clone()).unwrap();
    let g = (out * tensor(upstream.clone(), [N, m, C], &ad))
        .sum()
        .backward();
    let got = values(proj.grad(&g).unwrap());
    let h = 1e-3f32;
    for i in 0..grid.len() {
        let (mut plus, mut minus) = (grid.clone(), grid.clone());
        plus[i] += h;
        minus[i] -= h;
        let fd = (read(&plus) - read(&minus)) / (2.0 * h);
        assert!(
            (got[i] - fd).abs() <= 2e-2 * (1.0 + fd.abs()),
            "grid[{i}]: autodiff {}, finite difference {fd}",
            got[i]
        );
    }
}

/// Non-finite coordinates (a projection that went wrong upstream) read zero with a zero
/// gradient in the maps, instead of spreading NaN into them.
#[test]
fn non_finite_coordinates_read_zero() {
    non_finite_coordinates_read_zero_on(&device());
    // flex: the weighted gather's taps, computed on the host.
    non_finite_coordinates_read_zero_on(&Device::flex());
}

/// The same on wgpu, whose read tests the map's bounds as its own kernels do.
#[cfg(feature = "wgpu")]
#[test]
fn non_finite_coordinates_read_zero_on_wgpu() {
    if let Some(dev) = common::wgpu_device() {
        non_finite_coordinates_read_zero_on(&dev);
    }
}

fn non_finite_coordinates_read_zero_on(dev: &Device) {
    let ad = dev.clone().autodiff();
    let maps = tensor(maps_values(), [N, C, H, W], &ad).require_grad();
    let grid = vec![
        f32::NAN,
        0.0,
        0.0,
        f32::INFINITY,
        f32::NEG_INFINITY,
        0.2,
        0.1,
        0.1,
    ];
    let proj = tensor(grid.clone(), [N, 2, 2], &ad);
    let out = sample(maps.clone(), proj).unwrap();
    let v = values(out.clone());
    assert!(v.iter().all(|x| x.is_finite()), "{v:?}");
    // Points 0 and 1 of view 0 and point 0 of view 1 are non-finite: zero reads.
    assert_eq!(&v[0..2 * C], &[0.0; 2 * C]);
    assert_eq!(&v[2 * C..3 * C], &[0.0; C]);
    assert!(
        v[3 * C..].iter().any(|x| *x != 0.0),
        "the finite point reads"
    );
    let g = out.sum().backward();
    let gm = values(maps.grad(&g).unwrap());
    assert!(gm.iter().all(|x| x.is_finite()));
}

/// Shapes: a grid for another number of views is refused, an empty grid reads nothing.
#[test]
fn shape_errors_and_empty_grids() {
    let dev = device();
    let maps = tensor(maps_values(), [N, C, H, W], &dev);
    assert!(sample(maps.clone(), tensor(vec![0.0; 6], [3, 1, 2], &dev)).is_err());
    assert!(sample(maps.clone(), tensor(vec![0.0; 6], [2, 1, 3], &dev)).is_err());
    let empty = sample(maps, Tensor::<3>::zeros([N, 0, 2], &dev)).unwrap();
    assert_eq!(empty.dims(), [N, 0, C]);
}

/// The fused host read (a host copy of the rows, a grid without gradients: inference on the CPU
/// backends) against the tensor read and `grid_sample_2d`, with the edge cases and non-finite
/// coordinates; a grid that carries gradients still takes the tensor path.
#[test]
fn host_read_matches_the_tensor_read() {
    use nia_model::encoder::bilinear::ViewRows;
    let dev = device();
    let (mut grid, m) = grid_values();
    grid[0] = f32::NAN;
    grid[3] = f32::INFINITY;
    let maps = tensor(maps_values(), [N, C, H, W], &dev);
    let proj = tensor(grid.clone(), [N, m, 2], &dev);
    let rows = ViewRows::new(maps.clone()).unwrap();
    let host = rows.clone().with_host_copy().unwrap();
    assert!(host.has_host_copy() && !rows.has_host_copy());
    let tensor_read = values(rows.sample(proj.clone()).unwrap());
    let host_read = values(host.sample(proj.clone()).unwrap());
    assert_eq!(tensor_read.len(), host_read.len());
    for (i, (t, h)) in tensor_read.iter().zip(&host_read).enumerate() {
        assert!(h.is_finite(), "[{i}] {h}");
        assert!((t - h).abs() <= 1e-6, "[{i}] tensor {t} vs host {h}");
    }
    // The non-finite coordinates read zero.
    assert_eq!(&host_read[..C], &[0.0; C]);
    assert_eq!(&host_read[C..2 * C], &[0.0; C]);
    let finite: Vec<f32> = grid
        .iter()
        .map(|v| if v.is_finite() { *v } else { 5.0 })
        .collect();
    let reference =
        values(grid_sample_reference(maps.clone(), tensor(finite, [N, m, 2], &dev)).unwrap());
    assert_close(&host_read, &reference, 1e-5, "host read vs grid_sample_2d");
    assert!(host
        .clone()
        .without_host_copy()
        .sample(proj.clone())
        .is_ok());
    // Under autodiff the same rows read with tensor operations, and gradients reach the grid.
    let ad = dev.clone().autodiff();
    let rows = ViewRows::new(tensor(maps_values(), [N, C, H, W], &ad))
        .unwrap()
        .with_host_copy()
        .unwrap();
    let proj = tensor(grid_values().0, [N, m, 2], &ad).require_grad();
    let grads = rows.sample(proj.clone()).unwrap().sum().backward();
    let g = values(proj.grad(&grads).expect("a gradient in the grid"));
    assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|v| *v != 0.0));
}
