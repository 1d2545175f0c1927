//! The synthetic generator: ZJU-MoCap layout and file contents, vertices = LBS(params),
//! masks that cover the projected body, byte-identical output for the same seed, and files that
//! real numpy loads with the same values.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use glam::{Mat3, Vec3};
use nia_data::body::{BodyModel, SmplParams};
use nia_data::formats::{load_any, PyValue};
use nia_data::geometry::camera::Camera;
use nia_data::synth::{
    generate, SynthEvent, SynthSpec, SynthSummary, BODY_MODEL_FILE, DESCRIPTION_FILE,
};

/// The same LBS of the same f32 parameters, recomputed: only f32 rounding of world coordinates
/// below ~3 m can differ (the brief's tolerance).
const VERTEX_TOL_M: f32 = 1e-5;

/// Fraction of projected body vertices that must land inside the clothed mask. The clothes
/// enclose the body, so only vertices in silhouette pixels the mask rounds away (under half
/// covered) may fall outside.
const MIN_VERTICES_IN_MASK: f32 = 0.97;

/// A vertex counts as inside when a mask pixel is within this many pixels: at 80 pixels the
/// fingers and wrists are about a pixel wide, and the mask keeps only pixels covered at least
/// half.
const MASK_SLACK_PX: i64 = 1;

/// Shirts and trousers stand at least this far off the skin on most of their vertices
/// (ease 6-15 mm minus folds of up to 5 mm)...
const CLOTH_MIN_OFFSET_M: f32 = 0.003;
/// ...and never more than a loose shirt's hem (ease + flare + folds, under 4 cm).
const CLOTH_MAX_OFFSET_M: f32 = 0.04;

/// JPEG ringing and the anti-aliased silhouette leave a little light outside the mask; the
/// background itself is black.
const MAX_BACKGROUND_MEAN: f32 = 6.0;

fn small_spec(seed: u64) -> SynthSpec {
    SynthSpec {
        subjects: 2,
        frames: 2,
        cameras: 3,
        size: 80,
        seed,
        first_subject_id: 500,
        supersample: 2,
        ..SynthSpec::default()
    }
}

/// A fresh directory under Cargo's per-target scratch space (reused by the next run, so the
/// datasets do not pile up in the system temp directory).
fn scratch_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("synth-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

struct Generated {
    dir: PathBuf,
    summary: SynthSummary,
    events: Vec<SynthEvent>,
}

fn run(spec: &SynthSpec, name: &str) -> Generated {
    let dir = scratch_dir(name);
    let mut events = Vec::new();
    let summary = generate(spec, &dir, &mut |e| events.push(e)).expect("generation succeeds");
    Generated {
        dir,
        summary,
        events,
    }
}

/// The dataset most tests read (seed 7), generated once per test process.
fn dataset() -> &'static Generated {
    static DATA: OnceLock<Generated> = OnceLock::new();
    DATA.get_or_init(|| run(&small_spec(7), "a"))
}

/// Every file under `dir`, relative path -> bytes, in sorted order.
fn all_files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                out.insert(
                    path.strip_prefix(root).unwrap().to_path_buf(),
                    std::fs::read(&path).unwrap(),
                );
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

fn array_f64(v: &PyValue) -> (Vec<usize>, Vec<f64>) {
    let a = v
        .as_array()
        .unwrap_or_else(|| panic!("expected an array, got {}", v.type_name()));
    (a.shape.clone(), a.to_f64_vec().unwrap())
}

/// Camera `c` of a loaded `annots.npy`, with T converted from millimetres to metres.
fn annots_camera(annots: &PyValue, c: usize, size: u32) -> Camera {
    let cams = annots.get("cams").unwrap();
    let entry = |key: &str| array_f64(&cams.get(key).unwrap().as_seq().unwrap()[c]).1;
    let (k, r, t) = (entry("K"), entry("R"), entry("T"));
    let rows = |m: &[f64]| [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[3 * i + j] as f32));
    Camera::from_rows(
        rows(&k),
        rows(&r),
        [0, 1, 2].map(|i| (t[i] / 1000.0) as f32),
        [0.0; 5],
        size,
        size,
    )
    .unwrap()
}

