//! The numpy / pickle formats against files made by real numpy 1.x and 2.x
//! (`scripts/fixtures/make_format_fixtures.py`): exact values (floats bitwise), the writers
//! byte for byte against numpy, a numpy round trip of what we write, and typed errors.

use std::path::{Path, PathBuf};
use std::process::Command;

use nia_data::formats::npy::{self, NpyError};
use nia_data::formats::pickle::{read_pickle, PickleError};
use nia_data::formats::{
    dense_array, dense_array_checked, load_any, npz, ArrayData, DenseError, FormatError, NdArray,
    PyValue,
};
use serde_json::{json, Value};

fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/formats")
}

fn expected() -> serde_json::Map<String, Value> {
    let text = std::fs::read_to_string(fixture_dir().join("expected.json")).unwrap();
    match serde_json::from_str(&text).unwrap() {
        Value::Object(m) => m,
        _ => panic!("expected.json is not an object"),
    }
}

/// A scratch directory unique to this process and test.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nia-formats-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

// ---------------------------------------------------------------------------------------------
// The tagged JSON of expected.json <-> PyValue

fn hex_bytes(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
        .collect()
}

fn to_hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

fn items(v: &Value) -> Vec<PyValue> {
    v["items"].as_array().unwrap().iter().map(decode).collect()
}

