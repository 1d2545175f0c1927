//! Crash safety of training with real `SIGKILL`s: the `nia-train` process is killed in the
//! middle of a checkpoint write (held open by the fault-injection pause,
//! [`checkpoint::FAULT_PAUSE_ENV`]) and at other points; every time, the newest complete
//! checkpoint loads, `--resume` continues from it, and the run finishes with a loadable final
//! checkpoint.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use nia_model::store::checkpoint::{self, FAULT_PAUSE_ENV};
use nia_train::config::TrainConfig;

mod common;

fn scratch(name: &str) -> PathBuf {
    common::scratch("crash", name)
}

/// The tiny config (1 training subject, 48 px, 8 samples) checkpointing after every step.
fn tiny_config(dir: &Path, steps: u64) -> PathBuf {
    common::tiny_config(dir, steps, 3, "validate_every = 0\nevaluate_at_end = false")
}

/// How long one tiny run may take before the test gives up waiting for a state.
const WAIT_LIMIT: Duration = Duration::from_secs(300);

fn spawn(config: &Path, out: &Path, resume: bool, pause_ms: Option<u64>) -> Child {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_nia-train"));
    cmd.arg("--config").arg(config).arg("--out").arg(out);
    if resume {
        cmd.arg("--resume");
    }
    match pause_ms {
        Some(ms) => cmd.env(FAULT_PAUSE_ENV, ms.to_string()),
        None => cmd.env_remove(FAULT_PAUSE_ENV),
    };
    cmd.stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Waits until `ready()` holds; panics (after killing `child`) if the child exits first or
/// the wait runs past [`WAIT_LIMIT`].
fn wait_for(child: &mut Child, what: &str, ready: impl Fn() -> bool) {
    let start = Instant::now();
    while !ready() {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            if let Some(mut e) = child.stderr.take() {
                use std::io::Read;
                let _ = e.read_to_string(&mut err);
            }
            panic!("nia-train exited ({status}) before {what}:\n{err}");
        }
        if start.elapsed() > WAIT_LIMIT {
            let _ = child.kill();
            panic!("timed out waiting for {what}");
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// `SIGKILL` (what `Child::kill` sends on Unix) and reap; `false` when the process had already
/// finished on its own (it can exit between a caller's last check and the kill).
fn try_kill9(child: &mut Child) -> bool {
    child.kill().unwrap();
    !child.wait().unwrap().success()
}

/// [`try_kill9`] of a process that must still be running (it waits on something).
fn kill9(child: &mut Child) {
    assert!(try_kill9(child), "the process was killed, not finished");
}

fn checkpoints_dir(out: &Path) -> PathBuf {
    out.join(checkpoint::CHECKPOINT_DIR)
}

/// Temporary (partial) checkpoint folders left in `out`.
fn partial_writes(out: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(checkpoints_dir(out)) else {
        return Vec::new();
    };
    entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with(".tmp_"))
        })
        .collect()
}

/// Loads the newest complete checkpoint (model and optimiser) the way `--resume` does and
/// returns its step.
fn load_latest(out: &Path) -> u64 {
    // burn restores optimiser state on its default device; keep it on the CPU here, as the
    // nia-train binary does for a CPU run.
    std::env::set_var("BURN_DEVICE", "ndarray");
    let (step, dir) = checkpoint::latest(out)
        .unwrap()
        .expect("a complete checkpoint exists");
    let saved = checkpoint::read_config(&dir).unwrap();
    let run: TrainConfig = serde_json::from_value(saved.run.clone()).unwrap();
    #[allow(deprecated)] // burn 0.22 spells the CPU device this way.
    let device = burn::prelude::Device::ndarray().autodiff();
    let model = saved.model.init(&device);
    let optimizer = nia_train::train_loop::adam(&run).init();
    let (_, _, loaded_step) = checkpoint::load(&dir, model, optimizer)
        .unwrap_or_else(|e| panic!("checkpoint {} does not load: {e}", dir.display()));
    assert_eq!(loaded_step, step);
    step
}

#[test]
fn sigkill_during_a_checkpoint_write_keeps_the_previous_checkpoint() {
    let dir = scratch("mid-write");
    let config = tiny_config(&dir, 3);
    let out = dir.join("run");
    // Every checkpoint write pauses 3 s between the model file and the optimiser file.
    let mut child = spawn(&config, &out, false, Some(3_000));
    let second_partial = checkpoints_dir(&out)
        .join(".tmp_step_00000002")
        .join(checkpoint::MODEL_FILE);
    // The first checkpoint is complete and the second is half written: kill now.
    wait_for(&mut child, "the second checkpoint write", || {
        second_partial.is_file() && checkpoints_dir(&out).join("step_00000001").is_dir()
    });
    kill9(&mut child);
    assert!(
        second_partial.is_file(),
        "the kill landed inside the write: the partial folder is still there"
    );
    assert!(!checkpoints_dir(&out).join("step_00000002").exists());
    assert_eq!(load_latest(&out), 1, "the previous checkpoint loads");

    // Resume without the pause: the run finishes and the partial write is cleaned up.
    let child = spawn(&config, &out, true, None);
    let output = child.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "resume failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert_eq!(load_latest(&out), 3);
    assert!(
        partial_writes(&out).is_empty(),
        "{:?}",
        partial_writes(&out)
    );
    let log = std::fs::read_to_string(out.join("metrics.jsonl")).unwrap();
    assert!(
        log.contains(r#""event":"started","first_step":1"#),
        "the resumed run started after step 1:\n{log}"
    );
}

#[test]
fn survives_repeated_sigkills_at_random_points() {
    let dir = scratch("random");
    let steps = 6;
    let config = tiny_config(&dir, steps);
    let out = dir.join("run");
    // Kill times after each (re)start, from a fixed LCG so failures reproduce; the second kill
    // waits for a checkpoint write (they pause 400 ms half-way) and lands inside it.
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut kills = 0;
    let mut mid_write = 0;
    for cycle in 0..4 {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        let delay = Duration::from_millis(300 + (state >> 33) % 2_500);
        let mut child = spawn(&config, &out, cycle > 0, Some(400));
        let start = Instant::now();
        if cycle == 1 {
            // One kill is aimed inside a checkpoint write: wait for a temporary folder.
            while partial_writes(&out).is_empty()
                && child.try_wait().unwrap().is_none()
                && start.elapsed() < WAIT_LIMIT
            {
                std::thread::sleep(Duration::from_millis(2));
            }
        } else {
            while start.elapsed() < delay && child.try_wait().unwrap().is_none() {
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        if child.try_wait().unwrap().is_some() {
            // Finished before the kill: nothing left to interrupt.
            break;
        }
        let cycle_start = std::time::SystemTime::now() - start.elapsed();
        if !try_kill9(&mut child) {
            // Finished between the check above and the kill.
            break;
        }
        kills += 1;
        // A temporary folder created by this process: the kill landed inside its write.
        if partial_writes(&out).iter().any(|p| {
            std::fs::metadata(p)
                .and_then(|m| m.modified())
                .is_ok_and(|t| t >= cycle_start)
        }) {
            mid_write += 1;
        }
        if checkpoint::latest(&out).unwrap().is_some() {
            load_latest(&out);
        }
    }
    let output = spawn(&config, &out, true, None).wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "the final resume failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert_eq!(load_latest(&out), steps, "the run completed");
    assert!(partial_writes(&out).is_empty());
    assert!(kills >= 2, "kills landed before the run ended: {kills}");
    assert!(mid_write >= 1, "one kill landed inside a checkpoint write");
    eprintln!("survived {kills} SIGKILLs ({mid_write} inside a checkpoint write)");
}