fn load_params(path: &Path) -> SmplParams {
    let v = load_any(path).unwrap();
    let get = |key: &str| {
        array_f64(
            v.get(key)
                .unwrap_or_else(|| panic!("{key} in {}", path.display())),
        )
    };
    let (ps, poses) = get("poses");
    let (rs, rh) = get("Rh");
    let (ts, th) = get("Th");
    let (ss, shapes) = get("shapes");
    assert_eq!(
        (ps, rs, ts, ss),
        (vec![1, 72], vec![1, 3], vec![1, 3], vec![1, 10])
    );
    assert!(
        poses[..3].iter().all(|&x| x == 0.0),
        "poses[0:3] must be zero (ZJU convention)"
    );
    let mut p = [0.0f32; 72];
    for (d, s) in p.iter_mut().zip(&poses) {
        *d = *s as f32;
    }
    SmplParams {
        poses: p,
        shapes: shapes.iter().map(|&x| x as f32).collect(),
        rh: Vec3::new(rh[0] as f32, rh[1] as f32, rh[2] as f32),
        th: Vec3::new(th[0] as f32, th[1] as f32, th[2] as f32),
    }
}

fn load_vertices(path: &Path) -> Vec<Vec3> {
    let v = load_any(path).unwrap();
    let a = v.as_array().unwrap();
    assert_eq!(a.data.dtype_name(), "float32");
    assert_eq!(a.shape[1], 3);
    a.to_f32_vec()
        .unwrap()
        .chunks(3)
        .map(|c| Vec3::new(c[0], c[1], c[2]))
        .collect()
}

fn load_mask(path: &Path) -> image::GrayImage {
    let img = image::open(path).unwrap();
    assert!(
        matches!(img, image::DynamicImage::ImageLuma8(_)),
        "{}: 8-bit gray PNG",
        path.display()
    );
    img.into_luma8()
}

#[test]
fn layout_follows_zju_mocap() {
    let data = dataset();
    let spec = small_spec(7);
    assert!(data.dir.join(BODY_MODEL_FILE).is_file());
    assert_eq!(data.summary.images, 2 * 2 * 3);
    for id in [500, 501] {
        let s = data.dir.join(format!("CoreView_{id}"));
        assert!(s.join("annots.npy").is_file());
        for i in 0..2 {
            assert!(s.join(format!("params/{i}.npy")).is_file());
            assert!(s.join(format!("vertices/{i}.npy")).is_file());
            for k in 1..=3 {
                assert!(s.join(format!("Camera_B{k}/{i:06}.jpg")).is_file());
                assert!(s.join(format!("mask/Camera_B{k}/{i:06}.png")).is_file());
                let img = image::open(s.join(format!("Camera_B{k}/{i:06}.jpg"))).unwrap();
                assert_eq!((img.width(), img.height()), (80, 80));
            }
        }
    }
    // Progress: one ImageWritten per image, counting up to the total.
    let written: Vec<usize> = data
        .events
        .iter()
        .filter_map(|e| match e {
            SynthEvent::ImageWritten { done, total, .. } => Some(*done).filter(|_| *total == 12),
            _ => None,
        })
        .collect();
    assert_eq!(written, (1..=12).collect::<Vec<_>>());
    // synth.json: the spec and a split with both sides non-empty.
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.dir.join(DESCRIPTION_FILE)).unwrap()).unwrap();
    assert_eq!(json["spec"]["seed"], 7);
    assert_eq!(json["spec"]["cameras"], 3);
    assert_eq!(json["train_subjects"], serde_json::json!([500]));
    assert_eq!(json["test_subjects"], serde_json::json!([501]));
    assert_eq!(spec.split(), (vec![500], vec![501]));
}

