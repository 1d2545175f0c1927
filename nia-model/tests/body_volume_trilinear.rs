//! The body volume's trilinear read: against a dense `grid_sample(align_corners=True)`
//! reference and burn's 2-D `grid_sample`, on wgpu against ndarray, the host read against the
//! tensor read, its gradients, and the GPU read's blocks.

mod common;

use burn::prelude::*;
use burn::tensor::ops::{GridSampleOptions, GridSamplePaddingMode, InterpolateMode};
use common::volume::{densify, normals, random_points, random_sites, TRILINEAR_TOL};
use common::{device, tensor, values};
use nia_data::geometry::sparse::{ScaleGeometry, TrilinearCorners, VoxelBox, CORNERS};
use nia_data::rng::Rng;
use nia_model::body_volume::trilinear::{sample, sample_with, CornerRead, SiteRows};
use nia_model::body_volume::TrilinearTensors;

/// A small grid placement in metres for the trilinear tests.
fn test_box() -> VoxelBox {
    VoxelBox::new([-0.1, 0.2, 0.05], 0.05, [7, 6, 8]).unwrap()
}

/// PyTorch's `grid_sample(align_corners=True, padding_mode="zeros")` of a dense
/// `[C, X, Y, Z]` grid whose corner samples are the voxel centres of `scale`, at `p`; zero
/// outside the level-0 box. Written from the normalise / unnormalise formulas, independent of
/// the site lookup.
fn dense_grid_sample(grid: &[f32], c: usize, scale: &ScaleGeometry, p: [f32; 3]) -> Vec<f32> {
    let dims = scale.sites.dims();
    let mut out = vec![0.0; c];
    let inside = (0..3).all(|a| p[a] >= scale.bounds_min_m[a] && p[a] <= scale.bounds_max_m[a]);
    if !inside {
        return out;
    }
    // Normalised coordinate: -1 at the first voxel centre, +1 at the last.
    let first = scale.centre_of([0, 0, 0]);
    let last = scale.centre_of(dims.map(|d| d as i32 - 1));
    let idx: [f32; 3] = std::array::from_fn(|a| {
        let g = -1.0 + 2.0 * (p[a] - first[a]) / (last[a] - first[a]);
        (g + 1.0) / 2.0 * (dims[a] as f32 - 1.0)
    });
    let lo = idx.map(|v| v.floor() as i64);
    for dx in 0..2 {
        for dy in 0..2 {
            for dz in 0..2 {
                let corner = [lo[0] + dx, lo[1] + dy, lo[2] + dz];
                let w: f32 = (0..3)
                    .map(|a| {
                        let t = idx[a] - lo[a] as f32;
                        if corner[a] == lo[a] {
                            1.0 - t
                        } else {
                            t
                        }
                    })
                    .product();
                if (0..3).any(|a| corner[a] < 0 || corner[a] >= dims[a] as i64) {
                    continue;
                }
                let [x, y, z] = corner.map(|v| v as usize);
                for ch in 0..c {
                    out[ch] += w * grid[((ch * dims[0] + x) * dims[1] + y) * dims[2] + z];
                }
            }
        }
    }
    out
}

