//! nia-data: everything NIA needs that is not a tensor.
//!
//! Cameras and rays, the SMPL-compatible body model and its linear blend skinning, a z-buffer
//! rasteriser with per-vertex visibility, nearest-surface queries, the numpy/pickle formats the
//! datasets are written in, the dataset readers and the evaluation protocol, the per-scene
//! geometry the network's inputs are computed from, SMPL fitted to masks and keypoints
//! (`fitting`: the loader's alignment and `nia-train prepare`'s fitter), and the synthetic
//! ZJU-MoCap-layout generator.
//!
//! Conventions: right-handed world, metres; cameras are world-to-camera `x_c = R x_w + T`,
//! OpenCV pixel convention (x right, y down, the centre of pixel (i, j) is at (i, j): see `geometry::camera::PIXEL_CENTRE_OFFSET`).

pub mod body;
pub mod dataset;
pub mod fitting;
pub mod formats;
pub mod geometry;
pub mod metrics;
pub mod own_capture;
pub mod rng;
pub mod scene;
pub mod synth;
