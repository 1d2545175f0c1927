//! Pickle writer: protocol 3, byte for byte what CPython's pickler writes for the same Python
//! value, with numpy arrays reduced as numpy 1.x reduces them
//! (`numpy.core.multiarray._reconstruct` + `BUILD (1, shape, dtype, False, raw)`), so object
//! `.npy` files we write are the files `np.save(path, obj, allow_pickle=True)` writes.
//!
//! Byte-exactness depends on object identity in the Python original, which a value tree does
//! not carry. We follow CPython's sharing rules for the objects numpy and the interpreter share:
//! the globals, builtin dtypes (one per descr), the 1-byte `b'b'` and empty bytes, and strings
//! CPython interns (empty, single latin-1 characters, and ASCII name-like strings such as dict
//! keys written as literals). Every other value is written as a distinct object. A Python value
//! built with other sharing pickles to different bytes that unpickle to the same value.

use std::collections::HashMap;

use super::npy::{checked_numel, encode_le, Dtype, DtypeKind};
use super::{ArrayData, NdArray, PyValue};

/// The protocol numpy 1.17+ uses in `np.save` (`numpy.lib.format.write_array`).
pub const PROTOCOL: u8 = 3;
/// CPython's pickler batches APPENDS/SETITEMS in groups of this many items.
const BATCH_SIZE: usize = 1000;
/// Deepest value nesting written (matches the reader's limit).
const MAX_DEPTH: usize = super::pickle::MAX_DEPTH;

/// Why a value could not be pickled.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PickleWriteError {
    #[error("array shape {shape:?} does not match its {len} elements")]
    ShapeMismatch { shape: Vec<usize>, len: usize },
    #[error("value nests deeper than {MAX_DEPTH} levels")]
    TooDeep,
    #[error("{what} of {len} bytes is too large for protocol 3")]
    TooLarge { what: &'static str, len: usize },
    #[error("cannot pickle {what}: {reason}")]
    Unsupported { what: String, reason: String },
}

/// Objects CPython shares between references (written once, then `BINGET`).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum SharedKey {
    Global(String, String),
    Str(String),
    Bytes(Vec<u8>),
    Dtype(String),
}

/// Pickle a value with protocol 3 (`PROTO 3` ... `STOP`).
pub fn to_pickle_bytes(value: &PyValue) -> Result<Vec<u8>, PickleWriteError> {
    let mut w = Writer {
        out: vec![0x80, PROTOCOL],
        memo_len: 0,
        shared: HashMap::new(),
    };
    w.save(value, 0)?;
    w.out.push(b'.');
    Ok(w.out)
}

struct Writer {
    out: Vec<u8>,
    memo_len: u32,
    shared: HashMap<SharedKey, u32>,
}

/// Strings CPython interns (so equal literals are one object): empty, one latin-1 character,
/// or only ASCII letters, digits and underscores (code-object constants).
fn interned(s: &str) -> bool {
    let mut chars = s.chars();
    match (chars.next(), chars.next()) {
        (None, _) => true,
        (Some(c), None) => (c as u32) < 256,
        _ => s.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_'),
    }
}

impl Writer {
    fn memoize(&mut self) -> u32 {
        let idx = self.memo_len;
        if idx < 256 {
            self.out.extend_from_slice(&[b'q', idx as u8]);
        } else {
            self.out.push(b'r');
            self.out.extend_from_slice(&idx.to_le_bytes());
        }
        self.memo_len += 1;
        idx
    }

    fn get(&mut self, idx: u32) {
        if idx < 256 {
            self.out.extend_from_slice(&[b'h', idx as u8]);
        } else {
            self.out.push(b'j');
            self.out.extend_from_slice(&idx.to_le_bytes());
        }
    }

    /// Write a BINGET if `key` was already written; returns whether it was.
    fn reuse(&mut self, key: &SharedKey) -> bool {
        match self.shared.get(key) {
            Some(&idx) => {
                self.get(idx);
                true
            }
            None => false,
        }
    }

