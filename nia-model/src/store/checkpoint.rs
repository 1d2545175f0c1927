//! Checkpoints: `OUT/checkpoints/step_XXXXXXXX/` with the model weights (`model.bpk`), the
//! optimiser state (`optimizer.bpk`, burn's burnpack), `config.json` (the run config and the
//! resolved network config) and `step.json`.
//!
//! A checkpoint is written into a hidden temporary folder and renamed into place, so a process
//! killed mid-write leaves the previous checkpoints untouched and no partial `step_*` folder.
//! Only the last `keep_last` are kept.
//!
//! Fault injection: with the environment variable [`FAULT_PAUSE_ENV`] set to a number of
//! milliseconds, [`save`] sleeps that long after writing the model file into the temporary
//! folder, so a crash test can kill the process in the middle of a checkpoint write.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::optim::ModuleOptimizer;
use burn::store::{ModuleRecord, RecordError};
use burn::tensor::Bytes;
use serde::{Deserialize, Serialize};

use crate::{ModelConfig, NiaModel};

/// Folder of the checkpoints inside the run's output folder.
pub const CHECKPOINT_DIR: &str = "checkpoints";
const PREFIX: &str = "step_";
const TMP_PREFIX: &str = ".tmp_step_";
pub const MODEL_FILE: &str = "model.bpk";
pub const OPTIMIZER_FILE: &str = "optimizer.bpk";
pub const CONFIG_FILE: &str = "config.json";
pub const STEP_FILE: &str = "step.json";
/// Milliseconds [`save`] pauses in the middle of a write (crash tests only; unset normally).
pub const FAULT_PAUSE_ENV: &str = "NIA_FAULT_CHECKPOINT_PAUSE_MS";

/// A checkpoint error, naming the file.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: {message}", path.display())]
    Record { path: PathBuf, message: String },
    #[error("{}: {source}", path.display())]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    /// A switch nia-rs no longer has, at a value other than its neutral one.
    #[error("{}: {message}", path.display())]
    Removed { path: PathBuf, message: String },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CheckpointError + '_ {
    move |source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// `step.json`: steps completed when the checkpoint was taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct StepInfo {
    pub step: u64,
}

/// `config.json`: the run config the checkpoint was trained with (the trainer's schema, kept
/// as JSON here) and the resolved network config.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SavedConfig {
    pub run: serde_json::Value,
    pub model: ModelConfig,
}

/// The folder name of the checkpoint after `step` steps.
pub fn dir_name(step: u64) -> String {
    format!("{PREFIX}{step:08}")
}

