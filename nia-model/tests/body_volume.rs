//! The body volume: rulebooks against brute force, sparse convolution against burn's dense
//! `conv3d`, gradients against finite differences, trilinear sampling against a dense
//! `grid_sample(align_corners=True)` reference, and the network end to end.

mod common;

use std::collections::BTreeSet;

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::module::conv3d;
use burn::tensor::ops::{ConvOptions, GridSampleOptions, GridSamplePaddingMode, InterpolateMode};
use common::relative_gap;
use nia_data::geometry::sparse::{
    kernel_offset, strided_dim, voxelize, Rulebook, ScaleGeometry, SiteIndex, TrilinearCorners,
    VoxelBox, CORNERS, KERNEL_VOLUME,
};
use nia_data::rng::Rng;
use nia_model::body_volume::trilinear::{sample, sample_with, CornerRead, SiteRows};
use nia_model::body_volume::{
    BodyVolumeGeometry, BodyVolumeNetConfig, ConvMethod, RulebookTensors, SiteNormConfig,
    SparseConv3d, SparseConv3dConfig, TrilinearTensors, NUM_SCALES,
};

/// Sparse vs dense convolution: both sum at most 27 * C_in products of O(1) f32 values in a
/// different order; 1e-4 absolute leaves ~50x room over the observed rounding.
const CONV_TOL: f32 = 1e-4;
/// Trilinear vs the dense reference: 8 products of O(1) values, weights from the same f32
/// coordinates computed along two formulas (normalise/unnormalise vs direct).
const TRILINEAR_TOL: f32 = 1e-4;
/// Finite-difference step on weights and features.
const FD_STEP: f64 = 1e-2;
/// The loss is quadratic in each entry, so a central difference is exact up to rounding: the
/// f32 outputs (~1e-7 relative) summed into an O(10) loss, divided by 2 * FD_STEP, give
/// ~1e-4; allow 2e-3 relative to max(1, |grad|).
const FD_TOL: f64 = 2e-3;

/// burn-ndarray, the reference CPU backend of the tests (deprecated upstream, still kept).
#[allow(deprecated)]
fn device() -> Device {
    Device::ndarray()
}

fn normals(rng: &mut Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.normal()).collect()
}

fn tensor3(values: Vec<f32>, dims: [usize; 3], device: &Device) -> Tensor<3> {
    Tensor::from_data(TensorData::new(values, dims), device)
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap()
}

fn random_sites(rng: &mut Rng, dims: [usize; 3], fraction: f32) -> SiteIndex {
    let mut sites = Vec::new();
    for x in 0..dims[0] {
        for y in 0..dims[1] {
            for z in 0..dims[2] {
                if rng.uniform() < fraction {
                    sites.push([x as i32, y as i32, z as i32]);
                }
            }
        }
    }
    // Shuffled order: the rulebooks must not rely on sorted inputs.
    rng.shuffle(&mut sites);
    SiteIndex::new(dims, sites).unwrap()
}

fn pair_set(rules: &Rulebook) -> BTreeSet<(usize, u32, u32)> {
    (0..KERNEL_VOLUME)
        .flat_map(|k| rules.pairs(k).map(move |(i, o)| (k, i, o)))
        .collect()
}

fn find(sites: &[[i32; 3]], c: [i32; 3]) -> Option<u32> {
    sites.iter().position(|s| *s == c).map(|i| i as u32)
}

