//! The file formats the datasets and the SMPL model are written in: Python pickles (our own
//! reader, docs/method.md "Data"), `.npy` (plain and object arrays), `.npz`, and the writers the
//! synthetic generator needs to produce files real numpy loads.

pub mod field;
pub mod npy;
pub mod npz;
pub mod pickle;
pub mod pickle_write;
pub mod value;

pub use field::FieldError;
pub use value::{ArrayData, NdArray, PyDict, PyValue};

use std::io::Write;
use std::path::{Path, PathBuf};

use self::npy::NpyError;
use self::pickle::PickleError;

/// A format error, always naming the file it came from.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("{path}: cannot read: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {msg}")]
    Invalid { path: PathBuf, msg: String },
    #[error("{path}: cannot write: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Pickle { path: PathBuf, source: PickleError },
    #[error("{path}: {source}")]
    Npy { path: PathBuf, source: NpyError },
    #[error("{path}: entry '{entry}': {source}")]
    NpzEntry {
        path: PathBuf,
        entry: String,
        source: NpyError,
    },
    #[error("{path}: not a readable .npz (zip) archive: {msg}")]
    Zip { path: PathBuf, msg: String },
    #[error("{path}: unknown extension (expected .pkl, .pickle, .npy or .npz)")]
    UnknownExtension { path: PathBuf },
    #[error("{path}: field '{field}': {source}")]
    Dense {
        path: PathBuf,
        field: String,
        source: Box<DenseError>,
    },
}

impl FormatError {
    pub fn invalid(path: &Path, msg: impl Into<String>) -> Self {
        FormatError::Invalid {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    /// The file this error is about.
    pub fn path(&self) -> &Path {
        match self {
            FormatError::Io { path, .. }
            | FormatError::Invalid { path, .. }
            | FormatError::Write { path, .. }
            | FormatError::Pickle { path, .. }
            | FormatError::Npy { path, .. }
            | FormatError::NpzEntry { path, .. }
            | FormatError::Zip { path, .. }
            | FormatError::UnknownExtension { path }
            | FormatError::Dense { path, .. } => path,
        }
    }
}

/// Read a pickle file (`.pkl`).
pub fn read_pickle_file(path: &Path) -> Result<PyValue, FormatError> {
    let bytes = std::fs::read(path).map_err(|source| FormatError::Io {
        path: path.into(),
        source,
    })?;
    pickle::read_pickle(&bytes).map_err(|source| FormatError::Pickle {
        path: path.into(),
        source,
    })
}

/// Load `.pkl`, `.npy` or `.npz` by extension. Object `.npy` files (a pickled dict saved with
/// `np.save`) return the pickled value itself (numpy's `.item()`); `.npz` returns a dict of arrays.
pub fn load_any(path: &Path) -> Result<PyValue, FormatError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("pkl" | "pickle") => read_pickle_file(path),
        Some("npy") => {
            let array = npy::read(path)?;
            match array.data {
                ArrayData::Object(mut items) if array.shape.is_empty() && items.len() == 1 => {
                    Ok(items.pop().unwrap_or(PyValue::None))
                }
                data => Ok(PyValue::Array(NdArray::new(array.shape, data))),
            }
        }
        Some("npz") => Ok(PyValue::Dict(
            npz::read(path)?
                .into_iter()
                .map(|(name, a)| (PyValue::Str(name), PyValue::Array(a)))
                .collect(),
        )),
        _ => Err(FormatError::UnknownExtension { path: path.into() }),
    }
}

/// Write `bytes` to `path` atomically: a temporary file in the same directory, flushed, then
/// renamed over `path`, so a reader never sees a half-written file.
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), FormatError> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let werr = |source| FormatError::Write {
        path: path.into(),
        source,
    };
    let file_name = path
        .file_name()
        .ok_or_else(|| FormatError::invalid(path, "cannot write: path has no file name"))?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(file_name);
    tmp_name.push(format!(
        ".tmp-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let tmp = dir.join(tmp_name);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(werr(e));
    }
    Ok(())
}

