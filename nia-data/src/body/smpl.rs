//! The SMPL body model (Loper et al. 2015): its arrays, their validation, and reading and writing
//! them in the layout of `SMPL_NEUTRAL.pkl` (or an `.npz` with the same keys).
//!
//! Coordinates are SMPL's: right-handed, metres, y up, the body facing +z, its left side at +x.
//! The same type holds the real SMPL model and the procedural SMPL-compatible body
//! ([`super::procedural`]); linear blend skinning is in [`super::lbs`].

use std::path::Path;

use glam::Vec3;

use super::error::BodyError;
use crate::formats::{self, ArrayData, NdArray, PyValue};

/// Number of SMPL joints (pelvis plus 23 body joints).
pub const NUM_JOINTS: usize = 24;

/// Length of SMPL's pose feature: 23 non-root joints x 9 entries of `(R - I)`.
pub const NUM_POSE_FEATURES: usize = (NUM_JOINTS - 1) * 9;

/// SMPL's joint names, in SMPL's joint order.
pub const JOINT_NAMES: [&str; NUM_JOINTS] = [
    "pelvis",
    "L_hip",
    "R_hip",
    "spine1",
    "L_knee",
    "R_knee",
    "spine2",
    "L_ankle",
    "R_ankle",
    "spine3",
    "L_foot",
    "R_foot",
    "neck",
    "L_collar",
    "R_collar",
    "head",
    "L_shoulder",
    "R_shoulder",
    "L_elbow",
    "R_elbow",
    "L_wrist",
    "R_wrist",
    "L_hand",
    "R_hand",
];

/// SMPL's kinematic tree: the parent of each joint (`kintree_table[0]`), -1 for the root.
pub const SMPL_PARENTS: [i32; NUM_JOINTS] = [
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
];

/// How SMPL files mark the root in `kintree_table[0]` (`uint32(-1)`).
pub const KINTREE_ROOT: u32 = u32::MAX;

/// How far a row of skinning weights may sum from 1: float32 storage rounds at ~1e-7 per entry,
/// and files written after rounding weights to a few decimals are off by up to ~1e-4.
pub const WEIGHT_SUM_TOL: f32 = 1e-3;

/// The keys of an SMPL model file, in the order [`BodyModel::to_arrays`] writes them.
pub const SMPL_KEYS: [&str; 7] = [
    "v_template",
    "shapedirs",
    "posedirs",
    "J_regressor",
    "weights",
    "kintree_table",
    "f",
];

/// An SMPL-compatible body model.
///
/// Invariants (checked by [`BodyModel::new`], relied on by [`BodyModel::lbs`]): `V >= 1`
/// vertices, every array sized from the same `V`, [`NUM_JOINTS`] joints whose parents form a
/// tree with each parent index below its child's, skinning weight rows summing to 1 (within
/// [`WEIGHT_SUM_TOL`]), face and regressor indices below `V`, and finite values everywhere.
/// The fields are public for reading; a model whose fields are edited afterwards should be
/// checked again with [`BodyModel::validate`]. Errors from [`BodyModel::new`] are attributed to
/// [`super::error::IN_MEMORY`].
#[derive(Debug, Clone, PartialEq)]
pub struct BodyModel {
    /// `[V]` rest-pose (T-pose) template vertices, metres.
    pub v_template: Vec<Vec3>,
    /// `[V, 3, S]` shape blend shapes, flat C order: entry `(v, c, s)` at `(v * 3 + c) * S + s`;
    /// metres per unit of `beta_s`. `S` = [`BodyModel::num_betas`] (10 for SMPL).
    pub shapedirs: Vec<f32>,
    /// `[V, 3, 207]` pose blend shapes, flat C order: entry `(v, c, p)` at
    /// `(v * 3 + c) * 207 + p`, metres per unit of pose feature `p` (see [`super::lbs`]).
    pub posedirs: Vec<f32>,
    /// `[24, V]` joint regressor, stored as sparse rows: for joint `k`, `(vertex, weight)` pairs,
    /// so `J_k = sum weight * v_shaped[vertex]`.
    pub j_regressor: Vec<Vec<(u32, f32)>>,
    /// `[V, 24]` linear blend skinning weights, rows sum to 1.
    pub weights: Vec<[f32; NUM_JOINTS]>,
    /// `[24]` parent of each joint (`kintree_table[0]`), -1 for the root (joint 0).
    pub parents: Vec<i32>,
    /// `[F]` triangles, vertex indices, counter-clockwise seen from outside (normals outward).
    pub faces: Vec<[u32; 3]>,
}

