//! `RenderOptions`: the `[render]` section of a run config, the command line's overrides of it,
//! and what every render reads (`renderer::view::render_view`). None of it is in the network:
//! the same model renders with any options.
//!
//! What rendering may leave out because the scene does not need it (adaptive work). Always on,
//! since they cannot change a pixel:
//! - rays that miss the body's ray box never reach the sampler (they render the background);
//! - a novel view never runs the reposing transform; a reposed render runs it only for the
//!   samples that reach the field;
//! - per-scene work (encoder features, vertex visibility, the body volume) is done once and
//!   reused by every target view and ray chunk, and animation rebuilds only the body volume.
//!
//! Switchable here: empty-space skipping (on by default), early ray termination and colour
//! culling (on by default, bounded error), visual-hull carving (off by default: it changes the
//! paper's density), supersampling (one ray per pixel by default, the paper's) and c0's weight
//! in the learned blend (F_B's own by default, the paper's; `ibr::c0_weight_scale`).
//!
//! [`RenderOptions::check`] is the one place the bounds are enforced; nia-train's config, every
//! `nia-infer` flag, the sweep and the viewer go through it.

use std::sync::Arc;

use glam::Vec3;
use nia_data::geometry::occupancy::{OccupancyError, OccupancyGrid};
use nia_data::geometry::occupancy_memo::shared_grid;
use serde::{Deserialize, Serialize};

use crate::ibr::c0_weight_scale::{MAX_C0_WEIGHT_SCALE, MIN_C0_WEIGHT_SCALE};

/// Default distance from the SMPL surface within which samples are evaluated, metres. A kept
/// cell reaches up to a cell diagonal (3.5 cm at the default cell) beyond it, so space up to
/// 3 cm from the surface is always evaluated and up to 6.5 cm often is. Measured in
/// docs/accuracy-time.md. Loose clothing that stands farther off the fitted SMPL surface needs
/// a larger value; `nia-infer sweep` measures the trade.
pub const DEFAULT_EMPTY_SPACE_M: f32 = 0.03;
/// Default occupancy cell edge, metres.
pub const DEFAULT_OCCUPANCY_CELL_M: f32 = 0.02;
/// Smallest occupancy cell edge accepted, metres (finer grids cost memory for no gain).
pub const MIN_OCCUPANCY_CELL_M: f32 = 0.005;
/// Default transmittance below which a ray stops (`early_termination`).
pub const DEFAULT_TERMINATION: f32 = 1e-3;
/// Default per-ray budget of culled weight (`colour_culling`).
pub const DEFAULT_COLOUR_CULLING: f32 = 1e-3;
/// Largest [`RenderOptions::hull_body_erode_px`] accepted.
pub const MAX_HULL_BODY_ERODE_PX: usize = 256;
/// Default of [`RenderOptions::supersample`]: one ray through each pixel's centre (NeRF's,
/// NHP's and NIA's rendering).
pub const DEFAULT_SUPERSAMPLE: usize = 1;
/// Largest [`RenderOptions::colour_points`] accepted (more is the paper's every sample).
pub const MAX_COLOUR_POINTS: usize = 16;
/// Smallest [`RenderOptions::density_grid_m`] accepted, metres.
pub const MIN_DENSITY_GRID_M: f32 = 0.002;
/// Largest [`RenderOptions::density_grid_m`] accepted, metres.
pub const MAX_DENSITY_GRID_M: f32 = 0.1;
/// Largest [`RenderOptions::supersample`] accepted (64 rays per pixel).
pub const MAX_SUPERSAMPLE: usize = 8;

/// A `[render]` value out of bounds, naming the key (the command line's flags are the keys
/// with dashes).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("`{key}` = {got}, expected {expected}")]
pub struct RenderOptionError {
    /// The `[render]` key.
    pub key: &'static str,
    /// What is accepted.
    pub expected: String,
    /// The value given.
    pub got: String,
}

/// How a scene is rendered (module docs): the `[render]` section.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderOptions {
    /// Skip samples in empty space (farther than `empty_space_m` from the body).
    pub skip_empty_space: bool,
    /// Distance from the SMPL surface within which samples are evaluated, metres.
    pub empty_space_m: f32,
    /// Occupancy grid cell edge, metres.
    pub occupancy_cell_m: f32,
    /// Early ray termination: a ray evaluates no more samples once its transmittance is below
    /// this (`renderer::termination`); 0 evaluates every kept sample.
    pub early_termination: f32,
    /// Colour culling: per ray, samples whose weights sum to at most this get no colour
    /// evaluation (`renderer::colour_culling`); 0 colours every evaluated sample.
    pub colour_culling: f32,
    /// Colour once per ray (not in the paper; `renderer::colour_once`): the density at every
    /// kept sample, the colour at the `colour_points` samples of each ray with the largest
    /// weights, composited with the ray's opacity (colour culling then does not apply). 0,
    /// the default, colours every sample (the paper's).
    pub colour_points: usize,
    /// The density baked per pose (not in the paper; `renderer::density_grid`): F_sigma run
    /// once per pose at the nodes of a grid of this spacing (metres) and read by trilinear
    /// interpolation at every sample of every view; the colour is then evaluated where
    /// `colour_points` or colour culling say. 0, the default, runs F_sigma at every sample
    /// (the paper's).
    pub density_grid_m: f32,
    /// Visual-hull carving (not in the paper; `nia_data::scene::visual_hull`): the density is
    /// zero wherever a source view's person mask says empty space, and with skipping those
    /// samples are not evaluated. Off (the default) gives the paper's density.
    pub visual_hull: bool,
    /// The fitted body's silhouette in each source view, shrunk by this many pixels, counts as
    /// person before carving (`nia_data::scene::masks_with_body`; `None`, the default: the
    /// masks as they are). A segmentation network that cuts a band out of the person or loses a
    /// hand in one source mask would otherwise have the hull carve that part away in every
    /// target view.
    pub hull_body_erode_px: Option<usize>,
    /// Rays per pixel side s (not in the paper): every pixel is the mean of s x s rays spread
    /// over its square (`RayBundle::through_pixel_footprints`), as a camera integrates over the
    /// pixel's area; s x s times the rays of 1, the paper's one ray through the centre.
    pub supersample: usize,
    /// c0's odds in F_B's blend multiplied by this at rendering (not in the paper;
    /// [`crate::ibr::c0_weight_scale`]): below 1 the blend leans on the source colours. 1, the
    /// default, is the paper's blend.
    pub c0_weight_scale: f32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            skip_empty_space: true,
            empty_space_m: DEFAULT_EMPTY_SPACE_M,
            occupancy_cell_m: DEFAULT_OCCUPANCY_CELL_M,
            early_termination: DEFAULT_TERMINATION,
            colour_culling: DEFAULT_COLOUR_CULLING,
            colour_points: 0,
            density_grid_m: 0.0,
            visual_hull: false,
            hull_body_erode_px: None,
            supersample: DEFAULT_SUPERSAMPLE,
            c0_weight_scale: 1.0,
        }
    }
}

