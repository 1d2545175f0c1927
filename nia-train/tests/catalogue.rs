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

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::Instant;

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

fn slash(p: &Path) -> String {
    p.display().to_string().replace('\\', "/")
}

/// The tiny run config, reading `root`.
fn config_text(root: &Path) -> String {
    format!(
        r#"[data]
root = "{root}"
ratio = 1.0
border_px = 1
loader_threads = 1

[synth]
subjects = 2
frames = 2
cameras = 4
size = {SIZE}
supersample = 1

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
        root = slash(root)
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
        let output = nia_train()
            .args([
                "synth",
                "--subjects",
                "2",
                "--frames",
                "2",
                "--cameras",
                "4",
            ])
            .args(["--size", &SIZE.to_string(), "--supersample", "1", "--out"])
            .arg(&data)
            .output()
            .unwrap();
        assert!(
            output.status.success(),
            "synth failed: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        // The checkpoint's run reads its own copy, so its visibility cache stays there.
        let ckpt_data = root.join("ckpt_data");
        link_tree(&data, &ckpt_data);
        let config = root.join("ckpt.toml");
        std::fs::write(&config, config_text(&ckpt_data)).unwrap();
        let out = root.join("ckpt_run");
        let output = nia_train()
            .arg("--config")
            .arg(&config)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            output.status.success(),
            "the 1-step run failed: {}",
            String::from_utf8_lossy(&output.stderr)
        );
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

    /// A copy of the base checkpoint's files in the folder `into`.
    fn checkpoint_copy(&self, into: &Path) -> PathBuf {
        std::fs::create_dir_all(into).unwrap();
        for f in ["model.bpk", "optimizer.bpk", "config.json", "step.json"] {
            std::fs::copy(base().checkpoint.join(f), into.join(f)).unwrap();
        }
        into.to_path_buf()
    }
}

/// One row: a name, how to build the bad input (returning the arguments), the texts stderr
/// must contain.
struct Case {
    name: &'static str,
    setup: Box<dyn Fn(&mut Ctx) -> Vec<OsString>>,
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
    let v = model_vertices();
    vec![
        // ---- dataset folders ----
        case(
            "annots_missing",
            &["CoreView_1/annots.npy", "missing", "cameras and image list"],
            |c| {
                c.remove(&format!("{SUBJECT}/annots.npy"));
                c.train()
            },
        ),
        case(
            "annots_truncated",
            &["CoreView_1/annots.npy", "truncated"],
            |c| {
                let rel = format!("{SUBJECT}/annots.npy");
                let old = std::fs::read(c.at(&rel)).unwrap();
                c.write(&rel, &old[..old.len() / 2]);
                c.train()
            },
        ),
        case("annots_not_npy", &["CoreView_1/annots.npy"], |c| {
            c.write(&format!("{SUBJECT}/annots.npy"), b"this is not numpy\n");
            c.train()
        }),
        case(
            "annots_missing_key_ims",
            &["CoreView_1/annots.npy", "ims", "no such key"],
            |c| {
                c.edit_object(&format!("{SUBJECT}/annots.npy"), |items| {
                    items.retain(|(k, _)| !matches!(k, PyValue::Str(s) if s == "ims"))
                });
                c.train()
            },
        ),
        case(
            "annots_missing_camera_T",
            &["CoreView_1/annots.npy", "T"],
            |c| {
                c.edit_object(&format!("{SUBJECT}/annots.npy"), |items| {
                    for (k, v) in items.iter_mut() {
                        if matches!(k, PyValue::Str(s) if s == "cams") {
                            if let PyValue::Dict(cams) = v {
                                cams.retain(|(k, _)| !matches!(k, PyValue::Str(s) if s == "T"));
                            }
                        }
                    }
                });
                c.train()
            },
        ),
        case(
            "annots_too_few_image_paths",
            &["CoreView_1/annots.npy", "ims[0]['ims']", "4 image paths"],
            |c| {
                c.edit_object(&format!("{SUBJECT}/annots.npy"), |items| {
                    for (k, v) in items.iter_mut() {
                        if matches!(k, PyValue::Str(s) if s == "ims") {
                            if let PyValue::List(frames) = v {
                                if let PyValue::Dict(f0) = &mut frames[0] {
                                    if let PyValue::List(paths) = &mut f0[0].1 {
                                        paths.pop();
                                    }
                                }
                            }
                        }
                    }
                });
                c.train()
            },
        ),
        case("subject_folder_missing", &["CoreView_1", "missing"], |c| {
            c.remove(SUBJECT);
            c.train()
        }),
        case(
            "camera_folder_missing",
            &["CoreView_1/Camera_B2", "camera folder missing"],
            |c| {
                c.remove(&format!("{SUBJECT}/Camera_B2"));
                c.train()
            },
        ),
        case(
            "image_missing_for_a_frame",
            &[
                "CoreView_1/Camera_B2/000001.jpg",
                "image missing for frame 1",
            ],
            |c| {
                c.remove(&format!("{SUBJECT}/Camera_B2/000001.jpg"));
                c.train()
            },
        ),
        case(
            "jpeg_garbage",
            &["CoreView_1/Camera_B2/000000.jpg", "cannot decode image"],
            |c| {
                c.write(
                    &format!("{SUBJECT}/Camera_B2/000000.jpg"),
                    b"not a jpeg at all",
                );
                c.train()
            },
        ),
        // A half-downloaded JPEG: the decoder would fill the missing scan data in silently; the
        // reader refuses a JPEG without its end-of-image marker.
        case(
            "jpeg_truncated_tail",
            &["CoreView_1/Camera_B", ".jpg", "cannot decode image"],
            |c| {
                c.each(SUBJECT, ".jpg", |b| b[..b.len() * 3 / 4].to_vec());
                c.train()
            },
        ),
        case(
            "image_of_the_wrong_size",
            &[
                "CoreView_1/Camera_B",
                "000001.jpg",
                "16x16",
                "expected 32x32",
            ],
            |c| {
                let small = png(16, 16);
                for cam in 1..=4 {
                    c.write(&format!("{SUBJECT}/Camera_B{cam}/000001.jpg"), &small);
                }
                let config = c.config(&[]);
                c.train_args(&config, &["--steps", "4"])
            },
        ),
        case(
            "mask_folder_missing",
            &["CoreView_1/mask", "a mask folder"],
            |c| {
                c.remove(&format!("{SUBJECT}/mask"));
                c.train()
            },
        ),
        case(
            "mask_files_missing",
            &[
                "CoreView_1/Camera_B",
                "no mask for this image",
                "mask/Camera_B",
            ],
            |c| {
                for f in c.files(&format!("{SUBJECT}/mask"), ".png") {
                    c.remove(&f);
                }
                c.train()
            },
        ),
        case(
            "mask_of_the_wrong_size",
            &["CoreView_1/mask/Camera_B", ".png", "16x16", "32x32"],
            |c| {
                let small = png(16, 16);
                c.each(&format!("{SUBJECT}/mask"), ".png", |_| small.clone());
                c.train()
            },
        ),
        case(
            "mask_corrupt",
            &["CoreView_1/mask/Camera_B", ".png", "cannot decode image"],
            |c| {
                c.each(&format!("{SUBJECT}/mask"), ".png", |_| {
                    b"\x89PNG\r\n\x1a\nbroken".to_vec()
                });
                c.train()
            },
        ),
        case(
            "params_folder_missing",
            &["CoreView_1/params", "SMPL parameters folder"],
            |c| {
                c.remove(&format!("{SUBJECT}/params"));
                c.train()
            },
        ),
        case(
            "params_file_missing",
            &["CoreView_1/params/", ".npy", "missing", "SMPL parameters"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/params"), ".npy") {
                    c.remove(&f);
                }
                c.train()
            },
        ),
        case(
            "params_with_nan",
            &["CoreView_1/params/", "poses", "non-finite", "NaN"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/params"), ".npy") {
                    c.edit_object(&f, |items| set_f(dict_array(items, "poses"), 5, f64::NAN));
                }
                c.train()
            },
        ),
        case(
            "params_missing_key_Th",
            &["CoreView_1/params/", "Th", "no such key"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/params"), ".npy") {
                    c.edit_object(&f, |items| {
                        items.retain(|(k, _)| !matches!(k, PyValue::Str(s) if s == "Th"))
                    });
                }
                c.train()
            },
        ),
        case(
            "params_poses_wrong_length",
            &["CoreView_1/params/", "poses", "shape [1, 72]", "[1, 69]"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/params"), ".npy") {
                    c.edit_object(&f, |items| {
                        let a = dict_array(items, "poses");
                        a.shape = vec![1, 69];
                        a.data = match &a.data {
                            ArrayData::F32(v) => ArrayData::F32(v[..69].to_vec()),
                            ArrayData::F64(v) => ArrayData::F64(v[..69].to_vec()),
                            _ => panic!("poses not float"),
                        };
                    });
                }
                c.train()
            },
        ),
        case(
            "vertices_folder_missing",
            &["CoreView_1/vertices", "SMPL vertices folder"],
            |c| {
                c.remove(&format!("{SUBJECT}/vertices"));
                c.train()
            },
        ),
        case(
            "vertices_file_missing",
            &["CoreView_1/vertices/", ".npy", "missing", "SMPL vertices"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/vertices"), ".npy") {
                    c.remove(&f);
                }
                c.train()
            },
        ),
        case(
            "vertices_wrong_shape",
            &["CoreView_1/vertices/", "shape [V, 3]", &format!("[{v}, 2]")],
            |c| {
                for f in c.files(&format!("{SUBJECT}/vertices"), ".npy") {
                    let p = c.at(&f);
                    let a = npy::read(&p).unwrap();
                    let xy: Vec<f32> = a
                        .to_f32_vec()
                        .unwrap()
                        .chunks_exact(3)
                        .flat_map(|v| [v[0], v[1]])
                        .collect();
                    std::fs::remove_file(&p).unwrap();
                    let n = xy.len() / 2;
                    npy::write_array(&p, &NdArray::new(vec![n, 2], ArrayData::F32(xy))).unwrap();
                }
                c.train()
            },
        ),
        case(
            "vertices_with_nan",
            &["CoreView_1/vertices/", "non-finite"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/vertices"), ".npy") {
                    let p = c.at(&f);
                    let mut a = npy::read(&p).unwrap();
                    set_f(&mut a, 10, f64::NAN);
                    std::fs::remove_file(&p).unwrap();
                    npy::write_array(&p, &a).unwrap();
                }
                c.train()
            },
        ),
        // Stored vertices that do not fit the SMPL model: named with both files at open time.
        case(
            "vertices_fewer_than_the_smpl_model",
            &[
                "CoreView_1/vertices/",
                "body_model.npz",
                &format!("{}", v - 100),
                &format!("{v}"),
            ],
            move |c| {
                for f in c.files(&format!("{SUBJECT}/vertices"), ".npy") {
                    let p = c.at(&f);
                    let mut a = npy::read(&p).unwrap();
                    keep_rows(&mut a, v - 100);
                    std::fs::remove_file(&p).unwrap();
                    npy::write_array(&p, &a).unwrap();
                }
                c.train()
            },
        ),
        // More stored vertices than the model has.
        case(
            "vertices_more_than_the_smpl_model",
            &[
                "CoreView_1/vertices/",
                "body_model.npz",
                &format!("{}", v + 100),
                &format!("{v}"),
            ],
            move |c| {
                for f in c.files(&format!("{SUBJECT}/vertices"), ".npy") {
                    let p = c.at(&f);
                    let a = npy::read(&p).unwrap();
                    let mut xyz = a.to_f32_vec().unwrap();
                    let first: Vec<f32> = xyz[..300].to_vec();
                    xyz.extend(first);
                    std::fs::remove_file(&p).unwrap();
                    npy::write_array(&p, &NdArray::new(vec![v + 100, 3], ArrayData::F32(xyz)))
                        .unwrap();
                }
                c.train()
            },
        ),
        case(
            "annots_nan_in_camera_K",
            &["CoreView_1/annots.npy", "K", "non-finite"],
            |c| {
                c.edit_object(&format!("{SUBJECT}/annots.npy"), |items| {
                    let cams = items
                        .iter_mut()
                        .find_map(|(k, v)| match (k, v) {
                            (PyValue::Str(s), PyValue::Dict(d)) if s == "cams" => Some(d),
                            _ => None,
                        })
                        .expect("cams");
                    match cams
                        .iter_mut()
                        .find(|(k, _)| matches!(k, PyValue::Str(s) if s == "K"))
                    {
                        Some((_, PyValue::List(ks))) => match &mut ks[0] {
                            PyValue::Array(a) => set_f(a, 0, f64::NAN),
                            other => panic!("K[0] is {}", other.type_name()),
                        },
                        Some((_, PyValue::Array(a))) => set_f(a, 0, f64::NAN),
                        _ => panic!("no cams['K']"),
                    }
                });
                c.train()
            },
        ),
        case(
            "monocap_format_without_lbs_folder",
            &["CoreView_1/lbs"],
            |c| {
                let config = c.config(&[("ratio = 1.0", "ratio = 1.0\nformat = \"monocap\"")]);
                c.train_args(&config, &[])
            },
        ),
        // ---- SMPL files ----
        case(
            "smpl_missing",
            &["body_model.npz", "cannot read", "No such file"],
            |c| {
                c.remove("body_model.npz");
                c.train()
            },
        ),
        case("smpl_npz_truncated", &["body_model.npz", "zip"], |c| {
            let old = std::fs::read(c.at("body_model.npz")).unwrap();
            c.write("body_model.npz", &old[..old.len() / 2]);
            c.train()
        }),
        case(
            "smpl_missing_weights",
            &["body_model.npz", "weights", "missing"],
            |c| {
                c.edit_npz("body_model.npz", |a| a.retain(|(n, _)| n != "weights"));
                c.train()
            },
        ),
        case(
            "smpl_wrong_vertex_count",
            &["body_model.npz", &format!("{}", v - 1)],
            move |c| {
                c.edit_npz("body_model.npz", |a| {
                    keep_rows(npz_array(a, "v_template"), v - 1)
                });
                c.train()
            },
        ),
        case(
            "smpl_weights_not_normalised",
            &["body_model.npz", "weights", "summing to 1"],
            |c| {
                c.edit_npz("body_model.npz", |a| {
                    let w = npz_array(a, "weights");
                    let old = w.to_f64_vec().unwrap()[0];
                    set_f(w, 0, old + 0.5);
                });
                c.train()
            },
        ),
        case(
            "smpl_face_index_out_of_range",
            &["body_model.npz", "`f`", "face 0"],
            |c| {
                c.edit_npz("body_model.npz", |a| {
                    let f = npz_array(a, "f");
                    match &mut f.data {
                        ArrayData::U32(v) => v[2] = 99_999,
                        ArrayData::I64(v) => v[2] = 99_999,
                        ArrayData::I32(v) => v[2] = 99_999,
                        other => panic!("faces {}", other.dtype_name()),
                    }
                });
                c.train()
            },
        ),
        case("smpl_pkl_not_a_pickle", &["bad_smpl.pkl", "pickle"], |c| {
            let pkl = c.dir.join("bad_smpl.pkl");
            std::fs::write(&pkl, b"this is not a pickle\n").unwrap();
            let line = format!("ratio = 1.0\nsmpl_model = \"{}\"", slash(&pkl));
            let config = c.config(&[("ratio = 1.0", &line)]);
            c.train_args(&config, &[])
        }),
        case(
            "smpl_pkl_of_a_list",
            &["list_smpl.pkl", "a dict with keys", "list"],
            |c| {
                let pkl = c.dir.join("list_smpl.pkl");
                let bytes =
                    pickle_write::to_pickle_bytes(&PyValue::List(vec![PyValue::Int(1)])).unwrap();
                std::fs::write(&pkl, bytes).unwrap();
                let line = format!("ratio = 1.0\nsmpl_model = \"{}\"", slash(&pkl));
                let config = c.config(&[("ratio = 1.0", &line)]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "smpl_unknown_extension",
            &["smpl.obj", "unknown extension", ".pkl"],
            |c| {
                let p = c.dir.join("smpl.obj");
                std::fs::write(&p, b"v 0 0 0\n").unwrap();
                let line = format!("ratio = 1.0\nsmpl_model = \"{}\"", slash(&p));
                let config = c.config(&[("ratio = 1.0", &line)]);
                c.train_args(&config, &[])
            },
        ),
        // ---- configs ----
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
            &["tiny.toml", "invalid table header"],
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
        // ---- model files ----
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
        // ---- command line ----
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
