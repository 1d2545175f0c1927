//! The catalogue of malformed inputs (issue 8, item 1): a table of broken dataset folders,
//! SMPL files, images, configs, model files and command lines, each run through the real
//! `nia-train` binary. Every case must exit non-zero, with a message naming the file, key or
//! flag and what was expected there, and must not panic.
//!
//! One small synthetic dataset (2 subjects, 2 frames, 4 cameras, 32 px) and one 1-step
//! checkpoint are made once (that run is also the control: the unmodified inputs train);
//! each case gets its own folder holding a hard-linked copy of the
//! dataset (a file is replaced, never written through the link) and the tiny config, breaks
//! one thing, and runs the binary. Errors at data loading are immediate; cases that reach the
//! first training step take about a second.
//!
//! `NIA_CATALOGUE_VERBOSE=1` prints the stderr of every case.

mod command_line;
#[path = "../common/mod.rs"]
mod common;
mod configs;
mod datasets;
mod model_files;
mod smpl_files;

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::Instant;

use common::slash;
use nia_data::formats::{npy, npz, pickle_write, ArrayData, NdArray, PyValue};

/// The training subject of the synthetic split (`CoreView_2` is held out).
const SUBJECT: &str = "CoreView_1";
/// Image size of the synthetic dataset, pixels.
const SIZE: u32 = 32;

/// What every case starts from, made once.
struct Base {
    root: PathBuf,
    /// The synthetic dataset (never modified).
    data: PathBuf,
    /// A complete checkpoint of the tiny network after 1 step.
    checkpoint: PathBuf,
}

fn nia_train() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_nia-train"));
    // A backtrace in an error report would hide whether the message itself is clear.
    cmd.env_remove("RUST_BACKTRACE")
        .env_remove("RUST_LIB_BACKTRACE");
    cmd
}

/// The tiny run config, reading `root` (its `[model]` header on line 14).
fn config_text(root: &Path) -> String {
    format!(
        r#"{data}
[model]
preset = "tiny"

[train]
steps = 1
rays_per_step = 16
samples = 4
source_views = 3
seed = 7
checkpoint_every = 1
keep_last = 1
validate_every = 0
backend = "ndarray"
"#,
        data = common::data_sections(root, SIZE, 1, "")
    )
}

/// Recreates `src` under `dst` with hard links to its files (copies where links fail).
fn link_tree(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for entry in std::fs::read_dir(src).unwrap() {
        let entry = entry.unwrap();
        let to = dst.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            link_tree(&entry.path(), &to);
        } else if std::fs::hard_link(entry.path(), &to).is_err() {
            std::fs::copy(entry.path(), &to).unwrap();
        }
    }
}

