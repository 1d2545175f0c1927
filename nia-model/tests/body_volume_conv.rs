//! The body volume's sparse convolution: rulebooks against brute force, the convolution
//! against burn's dense `conv3d`, the site normalisation, and gradients against finite
//! differences.

mod common;

use std::collections::BTreeSet;

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::module::conv3d;
use burn::tensor::ops::ConvOptions;
use common::volume::{densify, normals, random_sites};
use common::{device, tensor, values};
use nia_data::geometry::sparse::{kernel_offset, strided_dim, Rulebook, SiteIndex, KERNEL_VOLUME};
use nia_data::rng::Rng;
use nia_model::body_volume::{
    ConvMethod, RulebookTensors, SiteNormConfig, SparseConv3d, SparseConv3dConfig,
};

/// Sparse vs dense convolution: both sum at most 27 * C_in products of O(1) f32 values in a
/// different order; 1e-4 absolute leaves ~50x room over the observed rounding.
const CONV_TOL: f32 = 1e-4;
/// Finite-difference step on weights and features.
const FD_STEP: f64 = 1e-2;
/// The loss is quadratic in each entry, so a central difference is exact up to rounding: the
/// f32 outputs (~1e-7 relative) summed into an O(10) loss, divided by 2 * FD_STEP, give
/// ~1e-4; allow 2e-3 relative to max(1, |grad|).
const FD_TOL: f64 = 2e-3;

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
            tensor(features.clone(), [n, sites.len(), c_in], &dev),
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
    let y = values(norm.forward(tensor(x, [n, p, c], &dev)).unwrap());
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
    assert!(norm.forward(tensor(vec![0.0; 6], [1, 2, 3], &dev)).is_err());
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
        weight: Param::from_tensor(tensor(weight, dims, device)),
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
            let x = tensor(features.clone(), f_dims, &ad).require_grad();
            let out = conv.forward(x.clone(), &rules_ad).unwrap();
            let r_t = tensor(r.clone(), [n, rules.n_out, c_out], &ad);
            let grads = (out.clone() * out * r_t).sum().backward();
            let grad_w = values(conv.weight.grad(&grads).unwrap());
            let grad_x = values(x.grad(&grads).unwrap());

            // Central differences on the plain device.
            let rules_plain = RulebookTensors::with_method(&rules, method, &plain);
            let loss = |w: &[f32], f: &[f32]| {
                let conv = conv_with(w.to_vec(), w_dims, &plain);
                let out = conv
                    .forward(tensor(f.to_vec(), f_dims, &plain), &rules_plain)
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
