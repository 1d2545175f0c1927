//! What a 2D keypoint detector would report about the synthetic person (`nia-train synth
//! --keypoints`): the ground-truth test bed of the SMPL fitter. For each frame and camera,
//! `keypoints/Camera_B<k>/<frame:06>_keypoints.json` in OpenPose's JSON
//! ([`crate::own_capture::keypoints`]).
//!
//! The keypoints are the true posed body's ([`crate::own_capture::keypoint_map`] on the body
//! the images show, before any SMPL-fit flaw of [`super::capture`]), projected with the true
//! camera (before any calibration flaw). Then, per keypoint, in this order:
//!
//! 1. *occlusion*: the naked body is rasterised into the view (a depth test against the
//!    z-buffer). A surface keypoint (nose, eyes, ears, toes, heels: a vertex) is occluded, and
//!    not reported, when the surface in front at its pixel lies more than [`OCCLUSION_TOL_M`]
//!    in front of it. A joint keypoint lies inside its own limb, so the same test would hide
//!    every joint: it is occluded only when that surface also belongs to another part of the
//!    body, i.e. the face's nearest vertex is skinned mostly to a joint that is not the
//!    keypoint's joint, its parent, one of its children or one of its siblings (so the collar
//!    does not hide the neck, nor one hip the other, while a far leg behind the near one or a
//!    wrist behind the torso is hidden);
//! 2. *drops*: a fraction `drop` of the visible keypoints is not reported (a detector misses);
//! 3. *noise*: Gaussian pixel noise of `noise_px` per axis, and a confidence
//!    `0.9 - 0.1 r + 0.03 n` (`r` the noise offset over `noise_px`, `n` standard normal)
//!    clamped to `[0.05, 1]`: noisier keypoints are less confident, as a detector's are;
//! 4. *outliers*: a fraction `outliers` of the reported keypoints is moved 30 to 80 pixels in a
//!    random direction (a detector confusing a limb), with a plausible confidence in
//!    `[0.3, 0.7)`.
//!
//! Two more of a real detector's habits, off unless asked for:
//! - *detector offsets* (`detector_offsets`): a detector's hips, neck and shoulders are not
//!   SMPL's joints. Its hips sit higher and wider than SMPL's hip joints, its shoulders above
//!   and outside, its neck lower and in front ([`detector_offset`]: a few centimetres in the
//!   torso's frame, magnitudes assumed from what SMPLify and SPIN report, not measured here),
//!   so every frame and view sees the same bias a fitter cannot average away;
//! - *lost runs* (`lost_runs`): a keypoint a camera misses for several frames in a row (a limb
//!   behind a prop, motion blur), not frame by frame: at each frame a (camera, keypoint) pair
//!   starts a run of 3 to 8 frames with probability `lost_runs`.
//!
//! Keypoints outside the image (after noise) are not reported. Not reported means
//! `(0, 0, 0)`, OpenPose's convention. Each (frame, camera) draws from its own fork of the
//! subject's seed (a fork no other file uses), always the same number of draws per keypoint,
//! so the keypoints are deterministic and the rest of the set is the same bytes with or
//! without them.

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::{writer, SynthError};
use crate::body::{BodyModel, SMPL_PARENTS};
use crate::geometry::camera::Camera;
use crate::geometry::raster::{rasterize, MeshError, EMPTY_FACE};
use crate::own_capture::keypoint_map::{keypoint_sources, keypoints_3d, KeypointSource};
use crate::own_capture::keypoints::{openpose_json, KeypointLayout, Keypoints2d};
use crate::rng::Rng;

/// Folder of the keypoint files in a subject folder.
pub const KEYPOINTS_DIR: &str = "keypoints";

/// How far (camera depth, metres) a surface of another body part must lie in front of a
/// keypoint to hide it: above the rasteriser's depth error at the silhouette (millimetres),
/// below the gap between limbs that cross.
pub const OCCLUSION_TOL_M: f32 = 0.02;

/// Confidence of a keypoint with no noise offset.
pub const BASE_CONFIDENCE: f32 = 0.9;

/// Outliers move this far, pixels (uniform in the range).
pub const OUTLIER_RANGE_PX: (f32, f32) = (30.0, 80.0);

