//! The reposing transform of pose animation (docs/method.md, "Method", step 9).
//!
//! A query point `x` of the TARGET pose is carried to the REFERENCE (capture) pose, where the
//! source views were taken, by `T = T_fwd o T_inv`:
//!
//! 1. `T_inv`: inverse linear blend skinning to the canonical (rest, shaped) space,
//!    `x_c = A_tgt(x)^-1 x`, with `A_tgt(x) = sum_k w_k(x) A^tgt_k` and `w(x)` the barycentric
//!    interpolation of the per-vertex skinning weights over the face of the TARGET posed mesh
//!    nearest to `x`;
//! 2. `T_fwd`: forward skinning to the reference pose, `x' = A_ref(x_c) x_c`, with the weights
//!    interpolated over the face of the CANONICAL mesh (`v_shaped`) nearest to `x_c`.
//!
//! `A^pose_k` are [`Posed::joint_transforms`]: rest (shaped) space to world, `Rh`/`Th`
//! included. SMPL skins `v_shaped + B_P(theta)` (pose blend shapes `B_P`), so the canonical
//! point also drops the target pose's corrective offset and the forward step adds the
//! reference pose's, both interpolated over the same nearest faces (per-vertex offsets
//! `A(w_v)^-1 v - v_shaped`): a target vertex then lands exactly on the same reference vertex,
//! the correspondence the body volume uses (reference vertex features re-attached by index).
//! Bodies without pose blend shapes (the procedural one) skip this.
//!
//! A view direction follows the linear part of the relative transform,
//! `d' = normalise(L_ref(x_c) L_tgt(x)^-1 d)`: on a single rigid limb this is the limb's
//! rotation; between limbs the blended matrix is a rotation scaled a little, which the
//! normalisation removes.
//!
//! Two cases never touch the surfaces: equal parameters (the identity; callers check
//! [`Reposer::needed`] and skip reposing altogether) and equal body pose and shape with a
//! different global placement (`Rh`, `Th`), which is exactly the rigid map
//! `x' = R_ref R_tgt^T (x - Th_tgt) + Th_ref`: the body does not deform, so no point may.
//!
//! Where the blended target matrix is near-singular (`|det| <` [`INVERSE_LBS_MIN_DET`], the
//! criterion of [`crate::body::inverse_lbs`]: opposite rotations blended half and half) the
//! point instead follows the rigid relative transform `A^ref_k (A^tgt_k)^-1` of the dominant
//! joint `k` of the nearest target vertex; such points are counted in
//! [`RepositionedPoints::fallback`]. The output is finite for every finite input.
//!
//! Query points are data (no gradient flows through them). The blended transforms are formed
//! in f64, as in `crate::body::lbs`, and results are rounded to f32 once.

use glam::{DAffine3, DMat3, DVec3, Mat3, Vec3};
use rayon::prelude::*;

use super::{
    rodrigues, rodrigues_f64, BodyError, BodyModel, Posed, SmplParams, INVERSE_LBS_MIN_DET,
    NUM_JOINTS,
};
use crate::geometry::raster::MeshError;
use crate::geometry::surface::{interpolate_weights, Nearest, SurfaceIndex};

/// Query points per rayon task at least: one point is two nearest-face queries (a few
/// microseconds), so smaller tasks cost more in scheduling than they balance.
const MIN_POINTS_PER_TASK: usize = 256;

/// Directions shorter than this (after the transform) are returned unchanged instead of being
/// normalised: a zero input direction stays zero rather than becoming NaN.
const MIN_DIRECTION_NORM: f64 = 1e-12;

/// An error of [`Reposer`].
#[derive(Debug, thiserror::Error)]
pub enum RepositionError {
    /// The body model failed validation.
    #[error("Reposer::new: body model: {0}")]
    Body(#[from] BodyError),
    /// A nearest-surface index could not be built on a posed or canonical mesh.
    #[error("Reposer::new: {mesh} mesh: {source}")]
    Mesh {
        mesh: &'static str,
        #[source]
        source: MeshError,
    },
    /// A field of the reference or target parameters holds a non-finite value.
    #[error(
        "Reposer::new: {which} SmplParams field `{field}`: expected finite values, found {found}"
    )]
    Params {
        which: &'static str,
        field: &'static str,
        found: String,
    },
    /// The target has another body shape than the reference.
    #[error(
        "Reposer::new: target SmplParams field `shapes`: expected the reference's shape \
         coefficients (animation keeps the subject's body shape; copy the reference `shapes` \
         into the target), found beta[{index}] = {target} against {reference}"
    )]
    ShapeMismatch {
        index: usize,
        reference: f32,
        target: f32,
    },
    /// `dirs` passed to [`Reposer::map_points`] does not match `points`.
    #[error(
        "Reposer::map_points: `dirs` has {got} entries, expected {expected} (one per point) or 0"
    )]
    DirsLength { got: usize, expected: usize },
}

