//! The `Im2col` product as one operation with a one-buffer backward
//! (`nia_model::body_volume::im2col_op`, what training on a GPU backend runs) against the tensor
//! form that the other backends run (a gather, matmul and reshape per block, concatenated):
//! values and the gradients of the rows and the weight, on ndarray and on wgpu.

mod common;

use burn::prelude::*;
use common::{relative_gap, tensor, values};
use nia_data::rng::Rng;
use nia_model::body_volume::im2col_op::im2col_product;

/// A case: `n` views, `p` outputs per view, `r` input rows of `c_in`, `c_out` out channels.
struct Case {
    n: usize,
    p: usize,
    r: usize,
    c_in: usize,
    c_out: usize,
    rows: Vec<f32>,
    weight: Vec<f32>,
    /// `[27 N P]`, blocks of `chunk` outputs, view-major within a block.
    index: Vec<i64>,
    /// The output gradient's weights `[N, P, C_out]`.
    r_out: Vec<f32>,
}

fn case(n: usize, p: usize, r: usize, c_in: usize, c_out: usize, seed: u64) -> Case {
    let mut rng = Rng::new(seed);
    let mut draw = |len: usize| -> Vec<f32> { (0..len).map(|_| rng.range(-1.0, 1.0)).collect() };
    let rows = draw(r * c_in);
    let weight = draw(27 * c_in * c_out);
    let r_out = draw(n * p * c_out);
    let mut rng = Rng::new(seed + 1);
    // Rows repeat (many outputs share a neighbour, as the zero row is shared).
    let index = (0..27 * n * p)
        .map(|_| (rng.uniform() * r as f32).min(r as f32 - 1.0) as i64)
        .collect();
    Case {
        n,
        p,
        r,
        c_in,
        c_out,
        rows,
        weight,
        index,
        r_out,
    }
}

/// (output, d rows, d weight) of `sum(out * r_out)`, by the operation or by the tensor form.
fn run(device: &Device, c: &Case, chunk: usize, by_op: bool) -> [Vec<f32>; 3] {
    let ad = device.clone().autodiff();
    let rows = tensor(c.rows.clone(), [c.r, c.c_in], &ad).require_grad();
    let weight = tensor(c.weight.clone(), [27 * c.c_in, c.c_out], &ad).require_grad();
    let index = Tensor::<1, Int>::from_data(TensorData::new(c.index.clone(), [c.index.len()]), &ad);
    let out = if by_op {
        im2col_product(rows.clone(), weight.clone(), index, c.n, chunk)
    } else {
        let mut parts = Vec::new();
        for start in (0..c.p).step_by(chunk) {
            let len = chunk.min(c.p - start);
            let block = index
                .clone()
                .slice(27 * c.n * start..27 * c.n * (start + len));
            parts.push(
                rows.clone()
                    .select(0, block)
                    .reshape([c.n * len, 27 * c.c_in])
                    .matmul(weight.clone())
                    .reshape([c.n, len, c.c_out]),
            );
        }
        Tensor::cat(parts, 1)
    };
    let grads = (out.clone() * tensor(c.r_out.clone(), [c.n, c.p, c.c_out], &ad))
        .sum()
        .backward();
    [
        values(out),
        values(rows.grad(&grads).unwrap()),
        values(weight.grad(&grads).unwrap()),
    ]
}

fn assert_agree(got: &[Vec<f32>; 3], reference: &[Vec<f32>; 3], tol: f32, what: &str) {
    for (name, (g, r)) in ["output", "d rows", "d weight"]
        .iter()
        .zip(got.iter().zip(reference))
    {
        assert!(g.iter().all(|v| v.is_finite()), "{what}: {name} not finite");
        let gap = relative_gap(g, r);
        assert!(gap <= tol, "{what}: {name} differs by {gap} (relative)");
    }
}

#[test]
fn im2col_operation_matches_the_tensor_form_on_ndarray() {
    let device = common::device();
    // Several blocks with a short last one, one block, and blocks of one output.
    for (chunk, seed) in [(4usize, 1u64), (64, 2), (1, 3)] {
        let c = case(3, 11, 40, 5, 6, seed);
        let reference = run(&device, &c, chunk, false);
        let got = run(&device, &c, chunk, true);
        assert_agree(&got, &reference, 1e-5, &format!("chunk {chunk}"));
        // Every row the index names got a gradient; the weight's gradient is not zero.
        assert!(got[2].iter().any(|v| *v != 0.0));
    }
}

#[test]
fn im2col_operation_sums_a_row_read_by_every_output() {
    // Every neighbour of every output is row 0 (an output whose neighbours are all missing
    // reads the zero row 27 times): its gradient is the sum over all 27 N P reads.
    let device = common::device();
    let mut c = case(2, 9, 3, 4, 3, 7);
    c.index = vec![0; 27 * c.n * c.p];
    let reference = run(&device, &c, 2, false);
    let got = run(&device, &c, 2, true);
    assert_agree(&got, &reference, 1e-5, "all reads on row 0");
    assert!(got[1][c.c_in..].iter().all(|v| *v == 0.0), "unread rows");
    assert!(got[1][..c.c_in].iter().any(|v| *v != 0.0), "row 0");
}

#[cfg(feature = "wgpu")]
#[test]
fn im2col_operation_on_wgpu_matches_ndarray() {
    let Some(wgpu) = common::wgpu_device() else {
        return;
    };
    let device = common::device();
    let c = case(3, 21, 50, 8, 4, 11);
    let reference = run(&device, &c, 5, false);
    let got = run(&wgpu, &c, 5, true);
    // Atomic scatter-adds sum in no fixed order.
    assert_agree(&got, &reference, 1e-5, "wgpu");
}
