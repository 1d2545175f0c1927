//! What nia-train's integration tests share: the binary, scratch folders, the tiny run config
//! and the small synthetic dataset made by the real `nia-train synth`.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The `nia-train` binary of this build.
pub fn nia_train() -> Command {
    Command::new(env!("CARGO_BIN_EXE_nia-train"))
}

/// A fresh empty folder `<tmp>/nia-train-<test>-<pid>-<name>`.
pub fn scratch(test: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nia-train-{test}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Writes `<dir>/tiny.toml`: a `[synth]` dataset in `<dir>/data` of 2 subjects (1 train, 1
/// held out), 2 frames, 4 cameras, 48 px; the tiny network; `steps` steps of 32 rays x 8
/// samples on ndarray, checkpointing after every step; `extra_train` lines appended to
/// `[train]`.
pub fn tiny_config(dir: &Path, steps: u64, seed: u64, extra_train: &str) -> PathBuf {
    let text = format!(
        r#"
[data]
root = "{root}"
ratio = 1.0
border_px = 1
loader_threads = 1

[synth]
subjects = 2
frames = 2
cameras = 4
size = 48
supersample = 1
test_fraction = 0.5

[model]
preset = "tiny"

[optim]
lr = 5e-4
decay_steps = 1000
grad_clip_norm = 1.0

[train]
steps = {steps}
rays_per_step = 32
samples = 8
source_views = 3
seed = {seed}
checkpoint_every = 1
keep_last = 2
backend = "ndarray"
{extra_train}
"#,
        root = dir.join("data").display().to_string().replace('\\', "/"),
    );
    let path = dir.join("tiny.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// `nia-train synth` of 2 subjects, 2 frames, 4 cameras of `size` px (no supersampling) into
/// `data`.
pub fn synth_small(data: &Path, size: u32) {
    let output = nia_train()
        .args([
            "synth",
            "--subjects",
            "2",
            "--frames",
            "2",
            "--cameras",
            "4",
        ])
        .args(["--size", &size.to_string(), "--supersample", "1", "--out"])
        .arg(data)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "synth failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
}
