//! The ray sampler, first stage of the forward pass: stratified samples along each ray, and
//! the adaptive part that decides which of them the field evaluates.
//!
//! Stratified sampling (NeRF): S equal bins over `[near, far]` per ray, one sample per bin,
//! jittered in training and at the bin centre otherwise ([`stratified_t`]).
//!
//! Band sampling (switchable, `ModelConfig::band_sampling`; not in the paper): the S bins cover
//! only the part of `[near, far]` that lies in the occupancy band of the posed SMPL mesh (within
//! `band_margin_m` of its surface, or inside it), the space where the body can be. The quadrature
//! interval of each sample is its bin's length inside the band ([`RaySamples::delta`]), so the
//! rendered weights are the same integral over the band that stratified sampling approximates
//! over the whole ray when the density outside the band is zero, with S samples where the body is
//! instead of the few of S that land there otherwise. A ray that misses the band gets no
//! evaluated samples (background).
//!
//! Empty-space skipping (`RenderOptions::skip_empty_space`, on by default): samples farther
//! than `empty_space_m` from the posed body's surface (and not inside it) are not evaluated;
//! they keep zero density. The occupancy grid is built from the posed mesh once per frame and
//! pose (`RenderOptions::occupancy`); [`RaySamples::new`] keeps the samples in occupied cells.

mod band_march;
mod ray_sampler;

pub use ray_sampler::{RaySampler, DEFAULT_BAND_MARGIN_M};

use band_march::{band_segments, BandBuffers};

use glam::Vec3;
use nia_data::geometry::occupancy::OccupancyGrid;
use nia_data::geometry::rays::RayBundle;
use rayon::prelude::*;

/// Errors of the sampler, naming the argument.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SamplerError {
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
) -> Result<Vec<f32>, SamplerError> {
    check_sampler_inputs(near, far, samples, jitter)?;
    let mut t = Vec::with_capacity(near.len() * samples);
    for (ray, (&near, &far)) in near.iter().zip(far).enumerate() {
        let bin = (far - near) / samples as f32;
        for i in 0..samples {
            let u = jitter.map_or(0.5, |j| j[ray * samples + i]);
            // min(): rounding must not put a sample past `far` (the last delta would go < 0).
            t.push((near + (i as f32 + u) * bin).min(far));
        }
    }
    Ok(t)
}

