//! The `inspect` and `metrics` subcommands, run as a user would, on nia-data's fixtures.

mod common;

use std::path::{Path, PathBuf};

use common::{copy_dir, fails_with, fresh_dir, json_stdout, nia_infer, s};

/// `lbs_max_err_m` on the fixture (its vertices are LBS of its params, rounded to float32).
const LBS_TOL_M: f64 = 1e-5;
/// The CLI's SSIM against scikit-image (the library meets 1e-4; JSON printing keeps ~17 digits).
const SSIM_TOL: f64 = 1e-4;
const PSNR_TOL: f64 = 1e-6;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../nia-data/tests/fixtures")
}

#[test]
fn inspect_prints_one_json_object() {
    let dir = fixtures().join("zju/CoreView_377");
    let smpl = fixtures().join("zju/smpl_tiny.npz");
    let out = nia_infer(&[
        "inspect",
        dir.to_str().unwrap(),
        "--smpl",
        smpl.to_str().unwrap(),
    ]);
    let v = json_stdout(&out);
    assert_eq!(v["subject"], "CoreView_377");
    assert_eq!(v["num_cameras"], 4);
    assert_eq!(v["num_frames"], 2);
    assert_eq!(v["num_vertices"], 30);
    assert_eq!(v["image_size"], serde_json::json!([32, 32]));
    let k = &v["camera0"]["K"];
    assert!(k[0][0].as_f64().unwrap() > 40.0 && k[2][2] == 1.0, "{k}");
    // T in metres: the fixture's cameras stand 3 m from the body.
    let t: Vec<f64> = v["camera0"]["T"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let norm = t.iter().map(|x| x * x).sum::<f64>().sqrt();
    assert!(norm > 1.0 && norm < 10.0, "{t:?}");
    assert_eq!(v["camera0"]["R"].as_array().unwrap().len(), 3);
    for axis in 0..3 {
        assert!(v["bbox_min"][axis].as_f64().unwrap() < v["bbox_max"][axis].as_f64().unwrap());
    }
    let cov = v["mask_coverage"].as_f64().unwrap();
    assert!(cov > 0.02 && cov < 0.5, "{cov}");
    assert!(v["lbs_max_err_m"].as_f64().unwrap() < LBS_TOL_M);
    // Without --smpl there is no LBS error; the 313-style subject reads too.
    let dir313 = fixtures().join("zju/CoreView_313");
    let v = json_stdout(&nia_infer(&[
        "inspect",
        dir313.to_str().unwrap(),
        "--ratio",
        "1",
    ]));
    assert_eq!(v["image_size"], serde_json::json!([64, 64]));
    assert!(v.get("lbs_max_err_m").is_none());
}

#[test]
fn inspect_of_malformed_folders_fails_naming_the_file() {
    let root = fresh_dir("cli");
    let subject = root.join("CoreView_377");
    copy_dir(&fixtures().join("zju/CoreView_377"), &subject);
    std::fs::remove_dir_all(subject.join("Camera_B2")).unwrap();
    let good = fixtures().join("zju/CoreView_377");
    let bad = fixtures().join("zju/bad/smpl_one_vertex_fewer.npz");
    let cases: [(Vec<&str>, &[&str]); 4] = [
        (vec![s(&subject)], &["Camera_B2", "camera folder missing"]),
        // MonoCap needs lbs/.
        (vec![s(&good), "--format", "monocap"], &["lbs", "missing"]),
        // An SMPL model with another vertex count.
        (
            vec![s(&good), "--smpl", s(&bad)],
            &["29 vertices", "vertices/0.npy"],
        ),
        (vec![s(&good), "--format", "colmap"], &[]),
    ];
    for (args, expected) in cases {
        fails_with(&nia_infer(&[&["inspect"][..], &args].concat()), expected);
    }
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn metrics_match_scikit_image() {
    let dir = fixtures().join("ssim");
    let values: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("values.json")).unwrap()).unwrap();
    let mut checked = 0;
    for case in values["cases"].as_array().unwrap() {
        if case["channels"] != 3 {
            continue;
        }
        let pred = dir.join(case["pred"].as_str().unwrap());
        let gt = dir.join(case["gt"].as_str().unwrap());
        let mut args = vec![
            "metrics".to_string(),
            "--pred".into(),
            pred.display().to_string(),
            "--gt".into(),
            gt.display().to_string(),
        ];
        let want_ssim = match case["mask"].as_str() {
            Some(mask) => {
                args.push("--mask".into());
                args.push(dir.join(mask).display().to_string());
                case["nhp_ssim"].as_f64().unwrap()
            }
            None => case["ssim_range2"].as_f64().unwrap(),
        };
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let v = json_stdout(&nia_infer(&args));
        let ssim = v["ssim"].as_f64().unwrap();
        assert!(
            (ssim - want_ssim).abs() < SSIM_TOL,
            "{}: {ssim} vs {want_ssim}",
            case["name"]
        );
        if let Some(want_psnr) = case["nhp_psnr"].as_f64() {
            let psnr = v["psnr"].as_f64().unwrap();
            assert!((psnr - want_psnr).abs() < PSNR_TOL, "{psnr} vs {want_psnr}");
        }
        let mut one = args.clone();
        one.extend(["--ssim-data-range", "1"]);
        if case["mask"].is_null() {
            let v = json_stdout(&nia_infer(&one));
            let want = case["ssim_range1"].as_f64().unwrap();
            assert!((v["ssim"].as_f64().unwrap() - want).abs() < SSIM_TOL);
        }
        checked += 1;
    }
    assert_eq!(checked, 4);
}

