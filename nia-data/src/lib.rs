//! nia-data: everything NIA needs that is not a tensor.
//!
//! Cameras and rays, the SMPL-compatible body model and its linear blend skinning, a z-buffer
//! rasteriser with per-vertex visibility, nearest-surface queries, the numpy/pickle formats the
//! datasets are written in, and the synthetic ZJU-MoCap-layout generator.
//!
//! Conventions: right-handed world, metres; cameras are world-to-camera `x_c = R x_w + T`,
//! OpenCV pixel convention (x right, y down, the centre of pixel (i, j) is at (i, j): see `camera::PIXEL_CENTRE_OFFSET`).

pub mod body;
pub mod camera;
pub mod dataset;
pub mod formats;
pub mod loader;
pub mod metrics;
pub mod occupancy;
pub mod protocol;
pub mod raster;
pub mod rays;
pub mod rng;
pub mod sampling;
pub mod surface;
pub mod synth;
pub mod visibility;
