//! `.npy` files (numpy's `np.save` format, versions 1.0, 2.0 and 3.0) and the numpy dtypes
//! shared with the pickle reader.
//!
//! Layout: magic `\x93NUMPY`, major and minor version bytes, header length (u16 little-endian for
//! 1.0, u32 for 2.0/3.0), a Python dict literal `{'descr': '<f4', 'fortran_order': False,
//! 'shape': (2, 3), }` padded with spaces and a final newline to a multiple of 64 bytes, then the
//! raw elements. Object arrays (`descr` `|O`) carry a pickle of the whole array instead.

use std::path::Path;

use super::pickle::{read_pickle, PickleError};
use super::pickle_write::{to_pickle_bytes, PickleWriteError};
use super::{write_atomic, ArrayData, FormatError, NdArray, PyValue};

/// The 6-byte magic string every `.npy` file starts with.
pub const MAGIC: &[u8; 6] = b"\x93NUMPY";
/// numpy aligns the end of the header to this many bytes (`numpy.lib.format.ARRAY_ALIGN`).
const ARRAY_ALIGN: usize = 64;
/// Spare header spaces numpy leaves so the first axis can grow in place
/// (`numpy.lib.format.GROWTH_AXIS_MAX_DIGITS`, numpy >= 1.24).
const GROWTH_AXIS_MAX_DIGITS: usize = 21;
/// Nesting limit of the header literal parser (real headers nest two levels).
const MAX_HEADER_DEPTH: usize = 16;

/// Why a `.npy` byte stream could not be decoded (the caller adds the path, see
/// [`FormatError::Npy`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NpyError {
    #[error("not a .npy file: expected magic \\x93NUMPY, found {found:02x?}")]
    BadMagic { found: Vec<u8> },
    #[error("unsupported .npy version {major}.{minor} (expected 1.0, 2.0 or 3.0)")]
    UnsupportedVersion { major: u8, minor: u8 },
    #[error("truncated .npy: {what} needs {expected} bytes, only {found} present")]
    Truncated {
        what: &'static str,
        expected: usize,
        found: usize,
    },
    #[error("bad .npy header: {msg}")]
    Header { msg: String },
    #[error("unsupported dtype '{descr}': {reason}")]
    UnsupportedDtype { descr: String, reason: String },
    #[error(
        "data size mismatch: shape {shape:?} of dtype '{descr}' needs {expected} bytes, \
         file has {found}"
    )]
    SizeMismatch {
        shape: Vec<usize>,
        descr: String,
        expected: usize,
        found: usize,
    },
    #[error("object array payload: {0}")]
    Pickle(#[from] PickleError),
    #[error("object array payload: {msg}")]
    ObjectPayload { msg: String },
    #[error("cannot encode array: {msg}")]
    Encode { msg: String },
}

/// Element kind of a numpy dtype.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DtypeKind {
    Bool,
    Int,
    UInt,
    /// `f2` (decoded widened to f32, exactly), `f4`, `f8`.
    Float,
    /// Python objects (pickled).
    Object,
    /// Fixed-width UTF-32 strings (`<U8`); decoded to `ArrayData::Object` of `PyValue::Str`.
    Unicode,
    /// Fixed-width byte strings (`|S8`); decoded to `ArrayData::Object` of `PyValue::Bytes`.
    Bytes,
}

/// A numpy dtype the readers understand: kind, bytes per element, byte order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dtype {
    pub kind: DtypeKind,
    /// Bytes per element (for `Unicode`, 4 per character; 8 for objects).
    pub itemsize: usize,
    pub big_endian: bool,
}