#[test]
fn trilinear_matches_dense_grid_sample() {
    let dev = device();
    let mut rng = Rng::new(31);
    let vb = test_box();
    for level in [0u32, 1] {
        let (_, _, dims) = vb.level_placement(level);
        let sites = random_sites(&mut rng, dims, 0.6);
        let scale = ScaleGeometry::new(&vb, level, sites).unwrap();
        let (n, c, p) = (2, 3, scale.num_sites());
        let features = normals(&mut rng, n * p * c);
        let mut points = random_points(&mut rng, &vb, 300, 0.08);
        // Exactly on voxel centres and on the box faces.
        points.push(scale.centre_of([1, 2, 3]));
        points.push(vb.min_m);
        points.push(vb.max_m());
        points.push([f32::NAN, 0.3, 0.1]);
        let corners = TrilinearCorners::compute(&points, &scale);
        assert_eq!(corners.index.len(), points.len() * CORNERS);
        // Computed in parallel tasks of 1,024 points: 3,040 points get each point's own
        // corners, in order.
        let many: Vec<[f32; 3]> = (0..10).flat_map(|_| points.iter().copied()).collect();
        let all = TrilinearCorners::compute(&many, &scale);
        assert_eq!(all.num_points(), many.len());
        for (m, point) in many.iter().enumerate() {
            let one = TrilinearCorners::compute(&[*point], &scale);
            assert_eq!(&all.index[m * CORNERS..(m + 1) * CORNERS], &one.index[..]);
            assert_eq!(&all.weight[m * CORNERS..(m + 1) * CORNERS], &one.weight[..]);
        }
        let corner_tensors = TrilinearTensors::upload(&corners, &dev);
        let got =
            values(sample(tensor(features.clone(), [n, p, c], &dev), &corner_tensors).unwrap());
        // Blocks of 7 points give the same values; the GPU backends' read (one gather per
        // corner, corner-major corners, site-major rows) sums the same 8 products in another
        // order.
        let rows_for = |read| SiteRows::new(tensor(features.clone(), [n, p, c], &dev), read);
        let blocked =
            values(sample_with(&rows_for(CornerRead::Stacked), &corner_tensors, 7).unwrap());
        assert_eq!(got, blocked);
        let by_corner_tensors = TrilinearTensors::upload_for(&corners, CornerRead::ByCorner, &dev);
        for block in [7, points.len()] {
            let by_corner = values(
                sample_with(&rows_for(CornerRead::ByCorner), &by_corner_tensors, block).unwrap(),
            );
            assert_eq!(by_corner.len(), got.len());
            for (a, b) in by_corner.iter().zip(&got) {
                // NaN points read weight 0 on every corner in both reads.
                assert!((a - b).abs() <= 1e-6, "by-corner read {a} vs stacked {b}");
            }
        }
        // Rows and corners laid out for different reads are an error, not a wrong read.
        assert!(sample_with(&rows_for(CornerRead::ByCorner), &corner_tensors, 7).is_err());
        // On flex the read is one weighted gather with its own backward
        // (`nia_model::kernels::weighted_rows`): the values and the features' gradient of ndarray's
        // tensor read.
        let upstream = normals(&mut rng, n * points.len() * c);
        let read_with_gradient = |device: &Device| {
            let ad = device.clone().autodiff();
            let f = tensor(features.clone(), [n, p, c], &ad).require_grad();
            let corner_tensors = TrilinearTensors::upload(&corners, &ad);
            let out = sample(f.clone(), &corner_tensors).unwrap();
            let g = (out.clone() * tensor(upstream.clone(), [n, points.len(), c], &ad))
                .sum()
                .backward();
            let host = corner_tensors.host.is_some();
            (values(out), values(f.grad(&g).unwrap()), host)
        };
        let (flex_out, flex_grad, flex_host) = read_with_gradient(&Device::flex());
        let (nd_out, nd_grad, nd_host) = read_with_gradient(&dev);
        assert!(flex_host && !nd_host);
        assert_eq!(nd_out, got);
        for (what, a, b) in [
            ("values", &flex_out, &nd_out),
            ("gradient", &flex_grad, &nd_grad),
        ] {
            let scale = b.iter().fold(1e-6f32, |s, v| s.max(v.abs()));
            for (x, y) in a.iter().zip(b.iter()) {
                assert!(
                    (x - y).abs() <= 1e-6 * scale,
                    "flex {what} {x} vs ndarray {y}"
                );
            }
        }
        let sites = &scale.sites;
        let grid = densify(&features, n, c, sites);
        let per_view = c * dims.iter().product::<usize>();
        let mut outside = 0;
        for (m, point) in points.iter().enumerate() {
            let w = &corners.weight[m * CORNERS..(m + 1) * CORNERS];
            let sum: f32 = w.iter().sum();
            if scale.in_bounds(*point) {
                assert!((sum - 1.0).abs() <= TRILINEAR_TOL, "weights sum {sum}");
            } else {
                outside += 1;
                assert_eq!(sum, 0.0);
            }
            for v in 0..n {
                let expected =
                    dense_grid_sample(&grid[v * per_view..(v + 1) * per_view], c, &scale, *point);
                for ch in 0..c {
                    let g = got[(v * points.len() + m) * c + ch];
                    assert!(
                        (g - expected[ch]).abs() <= TRILINEAR_TOL,
                        "level {level} point {point:?} view {v} ch {ch}: {g} vs {}",
                        expected[ch]
                    );
                }
            }
        }
        assert!(outside > 10, "the test should cover points outside the box");
    }
}

