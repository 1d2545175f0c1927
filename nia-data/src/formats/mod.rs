//! The file formats the datasets and the SMPL model are written in: Python pickles (our own
//! reader, DESIGN.md section 3), `.npy` (plain and object arrays), `.npz`, and the writers the
//! synthetic generator needs to produce files real numpy loads.

pub mod value;

pub use value::{ArrayData, NdArray, PyDict, PyValue};

use std::path::{Path, PathBuf};

/// A format error, always naming the file it came from.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("{path}: cannot read: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {msg}")]
    Invalid { path: PathBuf, msg: String },
}

impl FormatError {
    pub fn invalid(path: &Path, msg: impl Into<String>) -> Self {
        FormatError::Invalid { path: path.to_path_buf(), msg: msg.into() }
    }
}

/// Load `.pkl`, `.npy` or `.npz` by extension. Object `.npy` files (a pickled dict saved with
/// `np.save`) return the pickled value itself (numpy's `.item()`); `.npz` returns a dict of arrays.
pub fn load_any(path: &Path) -> Result<PyValue, FormatError> {
    Err(FormatError::invalid(path, "formats::load_any: not implemented yet"))
}

/// A dense numeric array from an ndarray, a chumpy `Ch` (its state's `x`), or a scipy sparse
/// matrix (`csc_matrix`/`csr_matrix` state `data`, `indices`, `indptr`, `_shape`).
pub fn dense_array(value: &PyValue) -> Option<NdArray> {
    match value {
        PyValue::Array(a) => Some(a.clone()),
        _ => None,
    }
}
