//! nia-train as a library: the run configuration, the data of a run, the training loop,
//! checkpoints and the events the loop reports. The library never prints; the binary
//! (`main.rs`) turns events into a progress bar and a JSONL log.

pub mod checkpoint;
pub mod config;
pub mod data;
pub mod evaluate;
pub mod events;
pub mod train_loop;