impl RenderOptions {
    /// Every sample evaluated (the reference for accuracy).
    pub fn exhaustive() -> Self {
        RenderOptions {
            skip_empty_space: false,
            early_termination: 0.0,
            colour_culling: 0.0,
            ..Self::default()
        }
    }

    /// Checks every value against its bounds (the constants above).
    pub fn check(&self) -> Result<(), RenderOptionError> {
        let bad = |key: &'static str, expected: &str, got: String| {
            Err(RenderOptionError {
                key,
                expected: expected.to_string(),
                got,
            })
        };
        if !(self.empty_space_m.is_finite() && self.empty_space_m >= 0.0) {
            return bad(
                "empty_space_m",
                "a distance >= 0 (metres)",
                self.empty_space_m.to_string(),
            );
        }
        if !(self.occupancy_cell_m.is_finite() && self.occupancy_cell_m >= MIN_OCCUPANCY_CELL_M) {
            return bad(
                "occupancy_cell_m",
                &format!("a cell edge >= {MIN_OCCUPANCY_CELL_M} (metres)"),
                self.occupancy_cell_m.to_string(),
            );
        }
        if !(0.0..1.0).contains(&self.early_termination) {
            return bad(
                "early_termination",
                "a transmittance in [0, 1) (0: off)",
                self.early_termination.to_string(),
            );
        }
        if !(0.0..1.0).contains(&self.colour_culling) {
            return bad(
                "colour_culling",
                "a weight in [0, 1) (0: off)",
                self.colour_culling.to_string(),
            );
        }
        if let Some(px) = self
            .hull_body_erode_px
            .filter(|&px| px > MAX_HULL_BODY_ERODE_PX)
        {
            return bad(
                "hull_body_erode_px",
                &format!("at most {MAX_HULL_BODY_ERODE_PX} pixels"),
                px.to_string(),
            );
        }
        if !(MIN_C0_WEIGHT_SCALE..=MAX_C0_WEIGHT_SCALE).contains(&self.c0_weight_scale) {
            return bad(
                "c0_weight_scale",
                &format!("{MIN_C0_WEIGHT_SCALE} to {MAX_C0_WEIGHT_SCALE} (1: the paper's blend)"),
                self.c0_weight_scale.to_string(),
            );
        }
        if self.colour_points > MAX_COLOUR_POINTS {
            return bad(
                "colour_points",
                &format!("0 (every sample) to {MAX_COLOUR_POINTS} samples per ray"),
                self.colour_points.to_string(),
            );
        }
        let grid = self.density_grid_m;
        if grid != 0.0 && !(MIN_DENSITY_GRID_M..=MAX_DENSITY_GRID_M).contains(&grid) {
            return bad(
                "density_grid_m",
                &format!(
                    "0 (off) or a node spacing of {MIN_DENSITY_GRID_M} to {MAX_DENSITY_GRID_M} (metres)"
                ),
                grid.to_string(),
            );
        }
        if !(1..=MAX_SUPERSAMPLE).contains(&self.supersample) {
            return bad(
                "supersample",
                &format!("1 to {MAX_SUPERSAMPLE} rays per pixel side"),
                self.supersample.to_string(),
            );
        }
        Ok(())
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

    /// Samples coloured per ray (`SceneEncoding::with_colour_points`); `None` when every
    /// sample is (the paper's).
    pub fn colour_points(&self) -> Option<usize> {
        (self.colour_points > 0).then_some(self.colour_points)
    }

    /// The baked density's node spacing (`renderer::density_grid`); `None` when F_sigma runs
    /// at the samples (the paper's).
    pub fn density_grid(&self) -> Option<f32> {
        (self.density_grid_m > 0.0).then_some(self.density_grid_m)
    }

    /// c0's blend-weight scale (`SceneEncoding::with_c0_weight_scale`); `None` at 1, the
    /// paper's blend.
    pub fn c0_scale(&self) -> Option<f32> {
        (self.c0_weight_scale != 1.0).then_some(self.c0_weight_scale)
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
