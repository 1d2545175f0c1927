//! Reading real numpy files: every fixture, numpy 1 vs 2, python 2, SMPL-like, sparse, npz.

use super::*;

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