impl BodyModel {
    /// Build a model from its arrays (shapes as documented on the fields) and validate it.
    ///
    /// `shapedirs` holds `V * 3 * S` values for any `S >= 0`. Regressor rows are brought to a
    /// canonical form (sorted by vertex, repeated vertices summed, zero weights dropped). Errors name the field and the
    /// expected shape; the model is attributed to [`super::error::IN_MEMORY`] (see [`BodyError::with_path`]).
    pub fn new(
        v_template: Vec<Vec3>,
        shapedirs: Vec<f32>,
        posedirs: Vec<f32>,
        j_regressor: Vec<Vec<(u32, f32)>>,
        weights: Vec<[f32; NUM_JOINTS]>,
        parents: Vec<i32>,
        faces: Vec<[u32; 3]>,
    ) -> Result<Self, BodyError> {
        // Canonical sparse rows: sorted by vertex, duplicates summed, zeros dropped.
        let j_regressor = j_regressor
            .into_iter()
            .map(|mut row| {
                row.sort_by_key(|&(i, _)| i);
                let mut merged: Vec<(u32, f32)> = Vec::with_capacity(row.len());
                for (i, w) in row {
                    match merged.last_mut() {
                        Some(last) if last.0 == i => last.1 += w,
                        _ => merged.push((i, w)),
                    }
                }
                merged.retain(|&(_, w)| w != 0.0);
                merged
            })
            .collect();
        let model = BodyModel {
            v_template,
            shapedirs,
            posedirs,
            j_regressor,
            weights,
            parents,
            faces,
        };
        model.validate()?;
        Ok(model)
    }

