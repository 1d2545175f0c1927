//! How the sampler places the S samples of a ray: over the whole `[near, far]` or in the band
//! around the posed SMPL surface (the parent module's docs).

use std::sync::Arc;

use glam::Vec3;
use nia_data::geometry::occupancy::{OccupancyError, OccupancyGrid};
use nia_data::geometry::occupancy_memo::shared_grid;
use serde::{Deserialize, Serialize};

use crate::render_options::DEFAULT_OCCUPANCY_CELL_M;

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
