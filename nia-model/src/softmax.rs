//! The numerically stable softmax every weighting of the network uses (attention, blend
//! weights, variant (d)).

use burn::prelude::*;

/// Softmax along `dim` with the maximum subtracted first: `exp(x - max) / sum exp(x - max)`.
///
/// The max is detached (the softmax is shift-invariant, so its gradient is unchanged). Finite
/// inputs of any magnitude give finite outputs and gradients; the denominator is >= 1.
pub fn stable_softmax<const D: usize>(x: Tensor<D>, dim: usize) -> Tensor<D> {
    let max = x.clone().detach().max_dim(dim);
    let exp = (x - max).exp();
    let sum = exp.clone().sum_dim(dim);
    exp / sum
}
