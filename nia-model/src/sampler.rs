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
//! Adaptive work, what rendering may leave out because the scene does not need it. Always on
//! (they cannot change a pixel):
//! - rays that miss the body's ray box never reach the sampler (they render the background);
//! - a novel view never runs the reposing transform; a reposed render runs it only for the
//!   samples that reach the field;
//! - per-scene work (encoder features, vertex visibility, the body volume) is done once and
//!   reused by every target view and ray chunk, and animation rebuilds only the body volume.
//!
//! Switchable, on by default: empty-space skipping. Samples farther than
//! [`AdaptiveConfig::empty_space_m`] from the posed body's surface (and not inside it) are not
//! evaluated; they keep zero density. The occupancy grid is built from the posed mesh once per
//! frame and pose ([`OccupancyGrid`]); [`RaySamples::new`] keeps the samples in occupied cells.

use std::sync::Arc;

use crate::colour_culling::DEFAULT_COLOUR_CULLING;
use crate::termination::DEFAULT_TERMINATION;
use glam::Vec3;
use nia_data::geometry::occupancy::{OccupancyError, OccupancyGrid};
use nia_data::geometry::occupancy_memo::shared_grid;
use nia_data::geometry::rays::RayBundle;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

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
        let mut t = Vec::with_capacity(rays.len() * samples);
        let mut delta = Vec::with_capacity(rays.len() * samples);
        let mut hit = vec![false; rays.len()];
        let mut segments: Vec<(f32, f32)> = Vec::new();
        for r in 0..rays.len() {
            let (near, far) = (rays.near[r], rays.far[r]);
            segments.clear();
            let steps = ((far - near) / step).ceil().max(0.0) as usize;
            for k in 0..steps {
                let a = near + k as f32 * step;
                let b = (a + step).min(far);
                if band.occupied(rays.origins[r] + rays.dirs[r] * (0.5 * (a + b))) {
                    match segments.last_mut() {
                        Some(last) if last.1 >= a => last.1 = b,
                        _ => segments.push((a, b)),
                    }
                }
            }
            let length: f32 = segments.iter().map(|(a, b)| b - a).sum();
            if length <= 0.0 {
                t.extend(std::iter::repeat_n(near, samples));
                delta.extend(std::iter::repeat_n(0.0, samples));
                continue;
            }
            hit[r] = true;
            let bin = length / samples as f32;
            // Positions u in [0, length) along the band, mapped back to t segment by segment.
            let mut segment = 0;
            let mut before = 0.0f32;
            let mut u_prev = 0.0f32;
            for i in 0..samples {
                let j = jitter.map_or(0.5, |j| j[r * samples + i]);
                let u = ((i as f32 + j) * bin).min(length);
                while segment + 1 < segments.len()
                    && u > before + (segments[segment].1 - segments[segment].0)
                {
                    before += segments[segment].1 - segments[segment].0;
                    segment += 1;
                }
                let (a, b) = segments[segment];
                t.push((a + (u - before)).min(b));
                if i > 0 {
                    delta.push((u - u_prev).max(0.0));
                }
                u_prev = u;
            }
            delta.push((length - u_prev).max(0.0));
        }
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
                    .filter(|&i| ray_hit(i) && occupancy.is_none_or(|grid| grid.occupied(at(i))))
                    .collect();
                (kept.len() < total).then_some(kept)
            };
        let (points, dirs) = match &kept {
            Some(k) => k.iter().map(|&i| (at(i), rays.dirs[i / samples])).unzip(),
            None => (0..total).map(|i| (at(i), rays.dirs[i / samples])).unzip(),
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

/// How the sampler places the S samples of a ray (module docs). Part of the network's config,
/// so inference samples as training did.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum RaySampler {
    /// S bins over the ray's whole `[near, far]` (NeRF, NHP, NIA).
    Stratified,
    /// S bins over the part of the ray within `margin_m` of the posed SMPL surface or inside
    /// it, found on an occupancy grid of `cell_m` cells built per frame and pose.
    Band {
        /// Distance from the SMPL surface that the band reaches, metres.
        #[serde(default = "default_band_margin_m")]
        margin_m: f32,
        /// Cell edge of the band's occupancy grid, metres.
        #[serde(default = "default_band_cell_m")]
        cell_m: f32,
    },
}

fn default_band_margin_m() -> f32 {
    DEFAULT_BAND_MARGIN_M
}

fn default_band_cell_m() -> f32 {
    DEFAULT_OCCUPANCY_CELL_M
}

/// Default reach of the band sampler beyond the SMPL surface, metres: the synthetic clothing
/// stands up to ~3 cm off the body; a cell diagonal more is kept by the grid.
pub const DEFAULT_BAND_MARGIN_M: f32 = 0.05;

impl RaySampler {
    /// The band's occupancy grid of the posed mesh (`vertices` [V] world metres); `None` for
    /// stratified sampling.
    pub fn band(
        &self,
        vertices: &[Vec3],
        faces: &[[u32; 3]],
    ) -> Result<Option<Arc<OccupancyGrid>>, OccupancyError> {
        match *self {
            RaySampler::Stratified => Ok(None),
            RaySampler::Band { margin_m, cell_m } => {
                shared_grid(vertices, faces, margin_m, cell_m).map(Some)
            }
        }
    }

