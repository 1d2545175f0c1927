//! The renderer, last stage of the forward pass, and the render entry points:
//!
//! - [`quadrature`]: NeRF volume rendering of R rays of S ordered samples;
//! - [`forward`]: [`crate::NiaModel::render`], one batch of rays through sampler -> field ->
//!   quadrature;
//! - [`termination`] and [`colour_culling`]: what an inference render may leave out behind an
//!   opaque front or under a negligible weight; [`colour_once`]: the colour at a few samples
//!   of each ray only; [`density_grid`]: the density baked once per pose
//!   ([`density_bake`]) and read at every view's samples;
//! - [`shape_buckets`]: the point counts of a GPU render's network calls padded to a few shapes;
//! - [`image`]: whole target images in chunks of rays;
//! - [`call_size`]: how many rays a chunk holds by default (more on a GPU);
//! - [`view`]: [`view::render_view`], the one entry point every command renders through (scene
//!   encoding with the `[render]` options, rays through the pixels, the image).

pub mod call_size;
pub mod colour_culling;
pub mod colour_once;
pub mod density_bake;
pub mod density_grid;
mod forward;
pub mod image;
pub mod quadrature;
pub mod shape_buckets;
pub mod termination;
pub mod view;

pub use quadrature::{
    render_rays, render_rays_delta, sample_weights, sample_weights_delta, RenderOutput,
    OPTICAL_DEPTH_MAX,
};
