//! The keypoint term of a fit:
//!
//! `E_kp = sum_(k, n) c_kn rho(|pi_n(X_k) - x_kn|^2) / sum_(k, n) c_kn`
//!
//! over the keypoints `k` with a binding and the views `n`, `X_k` the keypoint's place on the
//! posed body ([`KeypointBinding`]: a weighted sum of joints and vertices), `x_kn` and `c_kn`
//! the detection and its confidence, `rho` Geman-McClure with the scale `sigma` in pixels
//! (SMPLify's data term): an outlier detection hardly pulls.

use glam::{Vec2, Vec3};

use super::projection::{project, Pixels};
use super::silhouette::{geman_mcclure, Residual};
use super::FitError;
use crate::body::NUM_JOINTS;
use crate::geometry::camera::Camera;

/// Where one 2D keypoint sits on the body: a weighted sum of posed SMPL joints and vertices
/// (an OpenPose `MidHip` is half of each hip joint; a `Nose` one vertex). Empty: the keypoint
/// has no counterpart on the body and is ignored.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct KeypointBinding {
    /// `(joint, weight)` pairs, joints in SMPL order.
    pub joints: Vec<(usize, f32)>,
    /// `(vertex, weight)` pairs, model vertex indices.
    pub vertices: Vec<(usize, f32)>,
}

impl KeypointBinding {
    /// One joint.
    pub fn joint(j: usize) -> Self {
        Self {
            joints: vec![(j, 1.0)],
            vertices: Vec::new(),
        }
    }

    /// One vertex.
    pub fn vertex(v: usize) -> Self {
        Self {
            joints: Vec::new(),
            vertices: vec![(v, 1.0)],
        }
    }

    /// The midpoint of two joints.
    pub fn midpoint(a: usize, b: usize) -> Self {
        Self {
            joints: vec![(a, 0.5), (b, 0.5)],
            vertices: Vec::new(),
        }
    }

    /// Whether the keypoint has no counterpart on the body.
    pub fn is_unmapped(&self) -> bool {
        self.joints.is_empty() && self.vertices.is_empty()
    }

    /// Whether it is made of torso joints only (pelvis, hips, spine, neck, collars,
    /// shoulders): the points that place the body before its limbs are posed.
    pub fn is_torso(&self) -> bool {
        const TORSO: [usize; 11] = [0, 1, 2, 3, 6, 9, 12, 13, 14, 16, 17];
        !self.joints.is_empty()
            && self.vertices.is_empty()
            && self.joints.iter().all(|(j, _)| TORSO.contains(j))
    }

    /// Whether it is made of the joints a 2D detector places off SMPL's (hips, neck,
    /// shoulders: a detector's hips sit higher and wider, its shoulders above and outside;
    /// docs/data.md "Own-capture inputs"), so that a fit may trust it less.
    pub fn is_offset_prone(&self) -> bool {
        const OFF_SMPL: [usize; 5] = [1, 2, 12, 16, 17];
        !self.joints.is_empty()
            && self.vertices.is_empty()
            && self.joints.iter().all(|(j, _)| OFF_SMPL.contains(j))
    }

    /// Checks indices against a model of `vertex_count` vertices.
    pub(crate) fn check(&self, keypoint: usize, vertex_count: usize) -> Result<(), FitError> {
        let bad = |what: String| FitError::BadBinding { keypoint, what };
        if let Some((j, _)) = self.joints.iter().find(|(j, _)| *j >= NUM_JOINTS) {
            return Err(bad(format!("joint {j}, the body has {NUM_JOINTS}")));
        }
        if let Some((v, _)) = self.vertices.iter().find(|(v, _)| *v >= vertex_count) {
            return Err(bad(format!("vertex {v}, the body has {vertex_count}")));
        }
        Ok(())
    }
}

/// One view's detections as [`KeypointTerms`] reads them.
pub(crate) struct KeypointView<'a> {
    pub camera: &'a Camera,
    pub pixels: Pixels,
    /// `[K]` `(x, y, confidence)` (confidence 0: missing); empty: no keypoints in the view.
    pub keypoints: &'a [[f32; 3]],
}

/// The keypoint term of one frame.
pub(crate) struct KeypointTerms<'a> {
    pub views: Vec<KeypointView<'a>>,
    pub bindings: &'a [KeypointBinding],
    /// `sigma^2`, pixels squared.
    pub sigma2: f32,
    /// Only the torso's keypoints count (the rigid placement of a frame fitted from scratch).
    pub torso_only: bool,
    /// The weight of the keypoints a detector places off SMPL's joints
    /// ([`KeypointBinding::is_offset_prone`]), on top of their confidence.
    pub offset_prone_weight: f32,
}

impl KeypointTerms<'_> {
    /// Whether keypoint `k` of `view` counts, with its confidence.
    fn confidence(&self, view: &KeypointView<'_>, k: usize) -> f32 {
        let binding = &self.bindings[k];
        let c = view.keypoints.get(k).map_or(0.0, |p| p[2]);
        if binding.is_unmapped() || (self.torso_only && !binding.is_torso()) {
            0.0
        } else if binding.is_offset_prone() {
            c * self.offset_prone_weight
        } else {
            c
        }
    }

    /// `sum c` of the counted detections.
    fn confidence_sum(&self) -> f32 {
        self.views
            .iter()
            .map(|v| {
                (0..v.keypoints.len())
                    .map(|k| self.confidence(v, k))
                    .sum::<f32>()
            })
            .sum()
    }

    /// `E_kp` of the keypoints' world places `points` (`[K]`, one per binding); with `sink`,
    /// every residual (its index: the keypoint's).
    pub fn energy(&self, points: &[Vec3], mut sink: Option<&mut dyn FnMut(Residual)>) -> f32 {
        let total = self.confidence_sum();
        if total <= 0.0 {
            return 0.0;
        }
        let mut energy = 0.0f64;
        for view in &self.views {
            for (k, detection) in view.keypoints.iter().enumerate() {
                let c = self.confidence(view, k);
                if c <= 0.0 {
                    continue;
                }
                let Some((uv, du, dv)) = project(view.camera, view.pixels, points[k]) else {
                    continue;
                };
                let e = uv - Vec2::new(detection[0], detection[1]);
                let (rho, w) = geman_mcclure(e.length_squared(), self.sigma2);
                let share = c / total;
                energy += f64::from(rho * share);
                if let Some(s) = sink.as_deref_mut() {
                    let w = w * share;
                    s(Residual {
                        index: k,
                        a: du,
                        r: e.x,
                        w,
                    });
                    s(Residual {
                        index: k,
                        a: dv,
                        r: e.y,
                        w,
                    });
                }
            }
        }
        energy as f32
    }

    /// Mean distance (pixels) between the projected and the detected keypoints with
    /// confidence, over every view (the fit's reported error).
    pub fn mean_error_px(&self, points: &[Vec3]) -> f32 {
        let (mut sum, mut count) = (0.0f64, 0usize);
        for view in &self.views {
            for (k, detection) in view.keypoints.iter().enumerate() {
                if detection[2] <= 0.0 || self.bindings[k].is_unmapped() {
                    continue;
                }
                if let Some((uv, _, _)) = project(view.camera, view.pixels, points[k]) {
                    sum += f64::from(uv.distance(Vec2::new(detection[0], detection[1])));
                    count += 1;
                }
            }
        }
        (sum / count.max(1) as f64) as f32
    }
}