impl Dtype {
    /// Parse a numpy type string: optional byte order (`<`, `>`, `|`, `=`), kind, size —
    /// `'<f4'`, `'|O'`, `'>i8'`, `'|b1'`, `'<U12'`, or the pickled form `'f4'`, `'O8'`.
    pub fn parse(descr: &str) -> Result<Dtype, String> {
        let mut chars = descr.chars();
        let (order, rest) = match chars.next() {
            Some(c @ ('<' | '>' | '|' | '=')) => (c, chars.as_str()),
            Some(_) => ('=', descr),
            None => return Err("empty type string".into()),
        };
        let big_endian = match order {
            '>' => true,
            '<' => false,
            _ => cfg!(target_endian = "big"),
        };
        let mut rc = rest.chars();
        let kind_char = rc.next().ok_or("missing kind character")?;
        let digits = rc.as_str();
        let size: Option<usize> = if digits.is_empty() {
            None
        } else if digits.bytes().all(|b| b.is_ascii_digit()) && digits.len() <= 9 {
            digits.parse().ok()
        } else {
            return Err(format!("bad size '{digits}'"));
        };
        let (kind, itemsize) = match (kind_char, size) {
            ('b', Some(1)) | ('b', None) | ('?', None) => (DtypeKind::Bool, 1),
            ('i', Some(s @ (1 | 2 | 4 | 8))) => (DtypeKind::Int, s),
            ('u', Some(s @ (1 | 2 | 4 | 8))) => (DtypeKind::UInt, s),
            ('f', Some(s @ (2 | 4 | 8))) => (DtypeKind::Float, s),
            ('O', None) | ('O', Some(8)) | ('O', Some(4)) => (DtypeKind::Object, 8),
            // Zero-width strings would let a tiny file claim any number of elements.
            ('U', Some(n)) if n > 0 => (
                DtypeKind::Unicode,
                n.checked_mul(4).ok_or("unicode width overflows")?,
            ),
            ('S', Some(n)) | ('a', Some(n)) if n > 0 => (DtypeKind::Bytes, n),
            ('U' | 'S' | 'a', _) => return Err("zero-width string dtype".into()),
            ('c' | 'M' | 'm' | 'V', _) => {
                return Err(format!(
                    "kind '{kind_char}' (complex/datetime/void) is not supported"
                ))
            }
            _ => return Err(format!("unknown kind '{kind_char}' with size {size:?}")),
        };
        Ok(Dtype {
            kind,
            itemsize,
            big_endian,
        })
    }

    /// The dtype `write_array` uses for an element storage (native little-endian).
    pub fn of(data: &ArrayData) -> Dtype {
        let (kind, itemsize) = match data {
            ArrayData::F32(_) => (DtypeKind::Float, 4),
            ArrayData::F64(_) => (DtypeKind::Float, 8),
            ArrayData::I8(_) => (DtypeKind::Int, 1),
            ArrayData::I16(_) => (DtypeKind::Int, 2),
            ArrayData::I32(_) => (DtypeKind::Int, 4),
            ArrayData::I64(_) => (DtypeKind::Int, 8),
            ArrayData::U8(_) => (DtypeKind::UInt, 1),
            ArrayData::U16(_) => (DtypeKind::UInt, 2),
            ArrayData::U32(_) => (DtypeKind::UInt, 4),
            ArrayData::U64(_) => (DtypeKind::UInt, 8),
            ArrayData::Bool(_) => (DtypeKind::Bool, 1),
            ArrayData::Object(_) => (DtypeKind::Object, 8),
        };
        Dtype {
            kind,
            itemsize,
            big_endian: false,
        }
    }

    fn kind_char(&self) -> char {
        match self.kind {
            DtypeKind::Bool => 'b',
            DtypeKind::Int => 'i',
            DtypeKind::UInt => 'u',
            DtypeKind::Float => 'f',
            DtypeKind::Object => 'O',
            DtypeKind::Unicode => 'U',
            DtypeKind::Bytes => 'S',
        }
    }

    fn size_number(&self) -> usize {
        match self.kind {
            DtypeKind::Unicode => self.itemsize / 4,
            _ => self.itemsize,
        }
    }

    /// Byte-order character as numpy prints it (`|` where order does not apply).
    pub fn order_char(&self) -> char {
        let single_byte = self.itemsize <= 1
            || matches!(
                self.kind,
                DtypeKind::Object | DtypeKind::Bytes | DtypeKind::Bool
            );
        if single_byte {
            '|'
        } else if self.big_endian {
            '>'
        } else {
            '<'
        }
    }

    /// The `.npy` header `descr`: `'<f4'`, `'|u1'`, `'|b1'`, `'|O'`.
    pub fn descr(&self) -> String {
        match self.kind {
            DtypeKind::Object => "|O".into(),
            _ => format!(
                "{}{}{}",
                self.order_char(),
                self.kind_char(),
                self.size_number()
            ),
        }
    }

