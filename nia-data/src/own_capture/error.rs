//! The error type of the own-capture readers. Every variant names the file at fault, and where
//! it can the line or the field, and says what was expected there.

use std::path::PathBuf;

use crate::formats::FieldError;
use crate::geometry::camera::CameraError;

/// An own-capture input error (keypoints, cameras).
#[derive(Debug, thiserror::Error)]
pub enum OwnCaptureError {
    /// The file could not be read or written.
    #[error("{}: cannot {action}: {source}", path.display())]
    Io {
        path: PathBuf,
        action: &'static str,
        source: std::io::Error,
    },
    /// The file is not valid JSON.
    #[error("{}: not valid JSON ({expected}): {source}", path.display())]
    Json {
        path: PathBuf,
        expected: &'static str,
        source: serde_json::Error,
    },
    /// A JSON field is missing or holds the wrong type, shape or value.
    #[error(transparent)]
    Field(#[from] FieldError),
    /// A keypoint array holds a number of values no supported layout has.
    #[error(
        "{}: `{field}` holds {values} values: expected 75 (BODY_25: 25 keypoints x (x, y, \
         confidence)) or 54 (COCO-18: 18 x 3)",
        path.display()
    )]
    KeypointCount {
        path: PathBuf,
        field: String,
        values: usize,
    },
    /// A line of a text file (COLMAP) is malformed; `line` counts from 1.
    #[error("{}:{line}: {what}: expected {expected}, found `{found}`", path.display())]
    Line {
        path: PathBuf,
        line: usize,
        what: String,
        expected: String,
        found: String,
    },
    /// A COLMAP camera model the reader does not take.
    #[error(
        "{}:{line}: camera {camera_id} uses the COLMAP model {model}: expected PINHOLE, \
         SIMPLE_PINHOLE or OPENCV (undistort the images, e.g. `colmap image_undistorter`, or \
         re-run the calibration with one of these models)",
        path.display()
    )]
    UnsupportedCameraModel {
        path: PathBuf,
        line: usize,
        camera_id: u32,
        model: String,
    },
    /// An image of `images.txt` refers to a camera `cameras.txt` does not define.
    #[error(
        "{}:{line}: image `{image}` refers to camera id {camera_id}, which {} does not \
         define (defined: {defined:?})",
        path.display(),
        cameras.display()
    )]
    UnknownCamera {
        path: PathBuf,
        line: usize,
        image: String,
        camera_id: u32,
        cameras: PathBuf,
        defined: Vec<u32>,
    },
    /// The values read make no valid camera.
    #[error("{}: camera of `{view}`: {source}", path.display())]
    Camera {
        path: PathBuf,
        view: String,
        source: CameraError,
    },
}

impl OwnCaptureError {
    /// A [`OwnCaptureError::Field`] error.
    pub(crate) fn field(
        path: &std::path::Path,
        field: impl Into<String>,
        expected: impl Into<String>,
        found: impl Into<String>,
    ) -> Self {
        FieldError::new(path, field, expected, found).into()
    }

    /// A [`OwnCaptureError::Line`] error.
    pub(crate) fn line(
        path: &std::path::Path,
        line: usize,
        what: impl Into<String>,
        expected: impl Into<String>,
        found: impl Into<String>,
    ) -> Self {
        OwnCaptureError::Line {
            path: path.to_path_buf(),
            line,
            what: what.into(),
            expected: expected.into(),
            found: found.into(),
        }
    }

    /// A [`OwnCaptureError::Io`] error.
    pub(crate) fn io(path: &std::path::Path, action: &'static str, source: std::io::Error) -> Self {
        OwnCaptureError::Io {
            path: path.to_path_buf(),
            action,
            source,
        }
    }
}

/// A short rendering of a JSON value for an error message (at most ~60 characters).
pub(crate) fn show(value: &serde_json::Value) -> String {
    let text = value.to_string();
    if text.chars().count() > 60 {
        let head: String = text.chars().take(57).collect();
        format!("{head}...")
    } else {
        text
    }
}
