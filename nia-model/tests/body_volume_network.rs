//! The body volume end to end: voxelisation, the network's forward and backward, on wgpu
//! against ndarray, and the host kernels against the tensor path.

mod common;

use burn::prelude::*;
use common::relative_gap;
use common::volume::{normals, random_points, TRILINEAR_TOL};
use common::{device, tensor, values};
use nia_data::geometry::sparse::{strided_dim, voxelize, Rulebook, VoxelBox};
use nia_data::rng::Rng;
use nia_model::body_volume::{
    BodyVolumeGeometry, BodyVolumeNetConfig, ConvMethod, RulebookTensors, TrilinearTensors,
    NUM_SCALES,
};

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
        let x = tensor(features.clone(), [n, vertices.len(), c_v], &ad).require_grad();
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
    let vertex_features = tensor(
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
    let no_views = tensor(vec![], [0, vertices.len(), c_v], &ad);
    assert!(net.forward(&geometry, no_views).is_err());
    let wrong = tensor(vec![0.0; n * 3 * c_v], [n, 3, c_v], &ad);
    assert!(net.forward(&geometry, wrong).is_err());
    assert!(volume.sample(&corners[..2]).is_err());
}

/// Host kernels against the tensor path: the same products summed in another order (blocks,
/// chunks); relative to the largest magnitude of each compared set.
const HOST_TOL: f32 = 1e-4;

/// A network and its inputs, run by [`outputs_and_gradients`] on several devices and methods.
struct NetworkCase<'a> {
    /// `[V]` body vertices, metres.
    vertices: &'a [[f32; 3]],
    vb: &'a VoxelBox,
    config: &'a BodyVolumeNetConfig,
    /// The weights every run loads, so every run has the same network.
    net_record: &'a nia_model::body_volume::BodyVolumeNet,
    /// `[N, V, C_v]` vertex features.
    vertex_values: &'a [f32],
    views: usize,
    /// Seed of the loss's random weights `r_s`.
    seed: u64,
}

/// The network's scale features and the gradients of `sum_s sum(features_s * r_s)` at the
/// vertex features and at every convolution weight, for `case` on `device` with the rulebooks
/// run by `method`.
fn outputs_and_gradients(
    case: &NetworkCase<'_>,
    device: &Device,
    method: ConvMethod,
) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    use burn::module::Module;
    let NetworkCase {
        vertices,
        vb,
        config,
        net_record,
        vertex_values,
        views,
        seed,
    } = *case;
    let geometry = BodyVolumeGeometry::build_with_method(vertices, vb, method, device).unwrap();
    for rules in geometry.submanifold.iter().chain(&geometry.strided) {
        assert_eq!(rules.method(), method);
    }
    let net = config
        .init(device)
        .load_record(net_record.clone().into_record());
    let x = tensor(
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
        let r = tensor(normals(&mut rng, dims.iter().product()), dims, device);
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
    let case = NetworkCase {
        vertices: &vertices,
        vb: &vb,
        config: &config,
        net_record: &record,
        vertex_values: &vertex_values,
        views,
        seed: 5,
    };
    let run = |device: &Device, method: ConvMethod| outputs_and_gradients(&case, device, method);
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
    let x = tensor(
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
