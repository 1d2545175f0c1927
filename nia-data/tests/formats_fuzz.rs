//! Fuzz-style robustness of the format readers: thousands of random and mutated inputs derived
//! from the real numpy fixtures must each return `Ok` or a typed `Err` — never panic, hang or
//! allocate without bound. Runs in the test itself (a panic fails it), seeded with the
//! project's deterministic RNG.

use std::path::Path;

use nia_data::formats::npy;
use nia_data::formats::npz;
use nia_data::formats::pickle::read_pickle;
use nia_data::formats::{dense_array_checked, ArrayData, PyValue};
use nia_data::rng::Rng;

/// Mutated inputs per run (each fixture is mutated about this / number-of-fixtures times).
/// `NIA_FUZZ_CASES=N` runs a longer campaign, `NIA_FUZZ_SEED=S` another stream.
const MUTATED_CASES: usize = 8000;
/// Purely random inputs per run.
const RANDOM_CASES: usize = 1000;
/// Random opcode streams per run (built from the tokens below, so they reach BUILD, REDUCE
/// and the numpy reconstruction with odd arguments far more often than byte noise does).
const TOKEN_CASES: usize = 3000;

/// Pickle fragments: opcodes with operands, numpy and Python globals, memo traffic.
const TOKENS: &[&[u8]] = &[
    b"(",
    b"N",
    b"K\x03",
    b"K\x00",
    b"K\x01",
    b"J\xff\xff\xff\xff",
    b"M\xff\xff",
    b"G?\xf0\x00\x00\x00\x00\x00\x00",
    b"X\x01\x00\x00\x00<",
    b"X\x01\x00\x00\x00>",
    b"X\x01\x00\x00\x00x",
    b"U\x01F",
    b"C\x01b",
    b"X\x02\x00\x00\x00f4",
    b"X\x02\x00\x00\x00O8",
    b"U\x02i8",
    b"X\x02\x00\x00\x00U2",
    b"X\x06\x00\x00\x00latin1",
    b"C\x08\x00\x00\x80?\x00\x00\x00@",
    b"T\x04\x00\x00\x00\x01\x02\x03\x04",
    b"\x8a\x01\xff",
    b"\x8a\x00",
    b"\x85",
    b"\x86",
    b"\x87",
    b"t",
    b")",
    b"]",
    b"}",
    b"a",
    b"e",
    b"s",
    b"u",
    b"l",
    b"d",
    b"R",
    b"b",
    b"\x81",
    b"q\x00",
    b"q\x01",
    b"q\x02",
    b"h\x00",
    b"h\x01",
    b"h\x02",
    b"\x94",
    b"0",
    b"1",
    b"2",
    b"\x88",
    b"\x89",
    b"\x8f",
    b"\x90",
    b"\x91",
    b"\x93",
    b"\x8c\x05numpy",
    b"\x8c\x05dtype",
    b"cnumpy.core.multiarray\n_reconstruct\n",
    b"cnumpy._core.multiarray\n_reconstruct\n",
    b"cnumpy\nndarray\n",
    b"cnumpy\ndtype\n",
    b"c_codecs\nencode\n",
    b"cnumpy.core.multiarray\nscalar\n",
    b"cnumpy._core.numeric\n_frombuffer\n",
    b"cchumpy.ch\nCh\n",
    b"c__builtin__\nset\n",
    b"ccollections\nOrderedDict\n",
    b"ccopy_reg\n_reconstructor\n",
    b"c__builtin__\nbytes\n",
    b"cscipy.sparse.csc\ncsc_matrix\n",
];

#[derive(Clone, Copy, PartialEq, Debug)]
enum Kind {
    Pickle,
    Npy,
    Npz,
}

fn fixtures() -> Vec<(String, Kind, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/formats");
    let mut out = Vec::new();
    let mut entries: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        let kind = match p.extension().and_then(|e| e.to_str()) {
            Some("pkl") => Kind::Pickle,
            Some("npy") => Kind::Npy,
            Some("npz") => Kind::Npz,
            _ => continue,
        };
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        out.push((name, kind, std::fs::read(&p).unwrap()));
    }
    out
}

/// Bytes that make parsers take unusual paths: lengths at type limits, pickle opcodes.
const INTERESTING: [u8; 16] = [
    0x00, 0xff, 0x7f, 0x80, 0x01, b'(', b'.', b'R', b'b', b'h', b'q', 0x94, 0x95, b'X', b'T', 0x8a,
];

fn mutate(rng: &mut Rng, src: &[u8]) -> Vec<u8> {
    let mut v = src.to_vec();
    let rounds = 1 + rng.below(4);
    for _ in 0..rounds {
        if v.is_empty() {
            v.push(rng.next_u64() as u8);
            continue;
        }
        let at = rng.below(v.len());
        match rng.below(8) {
            0 => v[at] ^= 1 << rng.below(8),
            1 => v[at] = INTERESTING[rng.below(INTERESTING.len())],
            2 => v.truncate(at),
            3 => {
                let end = (at + 1 + rng.below(16)).min(v.len());
                v.drain(at..end);
            }
            4 => {
                let n = 1 + rng.below(8);
                for _ in 0..n {
                    v.insert(at, rng.next_u64() as u8);
                }
            }
            5 => {
                // Duplicate a chunk somewhere else (repeats opcodes / memo references).
                let end = (at + 1 + rng.below(64)).min(v.len());
                let chunk = v[at..end].to_vec();
                let to = rng.below(v.len() + 1);
                v.splice(to..to, chunk);
            }
            6 => {
                // A 4-byte length field at a type limit.
                let word: u32 =
                    [0xffff_ffff, 0x7fff_ffff, 0x8000_0000, 0x0001_0000, 0][rng.below(5)];
                for (i, b) in word.to_le_bytes().iter().enumerate() {
                    if let Some(slot) = v.get_mut(at + i) {
                        *slot = *b;
                    }
                }
            }
            _ => v[at] = rng.next_u64() as u8,
        }
    }
    v
}

