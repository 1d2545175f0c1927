//! Bad input: typed errors naming the file and what was expected.

use super::*;

fn write_scratch(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// Writes `bytes` as `name` in `dir` and reads it back: the `.npy` error, and the message, which
/// names the file.
fn npy_error(dir: &Path, name: &str, bytes: &[u8]) -> (NpyError, String) {
    let err = load_any(&write_scratch(dir, name, bytes)).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains(name), "{msg}");
    match err {
        FormatError::Npy { source, .. } => (source, msg),
        other => panic!("not an .npy error: {other}"),
    }
}

#[test]
fn bad_npy_files_give_typed_errors_naming_the_file() {
    let dir = scratch("bad-npy");
    let good = std::fs::read(fixture_dir().join("dtype_f8.npy")).unwrap();

    let (err, msg) = npy_error(&dir, "magic.npy", b"PK\x03\x04 not numpy at all");
    assert!(matches!(err, NpyError::BadMagic { .. }), "{msg}");
    assert!(msg.contains("expected magic"), "{msg}");

    let mut v = good.clone();
    v[6] = 9;
    let (err, msg) = npy_error(&dir, "version.npy", &v);
    assert!(
        matches!(err, NpyError::UnsupportedVersion { major: 9, minor: 0 }),
        "{msg}"
    );

    let (err, msg) = npy_error(&dir, "short_header.npy", &good[..40]);
    assert!(
        matches!(err, NpyError::Truncated { what: "header", .. }),
        "{msg}"
    );

    // Data cut short: shape (2, 2) float64 needs 32 bytes.
    let (err, msg) = npy_error(&dir, "truncated.npy", &good[..good.len() - 3]);
    match &err {
        NpyError::SizeMismatch {
            shape,
            expected,
            found,
            ..
        } => {
            assert_eq!(
                (shape.as_slice(), *expected, *found),
                (&[2usize, 2][..], 32, 29)
            );
        }
        other => panic!("{other}"),
    }
    assert!(
        msg.contains("needs 32 bytes") && msg.contains("has 29"),
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
    let garbage = header("{'descr': '<f4', 'fortran_order': Maybe}");
    let (err, msg) = npy_error(&dir, "garbage.npy", &garbage);
    assert!(matches!(err, NpyError::Header { .. }), "{msg}");
    let mut b = header("{'descr': '<c16', 'fortran_order': False, 'shape': (1,), }");
    b.extend_from_slice(&[0; 16]);
    let (err, msg) = npy_error(&dir, "complex.npy", &b);
    assert!(matches!(err, NpyError::UnsupportedDtype { .. }), "{msg}");
    assert!(msg.contains("'<c16'"), "{msg}");
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
