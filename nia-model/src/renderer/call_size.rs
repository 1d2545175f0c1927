//! How many rays an image render sends through the network per call, when the user does not
//! say (`nia-infer --chunk`).
//!
//! Every call costs a fixed toll besides its arithmetic. On the CPU backends that is the
//! host's point inputs and the host MLPs split into rayon tasks (threads woken and joined per
//! pass), tensor allocations and the read-backs; with early termination a call covers one of
//! [`TERMINATION_SEGMENTS`] depth segments, so 1024 rays of 32 samples left a few hundred to a
//! thousand points a call after skipping. There a chunk of up to [`CPU_POINTS_PER_CALL`]
//! points, at most [`CPU_MAX_RAYS_PER_CALL`] rays, rendered the main command's images in
//! 0.79-0.84x the time of 1024 rays, the same PNGs to every byte, and evaluated a held-out set
//! in 0.80x (docs/speed.md, "Larger calls on the CPU"). Without termination a call holds every sample of its rays, and the floor of
//! [`MIN_RAYS_PER_CALL`] rays keeps the worst case of before, 1024 rays x 64 samples.
//!
//! On a GPU a call also costs kernel launches, burn's work on the host and, with termination,
//! a read-back of the densities after each depth segment (a device synchronisation). With
//! 1024 rays of 64 samples, a segment after empty-space skipping holds a few thousand points,
//! far too few to fill a GPU, and a 512x512 image paid that toll in 30 calls of 8 segments each
//! (docs/speed.md, "The second device run"). So on a GPU the chunk grows until a call's worst
//! case reaches [`GPU_POINTS_PER_CALL`] points, the worst case of 1024 rays x 64 samples
//! without termination, which the paper setting's bench forward runs: 8192 rays of 64 samples
//! with termination make 65,536 points at most (before skipping, which typically leaves a
//! fifth).
//!
//! Either way the memory of a call stays within the worst case of 1024 rays x 64 samples
//! without termination; only the per-ray tensors of sampling and compositing (`[R * S, K]`,
//! a few MB) grow with the chunk.

use burn::tensor::Device;

use crate::device::computes_on_cpu;
use crate::render_options::RenderOptions;
use crate::renderer::termination::TERMINATION_SEGMENTS;

/// The fewest rays per call, on every backend (without termination: a call of 1024 rays x
/// 64 samples, the worst case that bounds a call's memory).
pub const MIN_RAYS_PER_CALL: usize = 1024;

/// The most points one network call of a CPU render may get (module docs).
pub const CPU_POINTS_PER_CALL: usize = 16_384;

/// The most rays per call on the CPU backends.
pub const CPU_MAX_RAYS_PER_CALL: usize = 4096;

/// The largest number of points one network call of a GPU render may get (before
/// shape-bucket padding, which leaves a power of two such as this one unchanged).
pub const GPU_POINTS_PER_CALL: usize = 65_536;

/// The most rays per call on a GPU (bounds the per-sample tensors of compositing).
pub const GPU_MAX_RAYS_PER_CALL: usize = 16_384;

/// Rays per network call for rendering with `samples` samples per ray and `options` on
/// `device` (module docs): as many as keep a call's points within [`CPU_POINTS_PER_CALL`]
/// (CPU backends) or [`GPU_POINTS_PER_CALL`] (GPU backends), at least [`MIN_RAYS_PER_CALL`]
/// and at most [`CPU_MAX_RAYS_PER_CALL`] or [`GPU_MAX_RAYS_PER_CALL`].
pub fn rays_per_call(device: &Device, samples: usize, options: &RenderOptions) -> usize {
    let terminates = options.termination().is_some();
    match computes_on_cpu(device) {
        true => cpu_rays_per_call(samples, terminates),
        false => gpu_rays_per_call(samples, terminates),
    }
}

/// [`rays_per_call`] on the CPU backends: `samples` per ray, evaluated in
/// [`TERMINATION_SEGMENTS`] depth segments when `terminates`.
pub fn cpu_rays_per_call(samples: usize, terminates: bool) -> usize {
    rays_within(
        CPU_POINTS_PER_CALL,
        CPU_MAX_RAYS_PER_CALL,
        samples,
        terminates,
    )
}

/// [`rays_per_call`] on a GPU: `samples` per ray, evaluated in [`TERMINATION_SEGMENTS`]
/// depth segments when `terminates`.
pub fn gpu_rays_per_call(samples: usize, terminates: bool) -> usize {
    rays_within(
        GPU_POINTS_PER_CALL,
        GPU_MAX_RAYS_PER_CALL,
        samples,
        terminates,
    )
}

/// Rays whose points in one call (a depth segment's with termination, all samples without)
/// stay within `points`, clamped to `[MIN_RAYS_PER_CALL, max_rays]`.
fn rays_within(points: usize, max_rays: usize, samples: usize, terminates: bool) -> usize {
    let points_per_ray = if terminates {
        samples.div_ceil(TERMINATION_SEGMENTS)
    } else {
        samples
    };
    (points / points_per_ray.max(1)).clamp(MIN_RAYS_PER_CALL, max_rays)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gpu_call_of_the_paper_setting_holds_at_most_65536_points() {
        // 64 samples in 8 segments of 8 bins: 8192 rays, 65,536 points a call.
        assert_eq!(gpu_rays_per_call(64, true), 8192);
        assert_eq!(
            8192 * 64usize.div_ceil(TERMINATION_SEGMENTS),
            GPU_POINTS_PER_CALL
        );
        // Without termination every sample of a ray is in the one call: 1024 rays.
        assert_eq!(gpu_rays_per_call(64, false), 1024);
        // The quickstart's 32 samples: 4 bins a segment, capped at 16,384 rays.
        assert_eq!(gpu_rays_per_call(32, true), 16_384);
        // 12 samples do not split evenly: 2 bins in the widest segment.
        assert_eq!(gpu_rays_per_call(12, true), 16_384);
        assert_eq!(gpu_rays_per_call(100, true), 65_536 / 13);
        // Never below the CPU's chunk, never above the cap.
        assert_eq!(gpu_rays_per_call(256, false), MIN_RAYS_PER_CALL);
        assert_eq!(gpu_rays_per_call(0, false), GPU_MAX_RAYS_PER_CALL);
    }

    #[test]
    fn a_cpu_call_holds_at_most_16384_points_with_termination() {
        // The quickstart's 32 samples in 8 segments of 4 bins: 4096 rays.
        assert_eq!(cpu_rays_per_call(32, true), 4096);
        assert_eq!(
            4096 * 32usize.div_ceil(TERMINATION_SEGMENTS),
            CPU_POINTS_PER_CALL
        );
        // The paper's 64: 2048 rays of 8 bins.
        assert_eq!(cpu_rays_per_call(64, true), 2048);
        // Without termination the floor: 1024 rays x 64 samples as before.
        assert_eq!(cpu_rays_per_call(64, false), MIN_RAYS_PER_CALL);
        assert_eq!(cpu_rays_per_call(32, false), MIN_RAYS_PER_CALL);
        assert_eq!(cpu_rays_per_call(0, true), CPU_MAX_RAYS_PER_CALL);
        #[allow(deprecated)]
        let ndarray = Device::ndarray();
        assert_eq!(rays_per_call(&ndarray, 32, &RenderOptions::default()), 4096);
        assert_eq!(
            rays_per_call(&ndarray, 64, &RenderOptions::exhaustive()),
            MIN_RAYS_PER_CALL
        );
    }
}
