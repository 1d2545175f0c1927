//! `ModelError`: what a forward pass can fail with, naming the stage.

use nia_data::geometry::occupancy::OccupancyError;
use nia_data::geometry::sparse::SparseGridError;
use nia_data::scene::SceneError;

use crate::body_volume::BodyVolumeError;
use crate::sampler::SamplerError;
use crate::shape::ShapeError;

/// Errors of a forward pass, naming the stage.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error("body volume: {0}")]
    Volume(#[from] BodyVolumeError),
    #[error("{0}")]
    Shape(#[from] ShapeError),
    #[error("sampler: {0}")]
    Sampler(#[from] SamplerError),
    #[error("rays: {0}")]
    Rays(String),
    /// The band sampler's occupancy grid could not be built.
    #[error("band sampler: {0}")]
    Band(#[from] OccupancyError),
    /// Inputs that do not fit together (vertex counts, an encoding without a volume, reposing).
    #[error("{0}")]
    Input(String),
    /// The caller's cancellation hook stopped the render before it was done.
    #[error("rendering was cancelled")]
    Cancelled,
}

impl From<SparseGridError> for ModelError {
    fn from(e: SparseGridError) -> Self {
        ModelError::Volume(e.into())
    }
}