    /// Checks the band's distances.
    pub fn check(&self) -> Result<(), String> {
        if let RaySampler::Band { margin_m, cell_m } = *self {
            for (name, value) in [("margin_m", margin_m), ("cell_m", cell_m)] {
                if !(value.is_finite() && value > 0.0 && value <= 1.0) {
                    return Err(format!(
                        "`ray_sampler.{name}` = {value}, expected a value in (0, 1] metres"
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Default distance from the SMPL surface within which samples are evaluated, metres. A kept
/// cell reaches up to a cell diagonal (3.5 cm at the default cell) beyond it, so space up to
/// 3 cm from the surface is always evaluated and up to 6.5 cm often is. Measured on the
/// quickstart's unseen subject (README, "What accuracy costs"): 3.1x fewer network points and
/// 2.5x less time per image than no skipping, with PSNR 0.19 dB *higher* (floaters in empty
/// space are gone). Loose clothing that stands farther off the fitted SMPL surface needs a
/// larger value; `nia-infer sweep` measures the trade.
pub const DEFAULT_EMPTY_SPACE_M: f32 = 0.03;
/// Default of [`AdaptiveConfig::hull_dilate_px`]: the masks as they are (see the constant's
/// measurement in the README, "Quickstart").
pub const DEFAULT_HULL_DILATE_PX: usize = 0;
/// Largest [`AdaptiveConfig::hull_dilate_px`] accepted.
pub const MAX_HULL_DILATE_PX: usize = 256;
/// Default of [`AdaptiveConfig::supersample`]: one ray through each pixel's centre (NeRF's,
/// NHP's and NIA's rendering).
pub const DEFAULT_SUPERSAMPLE: usize = 1;
/// Largest [`AdaptiveConfig::supersample`] accepted (64 rays per pixel).
pub const MAX_SUPERSAMPLE: usize = 8;
/// Default occupancy cell edge, metres.
pub const DEFAULT_OCCUPANCY_CELL_M: f32 = 0.02;

/// The switchable parts of adaptive work.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdaptiveConfig {
    /// Skip samples in empty space (farther than `empty_space_m` from the body).
    pub skip_empty_space: bool,
    /// Distance from the SMPL surface within which samples are evaluated, metres.
    pub empty_space_m: f32,
    /// Occupancy grid cell edge, metres.
    pub occupancy_cell_m: f32,
    /// Early ray termination: a ray evaluates no more samples once its transmittance is below
    /// this (`termination`); 0 evaluates every kept sample.
    pub early_termination: f32,
    /// Colour culling: per ray, samples whose weights sum to at most this get no colour
    /// evaluation (`colour_culling`); 0 colours every evaluated sample.
    pub colour_culling: f32,
    /// Visual-hull carving (not in the paper; `nia_data::scene::visual_hull`): the density is
    /// zero wherever a source view's person mask says empty space, and with skipping those
    /// samples are not evaluated. Off gives the paper's density.
    pub visual_hull: bool,
    /// Pixels the masks are grown by before carving (noisy masks of real captures need a
    /// margin; the synthetic masks are exact).
    pub hull_dilate_px: usize,
    /// Rays per pixel side s (not in the paper): every pixel is the mean of s x s rays spread
    /// over its square (`RayBundle::through_pixel_footprints`), as a camera integrates over the
    /// pixel's area; s x s times the rays of 1, the paper's one ray through the centre.
    pub supersample: usize,
}

impl Default for AdaptiveConfig {
    fn default() -> Self {
        AdaptiveConfig {
            skip_empty_space: true,
            empty_space_m: DEFAULT_EMPTY_SPACE_M,
            occupancy_cell_m: DEFAULT_OCCUPANCY_CELL_M,
            early_termination: DEFAULT_TERMINATION,
            colour_culling: DEFAULT_COLOUR_CULLING,
            visual_hull: true,
            hull_dilate_px: DEFAULT_HULL_DILATE_PX,
            supersample: DEFAULT_SUPERSAMPLE,
        }
    }
}

impl AdaptiveConfig {
    /// Every sample evaluated (the reference for accuracy).
    pub fn exhaustive() -> Self {
        AdaptiveConfig {
            skip_empty_space: false,
            early_termination: 0.0,
            colour_culling: 0.0,
            ..Self::default()
        }
    }

    /// The transmittance at which rays stop (`SceneEncoding::with_termination`); `None` when
    /// early termination is off.
    pub fn termination(&self) -> Option<f32> {
        (self.early_termination > 0.0).then_some(self.early_termination)
    }

    /// The per-ray weight budget of colour culling (`SceneEncoding::with_colour_culling`);
    /// `None` when culling is off.
    pub fn culling(&self) -> Option<f32> {
        (self.colour_culling > 0.0).then_some(self.colour_culling)
    }

    /// The dilation of visual-hull carving (`SceneEncoding::with_visual_hull`); `None` when
    /// carving is off.
    pub fn hull(&self) -> Option<usize> {
        self.visual_hull.then_some(self.hull_dilate_px)
    }

    /// The occupancy grid of the posed mesh (`vertices` [V] world metres) when skipping is on.
    pub fn occupancy(
        &self,
        vertices: &[Vec3],
        faces: &[[u32; 3]],
    ) -> Result<Option<Arc<OccupancyGrid>>, OccupancyError> {
        if !self.skip_empty_space {
            return Ok(None);
        }
        shared_grid(vertices, faces, self.empty_space_m, self.occupancy_cell_m).map(Some)
    }
}
