//! `nia-train synth --keypoints`: the detector's keypoints of the true body (a module of the
//! own_capture test crate).

use super::*;
use crate::common::files_under;
use nia_data::dataset::zju::{read_annots, read_params};
use nia_data::synth::keypoints::keypoints_path;
use nia_data::synth::{self, KeypointSpec, SynthSpec};

/// Pixel tolerance between a noise-free written keypoint (f32 shortest text) and the
/// projection recomputed from the written body and cameras (f32, mm in annots.npy).
const NOISE_FREE_TOL_PX: f32 = 2e-2;

fn spec(keypoints: Option<KeypointSpec>) -> SynthSpec {
    SynthSpec {
        subjects: 1,
        frames: 2,
        cameras: 4,
        size: 96,
        supersample: 1,
        seed: 11,
        keypoints,
        ..SynthSpec::default()
    }
}

fn generate(name: &str, spec: &SynthSpec) -> PathBuf {
    let root = temp_dir(name);
    synth::generate(spec, &root, &mut |_| {}).unwrap();
    root
}

/// Noise, drops and outliers off: every reported keypoint is the true body's keypoint
/// projected by the written (true) camera, and most are reported.
#[test]
fn noise_free_keypoints_are_the_true_projection() {
    let exact = KeypointSpec {
        noise_px: 0.0,
        drop: 0.0,
        outliers: 0.0,
        ..KeypointSpec::default()
    };
    let root = generate("kp-exact", &spec(Some(exact)));
    let subject = root.join("CoreView_1");
    let body = BodyModel::load(&root.join("body_model.npz")).unwrap();
    let annots = read_annots(&subject.join("annots.npy")).unwrap();
    let sources = keypoint_sources(KeypointLayout::Body25, &body);
    let (mut reported, mut total) = (0, 0);
    for frame in 0..2 {
        let params = read_params(&subject.join(format!("params/{frame}.npy"))).unwrap();
        let posed = body.lbs(&params);
        let truth = keypoints_3d(&sources, &posed.vertices, &posed.joints);
        for (c, cam) in annots.cams.iter().enumerate() {
            let camera = cam.camera(96, 96).unwrap();
            let kp = read_openpose(&keypoints_path(&subject, c, frame))
                .unwrap()
                .unwrap();
            assert_eq!(kp.layout, KeypointLayout::Body25);
            for (k, (p, x)) in kp.points.iter().zip(&truth).enumerate() {
                total += 1;
                if p[2] == 0.0 {
                    assert_eq!(*p, [0.0; 3]);
                    continue;
                }
                reported += 1;
                let (uv, _) = camera.project(x.unwrap()).unwrap();
                let d = (Vec2::new(p[0], p[1]) - uv).abs().max_element();
                assert!(
                    d < NOISE_FREE_TOL_PX,
                    "frame {frame} camera {c} keypoint {k}: {d} px"
                );
                assert!((0.05..=1.0).contains(&p[2]));
            }
        }
    }
    // Occlusion hides some keypoints (the far side's), never most of them.
    assert!(reported * 10 >= total * 6, "{reported} of {total} reported");
    assert!(reported < total, "no keypoint occluded in {total}");
    let _ = std::fs::remove_dir_all(&root);
}