    /// The type string numpy's `dtype.__reduce__` pickles: `'f4'`, `'u1'`, `'b1'`, `'O8'`.
    pub fn pickle_typestr(&self) -> String {
        format!("{}{}", self.kind_char(), self.size_number())
    }

    /// Decode `count` elements from raw bytes (`raw.len()` must be `count * itemsize`).
    pub fn decode(&self, raw: &[u8], count: usize) -> Result<ArrayData, String> {
        let expected = count
            .checked_mul(self.itemsize)
            .ok_or_else(|| format!("{count} elements of {} bytes overflow", self.itemsize))?;
        if raw.len() != expected {
            return Err(format!(
                "{count} elements of dtype '{}' need {expected} bytes, found {}",
                self.descr(),
                raw.len()
            ));
        }
        let be = self.big_endian;
        macro_rules! num {
            ($t:ty, $n:expr, $variant:ident) => {{
                let v: Vec<$t> = raw
                    .chunks_exact($n)
                    .map(|c| {
                        let mut b = [0u8; $n];
                        b.copy_from_slice(c);
                        if be {
                            <$t>::from_be_bytes(b)
                        } else {
                            <$t>::from_le_bytes(b)
                        }
                    })
                    .collect();
                ArrayData::$variant(v)
            }};
        }
        Ok(match (self.kind, self.itemsize) {
            (DtypeKind::Bool, _) => ArrayData::Bool(raw.iter().map(|&b| b != 0).collect()),
            (DtypeKind::Int, 1) => ArrayData::I8(raw.iter().map(|&b| b as i8).collect()),
            (DtypeKind::Int, 2) => num!(i16, 2, I16),
            (DtypeKind::Int, 4) => num!(i32, 4, I32),
            (DtypeKind::Int, 8) => num!(i64, 8, I64),
            (DtypeKind::UInt, 1) => ArrayData::U8(raw.to_vec()),
            (DtypeKind::UInt, 2) => num!(u16, 2, U16),
            (DtypeKind::UInt, 4) => num!(u32, 4, U32),
            (DtypeKind::UInt, 8) => num!(u64, 8, U64),
            (DtypeKind::Float, 2) => {
                let ArrayData::U16(bits) = num!(u16, 2, U16) else {
                    return Err("internal: f16 decode".into());
                };
                ArrayData::F32(bits.into_iter().map(f16_to_f32).collect())
            }
            (DtypeKind::Float, 4) => num!(f32, 4, F32),
            (DtypeKind::Float, 8) => num!(f64, 8, F64),
            (DtypeKind::Unicode, size) => {
                let mut out = Vec::with_capacity(count);
                for i in 0..count {
                    let cell = raw.get(i * size..(i + 1) * size).unwrap_or(&[]);
                    let mut s = String::new();
                    for c in cell.chunks_exact(4) {
                        let b = [c[0], c[1], c[2], c[3]];
                        let cp = if be {
                            u32::from_be_bytes(b)
                        } else {
                            u32::from_le_bytes(b)
                        };
                        if cp == 0 {
                            break;
                        }
                        s.push(char::from_u32(cp).ok_or_else(|| {
                            format!("invalid code point {cp:#x} in unicode element {i}")
                        })?);
                    }
                    out.push(PyValue::Str(s));
                }
                ArrayData::Object(out)
            }
            (DtypeKind::Bytes, size) => {
                let mut out = Vec::with_capacity(count);
                for i in 0..count {
                    let cell = raw.get(i * size..(i + 1) * size).unwrap_or(&[]);
                    let end = cell.iter().rposition(|&b| b != 0).map_or(0, |p| p + 1);
                    out.push(PyValue::Bytes(cell[..end].to_vec()));
                }
                ArrayData::Object(out)
            }
            (kind, size) => {
                return Err(format!(
                    "cannot decode raw bytes of kind {kind:?} size {size}"
                ))
            }
        })
    }
}

/// IEEE half to single precision (exact: every f16 value is representable in f32).
fn f16_to_f32(h: u16) -> f32 {
    let sign = ((h >> 15) as u32) << 31;
    let exp = ((h >> 10) & 0x1f) as u32;
    let mant = (h & 0x3ff) as u32;
    let bits = if exp == 0 {
        if mant == 0 {
            sign
        } else {
            // Subnormal: value = mant * 2^-24.
            let v = mant as f32 * (1.0 / 16_777_216.0);
            return if sign != 0 { -v } else { v };
        }
    } else if exp == 0x1f {
        sign | 0x7f80_0000 | (mant << 13)
    } else {
        sign | ((exp + 127 - 15) << 23) | (mant << 13)
    };
    f32::from_bits(bits)
}

