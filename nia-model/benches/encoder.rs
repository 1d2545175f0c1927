//! Image-encoder timings at the paper's size (3 views of 512x512, ResNet-18 trunk to `layer3`):
//! every layer of the trunk, one pyramid reduction (tensor form, then its channels-last
//! layout), and the host forms (the folded channels-last trunk, the reduction that writes the
//! rows directly), on flex and ndarray.
//!
//! `CARGO_TARGET_DIR=$HOME/.cache/nia-rs/target cargo bench --all-features -p nia-model --bench encoder`
//! (`-- host`: the host path alone, five times, for profiling; `-- train`: the tensor path's
//! forward and backward on flex's autodiff device, trunk and reductions apart, as in training;
//! run it under the training binaries' heap policy, `GLIBC_TUNABLES=glibc.malloc.mmap_max=0:
//! glibc.malloc.trim_threshold=4611686018427387904`, or page faults dominate)
//! Plain `main` (no harness): prints milliseconds; speed is never asserted in a test.

use std::time::Instant;

use burn::prelude::*;
use burn::tensor::activation::relu;
use nia_model::encoder::bilinear::ViewRows;
use nia_model::encoder::host::HostTrunk;
use nia_model::encoder::pyramid_host::{reduce_to_rows, HostPyramid};
use nia_model::encoder::{ImageEncoder, ImageEncoderConfig, ENCODER_CHANNELS};

const VIEWS: usize = 3;
const SIZE: usize = 512;
const D: usize = 128;

/// Reads a scalar back, which waits for the device.
fn sync<const R: usize>(t: Tensor<R>) -> f32 {
    t.sum().into_scalar::<f32>()
}

/// A paper-width encoder, random source images and a random reduction weight on `device`.
fn setup(device: &Device) -> (ImageEncoder, Tensor<4>, Tensor<2>) {
    let encoder = ImageEncoderConfig::new().init(device);
    let images = Tensor::<4>::random(
        [VIEWS, 3, SIZE, SIZE],
        burn::tensor::Distribution::Uniform(0.0, 1.0),
        device,
    );
    let weight = Tensor::<2>::random(
        [ENCODER_CHANNELS, D],
        burn::tensor::Distribution::Normal(0.0, 0.05),
        device,
    );
    (encoder, images, weight)
}

#[allow(deprecated)] // burn-ndarray, timed beside flex
fn main() {
    // `-- host`: only the host trunk and reduction, repeated (for `perf record`).
    if std::env::args().any(|a| a == "host") {
        let device = Device::flex();
        let (encoder, images, weight) = setup(&device);
        for rep in 0..5 {
            let t = Instant::now();
            let trunk = HostTrunk::new(&encoder).expect("host trunk");
            let pyramid = trunk.forward(images.clone()).expect("host trunk forward");
            let host_trunk = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            drop(reduce_to_rows(&pyramid, weight.clone()).expect("host reduction"));
            let host_reduce = t.elapsed().as_secs_f64() * 1e3;
            println!("host rep {rep}: trunk {host_trunk:.0} ms, reduction {host_reduce:.0} ms");
        }
        return;
    }
    if std::env::args().any(|a| a == "train") {
        train();
        return;
    }
    for (name, device) in [("flex", Device::flex()), ("ndarray", Device::ndarray())] {
        let (encoder, images, weight) = setup(&device);
        sync(encoder.forward_pyramid(images.clone()).levels[3].clone());
        for rep in 0..2 {
            let total = Instant::now();
            let t = Instant::now();
            let x = relu(encoder.bn1.forward(encoder.conv1.forward(images.clone())));
            sync(x.clone());
            let stem = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            let mut x = encoder.maxpool.forward(x);
            sync(x.clone());
            let pool = t.elapsed().as_secs_f64() * 1e3;
            let mut layers = Vec::new();
            for layer in [&encoder.layer1, &encoder.layer2, &encoder.layer3] {
                let t = Instant::now();
                for block in layer {
                    x = block.forward(x);
                }
                sync(x.clone());
                layers.push(t.elapsed().as_secs_f64() * 1e3);
            }
            let t = Instant::now();
            let pyramid = encoder.forward_pyramid(images.clone());
            sync(pyramid.levels[3].clone());
            let whole = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            let reduced = pyramid.reduce(weight.clone()).expect("reduce");
            sync(reduced.clone());
            let reduce = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            let rows = ViewRows::new(reduced).expect("rows");
            drop(rows);
            let layout = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            let trunk = HostTrunk::new(&encoder).expect("host trunk");
            let host_pyramid = trunk.forward(images.clone()).expect("host trunk forward");
            let host_trunk = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            let host = reduce_to_rows(&host_pyramid, weight.clone()).expect("host reduction");
            drop(host);
            let host_reduce = t.elapsed().as_secs_f64() * 1e3;
            drop(HostPyramid::from_tensors(&pyramid).expect("read back"));
            println!(
                "{name} rep {rep}: stem {stem:.0} ms, maxpool {pool:.0}, layer1 {:.0}, layer2 {:.0}, \
                 layer3 {:.0}; whole trunk {whole:.0}; one reduction {reduce:.0}; rows {layout:.0}; \
                 host trunk {host_trunk:.0}, host reduction {host_reduce:.0}; all {:.0} ms",
                layers[0],
                layers[1],
                layers[2],
                total.elapsed().as_secs_f64() * 1e3
            );
        }
    }
}

