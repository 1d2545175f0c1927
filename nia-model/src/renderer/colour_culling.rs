//! Colour culling (adaptive work, inference only): a sample whose volume-rendering weight is
//! too small to change its ray's colour gets no colour evaluation.
//!
//! The colour half of the network (source colours, F_c0 and F_B: about two thirds of the
//! arithmetic per point at the paper's widths) only matters through `w_i c_i`, with
//! `w_i = T_i (1 - exp(-sigma_i delta_i))`. The density half runs first
//! ([`crate::NiaModel::query_density`]); then, front to back along each ray, a sample is culled
//! while the weights the ray has culled so far plus its own stay within the budget `epsilon`.
//! A culled sample keeps its density (opacity and depth are exact) and gets colour, c0, IBR
//! colour and blend weights zero, so the rendered colour, the composites and the blend maps
//! change by at most `epsilon` per ray (colours lie in [0, 1]). Samples in front of the surface
//! (faint density, tiny weight) and behind it (tiny transmittance) are what gets culled; the
//! few samples at the surface carry the weight and get their colour.

/// The front-to-back walk over one batch of samples: which get a colour evaluation.
///
/// `rays[k]` is sample k's ray, `steps[k] = sigma_k delta_k`; samples of one ray come in
/// front-to-back order (other rays' samples may come between them). `tau[ray]` is the optical
/// depth in front of the batch and `spent[ray]` the weight culled so far; both are updated.
/// Returns, per sample, whether its colour is evaluated (every sample for `epsilon = -inf`).
/// A non-finite step makes the sample opaque (it takes the ray's whole remaining transmittance
/// as weight).
pub fn cull(
    rays: &[usize],
    steps: &[f32],
    tau: &mut [f32],
    spent: &mut [f32],
    epsilon: f32,
) -> Vec<bool> {
    rays.iter()
        .zip(steps)
        .map(|(&ray, &step)| {
            let transmittance = (-tau[ray]).exp();
            let (alpha, step) = if step.is_finite() && step >= 0.0 {
                (1.0 - (-step).exp(), step)
            } else {
                (1.0, f32::INFINITY)
            };
            let weight = transmittance * alpha;
            tau[ray] += step;
            if spent[ray] + weight <= epsilon {
                spent[ray] += weight;
                false
            } else {
                true
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn culls_faint_samples_until_the_budget_is_spent_and_keeps_the_surface() {
        // One ray: three faint samples, an opaque one, two behind it.
        let rays = [0; 6];
        let steps = [1e-4, 2e-4, 3e-4, 50.0, 1.0, 1.0];
        let (mut tau, mut spent) = (vec![0.0], vec![0.0]);
        let evaluate = cull(&rays, &steps, &mut tau, &mut spent, 1e-3);
        // 1e-4 + 2e-4 + 3e-4 (about, times transmittance ~1) = 6e-4 <= 1e-3: culled; the surface
        // sample has weight ~1: evaluated; behind it the transmittance is e^-50: culled.
        assert_eq!(evaluate, [false, false, false, true, false, false]);
        assert!(spent[0] <= 1e-3 && spent[0] > 5.9e-4, "{}", spent[0]);
        assert!((tau[0] - (6e-4 + 52.0)).abs() < 1e-3);
    }

    #[test]
    fn the_budget_is_never_exceeded_and_zero_culls_only_weightless_samples() {
        let rays = [0, 1, 0, 1, 0, 1];
        let steps = [4e-4, 0.0, 4e-4, 0.0, 4e-4, 3.0];
        let (mut tau, mut spent) = (vec![0.0; 2], vec![0.0; 2]);
        let evaluate = cull(&rays, &steps, &mut tau, &mut spent, 1e-3);
        // Ray 0: 4e-4, 8e-4 culled, the third would pass 1e-3: evaluated.
        assert_eq!(evaluate, [false, false, false, false, true, true]);
        assert!(spent.iter().all(|&s| s <= 1e-3));
        let (mut tau, mut spent) = (vec![0.0; 2], vec![0.0; 2]);
        let evaluate = cull(&rays, &steps, &mut tau, &mut spent, 0.0);
        // Zero density weighs nothing and stays culled; everything else is evaluated.
        assert_eq!(evaluate, [true, false, true, false, true, true]);
    }

    #[test]
    fn non_finite_densities_are_opaque_and_stay_finite() {
        let rays = [0, 0, 0];
        let steps = [f32::NAN, 1.0, f32::INFINITY];
        let (mut tau, mut spent) = (vec![0.0], vec![0.0]);
        let evaluate = cull(&rays, &steps, &mut tau, &mut spent, 1e-3);
        // The NaN sample takes the whole transmittance (evaluated); nothing is left behind it.
        assert_eq!(evaluate, [true, false, false]);
        assert!(spent[0].is_finite() && spent[0] == 0.0);
    }
}
