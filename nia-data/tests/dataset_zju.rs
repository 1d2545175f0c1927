//! The ZJU-MoCap reader on numpy-written fixtures in the real layout
//! (`scripts/fixtures/make_zju_fixture.py`): two tiny subjects, 4 cameras, 2 frames, one with
//! the `Camera (k)` naming of 313/315. Plus one test per kind of broken input.

use std::path::{Path, PathBuf};

use nia_data::body::BodyModel;
use nia_data::dataset::protocol::{EvalSplit, FrameRange, Protocol, SubjectFrames, ViewSet};
use nia_data::dataset::{inspect, DatasetConfig, DatasetError, Subject};
use nia_data::formats::npy;

/// Stored vertices are float32 LBS (float64) of the float64 model; the .npz model is float32.
/// Both roundings are ~1e-7 relative on coordinates of ~1 m.
const LBS_TOL_M: f32 = 1e-5;
/// Reference views were decoded by libjpeg (PIL) and resampled by OpenCV with 1/32-pixel
/// fixed-point remap weights; ours by the `image` crate's decoder and exact bilinear weights.
/// Colours agree to a few levels of 255 on average.
const VIEW_MEAN_ABS_TOL: f32 = 0.01;
/// ... and a single pixel may differ by up to this (a JPEG block edge or a mask-edge pixel).
const VIEW_MAX_ABS_TOL: f32 = 0.25;
/// Mask pixels whose undistorted foreground weight sits at 0.5 may round either way.
const MASK_MISMATCH_FRACTION: f64 = 0.02;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/zju")
}

/// Copies the tree under `from` to `to`.
fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap().map(Result::unwrap) {
        let (path, target) = (entry.path(), to.join(entry.file_name()));
        if path.is_dir() {
            copy_dir(&path, &target);
        } else {
            std::fs::copy(&path, &target).unwrap();
        }
    }
}

/// A private copy of a fixture subject to break.
fn scratch_copy(subject: &str, tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "nia-dataset-zju-{}-{tag}/{subject}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    copy_dir(&fixtures().join(subject), &dir);
    dir
}

fn f32s(path: &Path) -> (Vec<usize>, Vec<f32>) {
    let a = npy::read(path).unwrap();
    let v = a.to_f32_vec().unwrap();
    (a.shape, v)
}

#[test]
fn reads_coreview_as_it_ships() {
    let s = Subject::open(&fixtures().join("CoreView_377"), &DatasetConfig::zju()).unwrap();
    assert_eq!(s.name, "CoreView_377");
    assert_eq!((s.num_cameras(), s.num_frames()), (4, 2));
    // 64x64 raw, ratio 0.5.
    assert_eq!((s.raw_cameras[0].width, s.cameras[0].width), (64, 32));
    assert!(s.params_dir.ends_with("params") && s.vertices_dir.ends_with("vertices"));
    assert_eq!(s.frames[1].number, 1);
    // T is stored in millimetres (camera 3 m from the body): metres here.
    let centre = s.raw_cameras[0].centre();
    assert!((centre.truncate().length() - 3.0).abs() < 1e-3, "{centre}");
    // K scaled by the ratio, distortion gone from the loaded images' camera.
    assert!((s.cameras[2].fx() - 0.5 * s.raw_cameras[2].fx()).abs() < 1e-5);
    assert_eq!(s.cameras[2].dist, [0.0; 5]);
    assert_ne!(s.raw_cameras[2].dist, [0.0; 5]);
    let v = s.load_vertices(1).unwrap();
    assert_eq!(v.len(), 30);
    let p = s.load_params(1).unwrap();
    assert_eq!(p.shapes.len(), 10);
    assert!((p.th.z - 0.9).abs() < 1e-6);
}

/// The loaded view equals NHP's preparation (cv2.undistort, INTER_AREA, INTER_NEAREST, black
/// background), computed by the fixture script with OpenCV.
fn check_view(subject: &str, config: DatasetConfig, frame: usize, view: usize, expected: &str) {
    let s = Subject::open(&fixtures().join(subject), &config).unwrap();
    let v = s.load_view(frame, view).unwrap();
    let (shape, image) = f32s(&fixtures().join(format!("expected/{expected}_image.npy")));
    let mask_arr = npy::read(&fixtures().join(format!("expected/{expected}_mask.npy"))).unwrap();
    let mask: Vec<bool> = mask_arr
        .to_f64_vec()
        .unwrap()
        .iter()
        .map(|m| *m != 0.0)
        .collect();
    assert_eq!(shape, vec![v.height() as usize, v.width() as usize, 3]);
    let mismatched = v.mask.iter().zip(&mask).filter(|(a, b)| a != b).count();
    assert!(
        (mismatched as f64) <= MASK_MISMATCH_FRACTION * mask.len() as f64,
        "{subject}: {mismatched} mask pixels differ"
    );
    assert!(mask.iter().any(|m| *m), "the reference mask is not empty");
    // Colours where both masks agree.
    let mut sum = 0.0f32;
    let mut n = 0usize;
    let mut max = 0.0f32;
    for (i, (a, b)) in v.mask.iter().zip(&mask).enumerate() {
        if a != b {
            continue;
        }
        for c in 0..3 {
            let d = (v.image[i * 3 + c] - image[i * 3 + c]).abs();
            sum += d;
            max = max.max(d);
            n += 1;
        }
    }
    let mean = sum / n as f32;
    assert!(mean < VIEW_MEAN_ABS_TOL, "{subject}: mean |diff| {mean}");
    assert!(max < VIEW_MAX_ABS_TOL, "{subject}: max |diff| {max}");
    // Black background.
    for (px, m) in v.image.chunks_exact(3).zip(&v.mask) {
        if !m {
            assert_eq!(px, [0.0, 0.0, 0.0]);
        }
    }
}

