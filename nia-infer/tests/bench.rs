//! `nia-infer bench` as a user runs it, at toy sizes on the CPU backends: the JSON line it ends
//! with, the cross-backend check, the training-only mode, and refused flag combinations.

mod common;

use common::{fails_with, nia_infer, ok};

/// ndarray and flex run the same network with different kernels (host fast paths on flex):
/// colours in [0, 1] agree far inside this.
const BACKEND_TOL: f64 = 1e-4;

/// The last stdout line as JSON (the table comes first).
fn report(args: &[&str]) -> serde_json::Value {
    let out = nia_infer(args);
    ok(&out);
    last_json(&String::from_utf8_lossy(&out.stdout))
}

fn last_json(stdout: &str) -> serde_json::Value {
    let line = stdout.lines().last().expect("bench printed nothing");
    serde_json::from_str(line).unwrap_or_else(|e| panic!("not JSON ({e}): {line}"))
}

/// The tiny network at toy sizes: 8 rays of 4 samples, 32 x 32 sources, one timed repetition.
const TOY: [&str; 9] = [
    "--tiny",
    "--rays",
    "8",
    "--samples",
    "4",
    "--size",
    "32",
    "--reps",
    "1",
];

/// `nia-infer bench` on `backend` at toy sizes, then `extra`.
fn toy<'a>(backend: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["bench", "--backend", backend];
    args.extend(TOY);
    args.extend(extra);
    args
}

/// The training step alone on flex at toy sizes, in chunks of `ray_chunk` rays (0: without
/// chunks).
fn train_toy(ray_chunk: &str) -> Vec<&str> {
    toy("flex", &["--train-only", "--ray-chunk", ray_chunk])
}

#[test]
fn check_against_reports_a_small_difference_between_backends() {
    let v = report(&toy("ndarray", &["--no-train", "--check-against", "flex"]));
    let check = &v["check"];
    assert_eq!(check["against"], "flex");
    let max = check["max_abs_diff"].as_f64().unwrap();
    let rel = check["rel_l2"].as_f64().unwrap();
    assert!(
        max.is_finite() && max <= BACKEND_TOL,
        "max |difference| {max}"
    );
    assert!(rel.is_finite() && rel <= BACKEND_TOL, "relative L2 {rel}");
    assert!(check["gradients"].as_array().unwrap().is_empty());
    // The first (warm-up) forward is reported apart from the steady state.
    assert!(v["first_forward_s"].as_f64().unwrap() > 0.0);
    assert!(v["forward_s"].as_f64().unwrap() > 0.0);
    assert!(
        v["train_step_s"].is_null(),
        "--no-train: {}",
        v["train_step_s"]
    );
}

/// With the training step, `--check-against` also compares one training forward's gradients:
/// the encoder, the body volume, F_sigma and F_B, each within float rounding of the other
/// backend's.
#[test]
fn check_against_with_training_compares_the_gradients() {
    let v = report(&toy("ndarray", &["--check-against", "flex"]));
    let gradients = v["check"]["gradients"].as_array().unwrap();
    let names: Vec<&str> = gradients.iter().map(|g| g[0].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "encoder.conv1",
            "body_volume.full[0]",
            "density",
            "blender.token_input"
        ]
    );
    for g in gradients {
        let rel = g[1].as_f64().unwrap();
        assert!(rel.is_finite() && rel <= 1e-3, "{g}");
    }
    assert!(v["train_step_s"].as_f64().unwrap() > 0.0);
}

#[test]
fn train_only_times_the_training_step_alone() {
    let v = report(&train_toy("0"));
    assert!(
        v["forward_s"].is_null() && v["first_forward_s"].is_null(),
        "{v}"
    );
    let step = v["train_step_s"].as_f64().unwrap();
    let forward = v["train_forward_s"].as_f64().unwrap();
    let backward = v["train_backward_s"].as_f64().unwrap();
    assert!(step > 0.0 && forward > 0.0 && backward >= 0.0);
    assert!(
        (forward + backward - step).abs() < 1e-9,
        "{forward} + {backward} != {step}"
    );
    assert!(v["first_train_step_s"].as_f64().unwrap() > 0.0);
    assert!(v["check"].is_null());
    // The forward's stage table is not printed with NaN seconds when the forward is skipped.
    let out = nia_infer(&train_toy("0"));
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("stages: not timed (--train-only)"),
        "{stdout}"
    );
    assert!(!stdout.contains("NaN"), "{stdout}");
}

/// `--ray-chunk`: the training step in chunks of 3 of the 8 rays is timed whole (no forward
/// and backward split, null rather than NaN in the JSON) and says so.
#[test]
fn ray_chunks_time_the_whole_step() {
    let out = nia_infer(&train_toy("3"));
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("in chunks of 3 rays"), "{stdout}");
    let v = last_json(&stdout);
    assert!(v["train_step_s"].as_f64().unwrap() > 0.0, "{v}");
    assert!(
        v["train_forward_s"].is_null() && v["train_backward_s"].is_null(),
        "{v}"
    );
}

