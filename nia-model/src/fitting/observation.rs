//! What the fitter is given per frame: each view's camera, 2D keypoints and silhouette, and how
//! each keypoint relates to the body ([`KeypointBinding`]).

use nia_data::body::NUM_JOINTS;
use nia_data::geometry::camera::Camera;

use super::silhouette::SilhouetteTarget;
use super::FitError;

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

/// One camera's view of one frame.
#[derive(Debug, Clone)]
pub struct ViewObservation {
    /// The camera; keypoints and mask are in its raw (distorted) image.
    pub camera: Camera,
    /// `[K]` keypoints `(x, y, confidence)` in pixels, one per binding; confidence 0 marks a
    /// missing keypoint. An empty list: no keypoints in this view.
    pub keypoints: Vec<[f32; 3]>,
    /// The person's silhouette in this view, if there is one.
    pub silhouette: Option<SilhouetteTarget>,
}

/// All views of one frame.
#[derive(Debug, Clone)]
pub struct FrameObservation {
    /// `[N]` views, the same cameras in the same order in every frame.
    pub views: Vec<ViewObservation>,
}

/// Checks every frame against the bindings: view counts, keypoint counts, finite coordinates,
/// confidences in [0, 1], silhouettes the size of their images, and at least one keypoint with
/// confidence per frame.
pub(crate) fn check_frames(
    frames: &[FrameObservation],
    bindings: &[KeypointBinding],
) -> Result<(), FitError> {
    let first = frames.first().ok_or(FitError::NoFrames)?;
    let n = first.views.len();
    for (f, frame) in frames.iter().enumerate() {
        if frame.views.is_empty() || frame.views.len() != n {
            return Err(FitError::ViewCount {
                frame: f,
                expected: n.max(1),
                got: frame.views.len(),
            });
        }
        let mut any = false;
        for (v, view) in frame.views.iter().enumerate() {
            if !view.keypoints.is_empty() && view.keypoints.len() != bindings.len() {
                return Err(FitError::KeypointCount {
                    frame: f,
                    view: v,
                    expected: bindings.len(),
                    got: view.keypoints.len(),
                });
            }
            for (k, p) in view.keypoints.iter().enumerate() {
                let bad = |what: String| FitError::BadKeypoint {
                    frame: f,
                    view: v,
                    keypoint: k,
                    what,
                };
                if !p.iter().all(|x| x.is_finite()) {
                    return Err(bad(format!("non-finite value {p:?}")));
                }
                if !(0.0..=1.0).contains(&p[2]) {
                    return Err(bad(format!("confidence {} outside [0, 1]", p[2])));
                }
                any |= p[2] > 0.0 && !bindings[k].is_unmapped();
            }
            if let Some(s) = &view.silhouette {
                let (w, h) = (view.camera.width, view.camera.height);
                if s.width != w || s.height != h {
                    return Err(FitError::MaskSize {
                        frame: f,
                        view: v,
                        w,
                        h,
                        got_w: s.width,
                        got_h: s.height,
                    });
                }
            }
        }
        if !any {
            return Err(FitError::NoKeypoints { frame: f });
        }
    }
    Ok(())
}