#[test]
fn rulebooks_match_brute_force() {
    let mut rng = Rng::new(7);
    for dims in [[7, 6, 9], [8, 5, 4], [3, 3, 3]] {
        let sites = random_sites(&mut rng, dims, 0.3);
        let list = sites.sites().to_vec();

        let sub = Rulebook::submanifold(&sites);
        let mut expected = BTreeSet::new();
        for (o, c) in list.iter().enumerate() {
            for k in 0..KERNEL_VOLUME {
                let d = kernel_offset(k);
                if let Some(i) = find(&list, [c[0] + d[0], c[1] + d[1], c[2] + d[2]]) {
                    expected.insert((k, i, o as u32));
                }
            }
        }
        assert_eq!(pair_set(&sub), expected, "submanifold pairs, dims {dims:?}");
        assert_eq!((sub.n_in, sub.n_out), (list.len(), list.len()));

        let (coarse, strided) = Rulebook::strided(&sites).unwrap();
        let dims_out = dims.map(strided_dim);
        assert_eq!(coarse.dims(), dims_out);
        // Every coarse voxel, in linear order; an output exists iff some input reaches it.
        let mut expected_sites = Vec::new();
        let mut expected_pairs = Vec::new();
        for x in 0..dims_out[0] as i32 {
            for y in 0..dims_out[1] as i32 {
                for z in 0..dims_out[2] as i32 {
                    let mut reached = Vec::new();
                    for k in 0..KERNEL_VOLUME {
                        let d = kernel_offset(k);
                        let input = [2 * x + d[0], 2 * y + d[1], 2 * z + d[2]];
                        if let Some(i) = find(&list, input) {
                            reached.push((k, i));
                        }
                    }
                    if !reached.is_empty() {
                        let o = expected_sites.len() as u32;
                        expected_sites.push([x, y, z]);
                        expected_pairs.extend(reached.into_iter().map(|(k, i)| (k, i, o)));
                    }
                }
            }
        }
        assert_eq!(coarse.sites(), expected_sites.as_slice(), "dims {dims:?}");
        assert_eq!(
            pair_set(&strided),
            expected_pairs.into_iter().collect::<BTreeSet<_>>(),
            "strided pairs, dims {dims:?}"
        );
        // The neighbour map holds the same pairs.
        let map = strided.neighbour_map();
        for (k, i, o) in pair_set(&strided) {
            assert_eq!(map[o as usize * KERNEL_VOLUME + k], i);
        }
        let filled = map.iter().filter(|&&i| i as usize != strided.n_in).count();
        assert_eq!(filled, strided.num_pairs());
        // The host convolution's maps: the same neighbour map, and its inverse holds the same
        // pairs seen from the inputs; built once, and shared by the clones made after.
        assert!(strided.built_neighbour_maps().is_none());
        let maps = strided.neighbour_maps();
        assert_eq!(maps.neighbours, map);
        for (k, i, o) in pair_set(&strided) {
            assert_eq!(maps.inverse[i as usize * KERNEL_VOLUME + k], o);
        }
        let inverse_filled = maps
            .inverse
            .iter()
            .filter(|&&o| o as usize != strided.n_out);
        assert_eq!(inverse_filled.count(), strided.num_pairs());
        assert_eq!(maps.inverse.len(), strided.n_in * KERNEL_VOLUME);
        assert!(std::sync::Arc::ptr_eq(&maps, &strided.neighbour_maps()));
        let copy = strided.clone();
        assert!(std::sync::Arc::ptr_eq(
            &maps,
            &copy.built_neighbour_maps().unwrap()
        ));
    }
}

#[test]
fn site_index_rejects_bad_sites() {
    assert!(SiteIndex::new([2, 2, 2], vec![[0, 0, 0], [0, 0, 0]]).is_err());
    assert!(SiteIndex::new([2, 2, 2], vec![[0, 2, 0]]).is_err());
    assert!(SiteIndex::new([2, 2, 2], vec![[-1, 0, 0]]).is_err());
    let index = SiteIndex::new([2, 2, 2], vec![[1, 0, 1], [0, 1, 0]]).unwrap();
    assert_eq!(index.get([0, 1, 0]), Some(1));
    assert_eq!(index.get([1, 1, 1]), None);
    assert_eq!(index.get([-1, 1, 1]), None);
    assert_eq!(index.get([1, 1, 5]), None);
}

/// A dense `[N, C, X, Y, Z]` grid holding `features` `[N, P, C]` at the sites, zero elsewhere.
fn densify(features: &[f32], n: usize, c: usize, sites: &SiteIndex) -> Vec<f32> {
    let [dx, dy, dz] = sites.dims();
    let mut grid = vec![0.0; n * c * dx * dy * dz];
    let p = sites.len();
    for v in 0..n {
        for (s, site) in sites.sites().iter().enumerate() {
            for ch in 0..c {
                let [x, y, z] = site.map(|a| a as usize);
                grid[(((v * c + ch) * dx + x) * dy + y) * dz + z] = features[(v * p + s) * c + ch];
            }
        }
    }
    grid
}

/// The dense `Conv3d` weight `[C_out, C_in, 3, 3, 3]` equal to a sparse `[27, C_in, C_out]`.
fn dense_weight(sparse: &[f32], c_in: usize, c_out: usize) -> Vec<f32> {
    let mut w = vec![0.0; c_out * c_in * KERNEL_VOLUME];
    for k in 0..KERNEL_VOLUME {
        for i in 0..c_in {
            for o in 0..c_out {
                w[(o * c_in + i) * KERNEL_VOLUME + k] = sparse[(k * c_in + i) * c_out + o];
            }
        }
    }
    w
}