/// Little-endian raw bytes of a numeric array (object arrays are an error).
pub fn encode_le(data: &ArrayData) -> Result<Vec<u8>, String> {
    fn flat<T: Copy, const N: usize>(v: &[T], f: impl Fn(T) -> [u8; N]) -> Vec<u8> {
        let mut out = Vec::with_capacity(v.len() * N);
        for &x in v {
            out.extend_from_slice(&f(x));
        }
        out
    }
    Ok(match data {
        ArrayData::F32(v) => flat(v, f32::to_le_bytes),
        ArrayData::F64(v) => flat(v, f64::to_le_bytes),
        ArrayData::I8(v) => flat(v, i8::to_le_bytes),
        ArrayData::I16(v) => flat(v, i16::to_le_bytes),
        ArrayData::I32(v) => flat(v, i32::to_le_bytes),
        ArrayData::I64(v) => flat(v, i64::to_le_bytes),
        ArrayData::U8(v) => v.clone(),
        ArrayData::U16(v) => flat(v, u16::to_le_bytes),
        ArrayData::U32(v) => flat(v, u32::to_le_bytes),
        ArrayData::U64(v) => flat(v, u64::to_le_bytes),
        ArrayData::Bool(v) => v.iter().map(|&b| b as u8).collect(),
        ArrayData::Object(_) => return Err("object arrays have no raw bytes".into()),
    })
}

/// Reorder Fortran-ordered (column-major) elements into C order for `shape`.
/// If `data.len()` is not the product of `shape` the data is returned unchanged (callers
/// validate sizes first).
pub fn fortran_to_c<T: Clone>(data: &[T], shape: &[usize]) -> Vec<T> {
    if shape.len() < 2 || data.is_empty() || checked_numel(shape) != Some(data.len()) {
        return data.to_vec();
    }
    // Fortran strides (in elements): stride[0] = 1, stride[k] = stride[k-1] * shape[k-1].
    let mut strides = vec![1usize; shape.len()];
    for k in 1..shape.len() {
        strides[k] = strides[k - 1].saturating_mul(shape[k - 1]);
    }
    let mut index = vec![0usize; shape.len()];
    let mut out = Vec::with_capacity(data.len());
    let mut offset = 0usize;
    for _ in 0..data.len() {
        match data.get(offset) {
            Some(x) => out.push(x.clone()),
            None => break,
        }
        // Advance the C-order multi-index (last axis fastest), keeping `offset` in step.
        for k in (0..shape.len()).rev() {
            index[k] += 1;
            offset += strides[k];
            if index[k] < shape[k] {
                break;
            }
            offset -= strides[k] * shape[k];
            index[k] = 0;
        }
    }
    out
}

/// Reorder the elements of `data` (Fortran order) into C order.
pub fn array_data_fortran_to_c(data: ArrayData, shape: &[usize]) -> ArrayData {
    match data {
        ArrayData::F32(v) => ArrayData::F32(fortran_to_c(&v, shape)),
        ArrayData::F64(v) => ArrayData::F64(fortran_to_c(&v, shape)),
        ArrayData::I8(v) => ArrayData::I8(fortran_to_c(&v, shape)),
        ArrayData::I16(v) => ArrayData::I16(fortran_to_c(&v, shape)),
        ArrayData::I32(v) => ArrayData::I32(fortran_to_c(&v, shape)),
        ArrayData::I64(v) => ArrayData::I64(fortran_to_c(&v, shape)),
        ArrayData::U8(v) => ArrayData::U8(fortran_to_c(&v, shape)),
        ArrayData::U16(v) => ArrayData::U16(fortran_to_c(&v, shape)),
        ArrayData::U32(v) => ArrayData::U32(fortran_to_c(&v, shape)),
        ArrayData::U64(v) => ArrayData::U64(fortran_to_c(&v, shape)),
        ArrayData::Bool(v) => ArrayData::Bool(fortran_to_c(&v, shape)),
        ArrayData::Object(v) => ArrayData::Object(fortran_to_c(&v, shape)),
    }
}

