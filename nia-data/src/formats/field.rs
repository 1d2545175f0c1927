//! The error of one field of a file (an array of a `.npy`, a key of a JSON object): the file,
//! the field, what was expected there and what was found. The dataset readers' and the
//! own-capture readers' errors both carry it.

use std::path::PathBuf;

/// A field of a file that is missing or holds the wrong type, shape or value.
#[derive(Debug, thiserror::Error)]
#[error("{}: `{field}`: expected {expected}, found {found}", path.display())]
pub struct FieldError {
    pub path: PathBuf,
    pub field: String,
    pub expected: String,
    pub found: String,
}

impl FieldError {
    /// The error of `field` of the file `path`.
    pub fn new(
        path: impl Into<PathBuf>,
        field: impl Into<String>,
        expected: impl Into<String>,
        found: impl Into<String>,
    ) -> Self {
        FieldError {
            path: path.into(),
            field: field.into(),
            expected: expected.into(),
            found: found.into(),
        }
    }
}