/// The output of [`Reposer::map_points`].
#[derive(Debug, Clone, PartialEq)]
pub struct RepositionedPoints {
    /// `[M]` the query points carried to the reference pose, world metres.
    pub points: Vec<Vec3>,
    /// `[M]` unit directions in the reference pose (empty when no directions were given).
    pub dirs: Vec<Vec3>,
    /// How many points took the fallback (near-singular blended target matrix, or a query
    /// point that is not finite, which is returned unchanged).
    pub fallback: usize,
}

/// `sum_k w_k A_k` over the pairs of the two slices, zero weights skipped (the f64 affine
/// counterpart of [`crate::body::blend_transform`]).
fn blend(weights: &[f32], transforms: &[DAffine3]) -> DAffine3 {
    let mut matrix3 = DMat3::ZERO;
    let mut translation = DVec3::ZERO;
    for (&w, a) in weights.iter().zip(transforms) {
        if w != 0.0 {
            let w = w as f64;
            matrix3 += a.matrix3 * w;
            translation += a.translation * w;
        }
    }
    DAffine3::from_mat3_translation(matrix3, translation)
}

/// The inverse of an affine map, or `None` when `|det| <` [`INVERSE_LBS_MIN_DET`] (the
/// criterion of [`crate::body::inverse_lbs`], which returns only the point: the direction
/// needs the matrix too) or the result is not finite.
fn checked_inverse(a: &DAffine3) -> Option<DAffine3> {
    let det = a.matrix3.determinant();
    if det.is_nan() || det.abs() < INVERSE_LBS_MIN_DET {
        return None;
    }
    let inverse = a.inverse();
    inverse.is_finite().then_some(inverse)
}

/// `a` applied to a point and (normalised) to a direction.
fn apply(a: &DAffine3, x: Vec3, d: Option<Vec3>) -> (Vec3, Option<Vec3>) {
    let p = a.transform_point3(x.as_dvec3()).as_vec3();
    let d = d.map(|d| {
        let v = a.transform_vector3(d.as_dvec3());
        let n = v.length();
        if n.is_finite() && n > MIN_DIRECTION_NORM {
            (v / n).as_vec3()
        } else {
            d
        }
    });
    (p, d)
}

/// The per-joint transforms of a posed body.
fn joint_affines(posed: &Posed) -> Vec<DAffine3> {
    posed
        .joint_transforms
        .iter()
        .map(|m| DAffine3::from_mat4(m.as_dmat4()))
        .collect()
}

/// The global placement `x -> R(Rh) x + Th` of `params`.
fn global_placement(params: &SmplParams) -> DAffine3 {
    DAffine3::from_mat3_translation(rodrigues_f64(params.rh.as_dvec3()), params.th.as_dvec3())
}

/// Shape coefficient `i`, missing ones counting as zero (as `BodyModel` reads them).
fn beta(shapes: &[f32], i: usize) -> f32 {
    shapes.get(i).copied().unwrap_or(0.0)
}

/// The first shape coefficient in which the two parameter sets differ.
fn first_shape_difference(reference: &SmplParams, target: &SmplParams) -> Option<usize> {
    let n = reference.shapes.len().max(target.shapes.len());
    (0..n).find(|&i| beta(&reference.shapes, i) != beta(&target.shapes, i))
}

/// Checks that every field of `params` is finite.
fn check_finite(which: &'static str, params: &SmplParams) -> Result<(), RepositionError> {
    let bad = |field: &'static str, found: String| RepositionError::Params {
        which,
        field,
        found,
    };
    if let Some(i) = params.poses.iter().position(|x| !x.is_finite()) {
        return Err(bad("poses", format!("{} at index {i}", params.poses[i])));
    }
    if let Some(i) = params.shapes.iter().position(|x| !x.is_finite()) {
        return Err(bad("shapes", format!("{} at index {i}", params.shapes[i])));
    }
    if !params.rh.is_finite() {
        return Err(bad("rh", format!("{}", params.rh)));
    }
    if !params.th.is_finite() {
        return Err(bad("th", format!("{}", params.th)));
    }
    Ok(())
}