#[test]
fn metrics_of_mismatched_images_fail_with_a_message() {
    let dir = fixtures().join("ssim");
    let gt = dir.join("dark_gt.png");
    for (pred, expected) in [
        (
            "noisy_field_pred.png",
            &["noisy_field_pred.png", "40x32", "16x16"][..],
        ),
        ("missing.png", &["missing.png"]),
    ] {
        let pred = dir.join(pred);
        fails_with(
            &nia_infer(&["metrics", "--pred", s(&pred), "--gt", s(&gt)]),
            expected,
        );
    }
}

/// The render flags are checked before the model file is read: a dilation past the limit, a
/// switch that is not on or off, a supersampling of 0 or past the limit, an unknown ray sampler
/// and a band margin out of bounds or without a band are errors naming the flag.
#[test]
fn bad_render_flags_fail_naming_the_flag() {
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/quickstart_tiny.nia");
    // `eval` with `flags` fails before reading the model; its stderr.
    let refused = |flags: &[&str]| {
        let mut args = vec![
            "eval",
            "--model",
            model.to_str().unwrap(),
            "--out",
            "/nonexistent/eval",
        ];
        args.extend_from_slice(flags);
        let out = nia_infer(&args);
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    for (flag, value, expected) in [
        ("--hull-body-erode-px", "1000", "256"),
        ("--hull-body-erode-px", "on", "off or a number of pixels"),
        ("--visual-hull", "maybe", "on or off"),
        ("--smpl-alignment", "maybe", "on or off"),
        ("--supersample", "0", "1 to 8"),
        ("--supersample", "9", "1 to 8"),
        ("--ray-sampler", "box", "band or stratified"),
        ("--band-margin-m", "0", "(0, 1] metres"),
        ("--band-margin-m", "NaN", "(0, 1] metres"),
    ] {
        let err = refused(&[flag, value]);
        assert!(err.contains(flag) && err.contains(expected), "{err}");
    }
    // A margin with a stratified sampler says what to pass instead.
    let err = refused(&["--ray-sampler", "stratified", "--band-margin-m", "0.1"]);
    assert!(err.contains("--ray-sampler band"), "{err}");
}
