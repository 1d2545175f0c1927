//! The body a fit moves and how it may move: the parameterisation, the one thing that differs
//! between the fits.
//!
//! - [`Freedom::Rigid`]: the posed body moved as one piece, `x -> R (x - c) + c + t` about its
//!   vertex centroid `c` (the loader's alignment to the source masks; `prepare`'s placement on
//!   the torso keypoints). Needs no body model.
//! - [`Freedom::Joints`]: the global `Rh`, `Th` and the 23 body joints' rotations, posed again
//!   by the body model's LBS (the loader's pose refinement; `prepare`'s pose stage).
//! - [`Freedom::Full`]: as `Joints`, plus the shape: betas shared by every frame of the fit
//!   (`prepare`'s shape stage).
//!
//! A step is linearised in world-frame rotations: `omega_0` turns the body about its centre
//! and `t` moves it; `omega_k` turns joint `k`'s subtree about the posed joint `J_k`, so a
//! vertex `x` moves by `W_k(x) omega_k x (x - J_k)` (`W_k(x)` the vertex's skinning weight
//! summed over `k` and its descendants) and a joint `J_j` below `k` by `omega_k x (J_j - J_k)`
//! (pose blend shapes are left out of the step, not out of the energy). `omega_k` becomes the
//! local rotation `exp(Q_p^T omega_k) R_k` (`Q_p` the parent's world rotation). The betas'
//! columns are central differences of the posed points. Every candidate is posed exactly, so
//! these first-order rows only steer the step.

use glam::{Mat3, Quat, Vec3};

use super::keypoints::KeypointBinding;
use crate::body::{BodyModel, Posed as PosedModel, SmplParams, NUM_JOINTS};

/// What a fit may change (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Freedom {
    Rigid,
    Joints,
    Full,
}

/// Parameters of a frame's step: `omega_0`, `t`, then `omega_k` of joints 1..23.
pub(crate) const JOINT_PARAMS: usize = 6 + 3 * (NUM_JOINTS - 1);
/// Skinning weights below this do not enter a vertex's Jacobian row.
const MIN_SUBTREE_WEIGHT: f32 = 1e-4;
/// Step of the betas' central differences.
const BETA_STEP: f32 = 1e-2;

impl Freedom {
    /// Step parameters of one frame (the shared betas come after every frame's).
    pub(crate) fn frame_params(self) -> usize {
        match self {
            Freedom::Rigid => 6,
            Freedom::Joints | Freedom::Full => JOINT_PARAMS,
        }
    }
}

/// A rigid motion `x -> rotation (x - centre) + centre + translation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidMotion {
    pub rotation: Quat,
    pub centre: Vec3,
    pub translation: Vec3,
}

impl RigidMotion {
    /// No motion about `centre`.
    pub fn identity(centre: Vec3) -> Self {
        RigidMotion {
            rotation: Quat::IDENTITY,
            centre,
            translation: Vec3::ZERO,
        }
    }

    /// The moved position of the world point `x`.
    pub fn apply_point(&self, x: Vec3) -> Vec3 {
        self.rotation * (x - self.centre) + self.centre + self.translation
    }

    /// Moves `vertices` ([V] world) and `params` so that they still agree: the SMPL world
    /// vertex `Rh v + Th` becomes `R Rh v + R (Th - c) + c + t`.
    pub fn apply(&self, vertices: &mut [Vec3], params: &mut SmplParams) {
        for v in vertices.iter_mut() {
            *v = self.apply_point(*v);
        }
        params.rh = (self.rotation * Quat::from_scaled_axis(params.rh)).to_scaled_axis();
        params.th = self.apply_point(params.th);
    }

    /// The rotation's angle, degrees.
    pub fn rotation_deg(&self) -> f32 {
        self.rotation.angle_between(Quat::IDENTITY).to_degrees()
    }
}

/// A frame's state: its SMPL parameters and, for [`Freedom::Rigid`], the motion of the body
/// posed at the start (identity for the other freedoms, whose steps change the parameters).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct FrameState {
    pub params: SmplParams,
    pub rigid: RigidMotion,
}

/// A frame's points where the terms read them.
#[derive(Debug, Clone)]
pub(crate) struct PosedPoints {
    /// `[indices]` world vertices ([`BodyPoints::indices`]).
    pub vertices: Vec<Vec3>,
    /// `[24]` world joints (empty without a body model).
    pub joints: Vec<Vec3>,
    /// `[24]` world rotations of the joints (empty without a body model).
    pub rotations: Vec<Quat>,
    /// `[K]` keypoints' world places.
    pub keypoints: Vec<Vec3>,
    /// Centroid of the silhouette sample: the pivot of `omega_0`.
    pub centre: Vec3,
}

