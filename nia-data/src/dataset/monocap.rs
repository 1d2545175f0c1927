//! MonoCap (DeepCap / DynaCap sequences as Animatable NeRF prepared them): the ZJU-MoCap layout
//! plus an `lbs/` folder, images used at full resolution (ratio 1). The images, masks, cameras,
//! params and vertices go through the same reader as ZJU-MoCap ([`super::Subject`]); this file
//! reads `lbs/`.
//!
//! `lbs/` (Animatable NeRF's `prepare_lbs_meta`): `joints.npy` [24, 3] canonical joints,
//! `parents.npy` [24], `weights.npy` [V, 24] skinning weights, `faces.npy` [F, 3],
//! `tvertices.npy` [V, 3] canonical (T-pose) vertices, `bigpose_vertices.npy` [V, 3]. Each file
//! is optional; a file that is present must have its shape.

use std::path::{Path, PathBuf};

use glam::Vec3;

use super::error::DatasetError;
use super::zju::{check_finite, Numeric};
use crate::formats::{self, PyValue};

/// SMPL's joint count, the second axis of `weights.npy` and the length of `parents.npy`.
pub const LBS_JOINTS: usize = 24;

/// The contents of a MonoCap `lbs/` folder.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MonoCapLbs {
    pub dir: PathBuf,
    /// [24] canonical joints, metres.
    pub joints: Option<Vec<Vec3>>,
    /// [24] parent joint index, -1 for the root.
    pub parents: Option<Vec<i64>>,
    /// [V * 24] skinning weights, row-major per vertex.
    pub weights: Option<Vec<f32>>,
    /// [F] triangles.
    pub faces: Option<Vec<[u32; 3]>>,
    /// [V] canonical T-pose vertices, metres.
    pub tvertices: Option<Vec<Vec3>>,
    /// [V] canonical "big pose" vertices, metres.
    pub bigpose_vertices: Option<Vec<Vec3>>,
}

fn array(path: &Path) -> Result<Option<Numeric>, DatasetError> {
    if !path.is_file() {
        return Ok(None);
    }
    let value = formats::load_any(path)?;
    let a = match &value {
        PyValue::Array(a) => a,
        other => {
            return Err(DatasetError::field(
                path,
                "<array>",
                "a numeric array",
                other.type_name(),
            ))
        }
    };
    let values = a.to_f64_vec().ok_or_else(|| {
        DatasetError::field(path, "<array>", "a numeric array", a.data.dtype_name())
    })?;
    check_finite(&values, path, "<array>")?;
    Ok(Some((a.shape.clone(), values)))
}

/// The array at `path` if present, checked by `ok` (on its shape and values); `expected`
/// describes the array in the error when the check fails.
fn checked(
    path: &Path,
    expected: &str,
    ok: impl Fn(&[usize], &[f64]) -> bool,
) -> Result<Option<Numeric>, DatasetError> {
    let Some((shape, v)) = array(path)? else {
        return Ok(None);
    };
    if !ok(&shape, &v) {
        return Err(DatasetError::field(
            path,
            "<array>",
            expected,
            format!("shape {shape:?}"),
        ));
    }
    Ok(Some((shape, v)))
}

fn points(path: &Path, rows: Option<usize>) -> Result<Option<Vec<Vec3>>, DatasetError> {
    let expected = match rows {
        Some(_) => "shape [24, 3]",
        None => "shape [V, 3]",
    };
    let array = checked(path, expected, |shape, _| {
        shape.len() == 2 && shape[1] == 3 && rows.is_none_or(|r| shape[0] == r)
    })?;
    Ok(array.map(|(_, v)| {
        v.chunks_exact(3)
            .map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
            .collect()
    }))
}

impl MonoCapLbs {
    /// Reads `dir` (which must exist) and checks the shapes of the files present.
    pub fn read(dir: &Path) -> Result<MonoCapLbs, DatasetError> {
        if !dir.is_dir() {
            return Err(DatasetError::Missing {
                path: dir.to_path_buf(),
                what: "MonoCap's lbs/ folder (joints, parents, skinning weights)".into(),
            });
        }
        let joints = points(&dir.join("joints.npy"), Some(LBS_JOINTS))?;
        let parents = checked(
            &dir.join("parents.npy"),
            "24 integer parent indices",
            |_, v| v.len() == LBS_JOINTS && v.iter().all(|p| p.fract() == 0.0),
        )?
        .map(|(_, v)| v.iter().map(|p| *p as i64).collect());
        let weights = checked(&dir.join("weights.npy"), "shape [V, 24]", |shape, _| {
            shape.len() == 2 && shape[1] == LBS_JOINTS
        })?
        .map(|(_, v)| v.iter().map(|w| *w as f32).collect());
        let faces = checked(
            &dir.join("faces.npy"),
            "shape [F, 3] of vertex indices",
            |shape, v| {
                shape.len() == 2 && shape[1] == 3 && v.iter().all(|i| *i >= 0.0 && i.fract() == 0.0)
            },
        )?
        .map(|(_, v)| {
            v.chunks_exact(3)
                .map(|c| [c[0] as u32, c[1] as u32, c[2] as u32])
                .collect()
        });
        Ok(MonoCapLbs {
            dir: dir.to_path_buf(),
            joints,
            parents,
            weights,
            faces,
            tvertices: points(&dir.join("tvertices.npy"), None)?,
            bigpose_vertices: points(&dir.join("bigpose_vertices.npy"), None)?,
        })
    }

    /// Number of vertices the per-vertex files agree on, if any is present.
    pub fn num_vertices(&self) -> Option<usize> {
        self.weights
            .as_ref()
            .map(|w| w.len() / LBS_JOINTS)
            .or(self.tvertices.as_ref().map(Vec::len))
            .or(self.bigpose_vertices.as_ref().map(Vec::len))
    }
}
