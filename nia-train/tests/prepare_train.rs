//! The folder `nia-train prepare` writes trains and evaluates as a user would run it (issue 37):
//! every subject of a tiny generated set fitted into one root, which has no `synth.json`, then
//! `nia-train --config configs/own_capture.toml` for two steps with the unseen-subject
//! evaluation at the end. A config with `[synth]` is refused on that root, naming it and what
//! to do, and leaves it untouched (before, it generated a synthetic set over the user's data).

use std::path::{Path, PathBuf};

use common::{fails_with, nia_train, run_ok, scratch};

mod common;

/// A fitter config small enough for a test (a few Adam steps per stage).
const FIT_CONFIG: &str = r#"{"global_iterations": 10, "cold_iterations": 25, "warm_iterations": 10,
  "shape_iterations": 10, "shape_frames": 1, "silhouette_vertices": 200, "boundary_samples": 50}"#;

fn in_workspace(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

fn copy_dir(from: &Path, to: &Path, skip: &[&str]) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if skip.contains(&name.as_str()) {
            continue;
        }
        if path.is_dir() {
            copy_dir(&path, &to.join(&name), &[]);
        } else {
            std::fs::copy(&path, to.join(&name)).unwrap();
        }
    }
}

/// Two generated people (2 frames, 4 cameras, 64 px, keypoints), each fitted by `prepare`
/// from a copy without `params/` and `vertices/` into `dir/fitted`; returns the root and the
/// SMPL model file.
fn fitted_root(dir: &Path) -> (PathBuf, PathBuf) {
    let generated = dir.join("gen");
    run_ok(
        nia_train()
            .args([
                "synth",
                "--subjects",
                "2",
                "--frames",
                "2",
                "--cameras",
                "4",
            ])
            .args([
                "--size",
                "64",
                "--supersample",
                "1",
                "--seed",
                "5",
                "--keypoints",
            ])
            .arg("--out")
            .arg(&generated),
    );
    let fit_config = dir.join("fit.json");
    std::fs::write(&fit_config, FIT_CONFIG).unwrap();
    let smpl = generated.join("body_model.npz");
    let root = dir.join("fitted");
    for subject in ["CoreView_1", "CoreView_2"] {
        let input = dir.join("input").join(subject);
        copy_dir(&generated.join(subject), &input, &["params", "vertices"]);
        run_ok(
            nia_train()
                .arg("prepare")
                .arg("--input")
                .arg(&input)
                .arg("--smpl")
                .arg(&smpl)
                .arg("--out")
                .arg(&root)
                .arg("--fit-config")
                .arg(&fit_config)
                .args(["--overlay-frames", "1"]),
        );
    }
    (root, smpl)
}

/// Every file under `dir` with its length, sorted (what "untouched" is checked against).
fn listing(dir: &Path) -> Vec<(PathBuf, u64)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let len = path.metadata().unwrap().len();
                out.push((path, len));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn the_prepared_root_trains_and_evaluates_with_the_own_capture_config() {
    let dir = scratch("prepare-train", "own");
    let (root, smpl) = fitted_root(&dir);
    assert!(!root.join("synth.json").exists());
    let before = listing(&root);

    // The quickstart's config generates data when its root has no synth.json: refused here,
    // naming the root and the way out, with nothing written.
    let refused = nia_train()
        .arg("--config")
        .arg(in_workspace("configs/quickstart_clean.toml"))
        .arg("--set")
        .arg(format!("data.root={}", common::slash(&root)))
        .args(["--set", "train.steps=2"])
        .arg("--out")
        .arg(dir.join("run_refused"))
        .output()
        .unwrap();
    let root_name = root.display().to_string();
    fails_with(
        &refused,
        &[
            &root_name,
            "synth.json",
            "[synth]",
            "configs/own_capture.toml",
        ],
    );
    assert_eq!(
        listing(&root),
        before,
        "the refused run left the root as it was"
    );

    // The shipped config, as docs/own-capture.md runs it (smaller split and views: 2 people,
    // 4 cameras), trains and evaluates the held-out person.
    let out = dir.join("run");
    let output = run_ok(
        nia_train()
            .arg("--config")
            .arg(in_workspace("configs/own_capture.toml"))
            .arg("--set")
            .arg(format!("data.root={}", common::slash(&root)))
            .arg("--set")
            .arg(format!("data.smpl_model={}", common::slash(&smpl)))
            .args(["--set", r#"data.split.train=["CoreView_1"]"#])
            .args(["--set", r#"data.split.test=["CoreView_2"]"#])
            .args(["--set", "data.split.input_views=[0, 2]"])
            .args(["--set", "data.split.train_frames=1"])
            .args(["--set", "train.source_views=2", "--set", "train.steps=2"])
            .args([
                "--set",
                "train.rays_per_step=64",
                "--set",
                "train.samples=8",
            ])
            .args(["--set", "render.supersample=1"])
            .arg("--out")
            .arg(&out),
    );
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains(r#"held out ["CoreView_2"]"#), "{stdout}");
    assert!(
        stdout.contains("evaluation (unseen_subjects, 4 images)"),
        "2 frames x 2 target views of the held-out person: {stdout}"
    );
    assert!(out.join("metrics.jsonl").is_file());

    // A held-out person the split names but the root lacks is a typo: refused, named.
    let typo = nia_train()
        .arg("--config")
        .arg(in_workspace("configs/own_capture.toml"))
        .arg("--set")
        .arg(format!("data.root={}", common::slash(&root)))
        .arg("--set")
        .arg(format!("data.smpl_model={}", common::slash(&smpl)))
        .args(["--set", r#"data.split.train=["CoreView_1"]"#])
        .args(["--set", r#"data.split.test=["CoreView_9"]"#])
        .args(["--set", "data.split.input_views=[0, 2]"])
        .args(["--set", "data.split.train_frames=1"])
        .args(["--set", "train.source_views=2", "--set", "train.steps=1"])
        .arg("--out")
        .arg(dir.join("run_typo"))
        .output()
        .unwrap();
    fails_with(&typo, &["CoreView_9", "is missing", "[data.split]"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_subjects_protocol_without_a_split_is_refused_naming_the_config() {
    let dir = scratch("prepare-train", "nosplit");
    let config = dir.join("own.toml");
    let text = std::fs::read_to_string(in_workspace("configs/own_capture.toml")).unwrap();
    let start = text.find("\n[data.split]\n").unwrap() + 1;
    let end = start + text[start..].find("\n[").unwrap() + 1;
    let without_split = format!("{}{}", &text[..start], &text[end..]);
    std::fs::write(&config, without_split).unwrap();
    std::fs::write(dir.join("body_model.npz"), b"").unwrap();
    let output = nia_train()
        .arg("--config")
        .arg(&config)
        .arg("--set")
        .arg(format!("data.root={}", common::slash(&dir)))
        .arg("--set")
        .arg(format!(
            "data.smpl_model={}",
            common::slash(&dir.join("body_model.npz"))
        ))
        .arg("--out")
        .arg(dir.join("run"))
        .output()
        .unwrap();
    fails_with(&output, &["own.toml", "data.split", "train = [...]"]);
    let _ = std::fs::remove_dir_all(&dir);
}
