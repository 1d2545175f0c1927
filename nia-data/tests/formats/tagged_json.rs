//! The tagged JSON of expected.json <-> PyValue, and value comparison.

use super::*;

pub(crate) fn hex_bytes(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
        .collect()
}

pub(crate) fn to_hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

pub(crate) fn items(v: &Value) -> Vec<PyValue> {
    v["items"].as_array().unwrap().iter().map(decode).collect()
}

pub(crate) fn array_from_le(dtype: &str, shape: Vec<usize>, raw: &[u8]) -> NdArray {
    macro_rules! num {
        ($t:ty, $v:ident) => {
            ArrayData::$v(
                raw.chunks_exact(std::mem::size_of::<$t>())
                    .map(|c| <$t>::from_le_bytes(c.try_into().unwrap()))
                    .collect(),
            )
        };
    }
    let data = match dtype {
        "float32" => num!(f32, F32),
        "float64" => num!(f64, F64),
        "int8" => num!(i8, I8),
        "int16" => num!(i16, I16),
        "int32" => num!(i32, I32),
        "int64" => num!(i64, I64),
        "uint8" => num!(u8, U8),
        "uint16" => num!(u16, U16),
        "uint32" => num!(u32, U32),
        "uint64" => num!(u64, U64),
        "bool" => ArrayData::Bool(raw.iter().map(|&b| b != 0).collect()),
        other => panic!("dtype {other}"),
    };
    NdArray::new(shape, data)
}

/// expected.json value -> the PyValue our reader must produce.
pub(crate) fn decode(v: &Value) -> PyValue {
    match v["t"].as_str().unwrap() {
        "none" => PyValue::None,
        "bool" => PyValue::Bool(v["v"].as_bool().unwrap()),
        "int" => PyValue::Int(v["v"].as_i64().unwrap()),
        "float" => PyValue::Float(f64::from_bits(
            u64::from_str_radix(v["bits"].as_str().unwrap(), 16).unwrap(),
        )),
        "str" => PyValue::Str(v["v"].as_str().unwrap().to_string()),
        "bytes" => PyValue::Bytes(hex_bytes(v["hex"].as_str().unwrap())),
        "list" => PyValue::List(items(v)),
        "tuple" => PyValue::Tuple(items(v)),
        "dict" => PyValue::Dict(
            v["items"]
                .as_array()
                .unwrap()
                .iter()
                .map(|kv| (decode(&kv[0]), decode(&kv[1])))
                .collect(),
        ),
        "array" => {
            let shape: Vec<usize> = v["shape"]
                .as_array()
                .unwrap()
                .iter()
                .map(|d| d.as_u64().unwrap() as usize)
                .collect();
            let dtype = v["dtype"].as_str().unwrap();
            if dtype == "object" {
                PyValue::Array(NdArray::new(shape, ArrayData::Object(items(v))))
            } else {
                PyValue::Array(array_from_le(
                    dtype,
                    shape,
                    &hex_bytes(v["hex"].as_str().unwrap()),
                ))
            }
        }
        "object" => PyValue::Object {
            class: v["class"].as_str().unwrap().to_string(),
            args: v["args"].as_array().unwrap().iter().map(decode).collect(),
            state: Box::new(decode(&v["state"])),
        },
        t => panic!("unknown tag {t}"),
    }
}

/// PyValue -> tagged JSON (for the numpy round-trip manifest).
pub(crate) fn encode(v: &PyValue) -> Value {
    match v {
        PyValue::None => json!({"t": "none"}),
        PyValue::Bool(b) => json!({"t": "bool", "v": b}),
        PyValue::Int(n) => json!({"t": "int", "v": n}),
        PyValue::Float(f) => json!({"t": "float", "bits": format!("{:016x}", f.to_bits())}),
        PyValue::Str(s) => json!({"t": "str", "v": s}),
        PyValue::Bytes(b) => json!({"t": "bytes", "hex": to_hex(b)}),
        PyValue::List(x) => json!({"t": "list", "items": x.iter().map(encode).collect::<Vec<_>>()}),
        PyValue::Tuple(x) => {
            json!({"t": "tuple", "items": x.iter().map(encode).collect::<Vec<_>>()})
        }
        PyValue::Dict(p) => {
            json!({"t": "dict", "items": p.iter().map(|(k, v)| json!([encode(k), encode(v)])).collect::<Vec<_>>()})
        }
        PyValue::Array(a) => match &a.data {
            ArrayData::Object(x) => json!({"t": "array", "dtype": "object", "shape": a.shape,
                "items": x.iter().map(encode).collect::<Vec<_>>()}),
            data => json!({"t": "array", "dtype": data.dtype_name(), "shape": a.shape,
                "hex": to_hex(&npy::encode_le(data).unwrap())}),
        },
        other => panic!("no tagged JSON for {}", other.type_name()),
    }
}

/// Structural equality with floats compared bitwise; panics naming the path of a difference.
pub(crate) fn assert_same(actual: &PyValue, expected: &PyValue, path: &str) {
    match (actual, expected) {
        (PyValue::Float(a), PyValue::Float(b)) => {
            assert_eq!(a.to_bits(), b.to_bits(), "{path}: float {a} != {b}")
        }
        (PyValue::List(a), PyValue::List(b)) | (PyValue::Tuple(a), PyValue::Tuple(b)) => {
            assert_eq!(a.len(), b.len(), "{path}: length");
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                assert_same(x, y, &format!("{path}[{i}]"));
            }
        }
        (PyValue::Dict(a), PyValue::Dict(b)) => {
            let ka: Vec<_> = a.iter().map(|(k, _)| k.clone()).collect();
            let kb: Vec<_> = b.iter().map(|(k, _)| k.clone()).collect();
            assert_eq!(ka, kb, "{path}: keys");
            for ((k, x), (_, y)) in a.iter().zip(b) {
                assert_same(x, y, &format!("{path}.{}", k.as_str().unwrap_or("?")));
            }
        }
        (PyValue::Array(a), PyValue::Array(b)) => {
            assert_eq!(a.shape, b.shape, "{path}: shape");
            assert_eq!(a.data.dtype_name(), b.data.dtype_name(), "{path}: dtype");
            assert_eq!(a.data.len(), a.numel(), "{path}: element count");
            match (&a.data, &b.data) {
                (ArrayData::Object(x), ArrayData::Object(y)) => {
                    assert_same(&PyValue::List(x.clone()), &PyValue::List(y.clone()), path)
                }
                (x, y) => assert_eq!(
                    npy::encode_le(x).unwrap(),
                    npy::encode_le(y).unwrap(),
                    "{path}: array bytes"
                ),
            }
        }
        (
            PyValue::Object {
                class: ca,
                args: aa,
                state: sa,
            },
            PyValue::Object {
                class: cb,
                args: ab,
                state: sb,
            },
        ) => {
            assert_eq!(ca, cb, "{path}: class");
            assert_same(
                &PyValue::List(aa.clone()),
                &PyValue::List(ab.clone()),
                &format!("{path}.args"),
            );
            assert_same(sa, sb, &format!("{path}.state"));
        }
        (a, b) => assert_eq!(a, b, "{path}"),
    }
}