fn base() -> &'static Base {
    static BASE: OnceLock<Base> = OnceLock::new();
    BASE.get_or_init(|| {
        let root = std::env::temp_dir().join(format!("nia-train-catalogue-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).unwrap();
        let data = root.join("data");
        common::synth_small(&data, SIZE);
        // The checkpoint's run reads its own copy, so its visibility cache stays there.
        let ckpt_data = root.join("ckpt_data");
        link_tree(&data, &ckpt_data);
        let config = root.join("ckpt.toml");
        std::fs::write(&config, config_text(&ckpt_data)).unwrap();
        let out = root.join("ckpt_run");
        common::ok(&common::train_run(&[], &config, &out));
        let checkpoint = out.join("checkpoints/step_00000001");
        assert!(checkpoint.join("model.bpk").is_file());
        Base {
            root,
            data,
            checkpoint,
        }
    })
}

/// One case's folder: `data/` (a linked copy of the dataset, made on first use) and the
/// config `tiny.toml`.
struct Ctx {
    dir: PathBuf,
    data: Option<PathBuf>,
}

impl Ctx {
    fn new(name: &str) -> Ctx {
        let dir = base().root.join("cases").join(name);
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Ctx { dir, data: None }
    }

    /// The case's dataset folder.
    fn data(&mut self) -> PathBuf {
        if self.data.is_none() {
            let d = self.dir.join("data");
            link_tree(&base().data, &d);
            self.data = Some(d);
        }
        self.data.clone().unwrap()
    }

    /// A path inside the dataset.
    fn at(&mut self, rel: &str) -> PathBuf {
        self.data().join(rel)
    }

    fn remove(&mut self, rel: &str) {
        let p = self.at(rel);
        if p.is_dir() {
            std::fs::remove_dir_all(&p).unwrap();
        } else {
            std::fs::remove_file(&p).unwrap();
        }
    }

    /// Replaces a file of the dataset (breaking the hard link first).
    fn write(&mut self, rel: &str, bytes: &[u8]) {
        let p = self.at(rel);
        let _ = std::fs::remove_file(&p);
        std::fs::write(&p, bytes).unwrap();
    }

    /// Every file of the dataset under `rel` whose name ends with `suffix`, relative paths.
    fn files(&mut self, rel: &str, suffix: &str) -> Vec<String> {
        fn walk(root: &Path, dir: &Path, suffix: &str, out: &mut Vec<String>) {
            for e in std::fs::read_dir(dir).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    walk(root, &p, suffix, out);
                } else if p.to_string_lossy().ends_with(suffix) {
                    out.push(slash(p.strip_prefix(root).unwrap()));
                }
            }
        }
        let root = self.data();
        let mut out = Vec::new();
        walk(&root, &root.join(rel), suffix, &mut out);
        out.sort();
        assert!(!out.is_empty(), "no {suffix} files under {rel}");
        out
    }

    /// Rewrites every matching file with `f(old bytes)`.
    fn each(&mut self, rel: &str, suffix: &str, f: impl Fn(&[u8]) -> Vec<u8>) {
        for file in self.files(rel, suffix) {
            let old = std::fs::read(self.at(&file)).unwrap();
            self.write(&file, &f(&old));
        }
    }

    /// Decodes an object `.npy` (a pickled dict) of the dataset, edits it, writes it back.
    fn edit_object(&mut self, rel: &str, f: impl Fn(&mut Vec<(PyValue, PyValue)>)) {
        let p = self.at(rel);
        let mut value = nia_data::formats::load_any(&p).unwrap();
        let PyValue::Dict(items) = &mut value else {
            panic!("{rel} is not a dict");
        };
        f(items);
        std::fs::remove_file(&p).unwrap();
        npy::write_object(&p, &value).unwrap();
    }

    /// Edits the arrays of an `.npz` of the dataset.
    fn edit_npz(&mut self, rel: &str, f: impl Fn(&mut Vec<(String, NdArray)>)) {
        let p = self.at(rel);
        let mut arrays = npz::read(&p).unwrap();
        f(&mut arrays);
        let refs: Vec<(&str, &NdArray)> = arrays.iter().map(|(n, a)| (n.as_str(), a)).collect();
        std::fs::remove_file(&p).unwrap();
        npz::write(&p, &refs).unwrap();
    }

    /// Writes `tiny.toml` (reading this case's dataset) with `(old, new)` line edits.
    fn config(&mut self, edits: &[(&str, &str)]) -> PathBuf {
        let mut text = config_text(&self.data());
        for (old, new) in edits {
            assert!(text.contains(old), "the config has no `{old}`");
            text = text.replacen(old, new, 1);
        }
        self.config_raw(text.as_bytes())
    }

    fn config_raw(&self, bytes: &[u8]) -> PathBuf {
        let p = self.dir.join("tiny.toml");
        std::fs::write(&p, bytes).unwrap();
        p
    }

    /// `--config CONFIG --out DIR/run` plus `extra`.
    fn train_args(&self, config: &Path, extra: &[&str]) -> Vec<OsString> {
        let mut args: Vec<OsString> = vec![
            "--config".into(),
            config.into(),
            "--out".into(),
            self.dir.join("run").into(),
        ];
        args.extend(extra.iter().map(OsString::from));
        args
    }

    /// Training on the (possibly broken) dataset with the unmodified config.
    fn train(&mut self) -> Vec<OsString> {
        let config = self.config(&[]);
        self.train_args(&config, &[])
    }

    /// Writes `bytes` to `name` in the case's folder and trains with the `[data]` key `key`
    /// naming that file.
    fn train_with_file(&mut self, name: &str, bytes: &[u8], key: &str) -> Vec<OsString> {
        let path = self.dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        let line = format!("ratio = 1.0\n{key} = \"{}\"", slash(&path));
        let config = self.config(&[("ratio = 1.0", &line)]);
        self.train_args(&config, &[])
    }

    /// A copy of the base checkpoint's files in the folder `into`.
    fn checkpoint_copy(&self, into: &Path) -> PathBuf {
        std::fs::create_dir_all(into).unwrap();
        for f in ["model.bpk", "optimizer.bpk", "config.json", "step.json"] {
            std::fs::copy(base().checkpoint.join(f), into.join(f)).unwrap();
        }
        into.to_path_buf()
    }
}

/// How a row builds its bad input, returning the arguments.
type Setup = dyn Fn(&mut Ctx) -> Vec<OsString>;

/// One row: a name, how to build the bad input (returning the arguments), the texts stderr
/// must contain.
struct Case {
    name: &'static str,
    setup: Box<Setup>,
    expect: Vec<String>,
}

fn case(
    name: &'static str,
    expect: &[&str],
    setup: impl Fn(&mut Ctx) -> Vec<OsString> + 'static,
) -> Case {
    Case {
        name,
        setup: Box::new(setup),
        expect: expect.iter().map(|e| e.to_string()).collect(),
    }
}

fn args(list: &[&str]) -> Vec<OsString> {
    list.iter().map(OsString::from).collect()
}

/// Sets element `index` of a numeric array to `value`.
fn set_f(a: &mut NdArray, index: usize, value: f64) {
    match &mut a.data {
        ArrayData::F32(v) => v[index] = value as f32,
        ArrayData::F64(v) => v[index] = value,
        other => panic!("not a float array: {}", other.dtype_name()),
    }
}

