//! Broken checkpoints and model files.

use super::*;

pub(super) fn cases() -> Vec<Case> {
    vec![
        case("init_from_garbage_model_file", &["model.bpk"], |c| {
            let ckpt = c.checkpoint_copy(&c.dir.join("ckpt"));
            std::fs::write(ckpt.join("model.bpk"), b"not a burnpack").unwrap();
            let line = format!("steps = 1\ninit_from = \"{}\"", slash(&ckpt));
            let config = c.config(&[("steps = 1", &line)]);
            c.train_args(&config, &[])
        }),
        case("init_from_truncated_model_file", &["model.bpk"], |c| {
            let ckpt = c.checkpoint_copy(&c.dir.join("ckpt"));
            let p = ckpt.join("model.bpk");
            let old = std::fs::read(&p).unwrap();
            std::fs::write(&p, &old[..old.len() / 2]).unwrap();
            let line = format!("steps = 1\ninit_from = \"{}\"", slash(&ckpt));
            let config = c.config(&[("steps = 1", &line)]);
            c.train_args(&config, &[])
        }),
        case("init_from_another_network", &["model.bpk", "shape"], |c| {
            let ckpt = c.checkpoint_copy(&c.dir.join("ckpt"));
            let line = format!("steps = 1\ninit_from = \"{}\"", slash(&ckpt));
            let config = c.config(&[
                ("steps = 1", &line),
                ("preset = \"tiny\"", "preset = \"tiny\"\nd_model = 8"),
            ]);
            c.train_args(&config, &[])
        }),
        case(
            "resume_with_garbage_optimizer_file",
            &["optimizer.bpk"],
            |c| {
                let ckpt = c.checkpoint_copy(&c.dir.join("run/checkpoints/step_00000001"));
                std::fs::write(ckpt.join("optimizer.bpk"), b"not a burnpack").unwrap();
                let config = c.config(&[]);
                c.train_args(&config, &["--resume", "--steps", "2"])
            },
        ),
        case("resume_with_corrupt_step_json", &["step.json"], |c| {
            let ckpt = c.checkpoint_copy(&c.dir.join("run/checkpoints/step_00000001"));
            std::fs::write(ckpt.join("step.json"), b"{\"step\": \"one\"}").unwrap();
            let config = c.config(&[]);
            c.train_args(&config, &["--resume", "--steps", "2"])
        }),
    ]
}