    /// Check the invariants listed on [`BodyModel`].
    pub fn validate(&self) -> Result<(), BodyError> {
        let v = self.v_template.len();
        if v == 0 {
            return Err(BodyError::field(
                "v_template",
                "[V, 3] with V >= 1",
                "no vertices",
            ));
        }
        if let Some(i) = self.v_template.iter().position(|p| !p.is_finite()) {
            return Err(BodyError::field(
                "v_template",
                "finite values",
                format!("{:?} at vertex {i}", self.v_template[i]),
            ));
        }
        if self.shapedirs.len() / (3 * v) * (3 * v) != self.shapedirs.len() {
            return Err(BodyError::field(
                "shapedirs",
                format!("[V, 3, S] = [{v}, 3, S]: a multiple of {} values", 3 * v),
                format!("{} values", self.shapedirs.len()),
            ));
        }
        check_finite("shapedirs", &self.shapedirs)?;
        if self.posedirs.len() != v * 3 * NUM_POSE_FEATURES {
            return Err(BodyError::field(
                "posedirs",
                format!(
                    "[V, 3, {NUM_POSE_FEATURES}] = [{v}, 3, {NUM_POSE_FEATURES}]: {} values",
                    v * 3 * NUM_POSE_FEATURES
                ),
                format!("{} values", self.posedirs.len()),
            ));
        }
        check_finite("posedirs", &self.posedirs)?;
        if self.j_regressor.len() != NUM_JOINTS {
            return Err(BodyError::field(
                "J_regressor",
                format!("[{NUM_JOINTS}, V] = [{NUM_JOINTS}, {v}]: {NUM_JOINTS} rows"),
                format!("{} rows", self.j_regressor.len()),
            ));
        }
        for (k, row) in self.j_regressor.iter().enumerate() {
            if row.is_empty() {
                return Err(BodyError::field(
                    "J_regressor",
                    format!(
                        "at least one non-zero weight in row {k} ({})",
                        JOINT_NAMES[k]
                    ),
                    "an empty row",
                ));
            }
            for &(i, w) in row {
                if i as usize >= v || !w.is_finite() {
                    return Err(BodyError::field(
                        "J_regressor",
                        format!("[{NUM_JOINTS}, {v}]: vertex indices < {v}, finite weights"),
                        format!("entry (vertex {i}, weight {w}) in row {k}"),
                    ));
                }
            }
        }
        if self.weights.len() != v {
            return Err(BodyError::field(
                "weights",
                format!("[V, {NUM_JOINTS}] = [{v}, {NUM_JOINTS}]"),
                format!("[{}, {NUM_JOINTS}]", self.weights.len()),
            ));
        }
        for (i, row) in self.weights.iter().enumerate() {
            let sum: f32 = row.iter().sum();
            if !row.iter().all(|w| w.is_finite()) || (sum - 1.0).abs() > WEIGHT_SUM_TOL {
                return Err(BodyError::field(
                    "weights",
                    format!("finite rows summing to 1 (within {WEIGHT_SUM_TOL})"),
                    format!("row {i} sums to {sum}"),
                ));
            }
        }
        if self.parents.len() != NUM_JOINTS {
            return Err(BodyError::field(
                "kintree_table",
                format!("parents of {NUM_JOINTS} joints ([2, {NUM_JOINTS}] table)"),
                format!("{} joints", self.parents.len()),
            ));
        }
        for (k, &p) in self.parents.iter().enumerate() {
            let ok = if k == 0 {
                p == -1
            } else {
                p >= 0 && (p as usize) < k
            };
            if !ok {
                return Err(BodyError::field(
                    "kintree_table",
                    "a tree rooted at joint 0 (parent -1) with every parent index below its \
                     child's",
                    format!("parent {p} for joint {k}"),
                ));
            }
        }
        for (t, f) in self.faces.iter().enumerate() {
            if f.iter().any(|&i| i as usize >= v) {
                return Err(BodyError::field(
                    "f",
                    format!("[F, 3] vertex indices < V = {v}"),
                    format!("face {t} = {f:?}"),
                ));
            }
        }
        Ok(())
    }

    /// Number of vertices `V`.
    pub fn num_vertices(&self) -> usize {
        self.v_template.len()
    }

    /// Number of shape components `S` (`shapedirs` is `[V, 3, S]`).
    pub fn num_betas(&self) -> usize {
        match self.v_template.len() {
            0 => 0,
            v => self.shapedirs.len() / (3 * v),
        }
    }

    /// `[V]` shaped rest-pose vertices `v_template + shapedirs . betas`, metres.
    ///
    /// Uses the first `min(S, betas.len())` components: missing betas count as zero (a 300-
    /// component SMPL model driven by ZJU's 10 betas), extra betas are ignored.
    pub fn shape_vertices(&self, betas: &[f32]) -> Vec<Vec3> {
        let s = self.num_betas();
        let n = s.min(betas.len());
        if n == 0 || betas[..n].iter().all(|&b| b == 0.0) {
            return self.v_template.clone();
        }
        self.v_template
            .iter()
            .enumerate()
            .map(|(v, &p)| {
                let mut offset = [0.0f64; 3];
                for (c, o) in offset.iter_mut().enumerate() {
                    let row = &self.shapedirs[(v * 3 + c) * s..(v * 3 + c) * s + n];
                    *o = row
                        .iter()
                        .zip(betas)
                        .map(|(&d, &b)| d as f64 * b as f64)
                        .sum();
                }
                (p.as_dvec3() + glam::DVec3::from_array(offset)).as_vec3()
            })
            .collect()
    }

