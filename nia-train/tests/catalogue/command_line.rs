//! Bad command lines of `nia-train` and `nia-train synth`.

use super::*;

pub(super) fn cases() -> Vec<Case> {
    vec![
        case("cli_unknown_flag", &["--frobnicate"], |c| {
            let config = c.config(&[]);
            c.train_args(&config, &["--frobnicate"])
        }),
        case("cli_missing_config", &["--config"], |c| {
            args(&["--out", &slash(&c.dir.join("run"))])
        }),
        case(
            "cli_config_does_not_exist",
            &["no_such.toml", "cannot read", "No such file"],
            |c| c.train_args(&c.dir.join("no_such.toml"), &[]),
        ),
        case(
            "cli_bad_backend",
            &["--backend", "tpu", "ndarray, flex or wgpu"],
            |c| {
                let config = c.config(&[]);
                c.train_args(&config, &["--backend", "tpu"])
            },
        ),
        case("cli_steps_not_a_number", &["--steps", "abc"], |c| {
            let config = c.config(&[]);
            c.train_args(&config, &["--steps", "abc"])
        }),
        // A negative step count is a bad `--steps` value, not an unknown flag.
        case("cli_steps_negative", &["--steps", "-3"], |c| {
            let config = c.config(&[]);
            c.train_args(&config, &["--steps", "-3"])
        }),
        case("cli_out_is_a_file", &["out_file", "output folder"], |c| {
            let out = c.dir.join("out_file");
            std::fs::write(&out, b"").unwrap();
            let config = c.config(&[]);
            args(&["--config", &slash(&config), "--out", &slash(&out)])
        }),
        case("cli_unknown_subcommand", &["frobnicate"], |_| {
            args(&["frobnicate"])
        }),
        case("synth_size_not_a_number", &["--size", "abc"], |c| {
            args(&["synth", "--size", "abc", "--out", &slash(&c.dir.join("s"))])
        }),
        case(
            "synth_size_zero",
            &["size", "between 16 and 4096", "0"],
            |c| args(&["synth", "--size", "0", "--out", &slash(&c.dir.join("s"))]),
        ),
        case("synth_zero_cameras", &["cameras", "at least 1"], |c| {
            args(&["synth", "--cameras", "0", "--out", &slash(&c.dir.join("s"))])
        }),
        case("synth_supersample_too_large", &["supersample", "9"], |c| {
            args(&[
                "synth",
                "--size",
                "16",
                "--supersample",
                "9",
                "--out",
                &slash(&c.dir.join("s")),
            ])
        }),
        case("synth_missing_out", &["--out"], |_| {
            args(&["synth", "--size", "16"])
        }),
        case("synth_out_is_a_file", &["out_file"], |c| {
            let out = c.dir.join("out_file");
            std::fs::write(&out, b"").unwrap();
            args(&[
                "synth",
                "--subjects",
                "1",
                "--frames",
                "1",
                "--cameras",
                "2",
                "--size",
                "16",
                "--out",
                &slash(&out),
            ])
        }),
    ]
}
