//! Render settings a user can predict: visual-hull carving is off unless a config, a model file
//! or a flag turns it on, and a model file keeps the setting it was trained and evaluated with.

use std::path::Path;

use nia_eval::run_settings::RunSettings;
use nia_model::render_options::RenderOptions;
use nia_model::store::model_file::ModelFile;

fn fixture_run() -> serde_json::Value {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/quickstart_tiny.nia");
    ModelFile::read(&path).unwrap().header.run
}

#[test]
fn carving_is_off_unless_asked_for() {
    assert!(!RenderOptions::default().visual_hull);
    assert!(!RenderOptions::exhaustive().visual_hull);
    // A `[render]` section without the key does not carve.
    let options: RenderOptions = toml::from_str("skip_empty_space = true").unwrap();
    assert!(!options.visual_hull);
    let options: RenderOptions = toml::from_str("visual_hull = true").unwrap();
    assert!(options.visual_hull);
    // The removed dilation is an unknown key in a config.
    let err = toml::from_str::<RenderOptions>("hull_dilate_px = 0").unwrap_err();
    assert!(err.to_string().contains("hull_dilate_px"), "{err}");
    // Nor does a section without `hull_body_erode_px` add the body to the masks.
    assert_eq!(options.hull_body_erode_px, None);
    let options: RenderOptions = toml::from_str("hull_body_erode_px = 2").unwrap();
    assert_eq!(options.hull_body_erode_px, Some(2));
}

/// c0's blend weight is F_B's unless a config, a model file or a flag rescales it: a section
/// or a model file without the key blends as the paper does; the key reads as written; a value
/// out of bounds is refused by its key.
#[test]
fn the_blend_is_the_papers_unless_c0s_weight_is_rescaled() {
    assert_eq!(RenderOptions::default().c0_weight_scale, 1.0);
    assert_eq!(RenderOptions::default().c0_scale(), None);
    let options: RenderOptions = toml::from_str("skip_empty_space = true").unwrap();
    assert_eq!(options.c0_scale(), None);
    let options: RenderOptions = toml::from_str("c0_weight_scale = 0.25").unwrap();
    assert_eq!(options.c0_scale(), Some(0.25));
    options.check().unwrap();
    let settings = RunSettings::from_json(&fixture_run()).unwrap();
    assert_eq!(
        settings.render.c0_scale(),
        None,
        "the fixture predates the key"
    );
    for bad in [0.0, -0.5, 1e-4, 2e3, f32::NAN] {
        let options = RenderOptions {
            c0_weight_scale: bad,
            ..RenderOptions::default()
        };
        let err = options.check().unwrap_err();
        assert_eq!(err.key, "c0_weight_scale", "{bad}");
    }
}

/// The committed fixture was trained and evaluated before carving existed: its header's
/// `[render]` has no `visual_hull`, and it loads without carving, as it was evaluated.
#[test]
fn a_model_file_from_before_carving_loads_without_it() {
    let run = fixture_run();
    assert!(
        run["render"].get("visual_hull").is_none(),
        "the fixture predates the key"
    );
    let settings = RunSettings::from_json(&run).unwrap();
    assert!(!settings.render.visual_hull);
    assert_eq!(settings.render.hull_body_erode_px, None);
}

/// A model file written while carving defaulted to on carries the whole `[render]` section
/// (the trainer writes every key), so it keeps carving after this change; one that said off
/// stays off.
#[test]
fn a_model_file_that_carved_keeps_carving() {
    for on in [true, false] {
        let mut run = fixture_run();
        let mut written = serde_json::to_value(RenderOptions {
            visual_hull: on,
            ..RenderOptions::default()
        })
        .unwrap();
        assert!(written.get("visual_hull").is_some(), "every key is written");
        written["empty_space_m"] = run["render"]["empty_space_m"].clone();
        run["render"] = written;
        let settings = RunSettings::from_json(&run).unwrap();
        assert_eq!(settings.render.visual_hull, on);
    }
}
