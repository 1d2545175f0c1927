//! Fuzzing of the run-config parser (issue 8, item 2): thousands of inputs derived from the
//! committed seed corpus `tests/corpus/config/*.toml` (the presets of `configs/`, the tiny test
//! config and hand-made edge cases) go through [`TrainConfig::load`] on a temporary file.
//!
//! Three streams, all from the project's deterministic [`Rng`]:
//! - byte-level mutations of a seed (bit flips, interesting bytes, truncation, deletion,
//!   insertion, duplicated chunks, crossover with another seed);
//! - token-level mutations (TOML tokens and whole lines replaced, deleted, duplicated, swapped
//!   or moved, values and keys drawn from a dictionary of every key and of values at type
//!   limits, section headers inserted);
//! - generated configs: well-formed TOML with random keys of the right sections and values of
//!   (mostly) the right type around the range limits, so the range checks are reached.
//!
//! Properties, for every input:
//! - `load` never panics (checked with `catch_unwind`; a panicking input is written next to the
//!   temporary file and printed);
//! - an error names the file path;
//! - `load` and `from_toml` of the same text agree (same outcome, same message);
//! - a config that loads validates consistently: `validate` accepts it again, it satisfies every
//!   documented range check, and written back as TOML it loads to the same config.
//!
//! Bounded by default ([`CASES`] inputs, a few seconds at the test profile's opt-level);
//! `NIA_FUZZ_CASES=N` runs a longer campaign, `NIA_FUZZ_SEED=S` another stream.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::Instant;

use nia_data::rng::Rng;
use nia_train::config::{ConfigError, TrainConfig};

mod common;

fn scratch(name: &str) -> PathBuf {
    common::scratch("config-fuzz", name)
}

/// Inputs per run by default (split over the three streams).
const CASES: usize = 12_000;
/// Default seed of the mutation stream.
const DEFAULT_SEED: u64 = 0xc0f1_6f22;

/// Every key of every section, for key replacement and generation (section, key).
const KEYS: &[(&str, &str)] = &[
    ("data", "root"),
    ("data", "format"),
    ("data", "ratio"),
    ("data", "smpl_model"),
    ("data", "protocol"),
    ("data", "visibility_cache"),
    ("data", "border_px"),
    ("data", "body_fraction"),
    ("data", "loader_threads"),
    ("data", "smpl_jitter_m"),
    ("model", "preset"),
    ("model", "variant"),
    ("model", "encoder_width"),
    ("model", "d_model"),
    ("model", "d_hidden"),
    ("model", "d_blend"),
    ("model", "dir_frequencies"),
    ("model", "voxel_size_m"),
    ("model", "box_enlarge"),
    ("model", "source_colours_at"),
    ("model", "blend_reads_features"),
    ("optim", "lr"),
    ("optim", "beta1"),
    ("optim", "beta2"),
    ("optim", "adam_eps"),
    ("optim", "decay_steps"),
    ("optim", "grad_clip_norm"),
    ("train", "steps"),
    ("train", "rays_per_step"),
    ("train", "samples"),
    ("train", "source_views"),
    ("train", "seed"),
    ("train", "checkpoint_every"),
    ("train", "keep_last"),
    ("train", "validate_every"),
    ("train", "validation_images"),
    ("train", "evaluate_at_end"),
    ("train", "backend"),
    ("train", "devices"),
    ("train", "init_from"),
    ("train", "encoder_weights"),
    ("train", "mask_loss_weight"),
    ("train", "distortion_loss_weight"),
    ("train", "colour_gain_tolerance"),
    ("synth", "subjects"),
    ("synth", "frames"),
    ("synth", "cameras"),
    ("synth", "size"),
    ("synth", "seed"),
    ("synth", "supersample"),
    ("synth", "test_fraction"),
    ("synth", "keypoints"),
    ("render", "skip_empty_space"),
    ("render", "empty_space_m"),
    ("render", "occupancy_cell_m"),
];

const SECTIONS: &[&str] = &["data", "model", "optim", "train", "synth", "render"];

