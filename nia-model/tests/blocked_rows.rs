#![allow(deprecated)] // Device::ndarray(): the reference CPU backend.

//! Row gathers and scatter-adds of many indices ([`nia_model::kernels::blocked_rows`]): the same as one
//! `select` / `select_assign` on the CPU backends, and with more than 65,536 indices (where
//! burn-cubecl's `select_assign` went wrong on lavapipe) the same numbers, and the same
//! gradients, on wgpu as on ndarray: in blocks of 32,768 rows on a device without float
//! atomics, in one kernel where the device adds floats atomically (lavapipe does).

mod common;

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use nia_data::rng::Rng;
use nia_model::device::adds_floats_atomically;
use nia_model::kernels::blocked_rows::{
    scatter_add_rows, scatter_block_rows, select_rows, ATOMIC_SCATTER_VALUES, MAX_SCATTER_INDICES,
};

const ROWS: usize = 500;
const C: usize = 8;

/// Indices with many repeats, enough for three blocks and a partial one.
const LEN: usize = 3 * MAX_SCATTER_INDICES + 1234;

fn inputs() -> (Vec<f32>, Vec<i64>, Vec<f32>) {
    let mut rng = Rng::new(21);
    let rows = (0..ROWS * C).map(|_| rng.normal()).collect();
    let index = (0..LEN).map(|_| rng.below(ROWS) as i64).collect();
    let values = (0..LEN * C).map(|_| rng.normal()).collect();
    (rows, index, values)
}

/// `(select_rows forward, d rows of sum(select_rows(rows) * values), scatter_add_rows)` on
/// `device` (autodiff for the gradient).
fn run(device: &Device) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let (rows, index, values) = inputs();
    let ad = device.clone().autodiff();
    let tensor = |v: &[f32], rows: usize, d: &Device| {
        Tensor::<2>::from_data(TensorData::new(v.to_vec(), [rows, C]), d)
    };
    let idx = |d: &Device| Tensor::<1, Int>::from_data(TensorData::new(index.clone(), [LEN]), d);
    let x = tensor(&rows, ROWS, &ad).require_grad();
    let gathered = select_rows(x.clone(), idx(&ad));
    let forward = gathered.clone().into_data().try_to_vec::<f32>().unwrap();
    let grads = (gathered * tensor(&values, LEN, &ad)).sum().backward();
    let grad = x
        .grad(&grads)
        .unwrap()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    let scattered = scatter_add_rows(
        Tensor::zeros([ROWS, C], device),
        idx(device),
        tensor(&values, LEN, device),
    )
    .into_data()
    .try_to_vec::<f32>()
    .unwrap();
    (forward, grad, scattered)
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// On the CPU the helpers are the plain ops: the same numbers to the last bit.
#[test]
fn on_the_cpu_the_helpers_are_the_plain_ops() {
    let device = Device::ndarray();
    let (rows, index, values) = inputs();
    let (forward, grad, scattered) = run(&device);
    // The reference by hand: gathered rows, and every value added to its row.
    let mut expected_grad = vec![0.0f32; ROWS * C];
    for (l, &i) in index.iter().enumerate() {
        let i = i as usize;
        assert_eq!(forward[l * C..(l + 1) * C], rows[i * C..(i + 1) * C]);
        for c in 0..C {
            expected_grad[i * C + c] += values[l * C + c];
        }
    }
    assert!(max_diff(&grad, &expected_grad) < 1e-3, "gradient");
    let plain = Tensor::<2>::zeros([ROWS, C], &device)
        .select_assign(
            0,
            Tensor::<1, Int>::from_data(TensorData::new(index, [LEN]), &device),
            Tensor::<2>::from_data(TensorData::new(values, [LEN, C]), &device),
            IndexingUpdateOp::Add,
        )
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    assert_eq!(scattered, plain);
}

/// The rows per block: 32,768 without float atomics; with them at most 64 MiB of values, a
/// power of two, never fewer than 32,768 rows. The CPU backends never take the atomic path.
#[test]
fn blocks_are_32768_rows_or_64_mib_of_values_with_atomics() {
    for columns in [1, 8, 64, 512, 4096] {
        assert_eq!(scatter_block_rows(false, columns), MAX_SCATTER_INDICES);
    }
    assert_eq!(ATOMIC_SCATTER_VALUES * 4, 64 << 20);
    assert_eq!(scatter_block_rows(true, 16), (64 << 20) / (16 * 4));
    assert_eq!(scatter_block_rows(true, 1), ATOMIC_SCATTER_VALUES);
    // A power of two, so that blocks start on the device's alignment: 2^24 / 48 = 349,525.
    assert_eq!(scatter_block_rows(true, 48), 1 << 18);
    assert_eq!(scatter_block_rows(true, 3), 1 << 22);
    // Very wide rows: the floor of 32,768 rows.
    assert_eq!(scatter_block_rows(true, 4096), MAX_SCATTER_INDICES);
    assert_eq!(scatter_block_rows(true, 0), ATOMIC_SCATTER_VALUES);
    for device in [Device::ndarray(), Device::flex()] {
        assert!(!adds_floats_atomically(&device));
        assert!(!adds_floats_atomically(&device.autodiff()));
    }
}

/// On wgpu, past 65,536 indices: the gather, its gradient and the scatter-add match ndarray's.
#[cfg(feature = "wgpu")]
#[test]
fn on_wgpu_many_indices_gather_and_scatter_like_ndarray() {
    let Some(gpu) = common::wgpu_device() else {
        return;
    };
    // Lavapipe adds floats atomically: there this is one kernel of all LEN rows.
    eprintln!(
        "wgpu device adds floats atomically: {}",
        adds_floats_atomically(&gpu)
    );
    assert_eq!(
        adds_floats_atomically(&gpu),
        adds_floats_atomically(&gpu.clone().autodiff())
    );
    let (f_cpu, g_cpu, s_cpu) = run(&Device::ndarray());
    let (f_gpu, g_gpu, s_gpu) = run(&gpu);
    assert_eq!(f_gpu, f_cpu, "gathered rows");
    // Sums of ~400 terms of N(0, 1) in another order: 1e-3 absolute.
    let scale = g_cpu.iter().fold(0.0f32, |m, x| m.max(x.abs()));
    assert!(scale > 10.0, "{scale}");
    let (dg, ds) = (max_diff(&g_gpu, &g_cpu), max_diff(&s_gpu, &s_cpu));
    assert!(
        dg < 1e-3,
        "select's gradient on wgpu differs by {dg} (largest {scale})"
    );
    assert!(
        ds < 1e-3,
        "scatter-add on wgpu differs by {ds} (largest {scale})"
    );
}
