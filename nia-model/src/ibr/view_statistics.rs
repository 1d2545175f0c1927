//! Across-view statistics of per-view quantities (IBRNet's global context; not in NIA): the
//! visibility-weighted mean and variance over the N source views of what each view reads at a
//! point (pixel features, source colours). Where the views agree (small variance) the point is
//! likely on the surface they all see; where they disagree it is in front of or behind it, or
//! occluded in some view. F_B uses them to compare views (`ModelConfig::blend_view_statistics`).
//!
//! ```text
//! omega_n = (o_n + FLOOR) / sum_k (o_k + FLOOR)
//! mean    = sum_n omega_n x_n,      var = sum_n omega_n (x_n - mean)^2
//! ```
//!
//! The floor gives an invisible view a weight of 1 % of a visible one's, so a point no view
//! sees gets the plain mean and variance instead of 0/0.

use burn::prelude::*;

use crate::shape::ShapeError;

/// Weight of an invisible view relative to a visible one's 1.
pub const STATISTICS_FLOOR: f32 = 0.01;

/// The normalised view weights omega_n.
///
/// # Shapes
/// - `visibility` o_n: `[N, M]` in [0, 1]
/// - output omega: `[N, M, 1]`, sums to 1 over N
pub fn view_weights(visibility: Tensor<2>) -> Tensor<3> {
    let [n, m] = visibility.dims();
    let weight = visibility.reshape([n, m, 1]).add_scalar(STATISTICS_FLOOR);
    weight.clone() / weight.sum_dim(0)
}

/// Mean and variance over the views of `x` under the weights `omega` of [`view_weights`].
///
/// # Shapes
/// - `x`: `[N, M, k]`; `omega`: `[N, M, 1]`
/// - output: `([M, k], [M, k])` (mean, variance >= 0)
pub fn mean_and_variance(
    x: Tensor<3>,
    omega: Tensor<3>,
) -> Result<(Tensor<2>, Tensor<2>), ShapeError> {
    let [n, m, k] = x.dims();
    ShapeError::check(
        "view statistics `omega` [N, M, 1]",
        &omega.dims(),
        &[Some(n), Some(m), Some(1)],
    )?;
    let mean = (x.clone() * omega.clone()).sum_dim(0); // [1, M, k]
    let var = ((x - mean.clone()).square() * omega).sum_dim(0);
    Ok((mean.reshape([m, k]), var.reshape([m, k])))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[allow(deprecated)] // Device::ndarray(): the reference CPU backend.
    fn weighted_mean_and_variance_of_two_views() {
        let device = Device::ndarray();
        // N = 2 views, M = 2 points, k = 1: values 1 and 3 at both points; both views see
        // point 0, only view 0 sees point 1.
        let x = Tensor::<3>::from_floats([[[1.0], [1.0]], [[3.0], [3.0]]], &device);
        let visibility = Tensor::<2>::from_floats([[1.0, 1.0], [1.0, 0.0]], &device);
        let (mean, var) = mean_and_variance(x, view_weights(visibility)).unwrap();
        let mean = mean.into_data().to_vec::<f32>().unwrap();
        let var = var.into_data().to_vec::<f32>().unwrap();
        assert!((mean[0] - 2.0).abs() < 1e-6 && (var[0] - 1.0).abs() < 1e-6);
        // omega = (1.01, 0.01) / 1.02
        let (w0, w1) = (1.01f32 / 1.02, 0.01f32 / 1.02);
        let m1 = w0 * 1.0 + w1 * 3.0;
        let v1 = w0 * (1.0 - m1).powi(2) + w1 * (3.0 - m1).powi(2);
        assert!((mean[1] - m1).abs() < 1e-6, "{} vs {m1}", mean[1]);
        assert!((var[1] - v1).abs() < 1e-6, "{} vs {v1}", var[1]);
    }

    #[test]
    #[allow(deprecated)]
    fn no_view_sees_the_point_gives_the_plain_mean() {
        let device = Device::ndarray();
        let x = Tensor::<3>::from_floats([[[0.0, 2.0]], [[4.0, 2.0]]], &device);
        let visibility = Tensor::<2>::zeros([2, 1], &device);
        let (mean, var) = mean_and_variance(x, view_weights(visibility)).unwrap();
        assert_eq!(mean.into_data().to_vec::<f32>().unwrap(), vec![2.0, 2.0]);
        assert_eq!(var.into_data().to_vec::<f32>().unwrap(), vec![4.0, 0.0]);
    }
}
