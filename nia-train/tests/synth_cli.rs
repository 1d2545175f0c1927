//! `nia-train synth` end to end: the binary writes the ZJU-MoCap layout, is deterministic, and
//! rejects bad arguments with a message naming the field.

use std::path::{Path, PathBuf};

use common::{fails_with, nia_train, run_ok};

mod common;

fn scratch(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("nia-train-synth-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// All files under `dir`, relative, sorted, with their bytes.
fn tree(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<(PathBuf, Vec<u8>)>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                out.push((
                    path.strip_prefix(root).unwrap().to_path_buf(),
                    std::fs::read(&path).unwrap(),
                ));
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

fn run_synth(out: &Path, seed: u64) {
    let counts = ["--subjects", "1", "--frames", "2", "--cameras", "3"];
    let seed = seed.to_string();
    let picture = ["--size", "48", "--supersample", "1", "--seed", &seed];
    run_ok(
        nia_train()
            .arg("synth")
            .args(counts)
            .args(picture)
            .arg("--out")
            .arg(out),
    );
}

#[test]
fn synth_writes_the_zju_layout_deterministically() {
    let a = scratch("a");
    let b = scratch("b");
    run_synth(&a, 3);
    run_synth(&b, 3);
    let ta = tree(&a);
    let tb = tree(&b);
    let names: Vec<String> = ta
        .iter()
        .map(|(p, _)| p.to_string_lossy().replace('\\', "/"))
        .collect();
    let subject = names
        .iter()
        .find_map(|n| n.strip_suffix("/annots.npy"))
        .expect("an annots.npy")
        .to_string();
    for expected in [
        format!("{subject}/params/0.npy"),
        format!("{subject}/params/1.npy"),
        format!("{subject}/vertices/1.npy"),
        format!("{subject}/Camera_B1/000000.jpg"),
        format!("{subject}/Camera_B3/000001.jpg"),
        format!("{subject}/mask/Camera_B3/000001.png"),
        "body_model.npz".to_string(),
    ] {
        assert!(names.contains(&expected), "missing {expected} in {names:?}");
    }
    assert_eq!(ta, tb, "same seed must give the same bytes");
    let _ = std::fs::remove_dir_all(&a);
    let _ = std::fs::remove_dir_all(&b);
}

#[test]
fn synth_rejects_a_zero_size_naming_the_field() {
    let out = scratch("bad");
    let output = nia_train()
        .args(["synth", "--size", "0", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    // The message names the field.
    fails_with(&output, &["size"]);
}

#[test]
fn synth_rejects_a_flaw_level_out_of_range_naming_it() {
    let out = scratch("bad-level");
    for (flag, field) in [
        ("--mask-level", "capture.masks"),
        ("--geometry-level", "capture.geometry"),
    ] {
        let output = nia_train()
            .args(["synth", flag, "9", "--out"])
            .arg(&out)
            .output()
            .unwrap();
        fails_with(&output, &[field]);
    }
    let _ = std::fs::remove_dir_all(&out);
}
