pub mod animate;
pub mod bench;
pub mod eval;
pub mod export;
pub mod inspect;
pub mod metrics;
pub mod render;
pub mod sweep;