/// Checks a sparse convolution against burn's dense `conv3d` at every output voxel: equal at
/// the output sites, bias-only (here: zero bias) everywhere else.
fn check_against_dense(
    dev: &Device,
    sites: &SiteIndex,
    strided: bool,
    method: ConvMethod,
    seed: u64,
) {
    let dev = dev.clone();
    let mut rng = Rng::new(seed);
    let (n, c_in, c_out) = (2, 3, 4);
    let (out_sites, rules) = if strided {
        Rulebook::strided(sites).unwrap()
    } else {
        (sites.clone(), Rulebook::submanifold(sites))
    };
    // Blocks of 3 outputs exercise the blocked Im2col path on these small grids.
    let tensors = RulebookTensors::with_method(&rules, method, &dev).with_outputs_per_chunk(3);
    assert_eq!(tensors.method(), method);
    let conv = SparseConv3dConfig::new(c_in, c_out).init(&dev);
    let bias = values(conv.bias.as_ref().unwrap().val());
    let features = normals(&mut rng, n * sites.len() * c_in);
    let sparse_out = values(
        conv.forward(
            tensor3(features.clone(), [n, sites.len(), c_in], &dev),
            &tensors,
        )
        .unwrap(),
    );
    assert_eq!(sparse_out.len(), n * out_sites.len() * c_out);
    assert!(sparse_out.iter().all(|v| v.is_finite()));

    let [dx, dy, dz] = sites.dims();
    let grid: Tensor<5> = Tensor::from_data(
        TensorData::new(densify(&features, n, c_in, sites), [n, c_in, dx, dy, dz]),
        &dev,
    );
    let w_dense: Tensor<5> = Tensor::from_data(
        TensorData::new(
            dense_weight(&values(conv.weight.val()), c_in, c_out),
            [c_out, c_in, 3, 3, 3],
        ),
        &dev,
    );
    let stride = if strided { 2 } else { 1 };
    let dense = conv3d(
        grid,
        w_dense,
        None,
        ConvOptions::new([stride; 3], [1; 3], [1; 3], 1),
    );
    let [_, _, ox, oy, oz] = dense.dims();
    assert_eq!([ox, oy, oz], out_sites.dims());
    let dense = values(dense);
    let p_out = out_sites.len();
    for v in 0..n {
        for x in 0..ox {
            for y in 0..oy {
                for z in 0..oz {
                    let site = out_sites.get([x as i32, y as i32, z as i32]);
                    for o in 0..c_out {
                        let d = dense[(((v * c_out + o) * ox + x) * oy + y) * oz + z];
                        match site {
                            Some(s) => {
                                let s = sparse_out[(v * p_out + s as usize) * c_out + o];
                                assert!(
                                    (s - bias[o] - d).abs() <= CONV_TOL,
                                    "{method:?} strided={strided} view {v} voxel {:?} ch {o}: \
                                     sparse {s} - bias {} vs dense {d}",
                                    [x, y, z],
                                    bias[o]
                                );
                            }
                            None if strided => assert!(
                                d.abs() <= CONV_TOL,
                                "strided: dense output {d} at inactive voxel {:?}",
                                [x, y, z]
                            ),
                            // Submanifold outputs exist only at the input sites.
                            None => {}
                        }
                    }
                }
            }
        }
    }
}

/// `check_against_dense` (its weights seeded with `weights_seed`) on random sites of each
/// `(dims, occupied fraction)` grid (drawn in turn from one generator seeded with `seed`), with
/// the two tensor methods on ndarray and flex and the host kernels on flex.
fn conv_matches_dense(seed: u64, grids: [([usize; 3], f32); 3], strided: bool, weights_seed: u64) {
    let mut rng = Rng::new(seed);
    for (dims, fraction) in grids {
        let sites = random_sites(&mut rng, dims, fraction);
        for method in [ConvMethod::Im2col, ConvMethod::Pairs] {
            for dev in [device(), Device::flex()] {
                check_against_dense(&dev, &sites, strided, method, weights_seed);
            }
        }
        check_against_dense(
            &Device::flex(),
            &sites,
            strided,
            ConvMethod::Host,
            weights_seed,
        );
    }
}

#[test]
fn submanifold_conv_matches_dense_conv3d() {
    let grids = [([5, 4, 6], 0.35), ([4, 4, 4], 0.9), ([6, 3, 5], 0.08)];
    conv_matches_dense(11, grids, false, 3);
}

#[test]
fn strided_conv_matches_dense_conv3d() {
    // Even and odd extents: with an even extent the last input row reaches past the coarse
    // grid (dropped, like spconv and the dense conv).
    let grids = [([6, 5, 7], 0.3), ([4, 8, 3], 0.6), ([7, 7, 7], 0.05)];
    conv_matches_dense(12, grids, true, 4);
}

#[test]
fn site_norm_normalises_each_view_over_its_sites() {
    let dev = device();
    let mut rng = Rng::new(15);
    let (n, p, c) = (3, 50, 4);
    // Views with very different scales and offsets.
    let x: Vec<f32> = (0..n * p * c)
        .map(|i| rng.normal() * (1 + i / (p * c)) as f32 * 10.0 + (i / (p * c)) as f32 * 5.0)
        .collect();
    let norm = SiteNormConfig::new(c).init(&dev);
    let y = values(norm.forward(tensor3(x, [n, p, c], &dev)).unwrap());
    for v in 0..n {
        for ch in 0..c {
            let column: Vec<f64> = (0..p).map(|s| y[(v * p + s) * c + ch] as f64).collect();
            let mean = column.iter().sum::<f64>() / p as f64;
            let var = column.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / p as f64;
            // Mean 0, variance var / (var + eps) ~ 1 for variances of ~100.
            assert!(mean.abs() < 1e-4, "view {v} ch {ch} mean {mean}");
            assert!((var - 1.0).abs() < 1e-3, "view {v} ch {ch} var {var}");
        }
    }
    assert!(norm
        .forward(tensor3(vec![0.0; 6], [1, 2, 3], &dev))
        .is_err());
}

