//! The invariants of an SMPL model ([`BodyModel::validate`]): array sizes from one vertex
//! count, a joint tree, normalised skinning weights, indices in range and finite values.

use super::{BodyModel, JOINT_NAMES, NUM_JOINTS, NUM_POSE_FEATURES, WEIGHT_SUM_TOL};
use crate::body::error::BodyError;

impl BodyModel {
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