/// `(forward, d features of sum(read * cotangent))` of the trilinear read of `features` at the
/// corners of `points`, on `device`, with `read` in blocks of `block` points.
#[cfg(feature = "wgpu")]
fn trilinear_with_gradient(
    device: &Device,
    features: &[f32],
    dims: [usize; 3],
    corners: &TrilinearCorners,
    read: CornerRead,
    block: usize,
) -> (Vec<f32>, Vec<f32>) {
    let ad = device.clone().autodiff();
    let [n, _, c] = dims;
    let x = tensor(features.to_vec(), dims, &ad).require_grad();
    let out = sample_with(
        &SiteRows::new(x.clone(), read),
        &TrilinearTensors::upload_for(corners, read, &ad),
        block,
    )
    .unwrap();
    let m = corners.num_points();
    let cotangent: Vec<f32> = (0..n * m * c)
        .map(|i| ((i % 13) as f32 - 6.0) / 6.0)
        .collect();
    let grads = (out.clone() * tensor(cotangent, [n, m, c], &ad))
        .sum()
        .backward();
    (values(out), values(x.grad(&grads).unwrap()))
}

/// The GPU backends' read (one gather per corner, large blocks) on wgpu against the CPU's
/// stacked read on ndarray: the values and the gradient of the features, in several blocks
/// and in the default one, with points outside the box and on its faces.
#[cfg(feature = "wgpu")]
#[test]
fn trilinear_by_corner_on_wgpu_matches_ndarray() {
    let Some(gpu) = common::wgpu_device() else {
        return;
    };
    let cpu = device();
    let mut rng = Rng::new(53);
    let vb = test_box();
    let (_, _, dims) = vb.level_placement(0);
    let scale = ScaleGeometry::new(&vb, 0, random_sites(&mut rng, dims, 0.6)).unwrap();
    let (n, c, p) = (3, 16, scale.num_sites());
    let features = normals(&mut rng, n * p * c);
    // 4,096 points: blocks of 2,048 are views of the corner-major rows on any alignment, blocks
    // of 777 are copies.
    let mut points = random_points(&mut rng, &vb, 4094, 0.08);
    points.push(vb.min_m);
    points.push(vb.max_m());
    let corners = TrilinearCorners::compute(&points, &scale);
    let fdims = [n, p, c];
    let (want, want_grad) =
        trilinear_with_gradient(&cpu, &features, fdims, &corners, CornerRead::Stacked, 300);
    for block in [777, 2048, points.len()] {
        let (got, got_grad) = trilinear_with_gradient(
            &gpu,
            &features,
            fdims,
            &corners,
            CornerRead::ByCorner,
            block,
        );
        for (what, a, b) in [("values", &got, &want), ("gradient", &got_grad, &want_grad)] {
            assert_eq!(a.len(), b.len());
            let diff = a
                .iter()
                .zip(b.iter())
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max);
            assert!(diff <= 1e-5, "{what} on wgpu, blocks of {block}: {diff}");
        }
    }
    // `sample` on wgpu picks the by-corner read; a scale volume there lays its rows out once
    // and reads them for every call, and reads corners uploaded for the stacked read too.
    let scale = std::sync::Arc::new(scale);
    let volume = nia_model::body_volume::ScaleVolume::new(
        tensor(features.clone(), fdims, &gpu),
        scale.clone(),
    );
    assert_eq!(volume.rows().map(|r| r.read), Some(CornerRead::ByCorner));
    for got in [
        sample(
            tensor(features.clone(), fdims, &gpu),
            &TrilinearTensors::upload(&corners, &gpu),
        )
        .unwrap(),
        volume
            .sample(&TrilinearTensors::upload(&corners, &gpu))
            .unwrap(),
        volume
            .sample(&TrilinearTensors::upload_for(
                &corners,
                CornerRead::Stacked,
                &gpu,
            ))
            .unwrap(),
    ] {
        let diff = values(got)
            .iter()
            .zip(&want)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(diff <= 1e-5, "sample on wgpu: {diff}");
    }
    assert_eq!(CornerRead::for_device(&gpu), CornerRead::ByCorner);
    assert_eq!(CornerRead::for_device(&cpu), CornerRead::Stacked);
}

