//! How a trained network is kept on disk:
//!
//! - [`model_file`]: the `.nia` file, one self-describing file for inference;
//! - [`checkpoint`]: training checkpoints (weights, optimiser state, configs, step), written
//!   atomically;
//! - [`removed_switches`]: keys of removed switches in files written before, dropped at their
//!   neutral value and refused at any other;
//! - [`pytorch_import`]: weights from the user's PyTorch files (torchvision trunks, LPIPS
//!   heads), checked tensor by tensor.

pub mod checkpoint;
pub mod model_file;
pub mod pytorch_import;
pub mod removed_switches;
