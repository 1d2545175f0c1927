//! Reading tensors back to host memory (sigma for early termination, the host copies of the
//! inference reads, rendered images).

use burn::prelude::*;

/// The values of `tensor` as f32, row-major. The error is burn's, as text, for the caller to
/// wrap with what it was reading.
pub fn host_values<const D: usize>(tensor: Tensor<D>) -> Result<Vec<f32>, String> {
    tensor
        .into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| format!("{e:?}"))
}