#[test]
fn annots_have_zju_structure_and_t_in_millimetres() {
    let data = dataset();
    let annots = load_any(&data.dir.join("CoreView_500/annots.npy")).unwrap();
    assert_eq!(annots.keys(), ["cams", "ims"]);
    let cams = annots.get("cams").unwrap();
    assert_eq!(cams.keys(), ["K", "D", "R", "T"]);
    for (key, shape) in [("K", [3, 3]), ("D", [5, 1]), ("R", [3, 3]), ("T", [3, 1])] {
        let list = cams
            .get(key)
            .unwrap()
            .as_seq()
            .unwrap_or_else(|| panic!("cams['{key}'] is a list"));
        assert_eq!(list.len(), 3);
        for a in list {
            let arr = a.as_array().unwrap();
            assert_eq!(arr.data.dtype_name(), "float64");
            assert_eq!(arr.shape, shape.to_vec(), "cams['{key}']");
        }
    }
    let ims = annots.get("ims").unwrap().as_seq().unwrap();
    assert_eq!(ims.len(), 2);
    for (i, frame) in ims.iter().enumerate() {
        let paths: Vec<&str> = frame
            .get("ims")
            .unwrap()
            .as_seq()
            .unwrap()
            .iter()
            .map(|p| p.as_str().unwrap())
            .collect();
        assert_eq!(
            paths,
            (1..=3)
                .map(|k| format!("Camera_B{k}/{i:06}.jpg"))
                .collect::<Vec<_>>()
        );
    }
    // T in millimetres: the camera centres -R^T T / 1000 lie 2.5-3 m (plus height) from the body.
    let verts = load_vertices(&data.dir.join("CoreView_500/vertices/0.npy"));
    let centre = verts.iter().copied().sum::<Vec3>() / verts.len() as f32;
    for c in 0..3 {
        let cam = annots_camera(&annots, c, 80);
        let horizontal = (cam.centre() - centre).truncate().length();
        assert!(
            (2.3..3.2).contains(&horizontal),
            "camera {c} at {horizontal} m"
        );
        let m = Mat3::from_cols_array(&cam.r.to_cols_array());
        assert!((m.determinant() - 1.0).abs() < 1e-5);
    }
}

#[test]
fn vertices_are_lbs_of_params() {
    let data = dataset();
    let body = BodyModel::load(&data.dir.join(BODY_MODEL_FILE)).unwrap();
    for id in [500, 501] {
        for i in 0..2 {
            let s = data.dir.join(format!("CoreView_{id}"));
            let params = load_params(&s.join(format!("params/{i}.npy")));
            let expected = body.lbs(&params).vertices;
            let got = load_vertices(&s.join(format!("vertices/{i}.npy")));
            assert_eq!(got.len(), body.num_vertices());
            let worst = got
                .iter()
                .zip(&expected)
                .map(|(a, b)| (*a - *b).abs().max_element())
                .fold(0.0, f32::max);
            assert!(
                worst <= VERTEX_TOL_M,
                "subject {id} frame {i}: off by {worst} m"
            );
            // Standing on the floor of a z-up world.
            let min_z = got.iter().map(|v| v.z).fold(f32::INFINITY, f32::min);
            let max_z = got.iter().map(|v| v.z).fold(f32::NEG_INFINITY, f32::max);
            assert!(
                min_z > -0.1 && min_z < 0.15 && max_z > 1.2,
                "z range {min_z}..{max_z}"
            );
        }
    }
    // The subjects differ in shape.
    let a = load_params(&data.dir.join("CoreView_500/params/0.npy"));
    let b = load_params(&data.dir.join("CoreView_501/params/0.npy"));
    assert_ne!(a.shapes, b.shapes);
}