/// The training step's share of the encoder: the trunk alone, then the trunk with the two
/// reductions a scene takes (pixel and vertex features, both width `D`) and their rows, each
/// forward and backward (a sum of every output as the loss) on flex's autodiff device.
fn train() {
    let device = Device::flex().autodiff();
    let (encoder, images, weight) = setup(&device);
    let weight = weight.require_grad();
    for rep in 0..3 {
        let t = Instant::now();
        let pyramid = encoder.forward_pyramid(images.clone());
        let loss = pyramid
            .levels
            .iter()
            .map(|f| f.clone().sum())
            .reduce(|a, b| a + b)
            .expect("four levels");
        let forward = t.elapsed().as_secs_f64() * 1e3;
        drop(loss.backward());
        let trunk = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let pyramid = encoder.forward_pyramid(images.clone());
        let mut loss: Option<Tensor<1>> = None;
        for _ in 0..2 {
            let reduced = pyramid.reduce(weight.clone()).expect("reduce");
            let rows = ViewRows::new(reduced).expect("rows");
            let part = rows.rows().sum();
            loss = Some(match loss {
                None => part,
                Some(l) => l + part,
            });
        }
        let loss = loss.expect("two reductions");
        sync(loss.clone());
        let with_forward = t.elapsed().as_secs_f64() * 1e3;
        drop(loss.backward());
        let with = t.elapsed().as_secs_f64() * 1e3;
        // One reduction alone, on a detached pyramid, forward and backward.
        let levels = encoder
            .forward_pyramid(images.clone())
            .levels
            .map(|f| f.detach().require_grad());
        let pyramid = nia_model::encoder::FeaturePyramid { levels };
        let t = Instant::now();
        let reduced = pyramid.reduce(weight.clone()).expect("reduce");
        sync(reduced.clone());
        let red_f = t.elapsed().as_secs_f64() * 1e3;
        drop(reduced.sum().backward());
        let red_fb = t.elapsed().as_secs_f64() * 1e3;
        println!(
            "train rep {rep}: trunk forward {forward:.0} ms, trunk forward + backward {trunk:.0}; \
             with two reductions and rows: forward {with_forward:.0}, forward + backward {with:.0}; \
             one reduction alone: forward {red_f:.0}, forward + backward {red_fb:.0} ms"
        );
    }
}