/// Decode with the reader for `kind`; on success also expand every value as a dense array
/// (this reaches the sparse-matrix validation with corrupted indices). Returns whether the
/// decode succeeded.
fn exercise(kind: Kind, bytes: &[u8]) -> bool {
    let fake = Path::new("fuzz/input.npz");
    match kind {
        Kind::Pickle => match read_pickle(bytes) {
            Ok(v) => {
                touch(&v, 0);
                true
            }
            Err(e) => {
                assert!(!e.to_string().is_empty());
                false
            }
        },
        Kind::Npy => match npy::read_bytes(bytes) {
            Ok(a) => {
                assert_eq!(Some(a.data.len()), npy::checked_numel(&a.shape));
                touch(&PyValue::Array(a), 0);
                true
            }
            Err(e) => {
                assert!(!e.to_string().is_empty());
                false
            }
        },
        Kind::Npz => match npz::read_bytes_named(bytes, fake) {
            Ok(arrays) => {
                for (_, a) in arrays {
                    assert_eq!(Some(a.data.len()), npy::checked_numel(&a.shape));
                }
                true
            }
            Err(e) => {
                assert!(e.to_string().contains("fuzz/input.npz"), "{e}");
                false
            }
        },
    }
}

/// Walk a decoded value, trying `dense_array_checked` on everything (must not panic).
fn touch(v: &PyValue, depth: usize) {
    let _ = dense_array_checked(v);
    if depth > 8 {
        return;
    }
    match v {
        PyValue::List(x) | PyValue::Tuple(x) => x.iter().for_each(|c| touch(c, depth + 1)),
        PyValue::Dict(p) => p.iter().for_each(|(_, c)| touch(c, depth + 1)),
        PyValue::Array(a) => {
            if let ArrayData::Object(x) = &a.data {
                x.iter().for_each(|c| touch(c, depth + 1));
            }
        }
        PyValue::Object { state, args, .. } => {
            touch(state, depth + 1);
            args.iter().for_each(|c| touch(c, depth + 1));
        }
        _ => {}
    }
}

#[test]
fn unmodified_fixtures_all_decode() {
    let fx = fixtures();
    assert!(fx.len() >= 35, "{} fixtures", fx.len());
    for (name, kind, bytes) in &fx {
        assert!(exercise(*kind, bytes), "{name} should decode");
    }
}

#[test]
fn mutated_and_random_inputs_never_panic() {
    let fx = fixtures();
    let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<u64>().ok());
    let mut rng = Rng::new(env("NIA_FUZZ_SEED").unwrap_or(0x5eed_f00d));
    let cases = env("NIA_FUZZ_CASES").map_or(MUTATED_CASES, |n| n as usize);
    let (mut ok, mut err) = (0usize, 0usize);
    for i in 0..cases {
        let (_, kind, src) = &fx[i % fx.len()];
        let input = mutate(&mut rng, src);
        if exercise(*kind, &input) {
            ok += 1;
        } else {
            err += 1;
        }
        // Object .npy payloads are pickles: hit the pickle reader directly too.
        if *kind == Kind::Npy && input.len() > 128 {
            let _ = read_pickle(&input[128..]);
        }
    }
    for i in 0..RANDOM_CASES {
        let len = rng.below(512);
        let mut input: Vec<u8> = (0..len).map(|_| rng.next_u64() as u8).collect();
        // Give some of them a valid start so the parsers get past the first check.
        let prefix: &[u8] = match i % 4 {
            0 => b"\x80\x02",
            1 => b"\x93NUMPY\x01\x00",
            2 => b"PK\x03\x04",
            _ => b"",
        };
        input.splice(0..0, prefix.iter().copied());
        for kind in [Kind::Pickle, Kind::Npy, Kind::Npz] {
            if exercise(kind, &input) {
                ok += 1;
            } else {
                err += 1;
            }
        }
    }
    let token_cases = if cases == MUTATED_CASES {
        TOKEN_CASES
    } else {
        cases
    };
    let before_tokens = ok;
    for _ in 0..token_cases {
        let mut input = b"\x80\x02".to_vec();
        for _ in 0..1 + rng.below(60) {
            input.extend_from_slice(TOKENS[rng.below(TOKENS.len())]);
        }
        input.push(b'.');
        if exercise(Kind::Pickle, &input) {
            ok += 1;
        } else {
            err += 1;
        }
    }
    let token_ok = ok - before_tokens;
    // Crossover: the head of one fixture glued to the tail of another.
    for _ in 0..RANDOM_CASES {
        let (_, kind, a) = &fx[rng.below(fx.len())];
        let (_, _, b) = &fx[rng.below(fx.len())];
        let mut input = a[..rng.below(a.len() + 1)].to_vec();
        input.extend_from_slice(&b[rng.below(b.len() + 1)..]);
        if exercise(*kind, &input) {
            ok += 1;
        } else {
            err += 1;
        }
    }
    // Both outcomes occur: mutations that keep a file valid and ones that break it.
    assert!(ok > 100 && err > 1000, "ok {ok}, err {err}");
    assert!(token_ok > 0, "no opcode stream decoded");
    eprintln!("fuzz: {ok} decoded ({token_ok} opcode streams), {err} typed errors");
}