/// The fused host read of the body volume (inference on the CPU backends) against the tensor
/// path, over two scales of different widths: points inside, outside, on voxel centres, on the
/// box faces and non-finite; and a mismatched set of corners is an error.
#[test]
fn host_read_matches_the_tensor_read_on_every_scale() {
    use nia_model::body_volume::{BodyVolume, HostVolume, ScaleVolume};
    use std::sync::Arc;
    let dev = device();
    let mut rng = Rng::new(47);
    let vb = test_box();
    let n = 3;
    let mut scales = Vec::new();
    for (level, c) in [(0u32, 3usize), (1, 5)] {
        let (_, _, dims) = vb.level_placement(level);
        let sites = random_sites(&mut rng, dims, 0.5);
        let geometry = Arc::new(ScaleGeometry::new(&vb, level, sites).unwrap());
        let p = geometry.num_sites();
        let features = tensor(normals(&mut rng, n * p * c), [n, p, c], &dev);
        scales.push(ScaleVolume::new(features, geometry));
    }
    let volume = BodyVolume { scales };
    let mut points = random_points(&mut rng, &vb, 400, 0.08);
    points.push(volume.scales[0].geometry.centre_of([1, 2, 3]));
    points.push(vb.min_m);
    points.push(vb.max_m());
    points.push([f32::NAN, 0.3, 0.1]);
    points.push([f32::INFINITY, 0.3, 0.1]);
    let corners: Vec<TrilinearCorners> = volume
        .scales
        .iter()
        .map(|s| TrilinearCorners::compute(&points, &s.geometry))
        .collect();
    let uploaded: Vec<TrilinearTensors> = corners
        .iter()
        .map(|c| TrilinearTensors::upload(c, &dev))
        .collect();
    let reference = values(volume.sample(&uploaded).unwrap());
    let host = HostVolume::read(&volume, None).unwrap();
    assert_eq!(host.channels(), 8);
    assert_eq!(host.num_views(), n);
    let fused = host.sample(&corners).unwrap();
    assert_eq!(fused.len(), n * points.len() * 8);
    assert_eq!(reference.len(), fused.len());
    let mut nonzero = 0;
    for (i, (r, f)) in reference.iter().zip(&fused).enumerate() {
        assert!(f.is_finite(), "[{i}] {f}");
        assert!((r - f).abs() <= 1e-5, "[{i}] tensor {r} vs host {f}");
        nonzero += usize::from(*f != 0.0);
    }
    assert!(
        nonzero > fused.len() / 4,
        "the points should mostly read sites"
    );
    // One corner set for two scales, or corners of another site count: errors.
    assert!(host.sample(&corners[..1]).is_err());
    let swapped = vec![corners[1].clone(), corners[0].clone()];
    assert!(host.sample(&swapped).is_err());
    let other_points = TrilinearCorners::compute(&points[..3], &volume.scales[1].geometry);
    assert!(host.sample(&[corners[0].clone(), other_points]).is_err());

    // Through a reduction to d = 4: the 5-channel scale is stored reduced per site (4 <= 5),
    // the 3-channel one as it is; the reduced read equals the reduction of the full read.
    use burn::nn::LinearConfig;
    use nia_model::kernels::linear_rows::linear_rows;
    let linear = LinearConfig::new(8, 4).init(&dev);
    let reducing = HostVolume::read(&volume, Some(linear.weight.val())).unwrap();
    assert_eq!(reducing.channels(), 3 + 4);
    let read = reducing.sample(&corners).unwrap();
    let reduced = reducing.reduce(&read, &linear).unwrap();
    let expected = values(linear_rows(&linear, volume.sample(&uploaded).unwrap()));
    assert_eq!(reduced.len(), expected.len());
    for (i, (r, e)) in reduced.iter().zip(&expected).enumerate() {
        assert!((r - e).abs() <= 1e-5, "[{i}] reduced host read {r} vs {e}");
    }
    // Without reduced scales `reduce` is the linear layer itself.
    let plain = host.reduce(&fused, &linear).unwrap();
    for (i, (r, e)) in plain.iter().zip(&expected).enumerate() {
        assert!((r - e).abs() <= 1e-5, "[{i}] host read reduced {r} vs {e}");
    }
    // A read that is not whole rows of the layout's channels is an error.
    let err = reducing
        .reduce(&read[..read.len() - 1], &linear)
        .unwrap_err();
    assert!(err.to_string().contains("rows of 7 channels"), "{err}");
    // A weight of another height is an error naming what was expected.
    let wrong = LinearConfig::new(6, 4).init(&dev);
    let err = HostVolume::read(&volume, Some(wrong.weight.val())).unwrap_err();
    assert!(err.to_string().contains("[8, d]"), "{err}");
}