    /// `[24]` joint locations `J_regressor . vertices` (accumulated in f64), metres.
    /// Regressor entries pointing past `vertices` are skipped.
    pub fn regress_joints(&self, vertices: &[Vec3]) -> Vec<Vec3> {
        self.regress_joints_f64(vertices)
            .into_iter()
            .map(|j| j.as_vec3())
            .collect()
    }

    pub(crate) fn regress_joints_f64(&self, vertices: &[Vec3]) -> Vec<glam::DVec3> {
        self.j_regressor
            .iter()
            .map(|row| {
                row.iter()
                    .filter_map(|&(i, w)| vertices.get(i as usize).map(|p| p.as_dvec3() * w as f64))
                    .sum()
            })
            .collect()
    }

    /// Read `SMPL_NEUTRAL.pkl` (or any SMPL-layout `.pkl`/`.npz`, see [`BodyModel::from_dict`]).
    pub fn load(path: &Path) -> Result<Self, BodyError> {
        let value = formats::load_any(path)?;
        Self::from_dict(&value, path)
    }

    /// Build a model from a decoded SMPL dict with keys `v_template [V,3]`, `shapedirs
    /// [V,3,S]`, `posedirs [V,3,207]`, `J_regressor [24,V]`, `weights [V,24]`, `kintree_table
    /// [2,24]` and `f [F,3]` (other keys are ignored). Values may be numpy arrays, chumpy `Ch`
    /// objects or (for `J_regressor`) a scipy sparse matrix, whatever
    /// [`formats::dense_array_checked`] decodes. `path` names the source in errors.
    pub fn from_dict(dict: &PyValue, path: &Path) -> Result<Self, BodyError> {
        if !matches!(dict, PyValue::Dict(_)) {
            return Err(BodyError::Field {
                path: path.to_path_buf(),
                field: "<file>".into(),
                expected: format!("a dict with keys {}", SMPL_KEYS.join(", ")),
                found: dict.type_name(),
            });
        }
        let reader = DictReader { dict, path };

        let v_template_arr = reader.array("v_template")?;
        let v = reader.dim(&v_template_arr, "v_template", 2, 0)?;
        reader.expect_shape(&v_template_arr, "v_template", &[Some(v), Some(3)], "[V, 3]")?;
        let v_template: Vec<Vec3> = reader
            .floats(&v_template_arr, "v_template")?
            .chunks_exact(3)
            .map(Vec3::from_slice)
            .collect();

        let shapedirs_arr = reader.array("shapedirs")?;
        reader.expect_shape(
            &shapedirs_arr,
            "shapedirs",
            &[Some(v), Some(3), None],
            "[V, 3, S]",
        )?;
        let shapedirs = reader.floats(&shapedirs_arr, "shapedirs")?;

        let posedirs_arr = reader.array("posedirs")?;
        reader.expect_shape(
            &posedirs_arr,
            "posedirs",
            &[Some(v), Some(3), Some(NUM_POSE_FEATURES)],
            "[V, 3, 207]",
        )?;
        let posedirs = reader.floats(&posedirs_arr, "posedirs")?;

        let regressor_arr = reader.array("J_regressor")?;
        reader.expect_shape(
            &regressor_arr,
            "J_regressor",
            &[Some(NUM_JOINTS), Some(v)],
            "[24, V]",
        )?;
        let dense = reader.floats(&regressor_arr, "J_regressor")?;
        let j_regressor = dense
            .chunks_exact(v)
            .map(|row| {
                row.iter()
                    .enumerate()
                    .filter(|(_, &w)| w != 0.0)
                    .map(|(i, &w)| (i as u32, w))
                    .collect()
            })
            .collect();

        let weights_arr = reader.array("weights")?;
        reader.expect_shape(
            &weights_arr,
            "weights",
            &[Some(v), Some(NUM_JOINTS)],
            "[V, 24]",
        )?;
        let weights = reader
            .floats(&weights_arr, "weights")?
            .chunks_exact(NUM_JOINTS)
            .map(|row| {
                let mut w = [0.0f32; NUM_JOINTS];
                w.copy_from_slice(row);
                w
            })
            .collect();

        let kintree_arr = reader.array("kintree_table")?;
        reader.expect_shape(
            &kintree_arr,
            "kintree_table",
            &[Some(2), Some(NUM_JOINTS)],
            "[2, 24]",
        )?;
        let kintree = reader.ints(&kintree_arr, "kintree_table")?;
        let (parent_row, id_row) = kintree.split_at(NUM_JOINTS);
        if id_row.iter().enumerate().any(|(k, &id)| id != k as i64) {
            return Err(BodyError::Field {
                path: path.to_path_buf(),
                field: "kintree_table".into(),
                expected: "second row = joint ids 0..23 in order".into(),
                found: format!("{id_row:?}"),
            });
        }
        let mut parents = Vec::with_capacity(NUM_JOINTS);
        for (k, &p) in parent_row.iter().enumerate() {
            let parent = if p == KINTREE_ROOT as i64 || p == -1 {
                -1
            } else if (0..NUM_JOINTS as i64).contains(&p) {
                p as i32
            } else {
                return Err(BodyError::Field {
                    path: path.to_path_buf(),
                    field: "kintree_table".into(),
                    expected: format!(
                        "parent ids in 0..{NUM_JOINTS} or {KINTREE_ROOT} (root) in the first row"
                    ),
                    found: format!("{p} for joint {k}"),
                });
            };
            parents.push(parent);
        }

        let faces_arr = reader.array("f")?;
        let f = reader.dim(&faces_arr, "f", 2, 0)?;
        reader.expect_shape(&faces_arr, "f", &[Some(f), Some(3)], "[F, 3]")?;
        let face_ids = reader.ints(&faces_arr, "f")?;
        let mut faces = Vec::with_capacity(f);
        for (t, tri) in face_ids.chunks_exact(3).enumerate() {
            let mut out = [0u32; 3];
            for (o, &i) in out.iter_mut().zip(tri) {
                if i < 0 || i >= v as i64 {
                    return Err(BodyError::Field {
                        path: path.to_path_buf(),
                        field: "f".into(),
                        expected: format!("[F, 3] vertex indices in 0..{v}"),
                        found: format!("face {t} = {tri:?}"),
                    });
                }
                *o = i as u32;
            }
            faces.push(out);
        }

        BodyModel::new(
            v_template,
            shapedirs,
            posedirs,
            j_regressor,
            weights,
            parents,
            faces,
        )
        .map_err(|e| e.with_path(path))
    }

