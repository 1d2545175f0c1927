//! nia-rs: Neural Image-based Avatars (Kwon et al., ICLR 2023) in Rust on Burn.
//!
//! This root package only hosts the cross-crate tests in `tests/`; the work lives in
//! [`nia_data`] (geometry, body model, datasets, metrics) and [`nia_model`] (the network).
pub use nia_data;
pub use nia_model;