/// Barycentric interpolation of per-vertex vectors over the face of `near`; zero where the
/// face does not index `values`.
fn interpolate_vec3(near: &Nearest, faces: &[[u32; 3]], values: &[DVec3]) -> DVec3 {
    let Some(face) = faces.get(near.face as usize) else {
        return DVec3::ZERO;
    };
    face.iter()
        .zip(near.bary)
        .filter_map(|(&v, b)| values.get(v as usize).map(|value| *value * b as f64))
        .sum()
}

/// `[V]` the pose-corrective offset of every vertex of `posed` (rest space, metres): its
/// unskinned position `A(w_v)^-1 v` minus its shaped rest position `v_shaped`; zero where the
/// vertex's blended transform is singular.
fn pose_offsets(posed: &Posed, weights: &[[f32; NUM_JOINTS]]) -> Vec<DVec3> {
    let transforms = joint_affines(posed);
    posed
        .vertices
        .iter()
        .zip(&posed.v_shaped)
        .zip(weights)
        .map(
            |((v, shaped), w)| match checked_inverse(&blend(w, &transforms)) {
                Some(inverse) => inverse.transform_point3(v.as_dvec3()) - shaped.as_dvec3(),
                None => DVec3::ZERO,
            },
        )
        .collect()
}

/// What [`Reposer::map_points`] does.
#[derive(Debug, Clone)]
enum Mode {
    /// Target == reference: points and directions come back unchanged.
    Identity,
    /// Same body pose and shape, different `Rh`/`Th`: one rigid map for every point.
    Rigid(DAffine3),
    /// The full `T_fwd o T_inv` through the two nearest-surface indices.
    Deform(Box<Deformation>),
}

/// Per-vertex pose-corrective offsets of the two poses, rest space, metres.
#[derive(Debug, Clone)]
struct PoseOffsets {
    /// `[V]` target pose.
    target: Vec<DVec3>,
    /// `[V]` reference pose.
    reference: Vec<DVec3>,
}

/// The state of the full transform.
#[derive(Debug, Clone)]
struct Deformation {
    /// Nearest-face index on the target posed mesh (world).
    target_index: SurfaceIndex,
    /// Nearest-face index on the canonical mesh (`v_shaped`).
    canonical_index: SurfaceIndex,
    /// `[F]` faces of both meshes.
    faces: Vec<[u32; 3]>,
    /// `[V * 24]` per-vertex skinning weights, row-major.
    weights: Vec<f32>,
    /// `[24]` target-pose joint transforms `A^tgt_k` (rest to world).
    target: Vec<DAffine3>,
    /// `[24]` reference-pose joint transforms `A^ref_k` (rest to world).
    reference: Vec<DAffine3>,
    /// `[24]` rigid fallbacks `A^ref_k (A^tgt_k)^-1`, identity where `A^tgt_k` is singular.
    joint_relative: Vec<DAffine3>,
    /// Pose-corrective offsets; `None` when the model has no pose blend shapes.
    pose_offsets: Option<PoseOffsets>,
}

impl Deformation {
    /// The fallback for a point whose nearest target face is `near`: the rigid relative
    /// transform of the dominant joint (first on ties) of the face's nearest vertex (largest
    /// barycentric).
    fn dominant_joint(&self, near: &Nearest) -> DAffine3 {
        let first_max = |values: &[f32]| {
            (0..values.len())
                .max_by(|&a, &b| values[a].total_cmp(&values[b]).then(b.cmp(&a)))
                .unwrap_or(0)
        };
        let vertex = self
            .faces
            .get(near.face as usize)
            .map_or(0, |f| f[first_max(&near.bary)] as usize);
        let row = self
            .weights
            .get(vertex * NUM_JOINTS..(vertex + 1) * NUM_JOINTS)
            .unwrap_or(&[]);
        self.joint_relative
            .get(first_max(row))
            .copied()
            .unwrap_or(DAffine3::IDENTITY)
    }

