//! The error type of the body model: construction, loading and procedural generation.

use std::path::{Path, PathBuf};

use crate::formats::FormatError;

/// The "path" of a body model that did not come from a file ([`super::BodyModel::new`]).
pub const IN_MEMORY: &str = "<in-memory body model>";

/// A body model error. Every variant names where the model came from (a file path, or
/// [`IN_MEMORY`]) and the field or key at fault, with the expected shape or value.
#[derive(Debug, thiserror::Error)]
pub enum BodyError {
    /// The file could not be read or decoded (the format error names the file). Boxed: format
    /// errors are large and body errors travel through every `Result` of this module.
    #[error(transparent)]
    Format(Box<FormatError>),
    /// A key the SMPL model needs is absent from the file.
    #[error("{}: body model key `{key}` is missing (keys present: {present})", path.display())]
    MissingKey {
        path: PathBuf,
        key: String,
        present: String,
    },
    /// A field has the wrong type, shape or values.
    #[error("{}: body model field `{field}`: expected {expected}, found {found}", path.display())]
    Field {
        path: PathBuf,
        field: String,
        expected: String,
        found: String,
    },
    /// A procedural body specification that cannot be built.
    #[error("procedural body spec field `{field}`: expected {expected}, found {found}")]
    Spec {
        field: String,
        expected: String,
        found: String,
    },
}

impl From<FormatError> for BodyError {
    fn from(e: FormatError) -> Self {
        BodyError::Format(Box::new(e))
    }
}

impl BodyError {
    /// A [`BodyError::Field`] error for a model built in memory.
    pub(crate) fn field(
        field: impl Into<String>,
        expected: impl Into<String>,
        found: impl Into<String>,
    ) -> Self {
        BodyError::Field {
            path: PathBuf::from(IN_MEMORY),
            field: field.into(),
            expected: expected.into(),
            found: found.into(),
        }
    }

    /// The same error, attributed to the file `path` (for errors raised while validating a
    /// model that was read from that file).
    pub fn with_path(self, path: &Path) -> Self {
        match self {
            BodyError::MissingKey { key, present, .. } => BodyError::MissingKey {
                path: path.to_path_buf(),
                key,
                present,
            },
            BodyError::Field {
                field,
                expected,
                found,
                ..
            } => BodyError::Field {
                path: path.to_path_buf(),
                field,
                expected,
                found,
            },
            other => other,
        }
    }
}