#[test]
fn trilinear_on_a_centre_plane_matches_burn_grid_sample_2d() {
    // With z on a plane of voxel centres, trilinear = bilinear on that slice: compare with
    // burn's grid_sample_2d(align_corners = true, zeros) on the slice [C, H = Y, W = X].
    let dev = device();
    let mut rng = Rng::new(41);
    let vb = test_box();
    let dims = vb.dims;
    let sites = random_sites(&mut rng, dims, 0.7);
    let scale = ScaleGeometry::new(&vb, 0, sites).unwrap();
    let (c, p) = (2, scale.num_sites());
    let features = normals(&mut rng, p * c);
    let z0 = 3;
    let z = scale.centre_of([0, 0, z0])[2];
    let first = scale.centre_of([0, 0, 0]);
    let last = scale.centre_of([dims[0] as i32 - 1, dims[1] as i32 - 1, 0]);
    // Points between the first and last voxel centres (grid coords in [-1, 1]).
    let points: Vec<[f32; 3]> = (0..64)
        .map(|_| {
            [
                rng.range(first[0], last[0]),
                rng.range(first[1], last[1]),
                z,
            ]
        })
        .collect();
    let corners = TrilinearCorners::compute(&points, &scale);
    let got = values(
        sample(
            tensor(features.clone(), [1, p, c], &dev),
            &TrilinearTensors::upload(&corners, &dev),
        )
        .unwrap(),
    );
    let mut slice = vec![0.0f32; c * dims[1] * dims[0]];
    for (s, site) in scale.sites.sites().iter().enumerate() {
        if site[2] == z0 {
            for ch in 0..c {
                slice[(ch * dims[1] + site[1] as usize) * dims[0] + site[0] as usize] =
                    features[s * c + ch];
            }
        }
    }
    let image: Tensor<4> =
        Tensor::from_data(TensorData::new(slice, [1, c, dims[1], dims[0]]), &dev);
    let grid: Vec<f32> = points
        .iter()
        .flat_map(|q| {
            [
                -1.0 + 2.0 * (q[0] - first[0]) / (last[0] - first[0]),
                -1.0 + 2.0 * (q[1] - first[1]) / (last[1] - first[1]),
            ]
        })
        .collect();
    let grid: Tensor<4> = Tensor::from_data(TensorData::new(grid, [1, 1, points.len(), 2]), &dev);
    let options = GridSampleOptions::new(InterpolateMode::Bilinear)
        .with_padding_mode(GridSamplePaddingMode::Zeros)
        .with_align_corners(true);
    let expected = values(image.grid_sample_2d(grid, options)); // [1, C, 1, M]
    for m in 0..points.len() {
        for ch in 0..c {
            let (g, e) = (got[m * c + ch], expected[ch * points.len() + m]);
            assert!(
                (g - e).abs() <= TRILINEAR_TOL,
                "point {m} ch {ch}: {g} vs {e}"
            );
        }
    }
}