/// The checks both samplers make: S >= 1, `far` and `jitter` of the right lengths, jitter in
/// [0, 1], every interval finite with near <= far.
fn check_sampler_inputs(
    near: &[f32],
    far: &[f32],
    samples: usize,
    jitter: Option<&[f32]>,
) -> Result<(), SamplerError> {
    let rays = near.len();
    if samples == 0 {
        return Err(SamplerError::NoSamples);
    }
    if far.len() != rays {
        return Err(SamplerError::Length {
            field: "far",
            got: far.len(),
            expected: rays,
        });
    }
    if let Some(jitter) = jitter {
        if jitter.len() != rays * samples {
            return Err(SamplerError::Length {
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
            return Err(SamplerError::Jitter { index, value });
        }
    }
    for (ray, (&near, &far)) in near.iter().zip(far).enumerate() {
        if !(near.is_finite() && far.is_finite() && near <= far) {
            return Err(SamplerError::Interval { ray, near, far });
        }
    }
    Ok(())
}

/// The samples of R rays, S per ray, and which of them the field evaluates.
#[derive(Debug, Clone)]
pub struct RaySamples {
    /// Samples per ray S.
    pub per_ray: usize,
    /// [R * S] ray parameters, metres, row-major `[R, S]`, non-decreasing per ray.
    pub t: Vec<f32>,
    /// [R * S] quadrature interval of each sample, metres, >= 0: `t_{i+1} - t_i` and
    /// `far - t_{S-1}` for stratified samples; the bin's length inside the band for band samples.
    pub delta: Vec<f32>,
    /// [M] the points the field evaluates, world metres (M = R * S without skipping).
    pub points: Vec<Vec3>,
    /// [M] their unit ray directions.
    pub dirs: Vec<Vec3>,
    /// [M] the flat `[R * S]` index of each evaluated point; `None` when every sample is
    /// evaluated (in order).
    pub kept: Option<Vec<usize>>,
}

impl RaySamples {
    /// Stratified samples of `rays` ([`stratified_t`]; `jitter` [R * S] in [0, 1] or `None`
    /// for bin centres), keeping only those in occupied cells of `occupancy` when given.
    pub fn new(
        rays: &RayBundle,
        samples: usize,
        jitter: Option<&[f32]>,
        occupancy: Option<&OccupancyGrid>,
    ) -> Result<Self, SamplerError> {
        let t = stratified_t(&rays.near, &rays.far, samples, jitter)?;
        let mut delta = Vec::with_capacity(t.len());
        for (r, row) in t.chunks(samples).enumerate() {
            for i in 0..samples {
                let next = if i + 1 < samples {
                    row[i + 1]
                } else {
                    rays.far[r]
                };
                delta.push((next - row[i]).max(0.0));
            }
        }
        Self::keep_occupied(rays, samples, t, delta, occupancy, None)
    }

    /// Band samples of `rays` (module docs): S bins over the part of each ray inside `band`
    /// (marched at a quarter of its cell edge), jittered by `jitter` ([R * S] in [0, 1]) or at
    /// the bin centres; then, as in [`RaySamples::new`], only the samples in occupied cells of
    /// `occupancy` are kept when given. Samples of a ray that misses the band sit at `near` with
    /// zero intervals and are not evaluated.
    pub fn in_band(
        rays: &RayBundle,
        samples: usize,
        jitter: Option<&[f32]>,
        band: &OccupancyGrid,
        occupancy: Option<&OccupancyGrid>,
    ) -> Result<Self, SamplerError> {
        check_sampler_inputs(&rays.near, &rays.far, samples, jitter)?;
        let step = band.cell_m() * 0.25;
        let mut t = vec![0.0f32; rays.len() * samples];
        let mut delta = vec![0.0f32; rays.len() * samples];
        let mut hit = vec![false; rays.len()];
        // One ray at a time, rays in parallel (each writes its own S samples).
        t.par_chunks_mut(samples)
            .zip(delta.par_chunks_mut(samples))
            .zip(hit.par_iter_mut())
            .enumerate()
            .with_min_len(RAYS_PER_TASK)
            .for_each_init(BandBuffers::default, |buffers, (r, ((t, delta), hit))| {
                let jitter = jitter.map(|j| &j[r * samples..(r + 1) * samples]);
                // A ray that misses the band gets S samples at `near` with zero intervals.
                band_segments(rays, r, step, band, buffers);
                *hit = spread_in_segments(&buffers.segments, rays.near[r], jitter, t, delta);
            });
        Self::keep_occupied(rays, samples, t, delta, occupancy, Some(&hit))
    }

    /// The evaluated points: every sample of a ray in `hit` (all rays when `None`) that lies in
    /// an occupied cell of `occupancy` (every one when `None`).
    fn keep_occupied(
        rays: &RayBundle,
        samples: usize,
        t: Vec<f32>,
        delta: Vec<f32>,
        occupancy: Option<&OccupancyGrid>,
        hit: Option<&[bool]>,
    ) -> Result<Self, SamplerError> {
        let total = t.len();
        let at = |i: usize| {
            let r = i / samples;
            rays.origins[r] + rays.dirs[r] * t[i]
        };
        let ray_hit = |i: usize| hit.is_none_or(|h| h[i / samples]);
        let kept: Option<Vec<usize>> =
            if occupancy.is_none() && hit.is_none_or(|h| h.iter().all(|&x| x)) {
                None
            } else {
                let kept: Vec<usize> = (0..total)
                    .into_par_iter()
                    .with_min_len(RAYS_PER_TASK * samples)
                    .filter(|&i| ray_hit(i) && occupancy.is_none_or(|grid| grid.occupied(at(i))))
                    .collect();
                (kept.len() < total).then_some(kept)
            };
        let (points, dirs) = match &kept {
            Some(k) => k
                .par_iter()
                .with_min_len(RAYS_PER_TASK * samples)
                .map(|&i| (at(i), rays.dirs[i / samples]))
                .unzip(),
            None => (0..total)
                .into_par_iter()
                .with_min_len(RAYS_PER_TASK * samples)
                .map(|i| (at(i), rays.dirs[i / samples]))
                .unzip(),
        };
        Ok(RaySamples {
            per_ray: samples,
            t,
            delta,
            points,
            dirs,
            kept,
        })
    }

    /// Keeps only the evaluated points for which `keep` (world point) is true; the others join
    /// the skipped samples (zero density, never evaluated).
    pub fn retain(&mut self, keep: impl Fn(Vec3) -> bool + Sync) {
        let flags: Vec<bool> = self.points.par_iter().map(|&p| keep(p)).collect();
        if flags.iter().all(|&k| k) {
            return;
        }
        let index: Vec<usize> = match &self.kept {
            Some(k) => k.clone(),
            None => (0..self.total()).collect(),
        };
        let mut kept = Vec::with_capacity(index.len());
        let (mut points, mut dirs) = (Vec::new(), Vec::new());
        for (j, &i) in index.iter().enumerate() {
            if flags[j] {
                kept.push(i);
                points.push(self.points[j]);
                dirs.push(self.dirs[j]);
            }
        }
        self.kept = Some(kept);
        self.points = points;
        self.dirs = dirs;
    }

    /// Samples in all, R * S.
    pub fn total(&self) -> usize {
        self.t.len()
    }

    /// Samples the field evaluates, M.
    pub fn evaluated(&self) -> usize {
        self.points.len()
    }
}

/// Rays per rayon task of the band sampler and of the occupancy test.
const RAYS_PER_TASK: usize = 64;

/// S samples `t` and their intervals `delta` ([S] each) spread evenly over the total length of
/// `segments`, bin by bin (`jitter` [S] within each bin, its centre when `None`). Returns
/// whether there was any length; without, the S samples sit at `near` with zero intervals.
fn spread_in_segments(
    segments: &[(f32, f32)],
    near: f32,
    jitter: Option<&[f32]>,
    t: &mut [f32],
    delta: &mut [f32],
) -> bool {
    let samples = t.len();
    let length: f32 = segments.iter().map(|(a, b)| b - a).sum();
    if length <= 0.0 {
        t.fill(near);
        delta.fill(0.0);
        return false;
    }
    let bin = length / samples as f32;
    // Positions u in [0, length) along the band, mapped back to t segment by segment.
    let mut segment = 0;
    let mut before = 0.0f32;
    let mut u_prev = 0.0f32;
    for i in 0..samples {
        let j = jitter.map_or(0.5, |j| j[i]);
        let u = ((i as f32 + j) * bin).min(length);
        while segment + 1 < segments.len()
            && u > before + (segments[segment].1 - segments[segment].0)
        {
            before += segments[segment].1 - segments[segment].0;
            segment += 1;
        }
        let (a, b) = segments[segment];
        t[i] = (a + (u - before)).min(b);
        if i > 0 {
            delta[i - 1] = (u - u_prev).max(0.0);
        }
        u_prev = u;
    }
    delta[samples - 1] = (length - u_prev).max(0.0);
    true
}
