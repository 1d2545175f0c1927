//! Volume rendering (NeRF quadrature): R rays of S ordered
//! samples composited over a black background.
//!
//! ```text
//! delta_i = t_{i+1} - t_i            (i < S - 1),   delta_{S-1} = far - t_{S-1}   (both >= 0)
//! tau_i   = clamp(sigma_i * delta_i, 0, OPTICAL_DEPTH_MAX)      (optical depth of sample i)
//! alpha_i = 1 - exp(-tau_i)
//! T_i     = exp(-sum_{j<i} tau_j)                               (exclusive cumulative sum)
//! w_i     = T_i * alpha_i
//! rgb = sum_i w_i c_i,  rgb0 = sum_i w_i c0_i,  acc = sum_i w_i,  depth = sum_i w_i t_i
//! blend_weights = sum_i w_i * softmax_i                          (per ray, [R, N + 1])
//! ```
//!
//! Numerics (docs/method.md, "Numerics"): the transmittance is `exp(-exclusive_cumsum(tau))`, never a
//! cumulative product of (1 - alpha), so an opaque sample does not turn later products into
//! 0 * inf. The last interval ends at `far` (no 1e10 sentinel). The exponent arguments are
//! always <= 0, so `exp` cannot overflow; tau is clamped to `[0, OPTICAL_DEPTH_MAX]`: the lower
//! bound keeps a negative density (a field without a non-negative activation) from turning
//! `exp(-tau)` into an overflow, the upper bound keeps an infinite density from producing
//! `inf - inf` in the cumulative sum. Within the clamp the gradient is exact; optical depths of
//! 1e4 give alpha = 1, T = 0 after them, and zero (finite) gradients. Rays with near == far have
//! all deltas 0: every weight is 0 (black, acc = 0, depth = 0) with finite gradients.

use burn::prelude::*;

use crate::shape::ShapeError;

/// Upper clamp of one sample's optical depth sigma * delta. exp(-x) is exactly 0 in f32 beyond
/// x ~ 104, so any bound above that changes no value; 1e6 also keeps the cumulative sum of
/// S <= 1e3 samples (<= 1e9) far from f32 overflow.
pub const OPTICAL_DEPTH_MAX: f32 = 1.0e6;

/// Per-ray results of [`render_rays`].
#[derive(Debug, Clone)]
pub struct RenderOutput {
    /// Composited blended colour C, `[R, 3]` (black background).
    pub rgb: Tensor<2>,
    /// Composited NeRF colour C0, `[R, 3]`.
    pub rgb0: Tensor<2>,
    /// Accumulated opacity sum_i w_i, `[R]` in [0, 1].
    pub acc: Tensor<1>,
    /// Expected depth sum_i w_i t_i, `[R]` metres (0 for empty rays).
    pub depth: Tensor<1>,
    /// Blend weights accumulated along the ray, `[R, N + 1]` (None when none were given).
    pub blend_weights: Option<Tensor<2>>,
    /// `[R, S]` compositing weights w_i (to composite further per-sample quantities).
    pub weights: Tensor<2>,
    /// `[R, S]` sample positions t_i along the ray, metres.
    pub t: Tensor<2>,
    /// `[R, S]` quadrature intervals delta_i, metres (clamped at 0).
    pub delta: Tensor<2>,
    /// `[R, 3]` the IBR-only composite ([`crate::field::PointOutput::ibr_colour`]), filled
    /// by [`crate::NiaModel::render`]; `None` from the quadrature alone.
    pub rgb_ibr: Option<Tensor<2>>,
    /// Sample points the network evaluated (`R * S` unless empty space was skipped).
    pub point_evaluations: usize,
    /// Of those, the points the colour half of the network evaluated (fewer with colour
    /// culling).
    pub colour_evaluations: usize,
}

/// The compositing weights w_i = T_i alpha_i of every sample.
///
/// # Shapes
/// - `sigma`: `[R, S]` per metre
/// - `t`: `[R, S]` metres, non-decreasing per ray
/// - `far`: `[R]` metres
/// - output w: `[R, S]`
pub fn sample_weights(
    sigma: Tensor<2>,
    t: Tensor<2>,
    far: Tensor<1>,
) -> Result<Tensor<2>, ShapeError> {
    let delta = stratified_delta(&sigma, t, far)?;
    sample_weights_delta(sigma, delta)
}

/// The quadrature intervals of stratified samples: `t_{i+1} - t_i` and `far - t_{S-1}`.
///
/// # Shapes
/// - `sigma` (for its shape only): `[R, S]`
/// - `t`: `[R, S]` metres; `far`: `[R]` metres
/// - output delta: `[R, S]` metres (not yet clamped at 0)
fn stratified_delta(
    sigma: &Tensor<2>,
    t: Tensor<2>,
    far: Tensor<1>,
) -> Result<Tensor<2>, ShapeError> {
    let [r, s] = sigma.dims();
    ShapeError::check("render `t` [R, S]", &t.dims(), &[Some(r), Some(s)])?;
    ShapeError::check("render `far` [R]", &far.dims(), &[Some(r)])?;
    if s == 0 {
        return Err(ShapeError::empty("render samples S"));
    }
    let last_delta = far.reshape([r, 1]) - t.clone().slice(s![.., s - 1..s]);
    Ok(if s > 1 {
        let inner = t.clone().slice(s![.., 1..s]) - t.slice(s![.., 0..s - 1]);
        Tensor::cat(vec![inner, last_delta], 1)
    } else {
        last_delta
    })
}

