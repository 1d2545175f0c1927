//! How many rays an image render sends through the network per call, when the user does not
//! say (`nia-infer --chunk`).
//!
//! On the CPU backends a call's cost is its arithmetic, and 1024 rays keep the working set
//! small ([`CPU_RAYS_PER_CALL`]). On a GPU a call also costs a fixed toll: every tensor
//! operation is a kernel launch and burn's work on the host, and early termination reads the
//! densities back after each of its depth segments (a device synchronisation). With 1024 rays
//! of 64 samples, a segment after empty-space skipping holds a few thousand points, far too
//! few to fill a GPU, and a 512x512 image paid that toll in 30 calls of 8 segments each
//! (docs/speed.md, "The second device run").
//!
//! So on a GPU the chunk grows until a call's worst case reaches [`GPU_POINTS_PER_CALL`]
//! points, the worst case of 1024 rays x 64 samples without termination, which the paper
//! setting's bench forward runs: with termination a network call covers one depth segment,
//! `ceil(S / TERMINATION_SEGMENTS)` bins of each ray, so 8192 rays of 64 samples make
//! 65,536 points at most (before skipping, which typically leaves a fifth). The memory of a
//! call is therefore bounded as before; only the per-ray tensors of sampling and compositing
//! (`[R * S, K]`, a few MB) grow with the chunk.

use burn::tensor::Device;

use crate::device::computes_on_cpu;
use crate::render_options::RenderOptions;
use crate::renderer::termination::TERMINATION_SEGMENTS;

/// Rays per call on the CPU backends.
pub const CPU_RAYS_PER_CALL: usize = 1024;

/// The largest number of points one network call of a GPU render may get (before
/// shape-bucket padding, which leaves a power of two such as this one unchanged).
pub const GPU_POINTS_PER_CALL: usize = 65_536;

/// The most rays per call on a GPU (bounds the per-sample tensors of compositing).
pub const GPU_MAX_RAYS_PER_CALL: usize = 16_384;

/// Rays per network call for rendering with `samples` samples per ray and `options` on
/// `device` (module docs): [`CPU_RAYS_PER_CALL`] on the CPU backends; on the GPU backends
/// as many as keep a call's points within [`GPU_POINTS_PER_CALL`], between
/// [`CPU_RAYS_PER_CALL`] and [`GPU_MAX_RAYS_PER_CALL`].
pub fn rays_per_call(device: &Device, samples: usize, options: &RenderOptions) -> usize {
    rays_per_call_or(device, samples, options, CPU_RAYS_PER_CALL)
}

/// [`rays_per_call`] with `cpu` rays per call on the CPU backends (training validates in
/// chunks of its rays per step there).
pub fn rays_per_call_or(
    device: &Device,
    samples: usize,
    options: &RenderOptions,
    cpu: usize,
) -> usize {
    if computes_on_cpu(device) {
        return cpu;
    }
    gpu_rays_per_call(samples, options.termination().is_some())
}

/// [`rays_per_call`] on a GPU: `samples` per ray, evaluated in [`TERMINATION_SEGMENTS`]
/// depth segments when `terminates`.
pub fn gpu_rays_per_call(samples: usize, terminates: bool) -> usize {
    let points_per_ray = if terminates {
        samples.div_ceil(TERMINATION_SEGMENTS)
    } else {
        samples
    };
    (GPU_POINTS_PER_CALL / points_per_ray.max(1)).clamp(CPU_RAYS_PER_CALL, GPU_MAX_RAYS_PER_CALL)
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
        assert_eq!(gpu_rays_per_call(256, false), CPU_RAYS_PER_CALL);
        assert_eq!(gpu_rays_per_call(0, false), GPU_MAX_RAYS_PER_CALL);
    }

    #[test]
    fn the_cpu_backends_keep_1024_rays() {
        #[allow(deprecated)]
        let ndarray = Device::ndarray();
        assert_eq!(
            rays_per_call(&ndarray, 64, &RenderOptions::default()),
            CPU_RAYS_PER_CALL
        );
        assert_eq!(
            rays_per_call(&ndarray, 64, &RenderOptions::exhaustive()),
            CPU_RAYS_PER_CALL
        );
    }
}
