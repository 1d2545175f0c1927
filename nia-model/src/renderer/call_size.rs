//! How an image render divides its rays into chunks, when the user does not say
//! (`nia-infer --chunk`), and how many points one network call may get.
//!
//! A chunk's rays are sampled, walked front to back and composited together; the network sees
//! a chunk's points in calls of at most [`MAX_POINTS_PER_CALL`] (one call per depth segment of
//! [`TERMINATION_SEGMENTS`] with early termination, one for the chunk without, each split in
//! several when it holds more). So a call's memory is bounded whatever the chunk, by the worst
//! case of 1024 rays x 64 samples that bounded it before; only the per-sample tensors of
//! sampling and compositing (`[R * S, K]`) grow with the chunk.
//!
//! Every call costs a fixed toll besides its arithmetic. On the CPU backends that is the
//! host's point inputs and the host MLPs split into rayon tasks (threads woken and joined per
//! pass), tensor allocations and the read-backs; with early termination a call covers one
//! depth segment, so 1024 rays of 32 samples left a few hundred to a thousand points a call
//! after skipping. There a chunk of up to [`CPU_POINTS_PER_CALL`] points a segment rendered the
//! main command's images in 0.79-0.84x the time of 1024 rays, the same PNGs to every byte, and
//! evaluated a held-out set in 0.80x (docs/speed.md, "Larger calls on the CPU"). The budget
//! counts every sample of a segment, where skipping keeps about a third, so a segment's calls
//! stay small at few samples per ray: the cap of [`CPU_MAX_RAYS_PER_CHUNK`] rays lets the
//! viewer's drag frames (8 samples) take 16,384 rays a chunk, 0.82x the time of 4096 with the
//! same PNG bytes (a 512x512 image of the tiny network). Without termination a chunk's samples are one
//! call, and the floor of [`MIN_RAYS_PER_CHUNK`] rays keeps the worst case of before, 1024
//! rays x 64 samples.
//!
//! On a GPU a call also costs kernel launches, burn's work on the host and, with termination,
//! a read-back of the densities after each depth segment (a device synchronisation). A chunk
//! of 8192 rays whose segments could each hold 65,536 points kept, after empty-space skipping
//! (which typically leaves a fifth) and termination, a few thousand to ten thousand points a
//! call: calls far from filling a GPU, and 8 read-backs per 8192 rays. So on a GPU a chunk is
//! [`GPU_SAMPLES_PER_CHUNK`] samples (65,536 rays of 64 samples, a 512x512 image's body in one
//! or two chunks), and the segments' points fill calls up to [`MAX_POINTS_PER_CALL`]
//! (docs/speed.md, "Chunks apart from calls").

use burn::tensor::Device;

use crate::device::computes_on_cpu;
use crate::render_options::RenderOptions;
use crate::renderer::termination::TERMINATION_SEGMENTS;

/// The most points one network call of a render gets, on every backend (the default of
/// `SceneEncoding::points_per_call`): a depth segment (or, without termination, a chunk) of
/// more points is evaluated in several calls, front to back. 1024 rays x 64 samples, the
/// paper setting's bench forward; a power of two, so a GPU's shape bucket leaves it unchanged.
pub const MAX_POINTS_PER_CALL: usize = 65_536;

/// The fewest rays per chunk, on every backend (without termination on the CPU: a call of
/// 1024 rays x 64 samples).
pub const MIN_RAYS_PER_CHUNK: usize = 1024;

/// The most points one depth segment of a CPU chunk may hold (module docs).
pub const CPU_POINTS_PER_CALL: usize = 16_384;

/// The most rays per chunk on the CPU backends (16,384 at 8 samples a ray, 4096 at 32).
pub const CPU_MAX_RAYS_PER_CHUNK: usize = 16_384;

/// The samples (rays x samples per ray) of a chunk on a GPU: bounds the per-sample tensors of
/// sampling and compositing (14 f32 columns of 2^22 rows, 235 MB, at the paper's 3 views).
pub const GPU_SAMPLES_PER_CHUNK: usize = 1 << 22;

/// The most rays per chunk on a GPU.
pub const GPU_MAX_RAYS_PER_CHUNK: usize = 65_536;

