//! What a training run leaves for the dashboards: `curves.svg` (loss and PSNR against steps,
//! redrawn on demand by `nia-train curves RUN`) and TensorBoard event files whose scalars and
//! validation images TensorBoard's own reader returns with the logged values.

use std::path::{Path, PathBuf};

use nia_train::tensorboard::read_records;

mod common;

/// The event files of a run folder.
fn event_files(out: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(out.join("tensorboard"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("events.out.tfevents."))
        })
        .collect();
    files.sort();
    files
}

/// TensorBoard's `EventAccumulator` over `dir`: {"scalars": {tag: [[step, value]..]},
/// "images": {tag: [[step, width, height, png_bytes]..]}}.
const READ_WITH_TENSORBOARD: &str = r#"
import json, sys
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
acc = EventAccumulator(sys.argv[1], size_guidance={"scalars": 0, "images": 0})
acc.Reload()
tags = acc.Tags()
out = {"scalars": {}, "images": {}}
for t in tags["scalars"]:
    out["scalars"][t] = [[e.step, e.value] for e in acc.Scalars(t)]
for t in tags["images"]:
    out["images"][t] = [[e.step, e.width, e.height, len(e.encoded_image_string)] for e in acc.Images(t)]
json.dump(out, sys.stdout)
"#;

fn tensorboard_available() -> bool {
    let found = std::process::Command::new("python3")
        .args([
            "-c",
            "import tensorboard.backend.event_processing.event_accumulator",
        ])
        .output()
        .is_ok_and(|o| o.status.success());
    if !found {
        assert!(
            std::env::var("NIA_REQUIRE_TENSORBOARD").as_deref() != Ok("1"),
            "NIA_REQUIRE_TENSORBOARD=1 but python3 with tensorboard is not available"
        );
        eprintln!("skipped: python3 -m pip install tensorboard to check the files with its reader");
    }
    found
}

#[test]
fn a_run_writes_curves_and_event_files_tensorboard_reads() {
    let dir = common::scratch("curves", "run");
    let config = common::tiny_config(&dir, 2, 3, "validate_every = 1\nvalidation_images = 1");
    let out = dir.join("run");
    common::ok(&common::train_run(&[], &config, &out));

    // The logged values, to compare with what the event files hold.
    let log = std::fs::read_to_string(out.join("metrics.jsonl")).unwrap();
    let events: Vec<serde_json::Value> = log
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let losses: Vec<f64> = events
        .iter()
        .filter(|e| e["event"] == "step")
        .map(|e| e["loss"].as_f64().unwrap())
        .collect();
    let validation: Vec<(u64, f64)> = events
        .iter()
        .filter(|e| e["event"] == "validation")
        .map(|e| (e["step"].as_u64().unwrap(), e["psnr"].as_f64().unwrap()))
        .collect();
    assert_eq!(losses.len(), 2);
    assert_eq!(validation.len(), 2);

    // The curves picture, and the same picture on demand.
    let svg = std::fs::read_to_string(out.join("curves.svg")).unwrap();
    for text in ["training loss", "PSNR", "held-out validation", "smoothed"] {
        assert!(svg.contains(text), "curves.svg lacks {text}");
    }
    std::fs::remove_file(out.join("curves.svg")).unwrap();
    common::run_ok(common::nia_train().arg("curves").arg(&out));
    assert_eq!(
        std::fs::read_to_string(out.join("curves.svg")).unwrap(),
        svg
    );
    // A folder without a log is named.
    let none = common::nia_train()
        .arg("curves")
        .arg(&dir)
        .output()
        .unwrap();
    common::fails_with(&none, &["metrics.jsonl"]);

    // One event file: the version event, 4 scalars per step, 2 scalars and one image per
    // validation (no final evaluation here), each record's checksums valid.
    let files = event_files(&out);
    assert_eq!(files.len(), 1, "{files:?}");
    let records = read_records(&files[0]).unwrap();
    assert_eq!(
        records.len(),
        1 + 2 * 4 + 2 * 2 + 2,
        "{} records",
        records.len()
    );

    if !tensorboard_available() {
        return;
    }
    let read = common::run_ok(
        std::process::Command::new("python3")
            .args(["-c", READ_WITH_TENSORBOARD])
            .arg(out.join("tensorboard")),
    );
    let tb: serde_json::Value = serde_json::from_slice(&read.stdout).unwrap();
    let scalars = |tag: &str| -> Vec<(u64, f64)> {
        tb["scalars"][tag]
            .as_array()
            .unwrap_or_else(|| panic!("no scalar {tag}: {tb}"))
            .iter()
            .map(|p| (p[0].as_u64().unwrap(), p[1].as_f64().unwrap()))
            .collect()
    };
    let loss = scalars("train/loss");
    assert_eq!(loss.len(), 2);
    for (i, (step, value)) in loss.iter().enumerate() {
        assert_eq!(*step, i as u64 + 1, "steps counted from 1 (steps done)");
        assert_eq!(*value as f32, losses[i] as f32, "loss of step {i}");
    }
    let psnr = scalars("validation/psnr");
    assert_eq!(psnr.len(), validation.len());
    for ((step, value), (want_step, want)) in psnr.iter().zip(&validation) {
        assert_eq!(step, want_step);
        assert_eq!(*value as f32, *want as f32);
    }
    for tag in [
        "train/psnr",
        "train/lr",
        "train/rays_per_s",
        "validation/ssim",
    ] {
        assert_eq!(
            scalars(tag).len(),
            2,
            "{tag}: one per step or per validation"
        );
    }
    let images = tb["images"]["validation/image_0"].as_array().unwrap();
    assert_eq!(images.len(), 2, "one grid per validation");
    let (w, h, bytes) = (
        images[0][1].as_u64().unwrap(),
        images[0][2].as_u64().unwrap(),
        images[0][3].as_u64().unwrap(),
    );
    assert!(
        w > h && h >= 48 && bytes > 100,
        "a grid of 48 px tiles: {w}x{h}, {bytes} B"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
