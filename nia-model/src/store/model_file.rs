//! The `.nia` model file: one self-describing file with everything needed to rebuild a trained
//! network (format version, network config, the run config it was trained with, the step, the
//! weights), written by `nia-infer export` and read by every `nia-infer` command.
//!
//! # Layout (all integers little-endian)
//!
//! | bytes | content |
//! |---|---|
//! | 0..8 | magic `NIAMODEL` |
//! | 8..12 | `u32` format version ([`FORMAT_VERSION`]) |
//! | 12..20 | `u64` header length `H` |
//! | 20..20+H | UTF-8 JSON header ([`ModelFileHeader`]) |
//! | 20+H..end | the weights: burn's burnpack bytes, exactly `header.weights.bytes` long |
//!
//! The header records the byte count and an FNV-1a 64-bit checksum of the weights, so a
//! truncated or corrupted file is refused with a message naming the file and what is wrong,
//! before any tensor is touched. Files are written to a temporary name and renamed into place.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::store::ModuleRecord;
use burn::tensor::{Bytes, Device};
use serde::{Deserialize, Serialize};

use crate::{ModelConfig, NiaModel};

/// The first 8 bytes of every `.nia` file.
pub const MAGIC: &[u8; 8] = b"NIAMODEL";
/// The format version this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;
/// The only weight encoding of format version 1.
pub const WEIGHTS_ENCODING: &str = "burnpack";
/// Headers larger than this are refused as corrupt (a real header is a few kilobytes).
const MAX_HEADER_BYTES: u64 = 16 << 20;
const PREAMBLE_BYTES: usize = 20;

/// An error reading or writing a model file; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum ModelFileError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: not a nia-rs model file (expected the magic bytes `NIAMODEL` at the start; got {found:?})", path.display())]
    Magic { path: PathBuf, found: Vec<u8> },
    #[error("{}: model file format version {found}, this build reads version {FORMAT_VERSION}", path.display())]
    Version { path: PathBuf, found: u32 },
    #[error("{}: truncated: {what} needs {needed} bytes, the file has {available} after offset {offset}", path.display())]
    Truncated {
        path: PathBuf,
        what: &'static str,
        offset: u64,
        needed: u64,
        available: u64,
    },
    #[error("{}: header: {message}", path.display())]
    Header { path: PathBuf, message: String },
    #[error("{}: weights: {message}", path.display())]
    Weights { path: PathBuf, message: String },
}

/// Where the weights are and how to check them.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WeightsInfo {
    /// Always [`WEIGHTS_ENCODING`] in format version 1.
    pub encoding: String,
    /// Byte count of the weights section.
    pub bytes: u64,
    /// FNV-1a 64 of the weights section, 16 lowercase hex digits.
    pub fnv1a64: String,
}

/// The JSON header.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelFileHeader {
    pub format_version: u32,
    /// The program and version that wrote the file, e.g. `nia-rs 0.1.0`.
    pub producer: String,
    /// The network: sizes, variant and switches. The weights must fit it exactly.
    pub model: ModelConfig,
    /// The run config the network was trained with (nia-train's TOML as JSON; opaque here).
    /// Inference reads its defaults from it: samples per ray, source views, protocol.
    pub run: serde_json::Value,
    /// Training steps taken.
    pub step: u64,
    pub weights: WeightsInfo,
}

/// A model file in memory.
#[derive(Debug, Clone)]
pub struct ModelFile {
    pub header: ModelFileHeader,
    /// The burnpack bytes.
    pub weights: Vec<u8>,
}

/// FNV-1a, 64-bit.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

impl ModelFile {
    /// Captures `model` (built from `config`) with its run config and step.
    pub fn from_model(
        model: &NiaModel,
        config: &ModelConfig,
        run: serde_json::Value,
        step: u64,
    ) -> Result<Self, String> {
        // `valid()` synchronises BatchNorm's pending running-statistics updates first.
        let weights = model
            .valid()
            .into_record()
            .into_bytes()
            .map_err(|e| format!("serialising the weights: {e:?}"))?
            .to_vec();
        Ok(ModelFile {
            header: ModelFileHeader {
                format_version: FORMAT_VERSION,
                producer: format!("nia-rs {}", env!("CARGO_PKG_VERSION")),
                model: config.clone(),
                run,
                step,
                weights: WeightsInfo {
                    encoding: WEIGHTS_ENCODING.into(),
                    bytes: weights.len() as u64,
                    fnv1a64: format!("{:016x}", fnv1a64(&weights)),
                },
            },
            weights,
        })
    }

    /// The file's bytes; `path` only names the file in errors.
    pub fn to_bytes(&self, path: &Path) -> Result<Vec<u8>, ModelFileError> {
        let header =
            serde_json::to_vec_pretty(&self.header).map_err(|e| ModelFileError::Header {
                path: path.to_path_buf(),
                message: format!("cannot serialise the header: {e}"),
            })?;
        let mut out = Vec::with_capacity(PREAMBLE_BYTES + header.len() + self.weights.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        out.extend_from_slice(&(header.len() as u64).to_le_bytes());
        out.extend_from_slice(&header);
        out.extend_from_slice(&self.weights);
        Ok(out)
    }

    /// Writes the file atomically: a temporary file beside `path`, synced, then renamed.
    pub fn write(&self, path: &Path) -> Result<(), ModelFileError> {
        let io = |source| ModelFileError::Io {
            path: path.to_path_buf(),
            source,
        };
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "model.nia".into());
        let bytes = self.to_bytes(path)?;
        let tmp = path.with_file_name(format!(".{name}.tmp"));
        let written = (|| {
            use std::io::Write;
            let mut file = std::fs::File::create(&tmp)?;
            file.write_all(&bytes)?;
            file.sync_all()?;
            std::fs::rename(&tmp, path)
        })();
        if written.is_err() {
            // Nothing half-written is left behind; an existing file at `path` is untouched.
            let _ = std::fs::remove_file(&tmp);
        }
        written.map_err(io)
    }