/// Rays per chunk for rendering with `samples` samples per ray and `options` on `device`
/// (module docs): on the CPU backends as many as keep a depth segment (all samples without
/// termination) within [`CPU_POINTS_PER_CALL`] points, between [`MIN_RAYS_PER_CHUNK`] and
/// [`CPU_MAX_RAYS_PER_CHUNK`]; on a GPU as many as make [`GPU_SAMPLES_PER_CHUNK`] samples, up
/// to [`GPU_MAX_RAYS_PER_CHUNK`].
pub fn rays_per_chunk(device: &Device, samples: usize, options: &RenderOptions) -> usize {
    match computes_on_cpu(device) {
        true => cpu_rays_per_chunk(samples, options.termination().is_some()),
        false => gpu_rays_per_chunk(samples),
    }
}

/// [`rays_per_chunk`] on the CPU backends: `samples` per ray, evaluated in
/// [`TERMINATION_SEGMENTS`] depth segments when `terminates`.
pub fn cpu_rays_per_chunk(samples: usize, terminates: bool) -> usize {
    let points_per_ray = if terminates {
        samples.div_ceil(TERMINATION_SEGMENTS)
    } else {
        samples
    };
    (CPU_POINTS_PER_CALL / points_per_ray.max(1)).clamp(MIN_RAYS_PER_CHUNK, CPU_MAX_RAYS_PER_CHUNK)
}

/// [`rays_per_chunk`] on a GPU: `samples` per ray, with or without termination (the calls
/// are bounded apart, [`MAX_POINTS_PER_CALL`]).
pub fn gpu_rays_per_chunk(samples: usize) -> usize {
    (GPU_SAMPLES_PER_CHUNK / samples.max(1)).clamp(MIN_RAYS_PER_CHUNK, GPU_MAX_RAYS_PER_CHUNK)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gpu_chunk_of_the_paper_setting_is_65536_rays() {
        // 64 samples: 2^22 / 64 rays, with or without termination.
        assert_eq!(gpu_rays_per_chunk(64), 65_536);
        assert_eq!(gpu_rays_per_chunk(64) * 64, GPU_SAMPLES_PER_CHUNK);
        // The quickstart's 32 samples: capped at 65,536 rays.
        assert_eq!(gpu_rays_per_chunk(32), GPU_MAX_RAYS_PER_CHUNK);
        assert_eq!(gpu_rays_per_chunk(128), 32_768);
        // Never below the floor, never above the cap.
        assert_eq!(gpu_rays_per_chunk(1 << 20), MIN_RAYS_PER_CHUNK);
        assert_eq!(gpu_rays_per_chunk(0), GPU_MAX_RAYS_PER_CHUNK);
        // The calls' bound is a power of two (a shape bucket of its own).
        assert!(MAX_POINTS_PER_CALL.is_power_of_two());
        assert_eq!(
            crate::renderer::shape_buckets::bucket_len(MAX_POINTS_PER_CALL),
            MAX_POINTS_PER_CALL
        );
    }

    #[test]
    fn a_cpu_segment_holds_at_most_16384_points_with_termination() {
        // The quickstart's 32 samples in 8 segments of 4 bins: 4096 rays.
        assert_eq!(cpu_rays_per_chunk(32, true), 4096);
        assert_eq!(
            4096 * 32usize.div_ceil(TERMINATION_SEGMENTS),
            CPU_POINTS_PER_CALL
        );
        // The paper's 64: 2048 rays of 8 bins.
        assert_eq!(cpu_rays_per_chunk(64, true), 2048);
        // 12 samples do not split evenly: 2 bins in the widest segment.
        assert_eq!(cpu_rays_per_chunk(12, true), 8192);
        // The viewer's drag frames, 8 samples: one bin a segment, the cap.
        assert_eq!(cpu_rays_per_chunk(8, true), CPU_MAX_RAYS_PER_CHUNK);
        assert_eq!(cpu_rays_per_chunk(8, true), CPU_POINTS_PER_CALL);
        // Without termination the floor: 1024 rays x 64 samples, one call as before.
        assert_eq!(cpu_rays_per_chunk(64, false), MIN_RAYS_PER_CHUNK);
        assert_eq!(MIN_RAYS_PER_CHUNK * 64, MAX_POINTS_PER_CALL);
        assert_eq!(cpu_rays_per_chunk(32, false), MIN_RAYS_PER_CHUNK);
        assert_eq!(cpu_rays_per_chunk(0, true), CPU_MAX_RAYS_PER_CHUNK);
        #[allow(deprecated)]
        let ndarray = Device::ndarray();
        assert_eq!(
            rays_per_chunk(&ndarray, 32, &RenderOptions::default()),
            4096
        );
        assert_eq!(
            rays_per_chunk(&ndarray, 64, &RenderOptions::exhaustive()),
            MIN_RAYS_PER_CHUNK
        );
    }
}
