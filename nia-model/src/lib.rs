//! nia-model: the NIA network as Burn modules (encoder, body volume with sparse convolution,
//! view-wise cross-attention, heads, image-based rendering, blending, volume rendering,
//! reposing). One code path for every backend; the `Device` picks it at run time.

pub mod adaptive;
pub mod attention;
pub mod blender;
pub mod body_volume;
pub mod config;
pub mod device;
pub mod encoder;
pub mod encoder_import;
pub mod encoding;
pub mod heads;
pub mod ibr;
pub mod image_render;
pub mod loss;
pub mod model;
pub mod model_file;
pub mod query;
pub mod renderer;
pub mod reposing;
pub mod scene;
pub mod variant;

pub use config::ModelConfig;
pub use model::{NiaModel, PointOutput, RayBatch, SceneEncoding};
pub use variant::Variant;
pub mod timing;