/// The defaults (BODY_25, 2 px, 10% drops, 2% outliers) are deterministic, and turning
/// keypoints on only adds `keypoints/` (and says so in synth.json): every other file is the
/// same bytes, so the set without them is unchanged.
#[test]
fn keypoints_are_deterministic_and_add_only_their_files() {
    let with = spec(Some(KeypointSpec::default()));
    let a = generate("kp-a", &with);
    let b = generate("kp-b", &with);
    let plain = generate("kp-plain", &spec(None));
    let (fa, fb, fp) = (files_under(&a), files_under(&b), files_under(&plain));
    assert_eq!(fa, fb);
    let kp_files: Vec<&String> = fa.keys().filter(|k| k.contains("keypoints/")).collect();
    assert_eq!(kp_files.len(), 2 * 4);
    assert!(!fp.keys().any(|k| k.contains("keypoints")));
    for (name, bytes) in &fp {
        if name != "synth.json" {
            assert_eq!(fa.get(name), Some(bytes), "{name} changed with --keypoints");
        }
    }
    let description = String::from_utf8(fa["synth.json"].clone()).unwrap();
    assert!(description.contains("\"noise_px\": 2.0"), "{description}");
    assert!(!String::from_utf8(fp["synth.json"].clone())
        .unwrap()
        .contains("keypoints"));
    for dir in [a, b, plain] {
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[test]
fn coco18_and_bad_keypoint_specs() {
    let coco = KeypointSpec {
        layout: KeypointLayout::Coco18,
        ..KeypointSpec::default()
    };
    let mut s = spec(Some(coco));
    s.frames = 1;
    s.cameras = 2;
    let root = generate("kp-coco", &s);
    let kp = read_openpose(&keypoints_path(&root.join("CoreView_1"), 1, 0))
        .unwrap()
        .unwrap();
    assert_eq!(kp.layout, KeypointLayout::Coco18);
    assert!(kp.points.iter().filter(|p| p[2] > 0.0).count() >= 6);
    let _ = std::fs::remove_dir_all(&root);
    for (bad, field) in [
        (
            KeypointSpec {
                noise_px: f32::NAN,
                ..coco
            },
            "keypoints.noise_px",
        ),
        (KeypointSpec { drop: 1.5, ..coco }, "keypoints.drop"),
        (
            KeypointSpec {
                outliers: -0.1,
                ..coco
            },
            "keypoints.outliers",
        ),
    ] {
        let err = spec(Some(bad)).validate().unwrap_err().to_string();
        assert!(err.contains(field), "{err}");
    }
}

/// A real detector's habits (`detector_offsets`, `lost_runs`), each against the same set
/// without it: the offsets move the hips, neck and shoulders by a few pixels and leave the face
/// and feet where they were; lost runs take keypoints away in stretches of frames, not one frame
/// at a time, and leave every reported keypoint where it was.
#[test]
fn detector_offsets_and_lost_runs_are_what_they_say() {
    let exact = KeypointSpec {
        noise_px: 0.0,
        drop: 0.0,
        outliers: 0.0,
        ..KeypointSpec::default()
    };
    let with = |kp: KeypointSpec, frames: usize| SynthSpec {
        frames,
        ..spec(Some(kp))
    };
    let read = |root: &Path, camera: usize, frame: usize| {
        read_openpose(&keypoints_path(&root.join("CoreView_1"), camera, frame))
            .unwrap()
            .unwrap()
            .points
    };
    // BODY_25: Neck 1, RShoulder 2, LShoulder 5, MidHip 8, RHip 9, LHip 12; Nose 0, eyes 15-16,
    // toes and heels 19-24 are vertices.
    let moved = [1, 2, 5, 8, 9, 12];
    let plain = generate("kp-plain-offsets", &with(exact, 2));
    let offset = generate(
        "kp-offsets",
        &with(
            KeypointSpec {
                detector_offsets: true,
                ..exact
            },
            2,
        ),
    );
    let mut shifts = Vec::new();
    for camera in 0..4 {
        for frame in 0..2 {
            let (a, b) = (read(&plain, camera, frame), read(&offset, camera, frame));
            for (k, (p, q)) in a.iter().zip(&b).enumerate() {
                if p[2] == 0.0 || q[2] == 0.0 {
                    continue;
                }
                let d = Vec2::new(p[0] - q[0], p[1] - q[1]).length();
                if moved.contains(&k) {
                    shifts.push(d);
                } else {
                    assert_eq!(p, q, "keypoint {k} moved");
                }
            }
        }
    }
    // A few centimetres at 96 px across a ~1.8 m body: about 1-4 px.
    let mean = shifts.iter().sum::<f32>() / shifts.len() as f32;
    assert!(
        shifts.len() > 10 && (0.5..6.0).contains(&mean),
        "{mean} px over {}",
        shifts.len()
    );

    let frames = 16;
    let base = generate("kp-runs-base", &with(exact, frames));
    let runs = generate(
        "kp-runs",
        &with(
            KeypointSpec {
                lost_runs: 0.2,
                ..exact
            },
            frames,
        ),
    );
    let (mut lost, mut stretches) = (0usize, Vec::new());
    for camera in 0..4 {
        for k in 0..25 {
            let mut stretch = 0;
            for frame in 0..frames {
                let (p, q) = (read(&base, camera, frame)[k], read(&runs, camera, frame)[k]);
                if q[2] > 0.0 {
                    assert_eq!(p, q, "a reported keypoint moved");
                }
                if p[2] > 0.0 && q[2] == 0.0 {
                    lost += 1;
                    stretch += 1;
                } else if p[2] > 0.0 {
                    if stretch > 0 {
                        stretches.push(stretch);
                    }
                    stretch = 0;
                }
            }
        }
    }
    let mean_stretch = stretches.iter().sum::<usize>() as f32 / stretches.len().max(1) as f32;
    assert!(lost > 20, "{lost} keypoints lost");
    assert!(
        mean_stretch >= 2.5,
        "lost in stretches of {mean_stretch} frames on average"
    );
    for dir in [plain, offset, base, runs] {
        let _ = std::fs::remove_dir_all(&dir);
    }
}
