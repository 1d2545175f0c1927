//! Body-volume timings at the paper's size (6,890 vertices of the procedural SMPL-compatible
//! body, 5 mm voxels, 3 views, 65,536 sample points): the geometry build, every rulebook's
//! convolution with each method (flex: also the host kernels), the network forward, the trilinear corners and sampling,
//! and autodiff forwards + backwards (flex: the host kernels and Im2col), on flex and ndarray.
//!
//! `CARGO_TARGET_DIR=$HOME/.cache/nia-rs/target cargo bench --all-features -p nia-model --bench body_volume`
//! Plain `main` (no harness): prints milliseconds; speed is never asserted in a test.

use std::time::Instant;

use burn::prelude::*;
use nia_data::body::{ProceduralBody, ProceduralSpec, SmplParams};
use nia_data::geometry::sparse::VoxelBox;
use nia_data::rng::Rng;
use nia_model::body_volume::{
    BodyVolumeGeometry, BodyVolumeNetConfig, ConvMethod, RulebookTensors, SparseConv3dConfig,
    TrilinearTensors,
};

const VIEWS: usize = 3;
const POINTS: usize = 65_536;

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

fn normals(rng: &mut Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.normal()).collect()
}

fn tensor3(values: Vec<f32>, dims: [usize; 3], device: &Device) -> Tensor<3> {
    Tensor::from_data(TensorData::new(values, dims), device)
}

/// Reads a scalar back, which waits for the device.
fn sync(t: Tensor<1>) -> f32 {
    t.into_scalar::<f32>()
}

#[allow(deprecated)]
fn main() {
    let body = ProceduralBody::generate(&ProceduralSpec {
        target_vertices: 6890,
        ..ProceduralSpec::default()
    })
    .expect("procedural body");
    let vertices: Vec<[f32; 3]> = body
        .lbs(&SmplParams::default())
        .vertices
        .iter()
        .map(|v| v.to_array())
        .collect();
    let mut rng = Rng::new(81);
    let vb = VoxelBox::enclosing(&vertices, 0.025, 0.005).expect("voxel box");
    let config = BodyVolumeNetConfig::new();
    let max = vb.max_m();
    let points: Vec<[f32; 3]> = (0..POINTS)
        .map(|_| std::array::from_fn(|a| rng.range(vb.min_m[a], max[a])))
        .collect();
    for (name, dev) in [("flex", Device::flex()), ("ndarray", Device::ndarray())] {
        let t = Instant::now();
        let geometry = BodyVolumeGeometry::build(&vertices, &vb, &dev).expect("geometry");
        let build = ms(t);
        let sites: Vec<usize> = geometry.levels.iter().map(|l| l.num_sites()).collect();
        println!(
            "{name}: V {} N {VIEWS} box {:?} sites per level {sites:?}, geometry build {build:.1} ms",
            vertices.len(),
            vb.dims,
        );
        // Per rulebook: one convolution with that stage's channels, both methods.
        let channels = [config.full_channels, 32, 64, 128, 128];
        let rules = geometry
            .submanifold_rules
            .iter()
            .enumerate()
            .map(|(l, r)| (format!("subm level {l}"), r, channels[l], channels[l]))
            .chain(geometry.strided_rules.iter().enumerate().map(|(l, r)| {
                (
                    format!("strided {l}->{}", l + 1),
                    r,
                    channels[l],
                    channels[l + 1],
                )
            }));
        for (label, rulebook, c_in, c_out) in rules {
            let x = tensor3(
                normals(&mut rng, VIEWS * rulebook.n_in * c_in),
                [VIEWS, rulebook.n_in, c_in],
                &dev,
            );
            let conv = SparseConv3dConfig::new(c_in, c_out).init(&dev);
            let mut line = format!(
                "  {label} ({} -> {}, fill {:.2}):",
                rulebook.n_in,
                rulebook.n_out,
                rulebook.fill_ratio()
            );
            let methods: &[ConvMethod] = if name == "flex" {
                &[ConvMethod::Im2col, ConvMethod::Pairs, ConvMethod::Host]
            } else {
                &[ConvMethod::Im2col, ConvMethod::Pairs]
            };
            for &method in methods {
                let tensors = RulebookTensors::with_method(rulebook, method, &dev);
                sync(conv.forward(x.clone(), &tensors).expect("conv").sum());
                let t = Instant::now();
                sync(conv.forward(x.clone(), &tensors).expect("conv").sum());
                line += &format!(" {method:?} {:.1} ms", ms(t));
            }
            println!("{line}");
        }
        let net = config.init(&dev);
        let features = tensor3(
            normals(&mut rng, VIEWS * vertices.len() * config.vertex_channels),
            [VIEWS, vertices.len(), config.vertex_channels],
            &dev,
        );
        let mut forward = Vec::new();
        let mut volume = None;
        for _ in 0..3 {
            let t = Instant::now();
            let v = net.forward(&geometry, features.clone()).expect("forward");
            sync(v.scales[3].features().clone().sum());
            forward.push(format!("{:.0}", ms(t)));
            volume = Some(v);
        }
        let volume = volume.expect("three forwards ran");
        let im2col =
            BodyVolumeGeometry::build_with_method(&vertices, &vb, ConvMethod::Im2col, &dev)
                .expect("geometry");
        let t = Instant::now();
        sync(
            net.forward(&im2col, features.clone())
                .expect("forward")
                .scales[3]
                .features()
                .clone()
                .sum(),
        );
        println!("  network forward, Im2col everywhere: {:.0} ms", ms(t));
        let t = Instant::now();
        let corners = geometry.corners(&points);
        let corner_time = ms(t);
        let tensors: Vec<_> = corners
            .iter()
            .map(|c| TrilinearTensors::upload(c, &dev))
            .collect();
        let t = Instant::now();
        sync(volume.sample(&tensors).expect("sample").sum());
        let sample_time = ms(t);
        println!(
            "  network forward (Auto) {forward:?} ms, corners of {} points (4 scales) {corner_time:.1} ms, \
             sample {sample_time:.1} ms",
            points.len(),
        );

        // One training step's worth: forward + sample + backward on the autodiff device, with
        // the default method (flex: the host kernels) and with Im2col everywhere.
        let ad = dev.clone().autodiff();
        let net = config.init(&ad);
        let features = tensor3(
            normals(&mut rng, VIEWS * vertices.len() * config.vertex_channels),
            [VIEWS, vertices.len(), config.vertex_channels],
            &ad,
        )
        .require_grad();
        let tensors: Vec<_> = corners
            .iter()
            .map(|c| TrilinearTensors::upload(c, &ad))
            .collect();
        for method in [ConvMethod::Auto, ConvMethod::Im2col] {
            let geometry = BodyVolumeGeometry::build_with_method(&vertices, &vb, method, &ad)
                .expect("geometry");
            let mut line = format!("  autodiff, {:?}:", geometry.submanifold[0].method());
            for _ in 0..2 {
                let t = Instant::now();
                let volume = net.forward(&geometry, features.clone()).expect("forward");
                let loss = volume.sample(&tensors).expect("sample").sum();
                let forward_ad = ms(t);
                let t = Instant::now();
                let grads = loss.backward();
                sync(features.grad(&grads).expect("feature gradient").sum());
                line += &format!(
                    " forward + sample {forward_ad:.0} ms, backward {:.0} ms;",
                    ms(t)
                );
            }
            println!("{line}");
        }
    }
}
