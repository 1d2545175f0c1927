//! The values a pickle (or an object `.npy`) decodes to.
//!
//! Python objects are mapped onto a small tree: scalars, strings, containers, numpy arrays
//! ([`NdArray`], always stored in C order after decoding) and generic objects that carry their
//! class path and `BUILD` state (chumpy `Ch`, scipy `csc_matrix`, ...).

use std::collections::BTreeMap;

/// Element storage of a decoded numpy array, C order.
#[derive(Debug, Clone, PartialEq)]
pub enum ArrayData {
    F32(Vec<f32>),
    F64(Vec<f64>),
    I8(Vec<i8>),
    I16(Vec<i16>),
    I32(Vec<i32>),
    I64(Vec<i64>),
    U8(Vec<u8>),
    U16(Vec<u16>),
    U32(Vec<u32>),
    U64(Vec<u64>),
    Bool(Vec<bool>),
    /// dtype `object`: one Python value per element.
    Object(Vec<PyValue>),
}

impl ArrayData {
    /// Number of elements.
    pub fn len(&self) -> usize {
        match self {
            ArrayData::F32(v) => v.len(),
            ArrayData::F64(v) => v.len(),
            ArrayData::I8(v) => v.len(),
            ArrayData::I16(v) => v.len(),
            ArrayData::I32(v) => v.len(),
            ArrayData::I64(v) => v.len(),
            ArrayData::U8(v) => v.len(),
            ArrayData::U16(v) => v.len(),
            ArrayData::U32(v) => v.len(),
            ArrayData::U64(v) => v.len(),
            ArrayData::Bool(v) => v.len(),
            ArrayData::Object(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// numpy's name for the element type (`float32`, `int64`, `object`, ...).
    pub fn dtype_name(&self) -> &'static str {
        match self {
            ArrayData::F32(_) => "float32",
            ArrayData::F64(_) => "float64",
            ArrayData::I8(_) => "int8",
            ArrayData::I16(_) => "int16",
            ArrayData::I32(_) => "int32",
            ArrayData::I64(_) => "int64",
            ArrayData::U8(_) => "uint8",
            ArrayData::U16(_) => "uint16",
            ArrayData::U32(_) => "uint32",
            ArrayData::U64(_) => "uint64",
            ArrayData::Bool(_) => "bool",
            ArrayData::Object(_) => "object",
        }
    }

    /// Numeric elements widened to f64; `None` for object arrays.
    pub fn to_f64_vec(&self) -> Option<Vec<f64>> {
        Some(match self {
            ArrayData::F32(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::F64(v) => v.clone(),
            ArrayData::I8(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::I16(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::I32(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::I64(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::U8(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::U16(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::U32(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::U64(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::Bool(v) => v.iter().map(|&x| x as u8 as f64).collect(),
            ArrayData::Object(_) => return None,
        })
    }
}

/// A numpy array: shape plus C-ordered elements (`data.len() == shape.iter().product()`).
#[derive(Debug, Clone, PartialEq)]
pub struct NdArray {
    pub shape: Vec<usize>,
    pub data: ArrayData,
}

impl NdArray {
    pub fn new(shape: Vec<usize>, data: ArrayData) -> Self {
        Self { shape, data }
    }

    /// Number of elements implied by the shape.
    pub fn numel(&self) -> usize {
        self.shape.iter().product()
    }

    /// Numeric elements as f32 (C order); `None` for object arrays.
    pub fn to_f32_vec(&self) -> Option<Vec<f32>> {
        match &self.data {
            ArrayData::F32(v) => Some(v.clone()),
            other => other
                .to_f64_vec()
                .map(|v| v.into_iter().map(|x| x as f32).collect()),
        }
    }

    /// Numeric elements as f64 (C order); `None` for object arrays.
    pub fn to_f64_vec(&self) -> Option<Vec<f64>> {
        self.data.to_f64_vec()
    }

    /// Integer elements as i64 (floats with an integral value accepted); `None` otherwise.
    pub fn to_i64_vec(&self) -> Option<Vec<i64>> {
        match &self.data {
            ArrayData::I64(v) => Some(v.clone()),
            ArrayData::F32(_) | ArrayData::F64(_) => {
                let v = self.data.to_f64_vec()?;
                v.iter()
                    .map(|&x| {
                        if x.fract() == 0.0 && x.is_finite() {
                            Some(x as i64)
                        } else {
                            None
                        }
                    })
                    .collect()
            }
            ArrayData::U64(v) => Some(v.iter().map(|&x| x as i64).collect()),
            other => other
                .to_f64_vec()
                .map(|v| v.into_iter().map(|x| x as i64).collect()),
        }
    }
}

/// A decoded Python value.
#[derive(Debug, Clone, PartialEq)]
pub enum PyValue {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    /// `str` (Python 3) or a Python 2 `str` that decoded as UTF-8... see [`PyValue::Bytes`].
    Str(String),
    /// `bytes`, or a Python 2 `str` (SHORT_BINSTRING / BINSTRING), raw.
    Bytes(Vec<u8>),
    List(Vec<PyValue>),
    Tuple(Vec<PyValue>),
    /// Insertion-ordered key/value pairs (keys may be any hashable value).
    Dict(Vec<(PyValue, PyValue)>),
    Array(NdArray),
    /// A global reference (`GLOBAL`/`STACK_GLOBAL`), e.g. a class: `module.name`.
    Global {
        module: String,
        name: String,
    },
    /// An instance of a class the reader knows only by name, with its `BUILD` state
    /// (chumpy `Ch`, scipy sparse matrices, ...). `args` holds the constructor arguments.
    Object {
        class: String,
        args: Vec<PyValue>,
        state: Box<PyValue>,
    },
}

impl PyValue {
    /// `dict[key]` for a string key (str or Python 2 bytes); `None` if not a dict or absent.
    pub fn get(&self, key: &str) -> Option<&PyValue> {
        match self {
            PyValue::Dict(items) => items.iter().find_map(|(k, v)| match k {
                PyValue::Str(s) if s == key => Some(v),
                PyValue::Bytes(b) if b.as_slice() == key.as_bytes() => Some(v),
                _ => None,
            }),
            _ => None,
        }
    }

    /// String keys of a dict, in insertion order.
    pub fn keys(&self) -> Vec<String> {
        match self {
            PyValue::Dict(items) => items
                .iter()
                .filter_map(|(k, _)| match k {
                    PyValue::Str(s) => Some(s.clone()),
                    PyValue::Bytes(b) => Some(String::from_utf8_lossy(b).into_owned()),
                    _ => None,
                })
                .collect(),
            _ => Vec::new(),
        }
    }

    /// Elements of a list or tuple.
    pub fn as_seq(&self) -> Option<&[PyValue]> {
        match self {
            PyValue::List(v) | PyValue::Tuple(v) => Some(v),
            _ => None,
        }
    }

    pub fn as_array(&self) -> Option<&NdArray> {
        match self {
            PyValue::Array(a) => Some(a),
            _ => None,
        }
    }

    /// A string value (str, or Python 2 bytes that are valid UTF-8).
    pub fn as_str(&self) -> Option<&str> {
        match self {
            PyValue::Str(s) => Some(s),
            PyValue::Bytes(b) => std::str::from_utf8(b).ok(),
            _ => None,
        }
    }

    /// Python type name, for error messages.
    pub fn type_name(&self) -> String {
        match self {
            PyValue::None => "None".into(),
            PyValue::Bool(_) => "bool".into(),
            PyValue::Int(_) => "int".into(),
            PyValue::Float(_) => "float".into(),
            PyValue::Str(_) => "str".into(),
            PyValue::Bytes(_) => "bytes".into(),
            PyValue::List(_) => "list".into(),
            PyValue::Tuple(_) => "tuple".into(),
            PyValue::Dict(_) => "dict".into(),
            PyValue::Array(a) => format!("ndarray[{}; {:?}]", a.data.dtype_name(), a.shape),
            PyValue::Global { module, name } => format!("{module}.{name}"),
            PyValue::Object { class, .. } => class.clone(),
        }
    }
}

/// A string-keyed view of a dict, as most dataset files are.
pub type PyDict = BTreeMap<String, PyValue>;