/// Product of a shape, `None` on overflow.
pub fn checked_numel(shape: &[usize]) -> Option<usize> {
    shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))
}

// ---------------------------------------------------------------------------------------------
// Reading

/// The parsed `.npy` header.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyHeader {
    pub version: (u8, u8),
    pub descr: String,
    pub fortran_order: bool,
    pub shape: Vec<usize>,
    /// Byte offset of the first element.
    pub data_offset: usize,
}

/// Parse the magic, version and header dict of a `.npy` byte stream.
pub fn parse_header(bytes: &[u8]) -> Result<NpyHeader, NpyError> {
    let found_magic = bytes.get(..MAGIC.len()).unwrap_or(bytes);
    if found_magic != MAGIC {
        return Err(NpyError::BadMagic {
            found: found_magic.to_vec(),
        });
    }
    let (major, minor) = match bytes.get(6..8) {
        Some(v) => (v[0], v[1]),
        None => {
            return Err(NpyError::Truncated {
                what: "version",
                expected: 8,
                found: bytes.len(),
            })
        }
    };
    let (len_bytes, utf8) = match (major, minor) {
        (1, 0) => (2usize, false),
        (2, 0) => (4, false),
        (3, 0) => (4, true),
        _ => return Err(NpyError::UnsupportedVersion { major, minor }),
    };
    let len_end = 8 + len_bytes;
    let len_slice = bytes.get(8..len_end).ok_or(NpyError::Truncated {
        what: "header length",
        expected: len_end,
        found: bytes.len(),
    })?;
    let header_len = if len_bytes == 2 {
        u16::from_le_bytes([len_slice[0], len_slice[1]]) as usize
    } else {
        u32::from_le_bytes([len_slice[0], len_slice[1], len_slice[2], len_slice[3]]) as usize
    };
    let data_offset = len_end + header_len;
    let raw = bytes.get(len_end..data_offset).ok_or(NpyError::Truncated {
        what: "header",
        expected: data_offset,
        found: bytes.len(),
    })?;
    let text: String = if utf8 {
        std::str::from_utf8(raw)
            .map_err(|e| NpyError::Header {
                msg: format!("header is not UTF-8: {e}"),
            })?
            .to_string()
    } else {
        raw.iter().map(|&b| b as char).collect() // latin-1
    };
    let dict = HeaderParser {
        s: text.as_bytes(),
        pos: 0,
    }
    .parse_all()?;
    let field = |key: &str| {
        dict.get(key).ok_or_else(|| NpyError::Header {
            msg: format!("missing key '{key}' (expected 'descr', 'fortran_order', 'shape')"),
        })
    };
    let descr = match field("descr")? {
        PyValue::Str(s) => s.clone(),
        other => {
            return Err(NpyError::UnsupportedDtype {
                descr: format!("{other:?}"),
                reason: "structured dtypes are not supported (expected a type string)".into(),
            })
        }
    };
    let fortran_order = match field("fortran_order")? {
        PyValue::Bool(b) => *b,
        other => {
            return Err(NpyError::Header {
                msg: format!(
                    "'fortran_order' must be True or False, found {}",
                    other.type_name()
                ),
            })
        }
    };
    let shape = match field("shape")? {
        PyValue::Tuple(items) => items
            .iter()
            .map(|v| match v {
                PyValue::Int(n) if *n >= 0 => usize::try_from(*n).ok(),
                _ => None,
            })
            .collect::<Option<Vec<usize>>>()
            .ok_or_else(|| NpyError::Header {
                msg: "'shape' must be a tuple of non-negative integers".into(),
            })?,
        other => {
            return Err(NpyError::Header {
                msg: format!("'shape' must be a tuple, found {}", other.type_name()),
            })
        }
    };
    Ok(NpyHeader {
        version: (major, minor),
        descr,
        fortran_order,
        shape,
        data_offset,
    })
}

