//! The evaluation protocol as data: which subjects train, which are held out, which frames and
//! camera views are used (docs/method.md "Protocol"). Everything here is a plain `serde` value, so a
//! run config can carry or override any part of it.
//!
//! [`Protocol::nhp`] is Neural Human Performer's ZJU-MoCap protocol, which NIA follows (values
//! from NHP's `get_human_info.py`, `FrameSampler` and `train_or_eval.yaml`):
//! - train subjects 313, 315, 377, 386, 390, 392, 396 (each with its own frame range);
//! - unseen test subjects 387, 393, 394 (all frames);
//! - seen subjects, unseen poses: the frames after each training range;
//! - test input views `[0, 7, 15]`, target views `[3, 5, 10, 12, 18, 20]` (`[.., 21]` for 313
//!   and 315, whose annotations list 21 cameras);
//! - every 30th frame of a test range (counted from the range's first frame);
//! - training: 3 input views drawn at random among all cameras, any camera as the target.
//!
//! Frames are indices into `annots['ims']` (positions, not file numbers).
//!
//! - this file: the definitions ([`Protocol`], [`ViewSet`], [`FrameRange`], the splits);
//! - `presets.rs`: the NHP, synthetic, named-subjects and MonoCap protocols;
//! - `resolve.rs`: a protocol resolved against a subject's cameras and frames
//!   (its views, frames and evaluation images);
//! - `checks.rs`: checks of the definition and of a subject's data against it;
//! - `error.rs`: [`ProtocolError`].

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

mod checks;
mod error;
mod presets;
mod resolve;

pub use error::ProtocolError;
pub use presets::{
    SubjectSplit, NHP_INPUT_VIEWS, NHP_TARGET_VIEWS, NHP_TARGET_VIEWS_313_315,
    NHP_TEST_FRAME_STRIDE, SYNTH_TRAIN_FRAME_FRACTION,
};

/// Frames `begin, begin + interval, ...` below `begin + count` (and below the number of frames
/// the subject has). `count: None` means "to the last frame".
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameRange {
    pub begin: usize,
    #[serde(default)]
    pub count: Option<usize>,
    #[serde(default = "one")]
    pub interval: usize,
}

fn one() -> usize {
    1
}

impl FrameRange {
    pub fn new(begin: usize, count: usize, interval: usize) -> Self {
        FrameRange {
            begin,
            count: Some(count),
            interval,
        }
    }

    /// Every frame from `begin` on.
    pub fn all_from(begin: usize) -> Self {
        FrameRange {
            begin,
            count: None,
            interval: 1,
        }
    }

    /// The frame indices this range selects among `num_frames` frames (clipped, like NHP's
    /// `annots['ims'][begin:begin + count][::interval]`).
    pub fn frames(&self, num_frames: usize) -> Vec<usize> {
        let end = match self.count {
            Some(c) => self.begin.saturating_add(c).min(num_frames),
            None => num_frames,
        };
        (self.begin..end).step_by(self.interval.max(1)).collect()
    }
}

/// A subject (its folder name, e.g. `CoreView_313`) and the frames a split uses from it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SubjectFrames {
    pub subject: String,
    pub frames: FrameRange,
}

impl SubjectFrames {
    pub fn new(subject: impl Into<String>, frames: FrameRange) -> Self {
        SubjectFrames {
            subject: subject.into(),
            frames,
        }
    }
}

/// A set of camera views, explicit or derived from the number of cameras.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ViewSet {
    /// These camera indices (positions in `annots['cams']`).
    Explicit { views: Vec<usize> },
    /// `count` views spread evenly: `floor(i * num_cameras / count)` for `i < count`
    /// (23 cameras, 3 views: `[0, 7, 15]`, NHP's input views).
    Evenly { count: usize },
    /// Every `stride`-th camera that is not an input view.
    OthersThanInputs { stride: usize },
}

impl ViewSet {
    pub fn explicit(views: &[usize]) -> Self {
        ViewSet::Explicit {
            views: views.to_vec(),
        }
    }

    /// The views for a subject with `num_cameras` cameras; `inputs` is used by
    /// [`ViewSet::OthersThanInputs`].
    pub fn resolve(&self, num_cameras: usize, inputs: &[usize]) -> Vec<usize> {
        match self {
            ViewSet::Explicit { views } => views.clone(),
            ViewSet::Evenly { count } => {
                let count = (*count).min(num_cameras);
                (0..count).map(|i| i * num_cameras / count).collect()
            }
            ViewSet::OthersThanInputs { stride } => (0..num_cameras)
                .filter(|v| !inputs.contains(v))
                .step_by((*stride).max(1))
                .collect(),
        }
    }
}

/// The evaluation splits of the NHP protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EvalSplit {
    /// Held-out subjects (NHP `model_x_motion_x`): the headline generalisation numbers.
    UnseenSubjects,
    /// Training subjects in frames not trained on (NHP `model_o_motion_x`).
    SeenSubjectsUnseenPoses,
    /// Training subjects in their training frames (NHP `model_o_motion_o`).
    SeenSubjectsSeenPoses,
}

impl EvalSplit {
    pub const ALL: [EvalSplit; 3] = [
        EvalSplit::UnseenSubjects,
        EvalSplit::SeenSubjectsUnseenPoses,
        EvalSplit::SeenSubjectsSeenPoses,
    ];

    pub fn name(&self) -> &'static str {
        match self {
            EvalSplit::UnseenSubjects => "unseen_subjects",
            EvalSplit::SeenSubjectsUnseenPoses => "seen_subjects_unseen_poses",
            EvalSplit::SeenSubjectsSeenPoses => "seen_subjects_seen_poses",
        }
    }
}

/// One evaluation image: render `target_view` of `frame` of `subject` from `input_views`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct EvalItem {
    pub subject: String,
    /// Index into `annots['ims']`.
    pub frame: usize,
    pub input_views: Vec<usize>,
    pub target_view: usize,
}

/// A full protocol. See the module docs for the NHP values.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Protocol {
    pub name: String,
    /// Training subjects and their training frames.
    pub train: Vec<SubjectFrames>,
    /// Input views drawn (without repetition) per training scene.
    pub train_num_input_views: usize,
    /// Whether a training target may be one of that scene's input views (NHP: yes, the target
    /// is drawn among all cameras independently of the inputs).
    #[serde(default = "yes")]
    pub train_target_may_be_input: bool,
    /// Test-time input views.
    pub input_views: ViewSet,
    /// Test-time target views.
    pub target_views: ViewSet,
    /// Per-subject replacements of `target_views` (NHP: 313 and 315).
    #[serde(default)]
    pub target_views_by_subject: BTreeMap<String, ViewSet>,
    /// Evaluate every `test_frame_stride`-th frame of a test range.
    pub test_frame_stride: usize,
    /// The frames of each evaluation split.
    pub unseen_subjects: Vec<SubjectFrames>,
    #[serde(default)]
    pub seen_subjects_unseen_poses: Vec<SubjectFrames>,
    #[serde(default)]
    pub seen_subjects_seen_poses: Vec<SubjectFrames>,
}

fn yes() -> bool {
    true
}
