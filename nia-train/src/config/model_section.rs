//! `[model]`: the network config given as a preset and the keys written over it.

use nia_model::ModelConfig;
use serde::{Deserialize, Serialize};

/// Network preset the `[model]` keys start from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelPreset {
    /// The paper's sizes ([`ModelConfig::new`]).
    Paper,
    /// Narrow layers for CPU runs and tests ([`ModelConfig::tiny`]).
    Tiny,
}

/// `[model]`: the network config ([`ModelConfig`], nested as it is) given as a preset
/// (`preset = "paper"` by default, or `"tiny"`) and any of its keys on top, nested sections
/// included (`[model.body_volume]`). A key the network config does not have, or a value of the
/// wrong type, is an error naming `model.<key>`. A saved run config holds the resolved network
/// (every key), which reads back to the same network.
pub(super) fn model_from_preset<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<ModelConfig, D::Error> {
    use serde::de::Error;
    let mut keys = serde_json::Map::deserialize(d)?;
    let preset = match keys.remove("preset") {
        None => ModelPreset::Paper,
        Some(value) => serde_json::from_value(value)
            .map_err(|e| D::Error::custom(format!("key `model.preset`: {e}")))?,
    };
    let base = match preset {
        ModelPreset::Paper => ModelConfig::new(),
        ModelPreset::Tiny => ModelConfig::tiny(),
    };
    let base = serde_json::to_value(&base).map_err(D::Error::custom)?;
    let mut merged = base.clone();
    merge_keys(&mut merged, keys.clone(), "model").map_err(D::Error::custom)?;
    serde_json::from_value(merged).map_err(|e| {
        // Name the key: the first one that fails on its own over the preset.
        let culprit = keys.into_iter().find_map(|(key, value)| {
            let mut trial = base.clone();
            let one = serde_json::Map::from_iter([(key.clone(), value)]);
            merge_keys(&mut trial, one, "model").ok()?;
            serde_json::from_value::<ModelConfig>(trial)
                .err()
                .map(|e| format!("key `model.{key}`: {e}"))
        });
        D::Error::custom(culprit.unwrap_or_else(|| format!("`model`: {e}")))
    })
}

/// Writes `keys` over the object `base`, recursing into nested objects; every key must
/// already exist in `base` (`path` names the section in the message).
fn merge_keys(
    base: &mut serde_json::Value,
    keys: serde_json::Map<String, serde_json::Value>,
    path: &str,
) -> Result<(), String> {
    let Some(object) = base.as_object_mut() else {
        return Err(format!("`{path}` is not a section"));
    };
    for (key, value) in keys {
        let Some(slot) = object.get_mut(&key) else {
            let mut known: Vec<&str> = object.keys().map(String::as_str).collect();
            known.sort_unstable();
            return Err(format!(
                "unknown key `{path}.{key}`, expected one of `preset`, `{}`",
                known.join("`, `")
            ));
        };
        match value {
            // A tagged enum (`ray_sampler = { kind = "band", margin_m = 0.08 }`) given another
            // kind than the preset's is a new value: its fields are not the preset's.
            serde_json::Value::Object(inner) if slot.is_object() && !changes_kind(slot, &inner) => {
                merge_keys(slot, inner, &format!("{path}.{key}"))?
            }
            value => *slot = value,
        }
    }
    Ok(())
}

/// Whether `keys` name a `kind` other than the one of the tagged enum `slot`.
fn changes_kind(
    slot: &serde_json::Value,
    keys: &serde_json::Map<String, serde_json::Value>,
) -> bool {
    match (slot.get("kind"), keys.get("kind")) {
        (Some(was), Some(now)) => was != now,
        _ => false,
    }
}