/// Largest pixel noise accepted, pixels.
pub const MAX_NOISE_PX: f32 = 100.0;

/// The detector the generator imitates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KeypointSpec {
    /// Keypoint set written.
    pub layout: KeypointLayout,
    /// Standard deviation of the pixel noise per axis, pixels.
    pub noise_px: f32,
    /// Fraction of the visible keypoints not reported.
    pub drop: f32,
    /// Fraction of the reported keypoints moved 30 to 80 pixels.
    pub outliers: f32,
    /// The detector's hips, neck and shoulders off SMPL's joints ([`detector_offset`]).
    pub detector_offsets: bool,
    /// Probability per frame that a (camera, keypoint) pair starts a run of
    /// [`LOST_RUN_FRAMES`] frames without the keypoint.
    pub lost_runs: f32,
}

/// Shortest and longest run of frames a lost keypoint stays lost.
pub const LOST_RUN_FRAMES: (usize, usize) = (3, 8);

impl Default for KeypointSpec {
    /// BODY_25, 2 px noise, 10% dropped, 2% outliers.
    fn default() -> Self {
        KeypointSpec {
            layout: KeypointLayout::Body25,
            noise_px: 2.0,
            drop: 0.10,
            outliers: 0.02,
            detector_offsets: false,
            lost_runs: 0.0,
        }
    }
}

impl KeypointSpec {
    /// The first field out of range: `(spec field, expected, value)`.
    pub fn invalid(&self) -> Option<(&'static str, &'static str, f32)> {
        if !(self.noise_px.is_finite() && (0.0..=MAX_NOISE_PX).contains(&self.noise_px)) {
            return Some(("keypoints.noise_px", "pixels in [0, 100]", self.noise_px));
        }
        if !(0.0..=1.0).contains(&self.drop) {
            return Some(("keypoints.drop", "a fraction in [0, 1]", self.drop));
        }
        if !(0.0..=1.0).contains(&self.outliers) {
            return Some(("keypoints.outliers", "a fraction in [0, 1]", self.outliers));
        }
        if !(0.0..=1.0).contains(&self.lost_runs) {
            return Some((
                "keypoints.lost_runs",
                "a probability in [0, 1]",
                self.lost_runs,
            ));
        }
        None
    }
}

/// `<subject>/keypoints/Camera_B<k>/<frame:06>_keypoints.json` (OpenPose's file naming).
pub fn keypoints_path(subject_dir: &Path, camera: usize, frame: usize) -> PathBuf {
    subject_dir
        .join(KEYPOINTS_DIR)
        .join(writer::camera_dir_name(camera))
        .join(format!("{frame:06}_keypoints.json"))
}

/// Create `<subject>/keypoints/Camera_B<k>` for every camera.
pub(super) fn create_dirs(subject_dir: &Path, cameras: usize) -> Result<(), SynthError> {
    for c in 0..cameras {
        let dir = subject_dir
            .join(KEYPOINTS_DIR)
            .join(writer::camera_dir_name(c));
        std::fs::create_dir_all(&dir).map_err(|source| SynthError::Io { path: dir, source })?;
    }
    Ok(())
}

/// Joints whose parts may cover keypoint joint `j` without hiding it: `j`, its parent, its
/// children and its siblings.
fn neighbourhood(j: usize) -> Vec<usize> {
    let parent = SMPL_PARENTS.get(j).copied().unwrap_or(-1);
    let mut out = vec![j];
    if parent >= 0 {
        out.push(parent as usize);
    }
    out.extend((0..SMPL_PARENTS.len()).filter(|&c| {
        c != j && (SMPL_PARENTS[c] == j as i32 || (parent >= 0 && SMPL_PARENTS[c] == parent))
    }));
    out
}

/// Index of the largest weight (the lowest of equals).
fn dominant(weights: &[f32]) -> usize {
    weights
        .iter()
        .enumerate()
        .fold(
            (0, f32::NEG_INFINITY),
            |b, (j, &w)| if w > b.1 { (j, w) } else { b },
        )
        .0
}