/// Writes the checkpoint after `step` steps under `out/checkpoints/` and prunes old ones.
pub fn save(
    out: &Path,
    step: u64,
    model: &NiaModel,
    optimizer: &ModuleOptimizer,
    run: &impl Serialize,
    model_config: &ModelConfig,
    keep_last: usize,
) -> Result<PathBuf, CheckpointError> {
    let run = serde_json::to_value(run).map_err(|source| CheckpointError::Json {
        path: out.join(CONFIG_FILE),
        source,
    })?;
    let root = out.join(CHECKPOINT_DIR);
    std::fs::create_dir_all(&root).map_err(io(&root))?;
    let tmp = root.join(format!("{TMP_PREFIX}{step:08}"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
    let model_path = tmp.join(MODEL_FILE);
    // `valid()` first: BatchNorm's running statistics keep the last forward pass's update
    // pending until synchronised, and a record of the module as it stands would store the
    // statistics of one step earlier than the weights.
    model
        .valid()
        .save_file(&model_path)
        .map_err(|e| CheckpointError::Record {
            path: model_path.clone(),
            message: e.to_string(),
        })?;
    if let Some(ms) = std::env::var(FAULT_PAUSE_ENV)
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
    {
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
    let optim_path = tmp.join(OPTIMIZER_FILE);
    optimizer
        .save(&optim_path)
        .map_err(|e| CheckpointError::Record {
            path: optim_path.clone(),
            message: e.to_string(),
        })?;
    write_json(
        &tmp.join(CONFIG_FILE),
        &SavedConfig {
            run,
            model: model_config.clone(),
        },
    )?;
    write_json(&tmp.join(STEP_FILE), &StepInfo { step })?;
    let dest = root.join(dir_name(step));
    if dest.exists() {
        std::fs::remove_dir_all(&dest).map_err(io(&dest))?;
    }
    std::fs::rename(&tmp, &dest).map_err(io(&dest))?;
    prune(&root, keep_last)?;
    Ok(dest)
}

fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), CheckpointError> {
    let text = serde_json::to_string_pretty(value).map_err(|source| CheckpointError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    std::fs::write(path, text).map_err(io(path))
}

/// Complete checkpoints under `out/checkpoints/`, oldest first.
pub fn list(out: &Path) -> Result<Vec<(u64, PathBuf)>, CheckpointError> {
    let root = out.join(CHECKPOINT_DIR);
    if !root.is_dir() {
        return Ok(Vec::new());
    }
    let mut found = Vec::new();
    for entry in std::fs::read_dir(&root).map_err(io(&root))? {
        let path = entry.map_err(io(&root))?.path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if let Some(step) = name
            .strip_prefix(PREFIX)
            .and_then(|s| s.parse::<u64>().ok())
        {
            if path.join(STEP_FILE).is_file() {
                found.push((step, path));
            }
        }
    }
    found.sort();
    Ok(found)
}

/// The newest complete checkpoint, if any.
pub fn latest(out: &Path) -> Result<Option<(u64, PathBuf)>, CheckpointError> {
    Ok(list(out)?.pop())
}

/// Removes all but the newest `keep_last` checkpoints, and temporary folders left by writes
/// that were killed (one run writes at a time, so none is in progress here).
fn prune(root: &Path, keep_last: usize) -> Result<(), CheckpointError> {
    for entry in std::fs::read_dir(root).map_err(io(root))? {
        let path = entry.map_err(io(root))?.path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if name.starts_with(TMP_PREFIX) && path.is_dir() {
            std::fs::remove_dir_all(&path).map_err(io(&path))?;
        }
    }
    let all = list(root.parent().unwrap_or(root))?;
    let excess = all.len().saturating_sub(keep_last.max(1));
    for (_, path) in all.into_iter().take(excess) {
        std::fs::remove_dir_all(&path).map_err(io(&path))?;
    }
    Ok(())
}

/// Reads a whole record file into memory: nothing of a checkpoint is read lazily later, so
/// pruning or replacing the folder afterwards cannot pull data from under a loaded model.
fn read_bytes(path: &Path) -> Result<Bytes, CheckpointError> {
    Ok(Bytes::from_bytes_vec(
        std::fs::read(path).map_err(io(path))?,
    ))
}

fn record_error(path: &Path) -> impl FnOnce(RecordError) -> CheckpointError + '_ {
    move |e| CheckpointError::Record {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, CheckpointError> {
    let text = std::fs::read_to_string(path).map_err(io(path))?;
    serde_json::from_str(&text).map_err(|source| CheckpointError::Json {
        path: path.to_path_buf(),
        source,
    })
}

/// `config.json` of a checkpoint folder (switches removed since it was written dropped at
/// their neutral value, refused at any other: [`super::removed_switches`]).
pub fn read_config(dir: &Path) -> Result<SavedConfig, CheckpointError> {
    let path = dir.join(CONFIG_FILE);
    let mut doc: serde_json::Value = read_json(&path)?;
    super::removed_switches::strip_removed_switches(&mut doc).map_err(|message| {
        CheckpointError::Removed {
            path: path.clone(),
            message,
        }
    })?;
    serde_json::from_value(doc).map_err(|source| CheckpointError::Json { path, source })
}

/// Steps completed when the checkpoint in `dir` was taken (its `step.json`).
pub fn read_step(dir: &Path) -> Result<u64, CheckpointError> {
    read_json::<StepInfo>(&dir.join(STEP_FILE)).map(|info| info.step)
}

/// The checkpoint folder `path` names: itself when it holds a `step.json`, else the newest
/// complete checkpoint of the run folder `path`; `None` when it is neither.
pub fn resolve(path: &Path) -> Result<Option<PathBuf>, CheckpointError> {
    if path.join(STEP_FILE).is_file() {
        return Ok(Some(path.to_path_buf()));
    }
    Ok(latest(path)?.map(|(_, dir)| dir))
}

/// Loads a checkpoint folder into `model` and `optimizer` (fresh ones of the same config);
/// returns them with the number of steps completed.
///
/// burn materialises optimiser state on its default device and moves each tensor to its
/// parameter's device on the next step; binaries set `BURN_DEVICE` to the training backend so
/// that the default is that device.
pub fn load(
    dir: &Path,
    model: NiaModel,
    optimizer: ModuleOptimizer,
) -> Result<(NiaModel, ModuleOptimizer, u64), CheckpointError> {
    let step = read_step(dir)?;
    let model = load_model(dir, model)?;
    let optim_path = dir.join(OPTIMIZER_FILE);
    let optimizer = optimizer
        .from_bytes(read_bytes(&optim_path)?)
        .map_err(record_error(&optim_path))?;
    Ok((model, optimizer, step))
}

/// Loads only the model weights of a checkpoint folder into `model` (fine-tuning or
/// evaluating another run's model).
pub fn load_model(dir: &Path, model: NiaModel) -> Result<NiaModel, CheckpointError> {
    let model_path = dir.join(MODEL_FILE);
    let record =
        ModuleRecord::from_bytes(read_bytes(&model_path)?).map_err(record_error(&model_path))?;
    model
        .try_load_record(record)
        .map_err(record_error(&model_path))
}