    /// The relative transform `A_ref(x_c) A_tgt(x)^-1` at `x` (with the pose-corrective
    /// offsets in its translation), and whether it is the fallback. `w`: scratch weights.
    fn relative(&self, x: Vec3, w: &mut [f32; NUM_JOINTS]) -> (DAffine3, bool) {
        let near = self.target_index.nearest(x);
        if !near.is_hit() {
            return (DAffine3::IDENTITY, true);
        }
        let fallback = || (self.dominant_joint(&near), true);
        if interpolate_weights(&near, &self.faces, &self.weights, NUM_JOINTS, w).is_err() {
            return fallback();
        }
        let Some(inverse) = checked_inverse(&blend(w, &self.target)) else {
            return fallback();
        };
        // Canonical point: unskinned, minus the target pose's corrective offset.
        let o_target = self
            .pose_offsets
            .as_ref()
            .map(|offsets| interpolate_vec3(&near, &self.faces, &offsets.target));
        let x_c = inverse.transform_point3(x.as_dvec3()) - o_target.unwrap_or(DVec3::ZERO);
        let near_c = self.canonical_index.nearest(x_c.as_vec3());
        if !near_c.is_hit()
            || interpolate_weights(&near_c, &self.faces, &self.weights, NUM_JOINTS, w).is_err()
        {
            return fallback();
        }
        let forward = blend(w, &self.reference);
        let mut relative = forward * inverse;
        if let (Some(offsets), Some(o_target)) = (&self.pose_offsets, o_target) {
            // x' = A_ref (A_tgt^-1 x - o_tgt + o_ref): the offsets enter the translation.
            let o_reference = interpolate_vec3(&near_c, &self.faces, &offsets.reference);
            relative.translation += forward.transform_vector3(o_reference - o_target);
        }
        if relative.is_finite() {
            (relative, false)
        } else {
            fallback()
        }
    }
}

/// The reposing transform from one target pose to one reference pose of the same body.
///
/// Built once per (reference, target) pair: poses both and, when the body pose differs,
/// builds the nearest-face indices of the target posed mesh and of the canonical mesh.
#[derive(Debug, Clone)]
pub struct Reposer {
    mode: Mode,
    reference: Posed,
    /// `None` for the identity (then `reference` serves as the target too).
    target: Option<Posed>,
    /// The target's global placement (Rh as a rotation, Th): `world = R x_smpl + Th`.
    target_rotation: Mat3,
    target_translation: Vec3,
}

impl Reposer {
    /// Whether reposing does anything for this pair: `false` when the parameters are equal
    /// (shape coefficients compared with missing ones as zero). Cheap; callers check it before
    /// building a [`Reposer`] and skip reposing entirely when it is `false`.
    pub fn needed(reference: &SmplParams, target: &SmplParams) -> bool {
        !(reference.poses == target.poses
            && reference.rh == target.rh
            && reference.th == target.th
            && first_shape_difference(reference, target).is_none())
    }

