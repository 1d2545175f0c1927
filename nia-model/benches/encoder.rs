//! Image-encoder timings at the paper's size (3 views of 512x512, ResNet-18 trunk to `layer3`):
//! every layer of the trunk, one pyramid reduction (tensor form, then its channels-last
//! layout), and the host forms (the folded channels-last trunk, the reduction that writes the
//! rows directly), on flex and ndarray.
//!
//! `CARGO_TARGET_DIR=$HOME/.cache/nia-rs/target cargo bench --all-features -p nia-model --bench encoder`
//! (`-- host`: the host path alone, five times, for profiling; `-- train`: the tensor path's
//! forward and backward on flex's autodiff device, trunk and reductions apart, as in training;
//! `-- levels`: one reduction's parts per pyramid level under autodiff, the channel product and
//! the upsampling apart, then the rows' layout; `-- conv`: each kind of trunk convolution under
//! autodiff, flex's `conv2d` against the same convolution as an im2col matrix product, with the
//! largest differences of the outputs and gradients. Run the autodiff modes under the training
//! binaries' heap policy, `GLIBC_TUNABLES=glibc.malloc.mmap_max=0:
//! glibc.malloc.trim_threshold=4611686018427387904`, or page faults dominate)
//! Plain `main` (no harness): prints milliseconds; speed is never asserted in a test.

use std::time::Instant;