    /// Reads and checks a model file.
    pub fn read(path: &Path) -> Result<Self, ModelFileError> {
        let bytes = std::fs::read(path).map_err(|source| ModelFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(path, &bytes)
    }

    /// Parses the bytes of a model file; `path` only names it in errors.
    pub fn parse(path: &Path, bytes: &[u8]) -> Result<Self, ModelFileError> {
        let truncated = |what, offset: usize, needed: u64| ModelFileError::Truncated {
            path: path.to_path_buf(),
            what,
            offset: offset as u64,
            needed,
            available: bytes.len().saturating_sub(offset) as u64,
        };
        if bytes.len() < MAGIC.len() || &bytes[..MAGIC.len()] != MAGIC {
            return Err(ModelFileError::Magic {
                path: path.to_path_buf(),
                found: bytes[..bytes.len().min(MAGIC.len())].to_vec(),
            });
        }
        if bytes.len() < PREAMBLE_BYTES {
            return Err(truncated("the preamble", 0, PREAMBLE_BYTES as u64));
        }
        let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap_or([0; 4]));
        if version != FORMAT_VERSION {
            return Err(ModelFileError::Version {
                path: path.to_path_buf(),
                found: version,
            });
        }
        let header_len = u64::from_le_bytes(bytes[12..20].try_into().unwrap_or([0; 8]));
        let header_err = |message: String| ModelFileError::Header {
            path: path.to_path_buf(),
            message,
        };
        if header_len > MAX_HEADER_BYTES {
            return Err(header_err(format!(
                "length {header_len} bytes is over the {MAX_HEADER_BYTES}-byte limit (corrupt file)"
            )));
        }
        let header_end = PREAMBLE_BYTES + header_len as usize;
        if bytes.len() < header_end {
            return Err(truncated("the JSON header", PREAMBLE_BYTES, header_len));
        }
        let mut header: serde_json::Value =
            serde_json::from_slice(&bytes[PREAMBLE_BYTES..header_end])
                .map_err(|e| header_err(e.to_string()))?;
        super::removed_switches::strip_removed_switches(&mut header).map_err(&header_err)?;
        // Switches added to the network config after a file was written take their defaults
        // (the behaviour the file was trained with).
        if let (Some(model), Ok(serde_json::Value::Object(defaults))) = (
            header.get_mut("model").and_then(|m| m.as_object_mut()),
            serde_json::to_value(ModelConfig::new()),
        ) {
            for (key, value) in defaults {
                model.entry(key).or_insert(value);
            }
        }
        let header: ModelFileHeader =
            serde_json::from_value(header).map_err(|e| header_err(e.to_string()))?;
        if header.format_version != FORMAT_VERSION {
            return Err(ModelFileError::Version {
                path: path.to_path_buf(),
                found: header.format_version,
            });
        }
        let weights_err = |message: String| ModelFileError::Weights {
            path: path.to_path_buf(),
            message,
        };
        if header.weights.encoding != WEIGHTS_ENCODING {
            return Err(weights_err(format!(
                "encoding `{}`, expected `{WEIGHTS_ENCODING}`",
                header.weights.encoding
            )));
        }
        let available = (bytes.len() - header_end) as u64;
        if available < header.weights.bytes {
            return Err(truncated("the weights", header_end, header.weights.bytes));
        }
        if available > header.weights.bytes {
            return Err(weights_err(format!(
                "{} bytes follow the header but the header declares {} (trailing data: corrupt or concatenated file)",
                available, header.weights.bytes
            )));
        }
        let weights = bytes[header_end..].to_vec();
        let sum = format!("{:016x}", fnv1a64(&weights));
        if sum != header.weights.fnv1a64 {
            return Err(weights_err(format!(
                "checksum fnv1a64 {sum} does not match the header's {} (the file is corrupt)",
                header.weights.fnv1a64
            )));
        }
        Ok(ModelFile { header, weights })
    }

    /// Builds the network of the header's config on `device` and loads the weights into it.
    /// Weights that do not fit the config (another network size, a missing or extra tensor)
    /// are an error naming `path`.
    pub fn load(&self, path: &Path, device: &Device) -> Result<NiaModel, ModelFileError> {
        let weights_err = |message: String| ModelFileError::Weights {
            path: path.to_path_buf(),
            message,
        };
        self.header
            .model
            .check()
            .map_err(|e| ModelFileError::Header {
                path: path.to_path_buf(),
                message: format!("model config: {e}"),
            })?;
        let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(self.weights.clone()))
            .map_err(|e| weights_err(format!("{e:?}")))?;
        let model = self.header.model.init(device);
        model.try_load_record(record).map_err(|e| {
            weights_err(format!(
                "they do not fit the header's network config (trained with another config?): {e:?}"
            ))
        })
    }
}
