//! `PrepareError`: what `nia-train prepare` refuses, naming the file and what was expected.

use std::path::PathBuf;

use nia_data::body::BodyError;
use nia_data::dataset::image_io::ImageIoError;
use nia_data::dataset::DatasetError;
use nia_data::fitting::FitError;
use nia_data::formats::FormatError;
use nia_data::own_capture::OwnCaptureError;

/// Errors of the prepare step. Every input error names the file (or folder) at fault.
#[derive(Debug, thiserror::Error)]
pub enum PrepareError {
    /// A file or folder the layout needs is not there.
    #[error("{}: missing ({expected})", path.display())]
    Missing { path: PathBuf, expected: String },
    /// A file is there but holds something else than expected.
    #[error("{}: {what}", path.display())]
    Invalid { path: PathBuf, what: String },
    #[error(transparent)]
    Body(#[from] BodyError),
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Capture(#[from] OwnCaptureError),
    #[error(transparent)]
    Image(#[from] ImageIoError),
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error("fitting: {0}")]
    Fit(#[from] FitError),
    #[error("{}: {action}: {source}", path.display())]
    Io {
        path: PathBuf,
        action: &'static str,
        source: std::io::Error,
    },
    /// The output subject folder exists and `--overwrite` was not given.
    #[error("{}: already exists (pass --overwrite to replace it)", .0.display())]
    Exists(PathBuf),
    /// A bad command-line value.
    #[error("{0}")]
    Usage(String),
}

impl PrepareError {
    pub(crate) fn io(
        path: impl Into<PathBuf>,
        action: &'static str,
        source: std::io::Error,
    ) -> Self {
        PrepareError::Io {
            path: path.into(),
            action,
            source,
        }
    }

    pub(crate) fn invalid(path: impl Into<PathBuf>, what: impl Into<String>) -> Self {
        PrepareError::Invalid {
            path: path.into(),
            what: what.into(),
        }
    }

    pub(crate) fn missing(path: impl Into<PathBuf>, expected: impl Into<String>) -> Self {
        PrepareError::Missing {
            path: path.into(),
            expected: expected.into(),
        }
    }
}
