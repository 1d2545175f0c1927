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
}

impl Default for KeypointSpec {
    /// BODY_25, 2 px noise, 10% dropped, 2% outliers.
    fn default() -> Self {
        KeypointSpec {
            layout: KeypointLayout::Body25,
            noise_px: 2.0,
            drop: 0.10,
            outliers: 0.02,
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

    /// `[K]` the true 3D keypoints of a posed body (world metres).
    pub(super) fn points_3d(&self, vertices: &[Vec3], joints: &[Vec3]) -> Vec<Option<Vec3>> {
        keypoints_3d(&self.sources, vertices, joints)
    }

    /// The detector's report in `camera` of the body `(vertices, faces)` whose keypoints are
    /// `points` (from [`KeypointRig::points_3d`]).
    pub(super) fn observe(
        &self,
        camera: &Camera,
        points: &[Option<Vec3>],
        vertices: &[Vec3],
        faces: &[[u32; 3]],
        rng: &mut Rng,
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
            if u_drop < s.drop {
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