/// Values at type limits and of every TOML type, plus every enum name the config knows.
const VALUES: &[&str] = &[
    "0",
    "1",
    "2",
    "3",
    "-1",
    "+1",
    "1_000",
    "0x7fffffffffffffff",
    "0o777",
    "0b1",
    "9223372036854775807",
    "-9223372036854775808",
    "9223372036854775808",
    "18446744073709551615",
    "4294967295",
    "4294967296",
    "0.0",
    "-0.0",
    "0.5",
    "1.0",
    "1.5",
    "5e-4",
    "1e-45",
    "1e308",
    "1e309",
    "3.4e38",
    "3.5e38",
    "inf",
    "-inf",
    "+inf",
    "nan",
    "-nan",
    "true",
    "false",
    "\"\"",
    "''",
    "\"data/x\"",
    "\".\"",
    "\"Cargo.toml\"",
    "\"/\"",
    "\"\\u00e9\"",
    "\"\\uD800\"",
    "\"a\\\"b\"",
    "\"\"\"\nmulti\nline\"\"\"",
    "'''lit\\eral'''",
    "[]",
    "[1, 2]",
    "[[1], [\"a\"]]",
    "{}",
    "{ a = 1 }",
    "{ root = \"x\" }",
    "1979-05-27T07:32:00Z",
    "1979-05-27",
    "07:32:00",
    "\"tiny\"",
    "\"paper\"",
    "\"ndarray\"",
    "\"flex\"",
    "\"wgpu\"",
    "\"NDARRAY\"",
    "\"full\"",
    "\"no_body\"",
    "\"no_ibr\"",
    "\"simple_average\"",
    "\"cosine_weighted\"",
    "\"zju\"",
    "\"monocap\"",
    "\"nhp\"",
    "\"synthetic\"",
];

/// Structural TOML fragments inserted between tokens.
const FRAGMENTS: &[&str] = &[
    "[",
    "]",
    "[[",
    "]]",
    "=",
    "\"",
    "'",
    "\"\"\"",
    "'''",
    "{",
    "}",
    ",",
    ".",
    "#",
    "\n",
    "\r\n",
    "\\",
    "\\u",
    " ",
    "\t",
    "\0",
    "\u{feff}",
    "\u{e9}",
    "\u{1F600}",
    "[train]",
    "[data]",
    "[model]",
    "[optim]",
    "[synth]",
    "[render]",
    "[[train]]",
    "[train.x]",
    "[unknown]",
    "[data.root]",
    "steps",
    "root",
];

/// Bytes that make a TOML lexer take unusual paths.
const INTERESTING: &[u8] = &[
    b'"', b'\'', b'=', b'[', b']', b'{', b'}', b',', b'.', b'#', b'\n', b'\r', b'\\', b' ', b'0',
    b'-', b'+', b'e', b'_', 0x00, 0x7f, 0x80, 0xc3, 0xe2, 0xf0, 0xff,
];

fn corpus() -> Vec<(String, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/config");
    let mut entries: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    entries.sort();
    entries
        .into_iter()
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect()
}

fn pick<'a, T>(rng: &mut Rng, items: &'a [T]) -> &'a T {
    &items[rng.below(items.len())]
}

/// Byte-level mutations: 1 to 4 rounds.
fn mutate_bytes(rng: &mut Rng, src: &[u8], other: &[u8]) -> Vec<u8> {
    let mut v = src.to_vec();
    for _ in 0..1 + rng.below(4) {
        if v.is_empty() {
            v.push(*pick(rng, INTERESTING));
            continue;
        }
        let at = rng.below(v.len());
        match rng.below(8) {
            0 => v[at] ^= 1 << rng.below(8),
            1 => v[at] = *pick(rng, INTERESTING),
            2 => v.truncate(at),
            3 => {
                let end = (at + 1 + rng.below(16)).min(v.len());
                v.drain(at..end);
            }
            4 => {
                for _ in 0..1 + rng.below(4) {
                    v.insert(at, *pick(rng, INTERESTING));
                }
            }
            5 => {
                // A copy of up to 64 bytes inserted somewhere else.
                let chunk = v[at..(at + 1 + rng.below(64)).min(v.len())].to_vec();
                let to = rng.below(v.len() + 1);
                v.splice(to..to, chunk);
            }
            6 => {
                // Crossover: the head of this input glued to the tail of another seed.
                v.truncate(at);
                v.extend_from_slice(&other[rng.below(other.len() + 1)..]);
            }
            _ => v[at] = rng.next_u64() as u8,
        }
    }
    v
}

