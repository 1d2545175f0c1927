//! `nia-infer export`, `eval`, `render` and `animate` on a model really trained by `nia-train`
//! (2 steps of the tiny network on a tiny synthetic dataset), run as a user would, plus the
//! errors of broken model files and data folders.

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::OnceLock;

use common::{
    copy_dir, fails_with, fresh_dir, gif_frames, json_file, nia_infer, ok, s, train_tiny,
};
use nia_data::dataset::protocol::EvalSplit;
use nia_data::dataset::OpenedDataset;
use nia_eval::eval::{eval_items, evaluate_images, EvalOptions, EvalTask};
use nia_model::store::checkpoint;
use nia_model::store::model_file::{ModelFile, MAGIC};
use nia_train::config::TrainConfig;
use nia_train::events::TrainEvent;

/// Eval in nia-infer and at the end of training render the same rays with the same weights
/// (including BatchNorm's running statistics) in the same default chunk; the tolerance allows
/// float sums reordered between the two processes.
const EVAL_REPRODUCE_TOL_DB: f64 = 1e-6;
const EVAL_REPRODUCE_TOL_SSIM: f64 = 1e-7;
/// The bound for an exported model against its checkpoint.
const EXPORT_RENDER_TOL: f32 = 1e-5;

/// A trained tiny run shared by the tests: (scratch folder, run folder, the final evaluation
/// event of nia-train).
struct Trained {
    dir: PathBuf,
    run: PathBuf,
    model: PathBuf,
    evaluation: serde_json::Value,
}

fn trained() -> &'static Trained {
    static TRAINED: OnceLock<Trained> = OnceLock::new();
    TRAINED.get_or_init(|| {
        let dir = fresh_dir("models");
        let mut evaluation = None;
        let (run, model) = train_tiny(&dir, 40, 11, true, &mut |event| {
            if let TrainEvent::Evaluation {
                images, psnr, ssim, ..
            } = event
            {
                evaluation = Some(serde_json::json!({
                    "images": images, "psnr": psnr, "ssim": ssim
                }));
            }
        });
        let evaluation = evaluation.expect("nia-train evaluated the unseen subject");
        Trained {
            dir,
            run,
            model,
            evaluation,
        }
    })
}

/// `nia-infer COMMAND --model <the trained model> FLAGS.. EXTRA.. --out OUT`, where `flags` are
/// words separated by spaces and `extra` the arguments with paths or spaces.
fn on_model(command: &str, flags: &str, extra: &[&str], out: &Path) -> Output {
    let mut args = vec![command, "--model", s(&trained().model)];
    args.extend(flags.split_whitespace());
    args.extend_from_slice(extra);
    args.extend(["--out", s(out)]);
    nia_infer(&args)
}

/// Runs `eval` on the trained model with `flags`, asserts that it fails, and returns its stderr.
fn refused_eval(flags: &str, out: &Path) -> String {
    let refused = on_model("eval", flags, &[], out);
    assert!(!refused.status.success(), "`eval {flags}` succeeded");
    String::from_utf8_lossy(&refused.stderr).into_owned()
}

