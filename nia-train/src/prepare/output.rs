//! Writing the fitted subject in the ZJU-MoCap layout, atomically: everything goes into a
//! staging folder beside the output (`.<name>.partial-<pid>`), renamed into place at the end,
//! so a failed or interrupted run leaves no half-written subject.

use std::path::{Path, PathBuf};

use glam::Vec3;
use nia_data::formats::{npy, ArrayData, NdArray, PyValue};
use nia_data::geometry::camera::Camera;
use nia_data::synth::writer;

use super::PrepareError;

/// The staging folder of `final_dir` (same parent, so the rename stays on one file system).
pub fn staging_dir(final_dir: &Path) -> PathBuf {
    let name = final_dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "subject".into());
    final_dir.with_file_name(format!(".{name}.partial-{}", std::process::id()))
}

/// Creates `dir` (and parents).
pub fn create_dir(dir: &Path) -> Result<(), PrepareError> {
    std::fs::create_dir_all(dir).map_err(|e| PrepareError::io(dir, "create folder", e))
}

/// `annots.npy` for `cameras` and the images `ims[f][c]` (relative paths), as ZJU-MoCap's.
pub fn write_annots(
    dir: &Path,
    cameras: &[Camera],
    ims: &[Vec<String>],
) -> Result<(), PrepareError> {
    let mut value = writer::annots_value(cameras, 0);
    if let PyValue::Dict(items) = &mut value {
        for (key, v) in items.iter_mut() {
            if matches!(key, PyValue::Str(k) if k == "ims") {
                *v = PyValue::List(
                    ims.iter()
                        .map(|frame| {
                            PyValue::Dict(vec![(
                                PyValue::Str("ims".into()),
                                PyValue::List(
                                    frame.iter().map(|p| PyValue::Str(p.clone())).collect(),
                                ),
                            )])
                        })
                        .collect(),
                );
            }
        }
    }
    npy::write_object(&dir.join("annots.npy"), &value)?;
    Ok(())
}

/// `params/<n>.npy` and `vertices/<n>.npy` of one frame.
pub fn write_body(
    dir: &Path,
    number: usize,
    params: &nia_data::body::SmplParams,
    vertices: &[Vec3],
) -> Result<(), PrepareError> {
    let value = writer::params_value(&params.poses, params.rh, params.th, &params.shapes);
    npy::write_object(&dir.join("params").join(format!("{number}.npy")), &value)?;
    let data = vertices.iter().flat_map(|v| v.to_array()).collect();
    let array = NdArray::new(vec![vertices.len(), 3], ArrayData::F32(data));
    npy::write_array(&dir.join("vertices").join(format!("{number}.npy")), &array)?;
    Ok(())
}

/// Hard-links `from` to `to` (no copy of the photos), or copies where linking fails (another
/// file system).
pub fn link_or_copy(from: &Path, to: &Path) -> Result<(), PrepareError> {
    if let Some(dir) = to.parent() {
        create_dir(dir)?;
    }
    if std::fs::hard_link(from, to).is_ok() {
        return Ok(());
    }
    std::fs::copy(from, to)
        .map(|_| ())
        .map_err(|e| PrepareError::io(from, "copy into the output", e))
}

/// Moves the staging folder into place; an existing `final_dir` is replaced only when
/// `overwrite` (moved aside first, deleted after the rename).
pub fn commit(staging: &Path, final_dir: &Path, overwrite: bool) -> Result<(), PrepareError> {
    let old = final_dir.with_file_name(format!(
        ".{}.old-{}",
        final_dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        std::process::id()
    ));
    let replaced = final_dir.exists();
    if replaced {
        if !overwrite {
            return Err(PrepareError::Exists(final_dir.to_path_buf()));
        }
        std::fs::rename(final_dir, &old)
            .map_err(|e| PrepareError::io(final_dir, "move the old output aside", e))?;
    }
    std::fs::rename(staging, final_dir)
        .map_err(|e| PrepareError::io(staging, "rename into place", e))?;
    if replaced {
        std::fs::remove_dir_all(&old)
            .map_err(|e| PrepareError::io(&old, "delete the old output", e))?;
    }
    Ok(())
}
