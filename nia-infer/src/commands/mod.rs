//! One file per subcommand: argument struct (clap) and a `run` function.

pub mod inspect;
pub mod metrics;
