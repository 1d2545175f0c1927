//! What nia-infer's integration tests share: the binary and its outcomes, scratch folders, and a
//! tiny model trained in-process by nia-train and exported by `nia-infer export`.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use nia_data::synth::SynthSpec;
use nia_train::config::TrainConfig;
use nia_train::events::TrainEvent;
use nia_train::train_loop::{train, RunOptions};

/// Runs the `nia-infer` binary of this build with `args`.
pub fn nia_infer(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nia-infer"))
        .args(args)
        .output()
        .expect("run nia-infer")
}

/// Asserts that the command exited with success, showing its stderr otherwise.
pub fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "nia-infer failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Exit non-zero with every `expected` text in stderr, and no panic.
pub fn fails_with(out: &Output, expected: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "expected a failure, got success");
    assert!(!err.contains("panicked"), "panicked: {err}");
    for e in expected {
        assert!(err.contains(e), "stderr lacks `{e}`: {err}");
    }
}

/// The one JSON object a successful command printed.
pub fn json_stdout(out: &Output) -> serde_json::Value {
    ok(out);
    serde_json::from_slice(&out.stdout).expect("stdout is one JSON object")
}

/// A JSON file a command wrote.
pub fn json_file(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// How many frames the GIF at `path` holds.
pub fn gif_frames(path: &Path) -> usize {
    use image::AnimationDecoder;
    let gif = std::fs::File::open(path).unwrap();
    image::codecs::gif::GifDecoder::new(std::io::BufReader::new(gif))
        .unwrap()
        .into_frames()
        .collect_frames()
        .unwrap()
        .len()
}

/// One synthetic person unseen in training, `CoreView_<id>`: `frames` frames seen by `cameras`
/// cameras of `size` px, drawn with `seed`, without supersampling.
pub fn unseen_spec(id: u32, frames: usize, cameras: usize, size: u32, seed: u64) -> SynthSpec {
    SynthSpec {
        first_subject_id: id,
        frames,
        cameras,
        size,
        seed,
        subjects: 1,
        supersample: 1,
        ..SynthSpec::default()
    }
}

/// A path as a command-line argument.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A fresh empty folder `<tmp>/nia-infer-<name>-<pid>`.
pub fn fresh_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nia-infer-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Copies the tree under `from` to `to`, folder by folder.
pub fn copy_dir(from: &Path, to: &Path) {
    let mut pending = vec![(from.to_path_buf(), to.to_path_buf())];
    while let Some((src, dst)) = pending.pop() {
        std::fs::create_dir_all(&dst).unwrap();
        for entry in std::fs::read_dir(&src).unwrap().map(Result::unwrap) {
            let target = dst.join(entry.file_name());
            if entry.file_type().unwrap().is_dir() {
                pending.push((entry.path(), target));
            } else {
                std::fs::copy(entry.path(), &target).unwrap();
            }
        }
    }
}

/// The tiny network trained in-process through nia-train's library (the same loop as its
/// binary) for 2 steps on a synthetic set in `<dir>/data` (2 subjects, 3 frames, 4 cameras of
/// `size` px), checkpointed in `<dir>/run` and exported by `nia-infer export` to
/// `<dir>/tiny.nia`: (run folder, model file). Every training event goes to `on_event`.
pub fn train_tiny(
    dir: &Path,
    size: u32,
    seed: u64,
    evaluate_at_end: bool,
    on_event: &mut dyn FnMut(TrainEvent),
) -> (PathBuf, PathBuf) {
    let config = dir.join("tiny.toml");
    let root = dir.join("data").display().to_string().replace('\\', "/");
    let text = format!(
        "[data]\nroot = \"{root}\"\nratio = 1.0\nborder_px = 1\nloader_threads = 1\n\n\
         [synth]\nsubjects = 2\nframes = 3\ncameras = 4\nsize = {size}\nsupersample = 1\n\
         test_fraction = 0.5\n\n[model]\npreset = \"tiny\"\n\n[train]\nsteps = 2\n\
         rays_per_step = 32\nsamples = 8\nsource_views = 3\nseed = {seed}\n\
         checkpoint_every = 2\nvalidate_every = 0\nevaluate_at_end = {evaluate_at_end}\n\
         backend = \"ndarray\"\n"
    );
    std::fs::write(&config, text).unwrap();
    let config = TrainConfig::load(&config).unwrap();
    let run = dir.join("run");
    let options = RunOptions {
        out: run.clone(),
        resume: false,
    };
    train(&config, &options, on_event).unwrap();
    let model = dir.join("tiny.nia");
    ok(&nia_infer(&[
        "export",
        "--checkpoint",
        s(&run),
        "--out",
        s(&model),
    ]));
    (run, model)
}
