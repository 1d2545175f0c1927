//! Own-capture inputs: OpenPose keypoints, COLMAP and JSON cameras, and the keypoint map, read
//! from fixtures in the tools' exact formats (nia-data/tests/fixtures/own_capture, made by
//! scripts/fixtures/make_own_capture_fixtures.py and by hand), written and read back, and every
//! bad input refused with an error naming the file.

mod common;

use std::path::{Path, PathBuf};

use glam::{Mat3, Vec2, Vec3};
use nia_data::body::{BodyModel, ProceduralBody, ProceduralSpec, SmplParams, SMPL_PARENTS};
use nia_data::geometry::camera::Camera;
use nia_data::own_capture::cameras::{
    read_cameras_json, read_colmap_text, write_cameras_json, write_colmap_text,
};
use nia_data::own_capture::keypoint_map::{
    keypoint_sources, keypoints_3d, landmark_vertices, KeypointSource, SMPL_LANDMARK_VERTICES,
    SMPL_NUM_VERTICES,
};
use nia_data::own_capture::keypoints::{
    keypoint_names, read_openpose, write_openpose, KeypointLayout, Keypoints2d,
};
use nia_data::own_capture::OwnCaptureError;

/// Pixel tolerance of a projection computed in f32 from text values (sub-millipixel errors).
const PIXEL_TOL: f32 = 1e-3;

/// Tolerance of a camera read back from COLMAP's text (f32 printed shortest, quaternion
/// round trip: ~1e-7 relative).
const ROUND_TRIP_TOL: f32 = 1e-5;

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/own_capture")
        .join(rel)
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nia-own-capture-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The error's message, checked to name `file` (its file name) and every one of `words`.
fn assert_error_names<T: std::fmt::Debug>(
    result: Result<T, OwnCaptureError>,
    file: &str,
    words: &[&str],
) {
    let err = result.expect_err("a bad input must be refused");
    let msg = err.to_string();
    assert!(msg.contains(file), "error does not name `{file}`: {msg}");
    for w in words {
        assert!(msg.contains(w), "error does not say `{w}`: {msg}");
    }
}

// ---------------------------------------------------------------- OpenPose keypoints

#[test]
fn openpose_body25_and_coco18_are_read_with_their_layouts() {
    let kp = read_openpose(&fixture("openpose/body25.json"))
        .unwrap()
        .unwrap();
    assert_eq!(kp.layout, KeypointLayout::Body25);
    assert_eq!(kp.points.len(), 25);
    assert_eq!(kp.points[0], [500.0, 150.0, 0.9]);
    assert_eq!(kp.points[1], [500.25, 239.5, 0.89]);
    // REar (17) was not detected: (0, 0, 0).
    assert_eq!(kp.points[17], [0.0; 3]);
    assert!(!kp.detected(17) && kp.detected(16));
    assert_eq!(keypoint_names(kp.layout)[17], "REar");

    let coco = read_openpose(&fixture("openpose/coco18.json"))
        .unwrap()
        .unwrap();
    assert_eq!(coco.layout, KeypointLayout::Coco18);
    assert_eq!(coco.points.len(), 18);
    // COCO-18's RHip (8) is BODY_25's RHip (9): (460, 480) + (0.25 * 9 % 4, -0.5 * 8 % 3).
    assert_eq!(keypoint_names(KeypointLayout::Coco18)[8], "RHip");
    assert_eq!(&coco.points[8][..2], &[460.0, 479.0]);

    let legacy = read_openpose(&fixture("openpose/legacy.json"))
        .unwrap()
        .unwrap();
    assert_eq!(legacy.layout, KeypointLayout::Body25);
    assert_eq!(legacy.points[0], [500.0, 150.0, 0.7]);
}

#[test]
fn openpose_picks_the_most_confident_person_and_none_for_nobody() {
    let kp = read_openpose(&fixture("openpose/two_people.json"))
        .unwrap()
        .unwrap();
    // The second person (x + 200, confidence ~0.85) outweighs the first (~0.3).
    assert_eq!(kp.points[0][0], 700.0);
    assert!(kp.total_confidence() > 20.0);
    assert_eq!(
        read_openpose(&fixture("openpose/nobody.json")).unwrap(),
        None
    );
}