#[test]
fn masks_cover_the_projected_body_and_background_is_black() {
    let data = dataset();
    for id in [500, 501] {
        let s = data.dir.join(format!("CoreView_{id}"));
        let annots = load_any(&s.join("annots.npy")).unwrap();
        for i in 0..2 {
            let verts = load_vertices(&s.join(format!("vertices/{i}.npy")));
            for c in 0..3 {
                let cam = annots_camera(&annots, c, 80);
                let mask = load_mask(&s.join(format!("mask/Camera_B{}/{i:06}.png", c + 1)));
                assert!(
                    mask.pixels().all(|p| p.0[0] == 0 || p.0[0] == 255),
                    "mask is 0/255"
                );
                let fg = mask.pixels().filter(|p| p.0[0] == 255).count();
                let frac = fg as f32 / (80.0 * 80.0);
                assert!(
                    (0.03..0.6).contains(&frac),
                    "subject {id} frame {i} cam {c}: mask covers {frac}"
                );
                let near_mask = |x: i64, y: i64| {
                    (-MASK_SLACK_PX..=MASK_SLACK_PX).any(|dy| {
                        (-MASK_SLACK_PX..=MASK_SLACK_PX).any(|dx| {
                            let (px, py) = (x + dx, y + dy);
                            (0..80).contains(&px)
                                && (0..80).contains(&py)
                                && mask.get_pixel(px as u32, py as u32).0[0] == 255
                        })
                    })
                };
                let inside = verts
                    .iter()
                    .filter(|v| {
                        cam.project(**v).is_some_and(|(uv, _)| {
                            cam.contains_pixel(uv) && near_mask(uv.x as i64, uv.y as i64)
                        })
                    })
                    .count();
                let ratio = inside as f32 / verts.len() as f32;
                assert!(
                    ratio >= MIN_VERTICES_IN_MASK,
                    "subject {id} frame {i} cam {c}: {ratio} of vertices in mask"
                );
                let rgb = image::open(s.join(format!("Camera_B{}/{i:06}.jpg", c + 1)))
                    .unwrap()
                    .into_rgb8();
                let (mut bg, mut nbg, mut fgsum) = (0.0f32, 0usize, 0.0f32);
                for (p, m) in rgb.pixels().zip(mask.pixels()) {
                    let v = p.0.iter().map(|&x| x as f32).sum::<f32>() / 3.0;
                    if m.0[0] == 0 {
                        bg += v;
                        nbg += 1;
                    } else {
                        fgsum += v;
                    }
                }
                let (bg, fgm) = (bg / nbg.max(1) as f32, fgsum / fg as f32);
                assert!(bg < MAX_BACKGROUND_MEAN, "background mean {bg}");
                assert!(fgm > 20.0, "person is lit: mean {fgm}");
            }
        }
    }
}

#[test]
fn same_seed_same_bytes_other_seed_differs() {
    let a = all_files(&dataset().dir);
    let again = run(&small_spec(7), "b");
    let b = all_files(&again.dir);
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (path, bytes) in &a {
        assert!(
            bytes == &b[path],
            "{} differs between two runs with the same seed",
            path.display()
        );
    }
    let other = run(&small_spec(8), "c");
    let c = all_files(&other.dir);
    for path in [
        "CoreView_500/params/0.npy",
        "CoreView_500/annots.npy",
        "CoreView_500/Camera_B1/000000.jpg",
    ] {
        let p = Path::new(path);
        assert_ne!(a[p], c[p], "{path} should depend on the seed");
    }
    let _ = std::fs::remove_dir_all(&again.dir);
    let _ = std::fs::remove_dir_all(&other.dir);
}

#[test]
fn the_zju_reader_opens_a_synthetic_subject() {
    use nia_data::dataset::subject::Subject;
    use nia_data::dataset::DatasetConfig;
    let data = dataset();
    let root = data.dir.join("CoreView_501");
    let subject = Subject::open(&root, &DatasetConfig::zju()).expect("the ZJU reader opens it");
    assert_eq!((subject.num_cameras(), subject.num_frames()), (3, 2));
    let body = BodyModel::load(&data.dir.join(BODY_MODEL_FILE)).unwrap();
    let err = subject
        .lbs_max_error(&body, &data.dir.join(BODY_MODEL_FILE), 1)
        .unwrap();
    assert!(err <= VERTEX_TOL_M, "reader's LBS check: {err} m");
    let params = subject.load_params(1).unwrap();
    assert_eq!(params, load_params(&root.join("params/1.npy")));
    let view = subject.load_view(1, 2).unwrap();
    // ZJU's default ratio 0.5: 80 -> 40 pixels, K scaled by the same ratio.
    assert_eq!((view.width(), view.height()), (40, 40));
    assert!(view.mask_coverage() > 0.02);
}