#[test]
fn view_matches_nhp_preparation_with_mask_union() {
    check_view(
        "CoreView_377",
        DatasetConfig::zju(),
        1,
        2,
        "CoreView_377_f1_c2_r0.5",
    );
    // The union matters: mask/ alone covers only the upper part of the body.
    let s = Subject::open(&fixtures().join("CoreView_377"), &DatasetConfig::zju()).unwrap();
    let union = s.load_raw_mask(1, 2).unwrap();
    let cfg = DatasetConfig {
        mask_dirs: Some(vec!["mask".into()]),
        ..DatasetConfig::zju()
    };
    let only = Subject::open(&fixtures().join("CoreView_377"), &cfg).unwrap();
    let upper = only.load_raw_mask(1, 2).unwrap();
    let (nu, nm) = (
        union.iter().filter(|m| **m).count(),
        upper.iter().filter(|m| **m).count(),
    );
    assert!(nm > 0 && nu > nm + 20, "union {nu} vs mask/ alone {nm}");
}

#[test]
fn camera_k_naming_of_313_new_dirs_and_jpg_masks() {
    let mut cfg = DatasetConfig::zju();
    cfg.ratio = Some(1.0);
    let s = Subject::open(&fixtures().join("CoreView_313"), &cfg).unwrap();
    assert_eq!((s.num_cameras(), s.num_frames()), (4, 2));
    assert!(s.params_dir.ends_with("new_params") && s.vertices_dir.ends_with("new_vertices"));
    // Numbers from the fifth `_` field: frames 0, 1 read 1.npy, 2.npy.
    assert_eq!((s.frames[0].number, s.frames[1].number), (1, 2));
    assert!(s.frames[0].images[3]
        .to_string_lossy()
        .contains("Camera (4)"));
    assert!(s.vertices_path(1).unwrap().ends_with("new_vertices/2.npy"));
    let masks = s.mask_paths(0, 3).unwrap();
    assert_eq!(masks.len(), 2);
    assert!(masks[1].extension().unwrap() == "jpg");
    check_view("CoreView_313", cfg, 0, 3, "CoreView_313_f0_c3_r1");
}

#[test]
fn nhp_renamed_313_images_are_found() {
    // NHP's modify_313_315_filename.py renames the images to `Camera (k)/0001.jpg` and leaves
    // annots.npy alone.
    let root = scratch_copy("CoreView_313", "renamed");
    for cam in 1..=4 {
        for n in [1, 2] {
            let dir = root.join(format!("Camera ({cam})"));
            let long = dir.join(format!(
                "CoreView_313_Camera_({cam})_{n:04}_2019-08-23_16-08-50.592.jpg"
            ));
            std::fs::rename(&long, dir.join(format!("{n:04}.jpg"))).unwrap();
            let mdir = root.join(format!("mask/Camera ({cam})"));
            let mlong = mdir.join(format!(
                "CoreView_313_Camera_({cam})_{n:04}_2019-08-23_16-08-50.592.png"
            ));
            std::fs::rename(&mlong, mdir.join(format!("{n:04}.png"))).unwrap();
        }
    }
    let s = Subject::open(&root, &DatasetConfig::zju()).unwrap();
    assert!(s.frames[1].images[0].ends_with("Camera (1)/0002.jpg"));
    assert_eq!(s.frames[1].number, 2);
    let v = s.load_view(1, 0).unwrap();
    assert!(v.mask_coverage() > 0.02);
}

