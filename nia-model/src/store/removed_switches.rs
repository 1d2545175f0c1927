//! Switches nia-rs had and removed because they measured no gain (docs/results.md and
//! docs/robustness.md, "Tried and not kept"). Model files and checkpoints written before their
//! removal still carry them: at their neutral value (what every shipped config set) a key means
//! what the code does now and is dropped; at any other value the file was trained or rendered
//! with a behaviour this build no longer has, and reading it is an error naming the key, never a
//! silent change of what the model renders.

use serde_json::Value;

/// A removed key: its path in a `{ "model": .., "run": .. }` document and whether a value is
/// the neutral one.
struct Removed {
    path: &'static [&'static str],
    neutral: fn(&Value) -> bool,
    /// What it did, for the error.
    what: &'static str,
}

fn null_or_false(v: &Value) -> bool {
    v.is_null() || *v == Value::Bool(false)
}

fn null(v: &Value) -> bool {
    v.is_null()
}

fn zero(v: &Value) -> bool {
    v.as_f64() == Some(0.0)
}

const REMOVED: [Removed; 5] = [
    Removed {
        path: &["model", "visibility_masks"],
        neutral: null_or_false,
        what: "o_n's mask test",
    },
    Removed {
        path: &["model", "visibility_depth_tol_m"],
        neutral: null,
        what: "o_n's depth test",
    },
    Removed {
        path: &["model", "source_colour_balance"],
        neutral: null_or_false,
        what: "the source views' colour balance",
    },
    Removed {
        path: &["run", "render", "hull_dilate_px"],
        neutral: zero,
        what: "masks grown before visual-hull carving",
    },
    Removed {
        path: &["run", "train", "ibr_loss_weight"],
        neutral: zero,
        what: "the IBR-only loss",
    },
];

/// A path as the config names it: `model.visibility_masks`, `render.hull_dilate_px` (the run
/// config's sections are the TOML file's).
fn config_key(path: &[&str]) -> String {
    match path.split_first() {
        Some((&"run", rest)) => rest.join("."),
        _ => path.join("."),
    }
}

/// Drops the removed switches of `doc` (a model file's header or a checkpoint's
/// `config.json`) that hold their neutral value; the first that does not is an error naming
/// its key and value.
pub fn strip_removed_switches(doc: &mut Value) -> Result<(), String> {
    for removed in &REMOVED {
        let (key, parents) = removed
            .path
            .split_last()
            .expect("every removed path names a key");
        let table = parents
            .iter()
            .try_fold(&mut *doc, |table, part| table.get_mut(*part));
        let Some(object) = table.and_then(Value::as_object_mut) else {
            continue;
        };
        let Some(value) = object.get(*key) else {
            continue;
        };
        if !(removed.neutral)(value) {
            return Err(format!(
                "`{}` = {value}: {} was removed from nia-rs (it measured no gain); this file was \
                 trained or rendered with it, so it would render differently here",
                config_key(removed.path),
                removed.what,
            ));
        }
        object.remove(*key);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn neutral_values_are_dropped_and_others_refused_by_key() {
        let mut doc = json!({
            "model": { "visibility_masks": false, "visibility_depth_tol_m": null,
                       "source_colour_balance": null, "d_model": 8 },
            "run": { "render": { "hull_dilate_px": 0, "visual_hull": true },
                     "train": { "ibr_loss_weight": 0.0, "steps": 3 } },
        });
        strip_removed_switches(&mut doc).unwrap();
        assert_eq!(
            doc,
            json!({
                "model": { "d_model": 8 },
                "run": { "render": { "visual_hull": true }, "train": { "steps": 3 } },
            })
        );
        for (path, value) in [
            (["model", "visibility_masks"], json!(true)),
            (["model", "visibility_depth_tol_m"], json!(0.03)),
            (["model", "source_colour_balance"], json!(true)),
            (["render", "hull_dilate_px"], json!(2)),
            (["train", "ibr_loss_weight"], json!(0.5)),
        ] {
            let mut doc = json!({ "model": {}, "run": { "render": {}, "train": {} } });
            let table = if path[0] == "model" {
                &mut doc["model"]
            } else {
                &mut doc["run"][path[0]]
            };
            table[path[1]] = value.clone();
            let err = strip_removed_switches(&mut doc).unwrap_err();
            let key = format!("`{}.{}`", path[0], path[1]);
            assert!(err.starts_with(&format!("{key} = {value}")), "{err}");
        }
        // Documents without the sections are left as they are.
        let mut bare = json!({ "other": 1 });
        strip_removed_switches(&mut bare).unwrap();
        assert_eq!(bare, json!({ "other": 1 }));
    }
}