#[test]
fn openpose_round_trips_exactly_in_both_layouts() {
    let dir = temp_dir("openpose");
    for layout in [KeypointLayout::Body25, KeypointLayout::Coco18] {
        let mut kp = Keypoints2d::undetected(layout);
        for (i, p) in kp.points.iter_mut().enumerate() {
            if i % 5 != 3 {
                *p = [
                    100.0 + i as f32 * 13.37,
                    1.0 / 3.0 + i as f32,
                    0.1 + i as f32 / 40.0,
                ];
            }
        }
        let path = dir.join(format!("{layout}_keypoints.json"));
        write_openpose(&path, &kp).unwrap();
        let back = read_openpose(&path).unwrap().unwrap();
        assert_eq!(back, kp);
        // The real format: version, person_id, every OpenPose array present.
        let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        assert_eq!(v["version"], serde_json::json!(1.3));
        let person = &v["people"][0];
        assert_eq!(person["person_id"], serde_json::json!([-1]));
        for key in [
            "face_keypoints_2d",
            "hand_left_keypoints_2d",
            "hand_right_keypoints_2d",
            "pose_keypoints_3d",
        ] {
            assert_eq!(person[key], serde_json::json!([]), "{key}");
        }
        assert_eq!(
            person["pose_keypoints_2d"].as_array().unwrap().len(),
            3 * layout.len()
        );
    }
    let short = Keypoints2d {
        layout: KeypointLayout::Body25,
        points: vec![[1.0, 2.0, 0.5]; 18],
    };
    assert_error_names(
        write_openpose(&dir.join("short.json"), &short),
        "short.json",
        &["25 keypoints", "18 keypoints"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_openpose_files_are_refused_naming_the_file() {
    assert_error_names(
        read_openpose(&fixture("openpose/bad_count.json")),
        "bad_count.json",
        &["57 values", "75", "BODY_25", "54", "COCO-18"],
    );
    assert_error_names(
        read_openpose(&fixture("openpose/malformed.json")),
        "malformed.json",
        &["not valid JSON", "OpenPose"],
    );
    assert_error_names(
        read_openpose(&fixture("openpose/no_pose.json")),
        "no_pose.json",
        &["people[0].pose_keypoints_2d", "no such field"],
    );
    assert_error_names(
        read_openpose(&fixture("openpose/negative_conf.json")),
        "negative_conf.json",
        &["pose_keypoints_2d[14]", "confidence >= 0", "RWrist", "-0.5"],
    );
    // No `people` at all (a cameras file passed as keypoints).
    assert_error_names(
        read_openpose(&fixture("cameras.json")),
        "cameras.json",
        &["`people`", "no such field"],
    );
    assert_error_names(
        read_openpose(&fixture("openpose/absent.json")),
        "absent.json",
        &["cannot read"],
    );
}

#[test]
fn layouts_parse_by_name_and_count() {
    assert_eq!("body25".parse(), Ok(KeypointLayout::Body25));
    assert_eq!("coco18".parse(), Ok(KeypointLayout::Coco18));
    assert!("coco17"
        .parse::<KeypointLayout>()
        .unwrap_err()
        .contains("body25"));
    assert_eq!(KeypointLayout::from_count(25), Some(KeypointLayout::Body25));
    assert_eq!(KeypointLayout::from_count(18), Some(KeypointLayout::Coco18));
    assert_eq!(KeypointLayout::from_count(17), None);
    assert_eq!(KeypointLayout::Body25.index_of("MidHip"), Some(8));
    assert_eq!(KeypointLayout::Coco18.index_of("MidHip"), None);
}

// ---------------------------------------------------------------- COLMAP cameras

/// Hand values of the fixture `colmap/`:
/// - image 1: `q = (cos 45, 0, sin 45, 0)` is a 90 degree turn about y, `R = [[0, 0, 1],
///   [0, 1, 0], [-1, 0, 0]]`; `T = (0.1, -0.2, 3)`; the point `(-1, 0.5, 0.2)` is at
///   `R X + T = (0.3, 0.3, 4)` in the camera. PINHOLE `fx = 1000, fy = 1100` and COLMAP's
///   `(cx, cy) = (320.5, 240.5)`, which is `(320, 240)` with pixel centres at integers:
///   `u = 1000 * 0.3 / 4 + 320 = 395`, `v = 1100 * 0.3 / 4 + 240 = 322.5`.
/// - image 2: identity, `T = (0, 0, 2)`, SIMPLE_PINHOLE `f = 500, c = 256.5`: the point
///   `(0.2, -0.1, 0)` -> `(500 * 0.1 + 256, -500 * 0.05 + 256) = (306, 231)`.
/// - image 3: `q = (0, 0, 0, 1)`, a half turn about z, `R = diag(-1, -1, 1)`, `T = (0.5, 0,
///   4)`, OPENCV `f = 800, c = (400.5, 300.5)`: `(0.5, 0.2, 0)` -> camera `(0, -0.2, 4)` ->
///   ideal pixel `(400, 260)`; distortion `(k1, k2, p1, p2) = (-0.1, 0.01, 0.001, -0.002)`.
#[test]
fn colmap_text_model_gives_the_hand_computed_pixels() {
    let cams = read_colmap_text(&fixture("colmap")).unwrap();
    let names: Vec<&str> = cams.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        ["cam_a/000000.jpg", "cam_b/000000.jpg", "cam_c/000000.jpg"]
    );
    let expect = [
        (Vec3::new(-1.0, 0.5, 0.2), Vec2::new(395.0, 322.5), 4.0),
        (Vec3::new(0.2, -0.1, 0.0), Vec2::new(306.0, 231.0), 2.0),
        (Vec3::new(0.5, 0.2, 0.0), Vec2::new(400.0, 260.0), 4.0),
    ];
    for ((name, cam), (x, uv, depth)) in cams.iter().zip(expect) {
        let (got, z) = cam.project(x).unwrap();
        assert!(
            (got - uv).abs().max_element() < PIXEL_TOL,
            "{name}: {got} vs {uv}"
        );
        assert!((z - depth).abs() < 1e-5, "{name}: depth {z}");
    }
    let a = &cams[0].1;
    let r_expected =
        Mat3::from_cols_array_2d(&[[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]).transpose();
    assert!((a.r - r_expected)
        .abs()
        .to_cols_array()
        .iter()
        .all(|e| *e < 1e-6));
    assert_eq!(
        (a.width, a.height, a.fx(), a.fy()),
        (640, 480, 1000.0, 1100.0)
    );
    assert_eq!(cams[1].1.dist, [0.0; 5]);
    assert_eq!(cams[2].1.dist, [-0.1, 0.01, 0.001, -0.002, 0.0]);
    assert_eq!((cams[2].1.cx(), cams[2].1.cy()), (400.0, 300.0));
}

#[test]
fn colmap_round_trips_through_its_writer() {
    let dir = temp_dir("colmap");
    let mut cams = Vec::new();
    for (i, eye) in [Vec3::new(2.5, 1.0, 0.3), Vec3::new(-1.0, 1.2, -2.4)]
        .into_iter()
        .enumerate()
    {
        let mut c = Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 900.0, 905.0, 640, 480).unwrap();
        if i == 1 {
            c.dist = [-0.2, 0.05, 0.001, 0.002, 0.0];
        }
        cams.push((format!("Camera_B{}/000000.jpg", i + 1), c));
    }
    write_colmap_text(&dir, &cams).unwrap();
    let back = read_colmap_text(&dir).unwrap();
    assert_eq!(back.len(), cams.len());
    let cameras_txt = std::fs::read_to_string(dir.join("cameras.txt")).unwrap();
    assert!(
        cameras_txt.contains("1 PINHOLE 640 480 900 905 320.5 240.5"),
        "{cameras_txt}"
    );
    assert!(cameras_txt.contains("2 OPENCV"), "{cameras_txt}");
    for ((n0, c0), (n1, c1)) in cams.iter().zip(&back) {
        assert_eq!(n0, n1);
        assert_eq!(c0.k, c1.k);
        assert_eq!(c0.dist, c1.dist);
        assert_eq!((c0.width, c0.height), (c1.width, c1.height));
        let dr = (c0.r - c1.r).abs().to_cols_array();
        assert!(dr.iter().all(|e| *e < ROUND_TRIP_TOL), "{n0}: {dr:?}");
        assert!((c0.t - c1.t).abs().max_element() < ROUND_TRIP_TOL, "{n0}");
    }
    // A camera with skew has no COLMAP model here.
    let mut skewed = cams[0].1;
    skewed.k.y_axis.x = 0.5;
    assert_error_names(
        write_colmap_text(&dir, &[("skewed".into(), skewed)]),
        "cameras.txt",
        &["skewed", "no skew"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_colmap_models_are_refused_naming_the_file_and_line() {
    assert_error_names(
        read_colmap_text(&fixture("colmap_unsupported")),
        "colmap_unsupported/cameras.txt:5",
        &[
            "camera 2",
            "SIMPLE_RADIAL",
            "PINHOLE, SIMPLE_PINHOLE or OPENCV",
        ],
    );
    assert_error_names(
        read_colmap_text(&fixture("colmap_unknown_camera")),
        "colmap_unknown_camera/images.txt:7",
        &["cam_b/000000.jpg", "camera id 7", "cameras.txt", "[1]"],
    );
    assert_error_names(
        read_colmap_text(&fixture("colmap_bad_params")),
        "colmap_bad_params/cameras.txt:4",
        &["PINHOLE parameters", "4 values (fx fy cx cy)"],
    );
    assert_error_names(
        read_colmap_text(&fixture("openpose")),
        "openpose/cameras.txt",
        &["cannot read"],
    );
    // A malformed image line and a zero quaternion, written here.
    let dir = temp_dir("colmap-bad");
    std::fs::copy(
        fixture("colmap_unknown_camera/cameras.txt"),
        dir.join("cameras.txt"),
    )
    .unwrap();
    std::fs::write(dir.join("images.txt"), "# comment\n1 1 0 0 0 0 0 2 1\n\n").unwrap();
    assert_error_names(
        read_colmap_text(&dir),
        "images.txt:2",
        &["IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"],
    );
    std::fs::write(dir.join("images.txt"), "1 0 0 0 0 0 0 2 1 a.jpg\n\n").unwrap();
    assert_error_names(
        read_colmap_text(&dir),
        "images.txt:1",
        &["non-zero quaternion"],
    );
    std::fs::write(dir.join("images.txt"), "1 1 0 0 x 0 0 2 1 a.jpg\n\n").unwrap();
    assert_error_names(read_colmap_text(&dir), "images.txt:1", &["QZ", "`x`"]);
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------- cameras.json

#[test]
fn cameras_json_reads_in_file_order_with_hand_values() {
    let cams = read_cameras_json(&fixture("cameras.json")).unwrap();
    let names: Vec<&str> = cams.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["b_front", "a_side"]);
    // The same camera as COLMAP's image 1 (module docs of the COLMAP test): (395, 322.5).
    let (uv, _) = cams[0].1.project(Vec3::new(-1.0, 0.5, 0.2)).unwrap();
    assert!(
        (uv - Vec2::new(395.0, 322.5)).abs().max_element() < PIXEL_TOL,
        "{uv}"
    );
    let side = &cams[1].1;
    assert_eq!(side.t, Vec3::new(0.0, 0.0, 2.0));
    assert_eq!(side.dist, [-0.1, 0.01, 0.0, 0.0, 0.0]);
    assert_eq!((side.width, side.height), (512, 512));
}

#[test]
fn cameras_json_round_trips_exactly() {
    let dir = temp_dir("json");
    let mut cams = read_cameras_json(&fixture("cameras.json")).unwrap();
    cams.push((
        "Camera_B10".into(),
        Camera::look_at(
            Vec3::new(0.3, 1.1, 2.9),
            Vec3::ZERO,
            Vec3::Y,
            777.7,
            778.1,
            300,
            200,
        )
        .unwrap(),
    ));
    let path = dir.join("cameras.json");
    write_cameras_json(&path, &cams).unwrap();
    assert_eq!(read_cameras_json(&path).unwrap(), cams);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_cameras_json_is_refused_naming_the_file_and_field() {
    let cases: [(&str, &[&str]); 7] = [
        (
            "cameras_missing_t.json",
            &["cameras.a_side.T", "no such field", "metres"],
        ),
        (
            "cameras_unknown_key.json",
            &["cameras.a_side.d", "unknown key"],
        ),
        ("cameras_bad_k.json", &["cameras.a_side.K", "3x3"]),
        (
            "cameras_not_rotation.json",
            &["a_side", "orthonormal rotation"],
        ),
        ("cameras_no_cameras.json", &["not valid JSON", "views"]),
        ("cameras_malformed.json", &["not valid JSON"]),
        ("absent.json", &["cannot read"]),
    ];
    for (file, words) in cases {
        assert_error_names(read_cameras_json(&fixture(file)), file, words);
    }
}

// ---------------------------------------------------------------- keypoint map

/// A coarse procedural body, quick to generate.
fn procedural() -> BodyModel {
    ProceduralBody::generate(&ProceduralSpec {
        grid_step_m: 0.02,
        target_vertices: 2500,
        relax_iterations: 1,
        ..ProceduralSpec::default()
    })
    .unwrap()
}

#[test]
fn procedural_landmarks_lie_where_their_names_say() {
    let body = procedural();
    let sources = keypoint_sources(KeypointLayout::Body25, &body);
    assert_eq!(sources.len(), 25);
    assert!(!sources.contains(&KeypointSource::Unmapped));
    assert_eq!(sources[1], KeypointSource::Joint(12)); // Neck
    assert_eq!(sources[8], KeypointSource::Midpoint(1, 2)); // MidHip
    assert_eq!(sources[2], KeypointSource::Joint(17)); // RShoulder: SMPL's right
    assert_eq!(keypoint_sources(KeypointLayout::Body25, &body), sources);

    let rest = body.lbs(&SmplParams::default());
    let p = keypoints_3d(&sources, &rest.vertices, &rest.joints);
    let at = |name: &str| p[KeypointLayout::Body25.index_of(name).unwrap()].unwrap();
    let head = rest.joints[15];
    // Face: in front of the head (+z), eyes above the nose, the left ones at +x.
    assert!(at("Nose").z > head.z + 0.05, "{}", at("Nose"));
    assert!(at("LEye").x > 0.0 && at("REye").x < 0.0);
    assert!(at("LEye").y > at("Nose").y && at("REye").y > at("Nose").y);
    assert!(at("LEar").x > at("LEye").x && at("REar").x < at("REye").x);
    assert!(at("LEar").z < at("LEye").z);
    // Feet: toes in front of the ankle, heel behind, near the sole; the big toe medial.
    for side in ["L", "R"] {
        let ankle = at(&format!("{side}Ankle"));
        let (big, small, heel) = (
            at(&format!("{side}BigToe")),
            at(&format!("{side}SmallToe")),
            at(&format!("{side}Heel")),
        );
        assert!(big.z > ankle.z + 0.08 && small.z > ankle.z + 0.05, "{side}");
        assert!(heel.z < ankle.z && heel.y < ankle.y, "{side}");
        assert!(
            big.x.abs() < small.x.abs(),
            "{side}: big toe {big}, small {small}"
        );
    }
    // COCO-18 has no MidHip and no foot points; everything maps.
    let coco = keypoint_sources(KeypointLayout::Coco18, &body);
    assert_eq!(coco.len(), 18);
    assert!(!coco.contains(&KeypointSource::Unmapped));
}

/// A body of SMPL's vertex count (positions meaningless) takes SMPL's published vertices.
#[test]
fn a_model_with_smpl_topology_takes_the_published_vertices() {
    let n = SMPL_NUM_VERTICES;
    let v_template: Vec<Vec3> = (0..n)
        .map(|i| Vec3::new(i as f32 * 1e-4, 0.0, 0.0))
        .collect();
    let mut w = [0.0f32; 24];
    w[0] = 1.0;
    let model = BodyModel::new(
        v_template,
        Vec::new(),
        vec![0.0; n * 3 * 207],
        (0..24).map(|j| vec![(j as u32, 1.0)]).collect(),
        vec![w; n],
        SMPL_PARENTS.to_vec(),
        vec![[0, 1, 2]],
    )
    .unwrap();
    let sources = keypoint_sources(KeypointLayout::Body25, &model);
    assert_eq!(sources[0], KeypointSource::Vertex(332)); // Nose
    assert_eq!(sources[21], KeypointSource::Vertex(3387)); // LHeel
    assert_eq!(sources[24], KeypointSource::Vertex(6787)); // RHeel
    let landmarks = landmark_vertices(&model);
    for ((name, v), (n2, v2)) in landmarks.iter().zip(SMPL_LANDMARK_VERTICES) {
        assert_eq!((*name, *v), (n2, Some(v2)));
    }
}

#[test]
fn keypoints_3d_follows_each_source() {
    let vertices = [Vec3::X, Vec3::Y];
    let joints = [
        Vec3::ZERO,
        Vec3::new(2.0, 0.0, 0.0),
        Vec3::new(0.0, 4.0, 0.0),
    ];
    let sources = [
        KeypointSource::Joint(2),
        KeypointSource::Vertex(1),
        KeypointSource::Midpoint(1, 2),
        KeypointSource::Unmapped,
        KeypointSource::Vertex(5),
        KeypointSource::Midpoint(0, 9),
    ];
    assert_eq!(
        keypoints_3d(&sources, &vertices, &joints),
        [
            Some(Vec3::new(0.0, 4.0, 0.0)),
            Some(Vec3::Y),
            Some(Vec3::new(1.0, 2.0, 0.0)),
            None,
            None,
            None
        ]
    );
}

// ---------------------------------------------------------------- synth --keypoints

#[path = "own_capture/synth_keypoints.rs"]
mod synth_keypoints;
