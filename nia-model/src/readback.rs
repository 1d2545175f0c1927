//! Reading tensors back to host memory (sigma for early termination, the host copies of the
//! inference reads, rendered images).

use burn::prelude::*;

use crate::shape::ShapeError;

/// The values of `tensor` as f32, row-major. The error is burn's, as text, for the caller to
/// wrap with what it was reading.
pub fn host_values<const D: usize>(tensor: Tensor<D>) -> Result<Vec<f32>, String> {
    tensor
        .into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| format!("{e:?}"))
}

/// [`host_values`] with the error as a [`ShapeError`] naming `what` was read.
pub fn host_values_of<const D: usize>(
    what: &str,
    tensor: Tensor<D>,
) -> Result<Vec<f32>, ShapeError> {
    host_values(tensor).map_err(|e| ShapeError::value(what, format!("f32 values ({e})")))
}