/// The steady figures are medians of the timed repetitions, which the JSON lists: one
/// repetition that meets a new kernel on a GPU (seconds against a fraction of one) leaves the
/// median where the others are, as the PyTorch references report theirs.
#[test]
fn steady_figures_are_medians_of_the_listed_repetitions() {
    let mut args = toy("flex", &[]); // with the training step
    let reps = args.iter().position(|a| *a == "--reps").unwrap() + 1;
    args[reps] = "3";
    let v = report(&args);
    for (figure, list) in [
        ("forward_s", "forward_reps_s"),
        ("train_step_s", "train_reps_s"),
    ] {
        let mut times: Vec<f64> = v[list]
            .as_array()
            .unwrap_or_else(|| panic!("{list} missing: {v}"))
            .iter()
            .map(|t| t.as_f64().unwrap())
            .collect();
        assert_eq!(times.len(), 3, "{list}: {v}");
        assert!(
            times.iter().all(|t| t.is_finite() && *t > 0.0),
            "{list}: {v}"
        );
        times.sort_by(f64::total_cmp);
        assert_eq!(
            v[figure].as_f64().unwrap(),
            times[1],
            "{figure} is not the median: {v}"
        );
    }
    // On a CPU backend a stage's synchronisation is free: the timed forwards give the stages.
    assert_eq!(v["stages_timed_apart"], false, "{v}");
    let stages = v["stages_s"].as_array().unwrap();
    assert!(stages.iter().all(|s| s[1].as_f64().unwrap() >= 0.0), "{v}");
    // The host's point inputs are a stage of their own, ahead of the reads at the points.
    let names: Vec<&str> = stages.iter().map(|s| s[0].as_str().unwrap()).collect();
    let at = |name: &str| {
        names
            .iter()
            .position(|n| *n == name)
            .unwrap_or_else(|| panic!("no stage {name}: {v}"))
    };
    assert!(at("point_inputs") < at("sampling"), "{v}");
    let point_inputs = stages[at("point_inputs")][1].as_f64().unwrap();
    assert!(
        point_inputs > 0.0,
        "no time charged to the point inputs: {v}"
    );
}

/// On wgpu the forward's figure is taken without stage timings (a device synchronisation at
/// the end of every stage), as the PyTorch references take theirs, and the stage table comes
/// from forwards of their own. Runs where a Vulkan driver is installed (Mesa's software one in
/// CI; `NIA_REQUIRE_WGPU=1` makes a missing one a failure); elsewhere wgpu would fall back to
/// OpenGL, far too slow.
#[cfg(feature = "wgpu")]
#[test]
fn on_wgpu_the_stages_are_timed_in_forwards_of_their_own() {
    if !nia_model::device::vulkan_driver_installed() {
        let message = "no Vulkan driver (install mesa-vulkan-drivers)";
        assert!(
            std::env::var("NIA_REQUIRE_WGPU").as_deref() != Ok("1"),
            "NIA_REQUIRE_WGPU=1 but {message}"
        );
        eprintln!("skipped: {message}");
        return;
    }
    let mut args = toy("wgpu", &["--no-train"]);
    let reps = args.iter().position(|a| *a == "--reps").unwrap() + 1;
    args[reps] = "2";
    let out = nia_infer(&args);
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let v = last_json(&stdout);
    assert_eq!(v["stages_timed_apart"], true, "{v}");
    assert!(
        stdout.contains("stages: timed in 2 forwards of their own"),
        "{stdout}"
    );
    let forwards = v["forward_reps_s"].as_array().unwrap();
    assert_eq!(forwards.len(), 2, "{v}");
    assert!(v["forward_s"].as_f64().unwrap() > 0.0, "{v}");
    let stages: Vec<(&str, f64)> = v["stages_s"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| (s[0].as_str().unwrap(), s[1].as_f64().unwrap()))
        .collect();
    for name in ["encoder", "point_inputs", "sampling", "mlps"] {
        assert!(
            stages.iter().any(|&(n, t)| n == name && t > 0.0),
            "no time charged to {name}: {v}"
        );
    }
}

#[test]
fn contradictory_flags_are_refused() {
    fails_with(
        &nia_infer(&["bench", "--train-only", "--no-train"]),
        &["--train-only", "--no-train"],
    );
    fails_with(
        &nia_infer(&["bench", "--train-only", "--check-against", "flex"]),
        &["--train-only", "--check-against"],
    );
    fails_with(
        &nia_infer(&["bench", "--check-against", "cuda"]),
        &["unknown backend `cuda`", "ndarray, flex or wgpu"],
    );
    // No timed repetition leaves no median to report.
    fails_with(&nia_infer(&["bench", "--reps", "0"]), &["--reps", "0"]);
}