/// Splits TOML text into tokens: quoted strings, runs of bare-key/number characters, runs of
/// spaces, and single other characters. Joining the tokens gives the text back.
fn tokens(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let chars: Vec<char> = text.chars().collect();
    let mut i = 0;
    let word = |c: char| c.is_ascii_alphanumeric() || "_-+.:".contains(c);
    while i < chars.len() {
        let c = chars[i];
        let start = i;
        if c == '"' || c == '\'' {
            i += 1;
            while i < chars.len() && chars[i] != c && chars[i] != '\n' {
                if c == '"' && chars[i] == '\\' {
                    i += 1;
                }
                i += 1;
            }
            i = (i + 1).min(chars.len());
        } else if word(c) {
            while i < chars.len() && word(chars[i]) {
                i += 1;
            }
        } else if c == ' ' || c == '\t' {
            while i < chars.len() && (chars[i] == ' ' || chars[i] == '\t') {
                i += 1;
            }
        } else {
            i += 1;
        }
        out.push(chars[start..i].iter().collect());
    }
    out
}

/// Token- and line-level mutations: 1 to 4 rounds.
fn mutate_tokens(rng: &mut Rng, src: &str, other: &str) -> String {
    let mut text = src.to_string();
    for _ in 0..1 + rng.below(4) {
        if rng.below(3) == 0 {
            // Whole lines.
            let mut lines: Vec<String> = text.split('\n').map(str::to_string).collect();
            let at = rng.below(lines.len());
            match rng.below(6) {
                0 => {
                    lines.remove(at);
                }
                1 => {
                    let line = lines[at].clone();
                    let to = rng.below(lines.len() + 1);
                    lines.insert(to, line);
                }
                2 => {
                    let b = rng.below(lines.len());
                    lines.swap(at, b);
                }
                3 => {
                    let line = lines.remove(at);
                    let to = rng.below(lines.len() + 1);
                    lines.insert(to, line);
                }
                4 => {
                    let (section, key) = pick(rng, KEYS);
                    let line = if rng.below(2) == 0 {
                        format!("{key} = {}", pick(rng, VALUES))
                    } else {
                        format!("{section}.{key} = {}", pick(rng, VALUES))
                    };
                    lines.insert(at, line);
                }
                _ => {
                    let theirs: Vec<&str> = other.split('\n').collect();
                    let line = theirs[rng.below(theirs.len())].to_string();
                    lines.insert(at, line);
                }
            }
            text = lines.join("\n");
            continue;
        }
        let mut toks = tokens(&text);
        if toks.is_empty() {
            toks.push(pick(rng, FRAGMENTS).to_string());
        }
        let at = rng.below(toks.len());
        match rng.below(7) {
            0 | 1 => toks[at] = pick(rng, VALUES).to_string(),
            2 => toks[at] = pick(rng, KEYS).1.to_string(),
            3 => {
                toks.remove(at);
            }
            4 => {
                let t = toks[at].clone();
                toks.insert(rng.below(toks.len() + 1), t);
            }
            5 => {
                let b = rng.below(toks.len());
                toks.swap(at, b);
            }
            _ => toks.insert(at, pick(rng, FRAGMENTS).to_string()),
        }
        text = toks.concat();
    }
    text
}

/// A well-formed config with random sections, keys and values.
fn generate(rng: &mut Rng) -> String {
    let mut text = String::new();
    for section in SECTIONS {
        // `data` and `train` are required: nearly always present.
        let required = matches!(*section, "data" | "train");
        if rng.below(20) < if required { 19 } else { 14 } {
            text.push_str(&format!("[{section}]\n"));
            for (s, key) in KEYS.iter().filter(|(s, _)| s == section) {
                let must = matches!((*s, *key), ("data", "root") | ("train", "steps"))
                    || (*s == "synth"
                        && matches!(*key, "subjects" | "frames" | "cameras" | "size"));
                let optional = if *key == "init_from" { 40 } else { 3 };
                if must && rng.below(40) != 0 || rng.below(optional) == 0 {
                    text.push_str(&format!("{key} = {}\n", typed_value(rng, key)));
                }
            }
        }
    }
    text
}