    fn save_int(&mut self, x: i64) {
        if (0..=0xff).contains(&x) {
            self.out.extend_from_slice(&[b'K', x as u8]);
        } else if (0..=0xffff).contains(&x) {
            self.out.push(b'M');
            self.out.extend_from_slice(&(x as u16).to_le_bytes());
        } else if (i32::MIN as i64..=i32::MAX as i64).contains(&x) {
            self.out.push(b'J');
            self.out.extend_from_slice(&(x as i32).to_le_bytes());
        } else {
            // LONG1 with Python's encode_long: (bit_length >> 3) + 1 bytes, little-endian two's
            // complement, dropping a redundant 0xff for negatives.
            let bit_length = 64 - x.unsigned_abs().leading_zeros() as usize;
            let nbytes = (bit_length >> 3) + 1;
            let fill = if x < 0 { 0xffu8 } else { 0 };
            let le = x.to_le_bytes();
            let mut bytes: Vec<u8> = (0..nbytes)
                .map(|i| le.get(i).copied().unwrap_or(fill))
                .collect();
            if x < 0 && nbytes > 1 {
                let n = bytes.len();
                if bytes[n - 1] == 0xff && bytes[n - 2] & 0x80 != 0 {
                    bytes.pop();
                }
            }
            self.out.extend_from_slice(&[0x8a, bytes.len() as u8]);
            self.out.extend_from_slice(&bytes);
        }
    }

    /// `opcode` followed by `len` as protocol 3's 4-byte little-endian length; `what` names the
    /// object in the error when it is too long for that.
    fn put_len32(
        &mut self,
        opcode: u8,
        what: &'static str,
        len: usize,
    ) -> Result<(), PickleWriteError> {
        let n = u32::try_from(len).map_err(|_| PickleWriteError::TooLarge { what, len })?;
        self.out.push(opcode);
        self.out.extend_from_slice(&n.to_le_bytes());
        Ok(())
    }

    fn save_str_fresh(&mut self, s: &str) -> Result<u32, PickleWriteError> {
        let b = s.as_bytes();
        self.put_len32(b'X', "str", b.len())?;
        self.out.extend_from_slice(b);
        Ok(self.memoize())
    }

    fn save_str(&mut self, s: &str) -> Result<(), PickleWriteError> {
        if !interned(s) {
            self.save_str_fresh(s)?;
            return Ok(());
        }
        let key = SharedKey::Str(s.to_string());
        if !self.reuse(&key) {
            let idx = self.save_str_fresh(s)?;
            self.shared.insert(key, idx);
        }
        Ok(())
    }

    fn save_bytes(&mut self, b: &[u8]) -> Result<(), PickleWriteError> {
        // CPython shares the empty and the 1-byte bytes objects.
        let key = (b.len() <= 1).then(|| SharedKey::Bytes(b.to_vec()));
        if let Some(k) = &key {
            if self.reuse(k) {
                return Ok(());
            }
        }
        if b.len() <= 0xff {
            self.out.extend_from_slice(&[b'C', b.len() as u8]);
        } else {
            self.put_len32(b'B', "bytes", b.len())?;
        }
        self.out.extend_from_slice(b);
        let idx = self.memoize();
        if let Some(k) = key {
            self.shared.insert(k, idx);
        }
        Ok(())
    }

    fn save_global(&mut self, module: &str, name: &str) {
        let key = SharedKey::Global(module.to_string(), name.to_string());
        if self.reuse(&key) {
            return;
        }
        self.out.push(b'c');
        self.out.extend_from_slice(module.as_bytes());
        self.out.push(b'\n');
        self.out.extend_from_slice(name.as_bytes());
        self.out.push(b'\n');
        let idx = self.memoize();
        self.shared.insert(key, idx);
    }

    /// A tuple whose elements are written by `items` (CPython's save_tuple for protocol >= 2).
    fn save_tuple_with(
        &mut self,
        len: usize,
        items: impl FnOnce(&mut Self) -> Result<(), PickleWriteError>,
    ) -> Result<(), PickleWriteError> {
        match len {
            0 => {
                self.out.push(b')');
                return Ok(());
            }
            1..=3 => {
                items(self)?;
                self.out.push(0x84 + len as u8); // TUPLE1..TUPLE3
            }
            _ => {
                self.out.push(b'(');
                items(self)?;
                self.out.push(b't');
            }
        }
        self.memoize();
        Ok(())
    }

    fn save_seq_tuple(&mut self, items: &[PyValue], depth: usize) -> Result<(), PickleWriteError> {
        self.save_tuple_with(items.len(), |w| {
            for v in items {
                w.save(v, depth + 1)?;
            }
            Ok(())
        })
    }