/// The compositing weights w_i = T_i alpha_i from explicit quadrature intervals (band samples,
/// whose intervals are not the gaps between their positions).
///
/// # Shapes
/// - `sigma`: `[R, S]` per metre
/// - `delta`: `[R, S]` metres (negative values count as 0)
/// - output w: `[R, S]`
pub fn sample_weights_delta(sigma: Tensor<2>, delta: Tensor<2>) -> Result<Tensor<2>, ShapeError> {
    let [r, s] = sigma.dims();
    ShapeError::check("render `delta` [R, S]", &delta.dims(), &[Some(r), Some(s)])?;
    if s == 0 {
        return Err(ShapeError::empty("render samples S"));
    }
    Ok(weights_of_clamped(sigma, delta.clamp_min(0.0)))
}

/// w_i from intervals already clamped at 0 ([`sample_weights_delta`] without the checks).
fn weights_of_clamped(sigma: Tensor<2>, delta: Tensor<2>) -> Tensor<2> {
    let [r, s] = sigma.dims();
    let tau = (sigma * delta).clamp(0.0, OPTICAL_DEPTH_MAX);
    let device = tau.device();
    let exclusive = if s > 1 {
        let inclusive = tau.clone().slice(s![.., 0..s - 1]).cumsum(1);
        Tensor::cat(vec![Tensor::zeros([r, 1], &device), inclusive], 1)
    } else {
        Tensor::zeros([r, 1], &device)
    };
    let transmittance = exclusive.neg().exp();
    let alpha = tau.neg().exp().neg().add_scalar(1.0);
    transmittance * alpha
}

/// Volume-renders R rays of S samples.
///
/// # Shapes
/// - `sigma`: `[R, S]` per metre
/// - `colour` c: `[R, S, 3]`; `colour0` c0: `[R, S, 3]`
/// - `t`: `[R, S]` metres (non-decreasing per ray); `far`: `[R]` metres
/// - `blend` (optional): `[R, S, N + 1]` per-sample blend weights
/// - output: see [`RenderOutput`]
pub fn render_rays(
    sigma: Tensor<2>,
    colour: Tensor<3>,
    colour0: Tensor<3>,
    t: Tensor<2>,
    far: Tensor<1>,
    blend: Option<Tensor<3>>,
) -> Result<RenderOutput, ShapeError> {
    let delta = stratified_delta(&sigma, t.clone(), far)?;
    render_rays_delta(sigma, colour, colour0, t, delta, blend)
}

/// [`render_rays`] with explicit quadrature intervals `delta` `[R, S]` (metres) in place of
/// `far` (band samples, [`crate::sampler::RaySamples::delta`]).
pub fn render_rays_delta(
    sigma: Tensor<2>,
    colour: Tensor<3>,
    colour0: Tensor<3>,
    t: Tensor<2>,
    delta: Tensor<2>,
    blend: Option<Tensor<3>>,
) -> Result<RenderOutput, ShapeError> {
    let [r, s] = sigma.dims();
    ShapeError::check(
        "render `colour` [R, S, 3]",
        &colour.dims(),
        &[Some(r), Some(s), Some(3)],
    )?;
    ShapeError::check(
        "render `colour0` [R, S, 3]",
        &colour0.dims(),
        &[Some(r), Some(s), Some(3)],
    )?;
    if let Some(blend) = &blend {
        ShapeError::check(
            "render `blend` [R, S, N + 1]",
            &blend.dims(),
            &[Some(r), Some(s), None],
        )?;
    }
    ShapeError::check("render `t` [R, S]", &t.dims(), &[Some(r), Some(s)])?;
    ShapeError::check("render `delta` [R, S]", &delta.dims(), &[Some(r), Some(s)])?;
    if s == 0 {
        return Err(ShapeError::empty("render samples S"));
    }
    let delta = delta.clamp_min(0.0);
    let weights = weights_of_clamped(sigma, delta.clone());
    let w3 = weights.clone().reshape([r, s, 1]);
    let composite = |x: Tensor<3>| {
        let k = x.dims()[2];
        (x * w3.clone()).sum_dim(1).reshape([r, k])
    };
    Ok(RenderOutput {
        rgb: composite(colour),
        rgb0: composite(colour0),
        acc: weights.clone().sum_dim(1).reshape([r]),
        depth: (weights.clone() * t.clone()).sum_dim(1).reshape([r]),
        blend_weights: blend.map(composite),
        weights,
        t,
        delta,
        rgb_ibr: None,
        point_evaluations: r * s,
        colour_evaluations: r * s,
    })
}
