//! One file per subcommand: argument struct (clap) and a `run` function.

pub mod bench;
pub mod inspect;
pub mod metrics;