fn scratch(name: &str) -> PathBuf {
    let dir = trained().dir.join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn export_writes_a_self_describing_file() {
    let t = trained();
    let bytes = std::fs::read(&t.model).unwrap();
    assert_eq!(&bytes[..8], MAGIC);
    let file = ModelFile::parse(&t.model, &bytes).unwrap();
    assert_eq!(file.header.step, 2);
    assert_eq!(file.header.model.encoder_width, 8, "the tiny preset");
    assert_eq!(file.header.run["train"]["samples"], 8);
}

#[test]
fn eval_reproduces_the_numbers_training_printed() {
    let t = trained();
    let out_dir = scratch("eval");
    ok(&on_model("eval", "--backend ndarray", &[], &out_dir));
    let metrics = json_file(&out_dir.join("metrics.json"));
    let overall = &metrics["overall"];
    assert_eq!(overall["images"], t.evaluation["images"]);
    let (psnr, train_psnr) = (
        overall["psnr"].as_f64().unwrap(),
        t.evaluation["psnr"].as_f64().unwrap(),
    );
    let (ssim, train_ssim) = (
        overall["ssim"].as_f64().unwrap(),
        t.evaluation["ssim"].as_f64().unwrap(),
    );
    assert!(
        (psnr - train_psnr).abs() < EVAL_REPRODUCE_TOL_DB,
        "eval {psnr} vs training {train_psnr}"
    );
    assert!((ssim - train_ssim).abs() < EVAL_REPRODUCE_TOL_SSIM);
    // Per image in JSON and CSV, per subject, the report table, and the pictures.
    let images = metrics["images"].as_array().unwrap();
    assert_eq!(images.len() as u64, overall["images"].as_u64().unwrap());
    for image in images {
        assert!(image["psnr"].as_f64().unwrap().is_finite());
        let rays = image["rays"].as_u64().unwrap();
        // Empty-space skipping (on by default) evaluates a part of the rays x samples.
        let points = image["point_evaluations"].as_u64().unwrap();
        assert!(points > 0 && points < rays * 8, "{points} of {}", rays * 8);
        assert!(image["stage_ms"]["encoder"].as_f64().unwrap() > 0.0);
        let stem = format!(
            "{}_frame{:04}_view{:02}",
            image["subject"].as_str().unwrap(),
            image["frame"].as_u64().unwrap(),
            image["target_view"].as_u64().unwrap()
        );
        // Panels of 40 px with 2 px gaps: the grid's 3 sources + prediction + ground truth +
        // error map; the parts' C0 + IBR-only + prediction + ground truth + opacity; the
        // blend's NeRF + 3 source-view channels.
        for (picture, panels) in [("grid", 6), ("parts", 5), ("blend", 4)] {
            let png = image::open(
                out_dir
                    .join("pictures")
                    .join(format!("{stem}_{picture}.png")),
            )
            .unwrap();
            assert_eq!(png.width(), panels * 40 + (panels - 1) * 2, "{picture}");
            if picture != "blend" {
                assert_eq!(png.height(), 40, "{picture}");
            }
        }
    }
    assert_eq!(metrics["subjects"].as_object().unwrap().len(), 1);
    let csv = std::fs::read_to_string(out_dir.join("metrics.csv")).unwrap();
    assert_eq!(csv.lines().count(), images.len() + 1);
    let report = std::fs::read_to_string(out_dir.join("report.md")).unwrap();
    assert!(report.contains(&format!("**{psnr:.2}**")), "{report}");
    assert_eq!(metrics["stage_times"], true);

    // Without the stage timings: the same scores to the bit, no stage in any image's row.
    let untimed_dir = scratch("eval-untimed");
    ok(&on_model(
        "eval",
        "--backend ndarray --no-stage-times --no-pictures",
        &[],
        &untimed_dir,
    ));
    let untimed = json_file(&untimed_dir.join("metrics.json"));
    assert_eq!(untimed["stage_times"], false);
    assert_eq!(untimed["overall"]["psnr"], overall["psnr"]);
    assert_eq!(untimed["overall"]["ssim"], overall["ssim"]);
    let untimed_images = untimed["images"].as_array().unwrap();
    assert_eq!(untimed_images.len(), images.len());
    for (a, b) in untimed_images.iter().zip(images) {
        assert_eq!(a["point_evaluations"], b["point_evaluations"]);
        assert!(a["stage_ms"].as_object().unwrap().is_empty(), "{a}");
    }
}

/// A synthetic set other than the model's own (another seed, another number of people) is
/// evaluated with its own split, from its `synth.json`; a broken description is named.
#[test]
fn eval_on_another_synthetic_set_uses_that_sets_split() {
    let dir = scratch("eval-other-set");
    let other = dir.join("data");
    let spec = nia_data::synth::SynthSpec {
        subjects: 3,
        frames: 2,
        cameras: 4,
        size: 40,
        seed: 5,
        supersample: 1,
        test_fraction: 0.34,
        ..Default::default()
    };
    nia_data::synth::generate(&spec, &other, &mut |_| {}).unwrap();
    let out_dir = dir.join("out");
    let eval = |data: &Path| {
        let flags = "--backend ndarray --split test --no-pictures";
        on_model("eval", flags, &["--data", s(data)], &out_dir)
    };
    ok(&eval(&other));
    let metrics = json_file(&out_dir.join("metrics.json"));
    // The model's own set has 2 people (1 unseen); this one 3, of which CoreView_3 is unseen.
    let subjects: Vec<&String> = metrics["subjects"].as_object().unwrap().keys().collect();
    assert_eq!(subjects, vec!["CoreView_3"]);
    assert!(metrics["overall"]["psnr"].as_f64().unwrap().is_finite());
    // A description without its `spec` is an error naming the file.
    let description = other.join("synth.json");
    std::fs::write(&description, "{\"generator\": \"nia-data synth\"}").unwrap();
    fails_with(&eval(&other), &["synth.json", "`spec`"]);
    // A root without a description (one `nia-train prepare` wrote): the error says how to
    // name the people; --subjects (and --input-views) evaluates them.
    std::fs::remove_file(&description).unwrap();
    fails_with(&eval(&other), &["synth.json", "--subjects"]);
    let named = on_model(
        "eval",
        "--backend ndarray --no-pictures --subjects CoreView_1,CoreView_3 --input-views 0,2",
        &["--data", s(&other)],
        &out_dir,
    );
    ok(&named);
    let metrics = json_file(&out_dir.join("metrics.json"));
    let subjects: Vec<&String> = metrics["subjects"].as_object().unwrap().keys().collect();
    assert_eq!(subjects, vec!["CoreView_1", "CoreView_3"]);
    for image in metrics["images"].as_array().unwrap() {
        assert_eq!(image["input_views"], serde_json::json!([0, 2]));
    }
}

/// `--truth-data` scores the same render against a second set: against the model's own data the
/// truth scores equal the protocol's to the bit; a root without the subject is an error naming
/// the truth set and the subject.
#[test]
fn eval_scores_against_a_truth_set() {
    let out_dir = scratch("eval-truth");
    let data = trained().dir.join("data");
    let flags = "--backend ndarray --no-pictures --limit 2";
    ok(&on_model(
        "eval",
        flags,
        &["--truth-data", s(&data)],
        &out_dir,
    ));
    let metrics = json_file(&out_dir.join("metrics.json"));
    let images = metrics["images"].as_array().unwrap();
    assert_eq!(images.len(), 2);
    for row in images.iter().chain([&metrics["overall"]]) {
        let g = &row["diagnostics"];
        assert_eq!(g["psnr_truth"], row["psnr"], "{row}");
        assert_eq!(g["ssim_truth"], row["ssim"], "{row}");
        assert_eq!(g["psnr_ibr_truth"], g["psnr_ibr"], "{row}");
    }
    // Without the flag there is no truth score.
    ok(&on_model("eval", flags, &[], &out_dir));
    let plain = json_file(&out_dir.join("metrics.json"));
    assert!(plain["overall"]["diagnostics"].get("psnr_truth").is_none());
    // Synthetic sets hold the clothed surface their images show: wherever the depth error
    // against the fitted mesh is measured, the one against that surface is measured beside it
    // (the values themselves: `nia_eval::diagnostics`' unit test; this tiny model is seldom
    // opaque enough for either).
    let rows = plain["images"].as_array().unwrap();
    for row in rows.iter().chain([&plain["overall"]]) {
        let g = &row["diagnostics"];
        let fit = g["depth_error_m"].as_f64();
        let truth = g.get("depth_error_true_m").and_then(|v| v.as_f64());
        assert_eq!(fit.is_some(), truth.is_some(), "{g}");
        for m in [fit, truth].into_iter().flatten() {
            assert!((0.0..0.5).contains(&m), "{g}");
        }
    }
    // A truth root that lacks the subject.
    let empty = scratch("eval-truth-empty");
    let refused = on_model("eval", flags, &["--truth-data", s(&empty)], &out_dir);
    fails_with(&refused, &["truth set", "eval-truth-empty", "subject"]);
}

/// `--smpl-alignment on` moves each scene's fit onto its source masks and lists the correction
/// per image (and the settings once); `off` (the model's default) lists none.
#[test]
fn eval_with_smpl_alignment_reports_each_correction() {
    let out_dir = scratch("eval-align");
    let flags = "--backend ndarray --no-pictures --limit 2 --smpl-alignment on";
    ok(&on_model("eval", flags, &[], &out_dir));
    let metrics = json_file(&out_dir.join("metrics.json"));
    let robust_m = metrics["smpl_alignment"]["robust_m"].as_f64().unwrap();
    assert!(
        (robust_m - 0.03).abs() < 1e-6,
        "the default settings: {robust_m}"
    );
    let images = metrics["images"].as_array().unwrap();
    assert_eq!(images.len(), 2);
    for image in images {
        let a = &image["smpl_alignment"];
        let views = image["input_views"].as_array().unwrap().len() as u64;
        assert_eq!(a["views_used"].as_u64(), Some(views), "{a}");
        let (before, after) = (
            a["energy_before"].as_f64().unwrap(),
            a["energy_after"].as_f64().unwrap(),
        );
        assert!(after.is_finite() && after <= before, "{a}");
        let t: Vec<f64> = a["translation_m"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        assert!(
            t.iter().all(|x| x.abs() <= 0.1),
            "within the default bound: {a}"
        );
        assert!(a["rotation_deg"].as_f64().unwrap() <= 10.0 + 1e-3, "{a}");
        assert!(image["psnr"].as_f64().unwrap().is_finite());
    }
    for image in images {
        assert!(image["smpl_alignment"].get("pose").is_none(), "rigid only");
    }
    // The pose refinement after it: each image lists its joints' change.
    let flags = "--backend ndarray --no-pictures --limit 2 --smpl-pose-iterations 5";
    ok(&on_model("eval", flags, &[], &out_dir));
    let metrics = json_file(&out_dir.join("metrics.json"));
    assert_eq!(
        metrics["smpl_alignment"]["pose_iterations"].as_u64(),
        Some(5)
    );
    for image in metrics["images"].as_array().unwrap() {
        let pose = &image["smpl_alignment"]["pose"];
        let (before, after) = (
            pose["energy_before"].as_f64().unwrap(),
            pose["energy_after"].as_f64().unwrap(),
        );
        assert!(after.is_finite() && after <= before, "{pose}");
        let max = pose["max_joint_deg"].as_f64().unwrap();
        assert!((0.0..=15.0 + 1e-3).contains(&max), "{pose}");
        assert!(pose["steps"].as_u64().unwrap() <= 5, "{pose}");
    }
    ok(&on_model(
        "eval",
        "--backend ndarray --no-pictures --limit 1",
        &[],
        &out_dir,
    ));
    let metrics = json_file(&out_dir.join("metrics.json"));
    assert!(metrics["smpl_alignment"].is_null());
    assert!(metrics["images"][0].get("smpl_alignment").is_none());
    // A novel pose's reference keeps its stored fit: no image lists an alignment.
    let flags = "--backend ndarray --no-pictures --task novel_pose --smpl-pose-iterations 5";
    ok(&on_model("eval", flags, &[], &out_dir));
    let metrics = json_file(&out_dir.join("metrics.json"));
    let images = metrics["images"].as_array().unwrap();
    assert!(!images.is_empty());
    for image in images {
        assert!(image.get("smpl_alignment").is_none(), "{image}");
        assert!(image["psnr"].as_f64().unwrap().is_finite());
    }
    let flags =
        "--backend ndarray --no-pictures --limit 1 --smpl-alignment off --smpl-pose-iterations 5";
    let stderr = refused_eval(flags, &out_dir);
    assert!(stderr.contains("--smpl-pose-iterations"), "{stderr}");
}

/// `eval --c0-weight-scale S`: the metrics record the setting, c0's share of the blend falls
/// below the model's own where a view sees (the same images, the same IBR-only composite), and
/// a scale out of bounds is refused naming the flag.
#[test]
fn eval_with_a_c0_weight_scale_leans_on_the_views() {
    let out_dir = scratch("eval-c0-scale");
    let run = |extra: &str| {
        let flags = format!("--backend ndarray --no-pictures --limit 2 {extra}");
        ok(&on_model("eval", &flags, &[], &out_dir));
        json_file(&out_dir.join("metrics.json"))
    };
    let (plain, scaled) = (run(""), run("--c0-weight-scale 0.25"));
    assert_eq!(plain["adaptive"]["c0_weight_scale"].as_f64(), Some(1.0));
    assert_eq!(scaled["adaptive"]["c0_weight_scale"].as_f64(), Some(0.25));
    let diagnostic =
        |m: &serde_json::Value, key: &str| m["overall"]["diagnostics"][key].as_f64().unwrap();
    let (a, b) = (
        diagnostic(&plain, "c0_weight_seen"),
        diagnostic(&scaled, "c0_weight_seen"),
    );
    assert!(a > 0.0 && b < a, "c0's share where seen: {a} -> {b}");
    let (a, b) = (
        diagnostic(&plain, "psnr_ibr"),
        diagnostic(&scaled, "psnr_ibr"),
    );
    assert!((a - b).abs() < 1e-3, "the IBR-only composite: {a} -> {b}");
    assert!(scaled["overall"]["psnr"].as_f64().unwrap().is_finite());
    let flags = "--backend ndarray --no-pictures --limit 1 --c0-weight-scale 0";
    let stderr = refused_eval(flags, &out_dir);
    assert!(stderr.contains("--c0-weight-scale"), "{stderr}");
}

#[test]
fn novel_pose_eval_reposes_from_the_reference_frame() {
    let out_dir = scratch("eval-pose");
    // `--limit` counts evaluated images: the split's first images are of the reference frame,
    // which a novel pose leaves out before the limit (before, this evaluated none).
    let flags = "--backend ndarray --task novel_pose --no-pictures --limit 2";
    ok(&on_model("eval", flags, &[], &out_dir));
    let metrics = json_file(&out_dir.join("metrics.json"));
    assert_eq!(metrics["task"], "novel_pose");
    let images = metrics["images"].as_array().unwrap();
    assert_eq!(images.len(), 2);
    for image in images {
        assert_ne!(
            image["frame"], image["reference_frame"],
            "the reference is skipped"
        );
        assert!(image["psnr"].as_f64().unwrap().is_finite());
    }
}

#[test]
fn exported_file_renders_what_the_checkpoint_renders() {
    let t = trained();
    let (_, dir) = checkpoint::latest(&t.run).unwrap().unwrap();
    let saved = checkpoint::read_config(&dir).unwrap();
    let run: TrainConfig = serde_json::from_value(saved.run.clone()).unwrap();
    #[allow(deprecated)] // burn 0.22 spells the CPU device this way.
    let device = burn::prelude::Device::ndarray();
    let from_checkpoint = checkpoint::load_model(&dir, saved.model.init(&device)).unwrap();
    let file = ModelFile::read(&t.model).unwrap();
    let from_file = file.load(&t.model, &device).unwrap();
    let spec = run.synth.as_ref().map(|s| s.spec());
    let protocol = run.data.protocol(spec.as_ref()).unwrap();
    let data = OpenedDataset::open_split(&run.data, protocol, EvalSplit::UnseenSubjects).unwrap();
    let items = eval_items(
        &data,
        EvalSplit::UnseenSubjects,
        EvalTask::NovelView,
        Some(2),
    )
    .unwrap();
    let options = EvalOptions {
        task: EvalTask::NovelView,
        samples: 8,
        chunk: 256,
        timed: false,
        render: run.render,
        lpips: None,
        truth: None,
    };
    let render = |model| {
        let mut images = Vec::new();
        evaluate_images(
            model,
            &data,
            EvalSplit::UnseenSubjects,
            &items,
            options.clone(),
            &device,
            &mut |e| {
                images.push(e.rendered.rgb.clone());
                Ok(())
            },
        )
        .unwrap();
        images
    };
    let a = render(&from_checkpoint);
    let b = render(&from_file);
    assert_eq!(a.len(), 2);
    let max = a
        .iter()
        .flatten()
        .zip(b.iter().flatten())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    assert!(max <= EXPORT_RENDER_TOL, "max difference {max}");
    assert!(
        a.iter().flatten().any(|&v| v > 0.0),
        "something was rendered"
    );
}

/// `orbit`: views on the ring of the subject's calibrated cameras, PNG frames and a GIF of
/// as many frames (an MP4 where ffmpeg is installed), the person in every view.
#[test]
fn orbit_turns_around_the_subject() {
    let out_dir = scratch("orbit");
    ok(&on_model(
        "orbit",
        "--subject CoreView_2 --frame 1 --steps 4",
        &[],
        &out_dir,
    ));
    let report = json_file(&out_dir.join("orbit.json"));
    assert_eq!(report["views"], serde_json::json!([0, 1, 3]));
    let radius = report["radius_m"].as_f64().unwrap();
    assert!(radius > 0.5 && radius < 10.0, "radius {radius}");
    for k in 0..4 {
        let png = image::open(out_dir.join(format!("orbit_{k:03}.png")))
            .unwrap()
            .to_rgb8();
        assert_eq!((png.width(), png.height()), (40, 40));
        let lit = png.pixels().filter(|p| p.0.iter().any(|&c| c > 8)).count();
        // At 40 px the person is a few pixels wide; measured with the default visual-hull
        // carving 31 and 19 lit pixels in the first two views (43 and 30 without it).
        assert!(
            lit > 10,
            "view {k}: the person is in view ({lit} lit pixels)"
        );
    }
    assert_eq!(gif_frames(&out_dir.join("orbit.gif")), 4);
    let ffmpeg = std::process::Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success());
    assert_eq!(out_dir.join("orbit.mp4").is_file(), ffmpeg);
    assert_eq!(report["mp4"].is_null(), !ffmpeg);
}

#[test]
fn render_and_animate_write_pictures() {
    let t = trained();
    let subject = t.dir.join("data/CoreView_2");
    let out_dir = scratch("render");
    // `--data` is the dataset root in every command; `--subject` a name under it. Without
    // `--views`, the sources are the synthetic protocol's input views (4 cameras: 0, 1, 3).
    let root = t.dir.join("data");
    let flags = "--subject CoreView_2 --frame 1 --targets 3,1";
    ok(&on_model("render", flags, &["--data", s(&root)], &out_dir));
    let report = json_file(&out_dir.join("render.json"));
    assert_eq!(report["views"], serde_json::json!([0, 1, 3]));
    for (i, view) in [3, 1].iter().enumerate() {
        let img = &report["images"][i];
        assert_eq!(img["target_view"], *view);
        let (rays, pixels) = (
            img["rays"].as_u64().unwrap(),
            img["pixels"].as_u64().unwrap(),
        );
        assert!(
            rays > 0 && rays < pixels,
            "rays missing the box are skipped: {rays}/{pixels}"
        );
        let png = image::open(out_dir.join(format!("frame0001_view{view:02}.png"))).unwrap();
        assert_eq!((png.width(), png.height()), (40, 40));
        assert!(img["stage_ms"]["mlps"].as_f64().unwrap() > 0.0, "{img}");
    }
    assert_eq!(report["stage_times"], true);
    // Without stage timings: the same pictures to the byte, and no stage table.
    let untimed_dir = scratch("render-untimed");
    let untimed_flags = format!("{flags} --no-stage-times");
    ok(&on_model(
        "render",
        &untimed_flags,
        &["--data", s(&root)],
        &untimed_dir,
    ));
    let untimed = json_file(&untimed_dir.join("render.json"));
    assert_eq!(untimed["stage_times"], false);
    assert_eq!(untimed["encode_stage_ms"], serde_json::json!({}));
    for (i, view) in [3, 1].iter().enumerate() {
        assert_eq!(untimed["images"][i]["stage_ms"], serde_json::json!({}));
        assert_eq!(
            untimed["images"][i]["point_evaluations"],
            report["images"][i]["point_evaluations"]
        );
        for suffix in ["", "_acc", "_blend"] {
            let file = format!("frame0001_view{view:02}{suffix}.png");
            assert!(
                std::fs::read(out_dir.join(&file)).unwrap()
                    == std::fs::read(untimed_dir.join(&file)).unwrap(),
                "{file} differs with --no-stage-times"
            );
        }
    }

    // Poses from a range of frames, then from a folder of params files (here the subject's
    // own, in name order).
    let params = subject.join("params");
    let animate = |poses: [&str; 2], more: &str, name: &str| {
        let out = scratch(name);
        let extra = [&["--subject", s(&subject)][..], &poses].concat();
        let flags = format!("--ref-frame 0 --views 0,1,2 --target 3 {more}");
        ok(&on_model("animate", &flags, &extra, &out));
        out
    };
    let anim = animate(["--poses", "0..=2"], "", "animate");
    for i in 0..3 {
        assert!(anim.join(format!("pose_{i:04}.png")).is_file());
    }
    assert_eq!(gif_frames(&anim.join("animation.gif")), 3);
    let timed = json_file(&anim.join("animate.json"));
    for pose in timed["poses"].as_array().unwrap() {
        assert!(pose["stage_ms"]["mlps"].as_f64().unwrap() > 0.0, "{pose}");
    }
    // From the params files, and without the stage timings.
    let from_params = animate(
        ["--params", s(&params)],
        "--no-stage-times",
        "animate-params",
    );
    let report = json_file(&from_params.join("animate.json"));
    let poses = report["poses"].as_array().unwrap();
    assert_eq!(poses.len(), 3, "one pose per params file");
    assert!(poses[2]["pose"].as_str().unwrap().ends_with("2.npy"));
    assert_eq!(
        (timed["stage_times"].clone(), report["stage_times"].clone()),
        (true.into(), false.into())
    );
    for pose in poses {
        assert!(pose["stage_ms"].as_object().unwrap().is_empty(), "{pose}");
    }
}

#[test]
fn sweep_writes_the_table_and_the_plot() {
    let out_dir = scratch("sweep");
    let axes =
        "--sample-counts 8 --view-counts 1,3 --ratios 1.0 --supersamples 1,2 --colour-point-counts 0,1 --density-grids 0,0.02";
    ok(&on_model("sweep", axes, &["--limit", "1"], &out_dir));
    let csv = std::fs::read_to_string(out_dir.join("sweep.csv")).unwrap();
    // 1 sample count x 2 view counts x 1 ratio x 2 supersamplings x 2 colour-point counts x
    // (skipping on/off without the baked density, on with it), plus the header.
    assert_eq!(csv.lines().count(), 1 + 16 + 8, "{csv}");
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert!(
        rows.iter().any(|r| r[10] == "true"),
        "a Pareto front is marked"
    );
    for r in &rows {
        let (psnr, evals): (f64, f64) = (r[6].parse().unwrap(), r[9].parse().unwrap());
        assert!(psnr.is_finite() && evals > 0.0);
    }
    let evals = |supersample: &str, skip: &str| -> f64 {
        rows.iter()
            .find(|r| {
                r[1] == "3" && r[3] == supersample && r[4] == skip && r[11] == "0" && r[12] == "0"
            })
            .unwrap()[9]
            .parse()
            .unwrap()
    };
    // Skipping on evaluates fewer points than off at the same setting.
    assert!(evals("1", "true") < evals("1", "false"));
    // 2 x 2 rays per pixel: four times the rays (pixels whose centre ray misses the box but
    // another of their rays does not add a few more).
    let ratio = evals("2", "false") / evals("1", "false");
    assert!((4.0..4.5).contains(&ratio), "{ratio}");
    let svg = std::fs::read_to_string(out_dir.join("sweep.svg")).unwrap();
    assert!(svg.starts_with("<svg"));
    // The baked density: the network runs at the coloured points only, fewer than the
    // density walk's at the same setting.
    let baked = |k: &str| -> f64 {
        rows.iter()
            .find(|r| r[1] == "3" && r[3] == "1" && r[11] == k && r[12] == "0.02")
            .unwrap()[9]
            .parse()
            .unwrap()
    };
    assert!(baked("1") < evals("1", "true"));
    // Every setting is a labelled dot (once with skipping on, once off; the baked density's
    // with skipping on only), and the legend names both series and the front.
    for r in &rows {
        let mut label = format!("r{} v{} s{} x{}", r[2], r[1], r[0], r[3]);
        if r[11] != "0" {
            label += &format!(" c{}", r[11]);
        }
        let grid = r[12] != "0";
        if grid {
            label += &format!(" g{}", r[12]);
        }
        let drawn = svg.lines().filter(|l| l.trim() == label).count();
        assert_eq!(drawn, if grid { 1 } else { 2 }, "{label}");
    }
    for name in ["skipping on", "skipping off", "Pareto front"] {
        assert!(svg.contains(name), "{name}");
    }
    assert!(std::fs::read_to_string(out_dir.join("sweep.md"))
        .unwrap()
        .contains("| ratio | views | samples |"));
}

#[test]
fn broken_model_files_and_data_give_clear_errors() {
    let t = trained();
    let dir = scratch("broken");
    let bytes = std::fs::read(&t.model).unwrap();
    let eval_with =
        |model: &Path| nia_infer(&["eval", "--model", s(model), "--out", s(&dir.join("out"))]);
    // Truncated in the weights.
    let truncated = dir.join("truncated.nia");
    std::fs::write(&truncated, &bytes[..bytes.len() - 100]).unwrap();
    fails_with(
        &eval_with(&truncated),
        &["truncated.nia", "truncated", "weights"],
    );
    // Truncated in the header.
    let short = dir.join("short.nia");
    std::fs::write(&short, &bytes[..30]).unwrap();
    fails_with(&eval_with(&short), &["short.nia", "truncated", "header"]);
    // One flipped byte in the weights.
    let corrupt = dir.join("corrupt.nia");
    let mut flipped = bytes.clone();
    let last = flipped.len() - 10;
    flipped[last] ^= 0x55;
    std::fs::write(&corrupt, &flipped).unwrap();
    fails_with(&eval_with(&corrupt), &["corrupt.nia", "checksum"]);
    // Not a model file at all.
    let text = dir.join("notes.nia");
    std::fs::write(&text, "hello").unwrap();
    fails_with(&eval_with(&text), &["notes.nia", "NIAMODEL"]);
    // Weights of the tiny network under a header claiming the paper's network.
    let mut file = ModelFile::read(&t.model).unwrap();
    file.header.model = nia_model::ModelConfig::new();
    let other = dir.join("other-config.nia");
    file.write(&other).unwrap();
    fails_with(&eval_with(&other), &["other-config.nia", "another config"]);
    // Missing file.
    fails_with(&eval_with(&dir.join("absent.nia")), &["absent.nia"]);

    // A data folder missing a requested view's image.
    let data = dir.join("data");
    copy_dir(&t.dir.join("data/CoreView_2"), &data);
    std::fs::remove_dir_all(data.join("Camera_B2")).unwrap();
    let (own, smpl) = (
        t.dir.join("data/CoreView_2"),
        t.dir.join("data/body_model.npz"),
    );
    let with_views =
        |subject, views| vec!["--subject", subject, "--smpl", s(&smpl), "--views", views];
    let cases: [(Vec<&str>, &[&str]); 4] = [
        (
            with_views(s(&data), "0,1,2"),
            &["Camera_B2", "camera folder missing"],
        ),
        // A camera index the subject does not have.
        (with_views(s(&own), "0,1,9"), &["--views 9", "4 cameras"]),
        // `--data` given a subject folder says what it expects instead.
        (
            vec!["--data", s(&own), "--subject", "CoreView_2"],
            &[
                "a subject folder, not a dataset root",
                "--subject CoreView_2",
            ],
        ),
        // A subject that is not there names where it looked.
        (
            vec!["--subject", "CoreView_99"],
            &["--subject CoreView_99", "annots.npy"],
        ),
    ];
    let render_out = dir.join("render");
    for (flags, expected) in cases {
        let out = on_model("render", "--frame 0 --targets 3", &flags, &render_out);
        fails_with(&out, expected);
    }
}
