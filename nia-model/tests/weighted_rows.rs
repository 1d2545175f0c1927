//! The weighted row gather as one host operation with its own backward
//! (`nia_model::kernels::weighted_rows`) against the tensor read it replaces on flex (row gathers,
//! weights, a sum over the taps): values and the table's gradient.

mod common;

use burn::prelude::*;
use common::{relative_gap, values as read};
use nia_data::rng::Rng;
use nia_model::kernels::weighted_rows::{weighted_rows, Taps};

/// `n` values in [-1, 1) drawn from `seed`.
fn values(n: usize, seed: u64) -> Vec<f32> {
    let mut rng = Rng::new(seed);
    (0..n).map(|_| rng.range(-1.0, 1.0)).collect()
}

/// R rows of K taps into a table of T rows; every fifth tap reads the last row (the zero row
/// of the reads) with weight 0, and indices repeat, as corners shared by neighbouring points do.
fn taps(r: usize, k: usize, t: usize, seed: u64) -> Taps {
    let raw = values(2 * r * k, seed);
    let mut index = Vec::with_capacity(r * k);
    let mut weight = Vec::with_capacity(r * k);
    for j in 0..r * k {
        if j % 5 == 4 {
            index.push((t - 1) as u32);
            weight.push(0.0);
        } else {
            index.push((((raw[2 * j] + 1.0) / 2.0 * (t - 1) as f32) as usize).min(t - 2) as u32);
            weight.push((raw[2 * j + 1] + 1.0) / 2.0);
        }
    }
    Taps::new(k, index, weight)
}

/// The table `[T, C]` (last row zero), read at `taps` through the host operation or the tensor
/// read; the output and the table's gradient of `sum(out * r)`.
fn run(device: &Device, t: usize, c: usize, taps: &Taps, host: bool) -> (Vec<f32>, Vec<f32>) {
    let mut v = values(t * c, 5);
    v[(t - 1) * c..].iter_mut().for_each(|x| *x = 0.0);
    let table = Tensor::<2>::from_data(TensorData::new(v, [t, c]), device).require_grad();
    let (r, k) = (taps.rows(), taps.per_row);
    let out = if host {
        weighted_rows(table.clone(), taps.clone())
    } else {
        let index: Vec<i64> = taps.index.iter().map(|&i| i as i64).collect();
        let index = Tensor::<1, Int>::from_data(TensorData::new(index, [r * k]), device);
        let w = Tensor::<2>::from_data(TensorData::new(taps.weight.to_vec(), [r * k, 1]), device);
        (table.clone().select(0, index) * w)
            .reshape([r, k, c])
            .sum_dim(1)
            .reshape([r, c])
    };
    let weights = Tensor::<2>::from_data(TensorData::new(values(r * c, 9), [r, c]), device);
    let grads = (out.clone() * weights).sum().backward();
    (read(out), read(table.grad(&grads).unwrap()))
}

#[test]
#[allow(deprecated)] // Device::ndarray(): the reference CPU backend the project keeps
fn weighted_rows_match_the_tensor_read() {
    let flex = Device::flex().autodiff();
    let nd = Device::ndarray().autodiff();
    for &(r, k, t, c) in &[(1, 1, 2, 1), (300, 8, 50, 7), (2000, 4, 900, 16)] {
        let taps = taps(r, k, t, 3);
        let (out, grad) = run(&flex, t, c, &taps, true);
        for (device, what) in [(&flex, "flex"), (&nd, "ndarray")] {
            let (want_out, want_grad) = run(device, t, c, &taps, false);
            let gap = relative_gap(&out, &want_out);
            assert!(
                gap <= 1e-6,
                "[{r} x {k}] from [{t}, {c}], {what}: output gap {gap}"
            );
            let gap = relative_gap(&grad, &want_grad);
            assert!(
                gap <= 1e-6,
                "[{r} x {k}] from [{t}, {c}], {what}: gradient gap {gap}"
            );
        }
        assert!(grad.iter().all(|v| v.is_finite()));
        // The zero row's gradient comes only from weight-0 taps.
        assert!(grad[(t - 1) * c..].iter().all(|v| *v == 0.0));
        if r > 1 {
            assert!(grad.iter().any(|v| *v != 0.0));
        }
    }
}

#[test]
fn weighted_rows_are_the_same_whatever_the_number_of_threads() {
    let flex = Device::flex().autodiff();
    // Large enough for both passes to run on rayon's threads.
    let (t, c) = (3000, 16);
    let taps = taps(20_000, 4, t, 7);
    let reference = run(&flex, t, c, &taps, true);
    for threads in [1, 2, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let got = pool.install(|| run(&flex, t, c, &taps, true));
        assert_eq!(got, reference, "{threads} threads");
    }
    // Without autodiff: the same forward.
    let plain = Device::flex();
    let mut v = values(t * c, 5);
    v[(t - 1) * c..].iter_mut().for_each(|x| *x = 0.0);
    let table = Tensor::<2>::from_data(TensorData::new(v, [t, c]), &plain);
    assert_eq!(read(weighted_rows(table, taps)), reference.0);
}

#[test]
fn taps_read_in_several_views_are_the_taps_of_each_view() {
    // Three views of 40 rows each (the last row of each zero): the per-view taps against the
    // same taps written out view by view.
    let (views, stride, c) = (3, 40, 5);
    let t = views * stride;
    let one = taps(70, 8, stride, 21);
    let per_view = Taps {
        views,
        view_stride: stride,
        ..one.clone()
    };
    let written_out = Taps::new(
        8,
        (0..views)
            .flat_map(|v| one.index.iter().map(move |&i| i + (v * stride) as u32))
            .collect(),
        (0..views)
            .flat_map(|_| one.weight.iter().copied())
            .collect(),
    );
    assert_eq!(per_view.rows(), written_out.rows());
    let flex = Device::flex().autodiff();
    assert_eq!(
        run(&flex, t, c, &per_view, true),
        run(&flex, t, c, &written_out, true)
    );
}

#[test]
fn no_taps_read_nothing() {
    let flex = Device::flex().autodiff();
    let table = Tensor::<2>::ones([4, 3], &flex).require_grad();
    let empty = Taps::new(8, Vec::new(), Vec::new());
    let out = weighted_rows(table.clone(), empty);
    assert_eq!(out.dims(), [0, 3]);
    let grads = (out.sum() + table.clone().sum() * 0.0).backward();
    assert_eq!(read(table.grad(&grads).unwrap()), vec![0.0; 12]);
}

#[test]
#[should_panic(expected = "weighted rows")]
fn a_tap_past_the_table_is_refused_before_any_read() {
    let table = Tensor::<2>::ones([4, 3], &Device::flex());
    let taps = Taps::new(1, vec![4], vec![1.0]);
    let _ = weighted_rows(table, taps);
}
