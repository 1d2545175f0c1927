//! `--set section.key=value` overrides of a run config: TOML values and bare words, nested
//! keys, the order of several, and errors that name the override or the key.

use nia_data::fitting::SmplAlignment;
use nia_model::render_options::RenderOptions;
use nia_model::sampler::RaySampler;
use nia_train::config::{ConfigError, TrainConfig};

mod common;

fn overrides(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

#[test]
fn overrides_write_over_the_file() {
    let dir = common::scratch("overrides", "ok");
    let path = common::tiny_config(&dir, 2, 5, "");
    let config = TrainConfig::load_with(
        &path,
        &overrides(&[
            "train.steps=7",
            "train.mask_loss_weight = 0.3",
            "train.backend=flex",
            "model.ray_sampler={ kind = \"band\" }",
            "model.body_volume.full_convs=2",
            "optim.lr=1e-3",
            "optim.lr=2e-3",
            "render.skip_empty_space=false",
            "model.source_colours_at=surface",
            "train.distortion_loss_weight=0.5",
        ]),
    )
    .unwrap();
    assert_eq!(config.train.steps, 7);
    assert_eq!(config.train.mask_loss_weight, 0.3);
    assert_eq!(config.train.backend.name(), "flex");
    assert!(matches!(config.model.ray_sampler, RaySampler::Band { .. }));
    assert_eq!(config.model.body_volume.full_convs, 2);
    assert_eq!(config.optim.lr, 2e-3, "the last of two overrides wins");
    assert!(!config.render.skip_empty_space);
    assert_eq!(
        config.model.source_colours_at,
        Some(nia_model::config::SourceColoursAt::Surface)
    );
    assert_eq!(config.train.distortion_loss_weight, 0.5);
    // Keys the overrides do not touch keep the file's values.
    assert_eq!(config.train.rays_per_step, 32);
    assert_eq!(
        config.render.empty_space_m,
        RenderOptions::default().empty_space_m
    );
    // No overrides: the same as `load`.
    let plain = TrainConfig::load_with(&path, &[]).unwrap();
    assert_eq!(plain.train.steps, 2);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A tagged enum given another kind than the preset's takes its own fields (the tiny preset
/// samples stratified, which has no `margin_m`); keys under the same kind merge as sections do.
#[test]
fn a_sampler_of_another_kind_takes_its_own_fields() {
    let dir = common::scratch("overrides", "kind");
    let path = common::tiny_config(&dir, 2, 5, "");
    let band = |list: &[&str]| match TrainConfig::load_with(&path, &overrides(list))
        .unwrap()
        .model
        .ray_sampler
    {
        RaySampler::Band { margin_m, cell_m } => (margin_m, cell_m),
        other => panic!("expected the band sampler, got {other:?}"),
    };
    let (margin_m, cell_m) = band(&["model.ray_sampler={ kind = \"band\", margin_m = 0.08 }"]);
    assert_eq!(margin_m, 0.08);
    assert_eq!(cell_m, nia_model::render_options::DEFAULT_OCCUPANCY_CELL_M);
    let (margin_m, cell_m) = band(&[
        "model.ray_sampler={ kind = \"band\", margin_m = 0.08 }",
        "model.ray_sampler.cell_m=0.03",
    ]);
    assert_eq!(
        (margin_m, cell_m),
        (0.08, 0.03),
        "same kind: the keys merge"
    );
    let err = TrainConfig::load_with(
        &path,
        &overrides(&["model.ray_sampler={ kind = \"band\", margin = 0.08 }"]),
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("model.ray_sampler") && err.contains("margin"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_overrides_name_the_setting_or_the_key() {
    let dir = common::scratch("overrides", "bad");
    let path = common::tiny_config(&dir, 2, 5, "");
    let message = |list: &[&str]| match TrainConfig::load_with(&path, &overrides(list)) {
        Ok(_) => panic!("{list:?} was accepted"),
        Err(e) => (matches!(e, ConfigError::Override { .. }), e.to_string()),
    };
    let (is_override, m) = message(&["train.steps"]);
    assert!(
        is_override && m.contains("--set `train.steps`") && m.contains("section.key=value"),
        "{m}"
    );
    let (is_override, m) = message(&["steps=3"]);
    assert!(
        is_override && m.contains("`steps` is not `section.key`"),
        "{m}"
    );
    let (is_override, m) = message(&["train.steps.deeper=3"]);
    assert!(is_override && m.contains("`train.steps` is a value"), "{m}");
    let (_, m) = message(&["train.stepz=3"]);
    assert!(m.contains("stepz"), "{m}");
    let (_, m) = message(&["train.steps=many"]);
    assert!(m.contains("steps"), "{m}");
    let (_, m) = message(&["train.mask_loss_weight=-1"]);
    assert!(m.contains("train.mask_loss_weight"), "{m}");
    let (_, m) = message(&["train.distortion_loss_weight=nan"]);
    assert!(m.contains("train.distortion_loss_weight"), "{m}");
    // A removed switch is an unknown key.
    let (_, m) = message(&["train.ibr_loss_weight=0"]);
    assert!(m.contains("ibr_loss_weight"), "{m}");
    let (_, m) = message(&["model.source_colours_at=\"expected\""]);
    assert!(
        m.contains("model.source_colours_at") && m.contains("`samples` or `surface`"),
        "{m}"
    );
    // The SMPL alignment's table: a setting out of range names its key, an unknown one too.
    let (_, m) = message(&["data.smpl_alignment={ robust_m = 0.0 }"]);
    assert!(
        m.contains("data.smpl_alignment.robust_m") && m.contains("(0, 1]"),
        "{m}"
    );
    let (_, m) = message(&["data.smpl_alignment={ robust = 0.03 }"]);
    assert!(m.contains("robust"), "{m}");
    let aligned = TrainConfig::load_with(&path, &overrides(&["data.smpl_alignment={}"])).unwrap();
    assert_eq!(aligned.data.smpl_alignment, Some(SmplAlignment::default()));
    let (_, m) = message(&["data.smpl_alignment={ pose_iterations = 20, pose_prior_deg = -1.0 }"]);
    assert!(
        m.contains("data.smpl_alignment.pose_prior_deg") && m.contains("(0, 180]"),
        "{m}"
    );
    let posed = TrainConfig::load_with(
        &path,
        &overrides(&["data.smpl_alignment={ pose_iterations = 20 }"]),
    )
    .unwrap();
    let posed = posed.data.smpl_alignment.unwrap();
    assert_eq!((posed.pose_iterations, posed.pose_prior_deg), (20, 40.0));
    let _ = std::fs::remove_dir_all(&dir);
}
