//! `render` (as `view`, `orbit` and `animate`, through the same session) with `--data` and no
//! `--views` takes the default source views from the dataset at `--data`: the committed model
//! was trained on `data/quickstart`, which does not exist where the tests run, and the set at
//! `--data` (another seed, another camera count) brings its own protocol.

mod common;

use std::path::Path;

use common::{json_file, nia_infer, s};
use nia_data::dataset::protocol::Protocol;
use nia_data::synth;

#[test]
fn render_with_data_takes_that_datasets_source_views() {
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/quickstart_tiny.nia");
    let root = std::env::temp_dir().join(format!("nia-data-views-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let spec = common::unseen_spec(60, 1, 5, 48, 31);
    let set = root.join("set");
    synth::generate(&spec, &set, &mut |_| {}).unwrap();
    let out = root.join("render");
    let run = nia_infer(&[
        "render",
        "--model",
        s(&model),
        "--data",
        s(&set),
        "--subject",
        "CoreView_60",
        "--frame",
        "0",
        "--targets",
        "1",
        "--samples",
        "8",
        "--out",
        s(&out),
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    assert!(!stderr.contains("no dataset here"), "{stderr}");
    let report = json_file(&out.join("render.json"));
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