#[test]
fn trilinear_gradients_reach_features_and_outside_points_are_zero() {
    let ad = device().autodiff();
    let mut rng = Rng::new(51);
    let vb = test_box();
    let scale = ScaleGeometry::new(&vb, 0, random_sites(&mut rng, vb.dims, 0.5)).unwrap();
    let (n, c, p) = (2, 3, scale.num_sites());
    let far = [vb.max_m()[0] + 1.0, 0.0, 0.0];
    let points = vec![scale.centre_of([2, 2, 2]), far, [0.0, 0.3, 0.2]];
    let corners = TrilinearCorners::compute(&points, &scale);
    let features = tensor(normals(&mut rng, n * p * c), [n, p, c], &ad).require_grad();
    let out = sample(features.clone(), &TrilinearTensors::upload(&corners, &ad)).unwrap();
    let r = normals(&mut rng, n * points.len() * c);
    let loss = (out.clone() * tensor(r.clone(), [n, points.len(), c], &ad)).sum();
    let grads = loss.backward();
    let out = values(out);
    for v in 0..n {
        for ch in 0..c {
            assert_eq!(out[(v * points.len() + 1) * c + ch], 0.0, "far point");
        }
    }
    // d loss / d features[n, s, ch] = sum_m r[n, m, ch] * weight of site s for point m.
    let grad = values(features.grad(&grads).unwrap());
    assert!(grad.iter().all(|g| g.is_finite()));
    let mut expected = vec![0.0f32; n * p * c];
    for m in 0..points.len() {
        for j in 0..CORNERS {
            let s = corners.index[m * CORNERS + j] as usize;
            if s == p {
                continue;
            }
            for v in 0..n {
                for ch in 0..c {
                    expected[(v * p + s) * c + ch] +=
                        corners.weight[m * CORNERS + j] * r[(v * points.len() + m) * c + ch];
                }
            }
        }
    }
    for (g, e) in grad.iter().zip(&expected) {
        assert!((g - e).abs() <= TRILINEAR_TOL, "{g} vs {e}");
    }
}

/// The GPU read's blocks hold a multiple of `BY_CORNER_BLOCK_ALIGN` points (so a block's slice
/// of a corner's row is a view, not a copy) and no more than 64 MiB of gathered values, at the
/// paper's scales and at widths too large for one aligned block.
#[test]
fn by_corner_blocks_are_aligned_and_within_their_bytes() {
    use nia_model::body_volume::trilinear::{BY_CORNER_BLOCK_ALIGN, BY_CORNER_BLOCK_BYTES};
    for (n, c) in [(3, 32), (3, 64), (3, 128), (1, 8), (4, 128)] {
        let points = CornerRead::ByCorner.points_per_block(n, c);
        assert_eq!(
            points % BY_CORNER_BLOCK_ALIGN,
            0,
            "N {n} C {c}: {points} points"
        );
        assert!(points * n * c * 4 <= BY_CORNER_BLOCK_BYTES, "N {n} C {c}");
        assert!((points + BY_CORNER_BLOCK_ALIGN) * n * c * 4 > BY_CORNER_BLOCK_BYTES);
    }
    // Rows too wide for even one aligned block: as many points as fit, at least one.
    let wide = CornerRead::ByCorner.points_per_block(1, BY_CORNER_BLOCK_BYTES / 4 / 1000);
    assert!((1..BY_CORNER_BLOCK_ALIGN).contains(&wide), "{wide}");
    assert_eq!(
        CornerRead::ByCorner.points_per_block(1, BY_CORNER_BLOCK_BYTES),
        1
    );
}
