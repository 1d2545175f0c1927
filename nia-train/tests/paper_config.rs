//! `configs/zju_paper.toml` is the paper's method and NHP's protocol with nothing added: its
//! keys, section by section, are exactly the written list below at the paper's values (the
//! user's three paths aside), and the config it resolves to has every nia-rs addition off.

use std::path::Path;

use nia_model::config::SourceColoursAt;
use nia_model::sampler::RaySampler;
use nia_model::{ModelConfig, RenderOptions, Variant};
use nia_train::config::TrainConfig;

/// The paper's values (NIA section 4 and appendix; NHP's protocol and schedule), one table per
/// section. Where the user's copies of data, SMPL and weights are is theirs to set.
const PAPER: &str = r#"
[data]
format = "zju"
ratio = 0.5
protocol = "nhp"
border_px = 5
body_fraction = 0.5
smpl_jitter_m = 0.0

[model]
preset = "paper"
variant = "full"
voxel_size_m = 0.005
ray_sampler = { kind = "stratified" }
source_colours_at = "samples"
blend_view_statistics = false

[optim]
lr = 5e-4
beta1 = 0.9
beta2 = 0.999
adam_eps = 1e-8
decay_steps = 500000
grad_clip_norm = 0.0

[train]
steps = 125000
rays_per_step = 1024
samples = 64
source_views = 3
seed = 0
checkpoint_every = 5000
keep_last = 3
validate_every = 5000
evaluate_at_end = true
backend = "wgpu"
mask_loss_weight = 0.0
distortion_loss_weight = 0.0
c0_shuffle = 0.0
colour_gain_tolerance = 0.0

[render]
skip_empty_space = false
early_termination = 0.0
colour_culling = 0.0
visual_hull = false
supersample = 1
c0_weight_scale = 1.0
"#;

/// Keys whose values are the user's files, not the method's.
const PATHS: [(&str, &str); 3] = [
    ("data", "root"),
    ("data", "smpl_model"),
    ("train", "encoder_weights"),
];

fn config_path() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/zju_paper.toml")
}

#[test]
fn every_section_holds_exactly_the_papers_keys_and_values() {
    let text = std::fs::read_to_string(config_path()).unwrap();
    let mut file: toml::Table = toml::from_str(&text).unwrap();
    let paper: toml::Table = toml::from_str(PAPER).unwrap();
    for (section, key) in PATHS {
        let table = file[section].as_table_mut().unwrap();
        assert!(
            table.remove(key).is_some(),
            "{section}.{key}: the user's path is there"
        );
    }
    let sections = |t: &toml::Table| t.keys().cloned().collect::<Vec<_>>();
    assert_eq!(sections(&file), sections(&paper), "the sections");
    for (section, expected) in &paper {
        let got = file[section].as_table().unwrap();
        let expected = expected.as_table().unwrap();
        for (key, value) in expected {
            assert_eq!(
                got.get(key),
                Some(value),
                "{section}.{key}: the paper's value"
            );
        }
        for key in got.keys() {
            assert!(
                expected.contains_key(key),
                "{section}.{key}: not in the paper's list (an addition?)"
            );
        }
    }
}

#[test]
fn the_resolved_config_has_every_addition_off() {
    // The data folder, SMPL model and encoder weights are the user's: existing stand-ins.
    let root = std::env::temp_dir().join(format!("nia-paper-config-{}", std::process::id()));
    std::fs::create_dir_all(&root).unwrap();
    let file = root.join("stand-in");
    std::fs::write(&file, b"").unwrap();
    let quoted = |p: &Path| format!("{:?}", p.display().to_string());
    let overrides = [
        format!("data.root={}", quoted(&root)),
        format!("data.smpl_model={}", quoted(&file)),
        format!("train.encoder_weights={}", quoted(&file)),
    ];
    let config = TrainConfig::load_with(&config_path(), &overrides).unwrap();
    let _ = std::fs::remove_dir_all(&root);
    // The network: the paper preset, as ModelConfig::new() defines it.
    let paper_net = ModelConfig::new()
        .with_source_colours_at(Some(SourceColoursAt::Samples))
        .with_variant(Variant::Full);
    assert_eq!(config.model, paper_net);
    assert_eq!(config.model.ray_sampler, RaySampler::Stratified);
    assert!(!config.model.blend_view_statistics);
    // Data: the stored SMPL.
    assert_eq!(config.data.smpl_jitter_m, 0.0);
    assert!(config.data.smpl_alignment.is_none());
    // The loss: the paper's two terms alone; no clipping.
    let t = &config.train;
    assert_eq!(
        (
            t.mask_loss_weight,
            t.distortion_loss_weight,
            t.c0_shuffle,
            t.c0_noise_std,
            t.colour_gain_tolerance
        ),
        (0.0, 0.0, 0.0, 0.0, 0.0)
    );
    assert_eq!(config.optim.grad_clip_norm, 0.0);
    assert_eq!((t.rays_per_step, t.samples, t.source_views), (1024, 64, 3));
    // Rendering: every sample, the paper's blend, no carving.
    assert_eq!(config.render, RenderOptions::exhaustive());
}
