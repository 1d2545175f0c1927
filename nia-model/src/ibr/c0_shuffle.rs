//! c0 shuffling, a training augmentation of the blend (switchable, `train.c0_shuffle`; not in
//! the paper).
//!
//! F_B learns how far to trust the NeRF colour c0 on the training people, where F_c0 has
//! memorised their appearance: after 1000 quickstart steps c0 alone scores 24.0 dB on the
//! training people (unseen poses) and 19.8 dB on the unseen one, and F_B gives c0 a quarter of
//! the blend on both; after 2000 steps c0's share grows to 0.38 and the blend falls further
//! below the source views alone on unseen people. With shuffling, a `fraction` of the training
//! points blend the c0 of another point of the same batch (another place on the same person,
//! detached), a plausible colour that is wrong there, as c0 is on a person F_c0 has not seen.
//! F_B, which sees c0 next to the source colours and their across-view statistics, then learns
//! to tell a c0 that agrees with the views from one that does not. F_c0 itself is still
//! trained on the true c0 (the NeRF-only loss), and inference never shuffles. Only the
//! variants with F_B shuffle (`Variant::uses_blender`): (b) shows c0 as it is, and (c) and (d)
//! mix it by fixed rules, where a shuffled c0 would only be noise in the trained colour.
//!
//! With `seen_only`, only points that some source view sees (max_n o_n > 1/2) are shuffled: a
//! point no view sees keeps its true c0, the one colour it has, so F_B learns to hand such
//! points to c0 (the paper's "c0 takes over where no source sees") however strongly the seen
//! points are shuffled.
//!
//! With `noise_std`, the seen points' c0 in the blend also gets Gaussian noise of that standard
//! deviation per channel (detached, drawn per point): on the training people F_c0's c0 is as
//! good as the source views (NeRF-only within 0.25 dB of IBR-only at every checkpoint of a 4x
//! run), on new people 2.2-2.4 dB worse, and F_B, trained longer, learns the trust that fits
//! the first (docs/robustness.md, "Training longer makes it worse"). The noise makes the c0
//! it learns on less exact, nearer the one it will meet; at sigma 0.2 c0's share of the blend
//! halves and the blend no longer needs c0's odds rescaled on the report sets (docs/blend.md).
//!
//! That memorisation is what F_B learns its trust from is doubtful: trained only on a person
//! F_c0 never fitted, F_B gives c0 as large a share (docs/robustness.md, "What teaches F_B to
//! hedge"). Shuffling stays for what it measured (docs/results.md, "The quickstart's switches").

use burn::prelude::*;
use nia_data::rng::Rng;

/// Which points blend another point's c0, and with which seed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct C0Shuffle {
    /// Fraction of points whose c0 in the blend comes from another point, in [0, 1].
    pub fraction: f32,
    /// Seed of the choice (the trainer derives it from the run's seed and the scene's index).
    pub seed: u64,
    /// Shuffle only points that some source view sees (module docs).
    pub seen_only: bool,
    /// Standard deviation of the Gaussian noise added to every shuffled-or-kept c0 that
    /// `seen_only` lets through (all points without it), per channel; 0: none (module docs).
    pub noise_std: f32,
}

/// Label of the noise stream forked from [`C0Shuffle::seed`], so the donors are the same with
/// or without noise.
const NOISE_STREAM: u64 = 0x006e_6f69_7365;

/// Visibility o_n above which a view counts as seeing a point ([`C0Shuffle::seen_only`]).
pub const SEEN_VISIBILITY: f32 = 0.5;

impl C0Shuffle {
    /// For M points: the point each one's blended c0 is read from (itself, or for about
    /// `fraction` of them a uniformly drawn point), and whether it was replaced.
    pub fn sources(&self, m: usize) -> (Vec<i64>, Vec<bool>) {
        let mut rng = Rng::new(self.seed);
        (0..m)
            .map(|i| {
                if m > 1 && rng.uniform() < self.fraction {
                    (rng.below(m) as i64, true)
                } else {
                    (i as i64, false)
                }
            })
            .unzip()
    }

    /// Noise of the first `points` of M rows, `[M * 3]` row-major, 0 on the padding rows.
    fn noise(&self, points: usize, m: usize) -> Vec<f32> {
        let mut rng = Rng::new(self.seed).fork(NOISE_STREAM);
        let mut out: Vec<f32> = (0..points * 3)
            .map(|_| self.noise_std * rng.normal())
            .collect();
        out.resize(m * 3, 0.0);
        out
    }

