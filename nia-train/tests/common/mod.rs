//! What nia-train's integration tests share: the binary and its outcomes, scratch folders, the
//! tiny run config and the small synthetic dataset made by the real `nia-train synth`.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The `nia-train` binary of this build.
pub fn nia_train() -> Command {
    Command::new(env!("CARGO_BIN_EXE_nia-train"))
}

/// `nia-train ARGS.. --config CONFIG --out OUT`, run to the end.
pub fn train_run(args: &[&str], config: &Path, out: &Path) -> Output {
    let mut command = nia_train();
    command.args(args).arg("--config").arg(config);
    command.arg("--out").arg(out).output().unwrap()
}

/// Runs `command`, failing the test with its stderr unless it exits with success.
pub fn run_ok(command: &mut Command) -> Output {
    let output = command.output().expect("run the command");
    ok(&output);
    output
}

/// Fails the test with the command's stderr unless it exited with success.
pub fn ok(output: &Output) {
    if !output.status.success() {
        panic!(
            "the command failed:\n{}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
}

/// Exit non-zero with every `expected` text in stderr, and no panic; the stderr.
pub fn fails_with(output: &Output, expected: &[&str]) -> String {
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(!output.status.success(), "expected a failure: {stderr}");
    assert!(!stderr.contains("panicked"), "must not panic: {stderr}");
    for e in expected {
        assert!(stderr.contains(e), "stderr lacks `{e}`: {stderr}");
    }
    stderr
}

/// A path as it is written in a config file (`/` separators).
pub fn slash(p: &Path) -> String {
    p.display().to_string().replace('\\', "/")
}

/// A fresh empty folder `<tmp>/nia-train-<test>-<pid>-<name>`.
pub fn scratch(test: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nia-train-{test}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The `[data]` and `[synth]` sections of the tiny runs: the dataset in `root`, read by
/// `loader_threads` threads, with the `extra_data` lines; made where absent as 2 subjects,
/// 2 frames and 4 cameras of `size` px, without supersampling.
pub fn data_sections(root: &Path, size: u32, loader_threads: usize, extra_data: &str) -> String {
    format!(
        "[data]\nroot = \"{}\"\nratio = 1.0\nborder_px = 1\nloader_threads = {loader_threads}\n\
         {extra_data}\n[synth]\nsubjects = 2\nframes = 2\ncameras = 4\nsize = {size}\n\
         supersample = 1\n",
        slash(root)
    )
}

/// Writes `<dir>/tiny.toml`: a `[synth]` dataset in `<dir>/data` of 2 subjects (1 train, 1
/// held out), 2 frames, 4 cameras, 48 px; the tiny network; `steps` steps of 32 rays x 8
/// samples on ndarray, checkpointing after every step; `extra_train` lines appended to
/// `[train]`.
pub fn tiny_config(dir: &Path, steps: u64, seed: u64, extra_train: &str) -> PathBuf {
    let text = format!(
        r#"{data}test_fraction = 0.5

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
        data = data_sections(&dir.join("data"), 48, 1, ""),
    );
    let path = dir.join("tiny.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// `nia-train synth` of 2 subjects, 2 frames, 4 cameras of `size` px (no supersampling) into
/// `data`.
pub fn synth_small(data: &Path, size: u32) {
    let size = size.to_string();
    let counts = ["--subjects", "2", "--frames", "2", "--cameras", "4"];
    run_ok(
        nia_train()
            .arg("synth")
            .args(counts)
            .args(["--size", &size, "--supersample", "1", "--out"])
            .arg(data),
    );
}
