//! A linear layer on a rank-3 input as one matrix product over all its rows.
//!
//! `Linear::forward` on `[A, B, d]` may run as a batch of A products of `[B, d] x [d, d_out]`
//! (burn folds the batch into the rows only when the input is contiguous and the fold makes
//! the product squarer). For the field's inputs that batch is the points (A = M in the
//! thousands, B = N views: thousands of 3-row products) or the tokens, so the layers here
//! always fold: `[A B, d] x [d, d_out]`, one well-tiled product (a layout copy first when the
//! input is a transposed view).

use burn::nn::Linear;
use burn::prelude::*;

/// `linear` applied to every row of `x`.
///
/// # Shapes
/// - `x`: `[A, B, d_in]`
/// - output: `[A, B, d_out]`
pub fn linear_rows(linear: &Linear, x: Tensor<3>) -> Tensor<3> {
    let [a, b, d] = x.dims();
    let y = crate::kernels::linear_host::linear(linear, x.reshape([a * b, d]), false);
    let d_out = y.dims()[1];
    y.reshape([a, b, d_out])
}
