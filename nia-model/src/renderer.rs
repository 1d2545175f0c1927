//! Volume rendering (NeRF quadrature) over R rays of S ordered samples, black background, and
//! the stratified sampler of the ray parameters t.
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
//! Numerics (DESIGN.md section 5): the transmittance is `exp(-exclusive_cumsum(tau))`, never a
//! cumulative product of (1 - alpha), so an opaque sample does not turn later products into
//! 0 * inf. The last interval ends at `far` (no 1e10 sentinel). The exponent arguments are
//! always <= 0, so `exp` cannot overflow; tau is clamped to `[0, OPTICAL_DEPTH_MAX]`: the lower
//! bound keeps a negative density (a field without a non-negative activation) from turning
//! `exp(-tau)` into an overflow, the upper bound keeps an infinite density from producing
//! `inf - inf` in the cumulative sum. Within the clamp the gradient is exact; optical depths of
//! 1e4 give alpha = 1, T = 0 after them, and zero (finite) gradients. Rays with near == far have
//! all deltas 0: every weight is 0 (black, acc = 0, depth = 0) with finite gradients.

use burn::prelude::*;

use crate::blender::ShapeError;

/// Upper clamp of one sample's optical depth sigma * delta. exp(-x) is exactly 0 in f32 beyond
/// x ~ 104, so any bound above that changes no value; 1e6 also keeps the cumulative sum of
/// S <= 1e3 samples (<= 1e9) far from f32 overflow.
pub const OPTICAL_DEPTH_MAX: f32 = 1.0e6;

/// Errors of the renderer and the sampler.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RenderError {
    /// A tensor argument has the wrong shape.
    #[error(transparent)]
    Shape(#[from] ShapeError),
    /// Two per-ray slices of the sampler have different lengths.
    #[error("stratified_t: `{field}` has {got} values, expected {expected}")]
    Length {
        /// The argument.
        field: &'static str,
        /// Its length.
        got: usize,
        /// The expected length.
        expected: usize,
    },
    /// A ray interval is not finite or ends before it starts.
    #[error("stratified_t: ray {ray}: expected finite near <= far, got near {near}, far {far}")]
    Interval {
        /// Ray index.
        ray: usize,
        /// Its near bound (metres).
        near: f32,
        /// Its far bound (metres).
        far: f32,
    },
    /// A jitter value is outside [0, 1].
    #[error("stratified_t: `jitter[{index}]` = {value}, expected a value in [0, 1]")]
    Jitter {
        /// Flat index [ray * S + sample].
        index: usize,
        /// The value.
        value: f32,
    },
    /// Zero samples per ray were requested.
    #[error("stratified_t: `samples` must be at least 1")]
    NoSamples,
}

/// Stratified sample positions: S equal bins over [near, far] per ray, one sample per bin at
/// `near + (i + u_i) (far - near) / S`. `jitter` holds the `u_i` in [0, 1] (row-major `[R, S]`,
/// drawn by the caller, so runs are deterministic); `None` puts every sample at its bin's centre
/// (u = 0.5, the test-time choice). The result is sorted per ray.
///
/// # Shapes
/// - `near`, `far`: `[R]` metres
/// - `jitter`: `[R * S]` or `None`
/// - output t: `[R * S]` row-major `[R, S]`, metres
pub fn stratified_t(
    near: &[f32],
    far: &[f32],
    samples: usize,
    jitter: Option<&[f32]>,
) -> Result<Vec<f32>, RenderError> {
    let rays = near.len();
    if samples == 0 {
        return Err(RenderError::NoSamples);
    }
    if far.len() != rays {
        return Err(RenderError::Length {
            field: "far",
            got: far.len(),
            expected: rays,
        });
    }
    if let Some(jitter) = jitter {
        if jitter.len() != rays * samples {
            return Err(RenderError::Length {
                field: "jitter",
                got: jitter.len(),
                expected: rays * samples,
            });
        }
        if let Some((index, &value)) = jitter
            .iter()
            .enumerate()
            .find(|(_, u)| !(0.0..=1.0).contains(*u))
        {
            return Err(RenderError::Jitter { index, value });
        }
    }
    let mut t = Vec::with_capacity(rays * samples);
    for (ray, (&near, &far)) in near.iter().zip(far).enumerate() {
        if !(near.is_finite() && far.is_finite() && near <= far) {
            return Err(RenderError::Interval { ray, near, far });
        }
        let bin = (far - near) / samples as f32;
        for i in 0..samples {
            let u = jitter.map_or(0.5, |j| j[ray * samples + i]);
            // min(): rounding must not put a sample past `far` (the last delta would go < 0).
            t.push((near + (i as f32 + u) * bin).min(far));
        }
    }
    Ok(t)
}

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
    /// Sample points the network evaluated (`R * S` unless empty space was skipped).
    pub point_evaluations: usize,
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
    let [r, s] = sigma.dims();
    ShapeError::check("render `t` [R, S]", &t.dims(), &[Some(r), Some(s)])?;
    ShapeError::check("render `far` [R]", &far.dims(), &[Some(r)])?;
    if s == 0 {
        return Err(ShapeError::empty("render samples S"));
    }
    let last_delta = far.reshape([r, 1]) - t.clone().slice(s![.., s - 1..s]);
    let delta = if s > 1 {
        let inner = t.clone().slice(s![.., 1..s]) - t.slice(s![.., 0..s - 1]);
        Tensor::cat(vec![inner, last_delta], 1)
    } else {
        last_delta
    };
    let delta = delta.clamp_min(0.0);
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
    Ok(transmittance * alpha)
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
) -> Result<RenderOutput, RenderError> {
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
    let weights = sample_weights(sigma, t.clone(), far)?;
    let w3 = weights.clone().reshape([r, s, 1]);
    let composite = |x: Tensor<3>| {
        let k = x.dims()[2];
        (x * w3.clone()).sum_dim(1).reshape([r, k])
    };
    Ok(RenderOutput {
        rgb: composite(colour),
        rgb0: composite(colour0),
        acc: weights.clone().sum_dim(1).reshape([r]),
        depth: (weights * t).sum_dim(1).reshape([r]),
        blend_weights: blend.map(composite),
        point_evaluations: r * s,
    })
}
