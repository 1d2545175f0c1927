//! What follows F_B's logits, on host values in one pass (inference on the CPU backends).
//!
//! The tensor path turns the logits `[M, N + 1]` into colours in a dozen passes on the calling
//! thread: the softmax ([`crate::softmax::stable_softmax`]), with `[render] c0_weight_scale` the
//! rescaled odds of c0 ([`crate::ibr::c0_weight_scale::rescale_c0_weight`]) and a second mix,
//! then the mix `c = w . [c0, c_1..c_N]` ([`crate::ibr::blender::mix`]) and the IBR-only colour.
//! Here each task of [`ROWS_PER_TASK`] points does all of it per point, in parallel, with the same
//! formulas in the same order, so the results agree to rounding
//! (`nia-model/tests/host_network.rs`). The tensor path stays the reference, the path with
//! gradients and the one on the GPU.

use rayon::prelude::*;

use super::c0_weight_scale::check_c0_weight_scale;
use crate::kernels::host_mlp::ROWS_PER_TASK;
use crate::shape::ShapeError;

/// Weight a view keeps in the IBR-only colour whatever its blend weight, so a point that puts
/// all weight on c0 gets the plain mean of the source colours instead of 0/0.
pub const IBR_ONLY_FLOOR: f32 = 1e-6;

/// The blend of M points on the host.
#[derive(Debug, Clone, PartialEq)]
pub struct HostBlend {
    /// c, `[M, 3]` row-major.
    pub colour: Vec<f32>,
    /// The effective weights over `[c0, c_1..c_N]` (after any c0 rescaling), `[M, N + 1]`.
    pub blend_weights: Vec<f32>,
    /// The source colours under the view weights renormalised over the views, `[M, 3]`.
    pub ibr_colour: Vec<f32>,
}

/// Softmax of the logits, c0's odds times `c0_weight_scale` (if any), the mix and the IBR-only
/// colour of every point.
///
/// # Shapes
/// - `logits_token_major`: `[N + 1, M]` (token 0 = c0), as F_B's host token layers write it
/// - `c0`: `[M, 3]`; `source_colours` c_n: `[N, M, 3]`
/// - output: [`HostBlend`]
pub fn blend_on_host(
    logits_token_major: &[f32],
    c0: &[f32],
    source_colours: &[f32],
    n: usize,
    m: usize,
    c0_weight_scale: Option<f32>,
) -> Result<HostBlend, ShapeError> {
    let t = n + 1;
    ShapeError::check(
        "host blend `logits` [N + 1, M]",
        &[logits_token_major.len()],
        &[Some(t * m)],
    )?;
    ShapeError::check("host blend `c0` [M, 3]", &[c0.len()], &[Some(m * 3)])?;
    ShapeError::check(
        "host blend `source_colours` [N, M, 3]",
        &[source_colours.len()],
        &[Some(n * m * 3)],
    )?;
    if let Some(scale) = c0_weight_scale {
        check_c0_weight_scale(scale)?;
    }
    let mut out = HostBlend {
        colour: vec![0.0; m * 3],
        blend_weights: vec![0.0; m * t],
        ibr_colour: vec![0.0; m * 3],
    };
    out.colour
        .par_chunks_mut(ROWS_PER_TASK * 3)
        .zip(out.blend_weights.par_chunks_mut(ROWS_PER_TASK * t))
        .zip(out.ibr_colour.par_chunks_mut(ROWS_PER_TASK * 3))
        .enumerate()
        .for_each(|(task, ((colour, weights), ibr))| {
            for (r, w) in weights.chunks_mut(t).enumerate() {
                let i = task * ROWS_PER_TASK + r;
                // stable_softmax: exp(x - max) / sum exp(x - max).
                let logit = |k: usize| logits_token_major[k * m + i];
                let max = (0..t).map(logit).fold(f32::NEG_INFINITY, f32::max);
                for (k, wk) in w.iter_mut().enumerate() {
                    *wk = (logit(k) - max).exp();
                }
                let sum: f32 = w.iter().sum();
                for wk in w.iter_mut() {
                    *wk /= sum;
                }
                // rescale_c0_weight: w_0' = s w_0 / (s w_0 + 1 - w_0), w_n' = w_n / (...).
                if let Some(scale) = c0_weight_scale {
                    let w0 = w[0].clamp(0.0, 1.0);
                    let scaled = w0 * scale;
                    let denominator = scaled + (1.0 - w0);
                    w[0] = scaled / denominator;
                    for wk in w[1..].iter_mut() {
                        *wk /= denominator;
                    }
                }
                // mix: c = w_0 c0 + sum_n w_n c_n; IBR-only: sum_n v_n c_n / sum_n v_n with
                // v_n = w_n + IBR_ONLY_FLOOR.
                let mut c = [0.0f32; 3];
                let mut ibr_sum = [0.0f32; 3];
                let mut ibr_total = 0.0f32;
                for (ch, x) in c.iter_mut().enumerate() {
                    *x = c0[i * 3 + ch] * w[0];
                }
                for view in 0..n {
                    let cn = &source_colours[(view * m + i) * 3..(view * m + i) * 3 + 3];
                    let v = w[view + 1] + IBR_ONLY_FLOOR;
                    for ch in 0..3 {
                        c[ch] += cn[ch] * w[view + 1];
                        ibr_sum[ch] += cn[ch] * v;
                    }
                    ibr_total += v;
                }
                colour[r * 3..r * 3 + 3].copy_from_slice(&c);
                for ch in 0..3 {
                    ibr[r * 3 + ch] = ibr_sum[ch] / ibr_total;
                }
            }
        });
    Ok(out)
}
