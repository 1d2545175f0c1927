//! The numpy / pickle formats against files made by real numpy 1.x and 2.x
//! (`scripts/fixtures/make_format_fixtures.py`): exact values (floats bitwise), the writers
//! byte for byte against numpy, a numpy round trip of what we write, and typed errors.

mod bad_input;
mod reading;
mod tagged_json;
mod writing;

pub(crate) use std::path::{Path, PathBuf};
pub(crate) use std::process::Command;

pub(crate) use nia_data::formats::npy::{self, NpyError};
pub(crate) use nia_data::formats::pickle::{read_pickle, PickleError};
pub(crate) use nia_data::formats::{
    dense_array, dense_array_checked, load_any, npz, ArrayData, DenseError, FormatError, NdArray,
    PyValue,
};
pub(crate) use serde_json::{json, Value};

pub(crate) fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/formats")
}

pub(crate) fn expected() -> serde_json::Map<String, Value> {
    let text = std::fs::read_to_string(fixture_dir().join("expected.json")).unwrap();
    match serde_json::from_str(&text).unwrap() {
        Value::Object(m) => m,
        _ => panic!("expected.json is not an object"),
    }
}

/// A scratch directory unique to this process and test.
pub(crate) fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nia-formats-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

pub(crate) use tagged_json::*;
