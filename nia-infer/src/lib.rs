//! nia-infer as a library: what inference and evaluation share with the trainer.
//!
//! - [`diagnostics`]: the instruments of the hybrid per evaluated image (blend use, IBR-only
//!   and NeRF-only PSNR, depth error, opacity off the person);
//! - [`eval`]: held-out evaluation (render and score a split's images), used by `nia-infer
//!   eval`/`sweep` and by the trainer's validation and final evaluation;
//! - [`heap`]: the process heap's policy for tensor buffers (binaries set it first thing);
//! - [`perceptual`]: LPIPS weight files and the distance on SSIM's crop;
//! - [`pictures`]: comparison grids, error maps and blend-weight maps as images;
//! - [`plot`]: SVG plots (the sweep's accuracy-time scatter, training curves);
//! - [`run_settings`]: the settings inference takes from the run a model was trained with.
//!
//! The binary (`main.rs`) holds the commands; the library never prints.

pub mod diagnostics;
pub mod eval;
pub mod heap;
pub mod perceptual;
pub mod pictures;
pub mod plot;
pub mod run_settings;