    /// The c0 that F_B blends: `c0` with the replaced rows taken from their source point,
    /// detached (no gradient reaches F_c0 through a shuffled colour), plus `noise_std`'s noise.
    /// With `seen_only`, rows whose `visibility` is at most [`SEEN_VISIBILITY`] in every view
    /// keep their own c0, without noise.
    /// Only the first `points` rows are points; rows from there on are shape-bucket padding
    /// (`renderer::shape_buckets`), which keep their own c0 and lend it to no point, so the
    /// points draw the same donors padded or not.
    ///
    /// # Shapes
    /// - `c0`: `[M, 3]`; `visibility` o_n: `[N, M]`; output `[M, 3]`
    pub fn apply(&self, c0: Tensor<2>, visibility: Tensor<2>, points: usize) -> Tensor<2> {
        let [m, _] = c0.dims();
        let device = c0.device();
        let points = points.min(m);
        // [N, M] -> [1, M] -> [M, 1]: 1 where some view sees the point.
        let seen = self.seen_only.then(|| {
            visibility
                .detach()
                .max_dim(0)
                .greater_elem(SEEN_VISIBILITY)
                .float()
                .reshape([m, 1])
        });
        // Noise alone (`fraction` 0) swaps nothing: no gather.
        let out = if self.fraction > 0.0 {
            let (mut sources, mut replaced) = self.sources(points);
            sources.extend(points as i64..m as i64);
            replaced.resize(m, false);
            let index = Tensor::<1, Int>::from_data(TensorData::new(sources, [m]), &device);
            let mask: Vec<f32> = replaced.iter().map(|&r| r as u8 as f32).collect();
            let mut mask = Tensor::<2>::from_data(TensorData::new(mask, [m, 1]), &device);
            if let Some(seen) = seen.clone() {
                mask = mask * seen;
            }
            let shuffled = c0.clone().detach().select(0, index);
            c0 * mask.clone().neg().add_scalar(1.0) + shuffled * mask
        } else {
            c0
        };
        if self.noise_std <= 0.0 {
            return out;
        }
        let noise = TensorData::new(self.noise(points, m), [m, 3]);
        let noise = Tensor::<2>::from_data(noise, &device);
        match seen {
            Some(seen) => out + noise * seen,
            None => out + noise,
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(deprecated)] // Device::ndarray(): the reference CPU backend.
    use super::*;

    #[test]
    fn a_fraction_of_the_points_blend_another_points_colour_and_the_rest_their_own() {
        let device = Device::ndarray();
        let m = 2000;
        let c0: Vec<f32> = (0..m * 3).map(|i| i as f32).collect();
        let c0 = Tensor::<2>::from_data(TensorData::new(c0, [m, 3]), &device);
        let shuffle = C0Shuffle {
            fraction: 0.25,
            seed: 3,
            seen_only: false,
            noise_std: 0.0,
        };
        let (sources, replaced) = shuffle.sources(m);
        let share = replaced.iter().filter(|&&r| r).count() as f32 / m as f32;
        assert!((share - 0.25).abs() < 0.04, "{share}");
        // Unseen by both views: without seen_only that does not matter.
        let visibility = Tensor::<2>::zeros([2, m], &device);
        let out = shuffle
            .apply(c0, visibility, m)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        for i in 0..m {
            let from = if replaced[i] { sources[i] as usize } else { i };
            assert_eq!(
                out[3 * i..3 * i + 3],
                [
                    3.0 * from as f32,
                    3.0 * from as f32 + 1.0,
                    3.0 * from as f32 + 2.0
                ]
            );
        }
        // Deterministic in the seed; none replaced at fraction 0, all at 1.
        assert_eq!(shuffle.sources(m), (sources, replaced));
        let none = C0Shuffle {
            fraction: 0.0,
            seed: 3,
            seen_only: false,
            noise_std: 0.0,
        }
        .sources(m)
        .1;
        assert!(none.iter().all(|&r| !r));
        let all = C0Shuffle {
            fraction: 1.0,
            seed: 3,
            seen_only: false,
            noise_std: 0.0,
        }
        .sources(m)
        .1;
        assert!(all.iter().all(|&r| r));
    }

    #[test]
    fn seen_only_shuffles_the_points_some_view_sees_and_keeps_the_rest() {
        let device = Device::ndarray();
        let m = 400;
        let c0: Vec<f32> = (0..m * 3).map(|i| i as f32).collect();
        let c0 = Tensor::<2>::from_data(TensorData::new(c0, [m, 3]), &device);
        // Two views. i % 3 == 0: view 0 sees the point (0.9); 1: view 1 does (0.6; view 0 is
        // at 0.5, which is not "seen"); 2: no view does (0.5 and 0).
        let mut o = vec![0.0f32; 2 * m];
        for i in 0..m {
            match i % 3 {
                0 => o[i] = 0.9,
                1 => {
                    o[m + i] = 0.6;
                    o[i] = 0.5;
                }
                _ => o[i] = 0.5,
            }
        }
        let visibility = Tensor::<2>::from_data(TensorData::new(o, [2, m]), &device);
        let shuffle = C0Shuffle {
            fraction: 1.0,
            seed: 11,
            seen_only: true,
            noise_std: 0.0,
        };
        let (sources, _) = shuffle.sources(m);
        let out = shuffle
            .apply(c0, visibility, m)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let mut moved = 0;
        for i in 0..m {
            let from = if i % 3 == 2 { i } else { sources[i] as usize };
            assert_eq!(out[3 * i], 3.0 * from as f32, "point {i}");
            moved += (from != i) as usize;
        }
        assert!(moved > m / 2, "{moved} of the {m} points moved");
    }

    #[test]
    fn padding_rows_keep_their_own_colour_and_the_points_draw_the_same_donors() {
        let device = Device::ndarray();
        let (m, padded) = (300, 384);
        // The padding repeats the last point, as renderer::shape_buckets pads.
        let rows: Vec<f32> = (0..padded * 3)
            .map(|i| (i / 3).min(m - 1) as f32 * 3.0 + (i % 3) as f32)
            .collect();
        let shuffle = C0Shuffle {
            fraction: 0.5,
            seed: 5,
            seen_only: false,
            noise_std: 0.0,
        };
        let values = |len: usize| rows[..len * 3].to_vec();
        let run = |rows: usize, points: usize| {
            let c0 = Tensor::<2>::from_data(TensorData::new(values(rows), [rows, 3]), &device);
            shuffle
                .apply(c0, Tensor::<2>::ones([2, rows], &device), points)
                .into_data()
                .try_to_vec::<f32>()
                .unwrap()
        };
        let plain = run(m, m);
        let with_padding = run(padded, m);
        assert_eq!(with_padding[..m * 3], plain[..]);
        // Every padding row keeps its own c0, the last point's.
        for i in m..padded {
            assert_eq!(with_padding[3 * i], 3.0 * (m - 1) as f32, "row {i}");
        }
        assert!(
            plain.iter().zip(&rows).any(|(a, b)| a != b),
            "nothing shuffled"
        );
    }

    #[test]
    fn noise_reaches_the_seen_points_alone_and_leaves_the_donors_as_they_were() {
        let device = Device::ndarray();
        let (m, padded) = (3000, 3072);
        let c0 = Tensor::<2>::full([padded, 3], 0.5, &device);
        // Even rows seen by view 0, odd rows by none.
        let o: Vec<f32> = (0..padded).map(|i| (i % 2 == 0) as u8 as f32).collect();
        let visibility = Tensor::<2>::from_data(TensorData::new(o, [1, padded]), &device);
        let noisy = C0Shuffle {
            fraction: 0.0,
            seed: 9,
            seen_only: true,
            noise_std: 0.1,
        };
        let out = noisy
            .apply(c0, visibility, m)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let mut offsets = Vec::new();
        for i in 0..padded {
            let row = &out[3 * i..3 * i + 3];
            if i % 2 == 1 || i >= m {
                assert_eq!(row, [0.5; 3], "row {i}: unseen or padding");
            } else {
                offsets.extend(row.iter().map(|v| v - 0.5));
            }
        }
        let n = offsets.len() as f32;
        let mean = offsets.iter().sum::<f32>() / n;
        let std = (offsets.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / n).sqrt();
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((std - 0.1).abs() < 0.01, "std {std}");
        // The noise has its own stream: the donors do not depend on it.
        let plain = C0Shuffle {
            noise_std: 0.0,
            fraction: 0.5,
            ..noisy
        };
        let with_noise = C0Shuffle {
            fraction: 0.5,
            ..noisy
        };
        assert_eq!(plain.sources(m), with_noise.sources(m));
    }
}
