//! Tensor-free geometry: cameras and rays, the z-buffer rasteriser and per-vertex visibility,
//! nearest-surface queries, the occupancy grid of empty-space skipping, and the sparse voxel
//! grids (sites, rulebooks, trilinear corners) the body volume is built on.
//!
//! - [`camera`]: pinhole cameras with OpenCV distortion, projection and pixel conventions.
//! - [`rays`]: single rays, ray bundles, ray/box clipping and `mask_at_box`.
//! - [`raster`]: the z-buffer rasteriser.
//! - [`distance_transform`]: a mask's exact Euclidean distance transform and boundary pixels.
//! - [`visibility`]: per-vertex visibility in a view by rasterisation.
//! - [`surface`]: nearest point on a triangle mesh (BVH) with barycentric weights.
//! - [`occupancy`]: the occupancy grid of a posed mesh (which samples can be skipped).
//! - [`mesh_memo`]: values built from a mesh, remembered for the most recently seen meshes.
//! - [`occupancy_memo`]: grids of recently seen meshes, shared instead of rebuilt.
//! - [`surface_memo`]: nearest-surface indices of recently seen meshes.
//! - [`point_grid`]: exact nearest-neighbour queries over 2D points.
//! - [`orbit`]: a 360-degree camera path on the ring of a dataset's calibrated cameras.
//! - [`sparse`]: voxel boxes, active sites, convolution rulebooks and trilinear corners.

pub mod camera;
pub mod distance_transform;
pub mod mesh_memo;
pub mod occupancy;
pub mod occupancy_memo;
pub mod orbit;
pub mod point_grid;
pub mod raster;
pub mod rays;
pub mod sparse;
pub mod surface;
pub mod surface_memo;
pub mod visibility;
