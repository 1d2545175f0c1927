//! Writing: byte-for-byte against numpy, exact read-back, numpy loads what we write.

use super::*;

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
