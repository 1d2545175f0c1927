//! Rodrigues' formula on tensors (batched, differentiable).
//!
//! `R = I + a K + b K^2` with `K = [r]_x`, `t = |r|`, `a = sin(t) / t`,
//! `b = (1 - cos t) / t^2 = 0.5 (sin(t/2) / (t/2))^2` (the half-angle form keeps `b` exact in
//! f32 near 0), and `K^2 = r r^T - t^2 I`.

use burn::prelude::*;

/// Added to `|r|^2` before the square root: keeps `t`, `sin(t)/t` and their gradients finite at
/// `r = 0` (where the exact values are `a = 1`, `b = 1/2`); 1e-12 moves `t` by at most 1e-6 rad.
pub const RODRIGUES_EPS: f32 = 1e-12;

/// Rotation matrices of axis-angle vectors (radians).
///
/// # Shapes
/// - `r`: `[N, 3]`
/// - output: `[N, 3, 3]`, row-major (`out[n, i, j] = R_n[i][j]`)
pub fn rodrigues(r: Tensor<2>) -> Tensor<3> {
    let [n, _] = r.dims();
    let device = r.device();
    let t2 = r.clone().square().sum_dim(1); // [N, 1]
    let t = (t2.clone() + RODRIGUES_EPS).sqrt();
    let a = t.clone().sin() / t.clone();
    let half = t * 0.5;
    let b = (half.clone().sin() / half).square() * 0.5;
    let x = r.clone().narrow(1, 0, 1);
    let y = r.clone().narrow(1, 1, 1);
    let z = r.clone().narrow(1, 2, 1);
    let zero = Tensor::<2>::zeros([n, 1], &device);
    let k = Tensor::cat(
        vec![
            zero.clone(),
            -z.clone(),
            y.clone(),
            z,
            zero.clone(),
            -x.clone(),
            -y,
            x,
            zero,
        ],
        1,
    )
    .reshape([n, 3, 3]);
    let outer = r.clone().unsqueeze_dim::<3>(2) * r.unsqueeze_dim::<3>(1); // [N, 3, 3]
    let eye = Tensor::<2>::eye(3, &device).unsqueeze_dim::<3>(0); // [1, 3, 3]
    let k2 = outer - eye.clone() * t2.clone().unsqueeze_dim::<3>(2);
    eye + k * a.unsqueeze_dim::<3>(2) + k2 * b.unsqueeze_dim::<3>(2)
}
