//! Data-parallel training (`train.devices`) on two real CPU devices of burn's dispatch,
//! ndarray and flex: each step takes one scene per device, the gradients are summed with
//! burn's `MultiGradientsParams` onto the first device and one Adam step is taken. Checked
//! against an independent reference built here from the public API: one device, each step's
//! two scenes through their own forward and backward pass, the gradients added by hand, then
//! the same clipping and Adam step. Also across a resume.

use std::path::{Path, PathBuf};

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;
use nia_data::dataset::loader::{SceneLoader, SceneTarget};
use nia_data::rng::Rng;
use nia_data::scene::SceneInput;
use nia_model::loss::render_loss;
use nia_model::store::checkpoint;
use nia_model::NiaModel;
use nia_train::config::TrainConfig;
use nia_train::data::TrainData;
use nia_train::train_loop::adam;

mod common;

/// Adam's first steps move a weight by about lr = 5e-4 whatever the gradient's size, so a
/// gradient component near zero whose sign differs between ndarray's and flex's rounding
/// moves by up to 2 lr per step: over 2 steps at most 4 lr. All other weights agree to
/// float rounding.
const MAX_DIFF: f32 = 4.0 * 5e-4;
/// Weights further apart than rounding (see [`differing_share`]).
const ROUNDING: f32 = 1e-5;
/// Share of weights allowed beyond rounding between the two-device run and the one-device
/// reference (the sign flips above; measured: 7.9e-4, largest difference 5.8e-5).
const MAX_DIFFERING_SHARE: f64 = 0.01;
/// Largest weight difference allowed between the multi-device path on two ndarray devices
/// and the reference on one: float rounding only (measured: 1.5e-8, from the clipping factor,
/// whose norm the reference sums in f64 on the host).
const SAME_BACKEND_MAX_DIFF: f32 = ROUNDING;
/// Relative difference allowed between a step's loss in the two-device run and in the
/// reference (float rounding of the forward pass on two backends).
const LOSS_REL_TOL: f64 = 1e-4;
/// The label of the sample-jitter stream forked from a scene's RNG: `JITTER_STREAM` in
/// nia-train's training step (`Rng::new(seed).fork(scene index).fork(1)`).
const JITTER_STREAM: u64 = 1;

/// `optim.grad_clip_norm` of these runs: below the tiny runs' summed gradient norms (about
/// 0.05 over the first two steps), so every step of both paths clips.
const GRAD_CLIP_NORM: f32 = 0.01;

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
    let clip = "grad_clip_norm = 1.0";
    assert!(text.contains(clip), "the tiny config sets {clip}");
    let text = text.replace(clip, &format!("grad_clip_norm = {GRAD_CLIP_NORM}"));
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

/// Every trained float parameter of `model`, flattened in visiting order: the batch-norm
/// running statistics (`running_mean`, `running_var`) are left out. They are buffers, not
/// gradients: burn 0.22's `RunningState` keeps one pending update per thread and averages
/// them, so devices on their own threads (the multi-device path) give the average of the
/// scenes' batch statistics where one thread taking both scenes (the reference) keeps the
/// last one.
fn flat_weights(model: &NiaModel) -> Vec<f32> {
    struct Collect {
        path: Vec<String>,
        values: Vec<f32>,
    }
    impl ModuleVisitor for Collect {
        fn enter_module(&mut self, name: &str, _container_type: &str) {
            self.path.push(name.to_string());
        }
        fn exit_module(&mut self, _name: &str, _container_type: &str) {
            self.path.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let running = matches!(
                self.path.last().map(String::as_str),
                Some("running_mean" | "running_var")
            );
            if running {
                return;
            }
            let v = param.val().into_data().convert::<f32>();
            self.values.extend(v.try_to_vec::<f32>().unwrap());
        }
    }
    let mut c = Collect {
        path: Vec::new(),
        values: Vec::new(),
    };
    model.visit(&mut c);
    assert!(
        c.path.is_empty(),
        "every module entered was left again (the path walk above is balanced)"
    );
    c.values
}

/// Every parameter of the newest checkpoint of `out`, flattened.
fn weights(out: &Path) -> Vec<f32> {
    let (_, dir) = checkpoint::latest(out).unwrap().unwrap();
    let saved = checkpoint::read_config(&dir).unwrap();
    #[allow(deprecated)] // burn 0.22 spells the CPU device this way.
    let device = Device::ndarray();
    let model = checkpoint::load_model(&dir, saved.model.init(&device)).unwrap();
    flat_weights(&model)
}