use burn::prelude::*;
use burn::tensor::activation::relu;
use nia_model::encoder::bilinear::ViewRows;
use nia_model::encoder::host::HostTrunk;
use nia_model::encoder::pyramid_host::{reduce_to_rows, HostPyramid};
use nia_model::encoder::{reduce_level, ImageEncoder, ImageEncoderConfig, ENCODER_CHANNELS};

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
    if std::env::args().any(|a| a == "levels") {
        levels();
        return;
    }
    if std::env::args().any(|a| a == "conv") {
        conv();
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

/// Milliseconds since `t`.
fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// One pyramid reduction's parts on flex's autodiff device, per level of a detached pyramid:
/// the channel product `W_l^T f_l` and the upsampling of its result (two dense products), each
/// forward and forward + backward; then the channels-last layout of a `[3, D, 256, 256]` map
/// ([`ViewRows`]), whose time includes drawing the map.
fn levels() {
    let device = Device::flex().autodiff();
    let (encoder, images, weight) = setup(&device);
    let weight = weight.require_grad();
    let levels = encoder
        .forward_pyramid(images)
        .levels
        .map(|f| f.detach().require_grad());
    let [_, _, h2, w2] = levels[0].dims();
    for rep in 0..3 {
        let mut line = format!("levels rep {rep}:");
        let mut offset = 0;
        for f in &levels {
            let [_, c, h, _] = f.dims();
            let t = Instant::now();
            let reduced = reduce_level(&weight, offset, f);
            offset += c;
            sync(reduced.clone());
            let product = ms(t);
            drop(reduced.clone().sum().backward());
            let product_back = ms(t);
            let reduced = reduced.detach().require_grad();
            let t = Instant::now();
            let up = nia_model::encoder::upsample_bilinear(reduced, [h2, w2]);
            sync(up.clone());
            let upsample = ms(t);
            drop(up.sum().backward());
            let upsample_back = ms(t);
            line += &format!(
                " level {c}x{h}^2: product {product:.0}/{product_back:.0}, \
                 upsampling {upsample:.0}/{upsample_back:.0};"
            );
        }
        let t = Instant::now();
        let map = Tensor::<4>::random(
            [VIEWS, D, h2, w2],
            burn::tensor::Distribution::Uniform(0.0, 1.0),
            &device,
        )
        .require_grad();
        let rows = ViewRows::new(map).expect("rows");
        sync(rows.rows());
        let layout = ms(t);
        drop(rows.rows().sum().backward());
        let layout_back = ms(t);
        println!("{line} rows {layout:.0}/{layout_back:.0} (ms, forward/forward + backward)");
    }
}

/// `x` convolved with `weight` (`[C_out, C_in, k, k]`, stride `stride`, zero padding `pad`) as
/// one matrix product over the k^2 shifted (strided) slices of the padded input, concatenated
/// along the channels (im2col in tensor operations, differentiable on every backend).
///
/// # Shapes
/// - x: `[N, C_in, H, W]` -> `[N, C_out, H_out, W_out]`
fn im2col_conv(x: Tensor<4>, weight: Tensor<4>, stride: usize, pad: usize) -> Tensor<4> {
    use burn::tensor::ops::PadMode;
    use burn::tensor::s;
    let [n, c, h, w] = x.dims();
    let [c_out, _, k, _] = weight.dims();
    let h_out = (h + 2 * pad - k) / stride + 1;
    let w_out = (w + 2 * pad - k) / stride + 1;
    let padded = x.pad((pad, pad, pad, pad), PadMode::Constant(0.0));
    let step = stride as isize;
    let mut columns = Vec::with_capacity(k * k);
    for dy in 0..k {
        for dx in 0..k {
            columns.push(padded.clone().slice(s![
                ..,
                ..,
                dy..dy + stride * (h_out - 1) + 1;step,
                dx..dx + stride * (w_out - 1) + 1;step
            ]));
        }
    }
    // Column channel (dy k + dx) C_in + c meets weight[o, c, dy, dx].
    let columns = Tensor::cat(columns, 1).reshape([n, k * k * c, h_out * w_out]);
    let matrix = weight.permute([0, 2, 3, 1]).reshape([1, c_out, k * k * c]);
    matrix.matmul(columns).reshape([n, c_out, h_out, w_out])
}

/// The trunk's kinds of convolution at the paper's size on flex's autodiff device: flex's
/// `conv2d` and [`im2col_conv`], each forward and forward + backward (a sum as the loss), and
/// the largest differences of the outputs and gradients (the weight's relative to its largest).
fn conv() {
    use burn::nn::conv::Conv2dConfig;
    use burn::nn::PaddingConfig2d;
    let device = Device::flex().autodiff();
    // (name, C_in, C_out, kernel, stride, input size)
    let kinds = [
        ("stem 7x7/2", 3, 64, 7, 2, SIZE),
        ("layer1 3x3", 64, 64, 3, 1, SIZE / 4),
        ("layer2 first 3x3/2", 64, 128, 3, 2, SIZE / 4),
        ("layer2 3x3", 128, 128, 3, 1, SIZE / 8),
        ("layer3 3x3", 256, 256, 3, 1, SIZE / 16),
    ];
    for (name, c_in, c_out, k, stride, size) in kinds {
        let pad = k / 2;
        let conv = Conv2dConfig::new([c_in, c_out], [k, k])
            .with_stride([stride, stride])
            .with_padding(PaddingConfig2d::Explicit(pad, pad, pad, pad))
            .with_bias(false)
            .init(&device);
        let x = Tensor::<4>::random(
            [VIEWS, c_in, size, size],
            burn::tensor::Distribution::Uniform(0.0, 1.0),
            &device,
        )
        .require_grad();
        for rep in 0..3 {
            let t = Instant::now();
            let y = conv.forward(x.clone());
            sync(y.clone());
            let flex = ms(t);
            let grads = y.clone().sum().backward();
            let flex_back = ms(t);
            let t = Instant::now();
            let y2 = im2col_conv(x.clone(), conv.weight.val(), stride, pad);
            sync(y2.clone());
            let im2col = ms(t);
            let grads2 = y2.clone().sum().backward();
            let im2col_back = ms(t);
            let max_diff = |a: Tensor<4>, b: Tensor<4>| (a - b).abs().max().into_scalar::<f32>();
            let dy = max_diff(y.inner(), y2.inner());
            let dx = max_diff(
                x.grad(&grads).expect("x grad"),
                x.grad(&grads2).expect("x grad"),
            );
            // The weight gradients sum 3 x H x W terms each: their difference relative to
            // their largest magnitude.
            let grad_w = conv.weight.val().grad(&grads).expect("weight grad");
            let scale = grad_w.clone().abs().max().into_scalar::<f32>();
            let dw = max_diff(
                grad_w,
                conv.weight.val().grad(&grads2).expect("weight grad"),
            ) / scale;
            println!(
                "conv {name} rep {rep}: conv2d {flex:.0}/{flex_back:.0} ms, im2col product \
                 {im2col:.0}/{im2col_back:.0} ms (forward/forward + backward); max |diff| \
                 output {dy:.1e}, x grad {dx:.1e}, weight grad (relative) {dw:.1e}"
            );
        }
    }
}
