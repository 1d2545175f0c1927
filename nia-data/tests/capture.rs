//! Capture flaws in the generator: off by default and then byte for byte the clean output;
//! each flaw alone changes only the files it is about; a flawed set is described as such and
//! a config that asks for other flaws than a set has is refused naming the key.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use common::files_under;

use nia_data::dataset::{DataConfig, OpenError};
use nia_data::synth::capture::{CaptureFlaws, CapturePreset};
use nia_data::synth::{self, SynthSection, SynthSpec};

/// FNV-1a (64 bit) of `bytes`.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Every file under `root` (relative path with `/`) and its digest.
fn digests(root: &Path) -> BTreeMap<String, u64> {
    files_under(root)
        .into_iter()
        .map(|(rel, bytes)| (rel, fnv1a(&bytes)))
        .collect()
}

fn tiny(capture: CaptureFlaws) -> SynthSpec {
    SynthSpec {
        subjects: 1,
        frames: 3,
        cameras: 3,
        size: 32,
        supersample: 1,
        seed: 5,
        capture,
        ..SynthSpec::default()
    }
}

fn generate(name: &str, spec: &SynthSpec) -> (PathBuf, BTreeMap<String, u64>) {
    let root = std::env::temp_dir().join(format!("nia-capture-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    synth::generate(spec, &root, &mut |_| {}).unwrap();
    let d = digests(&root);
    (root, d)
}

/// The digest of every file of the tiny clean set, as the generator wrote it before capture
/// flaws existed (the generator with flaws, none on, wrote the quickstart's 144-image set
/// byte for byte as the one before it, `diff -r`): the same spec with no flaws must keep
/// writing exactly these bytes. A deliberate change of the clean output updates it. The
/// clothed surface (`clothed_vertices/`, written since) is not among those files.
const CLEAN_DIGEST: u64 = 0x32922a3c25c0eab;

/// One digest of the set's ZJU-MoCap files (paths and file digests in order).
fn set_digest(d: &BTreeMap<String, u64>) -> u64 {
    let mut bytes = Vec::new();
    for (path, h) in d.iter().filter(|(p, _)| !p.contains("/clothed_vertices/")) {
        bytes.extend_from_slice(path.as_bytes());
        bytes.extend_from_slice(&h.to_le_bytes());
    }
    fnv1a(&bytes)
}

#[test]
fn without_flaws_the_generator_writes_the_clean_bytes() {
    let (root, clean) = generate("clean", &tiny(CaptureFlaws::default()));
    assert_eq!(
        set_digest(&clean),
        CLEAN_DIGEST,
        "the clean set's bytes changed: {clean:#x?}"
    );
    let description = std::fs::read_to_string(root.join("synth.json")).unwrap();
    assert!(!description.contains("capture"), "{description}");
    assert!(
        clean.keys().any(|p| p.contains("/clothed_vertices/")),
        "the clothed surface is written"
    );
    let _ = std::fs::remove_dir_all(&root);
}

/// Each flaw alone at level 1 changes exactly the files it is about; the images always show
/// the true body (with hair and loose garments off SMPL when the geometry flaw is on).
#[test]
fn each_flaw_changes_only_its_own_files() {
    let (clean_root, clean) = generate("base", &tiny(CaptureFlaws::default()));
    /// A flaw's name, the flaws at level 1, and which of the written files it may change.
    type FlawCase = (&'static str, CaptureFlaws, fn(&str) -> bool);
    let cases: [FlawCase; 5] = [
        (
            "smpl_fit",
            CaptureFlaws {
                smpl_fit: 1.0,
                ..Default::default()
            },
            |p| p.contains("/params/") || p.contains("/vertices/"),
        ),
        (
            "calibration",
            CaptureFlaws {
                calibration: 1.0,
                ..Default::default()
            },
            |p| p.ends_with("annots.npy"),
        ),
        (
            "colour",
            CaptureFlaws {
                colour: 1.0,
                ..Default::default()
            },
            |p| p.ends_with(".jpg"),
        ),
        (
            "masks",
            CaptureFlaws {
                masks: 1.0,
                ..Default::default()
            },
            |p| p.contains("/mask/"),
        ),
        (
            "geometry",
            CaptureFlaws {
                geometry: 1.0,
                ..Default::default()
            },
            // The images, masks and surface of the body with hair and loose garments; not the
            // SMPL.
            |p| p.ends_with(".jpg") || p.contains("/mask/") || p.contains("/clothed_vertices/"),
        ),
    ];
    for (name, flaws, owns) in cases {
        let (root, flawed) = generate(name, &tiny(flaws));
        let changed: Vec<&String> = flawed
            .iter()
            .filter(|(p, h)| clean.get(*p) != Some(h))
            .map(|(p, _)| p)
            .collect();
        assert!(!changed.is_empty(), "{name}: nothing changed");
        for path in &changed {
            assert!(
                owns(path) || path.as_str() == "synth.json",
                "{name} changed {path}"
            );
        }
        let owned = clean.keys().filter(|p| owns(p)).count();
        let owned_changed = changed.iter().filter(|p| owns(p)).count();
        assert!(
            owned_changed * 2 >= owned,
            "{name}: only {owned_changed} of {owned} of its files changed"
        );
        let _ = std::fs::remove_dir_all(&root);
    }
    let _ = std::fs::remove_dir_all(&clean_root);
}

/// `[synth] capture = "zju_like"` sets every level to 1, a single level overrides it, a
/// level out of range names its key, and a config whose flaws differ from the set at
/// `data.root` is refused naming the key.
#[test]
fn the_preset_its_overrides_and_a_mismatched_set() {
    let section: SynthSection = serde_json::from_value(serde_json::json!({
        "subjects": 1, "frames": 3, "cameras": 3, "size": 32, "seed": 5, "supersample": 1,
        "capture": "zju_like", "mask_level": 2.0
    }))
    .unwrap();
    let flaws = section.capture();
    assert_eq!(
        flaws,
        CaptureFlaws {
            masks: 2.0,
            ..CapturePreset::ZjuLike.flaws()
        }
    );
    let bad = SynthSpec {
        capture: CaptureFlaws {
            colour: 9.0,
            ..flaws
        },
        ..tiny(flaws)
    };
    let err = bad.validate().unwrap_err().to_string();
    assert!(
        err.contains("capture.colour") && err.contains("[0, 4]"),
        "{err}"
    );
    assert_eq!(SynthSection::key("capture.colour"), "synth.colour_level");
    assert_eq!(
        SynthSection::key("capture.geometry"),
        "synth.geometry_level"
    );
    let geometry: SynthSection = serde_json::from_value(serde_json::json!({
        "subjects": 1, "frames": 3, "cameras": 3, "size": 32, "geometry_level": 1.5
    }))
    .unwrap();
    assert_eq!(
        geometry.capture(),
        CaptureFlaws {
            geometry: 1.5,
            ..CaptureFlaws::default()
        }
    );
    let err = SynthSpec {
        capture: CaptureFlaws {
            geometry: f32::NAN,
            ..flaws
        },
        ..tiny(flaws)
    }
    .validate()
    .unwrap_err()
    .to_string();
    assert!(err.contains("capture.geometry"), "{err}");

    // A clean set on disk, a config that asks for the flawed one.
    let (root, _) = generate("described", &tiny(CaptureFlaws::default()));
    let data: DataConfig = serde_json::from_value(serde_json::json!({
        "root": root, "protocol": "synthetic"
    }))
    .unwrap();
    assert!(data.protocol(Some(&tiny(CaptureFlaws::default()))).is_ok());
    let err = data.protocol(Some(&section.spec())).unwrap_err();
    assert!(
        matches!(&err, OpenError::SynthMismatch { key, .. } if key.starts_with("synth.")),
        "{err}"
    );
    assert!(err.to_string().contains("_level"), "{err}");
    // The same set asked for with more people (a config that grew): named, with the way out.
    let more = SynthSpec {
        subjects: tiny(CaptureFlaws::default()).subjects + 1,
        ..tiny(CaptureFlaws::default())
    };
    let err = data.protocol(Some(&more)).unwrap_err().to_string();
    assert!(
        err.contains("synth.json")
            && err.contains("`synth.subjects`")
            && err.contains("delete the folder"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&root);
}
