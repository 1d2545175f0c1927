//! Shape buckets for the GPU backends (inference): the network calls of a render get point
//! counts from a short fixed list instead of whatever skipping, termination and culling leave.
//!
//! On wgpu every new tensor shape can compile and autotune its kernels once, and a render's
//! calls each leave another number of points after empty-space skipping and the front-to-back
//! walk, so a first image paid for compilation call after call (docs/speed.md, "On a GPU").
//! Padded to a bucket (the last point repeated, its outputs dropped), the calls of every image
//! reuse a few shapes. On the CPU backends nothing compiles, so nothing is padded.

use crate::device::computes_on_cpu;
use crate::field::PointOutput;
use burn::tensor::Device;

/// The smallest bucket: every call of fewer points is padded to it.
///
/// Below it a call is bound by launches, not by the GPU's width (an H100 keeps about 270,000
/// threads in flight; 8,192 points of 64 channels are half a million values), so the padding
/// should cost a GPU little (reasoning; a device run is to measure it). What it saves is
/// compilation: cubecl autotunes a matrix product once per power of two of its rows, so the
/// network's layers in calls of 256 to 65,536 points met nine octaves of keys, now four. On
/// lavapipe a first render of three views in a fresh process tuned 38 matrix-product keys
/// instead of 68 (664 candidate kernels instead of 1,282; docs/speed.md, "A floor under the
/// buckets").
pub const MIN_BUCKET: usize = 8192;

/// The smallest `m * 2^k >= n` with `m` in 4..=7 (so at most 25 % padding), at least
/// [`MIN_BUCKET`]. `bucket_len(0) == 0`.
pub fn bucket_len(n: usize) -> usize {
    if n == 0 {
        return 0;
    }
    let n = n.max(MIN_BUCKET);
    // n >= MIN_BUCKET >= 4, so k = floor(log2 n) - 2 >= 0.
    let k = usize::BITS - 1 - n.leading_zeros() - 2;
    let step = 1usize << k;
    n.div_ceil(step) * step
}

/// Whether renders on `device` pad their network calls to buckets (the GPU backends, with or
/// without autodiff).
pub fn pads_to_buckets(device: &Device) -> bool {
    !computes_on_cpu(device)
}

/// How a network call lays out its points: one row per point, or padded to their bucket.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CallRows {
    /// One row per point (the CPU backends).
    Exact,
    /// [`bucket_len`] rows, the points first and the last one repeated (the GPU backends).
    Bucket,
}

impl CallRows {
    /// The layout of renders on `device`: [`Self::Bucket`] where they pad to buckets
    /// ([`pads_to_buckets`]).
    pub fn on(device: &Device) -> Self {
        if pads_to_buckets(device) {
            CallRows::Bucket
        } else {
            CallRows::Exact
        }
    }

    /// The rows of a call of `n` points.
    pub fn of(self, n: usize) -> usize {
        match self {
            CallRows::Exact => n,
            CallRows::Bucket => bucket_len(n),
        }
    }
}

/// `items` followed by copies of its last element up to `len` items (`items` unchanged when
/// empty or already that long).
pub fn pad_to<T: Copy>(items: &[T], len: usize) -> Vec<T> {
    let mut out = items.to_vec();
    if let Some(&last) = items.last() {
        out.resize(len.max(items.len()), last);
    }
    out
}

impl PointOutput {
    /// The first `len` points' outputs (the rest were padding).
    pub fn first(self, len: usize) -> PointOutput {
        PointOutput {
            sigma: self.sigma.narrow(0, 0, len),
            colour: self.colour.narrow(0, 0, len),
            c0: self.c0.narrow(0, 0, len),
            blend_c0: self.blend_c0.map(|b| b.narrow(0, 0, len)),
            blend_weights: self.blend_weights.narrow(0, 0, len),
            ibr_colour: self.ibr_colour.narrow(0, 0, len),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_cover_with_at_most_a_quarter_of_padding() {
        assert_eq!(bucket_len(0), 0);
        assert_eq!(bucket_len(1), MIN_BUCKET);
        assert_eq!(bucket_len(8192), 8192);
        assert_eq!(bucket_len(8193), 10240);
        assert_eq!(bucket_len(60_000), 65536);
        assert_eq!(bucket_len(65537), 81920);
        let mut buckets = std::collections::BTreeSet::new();
        for n in 1..100_000 {
            let b = bucket_len(n);
            assert!(b >= n && b >= MIN_BUCKET, "{n} -> {b}");
            assert!(
                n < MIN_BUCKET || b * 4 <= n * 5,
                "{n} -> {b}: over 25 % padding"
            );
            buckets.insert(b);
        }
        // The floor, then four per octave: 16 shapes for any count up to 100,000.
        assert_eq!(buckets.len(), 16, "{buckets:?}");
    }

    #[test]
    fn padding_repeats_the_last_item() {
        assert_eq!(pad_to(&[1, 2, 3], 5), vec![1, 2, 3, 3, 3]);
        assert_eq!(pad_to(&[1, 2, 3], 2), vec![1, 2, 3]);
        assert!(pad_to::<i32>(&[], 4).is_empty());
    }
}