#[test]
fn lbs_of_stored_params_reproduces_stored_vertices() {
    for model_name in ["smpl_tiny.npz", "smpl_tiny.pkl"] {
        let path = fixtures().join(model_name);
        let model = BodyModel::load(&path).unwrap();
        for (subject, ratio) in [("CoreView_377", 0.5), ("CoreView_313", 1.0)] {
            let mut cfg = DatasetConfig::zju();
            cfg.ratio = Some(ratio);
            let s = Subject::open(&fixtures().join(subject), &cfg).unwrap();
            for frame in 0..2 {
                let err = s.lbs_max_error(&model, &path, frame).unwrap();
                assert!(
                    err < LBS_TOL_M,
                    "{model_name} {subject} frame {frame}: {err} m"
                );
            }
        }
    }
}

#[test]
fn inspect_reports_the_subject() {
    let mut cfg = DatasetConfig::zju();
    cfg.smpl_model = Some(fixtures().join("smpl_tiny.npz"));
    let r = inspect(&fixtures().join("CoreView_377"), &cfg).unwrap();
    assert_eq!(r.subject, "CoreView_377");
    assert_eq!((r.num_cameras, r.num_frames, r.num_vertices), (4, 2, 30));
    assert_eq!(r.image_size, [32, 32]);
    assert!(
        r.camera0.t.iter().map(|t| t * t).sum::<f32>().sqrt() < 10.0,
        "metres"
    );
    assert!(r.bbox_min.iter().zip(&r.bbox_max).all(|(a, b)| a < b));
    assert!(
        (r.bbox_max[2] - r.bbox_min[2] - 1.7).abs() < 0.3,
        "a 1.7 m body"
    );
    assert!(r.mask_coverage > 0.02 && r.mask_coverage < 0.5);
    assert!(r.lbs_max_err_m.unwrap() < LBS_TOL_M);
    let json = serde_json::to_value(&r).unwrap();
    for key in ["K", "R", "T"] {
        assert!(json["camera0"][key].is_array(), "{key}");
    }
}

#[test]
fn protocol_applies_to_the_fixture() {
    let s = Subject::open(&fixtures().join("CoreView_377"), &DatasetConfig::zju()).unwrap();
    // The NHP protocol asks for views 7 and 15: a 4-camera subject cannot serve it.
    let nhp = Protocol::nhp();
    let err = nhp
        .eval_items(EvalSplit::SeenSubjectsUnseenPoses, |_| {
            (s.num_cameras(), s.num_frames())
        })
        .unwrap_err();
    assert!(err.to_string().contains("view 7"), "{err}");
    // An override that fits it (as a run config would write it).
    let mut p = Protocol::nhp();
    p.train.clear();
    p.seen_subjects_unseen_poses.clear();
    p.seen_subjects_seen_poses.clear();
    p.input_views = ViewSet::explicit(&[0, 2]);
    p.target_views = ViewSet::OthersThanInputs { stride: 1 };
    p.test_frame_stride = 1;
    p.unseen_subjects = vec![SubjectFrames::new("CoreView_377", FrameRange::all_from(0))];
    let items = p
        .eval_items(EvalSplit::UnseenSubjects, |_| {
            (s.num_cameras(), s.num_frames())
        })
        .unwrap();
    p.validate().unwrap();
    p.check_subject("CoreView_377", s.num_cameras(), s.num_frames())
        .unwrap();
    assert_eq!(items.len(), 2 * 2, "2 frames x targets {{1, 3}}");
    assert!(items
        .iter()
        .all(|i| i.target_view == 1 || i.target_view == 3));
}

// ---- broken inputs, one test each ----

fn open_err(root: &Path) -> DatasetError {
    Subject::open(root, &DatasetConfig::zju()).unwrap_err()
}

/// A scratch copy of `CoreView_377` without its file or folder `rel`.
fn without(tag: &str, rel: &str) -> PathBuf {
    let root = scratch_copy("CoreView_377", tag);
    let path = root.join(rel);
    match path.is_dir() {
        true => std::fs::remove_dir_all(&path).unwrap(),
        false => std::fs::remove_file(&path).unwrap(),
    }
    root
}

/// A scratch copy of `CoreView_377` with the broken fixture `bad/<bad>` in place of its file
/// `rel`, opened.
fn with_broken_file(tag: &str, bad: &str, rel: &str) -> (PathBuf, Subject) {
    let root = scratch_copy("CoreView_377", tag);
    std::fs::copy(fixtures().join("bad").join(bad), root.join(rel)).unwrap();
    let subject = Subject::open(&root, &DatasetConfig::zju()).unwrap();
    (root, subject)
}

/// Asserts that the error's message names every one of `parts`; the message.
fn names(err: &DatasetError, parts: &[&str]) -> String {
    let msg = err.to_string();
    for part in parts {
        assert!(msg.contains(part), "`{part}` not in: {msg}");
    }
    msg
}

#[test]
fn missing_camera_folder_is_named() {
    let err = open_err(&without("nocam", "Camera_B3"));
    let msg = names(&err, &["Camera_B3", "camera folder missing"]);
    assert!(
        matches!(err, DatasetError::CameraFolderMissing { camera: 2, .. }),
        "{msg}"
    );
}