/// How a point moves with the step's parameters of its frame: `omega_0`'s moment arm, `t`'s
/// coefficient and the moment arms of the joints it hangs from.
#[derive(Debug, Clone, Default)]
pub(crate) struct Arms {
    pub global: Vec3,
    pub translation: f32,
    pub joints: Vec<(usize, Vec3)>,
}

/// Which points of a body the terms read, and what stays fixed while it moves.
pub(crate) struct BodyPoints<'m> {
    pub model: Option<&'m BodyModel>,
    /// Vertex indices posed: the silhouette sample (`silhouette_len`), then the keypoint
    /// bindings' vertices.
    pub indices: Vec<usize>,
    pub silhouette_len: usize,
    /// `[indices]` the stored vertices' offsets from the model's LBS of the start parameters
    /// (zero for a fit of the model's own body).
    pub offsets: Vec<Vec3>,
    /// `[indices][24]` skinning weight summed over each joint's subtree.
    subtree: Vec<[f32; NUM_JOINTS]>,
    /// `[24]` each joint's strict ancestors.
    ancestors: Vec<Vec<usize>>,
    /// `[K]` keypoints as `(joint, weight)` and `(position in indices, weight)` pairs.
    keypoints: Vec<KeypointParts>,
    /// The start's posed points, which [`Freedom::Rigid`] moves.
    start: Option<PosedPoints>,
    /// The model posed at the start, with its betas: its shape (`v_shaped`, rest joints)
    /// serves every pose of the same betas ([`BodyModel::lbs_at`]).
    shaped: Option<(Vec<f32>, PosedModel)>,
}

/// A keypoint's `(joint, weight)` and `(position in indices, weight)` pairs.
type KeypointParts = (Vec<(usize, f32)>, Vec<(usize, f32)>);

/// Parent of joint `k` in `model` (`None` for the root).
fn parent(model: &BodyModel, k: usize) -> Option<usize> {
    model
        .parents
        .get(k)
        .copied()
        .filter(|&p| p >= 0 && (p as usize) < k)
        .map(|p| p as usize)
}

fn local_rotation(params: &SmplParams, k: usize) -> Quat {
    let p = &params.poses[3 * k..3 * k + 3];
    Quat::from_scaled_axis(Vec3::new(p[0], p[1], p[2]))
}

impl<'m> BodyPoints<'m> {
    /// The points of a body of `model` read by a fit: the silhouette sample `sample` (vertex
    /// indices) and the keypoints of `bindings`; `stored` ([V] world vertices) the fit's own
    /// vertices where they are not exactly the model's LBS of `start`.
    pub fn with_model(
        model: &'m BodyModel,
        sample: &[usize],
        bindings: &[KeypointBinding],
        start: &SmplParams,
        stored: Option<&[Vec3]>,
    ) -> Self {
        let mut indices = sample.to_vec();
        let keypoints = bindings
            .iter()
            .map(|b| {
                let vertices = b
                    .vertices
                    .iter()
                    .map(|&(v, w)| {
                        let at = indices.iter().position(|&i| i == v).unwrap_or_else(|| {
                            indices.push(v);
                            indices.len() - 1
                        });
                        (at, w)
                    })
                    .collect();
                (b.joints.clone(), vertices)
            })
            .collect();
        let shaped = model.lbs(start);
        let offsets = match stored {
            Some(stored) => indices
                .iter()
                .map(|&i| stored[i] - shaped.vertices[i])
                .collect(),
            None => vec![Vec3::ZERO; indices.len()],
        };
        let subtree = indices
            .iter()
            .map(|&i| {
                let mut w = [0.0f32; NUM_JOINTS];
                if let Some(weights) = model.weights.get(i) {
                    for (j, &wj) in weights.iter().enumerate() {
                        let mut k = Some(j);
                        while let Some(kk) = k {
                            w[kk] += wj;
                            k = parent(model, kk);
                        }
                    }
                }
                w
            })
            .collect();
        let ancestors = (0..NUM_JOINTS)
            .map(|j| {
                let mut chain = Vec::new();
                let mut k = parent(model, j);
                while let Some(kk) = k {
                    chain.push(kk);
                    k = parent(model, kk);
                }
                chain
            })
            .collect();
        BodyPoints {
            model: Some(model),
            silhouette_len: sample.len(),
            indices,
            offsets,
            subtree,
            ancestors,
            keypoints,
            start: None,
            shaped: Some((start.shapes.clone(), shaped)),
        }
    }