/// Values of `key` the range checks accept, and values of its type they reject (or, for keys
/// without a range check, more values of its type).
fn domain(key: &str) -> (&'static [&'static str], &'static [&'static str]) {
    const ANY_INT: &[&str] = &["0", "1", "2", "3", "16", "1024", "9223372036854775807"];
    const ANY_FLOAT: &[&str] = &["0.0", "-0.0", "1e-9", "0.5", "1.0", "-1.0", "nan", "inf"];
    match key {
        "root" => (&["\"data/g\"", "\".\""], &["\"no/such/dir\"", "\"\""]),
        "visibility_cache" => (&["\"data/g/cache\"", "\"\""], &["\"/\""]),
        "init_from" => (&[], &["\"no/such/run\"", "\".\""]),
        "devices" => (
            &["[\"flex\"]", "[\"ndarray\", \"flex\"]", "[]"],
            &["[\"flex:1\"]", "[\"cuda\"]", "\"flex\""],
        ),
        "encoder_weights" => (&["\"Cargo.toml\""], &["\"no_such.pth\"", "\".\""]),
        "smpl_model" => (&["\"Cargo.toml\""], &["\"no_such.pkl\"", "\".\""]),
        "format" => (&["\"zju\"", "\"monocap\""], &["\"MonoCap\"", "\"h36m\""]),
        "protocol" => (&["\"synthetic\"", "\"nhp\"", "\"monocap\""], &["\"zju\""]),
        "preset" => (&["\"tiny\"", "\"paper\""], &["\"huge\""]),
        "source_colours_at" => (
            &["\"samples\"", "\"surface\""],
            &["\"Surface\"", "\"expected\"", "1"],
        ),
        "variant" => (
            &[
                "\"full\"",
                "\"no_body\"",
                "\"no_ibr\"",
                "\"simple_average\"",
                "\"cosine_weighted\"",
            ],
            &["\"e\"", "\"Full\""],
        ),
        "backend" => (&["\"ndarray\"", "\"flex\"", "\"wgpu\""], &["\"cuda\""]),
        "evaluate_at_end" | "skip_empty_space" | "keypoints" | "blend_reads_features" => {
            (&["true", "false"], &["1", "\"yes\""])
        }
        "empty_space_m" => (&["0.0", "0.03", "1.0"], &["-0.1", "nan", "inf"]),
        "occupancy_cell_m" => (&["0.005", "0.02", "1.0"], &["0.004", "0.0", "nan", "-1.0"]),
        "ratio" => (
            &["0.25", "0.5", "1.0", "1e-9"],
            &["0.0", "-0.0", "1.0000001", "1.5", "nan", "inf"],
        ),
        "lr" => (
            &["5e-4", "1e-9", "1.0", "1e30"],
            &["0.0", "-1.0", "nan", "inf", "-inf"],
        ),
        "mask_loss_weight" | "distortion_loss_weight" => (
            &["0.0", "-0.0", "0.1", "1e30"],
            &["-1.0", "nan", "inf", "-1e-9"],
        ),
        "smpl_jitter_m" => (&["0.0", "0.025", "0.2"], &["-0.01", "0.21", "nan", "inf"]),
        "colour_gain_tolerance" => (&["0.0", "0.15", "1.0"], &["-0.1", "1.01", "nan", "inf"]),
        "grad_clip_norm" => (
            &["0.0", "-0.0", "1.0", "1e30"],
            &["-1.0", "nan", "inf", "-1e-9"],
        ),
        "rays_per_step" | "source_views" | "checkpoint_every" | "keep_last" | "loader_threads" => {
            (&["1", "2", "3", "1024"], &["0", "-1", "1.0"])
        }
        "samples" => (&["2", "8", "64"], &["0", "1", "-2"]),
        "body_fraction" | "voxel_size_m" | "box_enlarge" | "beta1" | "beta2" | "adam_eps"
        | "test_fraction" => (ANY_FLOAT, &["1e39", "\"0.5\""]),
        _ => (ANY_INT, &["-1", "1.5", "9223372036854775808"]),
    }
}

