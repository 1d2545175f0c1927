//! `nia-train --config` end to end on ndarray: a tiny synthetic dataset generated from the
//! config's `[synth]` section, 2 training steps, the JSONL log, checkpoints, config errors
//! naming the key and the file, and resume equal to an uninterrupted run.

use std::path::{Path, PathBuf};

use common::{fails_with, ok, slash, train_run};
use nia_model::store::checkpoint;

mod common;

fn scratch(name: &str) -> PathBuf {
    common::scratch("smoke", name)
}

/// The tiny config (2 subjects, 1 held out; 48 px) with `extra_train` lines.
fn tiny_config(dir: &Path, steps: u64, extra_train: &str) -> PathBuf {
    common::tiny_config(dir, steps, 7, extra_train)
}

/// The same weights rendering the same images: only reduction order may differ (ndarray).
const EVAL_REPEAT_TOL_DB: f64 = 1e-3;

fn events(out: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(out.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("bad JSON line {l}: {e}")))
        .collect()
}

fn of_kind<'a>(events: &'a [serde_json::Value], kind: &str) -> Vec<&'a serde_json::Value> {
    events.iter().filter(|e| e["event"] == kind).collect()
}

#[test]
fn trains_two_steps_end_to_end_on_ndarray() {
    let dir = scratch("two");
    let config = tiny_config(&dir, 2, "validate_every = 2\nevaluate_at_end = true");
    let out = dir.join("run");
    let run = train_run(&[], &config, &out);
    ok(&run);
    assert!(dir.join("data/synth.json").is_file(), "dataset generated");
    // Without a terminal every event and phase reaches stdout as a plain line.
    let stdout = String::from_utf8_lossy(&run.stdout);
    for line in [
        "generating the synthetic dataset: 0/16 images",
        "generating the synthetic dataset: 16/16 images",
        "validation: 0/2 images",
        "validation after 2 steps: PSNR",
        "checkpoint ",
        "step 2/2 loss",
        "final evaluation: 0/",
        "evaluation (unseen_subjects,",
    ] {
        assert!(stdout.contains(line), "stdout lacks `{line}`:\n{stdout}");
    }
    let all = events(&out);
    assert!(
        of_kind(&all, "progress").is_empty(),
        "phase progress is not a record"
    );
    let ready = of_kind(&all, "data_ready");
    assert_eq!(ready.len(), 1);
    assert_eq!(ready[0]["generated"], true);
    let steps = of_kind(&all, "step");
    assert_eq!(steps.len(), 2, "two steps taken, none skipped: {all:?}");
    for (i, s) in steps.iter().enumerate() {
        assert_eq!(s["step"], i as u64);
        let loss = s["loss"].as_f64().unwrap();
        assert!(loss.is_finite() && loss > 0.0, "loss {loss}");
        let (mse, mse0) = (s["mse"].as_f64().unwrap(), s["mse0"].as_f64().unwrap());
        assert!((mse + mse0 - loss).abs() < 1e-5, "loss = mse + mse0");
        assert!(s["psnr"].as_f64().unwrap().is_finite());
        assert!(s["rays_per_s"].as_f64().unwrap() > 0.0);
        // One device: the losses and the gradient norm in one read, nothing else.
        assert_eq!(s["readbacks"], 1, "reads of step {i}");
    }
    // lr * 0.1^(1/1000) at step 1.
    let lr1 = steps[1]["lr"].as_f64().unwrap();
    assert!((lr1 - 5e-4 * 0.1f64.powf(1e-3)).abs() < 1e-12, "lr {lr1}");
    let validation = of_kind(&all, "validation");
    assert_eq!(validation.len(), 1, "{all:?}");
    assert!(validation[0]["psnr"].as_f64().unwrap().is_finite());
    let ssim = validation[0]["ssim"].as_f64().unwrap();
    assert!((-1.0..=1.0).contains(&ssim), "ssim {ssim}");
    let evaluation = of_kind(&all, "evaluation");
    assert_eq!(evaluation.len(), 1, "{all:?}");
    // The held-out subject: 2 frames x the cameras that are not input views.
    assert!(evaluation[0]["images"].as_u64().unwrap() >= 2);
    assert_eq!(evaluation[0]["split"], "unseen_subjects");
    assert!(evaluation[0]["psnr"].as_f64().unwrap().is_finite());
    assert_eq!(of_kind(&all, "checkpoint").len(), 2);
    assert_eq!(of_kind(&all, "finished").len(), 1);
    let ckpt = out.join("checkpoints/step_00000002");
    for f in ["model.bpk", "optimizer.bpk", "config.json", "step.json"] {
        assert!(ckpt.join(f).is_file(), "missing {f}");
    }
    let saved: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(ckpt.join("config.json")).unwrap()).unwrap();
    assert_eq!(saved["run"]["train"]["steps"], 2);
    assert_eq!(
        saved["model"]["d_model"], 16,
        "the tiny preset was resolved"
    );
    let step: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(ckpt.join("step.json")).unwrap()).unwrap();
    assert_eq!(step["step"], 2);

    // Evaluation only (`steps = 0`) from the checkpoint's weights renders the same images.
    let eval_config = tiny_config(
        &dir,
        0,
        &format!("evaluate_at_end = true\ninit_from = \"{}\"", slash(&ckpt)),
    );
    let eval_out = dir.join("eval");
    ok(&train_run(&[], &eval_config, &eval_out));
    let again = events(&eval_out);
    assert!(of_kind(&again, "step").is_empty(), "no training step");
    let again = of_kind(&again, "evaluation");
    assert_eq!(again.len(), 1);
    let (p0, p1) = (
        evaluation[0]["psnr"].as_f64().unwrap(),
        again[0]["psnr"].as_f64().unwrap(),
    );
    assert!(
        (p0 - p1).abs() < EVAL_REPEAT_TOL_DB,
        "same weights, same images: {p0} vs {p1} dB"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn config_errors_name_the_key_and_the_file() {
    let dir = scratch("bad");
    let config = tiny_config(&dir, 2, "stepz = 3");
    let unknown_key = std::fs::read_to_string(&config).unwrap();
    let wrong_type = unknown_key
        .replace("stepz = 3", "")
        .replace("samples = 8", "samples = \"eight\"");
    // An unknown key, then a value of the wrong type: each names the key and the file.
    for (text, key) in [(unknown_key, "stepz"), (wrong_type, "samples")] {
        std::fs::write(&config, text).unwrap();
        fails_with(
            &train_run(&[], &config, &dir.join("run")),
            &[key, "tiny.toml"],
        );
    }
    assert!(
        !dir.join("data").exists(),
        "nothing generated for a bad config"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn resume_continues_like_an_uninterrupted_run() {
    let dir = scratch("resume");
    let config = tiny_config(&dir, 4, "");
    let (straight, resumed) = (dir.join("straight"), dir.join("resumed"));
    ok(&train_run(&[], &config, &straight));
    ok(&train_run(&["--steps", "2"], &config, &resumed));
    // A write killed half-way leaves only a hidden temporary folder: never resumed from.
    let partial = resumed.join("checkpoints/.tmp_step_00000099");
    std::fs::create_dir_all(&partial).unwrap();
    std::fs::write(partial.join("model.bpk"), b"truncated").unwrap();
    ok(&train_run(&["--resume"], &config, &resumed));
    let a = events(&straight);
    let b = events(&resumed);
    let started = of_kind(&b, "started");
    assert_eq!(started.len(), 2);
    assert_eq!(started[1]["first_step"], 2, "resumed after step 2");
    let loss = |events: &[serde_json::Value], step: u64| {
        of_kind(events, "step")
            .into_iter()
            .find(|e| e["step"] == step)
            .and_then(|e| e["loss"].as_f64())
            .unwrap_or_else(|| panic!("no step {step}"))
    };
    for step in 0..4 {
        // The same steps from the same state (weights, BatchNorm statistics, Adam moments),
        // deterministic on ndarray: identical losses.
        let (x, y) = (loss(&a, step), loss(&b, step));
        assert_eq!(x, y, "step {step}: straight {x} vs resumed {y}");
    }
    // The final weights (BatchNorm running statistics included) are bit-identical.
    assert_eq!(
        final_weights(&straight),
        final_weights(&resumed),
        "resumed and uninterrupted runs end with the same weights"
    );
    // keep_last = 2.
    let kept: Vec<_> = std::fs::read_dir(resumed.join("checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("step_"))
        .collect();
    assert_eq!(kept.len(), 2, "{kept:?}");
    assert!(
        !partial.exists(),
        "the killed write's leftovers are cleaned up"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every parameter and buffer of the newest checkpoint of `out`, as bits.
fn final_weights(out: &Path) -> Vec<Vec<u32>> {
    use burn::module::{Module, ModuleVisitor, Param};
    use burn::prelude::*;
    struct Collect(Vec<Vec<u32>>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let v = param
                .val()
                .into_data()
                .convert::<f32>()
                .try_to_vec::<f32>()
                .unwrap();
            self.0.push(v.iter().map(|x| x.to_bits()).collect());
        }
    }
    let (_, dir) = checkpoint::latest(out).unwrap().unwrap();
    let saved = checkpoint::read_config(&dir).unwrap();
    #[allow(deprecated)] // burn 0.22 spells the CPU device this way.
    let device = Device::ndarray();
    let model = checkpoint::load_model(&dir, saved.model.init(&device)).unwrap();
    let mut c = Collect(Vec::new());
    model.visit(&mut c);
    c.0
}

/// `<workspace>/<rel>`, a file other crates keep.
fn in_workspace(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

fn preset(name: &str) -> PathBuf {
    in_workspace("configs").join(name)
}

#[test]
fn presets_parse() {
    let quick = nia_train::config::TrainConfig::load(&preset("quickstart.toml")).unwrap();
    assert!(quick.synth.is_some(), "quickstart generates its data");
    assert_eq!(quick.model.d_model, 16, "tiny network");
    assert!(
        quick.data.smpl_alignment.is_some(),
        "flawed data: the fit aligned to the masks"
    );
    // zju.toml is complete but for the user's data: the only complaint is the missing folder.
    let err = nia_train::config::TrainConfig::load(&preset("zju.toml"));
    match err {
        Ok(c) => assert_eq!(c.train.rays_per_step, 1024),
        Err(e) => {
            let msg = e.to_string();
            assert!(
                msg.contains("zju.toml")
                    && (msg.contains("data.root") || msg.contains("data.smpl_model")),
                "{msg}"
            );
        }
    }
}

/// A second run into a folder that holds checkpoints is refused unless `--resume` or
/// `--overwrite` says which; the refusal leaves the folder as it was, `--overwrite` starts
/// afresh (a new log, checkpoints from step 1).
#[test]
fn a_rerun_into_a_used_folder_must_say_resume_or_overwrite() {
    let dir = scratch("rerun");
    let config = tiny_config(&dir, 1, "validate_every = 0");
    let out = dir.join("run");
    ok(&train_run(&[], &config, &out));
    let log = std::fs::read(out.join("metrics.jsonl")).unwrap();
    let refused = train_run(&[], &config, &out);
    fails_with(
        &refused,
        &["already holds a run", "--resume", "--overwrite"],
    );
    assert_eq!(
        std::fs::read(out.join("metrics.jsonl")).unwrap(),
        log,
        "the log was touched"
    );
    assert_eq!(checkpoint::latest(&out).unwrap().unwrap().0, 1);

    ok(&train_run(&["--overwrite"], &config, &out));
    let fresh = std::fs::read_to_string(out.join("metrics.jsonl")).unwrap();
    assert_eq!(
        fresh
            .lines()
            .filter(|l| l.contains("\"event\":\"started\""))
            .count(),
        1,
        "one run in the new log:\n{fresh}"
    );
    assert_eq!(checkpoint::latest(&out).unwrap().unwrap().0, 1);
    let both = train_run(&["--resume", "--overwrite"], &config, &out);
    assert!(!both.status.success(), "--resume and --overwrite together");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The torchvision ResNet fixture of nia-model's import tests (trunk width 8, the tiny preset's).
fn resnet_fixture(name: &str) -> PathBuf {
    in_workspace("nia-model/tests/fixtures/resnet").join(name)
}

/// `train.encoder_weights` puts the torchvision weights into the encoder before the first step,
/// and the encoder then trains: after one Adam step (lr 5e-4) every conv1 weight sits within one
/// step of the file's value and most have moved.
#[test]
fn encoder_weights_start_the_encoder_and_it_trains() {
    use burn::module::{Module, ModuleVisitor, Param};
    use burn::prelude::*;
    let dir = scratch("encoder_weights");
    let weights = resnet_fixture("resnet_tiny.pth");
    let line = format!("encoder_weights = \"{}\"", slash(&weights));
    let config = tiny_config(&dir, 1, &line);
    let out = dir.join("run");
    ok(&train_run(&[], &config, &out));

    struct Conv1(Option<Vec<f32>>);
    impl ModuleVisitor for Conv1 {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if self.0.is_none() && param.shape().dims::<4>() == [8, 3, 7, 7] {
                self.0 = Some(param.val().into_data().try_to_vec::<f32>().unwrap());
            }
        }
    }
    let (_, ckpt) = checkpoint::latest(&out).unwrap().unwrap();
    let saved = checkpoint::read_config(&ckpt).unwrap();
    #[allow(deprecated)] // burn 0.22 spells the CPU device this way.
    let device = Device::ndarray();
    let model = checkpoint::load_model(&ckpt, saved.model.init(&device)).unwrap();
    let mut visitor = Conv1(None);
    model.encoder.visit(&mut visitor);
    let trained = visitor.0.expect("the encoder's conv1 [8, 3, 7, 7]");
    let file = nia_data::formats::npy::read(&resnet_fixture("conv1_weight.npy"))
        .unwrap()
        .to_f32_vec()
        .unwrap();
    assert_eq!(trained.len(), file.len());
    let lr = 5e-4f32;
    let moved = trained
        .iter()
        .zip(&file)
        .filter(|(t, f)| (*t - *f).abs() > 0.1 * lr)
        .count();
    let worst = trained
        .iter()
        .zip(&file)
        .map(|(t, f)| (t - f).abs())
        .fold(0.0f32, f32::max);
    assert!(
        worst <= 1.01 * lr,
        "one Adam step moves at most lr: {worst}"
    );
    assert!(
        moved * 2 > trained.len(),
        "the loaded encoder trains: {moved} of {} moved",
        trained.len()
    );

    // A trunk of another width is refused, naming the key and the file.
    let bad = dir.join("bad");
    let output = train_run(&["--set", "model.encoder_width=16"], &config, &bad);
    fails_with(&output, &["train.encoder_weights", "resnet_tiny.pth"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `train.lpips` (here nia-model's narrow VGG fixture) adds LPIPS to validation and the final
/// evaluation: in the log, the printed lines and the events; a missing weight file is refused
/// before anything runs, naming the key.
#[test]
fn lpips_is_scored_in_validation_and_evaluation() {
    let dir = scratch("lpips");
    let lpips_dir = in_workspace("nia-model/tests/fixtures/lpips");
    let line = format!(
        "validate_every = 1\nevaluate_at_end = true\nlpips = {{ net = \"vgg\", backbone = \"{}\", heads = \"{}\", widths = [4, 4, 8, 8, 8, 8, 8, 12, 12, 12, 12, 12, 12] }}",
        slash(&lpips_dir.join("vgg_trunk.pth")),
        slash(&lpips_dir.join("vgg_heads.pth")),
    );
    let config = tiny_config(&dir, 1, &line);
    let out = dir.join("run");
    let run = train_run(&[], &config, &out);
    ok(&run);
    let all = events(&out);
    for kind in ["validation", "evaluation"] {
        let e = of_kind(&all, kind);
        assert_eq!(e.len(), 1, "{kind}");
        let lpips = e[0]["lpips"]
            .as_f64()
            .unwrap_or_else(|| panic!("{kind}: {:?}", e[0]));
        assert!(lpips.is_finite() && lpips >= 0.0, "{kind}: {lpips}");
    }
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        stdout.contains("LPIPS") && stdout.contains("(vgg)"),
        "{stdout}"
    );

    let text = std::fs::read_to_string(&config)
        .unwrap()
        .replace("vgg_heads.pth", "no_such_heads.pth");
    std::fs::write(&config, text).unwrap();
    let refused = train_run(&[], &config, &dir.join("run2"));
    fails_with(&refused, &["train.lpips", "no_such_heads.pth"]);
    let _ = std::fs::remove_dir_all(&dir);
}
