//! c0's weight in the blend rescaled at inference (switchable, `[render] c0_weight_scale`; not
//! in the paper).
//!
//! F_B learns on the training people how far to trust the NeRF colour c0 against the source
//! colours. A model trained on a real capture's flaws learns to give c0 about a third of the
//! blend where a source sees the point (0.33-0.42 on the quickstart's people), and on people
//! it has not seen that is too much: c0 is darker and blurrier than the source colours there
//! (18 % under the true brightness on the clean seed-21 set, where the source-only composite is
//! 1 % under), and the source-only composite beats the blend by 0.1-0.6 dB. Showing F_B a
//! wrong c0 on every seen training point (`train.c0_shuffle = 1`) lowers the share only to
//! 0.33; training without the SMPL jitter leaves it at 0.36, without the cameras' colour
//! responses at 0.40. No single flaw of the training data teaches the hedge, and about half of
//! it is the training recipe's (the colour-gain loss and the SMPL jitter; docs/robustness.md,
//! "c0's share of the blend" and "What teaches F_B to hedge"). Noise on the c0 that F_B blends
//! in training (`train.c0_noise_std`, `crate::ibr::c0_shuffle`) lowers the share to 0.21-0.27
//! and makes the rescale unneeded; the quickstart trains with it and renders at `s = 1`. The
//! rescale stays for models trained without it.
//!
//! The rescaling is F_B's own blend with the prior odds of c0 changed: every point's weights
//! `w` over `[c0, c_1..c_N]` become
//!
//! ```text
//! w_0' = s w_0 / (s w_0 + 1 - w_0),    w_n' = w_n / (s w_0 + 1 - w_0)
//! ```
//!
//! the softmax of F_B's logits with `ln s` added to c0's. F_B's ranking of the source views is
//! kept, and a point that no view sees (`w_0` near 1) keeps most of its c0. `s = 1` is the
//! paper's blend; training never rescales.

use burn::prelude::*;

use crate::shape::ShapeError;

/// Smallest accepted [`rescale_c0_weight`] scale: below it c0 would vanish even where no view
/// sees a point (a point with `w_0 = 0.999` keeps 0.5 at `1e-3`).
pub const MIN_C0_WEIGHT_SCALE: f32 = 1e-3;
/// Largest accepted scale.
pub const MAX_C0_WEIGHT_SCALE: f32 = 1e3;

/// Refuses a scale outside `[MIN_C0_WEIGHT_SCALE, MAX_C0_WEIGHT_SCALE]` (NaN too).
pub(crate) fn check_c0_weight_scale(scale: f32) -> Result<(), ShapeError> {
    match (MIN_C0_WEIGHT_SCALE..=MAX_C0_WEIGHT_SCALE).contains(&scale) {
        true => Ok(()),
        false => Err(ShapeError::value(
            "c0 weight rescaling `scale`",
            format!("{MIN_C0_WEIGHT_SCALE} to {MAX_C0_WEIGHT_SCALE}, got {scale}"),
        )),
    }
}

/// The blend weights with c0's odds multiplied by `scale` (module docs); rows still sum to 1.
/// `scale` must lie in `[MIN_C0_WEIGHT_SCALE, MAX_C0_WEIGHT_SCALE]` (else an error; NaN too);
/// the denominator is then at least `min(scale, 1)` for weights in `[0, 1]`, so no row divides
/// by zero.
///
/// # Shapes
/// - `blend_weights`: `[M, N + 1]` (index 0 = c0), rows summing to 1
/// - output: `[M, N + 1]`
pub fn rescale_c0_weight(blend_weights: Tensor<2>, scale: f32) -> Result<Tensor<2>, ShapeError> {
    let [m, k] = blend_weights.dims();
    if k < 2 {
        return Err(ShapeError::Mismatch {
            input: "c0 weight rescaling `blend_weights` [M, N + 1]".into(),
            expected: "[_, >= 2]".into(),
            got: vec![m, k],
        });
    }
    check_c0_weight_scale(scale)?;
    // Weights a softmax made lie in [0, 1]; clamping keeps a rounding excursion from turning
    // the denominator's `1 - w_0` negative.
    let w0 = blend_weights.clone().slice([0..m, 0..1]).clamp(0.0, 1.0); // [M, 1]
    let sources = blend_weights.slice([0..m, 1..k]); // [M, N]
    let scaled = w0.clone().mul_scalar(scale);
    let denominator = scaled.clone() + w0.neg().add_scalar(1.0); // [M, 1], >= min(scale, 1)
    Ok(Tensor::cat(vec![scaled, sources], 1) / denominator)
}
