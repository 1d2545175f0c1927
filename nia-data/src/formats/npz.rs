//! `.npz` archives: a zip of `.npy` members, one per array (`np.savez` stores them,
//! `np.savez_compressed` deflates them). Member `name.npy` holds array `name`.

use std::io::{Cursor, Read, Write};
use std::path::Path;

use zip::write::SimpleFileOptions;
use zip::{CompressionMethod, ZipArchive, ZipWriter};

use super::npy::{read_bytes, to_bytes};
use super::{write_atomic, FormatError, NdArray};

/// Read every array of an `.npz`, in archive order, names without the `.npy` suffix.
pub fn read(path: &Path) -> Result<Vec<(String, NdArray)>, FormatError> {
    let bytes = std::fs::read(path).map_err(|source| FormatError::Io {
        path: path.into(),
        source,
    })?;
    read_bytes_named(&bytes, path)
}

/// [`read`] from bytes already in memory; `path` names the archive in errors.
pub fn read_bytes_named(bytes: &[u8], path: &Path) -> Result<Vec<(String, NdArray)>, FormatError> {
    let zip_err = |e: zip::result::ZipError| FormatError::Zip {
        path: path.into(),
        msg: e.to_string(),
    };
    let mut archive = ZipArchive::new(Cursor::new(bytes)).map_err(zip_err)?;
    let mut out = Vec::with_capacity(archive.len().min(1024));
    for i in 0..archive.len() {
        let mut member = archive.by_index(i).map_err(zip_err)?;
        if member.is_dir() {
            continue;
        }
        let entry = member.name().map_err(zip_err)?.to_string();
        // Read what the member really holds (the declared size is not trusted for allocation).
        let mut data = Vec::new();
        member
            .read_to_end(&mut data)
            .map_err(|e| FormatError::Zip {
                path: path.into(),
                msg: format!("entry '{entry}': {e}"),
            })?;
        let array = read_bytes(&data).map_err(|source| FormatError::NpzEntry {
            path: path.into(),
            entry: entry.clone(),
            source,
        })?;
        let name = entry.strip_suffix(".npy").unwrap_or(&entry).to_string();
        out.push((name, array));
    }
    Ok(out)
}

/// Write arrays as `np.savez` does: an uncompressed zip with members `name.npy` (atomically).
pub fn write(path: &Path, arrays: &[(&str, &NdArray)]) -> Result<(), FormatError> {
    let zip_err = |e: zip::result::ZipError| FormatError::Zip {
        path: path.into(),
        msg: e.to_string(),
    };
    let mut zip = ZipWriter::new(Cursor::new(Vec::new()));
    let options = SimpleFileOptions::default()
        .compression_method(CompressionMethod::Stored)
        .large_file(false);
    for (name, array) in arrays {
        let npy = to_bytes(array).map_err(|source| FormatError::NpzEntry {
            path: path.into(),
            entry: format!("{name}.npy"),
            source,
        })?;
        zip.start_file(format!("{name}.npy"), options)
            .map_err(zip_err)?;
        zip.write_all(&npy).map_err(|source| FormatError::Write {
            path: path.into(),
            source,
        })?;
    }
    let bytes = zip.finish().map_err(zip_err)?.into_inner();
    write_atomic(path, &bytes)
}