/// `x` with coordinate `i` moved up by `FD_STEP`, and that moved down by twice the step (in
/// f32, as the tolerances were measured).
fn steps_at(x: &[f32], i: usize) -> (Vec<f32>, Vec<f32>) {
    let mut up = x.to_vec();
    up[i] += FD_STEP as f32;
    let mut down = up.clone();
    down[i] -= 2.0 * FD_STEP as f32;
    (up, down)
}

/// `sum(out^2 * r)` in f64 from the output values.
fn quadratic_loss(out: &[f32], r: &[f32]) -> f64 {
    out.iter()
        .zip(r)
        .map(|(&o, &r)| (o as f64) * (o as f64) * r as f64)
        .sum()
}

fn conv_with(weight: Vec<f32>, dims: [usize; 3], device: &Device) -> SparseConv3d {
    SparseConv3d {
        weight: Param::from_tensor(tensor3(weight, dims, device)),
        bias: None,
    }
}

#[test]
fn sparse_conv_gradients_match_finite_differences() {
    let mut rng = Rng::new(21);
    let sites = random_sites(&mut rng, [4, 4, 3], 0.35);
    let (n, c_in, c_out, p) = (2, 2, 3, sites.len());
    for strided in [false, true] {
        let rules = if strided {
            Rulebook::strided(&sites).unwrap().1
        } else {
            Rulebook::submanifold(&sites)
        };
        // The tensor methods on ndarray; the host kernels (hand-written backward) on flex.
        for (method, plain) in [
            (ConvMethod::Im2col, device()),
            (ConvMethod::Pairs, device()),
            (ConvMethod::Host, Device::flex()),
        ] {
            let ad = plain.clone().autodiff();
            let weight = normals(&mut rng, KERNEL_VOLUME * c_in * c_out);
            let features = normals(&mut rng, n * p * c_in);
            let r = normals(&mut rng, n * rules.n_out * c_out);
            let w_dims = [KERNEL_VOLUME, c_in, c_out];
            let f_dims = [n, p, c_in];

            // Analytic gradients on the autodiff device.
            let rules_ad =
                RulebookTensors::with_method(&rules, method, &ad).with_outputs_per_chunk(4);
            assert_eq!(rules_ad.method(), method);
            let conv = conv_with(weight.clone(), w_dims, &ad);
            let x = tensor3(features.clone(), f_dims, &ad).require_grad();
            let out = conv.forward(x.clone(), &rules_ad).unwrap();
            let r_t = tensor3(r.clone(), [n, rules.n_out, c_out], &ad);
            let grads = (out.clone() * out * r_t).sum().backward();
            let grad_w = values(conv.weight.grad(&grads).unwrap());
            let grad_x = values(x.grad(&grads).unwrap());

            // Central differences on the plain device.
            let rules_plain = RulebookTensors::with_method(&rules, method, &plain);
            let loss = |w: &[f32], f: &[f32]| {
                let conv = conv_with(w.to_vec(), w_dims, &plain);
                let out = conv
                    .forward(tensor3(f.to_vec(), f_dims, &plain), &rules_plain)
                    .unwrap();
                quadratic_loss(&values(out), &r)
            };
            let check = |name: &str, analytic: f32, plus: f64, minus: f64, i: usize| {
                let fd = (plus - minus) / (2.0 * FD_STEP);
                let err = (fd - analytic as f64).abs();
                assert!(
                    err <= FD_TOL * fd.abs().max(1.0),
                    "{method:?} strided={strided} d loss / d {name}[{i}]: autodiff {analytic}, \
                     finite difference {fd}"
                );
            };
            assert_eq!(grad_w.len(), weight.len());
            for (i, &g) in grad_w.iter().enumerate() {
                let (up, down) = steps_at(&weight, i);
                let (plus, minus) = (loss(&up, &features), loss(&down, &features));
                check("weight", g, plus, minus, i);
            }
            assert_eq!(grad_x.len(), features.len());
            for (i, &g) in grad_x.iter().enumerate() {
                let (up, down) = steps_at(&features, i);
                let (plus, minus) = (loss(&weight, &up), loss(&weight, &down));
                check("features", g, plus, minus, i);
            }
        }
    }
}

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

