//! Broken or contradictory config files.

use super::*;

pub(super) fn cases() -> Vec<Case> {
    vec![
        case("config_unknown_key", &["tiny.toml", "stepz"], |c| {
            let config = c.config(&[("steps = 1", "steps = 1\nstepz = 3")]);
            c.train_args(&config, &[])
        }),
        case("config_unknown_section", &["tiny.toml", "trian"], |c| {
            let config = c.config(&[("[train]", "[trian]\nsteps = 1\n\n[train]")]);
            c.train_args(&config, &[])
        }),
        case(
            "config_wrong_type",
            &["tiny.toml", "train.samples", "string"],
            |c| {
                let config = c.config(&[("samples = 4", "samples = \"four\"")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_negative_steps",
            &["tiny.toml", "train.steps", "-1"],
            |c| {
                let config = c.config(&[("steps = 1", "steps = -1")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_zero_rays",
            &["tiny.toml", "train.rays_per_step", ">= 1"],
            |c| {
                let config = c.config(&[("rays_per_step = 16", "rays_per_step = 0")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_one_sample",
            &["tiny.toml", "train.samples", ">= 2"],
            |c| {
                let config = c.config(&[("samples = 4", "samples = 1")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_nan_learning_rate",
            &["tiny.toml", "optim.lr", "positive", "NaN"],
            |c| {
                let config = c.config(&[("[train]", "[optim]\nlr = nan\n\n[train]")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_early_termination_out_of_range",
            &["tiny.toml", "render.early_termination", "[0, 1)", "1.5"],
            |c| {
                let config =
                    c.config(&[("[train]", "[render]\nearly_termination = 1.5\n\n[train]")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_colour_culling_out_of_range",
            &["tiny.toml", "render.colour_culling", "[0, 1)", "-0.5"],
            |c| {
                let config = c.config(&[("[train]", "[render]\ncolour_culling = -0.5\n\n[train]")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_hull_dilation_too_large",
            &["tiny.toml", "render.hull_dilate_px", "at most 256", "1000"],
            |c| {
                let config = c.config(&[("[train]", "[render]\nhull_dilate_px = 1000\n\n[train]")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_supersample_zero",
            &["tiny.toml", "render.supersample", "1 to 8", "0"],
            |c| {
                let config = c.config(&[("[train]", "[render]\nsupersample = 0\n\n[train]")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_c0_shuffle_out_of_range",
            &["tiny.toml", "train.c0_shuffle", "[0, 1]", "2"],
            |c| {
                let config = c.config(&[("samples = 4", "samples = 4\nc0_shuffle = 2.0")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_ratio_out_of_range",
            &["tiny.toml", "data.ratio", "(0, 1]", "1.5"],
            |c| {
                let config = c.config(&[("ratio = 1.0", "ratio = 1.5")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_unknown_backend",
            &["tiny.toml", "train.backend", "tpu", "ndarray"],
            |c| {
                let config = c.config(&[("backend = \"ndarray\"", "backend = \"tpu\"")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_unknown_preset",
            &["tiny.toml", "model.preset", "huge", "tiny"],
            |c| {
                let config = c.config(&[("preset = \"tiny\"", "preset = \"huge\"")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_unknown_variant",
            &["tiny.toml", "model.variant", "best", "full"],
            |c| {
                let config =
                    c.config(&[("preset = \"tiny\"", "preset = \"tiny\"\nvariant = \"best\"")]);
                c.train_args(&config, &[])
            },
        ),
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
                let config = c.config_raw(text[..at].as_bytes());
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_source_views_not_below_cameras",
            &["train.source_views", "4 cameras"],
            |c| {
                let config = c.config(&[("source_views = 3", "source_views = 4")]);
                c.train_args(&config, &[])
            },
        ),
        // The existing dataset (synth.json: 4 cameras) disagrees with the config's [synth]
        // section (6 cameras): named with the key and synth.json.
        case(
            "config_synth_section_disagrees_with_the_data",
            &["tiny.toml", "synth.cameras", "synth.json"],
            |c| {
                let config = c.config(&[("cameras = 4", "cameras = 6")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_visibility_cache_is_a_file",
            &["vis_cache_file"],
            |c| {
                let f = c.dir.join("vis_cache_file");
                std::fs::write(&f, b"").unwrap();
                let line = format!("ratio = 1.0\nvisibility_cache = \"{}\"", slash(&f));
                let config = c.config(&[("ratio = 1.0", &line)]);
                c.train_args(&config, &[])
            },
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
        case(
            "config_bad_toml_syntax",
            &["tiny.toml", "line 14", "unclosed table"],
            |c| {
                let config = c.config(&[("[model]", "[model")]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_empty_file",
            &["tiny.toml", "missing field `data`"],
            |c| {
                let config = c.config_raw(b"");
                c.train_args(&config, &[])
            },
        ),
        case(
            "config_not_utf8",
            &["tiny.toml", "cannot read", "UTF-8"],
            |c| {
                let config = c.config_raw(b"[data]\nroot = \"\xff\xfe\"\n");
                c.train_args(&config, &[])
            },
        ),
        case("config_is_a_folder", &["cannot read", "a directory"], |c| {
            let dir = c.dir.join("folder.toml");
            std::fs::create_dir_all(&dir).unwrap();
            c.train_args(&dir, &[])
        }),
    ]
}
