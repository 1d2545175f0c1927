//! The field's MLP stacks at a render chunk's size on flex: `Linear::forward` + ReLU layer by
//! layer (the tensor path) against [`HostMlp`] (fused row tasks), with the largest difference.
//!
//! `CARGO_TARGET_DIR=$HOME/.cache/nia-rs/target cargo bench --all-features -p nia-model --bench host_mlp`
//! Plain `main` (no harness): prints milliseconds (median of 7); speed is never asserted.

use std::time::Instant;

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;
use nia_model::kernels::host_mlp::{FirstLayerAddend, HostMlp};
use nia_model::kernels::readback::host_values;

const REPS: usize = 7;

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    xs[xs.len() / 2]
}

/// Layers of the given widths, freshly initialised on `device`.
fn stack(widths: &[usize], device: &Device) -> Vec<Linear> {
    widths
        .windows(2)
        .map(|w| LinearConfig::new(w[0], w[1]).init(device))
        .collect()
}

fn tensor_path(layers: &[Linear], x: Tensor<2>, addend: Option<&Tensor<2>>) -> Tensor<2> {
    let last = layers.len() - 1;
    let mut x = x;
    for (i, layer) in layers.iter().enumerate() {
        x = layer.forward(x);
        if i == 0 {
            if let Some(a) = addend {
                let [rows, w] = x.dims();
                let period = a.dims()[0];
                x = (x.reshape([rows / period, period, w]) + a.clone().unsqueeze_dim::<3>(0))
                    .reshape([rows, w]);
            }
        }
        if i < last {
            x = relu(x);
        }
    }
    x
}

fn case(name: &str, widths: &[usize], rows: usize, period: Option<usize>, device: &Device) {
    let layers = stack(widths, device);
    let x = Tensor::<2>::random(
        [rows, widths[0]],
        burn::tensor::Distribution::Uniform(-1.0, 1.0),
        device,
    );
    let addend = period.map(|p| {
        Tensor::<2>::random(
            [p, widths[1]],
            burn::tensor::Distribution::Uniform(-0.5, 0.5),
            device,
        )
    });
    let x_host = host_values(x.clone()).expect("x");
    let addend_host = addend.clone().map(|a| host_values(a).expect("addend"));
    let mlp = HostMlp::read(name, &layers).expect("host mlp");
    let mut tensor_s = Vec::new();
    let mut host_s = Vec::new();
    let mut worst = 0.0f32;
    for _ in 0..REPS {
        let t = Instant::now();
        let y = host_values(tensor_path(&layers, x.clone(), addend.as_ref())).expect("y");
        tensor_s.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let h = mlp
            .forward(
                name,
                &x_host,
                rows,
                addend_host.as_ref().map(|v| FirstLayerAddend {
                    values: v,
                    period: period.unwrap(),
                }),
                None,
            )
            .expect("host forward");
        host_s.push(t.elapsed().as_secs_f64());
        worst = y
            .iter()
            .zip(&h.output)
            .fold(worst, |w, (a, b)| w.max((a - b).abs()));
    }
    let (ts, hs) = (median(tensor_s), median(host_s));
    println!(
        "{name:<28} rows {rows:>6}: tensor {:>8.2} ms, host {:>8.2} ms, host/tensor {:.2}, max |diff| {worst:.2e}",
        ts * 1e3,
        hs * 1e3,
        hs / ts
    );
}

fn main() {
    let device = Device::flex();
    let threads = rayon::current_num_threads();
    println!("flex, {threads} threads");
    for points in [2_000usize, 8_000] {
        case(
            "F_sigma 128-256-256-256-1",
            &[128, 256, 256, 256, 1],
            points,
            None,
            &device,
        );
        case(
            "F_c0 155-256-256-256-4",
            &[155, 256, 256, 256, 4],
            points,
            None,
            &device,
        );
        let mut blender = vec![134usize];
        blender.extend([128; 7]);
        blender.push(1);
        case(
            "F_B 134-128x7-1 (4 tokens)",
            &blender,
            4 * points,
            Some(points),
            &device,
        );
    }
}