    /// A body of world points alone (no model, no keypoints): [`Freedom::Rigid`] only.
    pub fn rigid_points(points: Vec<Vec3>) -> Self {
        let n = points.len();
        let centre = centroid(&points);
        BodyPoints {
            model: None,
            indices: (0..n).collect(),
            silhouette_len: n,
            offsets: vec![Vec3::ZERO; n],
            subtree: Vec::new(),
            ancestors: Vec::new(),
            keypoints: Vec::new(),
            start: Some(PosedPoints {
                vertices: points,
                joints: Vec::new(),
                rotations: Vec::new(),
                keypoints: Vec::new(),
                centre,
            }),
            shaped: None,
        }
    }

    /// Fixes the start of a [`Freedom::Rigid`] fit: the body posed by `params`, which the
    /// rigid motion then moves.
    pub fn freeze_at(&mut self, params: &SmplParams) {
        if self.model.is_some() {
            self.start = Some(self.pose_params(params));
        }
    }

    /// The posed points of `state` (module docs).
    pub fn pose(&self, state: &FrameState) -> PosedPoints {
        let start = match &self.start {
            Some(start) => start.clone(),
            None => self.pose_params(&state.params),
        };
        let r = &state.rigid;
        if r.rotation == Quat::IDENTITY && r.translation == Vec3::ZERO {
            return start;
        }
        let moved =
            |points: &[Vec3]| -> Vec<Vec3> { points.iter().map(|&x| r.apply_point(x)).collect() };
        PosedPoints {
            vertices: moved(&start.vertices),
            joints: moved(&start.joints),
            rotations: start.rotations.iter().map(|&q| r.rotation * q).collect(),
            keypoints: moved(&start.keypoints),
            centre: r.apply_point(start.centre),
        }
    }

    /// The body posed by the model's LBS at `params` (the stored offsets added).
    fn pose_params(&self, params: &SmplParams) -> PosedPoints {
        let Some(model) = self.model else {
            unreachable!("a body without a model is only ever moved rigidly");
        };
        match &self.shaped {
            Some((betas, shaped)) if *betas == params.shapes => {
                let at = model.lbs_at(params, shaped, &self.indices);
                self.points_of(at.vertices, at.joints, &at.joint_transforms)
            }
            _ => self.points_of_model(&model.lbs(params)),
        }
    }

    fn points_of_model(&self, posed: &PosedModel) -> PosedPoints {
        let vertices = self.indices.iter().map(|&i| posed.vertices[i]).collect();
        self.points_of(vertices, posed.joints.clone(), &posed.joint_transforms)
    }

    /// The points from the posed `[indices]` vertices (offsets not yet added), joints and
    /// skinning transforms.
    fn points_of(
        &self,
        vertices: Vec<Vec3>,
        joints: Vec<Vec3>,
        joint_transforms: &[glam::Mat4],
    ) -> PosedPoints {
        let vertices: Vec<Vec3> = vertices
            .iter()
            .zip(&self.offsets)
            .map(|(v, o)| *v + *o)
            .collect();
        let keypoints = self
            .keypoints
            .iter()
            .map(|(js, verts)| {
                js.iter()
                    .map(|&(j, w)| joints[j] * w)
                    .chain(verts.iter().map(|&(p, w)| vertices[p] * w))
                    .sum()
            })
            .collect();
        let rotations = joint_transforms
            .iter()
            .map(|t| Quat::from_mat3(&Mat3::from_mat4(*t)).normalize())
            .collect();
        PosedPoints {
            centre: centroid(&vertices[..self.silhouette_len]),
            vertices,
            joints,
            rotations,
            keypoints,
        }
    }

    /// The arms of vertex `p` (a position in [`Self::indices`]) under `freedom`.
    pub fn vertex_arms(&self, posed: &PosedPoints, p: usize, freedom: Freedom) -> Arms {
        let x = posed.vertices[p];
        let mut arms = Arms {
            global: x - posed.centre,
            translation: 1.0,
            joints: Vec::new(),
        };
        if freedom != Freedom::Rigid {
            for (k, &w) in self.subtree[p].iter().enumerate().skip(1) {
                if w >= MIN_SUBTREE_WEIGHT {
                    arms.joints.push((k, (x - posed.joints[k]) * w));
                }
            }
        }
        arms
    }

    /// The arms of keypoint `k` under `freedom`: its joints' and vertices' arms, weighted.
    pub fn keypoint_arms(&self, posed: &PosedPoints, k: usize, freedom: Freedom) -> Arms {
        let (joints, verts) = &self.keypoints[k];
        let mut per_joint = [Vec3::ZERO; NUM_JOINTS];
        let mut arms = Arms::default();
        for &(j, w) in joints {
            let x = posed.joints[j];
            arms.global += (x - posed.centre) * w;
            arms.translation += w;
            if freedom != Freedom::Rigid {
                for &a in &self.ancestors[j] {
                    if a > 0 {
                        per_joint[a] += (x - posed.joints[a]) * w;
                    }
                }
            }
        }
        for &(p, w) in verts {
            let v = self.vertex_arms(posed, p, freedom);
            arms.global += v.global * w;
            arms.translation += w;
            for (a, m) in v.joints {
                per_joint[a] += m * w;
            }
        }
        arms.joints = per_joint
            .iter()
            .enumerate()
            .skip(1)
            .filter(|(_, m)| **m != Vec3::ZERO)
            .map(|(a, m)| (a, *m))
            .collect();
        arms
    }

