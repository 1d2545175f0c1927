//! How a trained network is kept on disk:
//!
//! - [`model_file`]: the `.nia` file, one self-describing file for inference;
//! - [`checkpoint`]: training checkpoints (weights, optimiser state, configs, step), written
//!   atomically.

pub mod checkpoint;
pub mod model_file;
