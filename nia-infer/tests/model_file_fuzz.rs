//! Fuzzing of the `.nia` model-file parser: thousands of mutated copies of the committed
//! trained model (`tests/fixtures/quickstart_tiny.nia`, the seed corpus) and of hand-made
//! headers. Nothing may panic; every error names the file; a file that parses has a header
//! that validates, and loading it either succeeds or fails with an error.
//!
//! `NIA_FUZZ_CASES=N` runs a longer campaign, `NIA_FUZZ_SEED=S` another stream.

use std::path::{Path, PathBuf};
use std::time::Instant;

use nia_data::rng::Rng;
use nia_model::store::model_file::{fnv1a64, ModelFile, MAGIC};

const DEFAULT_CASES: usize = 3000;

fn env(name: &str) -> Option<u64> {
    std::env::var(name).ok()?.parse().ok()
}

fn seed_file() -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/quickstart_tiny.nia"))
        .unwrap()
}

/// The byte offset where the weights start.
fn weights_start(bytes: &[u8]) -> usize {
    20 + u64::from_le_bytes(bytes[12..20].try_into().unwrap()) as usize
}

/// A file with `header` (JSON text) and `weights`, with a correct preamble.
fn assemble(header: &[u8], weights: &[u8]) -> Vec<u8> {
    let mut out = MAGIC.to_vec();
    out.extend_from_slice(&1u32.to_le_bytes());
    out.extend_from_slice(&(header.len() as u64).to_le_bytes());
    out.extend_from_slice(header);
    out.extend_from_slice(weights);
    out
}

/// One mutation of the seed.
fn mutate(seed: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut b = seed.to_vec();
    let ws = weights_start(seed);
    match rng.below(8) {
        // Flip bytes anywhere.
        0 => {
            for _ in 0..1 + rng.below(8) {
                let i = rng.below(b.len());
                b[i] ^= 1 << rng.below(8);
            }
        }
        // Flip bytes in the preamble or header only.
        1 => {
            for _ in 0..1 + rng.below(4) {
                let i = rng.below(ws);
                b[i] = rng.below(256) as u8;
            }
        }
        // Truncate.
        2 => b.truncate(rng.below(b.len())),
        // Append garbage.
        3 => {
            for _ in 0..1 + rng.below(64) {
                b.push(rng.below(256) as u8);
            }
        }
        // Header length field set to a random value.
        4 => {
            let v = match rng.below(3) {
                0 => rng.next_u64(),
                1 => rng.below(2 * ws) as u64,
                _ => u64::MAX - rng.below(16) as u64,
            };
            b[12..20].copy_from_slice(&v.to_le_bytes());
        }
        // A header edit that keeps JSON valid-looking: replace a number in the header text.
        5 => {
            let header = String::from_utf8_lossy(&seed[20..ws]).into_owned();
            let digits: Vec<usize> = header
                .char_indices()
                .filter(|(_, c)| c.is_ascii_digit())
                .map(|(i, _)| i)
                .collect();
            let mut h = header.into_bytes();
            if !digits.is_empty() {
                let i = digits[rng.below(digits.len())];
                h[i] = b"0123456789-"[rng.below(11)];
            }
            b = assemble(&h, &seed[ws..]);
        }
        // Valid checksum over corrupted weights (the burnpack reader must cope).
        6 => {
            let mut weights = seed[ws..].to_vec();
            if rng.below(2) == 0 {
                weights.truncate(rng.below(weights.len()));
            }
            for _ in 0..1 + rng.below(16) {
                if weights.is_empty() {
                    break;
                }
                let i = rng.below(weights.len());
                weights[i] = rng.below(256) as u8;
            }
            let header = String::from_utf8_lossy(&seed[20..ws]).into_owned();
            let mut json: serde_json::Value = serde_json::from_str(&header).unwrap();
            json["weights"]["bytes"] = (weights.len() as u64).into();
            json["weights"]["fnv1a64"] = format!("{:016x}", fnv1a64(&weights)).into();
            b = assemble(json.to_string().as_bytes(), &weights);
        }
        // Random bytes with the magic.
        _ => {
            b = MAGIC.to_vec();
            for _ in 0..rng.below(64) {
                b.push(rng.below(256) as u8);
            }
        }
    }
    b
}

#[test]
fn mutated_model_files_never_panic_and_errors_name_the_file() {
    let seed = seed_file();
    let cases = env("NIA_FUZZ_CASES").map_or(DEFAULT_CASES, |n| n as usize);
    let mut rng = Rng::new(env("NIA_FUZZ_SEED").unwrap_or(0x0de1_f11e));
    let path = PathBuf::from("fuzz/input.nia");
    #[allow(deprecated)] // burn 0.22 spells the CPU device this way.
    let device = burn::prelude::Device::ndarray();
    let start = Instant::now();
    let (mut parsed, mut loaded, mut rejected) = (0, 0, 0);
    for case in 0..cases {
        let bytes = mutate(&seed, &mut rng);
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            match ModelFile::parse(&path, &bytes) {
                Err(e) => {
                    let msg = e.to_string();
                    assert!(msg.contains("fuzz/input.nia"), "case {case}: {msg}");
                    (false, false)
                }
                Ok(file) => {
                    // Only headers with a buildable network parse into a load attempt of
                    // modest size; the check refuses the rest before allocating.
                    let ok = match file.load(&path, &device) {
                        Ok(_) => true,
                        Err(e) => {
                            assert!(e.to_string().contains("fuzz/input.nia"), "case {case}: {e}");
                            false
                        }
                    };
                    (true, ok)
                }
            }
        }));
        match outcome {
            Ok((true, true)) => {
                parsed += 1;
                loaded += 1
            }
            Ok((true, false)) => parsed += 1,
            Ok((false, _)) => rejected += 1,
            Err(_) => {
                let dump = std::env::temp_dir().join(format!("nia-model-fuzz-panic-{case}.nia"));
                std::fs::write(&dump, &bytes).unwrap();
                panic!("case {case} panicked; input saved to {}", dump.display());
            }
        }
    }
    eprintln!(
        "model-file fuzz: {cases} executions in {:.2} s; rejected {rejected}, parsed {parsed} (loaded {loaded})",
        start.elapsed().as_secs_f64()
    );
    assert!(rejected > cases / 2, "most mutations are refused");
}
