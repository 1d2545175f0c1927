//! The error of a protocol that cannot be applied: an invalid definition, or one that does
//! not fit a subject's data.

/// A protocol error: a definition that cannot be applied to the data.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProtocolError {
    #[error("protocol `{protocol}`: {field}: {msg}")]
    Invalid {
        protocol: String,
        field: String,
        msg: String,
    },
    #[error(
        "protocol `{protocol}`: subject `{subject}`: view {view} of `{field}` does not exist \
         (the subject has {num_cameras} cameras)"
    )]
    ViewOutOfRange {
        protocol: String,
        subject: String,
        field: &'static str,
        view: usize,
        num_cameras: usize,
    },
    /// An evaluation target that is also one of the input views: the render would see the
    /// image it is scored against.
    #[error(
        "protocol `{protocol}`: subject `{subject}`: target view {view} (camera index) is also \
         one of the input views {inputs:?}; a target view must be held out from the inputs"
    )]
    TargetIsInput {
        protocol: String,
        subject: String,
        view: usize,
        inputs: Vec<usize>,
    },
    #[error(
        "protocol `{protocol}`: subject `{subject}`: frame range starts at {begin} but the \
         subject has only {num_frames} frames"
    )]
    FramesOutOfRange {
        protocol: String,
        subject: String,
        begin: usize,
        num_frames: usize,
    },
}
