//! What the fitter is given per frame: each view's camera, 2D keypoints and silhouette (how each
//! keypoint relates to the body: [`KeypointBinding`]).

use super::keypoints::KeypointBinding;
use super::silhouette::SilhouetteTarget;
use super::FitError;
use crate::geometry::camera::Camera;

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