/// Decode a whole `.npy` byte stream into an array (C order). Object arrays are decoded with
/// the pickle reader and come back as `ArrayData::Object`.
pub fn read_bytes(bytes: &[u8]) -> Result<NdArray, NpyError> {
    let header = parse_header(bytes)?;
    let dtype = Dtype::parse(&header.descr).map_err(|reason| NpyError::UnsupportedDtype {
        descr: header.descr.clone(),
        reason,
    })?;
    let payload = bytes.get(header.data_offset..).unwrap_or(&[]);
    let numel = checked_numel(&header.shape).ok_or_else(|| NpyError::Header {
        msg: format!("shape {:?} overflows", header.shape),
    })?;
    if dtype.kind == DtypeKind::Object {
        return read_object_payload(payload, &header.shape);
    }
    let expected = numel
        .checked_mul(dtype.itemsize)
        .ok_or_else(|| NpyError::Header {
            msg: format!("shape {:?} overflows", header.shape),
        })?;
    if payload.len() != expected {
        return Err(NpyError::SizeMismatch {
            shape: header.shape,
            descr: header.descr,
            expected,
            found: payload.len(),
        });
    }
    let data = dtype
        .decode(payload, numel)
        .map_err(|msg| NpyError::Header { msg })?;
    let data = if header.fortran_order {
        array_data_fortran_to_c(data, &header.shape)
    } else {
        data
    };
    Ok(NdArray::new(header.shape, data))
}

fn read_object_payload(payload: &[u8], shape: &[usize]) -> Result<NdArray, NpyError> {
    match read_pickle(payload)? {
        PyValue::Array(a) if a.shape.as_slice() == shape => Ok(a),
        PyValue::Array(a) => Err(NpyError::ObjectPayload {
            msg: format!(
                "header shape {shape:?} but the pickled array has shape {:?}",
                a.shape
            ),
        }),
        other if shape.is_empty() => Ok(NdArray::new(Vec::new(), ArrayData::Object(vec![other]))),
        other => Err(NpyError::ObjectPayload {
            msg: format!(
                "expected a pickled ndarray of shape {shape:?}, found {}",
                other.type_name()
            ),
        }),
    }
}

/// Read a `.npy` file.
pub fn read(path: &Path) -> Result<NdArray, FormatError> {
    let bytes = std::fs::read(path).map_err(|source| FormatError::Io {
        path: path.into(),
        source,
    })?;
    read_bytes(&bytes).map_err(|source| FormatError::Npy {
        path: path.into(),
        source,
    })
}

/// Minimal parser for the Python literal subset of `.npy` headers: dicts, tuples, lists,
/// quoted strings, integers, `True`, `False`, `None`.
struct HeaderParser<'a> {
    s: &'a [u8],
    pos: usize,
}

