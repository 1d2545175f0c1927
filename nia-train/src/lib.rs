//! nia-train as a library: the run configuration, the data of a run, the training loop and the
//! events the loop reports. Checkpoints are [`nia_model::store::checkpoint`]; validation and
//! the final evaluation are [`nia_eval::eval`]. The library never prints; the binary
//! (`main.rs`) turns events into a progress bar, a JSONL log, TensorBoard event files
//! ([`tensorboard`]) and the curves picture ([`curves`]).

pub mod ablation;
pub mod config;
pub mod curves;
pub mod data;
pub mod events;
pub mod prepare;
pub mod tensorboard;
pub mod train_loop;