    /// The model as SMPL's key set, ready for the npz writer, in [`SMPL_KEYS`] order:
    /// `v_template` float32 `[V, 3]`, `shapedirs` float32 `[V, 3, S]`, `posedirs` float32
    /// `[V, 3, 207]`, `J_regressor` float64 `[24, V]` (dense), `weights` float32 `[V, 24]`,
    /// `kintree_table` uint32 `[2, 24]` (parents, with [`KINTREE_ROOT`] = 4294967295 for the
    /// root, over joint ids 0..23), `f` uint32 `[F, 3]`.
    ///
    /// The per-vertex arrays are written in the model's own precision, float32 (SMPL's pickle
    /// has float64, which would double `posedirs` to 8 bytes x 621 per vertex for no extra
    /// information); readers of SMPL files accept either.
    pub fn to_arrays(&self) -> Vec<(String, NdArray)> {
        let v = self.num_vertices();
        let f32s = |x: &[f32]| ArrayData::F32(x.to_vec());
        let v_template: Vec<f32> = self.v_template.iter().flat_map(|p| p.to_array()).collect();
        let mut regressor = vec![0.0f64; NUM_JOINTS * v];
        for (k, row) in self.j_regressor.iter().enumerate().take(NUM_JOINTS) {
            for &(i, w) in row {
                if (i as usize) < v {
                    regressor[k * v + i as usize] += w as f64;
                }
            }
        }
        let weights: Vec<f32> = self.weights.iter().flatten().copied().collect();
        let mut kintree: Vec<u32> = self
            .parents
            .iter()
            .map(|&p| if p < 0 { KINTREE_ROOT } else { p as u32 })
            .collect();
        kintree.extend(0..self.parents.len() as u32);
        let faces: Vec<u32> = self.faces.iter().flatten().copied().collect();
        let arrays = [
            NdArray::new(vec![v, 3], ArrayData::F32(v_template)),
            NdArray::new(vec![v, 3, self.num_betas()], f32s(&self.shapedirs)),
            NdArray::new(vec![v, 3, NUM_POSE_FEATURES], f32s(&self.posedirs)),
            NdArray::new(vec![NUM_JOINTS, v], ArrayData::F64(regressor)),
            NdArray::new(vec![v, NUM_JOINTS], ArrayData::F32(weights)),
            NdArray::new(vec![2, self.parents.len()], ArrayData::U32(kintree)),
            NdArray::new(vec![self.faces.len(), 3], ArrayData::U32(faces)),
        ];
        SMPL_KEYS
            .iter()
            .zip(arrays)
            .map(|(k, a)| (k.to_string(), a))
            .collect()
    }