/// Why a value is not a dense numeric array.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DenseError {
    #[error("expected an ndarray, chumpy Ch or scipy csc/csr matrix, found {found}")]
    NotAnArray { found: String },
    #[error("{class}: state has no field '{field}'")]
    MissingField { class: String, field: String },
    #[error("{class}: field '{field}': expected {expected}, found {found}")]
    BadField {
        class: String,
        field: String,
        expected: &'static str,
        found: String,
    },
    #[error("{class}: invalid sparse structure: {msg}")]
    BadSparse { class: String, msg: String },
    #[error("{class}: dense shape {shape:?} exceeds {max} elements")]
    TooLarge {
        class: String,
        shape: Vec<usize>,
        max: usize,
    },
    #[error("chumpy objects nest deeper than {0} levels")]
    TooDeep(usize),
}

/// Largest dense matrix a sparse matrix may expand to (elements). SMPL's J_regressor is
/// 24 x 6890; the cap keeps a corrupt `_shape` from requesting gigabytes.
pub const MAX_DENSE_ELEMENTS: usize = 1 << 28;
/// How many chumpy `Ch` wrappers (`x` holding another `Ch`) are followed.
const MAX_CH_NESTING: usize = 16;

/// A dense numeric array from an ndarray, a chumpy `Ch` (its state's `x`), or a scipy sparse
/// matrix (`csc_matrix`/`csr_matrix` state `data`, `indices`, `indptr`, `_shape`).
pub fn dense_array(value: &PyValue) -> Option<NdArray> {
    dense_array_checked(value).ok()
}

/// [`dense_array`] with the reason when the value is not (or not validly) an array.
///
/// Sparse matrices are validated (indptr monotone from 0 to nnz, indices inside the minor
/// dimension, matching lengths) and expanded with duplicate entries summed, as scipy's
/// `toarray()` does. The dense dtype is that of `data`.
pub fn dense_array_checked(value: &PyValue) -> Result<NdArray, DenseError> {
    dense_at_depth(value, 0)
}

fn dense_at_depth(value: &PyValue, depth: usize) -> Result<NdArray, DenseError> {
    if depth > MAX_CH_NESTING {
        return Err(DenseError::TooDeep(MAX_CH_NESTING));
    }
    match value {
        PyValue::Array(a) if !matches!(a.data, ArrayData::Object(_)) => Ok(a.clone()),
        PyValue::Object { class, state, .. } => {
            let short = class.rsplit('.').next().unwrap_or(class);
            match short {
                "csc_matrix" | "csc_array" => sparse_to_dense(class, state, true),
                "csr_matrix" | "csr_array" => sparse_to_dense(class, state, false),
                _ if class.starts_with("chumpy") || short == "Ch" => {
                    let x = state.get("x").ok_or_else(|| DenseError::MissingField {
                        class: class.clone(),
                        field: "x".into(),
                    })?;
                    dense_at_depth(x, depth + 1)
                }
                _ => Err(DenseError::NotAnArray {
                    found: class.clone(),
                }),
            }
        }
        other => Err(DenseError::NotAnArray {
            found: other.type_name(),
        }),
    }
}

