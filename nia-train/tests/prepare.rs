//! `nia-train prepare` end to end on a tiny generated subject: the fitted folder is the
//! ZJU-MoCap layout the readers take, and bad inputs are refused naming the file, with nothing
//! written.

use std::path::{Path, PathBuf};

use common::{fails_with, nia_train, run_ok, scratch};
use nia_data::dataset::zju::{read_annots, read_params, read_vertices};

mod common;

/// Image size of the tiny subject (pixels).
const SIZE: u32 = 96;

/// A fitter config small enough for a test (a few Adam steps per stage).
const FIT_CONFIG: &str = r#"{"global_iterations": 10, "cold_iterations": 25, "warm_iterations": 10,
  "shape_iterations": 10, "shape_frames": 1, "silhouette_vertices": 200, "boundary_samples": 50}"#;

/// A generated set (1 subject, 2 frames, 3 cameras, keypoints) in `dir/gen`, its capture
/// folder without `params/` and `vertices/` in `dir/input/CoreView_1`, and the fit config.
fn capture(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let generated = dir.join("gen");
    let size = SIZE.to_string();
    run_ok(
        nia_train()
            .args([
                "synth",
                "--subjects",
                "1",
                "--frames",
                "2",
                "--cameras",
                "3",
                "--size",
                &size,
                "--supersample",
                "1",
                "--seed",
                "7",
                "--keypoints",
            ])
            .arg("--out")
            .arg(&generated),
    );
    let input = dir.join("input").join("CoreView_1");
    copy_dir(
        &generated.join("CoreView_1"),
        &input,
        &["params", "vertices"],
    );
    let config = dir.join("fit.json");
    std::fs::write(&config, FIT_CONFIG).unwrap();
    (generated, input, config)
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

fn prepare(input: &Path, generated: &Path, config: &Path, out: &Path) -> std::process::Command {
    let mut c = nia_train();
    c.arg("prepare")
        .arg("--input")
        .arg(input)
        .arg("--smpl")
        .arg(generated.join("body_model.npz"))
        .arg("--out")
        .arg(out)
        .arg("--fit-config")
        .arg(config);
    c
}

#[test]
fn prepare_writes_the_zju_layout_the_readers_take() {
    let dir = scratch("prepare", "layout");
    let (generated, input, config) = capture(&dir);
    let out = dir.join("fitted");
    let output = run_ok(
        prepare(&input, &generated, &config, &out)
            .arg("--truth")
            .arg(generated.join("CoreView_1")),
    );
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("MPJPE"), "{stdout}");
    let subject = out.join("CoreView_1");
    let annots = read_annots(&subject.join("annots.npy")).unwrap();
    assert_eq!(annots.cams.len(), 3);
    assert_eq!(annots.ims.len(), 2);
    let truth_vertices = read_vertices(&generated.join("CoreView_1/vertices/0.npy")).unwrap();
    for frame in 0..2 {
        let params = read_params(&subject.join(format!("params/{frame}.npy"))).unwrap();
        assert_eq!(params.poses[..3], [0.0; 3]);
        assert_eq!(params.shapes.len(), 10);
        let vertices = read_vertices(&subject.join(format!("vertices/{frame}.npy"))).unwrap();
        assert_eq!(vertices.len(), truth_vertices.len());
    }
    for rel in [
        "Camera_B1/000000.jpg",
        "mask/Camera_B3/000001.png",
        "fit_overlay/Camera_B2/000000.png",
        "fit.json",
    ] {
        assert!(subject.join(rel).is_file(), "{rel} missing");
    }
    // Only the subject folder: no staging folder left behind.
    let names: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, vec![std::ffi::OsString::from("CoreView_1")]);
    // A second run does not replace it unasked.
    let again = prepare(&input, &generated, &config, &out).output().unwrap();
    fails_with(&again, &["already exists", "--overwrite"]);
}

/// A bad input: how to break a fresh capture copy, and what stderr must say.
struct Case {
    name: &'static str,
    breaks: fn(&Path, &Path),
    expected: &'static [&'static str],
    colmap: bool,
}

fn write_png(path: &Path, w: u32, h: u32) {
    image::GrayImage::from_pixel(w, h, image::Luma([255u8]))
        .save(path)
        .unwrap();
}

