//! The weighted row gather as one operation with a one-buffer backward
//! (`nia_model::kernels::tap_gather`, what training on a GPU backend runs for the bilinear and trilinear
//! reads) against the tensor form the other backends run (a gather, a product and a sum per
//! tap): values and the gradients of the rows and of the weights, on ndarray and on wgpu
//! (where the rows' gradient is the `nia_model::kernels::tap_scatter` kernel on a device that adds
//! floats atomically).

mod common;

use burn::prelude::*;
use common::{relative_gap, tensor, values};
use nia_data::rng::Rng;
use nia_model::kernels::tap_gather::tap_gather;

/// A read: `k` taps for each of `l` outputs from `r` rows of `c` values.
struct Case {
    k: usize,
    l: usize,
    r: usize,
    c: usize,
    rows: Vec<f32>,
    /// `[K, L]`, rows repeating (many taps share a row, as the zero row is shared).
    index: Vec<i64>,
    /// `[K, L]`, some of them zero (a corner off the map).
    weight: Vec<f32>,
    /// The output gradient's weights `[L, C]`.
    r_out: Vec<f32>,
}

fn case(k: usize, l: usize, r: usize, c: usize, seed: u64) -> Case {
    let mut rng = Rng::new(seed);
    let mut draw = |len: usize| -> Vec<f32> { (0..len).map(|_| rng.range(-1.0, 1.0)).collect() };
    let rows = draw(r * c);
    let r_out = draw(l * c);
    let weight = draw(k * l)
        .into_iter()
        .enumerate()
        .map(|(i, w)| if i % 7 == 3 { 0.0 } else { w })
        .collect();
    let mut rng = Rng::new(seed + 1);
    let index = (0..k * l)
        .map(|_| (rng.uniform() * r as f32).min(r as f32 - 1.0) as i64)
        .collect();
    Case {
        k,
        l,
        r,
        c,
        rows,
        index,
        weight,
        r_out,
    }
}

/// (output, d rows, d weight) of `sum(out * r_out)` by the operation or by the tensor form;
/// d weight is empty when the weights carry no gradient.
fn run(device: &Device, c: &Case, block: usize, weight_grad: bool, by_op: bool) -> [Vec<f32>; 3] {
    let ad = device.clone().autodiff();
    let rows = tensor(c.rows.clone(), [c.r, c.c], &ad).require_grad();
    let mut weight = tensor(c.weight.clone(), [c.k, c.l], &ad);
    if weight_grad {
        weight = weight.require_grad();
    }
    let index = Tensor::<2, Int>::from_data(TensorData::new(c.index.clone(), [c.k, c.l]), &ad);
    let out = if by_op {
        tap_gather(rows.clone(), index, weight.clone(), block)
    } else {
        (0..c.k)
            .map(|j| {
                let at = index.clone().narrow(0, j, 1).reshape([c.l]);
                let w = weight.clone().narrow(0, j, 1).reshape([c.l, 1]);
                rows.clone().select(0, at) * w
            })
            .reduce(|sum, term| sum + term)
            .unwrap()
    };
    let grads = (out.clone() * tensor(c.r_out.clone(), [c.l, c.c], &ad))
        .sum()
        .backward();
    let d_weight = if weight_grad {
        values(weight.grad(&grads).expect("the weights' gradient"))
    } else {
        assert!(weight.grad(&grads).is_none());
        Vec::new()
    };
    [
        values(out),
        values(rows.grad(&grads).expect("the rows' gradient")),
        d_weight,
    ]
}

fn assert_agree(got: &[Vec<f32>; 3], reference: &[Vec<f32>; 3], tol: f32, what: &str) {
    for (name, (g, r)) in ["output", "d rows", "d weight"]
        .iter()
        .zip(got.iter().zip(reference))
    {
        assert_eq!(g.len(), r.len(), "{what}: {name} length");
        assert!(g.iter().all(|v| v.is_finite()), "{what}: {name} not finite");
        if !r.is_empty() {
            let gap = relative_gap(g, r);
            assert!(gap <= tol, "{what}: {name} differs by {gap} (relative)");
        }
    }
}

#[test]
fn tap_gather_matches_the_tensor_form_on_ndarray() {
    let device = common::device();
    // Eight taps (a trilinear read) in several blocks with a short last one, four (bilinear)
    // in one block, and blocks of one output; with and without the weights' gradient.
    for (k, block, weight_grad, seed) in [
        (8usize, 4usize, false, 1u64),
        (8, 4, true, 2),
        (4, 64, true, 3),
        (4, 1, false, 4),
    ] {
        let c = case(k, 11, 40, 5, seed);
        let reference = run(&device, &c, block, weight_grad, false);
        let got = run(&device, &c, block, weight_grad, true);
        assert_agree(&got, &reference, 1e-5, &format!("k {k}, block {block}"));
        assert!(got[1].iter().any(|v| *v != 0.0), "d rows all zero");
        if weight_grad {
            assert!(got[2].iter().any(|v| *v != 0.0), "d weight all zero");
        }
    }
}

#[test]
fn tap_gather_sums_a_row_read_by_every_tap() {
    // Every tap reads row 0 (an output off the map reads the zero row at every corner): its
    // gradient is the weighted sum of every output's gradient, and no other row gets one.
    let device = common::device();
    let mut c = case(8, 9, 3, 4, 7);
    c.index = vec![0; c.k * c.l];
    let reference = run(&device, &c, 2, true, false);
    let got = run(&device, &c, 2, true, true);
    assert_agree(&got, &reference, 1e-5, "all taps on row 0");
    assert!(got[1][c.c..].iter().all(|v| *v == 0.0), "unread rows");
    assert!(got[1][..c.c].iter().any(|v| *v != 0.0), "row 0");
}

#[test]
fn tap_gather_of_no_outputs_is_empty() {
    let device = common::device();
    let rows = tensor(vec![1.0; 6], [3, 2], &device);
    let index = Tensor::<2, Int>::zeros([8, 0], &device);
    let weight = Tensor::<2>::zeros([8, 0], &device);
    assert_eq!(tap_gather(rows, index, weight, 16).dims(), [0, 2]);
}

#[cfg(feature = "wgpu")]
#[test]
fn tap_gather_on_wgpu_matches_ndarray() {
    let Some(wgpu) = common::wgpu_device() else {
        return;
    };
    let device = common::device();
    // Where the device adds floats atomically (lavapipe does) the rows' gradient is the
    // weighted scatter-add kernel (`nia_model::kernels::tap_scatter`): small cases, one of 8 x 5,000 x
    // 16 threads, and every tap on one row (all threads add to the same 16 values).
    eprintln!(
        "wgpu device adds floats atomically: {}",
        nia_model::device::adds_floats_atomically(&wgpu)
    );
    let mut on_one_row = case(8, 600, 5, 16, 14);
    on_one_row.index = vec![0; 8 * 600];
    for (c, block, weight_grad) in [
        (case(8, 37, 50, 6, 11), 16usize, false),
        (case(4, 37, 50, 6, 12), 64, true),
        (case(8, 5000, 300, 16, 13), 1024, false),
        (on_one_row, 256, true),
    ] {
        let reference = run(&device, &c, block, weight_grad, false);
        let got = run(&wgpu, &c, block, weight_grad, true);
        // Atomic scatter-adds sum in no fixed order.
        assert_agree(
            &got,
            &reference,
            1e-5,
            &format!("wgpu, k {}, l {}", c.k, c.l),
        );
        assert!(got[1].iter().any(|v| *v != 0.0), "d rows all zero");
    }
}
