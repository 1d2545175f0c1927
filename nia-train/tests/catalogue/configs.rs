//! Broken or contradictory config files.

use super::*;

/// One-line edits of the tiny config: (case name, texts stderr must contain, old, new).
#[rustfmt::skip]
const EDITS: &[(&str, &[&str], &str, &str)] = &[
    ("config_unknown_key", &["tiny.toml", "stepz"], "steps = 1", "steps = 1\nstepz = 3"),
    ("config_unknown_section", &["tiny.toml", "trian"], "[train]", "[trian]\nsteps = 1\n\n[train]"),
    ("config_wrong_type", &["tiny.toml", "train.samples", "string"], "samples = 4", "samples = \"four\""),
    ("config_negative_steps", &["tiny.toml", "train.steps", "-1"], "steps = 1", "steps = -1"),
    ("config_zero_rays", &["tiny.toml", "train.rays_per_step", ">= 1"], "rays_per_step = 16", "rays_per_step = 0"),
    ("config_one_sample", &["tiny.toml", "train.samples", ">= 2"], "samples = 4", "samples = 1"),
    ("config_nan_learning_rate", &["tiny.toml", "optim.lr", "positive", "NaN"], "[train]", "[optim]\nlr = nan\n\n[train]"),
    ("config_early_termination_out_of_range", &["tiny.toml", "render.early_termination", "[0, 1)", "1.5"], "[train]", "[render]\nearly_termination = 1.5\n\n[train]"),
    ("config_colour_culling_out_of_range", &["tiny.toml", "render.colour_culling", "[0, 1)", "-0.5"], "[train]", "[render]\ncolour_culling = -0.5\n\n[train]"),
    ("config_hull_erosion_too_large", &["tiny.toml", "render.hull_body_erode_px", "at most 256", "1000"], "[train]", "[render]\nhull_body_erode_px = 1000\n\n[train]"),
    ("config_supersample_zero", &["tiny.toml", "render.supersample", "1 to 8", "0"], "[train]", "[render]\nsupersample = 0\n\n[train]"),
    ("config_c0_shuffle_out_of_range", &["tiny.toml", "train.c0_shuffle", "[0, 1]", "2"], "samples = 4", "samples = 4\nc0_shuffle = 2.0"),
    ("config_c0_noise_negative", &["tiny.toml", "train.c0_noise_std", ">= 0", "-0.1"], "samples = 4", "samples = 4\nc0_noise_std = -0.1"),
    ("config_ratio_out_of_range", &["tiny.toml", "data.ratio", "(0, 1]", "1.5"], "ratio = 1.0", "ratio = 1.5"),
    ("config_unknown_backend", &["tiny.toml", "train.backend", "tpu", "ndarray"], "backend = \"ndarray\"", "backend = \"tpu\""),
    ("config_unknown_preset", &["tiny.toml", "model.preset", "huge", "tiny"], "preset = \"tiny\"", "preset = \"huge\""),
    ("config_unknown_variant", &["tiny.toml", "model.variant", "best", "full"], "preset = \"tiny\"", "preset = \"tiny\"\nvariant = \"best\""),
    ("config_source_views_not_below_cameras", &["train.source_views", "4 cameras"], "source_views = 3", "source_views = 4"),
    // The existing dataset (synth.json: 4 cameras) disagrees with the config's [synth]
    // section (6 cameras): named with the key and synth.json.
    ("config_synth_section_disagrees_with_the_data", &["tiny.toml", "synth.cameras", "synth.json"], "cameras = 4", "cameras = 6"),
    ("config_bad_toml_syntax", &["tiny.toml", "line 14", "unclosed table"], "[model]", "[model"),
];

/// Whole config files: (case name, texts stderr must contain, the file's bytes).
#[rustfmt::skip]
const RAW: &[(&str, &[&str], &[u8])] = &[
    ("config_empty_file", &["tiny.toml", "missing field `data`"], b""),
    ("config_not_utf8", &["tiny.toml", "cannot read", "UTF-8"], b"[data]\nroot = \"\xff\xfe\"\n"),
];

pub(super) fn cases() -> Vec<Case> {
    let mut cases: Vec<Case> = EDITS
        .iter()
        .map(|&(name, expect, old, new)| {
            case(name, expect, move |c| {
                let config = c.config(&[(old, new)]);
                c.train_args(&config, &[])
            })
        })
        .collect();
    cases.extend(RAW.iter().map(|&(name, expect, bytes)| {
        case(name, expect, move |c| {
            c.train_args(&c.config_raw(bytes), &[])
        })
    }));
    cases.extend([
        case(
            "config_missing_data_root_folder",
            &[
                "tiny.toml",
                "data.root",
                "an existing folder",
                "no_such_folder",
            ],
            |c| {
                let line = format!("root = \"{}\"", slash(&c.dir.join("no_such_folder")));
                let mut text = config_text(&c.dir.join("no_such_folder"));
                // Without [synth] nothing generates the folder.
                let synth = text.find("[synth]").unwrap();
                let model = text.find("[model]").unwrap();
                text.replace_range(synth..model, "");
                assert!(text.contains(&line));
                let config = c.config_raw(text.as_bytes());
                c.train_args(&config, &[])
            },
        ),
        case("config_missing_root_key", &["tiny.toml", "root"], |c| {
            let root = format!("root = \"{}\"\n", slash(&c.data()));
            let config = c.config(&[(&root, "")]);
            c.train_args(&config, &[])
        }),
        case(
            "config_missing_train_section",
            &["tiny.toml", "train"],
            |c| {
                let text = config_text(&c.data());
                let at = text.find("[train]").unwrap();
                let config = c.config_raw(&text.as_bytes()[..at]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_visibility_cache_is_a_file",
            &["vis_cache_file"],
            |c| c.train_with_file("vis_cache_file", b"", "visibility_cache"),
        ),
        case(
            "config_init_from_missing_folder",
            &["tiny.toml", "train.init_from", "model.bpk"],
            |c| {
                let line = format!("steps = 1\ninit_from = \"{}\"", slash(&c.dir.join("nope")));
                let config = c.config(&[("steps = 1", &line)]);
                c.train_args(&config, &[])
            },
        ),
        case("config_is_a_folder", &["cannot read", "a directory"], |c| {
            let dir = c.dir.join("folder.toml");
            std::fs::create_dir_all(&dir).unwrap();
            c.train_args(&dir, &[])
        }),
    ]);
    cases
}