fn random_points(rng: &mut Rng, vb: &VoxelBox, m: usize, margin: f32) -> Vec<[f32; 3]> {
    let max = vb.max_m();
    (0..m)
        .map(|_| std::array::from_fn(|a| rng.range(vb.min_m[a] - margin, max[a] + margin)))
        .collect()
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
            values(sample(tensor3(features.clone(), [n, p, c], &dev), &corner_tensors).unwrap());
        // Blocks of 7 points give the same values; the GPU backends' read (one gather per
        // corner, corner-major corners, site-major rows) sums the same 8 products in another
        // order.
        let rows_for = |read| SiteRows::new(tensor3(features.clone(), [n, p, c], &dev), read);
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
            let f = tensor3(features.clone(), [n, p, c], &ad).require_grad();
            let corner_tensors = TrilinearTensors::upload(&corners, &ad);
            let out = sample(f.clone(), &corner_tensors).unwrap();
            let g = (out.clone() * tensor3(upstream.clone(), [n, points.len(), c], &ad))
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
    let x = tensor3(features.to_vec(), dims, &ad).require_grad();
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
    let grads = (out.clone() * tensor3(cotangent, [n, m, c], &ad))
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
        tensor3(features.clone(), fdims, &gpu),
        scale.clone(),
    );
    assert_eq!(volume.rows().map(|r| r.read), Some(CornerRead::ByCorner));
    for got in [
        sample(
            tensor3(features.clone(), fdims, &gpu),
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
        let features = tensor3(normals(&mut rng, n * p * c), [n, p, c], &dev);
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
            tensor3(features.clone(), [1, p, c], &dev),
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
    let features = tensor3(normals(&mut rng, n * p * c), [n, p, c], &ad).require_grad();
    let out = sample(features.clone(), &TrilinearTensors::upload(&corners, &ad)).unwrap();
    let r = normals(&mut rng, n * points.len() * c);
    let loss = (out.clone() * tensor3(r.clone(), [n, points.len(), c], &ad)).sum();
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

/// Vertices on a few capsules shaped like a standing person (~1.7 m), SMPL-like density.
fn body_like_vertices(rng: &mut Rng, count: usize) -> Vec<[f32; 3]> {
    // (start, end, radius) metres: torso, head, arms, legs.
    let parts: [([f32; 3], [f32; 3], f32); 6] = [
        ([0.0, -0.05, 0.0], [0.0, 0.5, 0.0], 0.15),
        ([0.0, 0.6, 0.0], [0.0, 0.75, 0.0], 0.1),
        ([-0.2, 0.45, 0.0], [-0.75, 0.45, 0.05], 0.05),
        ([0.2, 0.45, 0.0], [0.75, 0.45, 0.05], 0.05),
        ([-0.1, -0.1, 0.0], [-0.12, -0.95, 0.02], 0.07),
        ([0.1, -0.1, 0.0], [0.12, -0.95, 0.02], 0.07),
    ];
    (0..count)
        .map(|i| {
            let (a, b, r) = parts[i % parts.len()];
            let t = rng.uniform();
            let theta = rng.range(0.0, std::f32::consts::TAU);
            let axis: [f32; 3] = std::array::from_fn(|k| b[k] - a[k]);
            let len = axis.iter().map(|v| v * v).sum::<f32>().sqrt();
            let u = axis.map(|v| v / len);
            // Any two unit vectors orthogonal to the axis.
            let helper = if u[2].abs() < 0.9 {
                [0.0, 0.0, 1.0]
            } else {
                [1.0, 0.0, 0.0]
            };
            let e1 = normalise(cross(u, helper));
            let e2 = cross(u, e1);
            std::array::from_fn(|k| {
                a[k] + t * axis[k] + r * (theta.cos() * e1[k] + theta.sin() * e2[k])
            })
        })
        .collect()
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalise(v: [f32; 3]) -> [f32; 3] {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    v.map(|x| x / n)
}

#[test]
fn voxelize_sorts_sites_and_maps_every_vertex() {
    let mut rng = Rng::new(61);
    let vertices = body_like_vertices(&mut rng, 600);
    let vb = VoxelBox::enclosing(&vertices, 0.025, 0.02).unwrap();
    // Each extent grows by 2.5% about the centre; the grid covers it.
    let lo: [f32; 3] =
        std::array::from_fn(|a| vertices.iter().map(|v| v[a]).fold(f32::MAX, f32::min));
    let hi: [f32; 3] =
        std::array::from_fn(|a| vertices.iter().map(|v| v[a]).fold(f32::MIN, f32::max));
    for a in 0..3 {
        let margin = 0.0125 * (hi[a] - lo[a]);
        assert!((lo[a] - margin - vb.min_m[a]).abs() < 1e-5);
        assert!(vb.max_m()[a] >= hi[a] + margin - 1e-5);
        assert!(vb.max_m()[a] < hi[a] + margin + vb.voxel_size_m);
    }
    let vox = voxelize(&vertices, &vb).unwrap();
    let sites = vox.sites.sites();
    let linear =
        |c: &[i32; 3]| (c[0] as usize * vb.dims[1] + c[1] as usize) * vb.dims[2] + c[2] as usize;
    assert!(sites.windows(2).all(|w| linear(&w[0]) < linear(&w[1])));
    for (i, v) in vertices.iter().enumerate() {
        let c = vox.vertex_voxel[i];
        for a in 0..3 {
            let lo = vb.min_m[a] + c[a] as f32 * vb.voxel_size_m;
            assert!(v[a] >= lo - 1e-5 && v[a] <= lo + vb.voxel_size_m + 1e-5);
        }
        assert_eq!(sites[vox.vertex_site[i] as usize], c);
    }
    assert_eq!(
        vox.site_vertex_count.iter().sum::<u32>() as usize,
        vertices.len()
    );
    assert!(vox.site_vertex_count.iter().all(|&c| c >= 1));

    assert!(voxelize(&[], &vb).is_err());
    assert!(voxelize(&[[f32::NAN, 0.0, 0.0]], &vb).is_err());
    assert!(voxelize(&[[vb.max_m()[0] + 0.1, 0.0, 0.0]], &vb).is_err());
    assert!(VoxelBox::enclosing(&vertices, 0.025, 0.0).is_err());
    assert!(VoxelBox::enclosing(&vertices, -1.0, 0.01).is_err());
}

fn small_config() -> BodyVolumeNetConfig {
    BodyVolumeNetConfig::new()
        .with_vertex_channels(4)
        .with_full_channels(4)
        .with_full_convs(1)
        .with_scale_channels([4, 6, 8, 8])
        .with_scale_convs([1, 1, 1, 1])
}

/// The network on wgpu against ndarray (both sum in a different order; the GPU's scatter-adds
/// are atomic): largest |difference| over the largest |value| of each output and gradient.
#[cfg(feature = "wgpu")]
const NETWORK_WGPU_TOL: f32 = 1e-4;

/// The body volume network on wgpu against ndarray, same weights and inputs: every scale's
/// features and the gradients of the vertex features and of the first convolution's weight,
/// with `Im2col` in blocks of 64 outputs (the stacked indices' block slices are views) and
/// with `Pairs`; the views' scatter-mean onto the sites included.
#[cfg(feature = "wgpu")]
#[test]
fn body_volume_network_on_wgpu_matches_ndarray() {
    let Some(gpu) = common::wgpu_device() else {
        return;
    };
    let mut rng = Rng::new(83);
    let vertices = body_like_vertices(&mut rng, 800);
    let vb = VoxelBox::enclosing(&vertices, 0.025, 0.03).unwrap();
    let config = small_config();
    let net = config.init(&device().autodiff());
    let (n, c_v) = (3, config.vertex_channels);
    let features = normals(&mut rng, n * vertices.len() * c_v);
    let run = |dev: &Device, method: ConvMethod, block: Option<usize>| {
        let ad = dev.clone().autodiff();
        let mut geometry =
            BodyVolumeGeometry::build_with_method(&vertices, &vb, method, &ad).unwrap();
        if let Some(b) = block {
            let blocked = |rules: Vec<RulebookTensors>| {
                rules
                    .into_iter()
                    .map(|r| r.with_outputs_per_chunk(b))
                    .collect()
            };
            geometry.submanifold = blocked(geometry.submanifold);
            geometry.strided = blocked(geometry.strided);
        }
        let net = net.clone().fork(&ad);
        let x = tensor3(features.clone(), [n, vertices.len(), c_v], &ad).require_grad();
        let volume = net.forward(&geometry, x.clone()).unwrap();
        let mut outputs = Vec::new();
        let mut loss = Tensor::<1>::zeros([1], &ad);
        for scale in &volume.scales {
            let f = scale.features().clone();
            outputs.push(values(f.clone()));
            loss = loss + (f.clone() * f).sum();
        }
        let grads = loss.backward();
        outputs.push(values(x.grad(&grads).unwrap()));
        outputs.push(values(net.full[0].conv.weight.grad(&grads).unwrap()));
        (geometry.levels[0].num_sites(), outputs)
    };
    for (method, block) in [(ConvMethod::Im2col, Some(64)), (ConvMethod::Pairs, None)] {
        let (sites, reference) = run(&device(), method, block);
        assert!(
            sites > 2 * 64,
            "{sites} level-0 sites: too few for several blocks"
        );
        let (_, got) = run(&gpu, method, block);
        for (i, (r, g)) in reference.iter().zip(&got).enumerate() {
            assert_eq!(r.len(), g.len());
            let scale = r.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(scale > 0.0, "{method:?} output {i} is all zeros");
            let diff = r
                .iter()
                .zip(g)
                .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
            // Where they differ, for a failure that does not come back at once (docs/testing.md,
            // "One intermittent failure"): how many values, and the first few.
            let off: Vec<(usize, f32, f32)> = r
                .iter()
                .zip(g)
                .enumerate()
                .filter(|(_, (a, b))| (*a - *b).abs() > NETWORK_WGPU_TOL * scale)
                .map(|(k, (a, b))| (k, *a, *b))
                .collect();
            assert!(
                diff <= NETWORK_WGPU_TOL * scale,
                "{method:?} blocks {block:?}, output {i} (scales, then d vertex features, \
                 d weight): max |wgpu - ndarray| {diff} of max |value| {scale}; {} of {} \
                 values off, the first (index, ndarray, wgpu): {:?}",
                off.len(),
                r.len(),
                &off[..off.len().min(12)]
            );
        }
    }
}

#[test]
fn network_forward_and_backward_are_finite() {
    let ad = device().autodiff();
    let mut rng = Rng::new(71);
    let vertices = body_like_vertices(&mut rng, 400);
    let vb = VoxelBox::enclosing(&vertices, 0.025, 0.03).unwrap();
    let geometry = BodyVolumeGeometry::build(&vertices, &vb, &ad).unwrap();
    assert_eq!(geometry.levels.len(), NUM_SCALES + 1);
    for l in 1..=NUM_SCALES {
        let dims = geometry.levels[l].sites.dims();
        assert_eq!(dims, geometry.levels[l - 1].sites.dims().map(strided_dim));
        assert!(geometry.levels[l].num_sites() > 0);
    }
    let config = small_config();
    let net = config.init(&ad);
    let (n, c_v) = (2, config.vertex_channels);
    let vertex_features = tensor3(
        normals(&mut rng, n * vertices.len() * c_v),
        [n, vertices.len(), c_v],
        &ad,
    )
    .require_grad();

    // Scatter-mean: every site holds the mean of its vertices.
    let site_features = values(
        geometry
            .site_features(vertex_features.clone().detach())
            .unwrap(),
    );
    let vf = values(vertex_features.clone().detach());
    let p0 = geometry.levels[0].num_sites();
    let mut sums = vec![0.0f32; n * p0 * c_v];
    for v in 0..n {
        for (i, &s) in geometry.voxels.vertex_site.iter().enumerate() {
            for ch in 0..c_v {
                sums[(v * p0 + s as usize) * c_v + ch] += vf[(v * vertices.len() + i) * c_v + ch];
            }
        }
    }
    for v in 0..n {
        for s in 0..p0 {
            let count = geometry.voxels.site_vertex_count[s] as f32;
            for ch in 0..c_v {
                let i = (v * p0 + s) * c_v + ch;
                assert!((site_features[i] - sums[i] / count).abs() <= TRILINEAR_TOL);
            }
        }
    }

    let volume = net.forward(&geometry, vertex_features.clone()).unwrap();
    assert_eq!(volume.scales.len(), NUM_SCALES);
    for (s, scale) in volume.scales.iter().enumerate() {
        let p_s = geometry.scale(s).unwrap().num_sites();
        assert_eq!(
            scale.features().dims(),
            [n, p_s, config.scale_channels[s]],
            "scale {s}"
        );
        assert!(values(scale.features().clone())
            .iter()
            .all(|v| v.is_finite()));
    }

    let mut points = random_points(&mut rng, &vb, 200, 0.0);
    let far = [vb.max_m()[0] + 0.5, vb.min_m[1] - 0.5, 0.0];
    points.push(far);
    let corners: Vec<_> = geometry
        .corners(&points)
        .iter()
        .map(|c| TrilinearTensors::upload(c, &ad))
        .collect();
    let sampled = volume.sample(&corners).unwrap();
    let m = points.len();
    assert_eq!(sampled.dims(), [n, m, config.output_channels()]);
    let sampled_values = values(sampled.clone());
    assert!(sampled_values.iter().all(|v| v.is_finite()));
    let c_total = config.output_channels();
    for v in 0..n {
        let row = &sampled_values[(v * m + m - 1) * c_total..(v * m + m) * c_total];
        assert!(row.iter().all(|&x| x == 0.0), "point outside the box");
    }
    assert!(sampled_values.iter().any(|&x| x != 0.0));

    let grads = sampled.sum().backward();
    let g = values(vertex_features.grad(&grads).unwrap());
    assert!(g.iter().all(|x| x.is_finite()));
    assert!(g.iter().any(|&x| x != 0.0));
    let gw = values(net.scales[0].down.conv.weight.grad(&grads).unwrap());
    assert!(gw.iter().all(|x| x.is_finite()) && gw.iter().any(|&x| x != 0.0));
    let gw = values(net.full[0].conv.weight.grad(&grads).unwrap());
    assert!(gw.iter().all(|x| x.is_finite()) && gw.iter().any(|&x| x != 0.0));

    // No points: an empty sample, not an error.
    let none: Vec<_> = geometry
        .corners(&[])
        .iter()
        .map(|c| TrilinearTensors::upload(c, &ad))
        .collect();
    assert_eq!(volume.sample(&none).unwrap().dims(), [n, 0, c_total]);

    // Shape errors are typed errors, not panics.
    let no_views = tensor3(vec![], [0, vertices.len(), c_v], &ad);
    assert!(net.forward(&geometry, no_views).is_err());
    let wrong = tensor3(vec![0.0; n * 3 * c_v], [n, 3, c_v], &ad);
    assert!(net.forward(&geometry, wrong).is_err());
    assert!(volume.sample(&corners[..2]).is_err());
}

/// Host kernels against the tensor path: the same products summed in another order (blocks,
/// chunks); relative to the largest magnitude of each compared set.
const HOST_TOL: f32 = 1e-4;

/// The network's scale features and the gradients of `sum_s sum(features_s * r_s)` at the
/// vertex features and at every convolution weight, on `device` with the rulebooks run by
/// `method`; the weights come from `net_record` so every call has the same network.
fn network_outputs_and_gradients(
    device: &Device,
    method: ConvMethod,
    vertices: &[[f32; 3]],
    vb: &VoxelBox,
    config: &BodyVolumeNetConfig,
    net_record: &nia_model::body_volume::BodyVolumeNet,
    vertex_values: &[f32],
    views: usize,
    seed: u64,
) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    use burn::module::Module;
    let geometry = BodyVolumeGeometry::build_with_method(vertices, vb, method, device).unwrap();
    for rules in geometry.submanifold.iter().chain(&geometry.strided) {
        assert_eq!(rules.method(), method);
    }
    let net = config
        .init(device)
        .load_record(net_record.clone().into_record());
    let x = tensor3(
        vertex_values.to_vec(),
        [views, vertices.len(), config.vertex_channels],
        device,
    )
    .require_grad();
    let volume = net.forward(&geometry, x.clone()).unwrap();
    let mut rng = Rng::new(seed);
    let mut loss = None;
    let mut outputs = Vec::new();
    for scale in &volume.scales {
        let dims = scale.features().dims();
        let r = tensor3(normals(&mut rng, dims.iter().product()), dims, device);
        outputs.push(values(scale.features().clone()));
        let term = (scale.features().clone() * r).sum();
        loss = Some(match loss {
            None => term,
            Some(l) => l + term,
        });
    }
    let grads = loss.unwrap().backward();
    let mut gradients = vec![values(x.grad(&grads).unwrap())];
    let blocks = net.full.iter().chain(
        net.scales
            .iter()
            .flat_map(|s| std::iter::once(&s.down).chain(&s.convs)),
    );
    for block in blocks {
        gradients.push(values(block.conv.weight.grad(&grads).unwrap()));
    }
    (outputs, gradients)
}

#[test]
fn host_kernels_match_the_tensor_path_through_the_network() {
    let mut rng = Rng::new(81);
    let vertices = body_like_vertices(&mut rng, 1500);
    let vb = VoxelBox::enclosing(&vertices, 0.02, 0.03).unwrap();
    // Widths from 8 to 32, so the blocks hold from 216 to 864 values per row.
    let config = BodyVolumeNetConfig::new()
        .with_vertex_channels(8)
        .with_full_channels(8)
        .with_full_convs(1)
        .with_scale_channels([8, 16, 32, 32])
        .with_scale_convs([1, 1, 2, 1]);
    let views = 3;
    let vertex_values = normals(&mut rng, views * vertices.len() * config.vertex_channels);
    let record = config.init(&Device::flex());
    let run = |device: &Device, method: ConvMethod| {
        network_outputs_and_gradients(
            device,
            method,
            &vertices,
            &vb,
            &config,
            &record,
            &vertex_values,
            views,
            5,
        )
    };
    let ad = Device::flex().autodiff();
    let (out_ref, grad_ref) = run(&ad, ConvMethod::Im2col);
    let (out_host, grad_host) = run(&ad, ConvMethod::Host);
    for (s, (a, b)) in out_host.iter().zip(&out_ref).enumerate() {
        let gap = relative_gap(a, b);
        assert!(gap <= HOST_TOL, "scale {s} features: relative gap {gap}");
    }
    assert_eq!(grad_host.len(), grad_ref.len());
    for (i, (a, b)) in grad_host.iter().zip(&grad_ref).enumerate() {
        assert!(a.iter().all(|v| v.is_finite()));
        assert!(b.iter().any(|v| *v != 0.0), "gradient {i} is all zero");
        let gap = relative_gap(a, b);
        // 0: the vertex features; then the convolution weights in network order.
        assert!(gap <= HOST_TOL, "gradient {i}: relative gap {gap}");
    }

    // The same numbers whatever the number of threads (fixed blocks and chunks, the chunks'
    // sums added in order), and under gradient checkpointing.
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let (out, grad) = pool.install(|| run(&ad, ConvMethod::Host));
        assert_eq!(out, out_host, "{threads} threads: features");
        assert_eq!(grad, grad_host, "{threads} threads: gradients");
    }
    let checkpointed = Device::flex().autodiff().gradient_checkpointing();
    let (out, grad) = run(&checkpointed, ConvMethod::Host);
    assert_eq!(out, out_host, "checkpointing: features");
    assert_eq!(grad, grad_host, "checkpointing: gradients");

    // Inference (flex without autodiff) runs the same forward.
    let geometry =
        BodyVolumeGeometry::build_with_method(&vertices, &vb, ConvMethod::Host, &Device::flex())
            .unwrap();
    let x = tensor3(
        vertex_values.clone(),
        [views, vertices.len(), config.vertex_channels],
        &Device::flex(),
    );
    let volume = record.forward(&geometry, x).unwrap();
    for (scale, expected) in volume.scales.iter().zip(&out_host) {
        assert_eq!(&values(scale.features().clone()), expected);
    }
    // On ndarray `Host` runs as its tensor equivalent.
    #[allow(deprecated)]
    let nd = Device::ndarray();
    let rules = Rulebook::submanifold(&geometry.levels[0].sites);
    assert_eq!(
        RulebookTensors::with_method(&rules, ConvMethod::Host, &nd).method(),
        ConvMethod::Im2col
    );
    assert_eq!(
        RulebookTensors::new(&rules, &Device::flex()).method(),
        ConvMethod::Host
    );
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
