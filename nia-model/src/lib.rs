//! nia-model: the NIA network as Burn modules. One code path for every backend; the `Device`
//! picks it at run time.
//!
//! The folders read as the forward pass does:
//!
//! ```text
//! encoder/         ResNet-18 feature maps of the source views          (per scene)
//! body_volume/     sparse-convolution body volume, trilinear reads      (per scene and pose)
//! scene_encoding/  NiaModel::encode: the two above, done once            -> SceneEncoding
//! sampler/         stratified or band samples, empty-space skipping     (per batch of rays)
//! field/           attention, F_sigma, F_c0: NiaModel::field / query
//! ibr/             source colours, pixel features, F_B (blender), surface IBR, c0 shuffle
//! renderer/        quadrature, NiaModel::render, termination, culling, images, render_view
//! ```
//!
//! Beside them: [`config`] (the network's sizes and switches), [`model`] (the module tree),
//! [`render_options`] (the `[render]` section), [`error`], [`loss`] (NIA eq. 6), [`lpips`]
//! (the perceptual metric), [`store`] (the `.nia` model file and checkpoints), the tensor
//! helpers ([`shape`], [`softmax`], [`timing`],
//! [`device`]) and [`kernels`]: the operations nia-rs writes itself (host and GPU kernels
//! with their backwards).

pub mod body_volume;
pub mod config;
pub mod device;
pub mod encoder;
pub mod error;
pub mod field;
pub mod ibr;
pub mod kernels;
pub mod loss;
pub mod lpips;
pub mod model;
pub mod render_options;
pub mod renderer;
pub mod sampler;
pub mod scene_encoding;
pub mod shape;
pub mod softmax;
pub mod store;
pub mod timing;
pub mod variant;

pub use config::ModelConfig;
pub use error::ModelError;
pub use field::PointOutput;
pub use model::NiaModel;
pub use render_options::RenderOptions;
pub use renderer::image::{ImageRenderOptions, RenderedImage};
pub use renderer::view::{prepare_pose, prepare_scene, render_view, TargetView};
pub use scene_encoding::SceneEncoding;
pub use variant::Variant;