/// Each parameter's gradient summed over `parts`, added by hand (`+` on the tensors).
struct AddByHand<'a> {
    parts: &'a mut [GradientsParams],
    sum: GradientsParams,
}

impl ModuleVisitor for AddByHand<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let total = self
            .parts
            .iter_mut()
            .filter_map(|g| g.remove::<D>(param.id))
            .reduce(|a, b| a + b);
        if let Some(total) = total {
            self.sum.register(param.id, total);
        }
    }
}

/// The squared L2 norm of every gradient, accumulated on the host in f64.
struct HostSquaredNorm<'a> {
    grads: &'a GradientsParams,
    total: f64,
}

impl ModuleVisitor for HostSquaredNorm<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.get::<D>(param.id) {
            let v = g.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
            self.total += v.iter().map(|x| (*x as f64) * (*x as f64)).sum::<f64>();
        }
    }
}

/// Every gradient times `factor`.
struct ScaleByHand<'a> {
    grads: &'a mut GradientsParams,
    factor: f32,
}

impl ModuleVisitor for ScaleByHand<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.remove::<D>(param.id) {
            self.grads.register(param.id, g.mul_scalar(self.factor));
        }
    }
}

/// The independent reference of the run `config` describes: everything on ONE device (the
/// first of `train.devices`). Each step takes K scenes (K = the number of devices), split as
/// nia-train splits them: scene `step * K + i` of the run is device i's share, with its sample
/// jitter drawn from `(seed, step * K + i)`. Each scene gets its own forward and backward
/// pass on that one device, the K gradients are added by hand, clipped to
/// `optim.grad_clip_norm` by their global norm, and one Adam step is taken. Returns the
/// weights after `train.steps` steps, each step's mean loss and how many steps were clipped.
///
/// The loss is the paper's (NIA eq. 6, `render_loss`); the config must leave the optional
/// terms off, which the tiny config does.
fn one_device_reference(config_path: &Path) -> (Vec<f32>, Vec<f64>, u64) {
    let config = TrainConfig::load(config_path).unwrap();
    let t = &config.train;
    assert!(
        t.mask_loss_weight == 0.0 && t.distortion_loss_weight == 0.0 && t.c0_shuffle == 0.0,
        "the reference implements the paper's loss only"
    );
    assert!(t.init_from.is_none() && t.encoder_weights.is_none());
    let specs = t.device_specs();
    let k = specs.len() as u64;
    assert!(k >= 2, "a multi-device config");
    let device = specs[0].device().unwrap().autodiff();
    let data = TrainData::open(&config, &mut |_, _| {}).unwrap();
    device.seed(t.seed);
    let mut model = config.model.init(&device);
    let mut optimizer = adam(&config).init();
    let requests = (0..t.steps * k)
        .map(|scene| data.request_for_step(t.seed, scene, t.source_views))
        .collect();
    let mut loader =
        SceneLoader::new(data.dataset.source.clone(), requests, data.dataset.loader).unwrap();
    let faces = &data.dataset.source.faces;
    let mut losses = Vec::new();
    let mut clipped = 0;
    for step in 0..t.steps {
        let mut parts = Vec::new();
        let mut loss_sum = 0.0;
        for i in 0..k {
            let scene = loader.next().unwrap().unwrap();
            let SceneTarget::Rays(rays) = &scene.target else {
                panic!("a training scene has rays");
            };
            let index = step * k + i;
            let input = SceneInput::from_loaded(&scene, faces);
            let encoded = model.encode(&input, None, &device, None).unwrap();
            let mut rng = Rng::new(t.seed).fork(index).fork(JITTER_STREAM);
            let jitter: Vec<f32> = (0..rays.len() * t.samples).map(|_| rng.uniform()).collect();
            let out = model
                .render(&encoded, &rays.rays, t.samples, Some(&jitter), None)
                .unwrap();
            let gt: Vec<f32> = rays.rgb.iter().flatten().copied().collect();
            let gt = Tensor::<2>::from_data(TensorData::new(gt, [rays.len(), 3]), &device);
            let loss = render_loss(out.rgb, out.rgb0, gt).unwrap().total;
            loss_sum += loss.clone().detach().into_scalar::<f32>() as f64;
            parts.push(GradientsParams::from_grads(loss.backward(), &model));
        }
        losses.push(loss_sum / k as f64);
        let mut add = AddByHand {
            parts: &mut parts,
            sum: GradientsParams::new(),
        };
        model.visit(&mut add);
        let mut grads = add.sum;
        let mut norm = HostSquaredNorm {
            grads: &grads,
            total: 0.0,
        };
        model.visit(&mut norm);
        let norm = norm.total.sqrt();
        eprintln!(
            "reference step {step}: mean loss {}, gradient norm {norm}",
            losses[losses.len() - 1]
        );
        let max_norm = config.optim.grad_clip_norm as f64;
        if max_norm > 0.0 && norm > max_norm {
            clipped += 1;
            model.visit(&mut ScaleByHand {
                grads: &mut grads,
                factor: (max_norm / norm) as f32,
            });
        }
        model = optimizer.step(config.optim.lr_at(step), model, grads);
    }
    // `valid()` commits the batch-norm running statistics' pending update (burn's
    // `RunningState` keeps the last one pending until it is read with a sync), as writing the
    // checkpoint the runs are read from does.
    (flat_weights(&model.valid()), losses, clipped)
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
fn two_devices_equal_one_device_adding_the_gradients_by_hand_and_resume() {
    let dir = common::scratch("multi", "runs");

    // ndarray + flex through nia-train's multi-device path, against the reference on ndarray
    // alone with the two scenes' gradients added by hand.
    let two = train(&dir, "two", 2, "\"ndarray\", \"flex\"", &[]);
    let config = dir.join("two").join("tiny.toml");
    let (reference, reference_losses, clipped) = one_device_reference(&config);
    assert_eq!(clipped, 2, "every step clips (GRAD_CLIP_NORM)");
    let (max, share) = differing_share(&weights(&two), &reference);
    eprintln!(
        "ndarray+flex vs reference: largest difference {max:e}, share beyond rounding {share:e}"
    );
    assert!(max <= MAX_DIFF, "largest difference {max}");
    assert!(
        share <= MAX_DIFFERING_SHARE,
        "{share} of the weights differ"
    );
    let two_losses = losses(&two);
    assert_eq!(two_losses.len(), reference_losses.len());
    for (a, b) in two_losses.iter().zip(&reference_losses) {
        assert!(
            (a - b).abs() <= LOSS_REL_TOL * b.abs(),
            "step loss {a} vs {b}"
        );
    }

    // The same multi-device path with ndarray twice: no backend rounding between the devices,
    // so only the order of float additions separates it from the reference.
    let same = train(&dir, "same", 2, "\"ndarray\", \"ndarray\"", &[]);
    let (max_same, _) = differing_share(&weights(&same), &reference);
    eprintln!("ndarray+ndarray vs reference: largest difference {max_same:e}");
    assert!(
        max_same <= SAME_BACKEND_MAX_DIFF,
        "largest difference {max_same}"
    );

    // A single device sees one scene per step: clearly other weights.
    let single = train(&dir, "single", 2, "\"ndarray\"", &[]);
    let (_, share_single) = differing_share(&weights(&single), &reference);
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

/// `train.ray_chunk`: the step's 32 rays in chunks of 8, each with its own backward and the
/// encoder's share through the cut, train to the weights and losses of one pass over all rays
/// (one device; only the order of float additions differs, and the sign flips of near-zero
/// gradients under Adam that [`MAX_DIFF`] allows).
#[test]
fn ray_chunks_train_like_one_pass_over_all_rays() {
    let dir = common::scratch("multi", "chunks");
    let whole = train(&dir, "whole", 2, "\"ndarray\"", &[]);
    let chunked = train(
        &dir,
        "chunked",
        2,
        "\"ndarray\"",
        &["--set", "train.ray_chunk=8"],
    );
    let (max, share) = differing_share(&weights(&chunked), &weights(&whole));
    eprintln!(
        "chunks of 8 vs one pass: largest difference {max:e}, share beyond rounding {share:e}"
    );
    assert!(max <= MAX_DIFF, "largest difference {max}");
    assert!(
        share <= MAX_DIFFERING_SHARE,
        "{share} of the weights differ"
    );
    let (a, b) = (losses(&chunked), losses(&whole));
    assert_eq!(a.len(), 2);
    assert_eq!(a.len(), b.len());
    for (a, b) in a.iter().zip(&b) {
        assert!(
            (a - b).abs() <= LOSS_REL_TOL * b.abs(),
            "step loss {a} vs {b}"
        );
    }
}
