//! Output buffers for the host kernels.
//!
//! `vec![0.0; n]` zeroes on the calling thread. The host kernels fill their outputs on rayon's
//! threads, so that zeroing was a serial stretch before every parallel one: with the heap
//! keeping freed memory (`nia_infer::heap`), a reused block is zeroed by `memset`, and in a
//! paper-size render that was most of what the render thread did while the workers waited
//! (docs/speed.md, "Readbacks without copies and buffers zeroed in parallel").

use rayon::prelude::*;

/// Below this many values the buffer is zeroed on the calling thread.
const PARALLEL_FROM: usize = 1 << 16;

/// `len` zeros, written on rayon's threads when `len` is large.
pub fn zeroed(len: usize) -> Vec<f32> {
    if len < PARALLEL_FROM {
        return vec![0.0; len];
    }
    let mut values = Vec::with_capacity(len);
    values.par_extend(rayon::iter::repeat_n(0.0f32, len));
    values
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_of_every_size_are_all_zeros() {
        for len in [
            0,
            1,
            17,
            PARALLEL_FROM - 1,
            PARALLEL_FROM,
            3 * PARALLEL_FROM + 5,
        ] {
            let v = zeroed(len);
            assert_eq!(v.len(), len);
            assert!(v.iter().all(|&x| x == 0.0 && x.is_sign_positive()));
        }
    }
}
