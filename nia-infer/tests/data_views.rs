//! `render` (as `view`, `orbit` and `animate`, through the same session) with `--data` and no
//! `--views` takes the default source views from the dataset at `--data`: the committed model
//! was trained on `data/quickstart`, which does not exist where the tests run, and the set at
//! `--data` (another seed, another camera count) brings its own protocol.

use std::path::Path;
use std::process::Command;

use nia_data::dataset::protocol::Protocol;
use nia_data::synth::{self, SynthSpec};

#[test]
fn render_with_data_takes_that_datasets_source_views() {
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/quickstart_tiny.nia");
    let root = std::env::temp_dir().join(format!("nia-data-views-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let spec = SynthSpec {
        subjects: 1,
        frames: 1,
        cameras: 5,
        size: 48,
        seed: 31,
        first_subject_id: 60,
        supersample: 1,
        ..SynthSpec::default()
    };
    synth::generate(&spec, &root.join("set"), &mut |_| {}).unwrap();
    let out = root.join("render");
    let run = Command::new(env!("CARGO_BIN_EXE_nia-infer"))
        .args(["render", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(root.join("set"))
        .args(["--subject", "CoreView_60", "--frame", "0", "--targets", "1"])
        .args(["--samples", "8", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    assert!(!stderr.contains("no dataset here"), "{stderr}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("render.json")).unwrap()).unwrap();
    let views: Vec<u64> = report["views"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    // The set's own protocol's input views for its 5 cameras.
    let protocol = Protocol::synthetic(&spec, 1);
    let expected: Vec<u64> = protocol
        .input_views
        .resolve(5, &[])
        .into_iter()
        .map(|v| v as u64)
        .collect();
    assert_eq!(views, expected);
    assert!(out.join("frame0000_view01.png").is_file());
    let _ = std::fs::remove_dir_all(&root);
}