/// Where a detector puts keypoint `source` against SMPL's joint, in the torso's frame (x the
/// body's left, y up, z forward), metres: OpenPose's hips higher and wider than SMPL's hip
/// joints (which sit inside the pelvis), its shoulders above and outside (on the shoulder's
/// surface, not the joint's centre), its neck lower and in front (at the base of the throat).
/// Magnitudes assumed from SMPLify's and SPIN's remarks (they down-weight or re-regress these
/// joints), not measured.
pub fn detector_offset(source: KeypointSource) -> Vec3 {
    match source {
        KeypointSource::Joint(1) => Vec3::new(0.03, 0.05, 0.0),
        KeypointSource::Joint(2) => Vec3::new(-0.03, 0.05, 0.0),
        KeypointSource::Midpoint(1, 2) | KeypointSource::Midpoint(2, 1) => {
            Vec3::new(0.0, 0.05, 0.0)
        }
        KeypointSource::Joint(12) => Vec3::new(0.0, -0.03, 0.02),
        KeypointSource::Joint(16) => Vec3::new(0.03, 0.02, 0.0),
        KeypointSource::Joint(17) => Vec3::new(-0.03, 0.02, 0.0),
        _ => Vec3::ZERO,
    }
}

/// The torso's frame of posed SMPL `joints` (columns: the body's left, up, forward), from the
/// hips (joints 1, 2), the pelvis (0) and the neck (12); `None` for a degenerate torso.
fn torso_frame(joints: &[Vec3]) -> Option<glam::Mat3> {
    let (pelvis, left_hip, right_hip, neck) = (
        joints.first()?,
        joints.get(1)?,
        joints.get(2)?,
        joints.get(12)?,
    );
    let left = (*left_hip - *right_hip).try_normalize()?;
    let up_raw = *neck - *pelvis;
    let up = (up_raw - left * up_raw.dot(left)).try_normalize()?;
    Some(glam::Mat3::from_cols(left, up, left.cross(up)))
}

/// The keypoint map of one body, ready to observe posed frames.
pub(super) struct KeypointRig {
    spec: KeypointSpec,
    sources: Vec<KeypointSource>,
    /// [V] the joint each vertex is skinned to most.
    part: Vec<usize>,
    /// [K] the parts that may cover each joint keypoint without hiding it; `None` for a
    /// surface keypoint (a plain depth test).
    allowed: Vec<Option<Vec<usize>>>,
}

impl KeypointRig {
    pub(super) fn new(spec: KeypointSpec, body: &BodyModel) -> Self {
        let sources = keypoint_sources(spec.layout, body);
        let part: Vec<usize> = body.weights.iter().map(|w| dominant(w)).collect();
        let allowed = sources
            .iter()
            .map(|s| match *s {
                KeypointSource::Joint(j) => Some(neighbourhood(j)),
                KeypointSource::Midpoint(a, b) => {
                    let mut n = neighbourhood(a);
                    n.extend(neighbourhood(b));
                    Some(n)
                }
                KeypointSource::Vertex(_) | KeypointSource::Unmapped => None,
            })
            .collect();
        KeypointRig {
            spec,
            sources,
            part,
            allowed,
        }
    }

    /// `[K]` the 3D keypoints a detector sees on a posed body (world metres): SMPL's, moved by
    /// the [`detector_offset`]s when the spec asks for them.
    pub(super) fn points_3d(&self, vertices: &[Vec3], joints: &[Vec3]) -> Vec<Option<Vec3>> {
        let points = keypoints_3d(&self.sources, vertices, joints);
        if !self.spec.detector_offsets {
            return points;
        }
        let Some(frame) = torso_frame(joints) else {
            return points;
        };
        points
            .iter()
            .zip(&self.sources)
            .map(|(p, &s)| p.map(|p| p + frame * detector_offset(s)))
            .collect()
    }

    /// Whether keypoint `k` is lost to `camera` at `frame` in a run (module docs): a run that
    /// started at one of the frames before it and lasts past it. Draws from `runs` only (one
    /// fork per (start frame, camera, keypoint)), so the other draws do not move.
    fn lost(&self, runs: &Rng, k: usize, frame: usize, camera: usize) -> bool {
        if self.spec.lost_runs <= 0.0 {
            return false;
        }
        let (shortest, longest) = LOST_RUN_FRAMES;
        let keypoints = self.sources.len();
        (frame.saturating_sub(longest - 1)..=frame).any(|start| {
            let label = ((start * 1024 + camera) * keypoints + k) as u64;
            let mut r = runs.fork(label);
            let (starts, length) = (r.uniform(), r.uniform());
            let length = shortest + (length * (longest - shortest + 1) as f32) as usize;
            starts < self.spec.lost_runs && frame < start + length.min(longest)
        })
    }

