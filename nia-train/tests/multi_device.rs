//! Data-parallel training (`train.devices`) on two real CPU devices of burn's dispatch,
//! ndarray and flex: each step takes one scene per device, the gradients are summed with
//! burn's `MultiGradientsParams` onto the first device and one Adam step is taken. Checked
//! against one device accumulating the same two scenes' gradients, and across a resume.

use std::path::{Path, PathBuf};

use nia_model::store::checkpoint;

mod common;

/// Adam's first steps move a weight by about lr = 5e-4 whatever the gradient's size, so a
/// gradient component near zero whose sign differs between ndarray's and flex's rounding
/// moves by up to 2 lr per step: over 2 steps at most 4 lr. All other weights agree to
/// float rounding.
const MAX_DIFF: f32 = 4.0 * 5e-4;
/// Weights further apart than rounding (see [`differing_share`]).
const ROUNDING: f32 = 1e-5;
/// Share of weights allowed beyond rounding between the two-device and the one-device run
/// (the sign flips above; measured: none, largest difference 6.9e-6).
const MAX_DIFFERING_SHARE: f64 = 0.01;

fn train(dir: &Path, name: &str, steps: u64, devices: &str, extra: &[&str]) -> PathBuf {
    std::fs::create_dir_all(dir.join(name)).unwrap();
    let config = common::tiny_config(
        &dir.join(name),
        steps,
        11,
        &format!("devices = [{devices}]\nvalidate_every = 0"),
    );
    // All runs share one dataset (the first run generates it).
    let text = std::fs::read_to_string(&config).unwrap().replace(
        &dir.join(name)
            .join("data")
            .display()
            .to_string()
            .replace('\\', "/"),
        &dir.join("data").display().to_string().replace('\\', "/"),
    );
    std::fs::write(&config, text).unwrap();
    let out = dir.join(name).join("run");
    let output = common::nia_train()
        .arg("--config")
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .args(extra)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{name}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    out
}

/// Every parameter of the newest checkpoint of `out`, flattened.
fn weights(out: &Path) -> Vec<f32> {
    use burn::module::{Module, ModuleVisitor, Param};
    use burn::prelude::*;
    struct Collect(Vec<f32>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let v = param.val().into_data().convert::<f32>();
            self.0.extend(v.try_to_vec::<f32>().unwrap());
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

/// (largest difference, share of weights differing by more than [`ROUNDING`]).
fn differing_share(a: &[f32], b: &[f32]) -> (f32, f64) {
    assert_eq!(a.len(), b.len());
    let diffs: Vec<f32> = a.iter().zip(b).map(|(x, y)| (x - y).abs()).collect();
    let max = diffs.iter().copied().fold(0.0, f32::max);
    let share = diffs.iter().filter(|&&d| d > ROUNDING).count() as f64 / a.len() as f64;
    (max, share)
}

fn losses(out: &Path) -> Vec<f64> {
    std::fs::read_to_string(out.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|e| e["event"] == "step")
        .map(|e| e["loss"].as_f64().unwrap())
        .collect()
}

#[test]
fn two_devices_equal_one_device_accumulating_the_same_scenes_and_resume() {
    let dir = common::scratch("multi", "runs");

    // ndarray + flex, and ndarray twice (one device accumulating both scenes' gradients).
    let two = train(&dir, "two", 2, "\"ndarray\", \"flex\"", &[]);
    let one = train(&dir, "one", 2, "\"ndarray\", \"ndarray\"", &[]);
    let (max, share) = differing_share(&weights(&two), &weights(&one));
    eprintln!("ndarray+flex vs ndarray+ndarray: largest difference {max:e}, share beyond rounding {share:e}");
    assert!(max <= MAX_DIFF, "largest difference {max}");
    assert!(
        share <= MAX_DIFFERING_SHARE,
        "{share} of the weights differ"
    );
    for (a, b) in losses(&two).iter().zip(losses(&one)) {
        assert!((a - b).abs() <= 1e-4 * b.abs(), "step loss {a} vs {b}");
    }

    // A single device sees one scene per step: clearly other weights.
    let single = train(&dir, "single", 2, "\"ndarray\"", &[]);
    let (_, share_single) = differing_share(&weights(&single), &weights(&one));
    eprintln!("one scene per step vs two: share beyond rounding {share_single:e}");
    assert!(
        share_single > 10.0 * MAX_DIFFERING_SHARE,
        "two scenes per step change the result: {share_single}"
    );

    // Resume mid-run on the two devices: 1 step, then on to 2, is the uninterrupted run.
    let resumed = train(&dir, "resumed", 1, "\"ndarray\", \"flex\"", &[]);
    let config = dir.join("resumed").join("tiny.toml");
    let output = common::nia_train()
        .arg("--config")
        .arg(&config)
        .args(["--out"])
        .arg(&resumed)
        .args(["--steps", "2", "--resume"])
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert_eq!(
        weights(&resumed)
            .iter()
            .map(|x| x.to_bits())
            .collect::<Vec<_>>(),
        weights(&two)
            .iter()
            .map(|x| x.to_bits())
            .collect::<Vec<_>>(),
        "resumed two-device run differs from the uninterrupted one"
    );

    // A CPU backend with a GPU index is refused, naming the key.
    std::fs::create_dir_all(dir.join("bad")).unwrap();
    let bad = common::tiny_config(&dir.join("bad"), 1, 11, "devices = [\"flex:1\"]");
    let output = common::nia_train()
        .arg("--config")
        .arg(&bad)
        .arg("--out")
        .arg(dir.join("bad/run"))
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains("train.devices") && stderr.contains("flex:1"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