/// A value for `key`: usually one the range checks accept, sometimes one they reject, rarely
/// any value at all.
fn typed_value(rng: &mut Rng, key: &str) -> String {
    let (valid, invalid) = domain(key);
    match rng.below(80) {
        0 => pick(rng, VALUES).to_string(),
        1 | 2 => pick(rng, invalid).to_string(),
        _ if valid.is_empty() => pick(rng, invalid).to_string(),
        _ => pick(rng, valid).to_string(),
    }
}

/// Every range the loader promises for a config it accepts (see `TrainConfig::validate`).
fn check_invariants(c: &TrainConfig, path: &Path) {
    let t = &c.train;
    assert!(t.rays_per_step >= 1, "{}", path.display());
    assert!(t.samples >= 2);
    assert!(t.source_views >= 1);
    assert!(t.checkpoint_every >= 1);
    assert!(t.keep_last >= 1);
    assert!(c.optim.lr.is_finite() && c.optim.lr > 0.0);
    assert!(c.optim.grad_clip_norm.is_finite() && c.optim.grad_clip_norm >= 0.0);
    if let Some(r) = c.data.ratio {
        assert!(r > 0.0 && r <= 1.0);
    }
    assert!(c.data.loader_threads >= 1);
    assert!(c.data.smpl_jitter_m.is_finite() && (0.0..=0.2).contains(&c.data.smpl_jitter_m));
    if let Some(a) = c.data.smpl_alignment {
        assert!(a.validate().is_ok(), "{}: {a:?}", path.display());
    }
    let tol = t.colour_gain_tolerance;
    assert!(tol.is_finite() && (0.0..=1.0).contains(&tol));
    let r = &c.render;
    assert!(r.empty_space_m.is_finite() && r.empty_space_m >= 0.0);
    assert!(r.occupancy_cell_m.is_finite() && r.occupancy_cell_m >= 0.005);
    if c.synth.is_none() {
        assert!(c.data.root.is_dir());
        assert!(c.data.smpl_model.as_ref().is_some_and(|m| m.is_file()));
    }
    if let Some(m) = &c.data.smpl_model {
        assert!(m.is_file());
    }
    if let Some(dir) = &t.init_from {
        assert!(dir.join(nia_model::store::checkpoint::MODEL_FILE).is_file());
    }
    if let Some(w) = &t.encoder_weights {
        assert!(w.is_file());
    }
    assert!(t
        .devices
        .iter()
        .all(|d| d.index.is_none() || d.backend.is_gpu()));
    // The network configuration of any accepted config is buildable.
    assert!(c.model.check().is_ok());
    let _ = c.optim.lr_at(t.steps);
}

/// What one input did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Outcome {
    Loaded,
    Rejected,
}

/// Runs the properties on one input (written to `path`).
fn exercise(bytes: &[u8], path: &Path) -> Outcome {
    std::fs::write(path, bytes).unwrap();
    let shown = path.display().to_string();
    match TrainConfig::load(path) {
        Ok(config) => {
            let text = std::str::from_utf8(bytes).expect("a loaded config is UTF-8");
            config
                .validate(path)
                .unwrap_or_else(|e| panic!("loaded, then validate rejects it: {e}"));
            check_invariants(&config, path);
            let again = TrainConfig::from_toml(text, path).expect("from_toml agrees with load");
            assert_eq!(
                toml::to_string(&again).unwrap(),
                toml::to_string(&config).unwrap()
            );
            // Written back as TOML, the config loads to the same config.
            let written = toml::to_string(&config)
                .unwrap_or_else(|e| panic!("a loaded config cannot be written back: {e}"));
            let reread = TrainConfig::from_toml(&written, path)
                .unwrap_or_else(|e| panic!("written back:\n{written}\ndoes not load: {e}"));
            assert_eq!(toml::to_string(&reread).unwrap(), written);
            Outcome::Loaded
        }
        Err(e) => {
            let message = e.to_string();
            assert!(
                message.contains(&shown),
                "the error does not name the file {shown}: {message}"
            );
            if let ConfigError::Invalid { key, .. } = &e {
                assert!(message.contains(key), "names the key: {message}");
            }
            match std::str::from_utf8(bytes) {
                Ok(text) => {
                    let direct = TrainConfig::from_toml(text, path)
                        .expect_err("from_toml rejects what load rejects");
                    assert_eq!(direct.to_string(), message, "load and from_toml agree");
                }
                Err(_) => assert!(
                    matches!(e, ConfigError::Read { .. }),
                    "non-UTF-8 fails reading: {message}"
                ),
            }
            Outcome::Rejected
        }
    }
}