impl HeaderParser<'_> {
    fn err(&self, what: &str) -> NpyError {
        NpyError::Header {
            msg: format!("{what} at header byte {}", self.pos),
        }
    }

    fn skip_ws(&mut self) {
        while self
            .s
            .get(self.pos)
            .is_some_and(|b| b.is_ascii_whitespace())
        {
            self.pos += 1;
        }
    }

    fn peek(&mut self) -> Option<u8> {
        self.skip_ws();
        self.s.get(self.pos).copied()
    }

    fn expect(&mut self, c: u8) -> Result<(), NpyError> {
        if self.peek() == Some(c) {
            self.pos += 1;
            Ok(())
        } else {
            Err(self.err(&format!("expected '{}'", c as char)))
        }
    }

    fn parse_all(mut self) -> Result<PyValue, NpyError> {
        let v = self.value(0)?;
        if self.peek().is_some() {
            return Err(self.err("trailing characters after the header dict"));
        }
        if !matches!(v, PyValue::Dict(_)) {
            return Err(NpyError::Header {
                msg: format!("expected a dict, found {}", v.type_name()),
            });
        }
        Ok(v)
    }

    /// Comma-separated items up to `close`; returns the items and whether a comma was seen.
    fn items(&mut self, close: u8, depth: usize) -> Result<(Vec<PyValue>, bool), NpyError> {
        let mut items = Vec::new();
        let mut comma = false;
        loop {
            if self.peek() == Some(close) {
                self.pos += 1;
                return Ok((items, comma));
            }
            items.push(self.value(depth + 1)?);
            match self.peek() {
                Some(b',') => {
                    self.pos += 1;
                    comma = true;
                }
                Some(c) if c == close => {}
                _ => return Err(self.err(&format!("expected ',' or '{}'", close as char))),
            }
        }
    }

    fn value(&mut self, depth: usize) -> Result<PyValue, NpyError> {
        if depth > MAX_HEADER_DEPTH {
            return Err(self.err("header nests too deeply"));
        }
        match self.peek() {
            Some(b'{') => {
                self.pos += 1;
                let mut pairs = Vec::new();
                loop {
                    if self.peek() == Some(b'}') {
                        self.pos += 1;
                        return Ok(PyValue::Dict(pairs));
                    }
                    let k = self.value(depth + 1)?;
                    self.expect(b':')?;
                    let v = self.value(depth + 1)?;
                    pairs.push((k, v));
                    match self.peek() {
                        Some(b',') => self.pos += 1,
                        Some(b'}') => {}
                        _ => return Err(self.err("expected ',' or '}'")),
                    }
                }
            }
            Some(b'(') => {
                self.pos += 1;
                let (items, comma) = self.items(b')', depth)?;
                if items.len() == 1 && !comma {
                    // A parenthesised expression, not a tuple.
                    Ok(items.into_iter().next().unwrap_or(PyValue::None))
                } else {
                    Ok(PyValue::Tuple(items))
                }
            }
            Some(b'[') => {
                self.pos += 1;
                Ok(PyValue::List(self.items(b']', depth)?.0))
            }
            Some(q @ (b'\'' | b'"')) => {
                self.pos += 1;
                let start = self.pos;
                while self.s.get(self.pos).is_some_and(|&b| b != q) {
                    if self.s.get(self.pos) == Some(&b'\\') {
                        return Err(self.err("escapes in header strings are not supported"));
                    }
                    self.pos += 1;
                }
                let body = self
                    .s
                    .get(start..self.pos)
                    .ok_or_else(|| self.err("bad string"))?;
                if self.s.get(self.pos) != Some(&q) {
                    return Err(self.err("unterminated string"));
                }
                self.pos += 1;
                Ok(PyValue::Str(String::from_utf8_lossy(body).into_owned()))
            }
            Some(c) if c.is_ascii_digit() || c == b'-' => {
                let start = self.pos;
                self.pos += 1;
                while self.s.get(self.pos).is_some_and(|b| b.is_ascii_digit()) {
                    self.pos += 1;
                }
                // Python 2 headers may write longs as `3L`.
                let text = std::str::from_utf8(&self.s[start..self.pos]).unwrap_or("");
                if self.s.get(self.pos) == Some(&b'L') {
                    self.pos += 1;
                }
                text.parse::<i64>()
                    .map(PyValue::Int)
                    .map_err(|_| self.err("bad integer"))
            }
            Some(c) if c.is_ascii_alphabetic() => {
                let start = self.pos;
                while self
                    .s
                    .get(self.pos)
                    .is_some_and(|b| b.is_ascii_alphanumeric())
                {
                    self.pos += 1;
                }
                match &self.s[start..self.pos] {
                    b"True" => Ok(PyValue::Bool(true)),
                    b"False" => Ok(PyValue::Bool(false)),
                    b"None" => Ok(PyValue::None),
                    _ => Err(self.err("unknown name")),
                }
            }
            Some(_) => Err(self.err("unexpected character")),
            None => Err(self.err("unexpected end of header")),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Writing

/// numpy's header text for a C-ordered array: `{'descr': '<f4', 'fortran_order': False,
/// 'shape': (2, 3), }` plus the growth-axis spaces, before padding.
fn header_text(descr: &str, shape: &[usize]) -> String {
    let shape_repr = match shape {
        [] => "()".to_string(),
        [n] => format!("({n},)"),
        dims => {
            let parts: Vec<String> = dims.iter().map(|d| d.to_string()).collect();
            format!("({})", parts.join(", "))
        }
    };
    let mut text =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_repr}, }}");
    if let Some(first) = shape.first() {
        let digits = first.to_string().len();
        text.push_str(&" ".repeat(GROWTH_AXIS_MAX_DIGITS.saturating_sub(digits)));
    }
    text
}