fn sparse_to_dense(class: &str, state: &PyValue, csc: bool) -> Result<NdArray, DenseError> {
    let field = |name: &str| {
        state.get(name).ok_or_else(|| DenseError::MissingField {
            class: class.into(),
            field: name.into(),
        })
    };
    let bad = |name: &str, expected: &'static str, found: &PyValue| DenseError::BadField {
        class: class.into(),
        field: name.into(),
        expected,
        found: found.type_name(),
    };
    let shape_value = field("_shape").or_else(|_| field("shape"))?;
    let shape: Vec<usize> = shape_value
        .as_seq()
        .and_then(|s| {
            s.iter()
                .map(|d| match d {
                    PyValue::Int(n) => usize::try_from(*n).ok(),
                    _ => None,
                })
                .collect::<Option<Vec<usize>>>()
        })
        .filter(|s| s.len() == 2)
        .ok_or_else(|| bad("_shape", "a pair of non-negative ints", shape_value))?;
    let (rows, cols) = (shape[0], shape[1]);
    let numel = rows
        .checked_mul(cols)
        .filter(|&n| n <= MAX_DENSE_ELEMENTS)
        .ok_or_else(|| DenseError::TooLarge {
            class: class.into(),
            shape: shape.clone(),
            max: MAX_DENSE_ELEMENTS,
        })?;
    let index_array = |name: &str| -> Result<Vec<i64>, DenseError> {
        let v = field(name)?;
        v.as_array()
            .filter(|a| {
                !matches!(
                    a.data,
                    ArrayData::Object(_) | ArrayData::F32(_) | ArrayData::F64(_)
                )
            })
            .and_then(|a| a.to_i64_vec())
            .ok_or_else(|| bad(name, "an integer ndarray", v))
    };
    let indices = index_array("indices")?;
    let indptr = index_array("indptr")?;
    let data_value = field("data")?;
    let data = data_value
        .as_array()
        .filter(|a| !matches!(a.data, ArrayData::Object(_)))
        .ok_or_else(|| bad("data", "a numeric ndarray", data_value))?;
    let (major, minor) = if csc { (cols, rows) } else { (rows, cols) };
    let sparse_err = |msg: String| DenseError::BadSparse {
        class: class.into(),
        msg,
    };
    if indptr.len() != major + 1 {
        return Err(sparse_err(format!(
            "indptr has {} entries, expected {} for shape {shape:?}",
            indptr.len(),
            major + 1
        )));
    }
    if indptr.first() != Some(&0) {
        return Err(sparse_err("indptr must start at 0".into()));
    }
    if let Some(w) = indptr.windows(2).position(|w| w[1] < w[0]) {
        return Err(sparse_err(format!(
            "indptr decreases at position {}",
            w + 1
        )));
    }
    let nnz = indptr.last().copied().unwrap_or(0);
    let nnz = usize::try_from(nnz).map_err(|_| sparse_err("negative nnz".into()))?;
    if nnz > indices.len() || nnz > data.data.len() {
        return Err(sparse_err(format!(
            "indptr ends at {nnz} but indices has {} and data {} entries",
            indices.len(),
            data.data.len()
        )));
    }
    // Position in the dense row-major matrix of every stored entry.
    let mut positions = Vec::with_capacity(nnz);
    for m in 0..major {
        let (start, end) = (indptr[m] as usize, indptr[m + 1] as usize);
        for &raw in &indices[start..end] {
            let i = usize::try_from(raw)
                .ok()
                .filter(|&i| i < minor)
                .ok_or_else(|| sparse_err(format!("index {raw} outside 0..{minor}")))?;
            let (r, c) = if csc { (i, m) } else { (m, i) };
            positions.push(r * cols + c);
        }
    }
    macro_rules! scatter {
        ($v:expr, $variant:ident, $zero:expr, $add:expr) => {{
            let mut dense = vec![$zero; numel];
            for (&p, &x) in positions.iter().zip($v.iter()) {
                dense[p] = $add(dense[p], x);
            }
            ArrayData::$variant(dense)
        }};
    }
    let dense = match &data.data {
        ArrayData::F32(v) => scatter!(v, F32, 0.0f32, |a: f32, b: f32| a + b),
        ArrayData::F64(v) => scatter!(v, F64, 0.0f64, |a: f64, b: f64| a + b),
        ArrayData::I8(v) => scatter!(v, I8, 0i8, i8::wrapping_add),
        ArrayData::I16(v) => scatter!(v, I16, 0i16, i16::wrapping_add),
        ArrayData::I32(v) => scatter!(v, I32, 0i32, i32::wrapping_add),
        ArrayData::I64(v) => scatter!(v, I64, 0i64, i64::wrapping_add),
        ArrayData::U8(v) => scatter!(v, U8, 0u8, u8::wrapping_add),
        ArrayData::U16(v) => scatter!(v, U16, 0u16, u16::wrapping_add),
        ArrayData::U32(v) => scatter!(v, U32, 0u32, u32::wrapping_add),
        ArrayData::U64(v) => scatter!(v, U64, 0u64, u64::wrapping_add),
        ArrayData::Bool(v) => scatter!(v, Bool, false, |a: bool, b: bool| a | b),
        ArrayData::Object(_) => return Err(bad("data", "a numeric ndarray", data_value)),
    };
    Ok(NdArray::new(shape, dense))
}