    /// [`BodyModel::to_arrays`] as a Python dict value (what [`BodyModel::from_dict`] reads).
    pub fn to_dict(&self) -> PyValue {
        PyValue::Dict(
            self.to_arrays()
                .into_iter()
                .map(|(k, a)| (PyValue::Str(k), PyValue::Array(a)))
                .collect(),
        )
    }
}

fn check_finite(field: &str, values: &[f32]) -> Result<(), BodyError> {
    match values.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(i) => Err(BodyError::field(
            field,
            "finite values",
            format!("{} at flat index {i}", values[i]),
        )),
    }
}

/// Typed access to the arrays of an SMPL dict, with errors naming the file and the key.
struct DictReader<'a> {
    dict: &'a PyValue,
    path: &'a Path,
}

impl DictReader<'_> {
    fn err(&self, key: &str, expected: impl Into<String>, found: impl Into<String>) -> BodyError {
        BodyError::Field {
            path: self.path.to_path_buf(),
            field: key.into(),
            expected: expected.into(),
            found: found.into(),
        }
    }

    fn array(&self, key: &str) -> Result<NdArray, BodyError> {
        let value = self.dict.get(key).ok_or_else(|| BodyError::MissingKey {
            path: self.path.to_path_buf(),
            key: key.into(),
            present: self.dict.keys().join(", "),
        })?;
        let array = formats::dense_array_checked(value).map_err(|reason| {
            self.err(
                key,
                "a numeric array (numpy array, chumpy Ch or scipy sparse matrix)",
                format!("{} ({reason})", value.type_name()),
            )
        })?;
        if array.numel() != array.data.len() {
            return Err(self.err(
                key,
                format!("{} elements for shape {:?}", array.numel(), array.shape),
                format!("{} elements", array.data.len()),
            ));
        }
        Ok(array)
    }

    /// Dimension `axis` of a `rank`-dimensional array.
    fn dim(&self, a: &NdArray, key: &str, rank: usize, axis: usize) -> Result<usize, BodyError> {
        if a.shape.len() != rank {
            return Err(self.err(
                key,
                format!("a {rank}-dimensional array"),
                format!("shape {:?}", a.shape),
            ));
        }
        Ok(a.shape[axis])
    }

    fn expect_shape(
        &self,
        a: &NdArray,
        key: &str,
        want: &[Option<usize>],
        pattern: &str,
    ) -> Result<(), BodyError> {
        let ok = a.shape.len() == want.len()
            && a.shape
                .iter()
                .zip(want)
                .all(|(&d, w)| w.is_none_or(|w| w == d));
        if ok {
            return Ok(());
        }
        let concrete: Vec<String> = want
            .iter()
            .map(|w| w.map_or("_".to_string(), |d| d.to_string()))
            .collect();
        Err(self.err(
            key,
            format!("shape {pattern} = [{}]", concrete.join(", ")),
            format!("shape {:?} ({})", a.shape, a.data.dtype_name()),
        ))
    }

    fn floats(&self, a: &NdArray, key: &str) -> Result<Vec<f32>, BodyError> {
        a.to_f32_vec()
            .ok_or_else(|| self.err(key, "numeric values", a.data.dtype_name()))
    }

    fn ints(&self, a: &NdArray, key: &str) -> Result<Vec<i64>, BodyError> {
        a.to_i64_vec()
            .ok_or_else(|| self.err(key, "integer values", a.data.dtype_name()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A two-triangle model with a 24-joint chain: small enough to check by hand.
    fn tiny() -> BodyModel {
        let v_template = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 1.0),
        ];
        let v = v_template.len();
        let shapedirs = (0..v * 3 * 2).map(|i| i as f32 * 0.01).collect();
        let posedirs = (0..v * 3 * NUM_POSE_FEATURES)
            .map(|i| (i % 7) as f32 * 1e-3)
            .collect();
        let j_regressor = (0..NUM_JOINTS)
            .map(|k| vec![((k % v) as u32, 0.25), (((k + 1) % v) as u32, 0.75)])
            .collect();
        let weights = (0..v)
            .map(|i| {
                let mut w = [0.0; NUM_JOINTS];
                w[i] = 0.5;
                w[i + 4] = 0.5;
                w
            })
            .collect();
        BodyModel::new(
            v_template,
            shapedirs,
            posedirs,
            j_regressor,
            weights,
            SMPL_PARENTS.to_vec(),
            vec![[0, 2, 1], [0, 3, 2]],
        )
        .expect("tiny model is valid")
    }

    #[test]
    fn to_arrays_from_dict_round_trips() {
        let model = tiny();
        let arrays = model.to_arrays();
        let keys: Vec<&str> = arrays.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(keys, SMPL_KEYS);
        let kintree = &arrays[5].1;
        assert_eq!(kintree.shape, vec![2, NUM_JOINTS]);
        match &kintree.data {
            ArrayData::U32(d) => {
                assert_eq!(d[0], 4294967295);
                assert_eq!(d[NUM_JOINTS + 23], 23);
            }
            other => panic!("kintree_table dtype {}", other.dtype_name()),
        }
        assert_eq!(arrays[3].1.shape, vec![NUM_JOINTS, 4]);
        let back = BodyModel::from_dict(&model.to_dict(), Path::new("mem.npz")).unwrap();
        // Field by field, so a failure prints only the field that differs.
        assert_eq!(back.v_template, model.v_template);
        assert_eq!(back.shapedirs, model.shapedirs);
        assert_eq!(back.posedirs, model.posedirs);
        assert_eq!(back.j_regressor, model.j_regressor);
        assert_eq!(back.weights, model.weights);
        assert_eq!(back.parents, model.parents);
        assert_eq!(back.faces, model.faces);
    }

    #[test]
    fn from_dict_names_file_and_key() {
        let model = tiny();
        let mut dict = model.to_dict();
        if let PyValue::Dict(items) = &mut dict {
            items.retain(|(k, _)| k.as_str() != Some("posedirs"));
        }
        let err = BodyModel::from_dict(&dict, Path::new("/data/SMPL_NEUTRAL.pkl"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("/data/SMPL_NEUTRAL.pkl"), "{err}");
        assert!(err.contains("posedirs"), "{err}");

        let mut dict = model.to_dict();
        if let PyValue::Dict(items) = &mut dict {
            for (k, val) in items.iter_mut() {
                if k.as_str() == Some("weights") {
                    *val = PyValue::Array(NdArray::new(
                        vec![4, 23],
                        ArrayData::F64(vec![0.0; 4 * 23]),
                    ));
                }
            }
        }
        let err = BodyModel::from_dict(&dict, Path::new("m.npz"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("m.npz") && err.contains("weights"), "{err}");
        assert!(err.contains("[V, 24]") && err.contains("[4, 23]"), "{err}");
    }
}