#[test]
fn frame_without_image_is_named() {
    let err = open_err(&without("noimage", "Camera_B2/000001.jpg"));
    let msg = names(&err, &["Camera_B2/000001.jpg", "image missing"]);
    assert!(
        matches!(
            err,
            DatasetError::ImageMissing {
                frame: 1,
                camera: 1,
                ..
            }
        ),
        "{msg}"
    );
}

#[test]
fn mask_of_wrong_size_is_named() {
    let mask = "mask_cihp/Camera_B1/000000.png";
    let (_, s) = with_broken_file("masksize", "mask_wrong_size.png", mask);
    let err = s.load_view(0, 0).unwrap_err();
    let msg = names(&err, &[mask, "64x32", "expected 64x64"]);
    assert!(
        matches!(err, DatasetError::Size { what: "mask", .. }),
        "{msg}"
    );
}

#[test]
fn nan_in_params_is_named() {
    let (_, s) = with_broken_file("nan", "params_nan.npy", "params/1.npy");
    s.load_params(0).unwrap();
    let err = s.load_params(1).unwrap_err();
    let msg = names(&err, &["params/1.npy", "`Th`", "NaN"]);
    assert!(
        matches!(err, DatasetError::NonFinite { ref field, index: 1, .. } if field == "Th"),
        "{msg}"
    );
}

#[test]
fn vertices_of_wrong_shape_are_named() {
    let (root, s) = with_broken_file("vshape", "vertices_wrong_shape.npy", "vertices/0.npy");
    let err = s.load_vertices(0).unwrap_err();
    let msg = names(&err, &["vertices/0.npy", "[V, 3]", "[30, 2]"]);
    assert!(matches!(err, DatasetError::Field(_)), "{msg}");
    // inspect fails the same way, naming the file.
    let err = inspect(&root, &DatasetConfig::zju()).unwrap_err();
    assert!(err.to_string().contains("vertices/0.npy"));
}

#[test]
fn smpl_with_other_vertex_count_is_named() {
    let model_path = fixtures().join("bad/smpl_one_vertex_fewer.npz");
    let model = BodyModel::load(&model_path).unwrap();
    let s = Subject::open(&fixtures().join("CoreView_377"), &DatasetConfig::zju()).unwrap();
    let err = s.lbs_max_error(&model, &model_path, 0).unwrap_err();
    let msg = names(&err, &["smpl_one_vertex_fewer.npz", "vertices/0.npy"]);
    let expected = matches!(
        err,
        DatasetError::VertexCount {
            model_vertices: 29,
            stored_vertices: 30,
            ..
        }
    );
    assert!(expected, "{msg}");
}

#[test]
fn missing_annots_and_params_folders_are_named() {
    let root = without("noparams", "params");
    names(&open_err(&root), &["params", "new_params"]);
    std::fs::remove_file(root.join("annots.npy")).unwrap();
    names(&open_err(&root), &["annots.npy", "missing"]);
    names(&open_err(&root.join("nope")), &["not a subject folder"]);
}

#[test]
fn monocap_subject_reads_lbs_at_full_resolution() {
    let root = scratch_copy("CoreView_377", "monocap");
    copy_dir(&fixtures().join("monocap_lbs"), &root.join("lbs"));
    let s = Subject::open(&root, &DatasetConfig::monocap()).unwrap();
    assert_eq!((s.ratio, s.cameras[0].width), (1.0, 64));
    let lbs = s.lbs.as_ref().unwrap();
    let model = BodyModel::load(&fixtures().join("smpl_tiny.npz")).unwrap();
    assert_eq!(lbs.num_vertices(), Some(model.num_vertices()));
    assert_eq!(lbs.parents.as_ref().unwrap()[..3], [-1, 0, 0]);
    assert_eq!(lbs.faces.as_ref().unwrap(), &model.faces);
    let joints = lbs.joints.as_ref().unwrap();
    assert_eq!(joints.len(), 24);
    let rest = model.regress_joints(&model.v_template);
    assert!(joints.iter().zip(&rest).all(|(a, b)| a.distance(*b) < 1e-5));
    assert!(s.load_view(0, 0).unwrap().mask_coverage() > 0.02);
    // A broken lbs file is named; a missing lbs/ folder too.
    std::fs::copy(
        fixtures().join("bad/vertices_wrong_shape.npy"),
        root.join("lbs/weights.npy"),
    )
    .unwrap();
    let open_monocap = || Subject::open(&root, &DatasetConfig::monocap()).unwrap_err();
    names(&open_monocap(), &["lbs/weights.npy", "[V, 24]"]);
    std::fs::remove_dir_all(root.join("lbs")).unwrap();
    names(&open_monocap(), &["lbs", "missing"]);
}