fn array_from_le(dtype: &str, shape: Vec<usize>, raw: &[u8]) -> NdArray {
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
fn decode(v: &Value) -> PyValue {
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
fn encode(v: &PyValue) -> Value {
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
fn assert_same(actual: &PyValue, expected: &PyValue, path: &str) {
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

// ---------------------------------------------------------------------------------------------
// Reading real numpy files

#[test]
fn every_fixture_loads_to_its_expected_value() {
    let exp = expected();
    assert!(exp.len() >= 35, "expected.json lists {} files", exp.len());
    for (name, entry) in &exp {
        let value = load_any(&fixture_dir().join(name)).unwrap_or_else(|e| panic!("{e}"));
        let want = decode(&entry["value"]);
        // A plain .npy array is compared as the array itself.
        assert_same(&value, &want, name);
    }
}

#[test]
fn numpy1_and_numpy2_dicts_decode_identically_with_aliased_array_built() {
    let v1 = load_any(&fixture_dir().join("np1_dict.npy")).unwrap();
    let v2 = load_any(&fixture_dir().join("np2_dict.npy")).unwrap();
    let p2 = load_any(&fixture_dir().join("py3_proto2.pkl")).unwrap();
    assert_same(&v1, &v2, "np1 vs np2");
    assert_same(&v1, &p2, "np1 vs py3 protocol 2");
    // The same array object is referenced from two keys; BUILD filled it for both aliases.
    let a = v1.get("shared_a").unwrap().as_array().unwrap();
    let b = v1.get("shared_b").unwrap().as_array().unwrap();
    assert_eq!(a.shape, vec![2, 3]);
    assert_eq!(a, b);
    let expected: Vec<f32> = (0..6).map(|i| i as f32 * 0.1f32).collect();
    assert_eq!(a.to_f32_vec().unwrap(), expected);
    // Fortran order is converted to C order: element [1, 2, 3] = (12 + 8 + 3) / 7.
    let f = v1.get("fortran").unwrap().as_array().unwrap();
    assert_eq!(f.shape, vec![2, 3, 4]);
    assert_eq!(f.to_f64_vec().unwrap()[23], 23.0 / 7.0);
    assert_eq!(f.to_f64_vec().unwrap()[4], 4.0 / 7.0);
    // Big-endian arrays come out native.
    let be = v1.get("big_endian").unwrap().as_array().unwrap();
    assert_eq!(be.data, ArrayData::F64(vec![0.0, 1.25, 2.5, 3.75, 5.0]));
    let kt = v1.get("kintree_table").unwrap().as_array().unwrap();
    assert_eq!(
        kt.data,
        ArrayData::I64(vec![4294967295, 0, 0, 1, 0, 1, 2, 3])
    );
    // numpy scalars become plain numbers.
    assert_eq!(v1.get("scalar_f64"), Some(&PyValue::Float(2.5)));
    assert_eq!(v1.get("scalar_i64"), Some(&PyValue::Int(-7)));
    assert_eq!(v1.get("scalar_f32"), Some(&PyValue::Float(0.1f32 as f64)));
}

#[test]
fn python2_pickle_has_bytes_keys_and_same_arrays() {
    let v1 = load_any(&fixture_dir().join("np1_dict.npy")).unwrap();
    let py2 = load_any(&fixture_dir().join("py2_style.pkl")).unwrap();
    match &py2 {
        PyValue::Dict(items) => assert_eq!(items[0].0, PyValue::Bytes(b"poses".to_vec())),
        other => panic!("not a dict: {}", other.type_name()),
    }
    for key in [
        "poses",
        "Rh",
        "shared_a",
        "shared_b",
        "fortran",
        "big_endian",
        "kintree_table",
        "strings",
    ] {
        assert_eq!(py2.get(key), v1.get(key), "{key}");
    }
    assert_eq!(
        py2.get("name"),
        Some(&PyValue::Bytes(b"CoreView_313".to_vec()))
    );
    assert_eq!(py2.get("int"), Some(&PyValue::Int(123456789012)));
}

#[test]
fn smpl_like_model_gives_dense_arrays() {
    let exp = expected();
    let entry = &exp["smpl_like.pkl"];
    let model = load_any(&fixture_dir().join("smpl_like.pkl")).unwrap();
    let dense = entry["dense"].as_object().unwrap();
    assert!(dense.len() >= 10);
    for (key, want) in dense {
        let got =
            dense_array_checked(model.get(key).unwrap()).unwrap_or_else(|e| panic!("{key}: {e}"));
        assert_same(&PyValue::Array(got), &decode(want), key);
    }
    // J_regressor: csc 4 x 6; row 3 = [0, 0, 0, 0, 0.25, 0.75].
    let j = dense_array(model.get("J_regressor").unwrap()).unwrap();
    assert_eq!(j.shape, vec![4, 6]);
    assert_eq!(
        j.to_f64_vec().unwrap()[18..24],
        [0.0, 0.0, 0.0, 0.0, 0.25, 0.75]
    );
    match model.get("J_regressor").unwrap() {
        PyValue::Object { class, .. } => assert_eq!(class, "scipy.sparse.csc.csc_matrix"),
        other => panic!("{}", other.type_name()),
    }
    // Nested Ch(Ch(x)).
    let jj = dense_array(model.get("J").unwrap()).unwrap();
    assert_eq!(
        jj.to_f64_vec().unwrap(),
        (0..12).map(f64::from).collect::<Vec<_>>()
    );
    let kt = dense_array(model.get("kintree_table").unwrap()).unwrap();
    assert_eq!(kt.to_i64_vec().unwrap()[0], 4294967295);
    assert_eq!(model.get("bs_style").and_then(|v| v.as_str()), Some("lbs"));
    assert_eq!(model.get("big_long"), Some(&PyValue::Int(4294967295)));
    assert_eq!(model.get("shared_1"), model.get("shared_2"));
    assert_eq!(
        dense_array(model.get("shared_1").unwrap()).unwrap().data,
        ArrayData::F64(vec![7.0, 8.0])
    );
}

#[test]
fn scipy_sparse_matrices_expand_like_toarray() {
    let exp = expected();
    let value = load_any(&fixture_dir().join("sparse.pkl")).unwrap();
    for (key, want) in exp["sparse.pkl"]["dense"].as_object().unwrap() {
        let got = dense_array_checked(value.get(key).unwrap()).unwrap();
        assert_same(&PyValue::Array(got), &decode(want), key);
    }
    // Duplicates are summed: (0,0) holds 1 + 2.
    let dup = dense_array(value.get("csc_duplicates").unwrap()).unwrap();
    assert_eq!(dup.data, ArrayData::F64(vec![3.0, 0.0, 0.0, 3.0]));
}

/// Replace one array in a sparse matrix's state.
fn with_state_field(m: &PyValue, field: &str, new: PyValue) -> PyValue {
    let PyValue::Object { class, args, state } = m.clone() else {
        panic!()
    };
    let PyValue::Dict(mut items) = *state else {
        panic!()
    };
    for (k, v) in items.iter_mut() {
        if k.as_str() == Some(field) {
            *v = new.clone();
        }
    }
    PyValue::Object {
        class,
        args,
        state: Box::new(PyValue::Dict(items)),
    }
}

#[test]
fn corrupt_sparse_matrices_are_typed_errors() {
    let value = load_any(&fixture_dir().join("sparse.pkl")).unwrap();
    let csc = value.get("csc").unwrap();
    let int32 = |v: Vec<i32>| PyValue::Array(NdArray::new(vec![v.len()], ArrayData::I32(v)));
    // Row index 3 is outside the 3 rows.
    let bad = with_state_field(csc, "indices", int32(vec![0, 2, 1, 0, 3, 2]));
    let err = dense_array_checked(&bad).unwrap_err();
    assert!(matches!(err, DenseError::BadSparse { .. }), "{err}");
    assert!(err.to_string().contains("index 3 outside 0..3"), "{err}");
    assert!(dense_array(&bad).is_none());
    // indptr of the wrong length for 4 columns.
    let err =
        dense_array_checked(&with_state_field(csc, "indptr", int32(vec![0, 2, 6]))).unwrap_err();
    assert!(
        err.to_string().contains("indptr has 3 entries, expected 5"),
        "{err}"
    );
    // Decreasing indptr.
    let err = dense_array_checked(&with_state_field(csc, "indptr", int32(vec![0, 3, 2, 4, 6])))
        .unwrap_err();
    assert!(err.to_string().contains("indptr decreases"), "{err}");
    // Old scipy pickles name the shape `shape` instead of `_shape`.
    let PyValue::Object { class, args, state } = csc.clone() else {
        panic!()
    };
    let PyValue::Dict(mut renamed) = *state else {
        panic!()
    };
    for (k, _) in renamed.iter_mut() {
        if k.as_str() == Some("_shape") {
            *k = PyValue::Str("shape".into());
        }
    }
    let old = PyValue::Object {
        class,
        args,
        state: Box::new(PyValue::Dict(renamed)),
    };
    assert_eq!(dense_array(&old), dense_array(csc));
    assert_eq!(dense_array(csc).unwrap().shape, vec![3, 4]);
    // Missing data.
    let PyValue::Object { class, args, .. } = csc.clone() else {
        panic!()
    };
    let empty = PyValue::Object {
        class,
        args,
        state: Box::new(PyValue::Dict(vec![])),
    };
    assert!(matches!(
        dense_array_checked(&empty),
        Err(DenseError::MissingField { .. })
    ));
    // A shape asking for more than MAX_DENSE_ELEMENTS.
    let huge = with_state_field(
        csc,
        "_shape",
        PyValue::Tuple(vec![PyValue::Int(1 << 20), PyValue::Int(1 << 20)]),
    );
    assert!(matches!(
        dense_array_checked(&huge),
        Err(DenseError::TooLarge { .. })
    ));
    assert!(matches!(
        dense_array_checked(&PyValue::Str("x".into())),
        Err(DenseError::NotAnArray { .. })
    ));
}

#[test]
fn npz_archives_read_in_order() {
    let z = npz::read(&fixture_dir().join("savez.npz")).unwrap();
    let names: Vec<&str> = z.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["a", "b", "c"]);
    assert_eq!(z[1].1.data, ArrayData::I64(vec![1, 2, 3]));
    let zc = npz::read(&fixture_dir().join("savez_compressed.npz")).unwrap();
    let arr0 = &zc.iter().find(|(n, _)| n == "arr_0").unwrap().1;
    assert_eq!(
        arr0.to_f64_vec().unwrap(),
        (0..100).map(f64::from).collect::<Vec<_>>()
    );
}

// ---------------------------------------------------------------------------------------------
// Writing

#[test]
fn write_object_reproduces_numpy1_np_save_byte_for_byte() {
    let exp = expected();
    let value = decode(&exp["np1_writer_ref.npy"]["value"]);
    let dir = scratch("writer-ref");
    let path = dir.join("ours.npy");
    npy::write_object(&path, &value).unwrap();
    let ours = std::fs::read(&path).unwrap();
    let numpy = std::fs::read(fixture_dir().join("np1_writer_ref.npy")).unwrap();
    if ours != numpy {
        let at = ours
            .iter()
            .zip(&numpy)
            .position(|(a, b)| a != b)
            .unwrap_or(ours.len().min(numpy.len()));
        panic!(
            "differs at byte {at} (ours {} bytes, numpy {}): ours {:02x?} numpy {:02x?}",
            ours.len(),
            numpy.len(),
            &ours[at..(at + 16).min(ours.len())],
            &numpy[at..(at + 16).min(numpy.len())]
        );
    }
    // And it reads back to the same value.
    assert_same(&load_any(&path).unwrap(), &value, "read back");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn write_array_reproduces_numpy2_np_save_byte_for_byte() {
    let dir = scratch("write-array");
    for name in [
        "f4", "f8", "i1", "i2", "i4", "i8", "u1", "u2", "u4", "u8", "b1", "zero_d", "empty",
    ] {
        let file = format!("dtype_{name}.npy");
        let numpy = std::fs::read(fixture_dir().join(&file)).unwrap();
        let array = npy::read(&fixture_dir().join(&file)).unwrap();
        let path = dir.join(&file);
        npy::write_array(&path, &array).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), numpy, "{file}");
    }
    // No temporary files are left behind by the atomic writes.
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left.len(), 13, "{left:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

fn all_dtype_arrays() -> Vec<(&'static str, NdArray)> {
    vec![
        (
            "f32",
            NdArray::new(
                vec![2, 2],
                ArrayData::F32(vec![1.5, -0.0, f32::MAX, f32::MIN_POSITIVE]),
            ),
        ),
        (
            "f64",
            NdArray::new(
                vec![3],
                ArrayData::F64(vec![std::f64::consts::PI, -1e-300, 1e300]),
            ),
        ),
        ("i8", NdArray::new(vec![2], ArrayData::I8(vec![-128, 127]))),
        (
            "i16",
            NdArray::new(vec![2], ArrayData::I16(vec![-32768, 32767])),
        ),
        (
            "i32",
            NdArray::new(vec![1, 2], ArrayData::I32(vec![i32::MIN, i32::MAX])),
        ),
        (
            "i64",
            NdArray::new(vec![2], ArrayData::I64(vec![i64::MIN, 4294967295])),
        ),
        (
            "u8",
            NdArray::new(vec![3], ArrayData::U8(vec![0, 128, 255])),
        ),
        ("u16", NdArray::new(vec![1], ArrayData::U16(vec![65535]))),
        (
            "u32",
            NdArray::new(vec![2], ArrayData::U32(vec![4294967295, 0])),
        ),
        ("u64", NdArray::new(vec![1], ArrayData::U64(vec![u64::MAX]))),
        (
            "bool",
            NdArray::new(vec![2, 1], ArrayData::Bool(vec![true, false])),
        ),
        ("scalar", NdArray::new(vec![], ArrayData::F64(vec![2.25]))),
        ("empty", NdArray::new(vec![0, 4], ArrayData::F32(vec![]))),
        (
            "long_axis",
            NdArray::new(
                vec![1000],
                ArrayData::U8((0..1000).map(|i| (i % 251) as u8).collect()),
            ),
        ),
    ]
}

#[test]
fn our_writes_read_back_exactly() {
    let dir = scratch("read-back");
    let arrays = all_dtype_arrays();
    for (name, a) in &arrays {
        let path = dir.join(format!("{name}.npy"));
        npy::write_array(&path, a).unwrap();
        assert_eq!(&npy::read(&path).unwrap(), a, "{name}");
    }
    let refs: Vec<(&str, &NdArray)> = arrays.iter().map(|(n, a)| (*n, a)).collect();
    let zpath = dir.join("all.npz");
    npz::write(&zpath, &refs).unwrap();
    let back = npz::read(&zpath).unwrap();
    assert_eq!(back.len(), arrays.len());
    for ((n1, a1), (n2, a2)) in back.iter().zip(&arrays) {
        assert_eq!(n1, n2);
        assert_eq!(a1, a2, "{n1}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A value exercising every PyValue kind numpy can load back.
fn roundtrip_object() -> PyValue {
    let s = |x: &str| PyValue::Str(x.to_string());
    let mut pairs: Vec<(PyValue, PyValue)> = all_dtype_arrays()
        .into_iter()
        .map(|(n, a)| (s(n), PyValue::Array(a)))
        .collect();
    pairs.extend([
        (s("int"), PyValue::Int(-(1 << 40))),
        (s("float"), PyValue::Float(-0.1)),
        (s("none"), PyValue::None),
        (s("bool"), PyValue::Bool(true)),
        (s("text"), s("caf\u{e9} / \u{2603}")),
        (s("bytes"), PyValue::Bytes(vec![0, 1, 255])),
        (
            s("list"),
            PyValue::List((0..1500).map(PyValue::Int).collect()),
        ),
        (
            s("tuple"),
            PyValue::Tuple(vec![
                PyValue::Int(1),
                s("a"),
                PyValue::Float(2.0),
                PyValue::None,
            ]),
        ),
        (
            s("nested"),
            PyValue::Dict(vec![(
                s("K"),
                PyValue::List(vec![PyValue::Array(NdArray::new(
                    vec![3, 3],
                    ArrayData::F64((0..9).map(f64::from).collect()),
                ))]),
            )]),
        ),
        (
            s("objects"),
            PyValue::Array(NdArray::new(
                vec![2],
                ArrayData::Object(vec![s("x"), PyValue::Int(3)]),
            )),
        ),
        (PyValue::Int(5), s("int key")),
    ]);
    PyValue::Dict(pairs)
}

fn numpy_python() -> Option<String> {
    let python = std::env::var("NIA_PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = Command::new(&python)
        .args(["-c", "import numpy"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if ok {
        Some(python)
    } else if std::env::var("NIA_REQUIRE_NUMPY").as_deref() == Ok("1") {
        panic!("NIA_REQUIRE_NUMPY=1 but `{python} -c 'import numpy'` fails");
    } else {
        None
    }
}

#[test]
fn numpy_loads_what_we_write_with_the_same_values() {
    let Some(python) = numpy_python() else {
        eprintln!("skipped: numpy not available");
        return;
    };
    let dir = scratch("numpy-roundtrip");
    let mut manifest = Vec::new();
    for (name, a) in all_dtype_arrays() {
        let path = dir.join(format!("{name}.npy"));
        npy::write_array(&path, &a).unwrap();
        manifest.push(json!({"file": path, "kind": "npy", "value": encode(&PyValue::Array(a))}));
    }
    let obj = roundtrip_object();
    let opath = dir.join("object.npy");
    npy::write_object(&opath, &obj).unwrap();
    manifest.push(json!({"file": opath, "kind": "object", "value": encode(&obj)}));
    let writer_ref = decode(&expected()["np1_writer_ref.npy"]["value"]);
    let wpath = dir.join("writer_ref.npy");
    npy::write_object(&wpath, &writer_ref).unwrap();
    manifest.push(json!({"file": wpath, "kind": "object", "value": encode(&writer_ref)}));
    let arrays = all_dtype_arrays();
    let refs: Vec<(&str, &NdArray)> = arrays.iter().map(|(n, a)| (*n, a)).collect();
    let zpath = dir.join("arrays.npz");
    npz::write(&zpath, &refs).unwrap();
    let zvalue = PyValue::Dict(
        arrays
            .iter()
            .map(|(n, a)| (PyValue::Str(n.to_string()), PyValue::Array(a.clone())))
            .collect(),
    );
    manifest.push(json!({"file": zpath, "kind": "npz", "value": encode(&zvalue)}));
    let mpath = dir.join("manifest.json");
    std::fs::write(&mpath, serde_json::to_string(&manifest).unwrap()).unwrap();
    let out = Command::new(&python)
        .arg(fixture_dir().join("check_roundtrip.py"))
        .arg(&mpath)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "numpy check failed:\n{stdout}\n{stderr}"
    );
    assert!(
        stdout.contains(&format!("checked {} files", manifest.len())),
        "{stdout}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

// ---------------------------------------------------------------------------------------------
// Bad input: typed errors naming the file and what was expected

fn write_scratch(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn bad_npy_files_give_typed_errors_naming_the_file() {
    let dir = scratch("bad-npy");
    let good = std::fs::read(fixture_dir().join("dtype_f8.npy")).unwrap();

    let p = write_scratch(&dir, "magic.npy", b"PK\x03\x04 not numpy at all");
    let err = load_any(&p).unwrap_err();
    assert!(
        matches!(
            err,
            FormatError::Npy {
                source: NpyError::BadMagic { .. },
                ..
            }
        ),
        "{err}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("magic.npy") && msg.contains("expected magic"),
        "{msg}"
    );

    let mut v = good.clone();
    v[6] = 9;
    let p = write_scratch(&dir, "version.npy", &v);
    let err = load_any(&p).unwrap_err();
    assert!(matches!(
        err,
        FormatError::Npy {
            source: NpyError::UnsupportedVersion { major: 9, minor: 0 },
            ..
        }
    ));
    assert!(err.to_string().contains("version.npy"));

    let p = write_scratch(&dir, "short_header.npy", &good[..40]);
    let err = load_any(&p).unwrap_err();
    assert!(
        matches!(
            err,
            FormatError::Npy {
                source: NpyError::Truncated { what: "header", .. },
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("short_header.npy"));

    // Data cut short: shape (2, 2) float64 needs 32 bytes.
    let p = write_scratch(&dir, "truncated.npy", &good[..good.len() - 3]);
    let err = load_any(&p).unwrap_err();
    match &err {
        FormatError::Npy {
            source:
                NpyError::SizeMismatch {
                    shape,
                    expected,
                    found,
                    ..
                },
            ..
        } => {
            assert_eq!(
                (shape.as_slice(), *expected, *found),
                (&[2usize, 2][..], 32, 29)
            );
        }
        other => panic!("{other}"),
    }
    let msg = err.to_string();
    assert!(
        msg.contains("truncated.npy") && msg.contains("needs 32 bytes") && msg.contains("has 29"),
        "{msg}"
    );

    // Header that is not a dict / lacks keys / has a bad dtype.
    let header = |text: &str| {
        let mut h = text.to_string();
        // Pad so magic + version + length + header + '\n' fill whole 64-byte blocks.
        let pad = (64 - (10 + h.len() + 1) % 64) % 64;
        h.push_str(&" ".repeat(pad));
        h.push('\n');
        let mut b = b"\x93NUMPY\x01\x00".to_vec();
        b.extend_from_slice(&(h.len() as u16).to_le_bytes());
        b.extend_from_slice(h.as_bytes());
        b
    };
    let p = write_scratch(
        &dir,
        "nokey.npy",
        &header("{'descr': '<f4', 'shape': (1,), }"),
    );
    let err = load_any(&p).unwrap_err();
    assert!(
        err.to_string().contains("missing key 'fortran_order'"),
        "{err}"
    );
    let p = write_scratch(
        &dir,
        "garbage.npy",
        &header("{'descr': '<f4', 'fortran_order': Maybe}"),
    );
    assert!(matches!(
        load_any(&p).unwrap_err(),
        FormatError::Npy {
            source: NpyError::Header { .. },
            ..
        }
    ));
    let mut b = header("{'descr': '<c16', 'fortran_order': False, 'shape': (1,), }");
    b.extend_from_slice(&[0; 16]);
    let p = write_scratch(&dir, "complex.npy", &b);
    let err = load_any(&p).unwrap_err();
    assert!(
        matches!(
            err,
            FormatError::Npy {
                source: NpyError::UnsupportedDtype { .. },
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("'<c16'"));
    let p = write_scratch(
        &dir,
        "negative.npy",
        &header("{'descr': '<f4', 'fortran_order': False, 'shape': (-1,), }"),
    );
    assert!(load_any(&p)
        .unwrap_err()
        .to_string()
        .contains("non-negative"));

    // Object array whose pickle is cut short.
    let obj = std::fs::read(fixture_dir().join("np1_dict.npy")).unwrap();
    let p = write_scratch(&dir, "object_cut.npy", &obj[..obj.len() / 2]);
    let err = load_any(&p).unwrap_err();
    assert!(
        matches!(
            err,
            FormatError::Npy {
                source: NpyError::Pickle(PickleError::Truncated { .. }),
                ..
            } | FormatError::Npy {
                source: NpyError::Pickle(PickleError::NoStop { .. }),
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("object_cut.npy"));

    // Missing file and unknown extension.
    let err = load_any(&dir.join("absent.npy")).unwrap_err();
    assert!(matches!(err, FormatError::Io { .. }) && err.to_string().contains("absent.npy"));
    let err = load_any(&dir.join("x.txt")).unwrap_err();
    assert!(
        matches!(err, FormatError::UnknownExtension { .. }) && err.to_string().contains("x.txt")
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `_reconstruct(ndarray, (0,), b'b')` + `BUILD (1, (3,), dtype('<f4'), False, raw)`.
fn ndarray_pickle(raw: &[u8]) -> Vec<u8> {
    let mut p =
        b"\x80\x02cnumpy.core.multiarray\n_reconstruct\ncnumpy\nndarray\nK\x00\x85C\x01b\x87R"
            .to_vec();
    p.extend_from_slice(b"(K\x01K\x03\x85cnumpy\ndtype\nX\x02\x00\x00\x00f4\x89\x88\x87R");
    p.extend_from_slice(
        b"(K\x03X\x01\x00\x00\x00<NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK\x00tb\x89",
    );
    p.extend_from_slice(&[b'C', raw.len() as u8]);
    p.extend_from_slice(raw);
    p.extend_from_slice(b"tb.");
    p
}

#[test]
fn bad_pickles_and_archives_give_typed_errors() {
    let dir = scratch("bad-pickle");
    let pkl = std::fs::read(fixture_dir().join("smpl_like.pkl")).unwrap();
    // Every strict prefix of a pickle fails (no STOP or truncated operand), never panics.
    for cut in [0, 1, 2, 7, 100, pkl.len() / 2, pkl.len() - 1] {
        let err = read_pickle(&pkl[..cut]).unwrap_err();
        assert!(
            matches!(
                err,
                PickleError::Truncated { .. }
                    | PickleError::NoStop { .. }
                    | PickleError::Invalid { .. }
            ),
            "cut {cut}: {err}"
        );
    }
    let p = write_scratch(&dir, "cut.pkl", &pkl[..pkl.len() - 1]);
    let err = load_any(&p).unwrap_err();
    assert!(
        matches!(err, FormatError::Pickle { .. }) && err.to_string().contains("cut.pkl"),
        "{err}"
    );
    // Specific malformed pickles.
    assert!(matches!(
        read_pickle(b"\x80\x02\xff."),
        Err(PickleError::UnknownOpcode {
            opcode: 0xff,
            offset: 2
        })
    ));
    assert!(matches!(
        read_pickle(b"\x80\x09N."),
        Err(PickleError::Unsupported { .. })
    ));
    let err = read_pickle(b"\x80\x02h\x05.").unwrap_err();
    assert!(err.to_string().contains("memo 5 unset"), "{err}");
    let err = read_pickle(b"\x80\x02X\xff\xff\xff\x7fabc.").unwrap_err();
    assert!(
        matches!(
            err,
            PickleError::Truncated {
                needed: 0x7fff_ffff,
                ..
            }
        ),
        "{err}"
    );
    assert!(matches!(
        read_pickle(b"\x80\x02Nq\x00Q."),
        Err(PickleError::Unsupported {
            op: "BINPERSID",
            ..
        })
    ));
    assert!(matches!(
        read_pickle(b"a."),
        Err(PickleError::Invalid { op: "APPEND", .. })
    ));
    // A list containing itself cannot become a tree.
    let err = read_pickle(b"\x80\x02]q\x00h\x00a.").unwrap_err();
    assert!(matches!(err, PickleError::Limit { .. }), "{err}");
    // Deep nesting is refused, not recursed into.
    let mut deep = b"\x80\x02".to_vec();
    deep.extend(std::iter::repeat_n(b']', 5000));
    deep.extend(std::iter::repeat_n(b'a', 4999));
    deep.push(b'.');
    assert!(matches!(read_pickle(&deep), Err(PickleError::Limit { .. })));
    // Exponential aliasing (each list holds the previous one twice) hits the copy budget.
    let mut bomb = b"\x80\x02]q\x00".to_vec();
    for i in 0..60u8 {
        bomb.extend_from_slice(&[b']', b'(', b'h', i, b'h', i, b'e', b'q', i + 1]);
    }
    bomb.push(b'.');
    assert!(matches!(read_pickle(&bomb), Err(PickleError::Limit { .. })));
    // A hand-written ndarray pickle: float32 shape (3,) needs 12 bytes of raw data.
    let ok = read_pickle(&ndarray_pickle(&[0, 0, 128, 63, 0, 0, 0, 64, 0, 0, 64, 64])).unwrap();
    assert_eq!(
        ok,
        PyValue::Array(NdArray::new(vec![3], ArrayData::F32(vec![1.0, 2.0, 3.0])))
    );
    let err = read_pickle(&ndarray_pickle(&[0; 8])).unwrap_err();
    assert!(
        matches!(err, PickleError::Invalid { op: "BUILD", .. }),
        "{err}"
    );
    assert!(err.to_string().contains("need 12 bytes, found 8"), "{err}");
    // Integers up to 64 bits, larger ones are refused.
    assert_eq!(
        read_pickle(b"\x80\x02\x8a\x08\xff\xff\xff\xff\xff\xff\xff\x7f.").unwrap(),
        PyValue::Int(i64::MAX)
    );
    assert!(read_pickle(b"\x80\x02\x8a\x09\xff\xff\xff\xff\xff\xff\xff\xff\x00.").is_err());
    // Text opcodes of protocol 0.
    assert_eq!(
        read_pickle(b"(I1\nI01\nL12345678901L\nF0.5\nt.").unwrap(),
        PyValue::Tuple(vec![
            PyValue::Int(1),
            PyValue::Bool(true),
            PyValue::Int(12345678901),
            PyValue::Float(0.5)
        ])
    );
    // Not a zip / a corrupt npz member.
    let p = write_scratch(&dir, "bad.npz", b"not a zip archive");
    let err = load_any(&p).unwrap_err();
    assert!(
        matches!(err, FormatError::Zip { .. }) && err.to_string().contains("bad.npz"),
        "{err}"
    );
    let zpath = dir.join("member.npz");
    let a = NdArray::new(vec![2], ArrayData::F32(vec![1.0, 2.0]));
    npz::write(&zpath, &[("a", &a)]).unwrap();
    let mut z = std::fs::read(&zpath).unwrap();
    let at = z.windows(6).position(|w| w == b"\x93NUMPY").unwrap();
    z[at + 1] = b'X';
    std::fs::write(&zpath, &z).unwrap();
    let err = load_any(&zpath).unwrap_err();
    match &err {
        FormatError::NpzEntry {
            entry,
            source: NpyError::BadMagic { .. },
            ..
        } => assert_eq!(entry, "a.npy"),
        FormatError::Zip { .. } => {} // the member's CRC no longer matches: also a typed error
        other => panic!("{other}"),
    }
    assert!(err.to_string().contains("member.npz"));
    // Writing an array whose shape disagrees with its data.
    let bad = NdArray::new(vec![3], ArrayData::F32(vec![1.0]));
    let err = npy::write_array(&dir.join("bad.npy"), &bad).unwrap_err();
    assert!(
        err.to_string().contains("bad.npy") && err.to_string().contains("shape [3]"),
        "{err}"
    );
    assert!(!dir.join("bad.npy").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