/// Intersection over union of a mask and the pixels a mesh covers at their centres.
fn coverage_iou(mask: &image::GrayImage, frags: &nia_data::geometry::raster::Fragments) -> f32 {
    let (mut both, mut either) = (0usize, 0usize);
    for (p, m) in mask.pixels().enumerate() {
        let (a, b) = (m.0[0] == 255, frags.depth[p].is_finite());
        both += (a && b) as usize;
        either += (a || b) as usize;
    }
    both as f32 / either.max(1) as f32
}

#[test]
fn the_clothed_surface_is_what_the_masks_show_and_the_reader_finds_it() {
    use nia_data::dataset::subject::Subject;
    use nia_data::dataset::DatasetConfig;
    use nia_data::geometry::raster::rasterize;
    let data = dataset();
    let body = BodyModel::load(&data.dir.join(BODY_MODEL_FILE)).unwrap();
    let root = data.dir.join("CoreView_500");
    let annots = load_any(&root.join("annots.npy")).unwrap();
    let subject = Subject::open(&root, &DatasetConfig::zju()).unwrap();
    for i in 0..2 {
        let clothed = load_vertices(&root.join(format!("clothed_vertices/{i}.npy")));
        let naked = load_vertices(&root.join(format!("vertices/{i}.npy")));
        assert_eq!(clothed.len(), naked.len(), "the same mesh, SMPL's vertices");
        assert_eq!(
            subject.load_clothed_vertices(i).unwrap(),
            Some(clothed.clone())
        );
        for c in 0..3 {
            let cam = annots_camera(&annots, c, 80);
            let mask = load_mask(&root.join(format!("mask/Camera_B{}/{i:06}.png", c + 1)));
            let on_clothes = coverage_iou(&mask, &rasterize(&cam, &clothed, &body.faces).unwrap());
            let on_body = coverage_iou(&mask, &rasterize(&cam, &naked, &body.faces).unwrap());
            // Only silhouette pixels may differ (the mask keeps pixels covered at least half
            // at 2 x 2 samples; the raster tests the pixel's centre).
            assert!(on_clothes > 0.9, "frame {i} camera {c}: IoU {on_clothes}");
            assert!(
                on_clothes > on_body,
                "frame {i} camera {c}: the clothed surface ({on_clothes}) explains the mask \
                 better than the naked body ({on_body})"
            );
        }
    }
    // Real datasets have no such folder: the reader says so with None.
    let bare = scratch_dir("no-clothed");
    std::fs::create_dir_all(&bare).unwrap();
    for entry in std::fs::read_dir(&root).unwrap() {
        let entry = entry.unwrap();
        if entry.file_name() != "clothed_vertices" {
            let to = bare.join(entry.file_name());
            std::os::unix::fs::symlink(entry.path(), to).unwrap();
        }
    }
    let subject = Subject::open(&bare, &DatasetConfig::zju()).unwrap();
    assert_eq!(subject.load_clothed_vertices(0).unwrap(), None);
    let _ = std::fs::remove_dir_all(&bare);
}

