//! TensorBoard event files (`events.out.tfevents.*`), written directly: TFRecord framing
//! around hand-encoded `tensorflow.Event` protocol buffers, so the dashboard people already use
//! reads a run's scalars and validation images without Python or TensorFlow on the training
//! machine.
//!
//! A record is `u64 length (LE) | u32 masked CRC-32C of the length | data | u32 masked CRC-32C
//! of the data`; the mask is `((crc >> 15) | (crc << 17)) + 0xa282ead8`. The first event of a
//! file carries `file_version = "brain.Event:2"`. Messages used (field number: type):
//! - `Event`: 1 wall_time double, 2 step int64, 3 file_version string, 5 summary Summary;
//! - `Summary`: 1 value repeated Value;
//! - `Summary.Value`: 1 tag string, 2 simple_value float, 4 image Image;
//! - `Summary.Image`: 1 height int32, 2 width int32, 3 colorspace int32 (3 = RGB),
//!   4 encoded_image_string bytes (PNG).

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

/// An event file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum TensorBoardError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A record whose framing or checksum is wrong (reading back).
    #[error("{}: record {index}: {what}", path.display())]
    Corrupt {
        path: PathBuf,
        index: usize,
        what: String,
    },
}

/// CRC-32C (Castagnoli, reflected polynomial 0x82f63b78), bitwise.
pub fn crc32c(data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &byte in data {
        crc ^= byte as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0x82f6_3b78
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// TFRecord's masked CRC.
pub fn masked_crc32c(data: &[u8]) -> u32 {
    let crc = crc32c(data);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// Protocol-buffer encoding of the few field kinds events use.
mod proto {
    pub fn varint(out: &mut Vec<u8>, mut v: u64) {
        while v >= 0x80 {
            out.push((v as u8) | 0x80);
            v >>= 7;
        }
        out.push(v as u8);
    }
    fn key(out: &mut Vec<u8>, field: u32, wire: u8) {
        varint(out, ((field as u64) << 3) | wire as u64);
    }
    pub fn int(out: &mut Vec<u8>, field: u32, v: i64) {
        key(out, field, 0);
        varint(out, v as u64);
    }
    pub fn double(out: &mut Vec<u8>, field: u32, v: f64) {
        key(out, field, 1);
        out.extend_from_slice(&v.to_le_bytes());
    }
    pub fn float(out: &mut Vec<u8>, field: u32, v: f32) {
        key(out, field, 5);
        out.extend_from_slice(&v.to_le_bytes());
    }
    pub fn bytes(out: &mut Vec<u8>, field: u32, v: &[u8]) {
        key(out, field, 2);
        varint(out, v.len() as u64);
        out.extend_from_slice(v);
    }
}

/// One `Summary.Value`'s payload.
pub enum SummaryValue<'a> {
    Scalar(f32),
    /// A PNG of `width` x `height` RGB pixels.
    Png {
        width: u32,
        height: u32,
        png: &'a [u8],
    },
}

/// The bytes of an `Event` at `wall_time` (s since the epoch) and `step` holding one summary
/// value `tag`.
pub fn summary_event(wall_time: f64, step: i64, tag: &str, value: &SummaryValue<'_>) -> Vec<u8> {
    let mut v = Vec::new();
    proto::bytes(&mut v, 1, tag.as_bytes());
    match value {
        SummaryValue::Scalar(x) => proto::float(&mut v, 2, *x),
        SummaryValue::Png { width, height, png } => {
            let mut image = Vec::new();
            proto::int(&mut image, 1, *height as i64);
            proto::int(&mut image, 2, *width as i64);
            proto::int(&mut image, 3, 3);
            proto::bytes(&mut image, 4, png);
            proto::bytes(&mut v, 4, &image);
        }
    }
    let mut summary = Vec::new();
    proto::bytes(&mut summary, 1, &v);
    let mut event = Vec::new();
    proto::double(&mut event, 1, wall_time);
    proto::int(&mut event, 2, step);
    proto::bytes(&mut event, 5, &summary);
    event
}

/// The bytes of the file's first `Event` (`file_version`).
pub fn version_event(wall_time: f64) -> Vec<u8> {
    let mut event = Vec::new();
    proto::double(&mut event, 1, wall_time);
    proto::bytes(&mut event, 3, b"brain.Event:2");
    event
}

/// `data` framed as one TFRecord.
pub fn record(data: &[u8]) -> Vec<u8> {
    let len = (data.len() as u64).to_le_bytes();
    let mut out = Vec::with_capacity(data.len() + 16);
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc32c(&len).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked_crc32c(data).to_le_bytes());
    out
}

/// The records of a TFRecord file, their checksums verified.
pub fn read_records(path: &Path) -> Result<Vec<Vec<u8>>, TensorBoardError> {
    let mut bytes = Vec::new();
    File::open(path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .map_err(|source| TensorBoardError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    let corrupt = |index, what: &str| TensorBoardError::Corrupt {
        path: path.to_path_buf(),
        index,
        what: what.to_string(),
    };
    let mut out = Vec::new();
    let mut at = 0usize;
    while at < bytes.len() {
        let index = out.len();
        let head = bytes
            .get(at..at + 12)
            .ok_or_else(|| corrupt(index, "truncated header"))?;
        let len_bytes: [u8; 8] = head[..8].try_into().expect("8 bytes");
        let crc = u32::from_le_bytes(head[8..12].try_into().expect("4 bytes"));
        if crc != masked_crc32c(&len_bytes) {
            return Err(corrupt(index, "length checksum mismatch"));
        }
        let len = usize::try_from(u64::from_le_bytes(len_bytes))
            .map_err(|_| corrupt(index, "length out of range"))?;
        let start = at + 12;
        let end = start
            .checked_add(len)
            .filter(|&e| e + 4 <= bytes.len())
            .ok_or_else(|| corrupt(index, "truncated data"))?;
        let data = &bytes[start..end];
        let crc = u32::from_le_bytes(bytes[end..end + 4].try_into().expect("4 bytes"));
        if crc != masked_crc32c(data) {
            return Err(corrupt(index, "data checksum mismatch"));
        }
        out.push(data.to_vec());
        at = end + 4;
    }
    Ok(out)
}

/// An open event file in a run's log folder.
pub struct EventWriter {
    path: PathBuf,
    file: BufWriter<File>,
}

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

impl EventWriter {
    /// Creates `dir/events.out.tfevents.<seconds>.nia-rs.<pid>` (a resumed run adds a file;
    /// TensorBoard reads every file of the folder) and writes the version event.
    pub fn create(dir: &Path) -> Result<Self, TensorBoardError> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| TensorBoardError::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let wall = now();
        let path = dir.join(format!(
            "events.out.tfevents.{}.nia-rs.{}",
            wall as u64,
            std::process::id()
        ));
        let file = File::create(&path).map_err(io(&path))?;
        let mut writer = EventWriter {
            path,
            file: BufWriter::new(file),
        };
        writer.write(&version_event(wall))?;
        Ok(writer)
    }

    /// The file written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn write(&mut self, event: &[u8]) -> Result<(), TensorBoardError> {
        self.file
            .write_all(&record(event))
            .map_err(|source| TensorBoardError::Io {
                path: self.path.clone(),
                source,
            })
    }

    /// A scalar `tag` at `step`.
    pub fn scalar(&mut self, tag: &str, step: u64, value: f32) -> Result<(), TensorBoardError> {
        self.write(&summary_event(
            now(),
            step as i64,
            tag,
            &SummaryValue::Scalar(value),
        ))
    }

    /// An RGB image `tag` at `step`, given as PNG bytes.
    pub fn png(
        &mut self,
        tag: &str,
        step: u64,
        width: u32,
        height: u32,
        png: &[u8],
    ) -> Result<(), TensorBoardError> {
        self.write(&summary_event(
            now(),
            step as i64,
            tag,
            &SummaryValue::Png { width, height, png },
        ))
    }

    /// Pushes what was written to the file (TensorBoard reads a growing file).
    pub fn flush(&mut self) -> Result<(), TensorBoardError> {
        self.file.flush().map_err(|source| TensorBoardError::Io {
            path: self.path.clone(),
            source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_matches_the_standard_check_values() {
        // The CRC-32C check value (RFC 3720 B.4 / the catalogue's "123456789").
        assert_eq!(crc32c(b"123456789"), 0xe306_9283);
        assert_eq!(crc32c(b""), 0);
        // RFC 3720 B.4: 32 bytes of zeros, and of 0xff.
        assert_eq!(crc32c(&[0u8; 32]), 0x8a91_36aa);
        assert_eq!(crc32c(&[0xffu8; 32]), 0x62a8_ab43);
    }

    #[test]
    fn scalar_event_bytes_by_hand() {
        // Event{wall_time: 1.5, step: 300, summary{value{tag: "a", simple_value: 2.0}}}.
        let e = summary_event(1.5, 300, "a", &SummaryValue::Scalar(2.0));
        let mut want = vec![0x09];
        want.extend_from_slice(&1.5f64.to_le_bytes());
        want.extend_from_slice(&[0x10, 0xac, 0x02]); // field 2 varint 300
        want.extend_from_slice(&[0x2a, 0x0a]); // field 5, 10 bytes of Summary
        want.extend_from_slice(&[0x0a, 0x08]); // field 1, 8 bytes of Value
        want.extend_from_slice(&[0x0a, 0x01, b'a']); // tag
        want.push(0x15); // field 2, fixed32
        want.extend_from_slice(&2.0f32.to_le_bytes());
        assert_eq!(e, want);
    }

    #[test]
    fn records_round_trip_and_corruption_is_named() {
        let dir = std::env::temp_dir().join(format!("nia-tb-unit-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut w = EventWriter::create(&dir).unwrap();
        w.scalar("loss", 0, 0.25).unwrap();
        w.png("validation/0", 5, 1, 1, &[1, 2, 3]).unwrap();
        w.flush().unwrap();
        let path = w.path().to_path_buf();
        drop(w);
        let records = read_records(&path).unwrap();
        assert_eq!(records.len(), 3);
        assert!(records[0].ends_with(b"brain.Event:2"));
        assert!(
            records[2].ends_with(&[0x22, 0x03, 1, 2, 3]),
            "PNG bytes last"
        );
        let mut bytes = std::fs::read(&path).unwrap();
        let last = bytes.len() - 6;
        bytes[last] ^= 0xff;
        std::fs::write(&path, &bytes).unwrap();
        let err = read_records(&path).unwrap_err().to_string();
        assert!(
            err.contains("record 2") && err.contains("checksum"),
            "{err}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