    /// The detector's report in `camera` (index `camera_index`) at `frame` of the body
    /// `(vertices, faces)` whose keypoints are `points` (from [`KeypointRig::points_3d`]);
    /// `runs`: the subject's fork the lost runs draw from.
    pub(super) fn observe(
        &self,
        camera: &Camera,
        points: &[Option<Vec3>],
        vertices: &[Vec3],
        faces: &[[u32; 3]],
        rng: &mut Rng,
        (frame, camera_index, runs): (usize, usize, &Rng),
    ) -> Result<Keypoints2d, MeshError> {
        let frags = rasterize(camera, vertices, faces)?;
        let s = &self.spec;
        let mut kp = Keypoints2d::undetected(s.layout);
        for (k, (out, point)) in kp.points.iter_mut().zip(points).enumerate() {
            // The same draws for every keypoint, whatever happens to it.
            let (n1, n2, n3) = (rng.normal(), rng.normal(), rng.normal());
            let (u_drop, u_outlier) = (rng.uniform(), rng.uniform());
            let (angle, reach) = (rng.uniform(), rng.uniform());
            let conf_outlier = rng.range(0.3, 0.7);
            let Some((uv, depth)) = point.and_then(|p| camera.project(p)) else {
                continue;
            };
            if !camera.contains_pixel(uv + Vec2::splat(0.5))
                || self.occluded(k, uv, depth, &frags, faces)
            {
                continue;
            }
            if u_drop < s.drop || self.lost(runs, k, frame, camera_index) {
                continue;
            }
            let offset = Vec2::new(n1, n2) * s.noise_px;
            let r = if s.noise_px > 0.0 {
                offset.length() / s.noise_px
            } else {
                0.0
            };
            let mut conf = (BASE_CONFIDENCE - 0.1 * r + 0.03 * n3).clamp(0.05, 1.0);
            let mut at = uv + offset;
            if u_outlier < s.outliers {
                let (lo, hi) = OUTLIER_RANGE_PX;
                let dir = Vec2::from_angle(angle * std::f32::consts::TAU);
                at += dir * (lo + (hi - lo) * reach);
                conf = conf_outlier;
            }
            if camera.contains_pixel(at + Vec2::splat(0.5)) {
                *out = [at.x, at.y, conf];
            }
        }
        Ok(kp)
    }

    /// True when the surface in front at `uv` lies more than [`OCCLUSION_TOL_M`] in front of
    /// keypoint `k`'s depth and, for a joint keypoint, belongs to a part not allowed to cover
    /// it.
    fn occluded(
        &self,
        k: usize,
        uv: Vec2,
        depth: f32,
        frags: &crate::geometry::raster::Fragments,
        faces: &[[u32; 3]],
    ) -> bool {
        let (x, y) = ((uv.x + 0.5).floor() as usize, (uv.y + 0.5).floor() as usize);
        let i = y * frags.width as usize + x;
        let (Some(&face), Some(&front), Some(bary)) =
            (frags.face.get(i), frags.depth.get(i), frags.bary.get(i))
        else {
            return false;
        };
        if face == EMPTY_FACE || front >= depth - OCCLUSION_TOL_M {
            return false;
        }
        let Some(allowed) = &self.allowed[k] else {
            return true;
        };
        let corner = dominant(bary);
        let vertex = faces[face as usize][corner] as usize;
        let part = self.part.get(vertex).copied().unwrap_or(0);
        !allowed.contains(&part)
    }
}

/// Write one keypoint file.
pub(super) fn write(path: &Path, kp: &Keypoints2d) -> Result<(), SynthError> {
    std::fs::write(path, openpose_json(Some(kp))).map_err(|source| SynthError::Io {
        path: path.to_path_buf(),
        source,
    })
}
