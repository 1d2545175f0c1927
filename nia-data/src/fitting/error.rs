//! `FitError`: why a fit could not start or finish, naming the field, frame or view.

/// Errors of the SMPL fits (the loader's alignment and `prepare`'s fitter). Frames and views
/// are 0-based indices into the caller's lists.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    /// A setting or an input out of its range.
    #[error("SMPL fit: {field}: expected {expected}, got {got}")]
    Invalid {
        field: String,
        expected: String,
        got: String,
    },
    /// No frames were given.
    #[error("no frames to fit")]
    NoFrames,
    /// A frame has no views, or a different number of views than the first frame.
    #[error(
        "frame {frame}: {got} views, expected {expected} (every frame needs the same cameras)"
    )]
    ViewCount {
        frame: usize,
        expected: usize,
        got: usize,
    },
    /// A view's keypoint list does not have one entry per keypoint binding.
    #[error("frame {frame}, view {view}: {got} keypoints, expected {expected} (one per keypoint of the layout)")]
    KeypointCount {
        frame: usize,
        view: usize,
        expected: usize,
        got: usize,
    },
    /// A keypoint with a non-finite coordinate or a confidence outside [0, 1].
    #[error("frame {frame}, view {view}, keypoint {keypoint}: {what}")]
    BadKeypoint {
        frame: usize,
        view: usize,
        keypoint: usize,
        what: String,
    },
    /// Every keypoint of the frame has zero confidence (or no binding): nothing to fit to.
    #[error("frame {frame}: no keypoint with confidence > 0 in any view (nothing to fit to)")]
    NoKeypoints { frame: usize },
    /// The body could not be placed: too few torso keypoints seen in two or more views.
    #[error("frame {frame}: cannot place the body: {what}")]
    Unplaceable { frame: usize, what: String },
    /// A keypoint binding names a joint or vertex the body model does not have.
    #[error("keypoint {keypoint}: {what}")]
    BadBinding { keypoint: usize, what: String },
    /// A silhouette whose size differs from its camera's image.
    #[error("frame {frame}, view {view}: mask is {got_w}x{got_h}, the camera's image is {w}x{h}")]
    MaskSize {
        frame: usize,
        view: usize,
        w: u32,
        h: u32,
        got_w: u32,
        got_h: u32,
    },
    /// The energy or the parameters became NaN or infinite.
    #[error("frame {frame}: the {stage} stage diverged (non-finite {what})")]
    NonFinite {
        frame: usize,
        stage: &'static str,
        what: &'static str,
    },
}

impl FitError {
    /// [`FitError::Invalid`] from its parts.
    pub fn invalid(
        field: impl Into<String>,
        expected: impl Into<String>,
        got: impl ToString,
    ) -> Self {
        FitError::Invalid {
            field: field.into(),
            expected: expected.into(),
            got: got.to_string(),
        }
    }

    /// The pose refinement asked for (`got`: the iterations) where no body model is at hand.
    pub(crate) fn no_body_model(got: String) -> Self {
        FitError::invalid(
            "pose_iterations",
            "0 when the scene source has no body model",
            got,
        )
    }
}