#[test]
fn corpus_seeds_behave_as_labelled() {
    let dir = scratch("seeds");
    let path = dir.join("seed.toml");
    // Seeds that load from the crate folder (cargo's working directory for tests), and seeds
    // that must be rejected; any other seed only feeds the fuzzer.
    let loads = [
        "crlf_floats.toml",
        "every_key.toml",
        "existing_root.toml",
        "inline_and_dotted.toml",
        "minimal.toml",
        "quickstart.toml",
        "strings_and_escapes.toml",
        "tiny.toml",
    ];
    let rejects = [
        "bad_syntax.toml",
        "empty.toml",
        "invalid_values.toml",
        "monocap.toml",
        "unknown_keys.toml",
        "wrong_types.toml",
        "zju.toml",
    ];
    let seeds = corpus();
    assert!(seeds.len() >= 16, "{} seeds", seeds.len());
    for (name, bytes) in &seeds {
        let outcome = exercise(bytes, &path);
        let expected = if loads.contains(&name.as_str()) {
            Outcome::Loaded
        } else if rejects.contains(&name.as_str()) {
            Outcome::Rejected
        } else {
            continue;
        };
        assert_eq!(
            outcome,
            expected,
            "{name}: {:?}",
            TrainConfig::load(&path).err()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn mutated_configs_never_panic_and_errors_name_the_file() {
    let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<u64>().ok());
    let cases = env("NIA_FUZZ_CASES").map_or(CASES, |n| n as usize);
    let seed = env("NIA_FUZZ_SEED").unwrap_or(DEFAULT_SEED);
    let mut rng = Rng::new(seed);
    let seeds = corpus();
    let texts: Vec<String> = seeds
        .iter()
        .map(|(_, b)| String::from_utf8(b.clone()).unwrap())
        .collect();
    let dir = scratch("run");
    let path = dir.join("fuzz.toml");
    let start = Instant::now();
    let mut counts = [[0usize; 2]; 3];
    let mut panics: Vec<(usize, String, PathBuf)> = Vec::new();
    for i in 0..cases {
        let stream = i % 3;
        let s = rng.below(seeds.len());
        let o = rng.below(seeds.len());
        let input: Vec<u8> = match stream {
            0 => mutate_bytes(&mut rng, &seeds[s].1, &seeds[o].1),
            1 => mutate_tokens(&mut rng, &texts[s], &texts[o]).into_bytes(),
            _ => generate(&mut rng).into_bytes(),
        };
        match catch_unwind(AssertUnwindSafe(|| exercise(&input, &path))) {
            Ok(Outcome::Loaded) => counts[stream][0] += 1,
            Ok(Outcome::Rejected) => counts[stream][1] += 1,
            Err(payload) => {
                let msg = payload
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                let keep = dir.join(format!("panic_{i}.toml"));
                std::fs::write(&keep, &input).unwrap();
                panics.push((i, msg, keep));
            }
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    let total: usize = counts.iter().flatten().sum::<usize>() + panics.len();
    eprintln!(
        "config fuzz: {total} executions in {elapsed:.2} s ({:.0}/s), seed {seed:#x}; \
         loaded/rejected: bytes {}/{}, tokens {}/{}, generated {}/{}; {} panics",
        total as f64 / elapsed.max(1e-9),
        counts[0][0],
        counts[0][1],
        counts[1][0],
        counts[1][1],
        counts[2][0],
        counts[2][1],
        panics.len()
    );
    assert!(
        panics.is_empty(),
        "{} inputs failed a property (input kept at the path):\n{}",
        panics.len(),
        panics
            .iter()
            .take(10)
            .map(|(i, m, p)| format!("case {i}: {m}\n  input: {}", p.display()))
            .collect::<Vec<_>>()
            .join("\n")
    );
    // Every stream both keeps configs loadable and breaks them (the fuzzer reaches past the
    // parser into the range checks and the round trip).
    if cases >= 3000 {
        for (stream, [loaded, rejected]) in counts.iter().enumerate() {
            assert!(
                *loaded > 10 && *rejected > 10,
                "stream {stream}: {loaded} loaded, {rejected} rejected"
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
