//! The SMPL body model (Loper et al. 2015): its arrays and the queries on them (shaping,
//! regressing joints).
//!
//! - this file: the constants of SMPL's skeleton and file layout, and [`BodyModel`] itself;
//! - `validate.rs`: the invariants [`BodyModel::new`] checks;
//! - `file.rs`: reading and writing the arrays in the layout of `SMPL_NEUTRAL.pkl`
//!   (or an `.npz` with the same keys).
//!
//! Coordinates are SMPL's: right-handed, metres, y up, the body facing +z, its left side at +x.
//! The same type holds the real SMPL model and the procedural SMPL-compatible body
//! ([`super::procedural`]); linear blend skinning is in [`super::lbs`].

use glam::Vec3;

use super::error::BodyError;

mod file;
mod validate;

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
        let model = BodyModel {
            v_template,
            shapedirs,
            posedirs,
            j_regressor: j_regressor.into_iter().map(canonical_row).collect(),
            weights,
            parents,
            faces,
        };
        model.validate()?;
        Ok(model)
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
}

/// A regressor row in canonical form: sorted by vertex, repeated vertices summed, zero weights
/// dropped.
fn canonical_row(mut row: Vec<(u32, f32)>) -> Vec<(u32, f32)> {
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
}