#[test]
fn bad_inputs_are_refused_naming_the_file_and_nothing_is_written() {
    let dir = scratch("prepare", "bad");
    let (generated, clean, config) = capture(&dir);
    let cases = [
        Case {
            name: "a missing mask",
            breaks: |input, _| {
                std::fs::remove_file(input.join("mask/Camera_B2/000001.png")).unwrap()
            },
            expected: &["mask/Camera_B2/000001.png", "missing"],
            colmap: false,
        },
        Case {
            name: "a missing view",
            breaks: |input, _| std::fs::remove_dir_all(input.join("Camera_B3")).unwrap(),
            expected: &["Camera_B3/000000.jpg", "missing"],
            colmap: false,
        },
        Case {
            name: "keypoints of the wrong count",
            breaks: |input, _| {
                let values = vec!["1.0"; 30].join(", ");
                let json = format!(
                    r#"{{"version": 1.3, "people": [{{"pose_keypoints_2d": [{values}]}}]}}"#
                );
                std::fs::write(
                    input.join("keypoints/Camera_B1/000000_keypoints.json"),
                    json,
                )
                .unwrap();
            },
            expected: &["Camera_B1/000000_keypoints.json", "75"],
            colmap: false,
        },
        Case {
            name: "keypoints that are not JSON",
            breaks: |input, _| {
                std::fs::write(
                    input.join("keypoints/Camera_B2/000001_keypoints.json"),
                    "nope",
                )
                .unwrap();
            },
            expected: &["Camera_B2/000001_keypoints.json", "JSON"],
            colmap: false,
        },
        Case {
            name: "a mask of the wrong size",
            breaks: |input, _| write_png(&input.join("mask/Camera_B1/000001.png"), 20, 20),
            expected: &["mask/Camera_B1/000001.png", "20x20", "96x96"],
            colmap: false,
        },
        Case {
            name: "a COLMAP camera model the reader does not take",
            breaks: |_, colmap| {
                std::fs::create_dir_all(colmap).unwrap();
                std::fs::write(
                    colmap.join("cameras.txt"),
                    "1 SIMPLE_RADIAL 96 96 100 48 48 0.01\n",
                )
                .unwrap();
                std::fs::write(
                    colmap.join("images.txt"),
                    "1 1 0 0 0 0 0 3 1 Camera_B1/000000.jpg\n\n",
                )
                .unwrap();
            },
            expected: &["cameras.txt", "SIMPLE_RADIAL"],
            colmap: true,
        },
    ];
    for (i, case) in cases.iter().enumerate() {
        let root = dir.join(format!("case{i}"));
        let input = root.join("CoreView_1");
        copy_dir(&clean, &input, &[]);
        let colmap = root.join("colmap");
        (case.breaks)(&input, &colmap);
        let out = root.join("fitted");
        let mut command = prepare(&input, &generated, &config, &out);
        if case.colmap {
            command
                .arg("--cameras")
                .arg(format!("colmap:{}", colmap.display()));
        }
        let output = command.output().unwrap();
        let stderr = fails_with(&output, case.expected);
        assert!(!stderr.contains("NaN"), "{}: {stderr}", case.name);
        let left: Vec<_> = std::fs::read_dir(&out)
            .map(|d| d.map(|e| e.unwrap().file_name()).collect())
            .unwrap_or_default();
        assert!(left.is_empty(), "{}: left {left:?}", case.name);
    }
}

/// A capture prepared subject by subject is a dataset root the trainer takes unchanged: a set
/// of 2 people (1 trained, 1 held out) with keypoints, its true `params/` and `vertices/`
/// removed, each subject fitted by `prepare`, then 2 training steps and the unseen-subject
/// evaluation on the fitted root.
#[test]
fn a_prepared_root_trains_and_evaluates() {
    let dir = scratch("prepare", "train");
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
                "48",
                "--supersample",
                "1",
                "--seed",
                "7",
                "--keypoints",
            ])
            .arg("--out")
            .arg(&generated),
    );
    let config = dir.join("fit.json");
    std::fs::write(&config, FIT_CONFIG).unwrap();
    let root = dir.join("fitted");
    std::fs::create_dir_all(&root).unwrap();
    // What a user copies beside the fitted subjects: the SMPL file and (for the synthetic
    // split protocol) the set's description.
    for file in ["body_model.npz", "synth.json"] {
        std::fs::copy(generated.join(file), root.join(file)).unwrap();
    }
    for subject in ["CoreView_1", "CoreView_2"] {
        let input = dir.join("input").join(subject);
        copy_dir(&generated.join(subject), &input, &["params", "vertices"]);
        run_ok(&mut prepare(&input, &generated, &config, &root));
        assert!(root.join(subject).join("params/1.npy").is_file());
    }
    let text = format!(
        "{data}\n[model]\npreset = \"tiny\"\n\n[optim]\nlr = 5e-4\ndecay_steps = 1000\n\n\
         [train]\nsteps = 2\nrays_per_step = 32\nsamples = 8\nsource_views = 3\nseed = 7\n\
         checkpoint_every = 2\nbackend = \"ndarray\"\nevaluate_at_end = true\n",
        data = common::data_sections(&root, 48, 1, ""),
    );
    let train_config = dir.join("train.toml");
    std::fs::write(&train_config, text).unwrap();
    let out = dir.join("run");
    let run = common::train_run(&[], &train_config, &out);
    common::ok(&run);
    let log = std::fs::read_to_string(out.join("metrics.jsonl")).unwrap();
    let evaluation = log
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|e| e["event"] == "evaluation" && e["split"] == "unseen_subjects")
        .unwrap_or_else(|| panic!("no unseen-subject evaluation in {log}"));
    assert!(evaluation["images"].as_u64().unwrap() > 0, "{evaluation}");
    let psnr = evaluation["psnr"].as_f64().unwrap();
    assert!(psnr.is_finite() && psnr > 0.0, "{evaluation}");
}