/// Magic, version and padded header exactly as `numpy.lib.format` writes them (version 1.0
/// unless the header does not fit a u16 length, then 2.0).
fn wrap_header(text: &str) -> Vec<u8> {
    let hlen = text.len() + 1; // + '\n'
    for (major, len_bytes) in [(1u8, 2usize), (2, 4)] {
        let prefix = MAGIC.len() + 2 + len_bytes;
        let padlen = ARRAY_ALIGN - ((prefix + hlen) % ARRAY_ALIGN);
        let total = hlen + padlen;
        if len_bytes == 2 && total > u16::MAX as usize {
            continue;
        }
        let mut out = Vec::with_capacity(prefix + total);
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&[major, 0]);
        if len_bytes == 2 {
            out.extend_from_slice(&(total as u16).to_le_bytes());
        } else {
            out.extend_from_slice(&(total as u32).to_le_bytes());
        }
        out.extend_from_slice(text.as_bytes());
        out.extend(std::iter::repeat_n(b' ', padlen));
        out.push(b'\n');
        return out;
    }
    Vec::new() // unreachable for headers below 4 GiB
}

/// The bytes `np.save` writes for this array (numeric arrays: little-endian raw data; object
/// arrays: `|O` and a protocol-3 pickle of the array, as numpy 1.x writes).
pub fn to_bytes(array: &NdArray) -> Result<Vec<u8>, NpyError> {
    if checked_numel(&array.shape) != Some(array.data.len()) {
        return Err(NpyError::Encode {
            msg: format!(
                "shape {:?} does not match {} elements",
                array.shape,
                array.data.len()
            ),
        });
    }
    let dtype = Dtype::of(&array.data);
    let mut out = wrap_header(&header_text(&dtype.descr(), &array.shape));
    match &array.data {
        ArrayData::Object(_) => {
            let payload = to_pickle_bytes(&PyValue::Array(array.clone()))
                .map_err(|e: PickleWriteError| NpyError::Encode { msg: e.to_string() })?;
            out.extend_from_slice(&payload);
        }
        data => out.extend_from_slice(&encode_le(data).map_err(|msg| NpyError::Encode { msg })?),
    }
    Ok(out)
}

/// The bytes `np.save(path, value, allow_pickle=True)` writes for a Python object (a dict,
/// list, ...): a 0-d object array whose payload pickles it. An `Array` value is written as the
/// array itself, as `np.save` does.
pub fn object_to_bytes(value: &PyValue) -> Result<Vec<u8>, NpyError> {
    match value {
        PyValue::Array(a) => to_bytes(a),
        other => to_bytes(&NdArray::new(
            Vec::new(),
            ArrayData::Object(vec![other.clone()]),
        )),
    }
}

/// Write an array as `.npy` (atomically: a temporary file in the same directory, then rename).
pub fn write_array(path: &Path, array: &NdArray) -> Result<(), FormatError> {
    let bytes = to_bytes(array).map_err(|source| FormatError::Npy {
        path: path.into(),
        source,
    })?;
    write_atomic(path, &bytes)
}

/// Write a Python value as `np.save(path, value, allow_pickle=True)` does (see
/// [`object_to_bytes`]); atomic like [`write_array`].
pub fn write_object(path: &Path, value: &PyValue) -> Result<(), FormatError> {
    let bytes = object_to_bytes(value).map_err(|source| FormatError::Npy {
        path: path.into(),
        source,
    })?;
    write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fortran_reorder_matches_hand_computed_3d() {
        // shape (2, 3, 2); F-order element (i, j, k) at i + 2 j + 6 k.
        let shape = [2usize, 3, 2];
        let f: Vec<usize> = (0..12).collect();
        let c = fortran_to_c(&f, &shape);
        let mut expected = Vec::new();
        for i in 0..2 {
            for j in 0..3 {
                for k in 0..2 {
                    expected.push(i + 2 * j + 6 * k);
                }
            }
        }
        assert_eq!(c, expected);
    }

    #[test]
    fn f16_conversion_exact() {
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x0001), 5.960_464_5e-8);
        assert_eq!(f16_to_f32(0x7bff), 65504.0);
        assert!(f16_to_f32(0x7e00).is_nan());
        assert_eq!(f16_to_f32(0x7c00), f32::INFINITY);
    }

    #[test]
    fn header_matches_numpy_layout() {
        let bytes = wrap_header(&header_text("<f4", &[2, 3]));
        assert_eq!(bytes.len() % ARRAY_ALIGN, 0);
        let text = std::str::from_utf8(&bytes[10..]).unwrap();
        assert!(text.starts_with("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }"));
        assert!(text.ends_with(" \n"));
    }
}
