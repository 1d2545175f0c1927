//! nia-eval: what evaluation is, shared by both binaries (`nia-train` validates and evaluates
//! with it, `nia-infer` scores, renders and plots with it).
//!
//! - [`eval`]: held-out evaluation (render and score a split's images with the protocol's PSNR,
//!   SSIM and LPIPS);
//! - [`diagnostics`]: the instruments of the hybrid per evaluated image (blend use, IBR-only
//!   and NeRF-only PSNR, depth error, opacity off the person);
//! - [`perceptual`]: LPIPS weight files and the distance on SSIM's crop;
//! - [`pictures`]: comparison grids, error maps and blend-weight maps as images;
//! - [`plot`]: SVG plots (the sweep's accuracy-time scatter, training curves);
//! - [`run_settings`]: the settings evaluation and inference take from the run a model was
//!   trained with;
//! - [`truth`]: a truer ground truth than the dataset's (the same synthetic capture without
//!   its mask flaw), scored beside the protocol's;
//! - [`heap`]: the process heap's policy for tensor buffers (both binaries set it first thing).
//!
//! The library never prints.

pub mod diagnostics;
pub mod eval;
pub mod heap;
pub mod perceptual;
pub mod pictures;
pub mod plot;
pub mod run_settings;
pub mod truth;