    fn save_shape(&mut self, shape: &[usize]) -> Result<(), PickleWriteError> {
        self.save_tuple_with(shape.len(), |w| {
            for &d in shape {
                let d = i64::try_from(d).map_err(|_| PickleWriteError::Unsupported {
                    what: "shape".into(),
                    reason: format!("dimension {d} exceeds i64"),
                })?;
                w.save_int(d);
            }
            Ok(())
        })
    }

    fn save_list(&mut self, items: &[PyValue], depth: usize) -> Result<(), PickleWriteError> {
        self.out.push(b']');
        self.memoize();
        match items.len() {
            0 => {}
            1 => {
                self.save(&items[0], depth + 1)?;
                self.out.push(b'a');
            }
            _ => {
                for batch in items.chunks(BATCH_SIZE) {
                    self.out.push(b'(');
                    for v in batch {
                        self.save(v, depth + 1)?;
                    }
                    self.out.push(b'e');
                }
            }
        }
        Ok(())
    }

    fn save_dict(
        &mut self,
        pairs: &[(PyValue, PyValue)],
        depth: usize,
    ) -> Result<(), PickleWriteError> {
        self.out.push(b'}');
        self.memoize();
        match pairs.len() {
            0 => {}
            1 => {
                self.save(&pairs[0].0, depth + 1)?;
                self.save(&pairs[0].1, depth + 1)?;
                self.out.push(b's');
            }
            _ => {
                for batch in pairs.chunks(BATCH_SIZE) {
                    self.out.push(b'(');
                    for (k, v) in batch {
                        self.save(k, depth + 1)?;
                        self.save(v, depth + 1)?;
                    }
                    self.out.push(b'u');
                }
            }
        }
        Ok(())
    }

    /// `numpy.dtype(typestr, False, True)` + `BUILD (3, order, None, None, None, elsize,
    /// alignment, flags)`; builtin dtypes are singletons in numpy, so each descr is written once.
    fn save_dtype(&mut self, dtype: &Dtype) -> Result<(), PickleWriteError> {
        let key = SharedKey::Dtype(dtype.descr());
        if self.reuse(&key) {
            return Ok(());
        }
        self.save_global("numpy", "dtype");
        self.save_tuple_with(3, |w| {
            w.save_str_fresh(&dtype.pickle_typestr())?;
            w.out.push(0x89); // align=False
            w.out.push(0x88); // copy=True
            Ok(())
        })?;
        self.out.push(b'R');
        let idx = self.memoize();
        self.shared.insert(key, idx);
        // Flexible dtypes carry their element size and alignment; numeric ones -1, -1.
        let (elsize, alignment) = match dtype.kind {
            DtypeKind::Unicode => (dtype.itemsize as i64, 4),
            DtypeKind::Bytes => (dtype.itemsize as i64, 1),
            _ => (-1, -1),
        };
        // NPY_OBJECT_DTYPE_FLAGS for object, 8 (NPY_USE_GETITEM) for unicode, else 0.
        let flags = match dtype.kind {
            DtypeKind::Object => 63,
            DtypeKind::Unicode => 8,
            _ => 0,
        };
        self.save_tuple_with(8, |w| {
            w.save_int(3);
            w.save_str(&dtype.order_char().to_string())?;
            w.out.extend_from_slice(b"NNN");
            w.save_int(elsize);
            w.save_int(alignment);
            w.save_int(flags);
            Ok(())
        })?;
        self.out.push(b'b');
        Ok(())
    }

    /// numpy 1.x `ndarray.__reduce__`: `_reconstruct(ndarray, (0,), b'b')` then
    /// `BUILD (1, shape, dtype, is_fortran=False, raw bytes or list of objects)`.
    fn save_array(&mut self, a: &NdArray, depth: usize) -> Result<(), PickleWriteError> {
        if checked_numel(&a.shape) != Some(a.data.len()) {
            return Err(PickleWriteError::ShapeMismatch {
                shape: a.shape.clone(),
                len: a.data.len(),
            });
        }
        self.save_global("numpy.core.multiarray", "_reconstruct");
        self.save_tuple_with(3, |w| {
            w.save_global("numpy", "ndarray");
            w.save_tuple_with(1, |w| {
                w.save_int(0);
                Ok(())
            })?;
            w.save_bytes(b"b")
        })?;
        self.out.push(b'R');
        self.memoize();
        let dtype = Dtype::of(&a.data);
        self.save_tuple_with(5, |w| {
            w.save_int(1);
            w.save_shape(&a.shape)?;
            w.save_dtype(&dtype)?;
            w.out.push(0x89); // is_fortran=False: we always hold C order
            match &a.data {
                ArrayData::Object(items) => w.save_list(items, depth + 1),
                data => {
                    let raw = encode_le(data).map_err(|reason| PickleWriteError::Unsupported {
                        what: "array".into(),
                        reason,
                    })?;
                    w.save_bytes(&raw)
                }
            }
        })?;
        self.out.push(b'b');
        Ok(())
    }

