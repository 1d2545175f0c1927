//! SMPL's file layout: [`BodyModel`] read from and written to the keys of `SMPL_NEUTRAL.pkl`
//! (or an `.npz` with the same keys), with errors naming the file and the key.

use std::path::Path;

use glam::Vec3;

use super::{BodyModel, KINTREE_ROOT, NUM_JOINTS, NUM_POSE_FEATURES, SMPL_KEYS};
use crate::body::error::BodyError;
use crate::formats::{self, ArrayData, NdArray, PyValue};

impl BodyModel {
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
        let reader = DictReader { dict, path };
        if !matches!(dict, PyValue::Dict(_)) {
            return Err(reader.err(
                "<file>",
                format!("a dict with keys {}", SMPL_KEYS.join(", ")),
                dict.type_name(),
            ));
        }

        let (v, v_template_arr) = reader.rows_of_three("v_template", "[V, 3]")?;
        let v_template: Vec<Vec3> = reader
            .floats(&v_template_arr, "v_template")?
            .chunks_exact(3)
            .map(Vec3::from_slice)
            .collect();

        let shapedirs_arr = reader.shaped("shapedirs", &[Some(v), Some(3), None], "[V, 3, S]")?;
        let shapedirs = reader.floats(&shapedirs_arr, "shapedirs")?;

        let posedirs_arr = reader.shaped(
            "posedirs",
            &[Some(v), Some(3), Some(NUM_POSE_FEATURES)],
            "[V, 3, 207]",
        )?;
        let posedirs = reader.floats(&posedirs_arr, "posedirs")?;

        let regressor_arr =
            reader.shaped("J_regressor", &[Some(NUM_JOINTS), Some(v)], "[24, V]")?;
        let j_regressor = reader
            .floats(&regressor_arr, "J_regressor")?
            .chunks_exact(v)
            .map(|row| {
                row.iter()
                    .enumerate()
                    .filter(|(_, &w)| w != 0.0)
                    .map(|(i, &w)| (i as u32, w))
                    .collect()
            })
            .collect();

        let weights_arr = reader.shaped("weights", &[Some(v), Some(NUM_JOINTS)], "[V, 24]")?;
        let weights = reader
            .floats(&weights_arr, "weights")?
            .chunks_exact(NUM_JOINTS)
            .map(|row| {
                let mut w = [0.0f32; NUM_JOINTS];
                w.copy_from_slice(row);
                w
            })
            .collect();

        let kintree_arr =
            reader.shaped("kintree_table", &[Some(2), Some(NUM_JOINTS)], "[2, 24]")?;
        let kintree = reader.ints(&kintree_arr, "kintree_table")?;
        let (parent_row, id_row) = kintree.split_at(NUM_JOINTS);
        if id_row.iter().enumerate().any(|(k, &id)| id != k as i64) {
            return Err(reader.err(
                "kintree_table",
                "second row = joint ids 0..23 in order",
                format!("{id_row:?}"),
            ));
        }
        let mut parents = Vec::with_capacity(NUM_JOINTS);
        for (k, &p) in parent_row.iter().enumerate() {
            let parent = if p == KINTREE_ROOT as i64 || p == -1 {
                -1
            } else if (0..NUM_JOINTS as i64).contains(&p) {
                p as i32
            } else {
                return Err(reader.err(
                    "kintree_table",
                    format!(
                        "parent ids in 0..{NUM_JOINTS} or {KINTREE_ROOT} (root) in the first row"
                    ),
                    format!("{p} for joint {k}"),
                ));
            };
            parents.push(parent);
        }

        let (f, faces_arr) = reader.rows_of_three("f", "[F, 3]")?;
        let face_ids = reader.ints(&faces_arr, "f")?;
        let mut faces = Vec::with_capacity(f);
        for (t, tri) in face_ids.chunks_exact(3).enumerate() {
            let mut out = [0u32; 3];
            for (o, &i) in out.iter_mut().zip(tri) {
                if i < 0 || i >= v as i64 {
                    return Err(reader.err(
                        "f",
                        format!("[F, 3] vertex indices in 0..{v}"),
                        format!("face {t} = {tri:?}"),
                    ));
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

    /// The array at `key`, checked to have the shape `want` (`None`: any size) that `pattern`
    /// names in errors.
    fn shaped(
        &self,
        key: &str,
        want: &[Option<usize>],
        pattern: &str,
    ) -> Result<NdArray, BodyError> {
        let a = self.array(key)?;
        self.expect_shape(&a, key, want, pattern)?;
        Ok(a)
    }

    /// The `[N, 3]` array at `key` (`pattern` names its shape in errors), with its `N`.
    fn rows_of_three(&self, key: &str, pattern: &str) -> Result<(usize, NdArray), BodyError> {
        let a = self.array(key)?;
        let n = self.dim(&a, key, 2, 0)?;
        self.expect_shape(&a, key, &[Some(n), Some(3)], pattern)?;
        Ok((n, a))
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
    use crate::body::smpl::SMPL_PARENTS;

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