#[test]
fn clothes_stand_off_the_body_and_skin_does_not() {
    use nia_data::body::{ProceduralBody, ProceduralSpec};
    use nia_data::rng::Rng;
    use nia_data::synth::clothing::{classify, Garment};
    use nia_data::synth::subject::{Subject, SubjectDesign};
    let body = ProceduralBody::generate(&ProceduralSpec::default()).unwrap();
    for k in 0..3 {
        let subject =
            Subject::prepare(&body, SubjectDesign::draw(k, &mut Rng::new(k as u64))).unwrap();
        let cut = &subject.design.cut;
        let (mut clothed, mut max) = (0usize, 0.0f32);
        for ((p, parts), &o) in subject
            .canonical
            .iter()
            .zip(&subject.parts)
            .zip(&subject.offsets_m)
        {
            let g = classify(&subject.frame, cut, *p, parts).garment;
            assert!(o >= 0.0 && o.is_finite());
            match g {
                Garment::Skin => assert_eq!(o, 0.0, "bare skin is not offset"),
                Garment::Shirt | Garment::Trousers => clothed += (o >= CLOTH_MIN_OFFSET_M) as usize,
                _ => {}
            }
            max = max.max(o);
        }
        let frac = clothed as f32 / subject.canonical.len() as f32;
        assert!(
            frac > 0.3,
            "subject {k}: only {frac} of the vertices carry clothes"
        );
        assert!(max <= CLOTH_MAX_OFFSET_M, "subject {k}: offset {max} m");
    }
}

#[test]
fn bad_specs_are_refused_with_the_field_named() {
    let dir = scratch_dir("refused");
    for (spec, field) in [
        (
            SynthSpec {
                subjects: 0,
                ..small_spec(1)
            },
            "subjects",
        ),
        (
            SynthSpec {
                size: 8,
                ..small_spec(1)
            },
            "size",
        ),
        (
            SynthSpec {
                supersample: 0,
                ..small_spec(1)
            },
            "supersample",
        ),
        (
            SynthSpec {
                size: 2048,
                supersample: 4,
                ..small_spec(1)
            },
            "supersample",
        ),
        (
            SynthSpec {
                fps: f32::NAN,
                ..small_spec(1)
            },
            "fps",
        ),
    ] {
        let err = generate(&spec, &dir, &mut |_| {}).unwrap_err();
        assert!(err.to_string().contains(&format!("`{field}`")), "{err}");
    }
    assert!(!dir.exists(), "nothing is written for a refused spec");
}

/// Arrays larger than this are compared at evenly strided elements (the body model's
/// `posedirs` has millions; every other file is compared in full).
const COMPARE_SAMPLES: usize = 20_000;

/// Converts a decoded value to the JSON the numpy script prints (arrays as
/// `{"dtype", "shape", "values"}`, floats as the bits of their f64 value), so both sides can
/// be compared exactly.
fn to_json(v: &PyValue) -> serde_json::Value {
    use serde_json::{json, Value};
    match v {
        PyValue::Dict(items) => Value::Object(
            items
                .iter()
                .map(|(k, v)| (k.as_str().expect("string keys").to_string(), to_json(v)))
                .collect(),
        ),
        PyValue::List(items) | PyValue::Tuple(items) => {
            Value::Array(items.iter().map(to_json).collect())
        }
        PyValue::Str(s) => json!(s),
        PyValue::Array(a) => {
            let n = a.numel();
            let stride = if n > COMPARE_SAMPLES {
                n.div_ceil(COMPARE_SAMPLES)
            } else {
                1
            };
            let values: Vec<Value> = if a.data.dtype_name().starts_with("float") {
                a.to_f64_vec()
                    .unwrap()
                    .into_iter()
                    .step_by(stride)
                    .map(|x| json!(x.to_bits()))
                    .collect()
            } else {
                a.to_i64_vec()
                    .unwrap()
                    .into_iter()
                    .step_by(stride)
                    .map(|x| json!(x))
                    .collect()
            };
            json!({"dtype": a.data.dtype_name(), "shape": a.shape, "values": values})
        }
        other => panic!("unexpected value {}", other.type_name()),
    }
}