    /// `d(point)/d(beta_j)` of every vertex and keypoint of the body at `params`, by central
    /// differences: `([S][indices], [S][K])`.
    pub fn beta_columns(&self, params: &SmplParams) -> (Vec<Vec<Vec3>>, Vec<Vec<Vec3>>) {
        let Some(model) = self.model else {
            return (Vec::new(), Vec::new());
        };
        let mut vertices = Vec::with_capacity(params.shapes.len());
        let mut keypoints = Vec::with_capacity(params.shapes.len());
        for j in 0..params.shapes.len() {
            let at = |h: f32| {
                let mut p = params.clone();
                p.shapes[j] += h;
                self.points_of_model(&model.lbs(&p))
            };
            let (plus, minus) = (at(BETA_STEP), at(-BETA_STEP));
            let d = |a: &[Vec3], b: &[Vec3]| -> Vec<Vec3> {
                a.iter()
                    .zip(b)
                    .map(|(a, b)| (*a - *b) / (2.0 * BETA_STEP))
                    .collect()
            };
            vertices.push(d(&plus.vertices, &minus.vertices));
            keypoints.push(d(&plus.keypoints, &minus.keypoints));
        }
        (vertices, keypoints)
    }

    /// The state after the step `delta` (this frame's parameters, `[frame_params]`) and
    /// `betas_delta` (the shared betas' step, [`Freedom::Full`]).
    pub fn step(
        &self,
        state: &FrameState,
        posed: &PosedPoints,
        freedom: Freedom,
        delta: &[f64],
        betas_delta: &[f64],
    ) -> FrameState {
        let v = |i: usize| Vec3::new(delta[i] as f32, delta[i + 1] as f32, delta[i + 2] as f32);
        let turn = Quat::from_scaled_axis(v(0));
        let mut next = state.clone();
        if freedom == Freedom::Rigid {
            // The step turns the moved body about its current centre c':
            // x' = turn (x - c') + c' + dt, composed with x = R (x0 - c_r) + c_r + t.
            let r = &state.rigid;
            let c = posed.centre;
            next.rigid.rotation = (turn * r.rotation).normalize();
            next.rigid.translation = turn * (r.centre + r.translation - c) + c + v(3) - r.centre;
            return next;
        }
        let c = posed.centre;
        next.params.rh = (turn * Quat::from_scaled_axis(state.params.rh))
            .normalize()
            .to_scaled_axis();
        next.params.th = turn * (state.params.th - c) + c + v(3);
        for k in 1..NUM_JOINTS {
            let q_parent = self.parent_rotation(posed, k);
            let local = Quat::from_scaled_axis(q_parent.inverse() * v(6 + 3 * (k - 1)));
            let r = (local * local_rotation(&state.params, k))
                .normalize()
                .to_scaled_axis();
            next.params.poses[3 * k..3 * k + 3].copy_from_slice(&r.to_array());
        }
        if freedom == Freedom::Full {
            for (b, d) in next.params.shapes.iter_mut().zip(betas_delta) {
                *b += *d as f32;
            }
        }
        next
    }

    /// World rotation of joint `k`'s parent (identity for the root).
    pub fn parent_rotation(&self, posed: &PosedPoints, k: usize) -> Quat {
        self.model
            .and_then(|m| parent(m, k))
            .and_then(|p| posed.rotations.get(p).copied())
            .unwrap_or(Quat::IDENTITY)
    }
}

/// Mean of `points` (the origin for none).
pub(crate) fn centroid(points: &[Vec3]) -> Vec3 {
    if points.is_empty() {
        return Vec3::ZERO;
    }
    points.iter().copied().sum::<Vec3>() / points.len() as f32
}

/// `[24]` per joint: the rotation taking `reference`'s local rotation to `params`'.
pub(crate) fn joint_changes(params: &SmplParams, reference: &SmplParams) -> Vec<Quat> {
    (0..NUM_JOINTS)
        .map(|k| (local_rotation(params, k) * local_rotation(reference, k).inverse()).normalize())
        .collect()
}

/// The local axis-angle of joint `k` of `params`.
pub(crate) fn local_axis_angle(params: &SmplParams, k: usize) -> Vec3 {
    let p = &params.poses[3 * k..3 * k + 3];
    Vec3::new(p[0], p[1], p[2])
}