fn dict_array<'a>(items: &'a mut [(PyValue, PyValue)], key: &str) -> &'a mut NdArray {
    items
        .iter_mut()
        .find_map(|(k, v)| match (k, v) {
            (PyValue::Str(s), PyValue::Array(a)) if s == key => Some(a),
            _ => None,
        })
        .unwrap_or_else(|| panic!("no array `{key}`"))
}

fn npz_array<'a>(arrays: &'a mut [(String, NdArray)], key: &str) -> &'a mut NdArray {
    arrays
        .iter_mut()
        .find(|(n, _)| n == key)
        .map(|(_, a)| a)
        .unwrap_or_else(|| panic!("no array `{key}`"))
}

/// Keeps the first `rows` rows of a C-order array.
fn keep_rows(a: &mut NdArray, rows: usize) {
    let row: usize = a.shape[1..].iter().product();
    let n = rows * row;
    a.data = match std::mem::replace(&mut a.data, ArrayData::Bool(Vec::new())) {
        ArrayData::F32(v) => ArrayData::F32(v[..n].to_vec()),
        ArrayData::F64(v) => ArrayData::F64(v[..n].to_vec()),
        other => panic!("not a float array: {}", other.dtype_name()),
    };
    a.shape[0] = rows;
}

/// A `w`x`h` grey PNG.
fn png(w: u32, h: u32) -> Vec<u8> {
    let p = std::env::temp_dir().join(format!("nia-catalogue-{}-{w}x{h}.png", std::process::id()));
    nia_data::dataset::image_io::write_rgb_png(&p, &vec![0.5; (w * h * 3) as usize], w, h).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let _ = std::fs::remove_file(&p);
    bytes
}

/// Number of vertices of the dataset's body model (the procedural SMPL-compatible body).
fn model_vertices() -> usize {
    let arrays = npz::read(&base().data.join("body_model.npz")).unwrap();
    arrays
        .iter()
        .find(|(n, _)| n == "v_template")
        .map(|(_, a)| a.shape[0])
        .unwrap()
}

fn catalogue() -> Vec<Case> {
    let mut cases = Vec::new();
    cases.extend(datasets::cases());
    cases.extend(smpl_files::cases());
    cases.extend(configs::cases());
    cases.extend(model_files::cases());
    cases.extend(command_line::cases());
    cases
}

/// What a case did.
struct Outcome {
    ok: bool,
    problems: Vec<String>,
    stderr: String,
    code: Option<i32>,
}

fn run_case(c: &Case) -> Outcome {
    let mut ctx = Ctx::new(c.name);
    let argv = (c.setup)(&mut ctx);
    let output = nia_train().args(&argv).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr).replace('\\', "/");
    let mut problems = Vec::new();
    if output.status.success() {
        problems.push("exited 0".to_string());
    }
    if output.status.code() == Some(101) || stderr.contains("panicked") {
        problems.push("panicked".to_string());
    }
    if stderr.contains("RUST_BACKTRACE") {
        problems.push("mentions RUST_BACKTRACE".to_string());
    }
    for e in &c.expect {
        if !stderr.contains(e.as_str()) {
            problems.push(format!("stderr lacks `{e}`"));
        }
    }
    Outcome {
        ok: problems.is_empty(),
        problems,
        stderr,
        code: output.status.code(),
    }
}

#[test]
fn malformed_inputs_fail_with_a_message_naming_the_file_or_flag() {
    let cases = catalogue();
    assert!(cases.len() >= 30, "{} cases", cases.len());
    let mut names: Vec<_> = cases.iter().map(|c| c.name).collect();
    names.sort();
    names.dedup();
    assert_eq!(names.len(), cases.len(), "case names are unique");
    base();
    // NIA_CATALOGUE_VERBOSE=1 prints every case's stderr.
    let verbose = std::env::var_os("NIA_CATALOGUE_VERBOSE").is_some();
    let start = Instant::now();
    let mut ok = 0;
    let mut failures = Vec::new();
    for c in &cases {
        let t = Instant::now();
        let out = run_case(c);
        let secs = t.elapsed().as_secs_f64();
        if verbose {
            eprintln!(
                "== {} ({secs:.1} s, exit {:?})\n{}",
                c.name, out.code, out.stderr
            );
        }
        match out.ok {
            true => ok += 1,
            false => {
                failures.push(format!(
                    "{} (exit {:?}): {}\n---- stderr ----\n{}----------------",
                    c.name,
                    out.code,
                    out.problems.join("; "),
                    out.stderr
                ));
            }
        }
    }
    eprintln!(
        "catalogue: {} cases, {} ok, {} failing ({:.1} s)",
        cases.len(),
        ok,
        failures.len(),
        start.elapsed().as_secs_f64()
    );
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
    let _ = std::fs::remove_dir_all(&base().root);
}
