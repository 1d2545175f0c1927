//! The error type of the dataset readers. Every variant names the file (or folder) at fault and
//! says what was expected there.

use std::path::PathBuf;

use super::image_io::ImageIoError;
use crate::body::BodyError;
use crate::formats::{FieldError, FormatError};
use crate::geometry::camera::CameraError;
use crate::geometry::raster::MeshError;

/// A dataset reading error.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// The subject folder itself is absent or not a folder.
    #[error("{}: not a subject folder (expected a directory holding annots.npy)", path.display())]
    NotADirectory { path: PathBuf },
    /// A required file or folder is absent.
    #[error("{}: missing ({what})", path.display())]
    Missing { path: PathBuf, what: String },
    /// A file could not be read or decoded.
    #[error(transparent)]
    Format(Box<FormatError>),
    /// An image or mask could not be read or decoded.
    #[error(transparent)]
    Image(#[from] ImageIoError),
    /// A field of a file has the wrong type, shape or value.
    #[error(transparent)]
    Field(#[from] FieldError),
    /// A field holds NaN or infinity.
    #[error("{}: `{field}` holds a non-finite value ({value}) at flat index {index}", path.display())]
    NonFinite {
        path: PathBuf,
        field: String,
        index: usize,
        value: f64,
    },
    /// A camera folder named by `annots['ims']` does not exist.
    #[error(
        "{}: camera folder missing (annots.npy ims[{frame}]['ims'][{camera}] = `{entry}`)",
        folder.display()
    )]
    CameraFolderMissing {
        folder: PathBuf,
        frame: usize,
        camera: usize,
        entry: String,
    },
    /// A frame listed in `annots['ims']` has no image file.
    #[error(
        "{}: image missing for frame {frame}, camera {camera} (annots.npy ims[{frame}]['ims'][{camera}] = `{entry}`)",
        path.display()
    )]
    ImageMissing {
        path: PathBuf,
        frame: usize,
        camera: usize,
        entry: String,
    },
    /// No mask file exists for an image in any of the mask folders.
    #[error("{}: no mask for this image (looked for {looked})", image.display())]
    MaskMissing { image: PathBuf, looked: String },
    /// An image or mask whose size differs from what it must match.
    #[error(
        "{}: {what} is {got_width}x{got_height}, expected {width}x{height} ({reason})",
        path.display()
    )]
    Size {
        path: PathBuf,
        what: &'static str,
        got_width: u32,
        got_height: u32,
        width: u32,
        height: u32,
        reason: String,
    },
    /// A camera in `annots.npy` is not a valid camera.
    #[error("{}: camera {camera}: {source}", path.display())]
    Camera {
        path: PathBuf,
        camera: usize,
        source: CameraError,
    },
    /// The SMPL model could not be loaded or used.
    #[error(transparent)]
    Body(Box<BodyError>),
    /// The SMPL model and the stored vertices disagree on the vertex count.
    #[error(
        "{}: SMPL model has {model_vertices} vertices but {} holds {stored_vertices}",
        model.display(), vertices.display()
    )]
    VertexCount {
        model: PathBuf,
        vertices: PathBuf,
        model_vertices: usize,
        stored_vertices: usize,
    },
    /// A frame or view index outside the subject.
    #[error("{subject}: {what} {index} out of range (the subject has {count})")]
    OutOfRange {
        subject: String,
        what: &'static str,
        index: usize,
        count: usize,
    },
    /// A reader setting that cannot be applied.
    #[error("dataset config `{field}`: expected {expected}, found {found}")]
    Config {
        field: &'static str,
        expected: String,
        found: String,
    },
    /// Visibility could not be computed (the mesh does not fit the faces, or similar).
    #[error("{subject}: frame {frame}, view {view}: visibility: {source}")]
    Visibility {
        subject: String,
        frame: usize,
        view: usize,
        source: MeshError,
    },
    /// A file or folder could not be read or written (cache files, directory listings).
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

impl DatasetError {
    /// A [`DatasetError::Field`] error.
    pub(crate) fn field(
        path: impl Into<PathBuf>,
        field: impl Into<String>,
        expected: impl Into<String>,
        found: impl Into<String>,
    ) -> Self {
        FieldError::new(path, field, expected, found).into()
    }
}

impl From<FormatError> for DatasetError {
    fn from(e: FormatError) -> Self {
        DatasetError::Format(Box::new(e))
    }
}

impl From<BodyError> for DatasetError {
    fn from(e: BodyError) -> Self {
        DatasetError::Body(Box::new(e))
    }
}