    fn save_object(
        &mut self,
        class: &str,
        args: &[PyValue],
        state: &PyValue,
        depth: usize,
    ) -> Result<(), PickleWriteError> {
        if class == "numpy.dtype" {
            if let Some(PyValue::Str(descr)) = args.first() {
                let dtype =
                    Dtype::parse(descr).map_err(|reason| PickleWriteError::Unsupported {
                        what: format!("numpy.dtype({descr:?})"),
                        reason,
                    })?;
                return self.save_dtype(&dtype);
            }
        }
        let (module, name) = class.rsplit_once('.').unwrap_or(("builtins", class));
        self.save_global(module, name);
        self.save_seq_tuple(args, depth)?;
        // Sets pickle as set(list) via REDUCE; class instances via NEWOBJ (protocol 2+).
        let is_set = matches!(class, "builtins.set" | "builtins.frozenset");
        self.out.push(if is_set { b'R' } else { 0x81 });
        self.memoize();
        if *state != PyValue::None {
            self.save(state, depth + 1)?;
            self.out.push(b'b');
        }
        Ok(())
    }

    fn save(&mut self, value: &PyValue, depth: usize) -> Result<(), PickleWriteError> {
        if depth > MAX_DEPTH {
            return Err(PickleWriteError::TooDeep);
        }
        match value {
            PyValue::None => self.out.push(b'N'),
            PyValue::Bool(true) => self.out.push(0x88),
            PyValue::Bool(false) => self.out.push(0x89),
            PyValue::Int(x) => self.save_int(*x),
            PyValue::Float(f) => {
                self.out.push(b'G');
                self.out.extend_from_slice(&f.to_be_bytes());
            }
            PyValue::Str(s) => self.save_str(s)?,
            PyValue::Bytes(b) => self.save_bytes(b)?,
            PyValue::List(items) => self.save_list(items, depth)?,
            PyValue::Tuple(items) => self.save_seq_tuple(items, depth)?,
            PyValue::Dict(pairs) => self.save_dict(pairs, depth)?,
            PyValue::Array(a) => self.save_array(a, depth)?,
            PyValue::Global { module, name } => self.save_global(module, name),
            PyValue::Object { class, args, state } => {
                self.save_object(class, args, state, depth)?
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::pickle::read_pickle;

    #[test]
    fn long_ints_round_trip_through_our_reader() {
        for x in [
            0i64,
            255,
            256,
            65535,
            65536,
            -1,
            -129,
            i32::MAX as i64 + 1,
            i32::MIN as i64 - 1,
            4_294_967_295,
            i64::MAX,
            i64::MIN,
            -(1 << 40),
            (1 << 55) - 1,
        ] {
            let bytes = to_pickle_bytes(&PyValue::Int(x)).unwrap();
            assert_eq!(read_pickle(&bytes).unwrap(), PyValue::Int(x), "{x}");
        }
    }

    #[test]
    fn encode_long_matches_python() {
        // pickle.dumps(2**31, 3)[2:-1] == b'\x8a\x05\x00\x00\x00\x80\x00'
        let b = to_pickle_bytes(&PyValue::Int(1 << 31)).unwrap();
        assert_eq!(&b[2..b.len() - 1], b"\x8a\x05\x00\x00\x00\x80\x00");
        // pickle.dumps(-2**31 - 1, 3)[2:-1] == b'\x8a\x05\xff\xff\xff\x7f\xff'
        let b = to_pickle_bytes(&PyValue::Int(-(1 << 31) - 1)).unwrap();
        assert_eq!(&b[2..b.len() - 1], b"\x8a\x05\xff\xff\xff\x7f\xff");
        // pickle.dumps(-2**63, 3)[2:-1] == b'\x8a\x08' + 7 zero bytes + b'\x80'
        let b = to_pickle_bytes(&PyValue::Int(i64::MIN)).unwrap();
        assert_eq!(
            &b[2..b.len() - 1],
            b"\x8a\x08\x00\x00\x00\x00\x00\x00\x00\x80"
        );
    }
}
