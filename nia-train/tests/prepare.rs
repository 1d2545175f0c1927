//! `nia-train prepare` end to end on a tiny generated subject: the fitted folder is the
//! ZJU-MoCap layout the readers take, and bad inputs are refused naming the file, with nothing
//! written.

use std::path::{Path, PathBuf};

use common::{fails_with, nia_train, run_ok, scratch};
use nia_data::dataset::zju::{read_annots, read_params, read_vertices};
use nia_data::formats::npy::write_object;
use nia_data::formats::value::PyValue;
use nia_data::synth::writer::annots_value;

mod common;

/// Image size of the tiny subject (pixels).
const SIZE: u32 = 96;

/// Largest MPJPE and mean vertex error the tiny capture's fit may print, cm (measured
/// 3.14 / 2.95 cm at 96 px, 3 views, 2 frames; 2 px of keypoint noise is about 2 cm there).
const MAX_TEST_FIT_ERROR_CM: f32 = 6.0;

/// A fitter config small enough for a test (a few solver steps per stage).
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
    // "against the truth: MPJPE X cm (worst frame Y cm), mean vertex error Z cm": the fit of
    // this tiny capture (3 views of 96 px, a few steps per stage) lands within a few cm.
    let cm = |after: &str| -> f32 {
        let tail = &stdout[stdout
            .find(after)
            .unwrap_or_else(|| panic!("{after}: {stdout}"))
            + after.len()..];
        tail.split_whitespace().next().unwrap().parse().unwrap()
    };
    let (mpjpe, vertices) = (cm("MPJPE "), cm("mean vertex error "));
    assert!(
        mpjpe.is_finite() && mpjpe < MAX_TEST_FIT_ERROR_CM && vertices < MAX_TEST_FIT_ERROR_CM,
        "MPJPE {mpjpe} cm, vertices {vertices} cm: {stdout}"
    );
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
            name: "a missing keypoint file",
            breaks: |input, _| {
                std::fs::remove_file(input.join("keypoints/Camera_B2/000001_keypoints.json"))
                    .unwrap()
            },
            expected: &["Camera_B2/000001_keypoints.json", "missing"],
            colmap: false,
        },
        Case {
            name: "annots.npy listing fewer images than cameras in a frame",
            breaks: |input, _| {
                let path = input.join("annots.npy");
                let annots = read_annots(&path).unwrap();
                let cameras: Vec<_> = annots
                    .cams
                    .iter()
                    .map(|c| c.camera(SIZE, SIZE).unwrap())
                    .collect();
                let mut value = annots_value(&cameras, annots.ims.len());
                // Frame 1 lists two images for the three cameras.
                if let PyValue::Dict(entries) = &mut value {
                    for (key, frames) in entries.iter_mut() {
                        if key == &PyValue::Str("ims".into()) {
                            let PyValue::List(frames) = frames else {
                                unreachable!()
                            };
                            let PyValue::Dict(frame) = &mut frames[1] else {
                                unreachable!()
                            };
                            let PyValue::List(images) = &mut frame[0].1 else {
                                unreachable!()
                            };
                            images.pop();
                        }
                    }
                }
                write_object(&path, &value).unwrap();
            },
            expected: &[
                "annots.npy",
                "ims[1]['ims']",
                "expected 3 image paths",
                "found 2",
            ],
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