const NUMPY_SCRIPT: &str = r#"
import json, struct, sys
import numpy as np
SAMPLES = int(sys.argv[1])
def conv(v):
    if isinstance(v, dict):
        return {str(k): conv(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [conv(x) for x in v]
    if isinstance(v, str):
        return v
    if isinstance(v, np.ndarray):
        if v.dtype == object:
            return conv(v.item())
        flat = v.ravel()
        stride = -(-flat.size // SAMPLES) if flat.size > SAMPLES else 1
        vals = flat[::stride].tolist()
        if v.dtype.kind == "f":
            vals = [struct.unpack("<Q", struct.pack("<d", x))[0] for x in vals]
        return {"dtype": str(v.dtype), "shape": list(v.shape), "values": vals}
    raise TypeError(type(v))
out = {}
for path in sys.argv[2:]:
    if path.endswith(".npz"):
        with np.load(path) as z:
            out[path] = {k: conv(z[k]) for k in z.files}
    else:
        out[path] = conv(np.load(path, allow_pickle=True))
json.dump(out, sys.stdout)
"#;

#[test]
fn numpy_loads_every_file_with_the_same_values() {
    let numpy = std::process::Command::new("python3")
        .args(["-c", "import numpy"])
        .output();
    if !numpy.as_ref().is_ok_and(|o| o.status.success()) {
        assert!(
            std::env::var("NIA_REQUIRE_NUMPY").as_deref() != Ok("1"),
            "NIA_REQUIRE_NUMPY=1 but python3 with numpy is not available"
        );
        eprintln!("skipped: numpy not available");
        return;
    }
    let data = dataset();
    let mut paths: Vec<PathBuf> = all_files(&data.dir)
        .into_keys()
        .filter(|p| p.extension().is_some_and(|e| e == "npy" || e == "npz"))
        .map(|p| data.dir.join(p))
        .collect();
    paths.sort();
    assert_eq!(
        paths.len(),
        1 + 2 * (1 + 2 + 2 + 2),
        "body model + per subject annots, params, vertices, clothed vertices"
    );
    let out = std::process::Command::new("python3")
        .arg("-c")
        .arg(NUMPY_SCRIPT)
        .arg(COMPARE_SAMPLES.to_string())
        .args(&paths)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "numpy failed: {stderr}");
    let loaded: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for path in &paths {
        let ours = to_json(&load_any(path).unwrap());
        let theirs = &loaded[path.to_str().unwrap()];
        assert!(
            &ours == theirs,
            "{}: numpy reads different values",
            path.display()
        );
    }
}

/// Throughput measurement (not a check): 2 subjects x 6 frames x 4 cameras at 256 and 512
/// pixels, timed from the first subject's start (after building and writing the body model).
/// Run with `cargo test -p nia-data --release --test synth -- --ignored --nocapture bench`.
/// Keeps the output under `$NIA_SYNTH_BENCH_DIR` when set (to look at the images).
#[test]
#[ignore]
fn bench_images_per_second() {
    for size in [256u32, 512] {
        let spec = SynthSpec {
            subjects: 2,
            frames: 6,
            cameras: 4,
            size,
            seed: 1,
            ..SynthSpec::default()
        };
        let dir = match std::env::var("NIA_SYNTH_BENCH_DIR") {
            Ok(d) => PathBuf::from(d).join(format!("size{size}")),
            Err(_) => scratch_dir(&format!("bench{size}")),
        };
        let t0 = std::time::Instant::now();
        let mut first_subject = None;
        let summary = generate(&spec, &dir, &mut |e| {
            if matches!(e, SynthEvent::SubjectStarted { index: 0, .. }) {
                first_subject = Some(std::time::Instant::now());
            }
        })
        .unwrap();
        let total_s = t0.elapsed().as_secs_f64();
        let render_s = first_subject.unwrap().elapsed().as_secs_f64();
        eprintln!(
            "size {size}: {} images in {total_s:.2} s ({:.2} s body model), {:.1} images/s rendered+written ({} threads)",
            summary.images,
            total_s - render_s,
            summary.images as f64 / render_s,
            rayon::current_num_threads()
        );
        if std::env::var("NIA_SYNTH_BENCH_DIR").is_err() {
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
}
