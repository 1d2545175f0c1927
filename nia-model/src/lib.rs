//! nia-model: the NIA network as Burn modules. One code path for every backend; the `Device`
//! picks it at run time.
//!
//! The forward pass reads sampler -> field -> renderer ([`model`]):
//!
//! - [`scene_encoding`]: the per-scene pass (feature maps, body volume), done once;
//! - [`sampler`]: stratified samples along each ray, empty-space skipping;
//! - [`field`]: encoder, body volume, IBR inputs, attention, heads, blender;
//! - [`renderer`]: NeRF quadrature;
//! - [`surface_ibr`]: source colours per sample (the paper) or at the expected surface point;
//! - [`image`]: whole target images in chunks of rays;
//! - [`loss`]: the training loss (NIA eq. 6);
//! - [`store`]: the `.nia` model file and training checkpoints.

pub mod c0_shuffle;
pub mod colour_culling;
pub mod config;
pub mod device;
pub mod field;
pub mod image;
pub mod loss;
pub mod lpips;
pub mod model;
pub mod readback;
pub mod renderer;
pub mod sampler;
pub mod scene_encoding;
pub mod shape;
pub mod softmax;
pub mod store;
pub mod surface_ibr;
pub mod termination;
pub mod timing;
pub mod variant;

pub use config::ModelConfig;
pub use field::PointOutput;
pub use model::{ModelError, NiaModel};
pub use scene_encoding::SceneEncoding;
pub use variant::Variant;