    /// Poses `model` in both parameter sets and prepares the transform: nothing more for the
    /// identity or a change of global placement only; otherwise the nearest-face indices of
    /// the target posed mesh and of the canonical mesh (a few tens of milliseconds at SMPL's
    /// size).
    ///
    /// Errors: the model fails [`BodyModel::validate`]; a parameter is not finite; the target
    /// shape differs from the reference shape (animation keeps the subject's shape).
    pub fn new(
        model: &BodyModel,
        reference: &SmplParams,
        target: &SmplParams,
    ) -> Result<Self, RepositionError> {
        model.validate()?;
        check_finite("reference", reference)?;
        check_finite("target", target)?;
        if let Some(index) = first_shape_difference(reference, target) {
            return Err(RepositionError::ShapeMismatch {
                index,
                reference: beta(&reference.shapes, index),
                target: beta(&target.shapes, index),
            });
        }
        let reference_posed = model.lbs(reference);
        if !Self::needed(reference, target) {
            return Ok(Reposer {
                mode: Mode::Identity,
                reference: reference_posed,
                target: None,
                target_rotation: rodrigues(target.rh),
                target_translation: target.th,
            });
        }
        let target_posed = model.lbs(target);
        let mode = if reference.poses == target.poses {
            // G_ref G_tgt^-1: the rest-to-world chains differ only by the global placement.
            Mode::Rigid(global_placement(reference) * global_placement(target).inverse())
        } else {
            let mesh = |mesh: &'static str| {
                move |source: MeshError| RepositionError::Mesh { mesh, source }
            };
            let target_index = SurfaceIndex::new(&target_posed.vertices, &model.faces)
                .map_err(mesh("target posed"))?;
            let canonical_index = SurfaceIndex::new(&target_posed.v_shaped, &model.faces)
                .map_err(mesh("canonical"))?;
            let target_affines = joint_affines(&target_posed);
            let reference_affines = joint_affines(&reference_posed);
            let joint_relative = target_affines
                .iter()
                .zip(&reference_affines)
                .map(|(t, r)| checked_inverse(t).map_or(DAffine3::IDENTITY, |inv| *r * inv))
                .collect();
            let pose_offsets = model
                .posedirs
                .iter()
                .any(|&p| p != 0.0)
                .then(|| PoseOffsets {
                    target: pose_offsets(&target_posed, &model.weights),
                    reference: pose_offsets(&reference_posed, &model.weights),
                });
            Mode::Deform(Box::new(Deformation {
                target_index,
                canonical_index,
                faces: model.faces.clone(),
                weights: model.weights.as_flattened().to_vec(),
                target: target_affines,
                reference: reference_affines,
                joint_relative,
                pose_offsets,
            }))
        };
        Ok(Reposer {
            mode,
            reference: reference_posed,
            target: Some(target_posed),
            target_rotation: rodrigues(target.rh),
            target_translation: target.th,
        })
    }

    /// A target-pose world point in the target's SMPL frame: `R(Rh_t)^T (x - Th_t)`.
    pub fn target_to_smpl(&self, p: Vec3) -> Vec3 {
        self.target_rotation.transpose() * (p - self.target_translation)
    }

    /// [V] target-pose vertices in the target's SMPL frame (where the body volume of an
    /// animation is built), metres.
    pub fn target_vertices_smpl(&self) -> Vec<[f32; 3]> {
        self.target_vertices()
            .iter()
            .map(|&v| self.target_to_smpl(v).to_array())
            .collect()
    }

    /// Whether this reposer is the identity (target parameters equal the reference ones).
    pub fn is_identity(&self) -> bool {
        matches!(self.mode, Mode::Identity)
    }

    /// Whether the body pose is unchanged and only the global placement (`Rh`, `Th`) differs:
    /// every point then moves by one rigid transform.
    pub fn is_rigid(&self) -> bool {
        matches!(self.mode, Mode::Rigid(_))
    }

    /// The body in the reference pose.
    pub fn reference_posed(&self) -> &Posed {
        &self.reference
    }

    /// The body in the target pose.
    pub fn target_posed(&self) -> &Posed {
        self.target.as_ref().unwrap_or(&self.reference)
    }

    /// `[V]` reference-pose world vertices, metres.
    pub fn reference_vertices(&self) -> &[Vec3] {
        &self.reference.vertices
    }

    /// `[V]` target-pose world vertices, metres (the body volume is built on these).
    pub fn target_vertices(&self) -> &[Vec3] {
        &self.target_posed().vertices
    }

    /// Carries target-pose query points (`points`: [M] world metres) and their directions
    /// (`dirs`: [M], any length; or empty for none) to the reference pose: [M] points and
    /// [M] unit directions (zero directions stay zero). Parallel over points (rayon).
    pub fn map_points(
        &self,
        points: &[Vec3],
        dirs: &[Vec3],
    ) -> Result<RepositionedPoints, RepositionError> {
        if !dirs.is_empty() && dirs.len() != points.len() {
            return Err(RepositionError::DirsLength {
                got: dirs.len(),
                expected: points.len(),
            });
        }
        let dir = |i: usize| dirs.get(i).copied();
        let mapped: Vec<(Vec3, Option<Vec3>, bool)> = match &self.mode {
            Mode::Identity => {
                return Ok(RepositionedPoints {
                    points: points.to_vec(),
                    dirs: dirs.to_vec(),
                    fallback: 0,
                })
            }
            Mode::Rigid(rigid) => points
                .iter()
                .enumerate()
                .map(|(i, &x)| {
                    let (p, d) = apply(rigid, x, dir(i));
                    (p, d, false)
                })
                .collect(),
            Mode::Deform(deformation) => points
                .par_iter()
                .enumerate()
                .with_min_len(MIN_POINTS_PER_TASK)
                .map_init(
                    || [0.0f32; NUM_JOINTS],
                    |w, (i, &x)| {
                        if !x.is_finite() {
                            return (x, dir(i), true);
                        }
                        let (relative, fell_back) = deformation.relative(x, w);
                        let (p, d) = apply(&relative, x, dir(i));
                        (p, d, fell_back)
                    },
                )
                .collect(),
        };
        let mut out = RepositionedPoints {
            points: Vec::with_capacity(mapped.len()),
            dirs: Vec::with_capacity(dirs.len()),
            fallback: 0,
        };
        for (p, d, fell_back) in mapped {
            out.points.push(p);
            out.dirs.extend(d);
            out.fallback += usize::from(fell_back);
        }
        Ok(out)
    }
}
