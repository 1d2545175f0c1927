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

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

use crate::synth::writer::subject_dir_name;
use crate::synth::SynthSpec;

/// Share of a synthetic training subject's frames used for training; the rest are its unseen
/// poses (NHP's ZJU split trains on 300 of ~600-1400 frames per subject; with the few frames of
/// a synthetic set, two thirds keeps both parts non-empty).
pub const SYNTH_TRAIN_FRAME_FRACTION: f64 = 2.0 / 3.0;

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

/// NHP's training subjects: `(subject, begin, count, interval)` (`get_human_info`, train).
const NHP_TRAIN: [(&str, usize, usize, usize); 7] = [
    ("CoreView_313", 0, 60, 1),
    ("CoreView_315", 0, 400, 6),
    ("CoreView_377", 0, 300, 30),
    ("CoreView_386", 0, 300, 6),
    ("CoreView_390", 700, 300, 6),
    ("CoreView_392", 0, 300, 6),
    ("CoreView_396", 810, 270, 5),
];

/// NHP's seen subjects' unseen-pose frames (`model_o_motion_x`): `(subject, begin, count)`.
const NHP_SEEN_UNSEEN_POSES: [(&str, usize, usize); 7] = [
    ("CoreView_313", 60, 1000),
    ("CoreView_315", 400, 1000),
    ("CoreView_377", 300, 317),
    ("CoreView_386", 300, 346),
    ("CoreView_390", 0, 700),
    ("CoreView_392", 300, 256),
    ("CoreView_396", 1080, 270),
];

/// NHP's unseen test subjects (`model_x_motion_x`): `(subject, begin, count)`.
const NHP_UNSEEN: [(&str, usize, usize); 3] = [
    ("CoreView_387", 0, 654),
    ("CoreView_393", 0, 658),
    ("CoreView_394", 0, 859),
];

/// NHP's test input views (B1, B8, B16).
pub const NHP_INPUT_VIEWS: [usize; 3] = [0, 7, 15];
/// NHP's test target views.
pub const NHP_TARGET_VIEWS: [usize; 6] = [3, 5, 10, 12, 18, 20];
/// NHP's test target views for 313 and 315 (21 cameras in their annotations).
pub const NHP_TARGET_VIEWS_313_315: [usize; 6] = [3, 5, 10, 12, 18, 21];
/// NHP evaluates every 30th frame.
pub const NHP_TEST_FRAME_STRIDE: usize = 30;

impl Protocol {
    /// NHP's ZJU-MoCap protocol (module docs).
    pub fn nhp() -> Self {
        let train: Vec<SubjectFrames> = NHP_TRAIN
            .iter()
            .map(|(s, b, c, i)| SubjectFrames::new(*s, FrameRange::new(*b, *c, *i)))
            .collect();
        let seen_seen = NHP_TRAIN
            .iter()
            .map(|(s, b, c, _)| SubjectFrames::new(*s, FrameRange::new(*b, *c, 1)))
            .collect();
        let seen_unseen = NHP_SEEN_UNSEEN_POSES
            .iter()
            .map(|(s, b, c)| SubjectFrames::new(*s, FrameRange::new(*b, *c, 1)))
            .collect();
        let unseen = NHP_UNSEEN
            .iter()
            .map(|(s, b, c)| SubjectFrames::new(*s, FrameRange::new(*b, *c, 1)))
            .collect();
        let mut by_subject = BTreeMap::new();
        for s in ["CoreView_313", "CoreView_315"] {
            by_subject.insert(s.to_string(), ViewSet::explicit(&NHP_TARGET_VIEWS_313_315));
        }
        Protocol {
            name: "nhp_zju_mocap".into(),
            train,
            train_num_input_views: 3,
            train_target_may_be_input: true,
            input_views: ViewSet::explicit(&NHP_INPUT_VIEWS),
            target_views: ViewSet::explicit(&NHP_TARGET_VIEWS),
            target_views_by_subject: by_subject,
            test_frame_stride: NHP_TEST_FRAME_STRIDE,
            unseen_subjects: unseen,
            seen_subjects_unseen_poses: seen_unseen,
            seen_subjects_seen_poses: seen_seen,
        }
    }

    /// The same kind of protocol for a synthetic set written by [`crate::synth::generate`]:
    /// its suggested split ([`SynthSpec::split`]: train subjects, held-out test subjects) and
    /// input views ([`SynthSpec::input_views`]); every other camera a target; training on the
    /// first [`SYNTH_TRAIN_FRAME_FRACTION`] of each training subject's frames (at least one),
    /// the rest being its unseen poses; every `test_frame_stride`-th frame evaluated.
    pub fn synthetic(spec: &SynthSpec, test_frame_stride: usize) -> Self {
        let (train_ids, test_ids) = spec.split();
        let name = |id: &u32| subject_dir_name(*id);
        let train_frames = ((spec.frames as f64 * SYNTH_TRAIN_FRAME_FRACTION).ceil() as usize)
            .clamp(1, spec.frames);
        Protocol {
            name: "synthetic".into(),
            train: train_ids
                .iter()
                .map(|s| SubjectFrames::new(name(s), FrameRange::new(0, train_frames, 1)))
                .collect(),
            train_num_input_views: spec.input_views().len().max(1),
            train_target_may_be_input: true,
            input_views: ViewSet::explicit(&spec.input_views()),
            target_views: ViewSet::OthersThanInputs { stride: 1 },
            target_views_by_subject: BTreeMap::new(),
            test_frame_stride,
            unseen_subjects: test_ids
                .iter()
                .map(|s| SubjectFrames::new(name(s), FrameRange::all_from(0)))
                .collect(),
            seen_subjects_unseen_poses: if train_frames < spec.frames {
                train_ids
                    .iter()
                    .map(|s| SubjectFrames::new(name(s), FrameRange::all_from(train_frames)))
                    .collect()
            } else {
                Vec::new()
            },
            seen_subjects_seen_poses: train_ids
                .iter()
                .map(|s| SubjectFrames::new(name(s), FrameRange::new(0, train_frames, 1)))
                .collect(),
        }
    }

    /// Cross-dataset evaluation on MonoCap (NIA Table 2: trained on ZJU-MoCap, tested on the
    /// four MonoCap sequences of Animatable NeRF, all unseen). NIA does not publish its MonoCap
    /// view choice; this default takes 3 input views spread evenly over the cameras and every
    /// 4th remaining camera as a target, every 30th frame. Override in config to match another
    /// paper's choice.
    pub fn monocap() -> Self {
        let subjects = [
            "lan_images620_1300",
            "marc_images35000_36200",
            "olek_images0812",
            "vlad_images1011",
        ];
        Protocol {
            name: "monocap".into(),
            train: Vec::new(),
            train_num_input_views: 3,
            train_target_may_be_input: true,
            input_views: ViewSet::Evenly { count: 3 },
            target_views: ViewSet::OthersThanInputs { stride: 4 },
            target_views_by_subject: BTreeMap::new(),
            test_frame_stride: NHP_TEST_FRAME_STRIDE,
            unseen_subjects: subjects
                .iter()
                .map(|s| SubjectFrames::new(*s, FrameRange::all_from(0)))
                .collect(),
            seen_subjects_unseen_poses: Vec::new(),
            seen_subjects_seen_poses: Vec::new(),
        }
    }

    /// The subject/frame list of an evaluation split.
    pub fn split(&self, split: EvalSplit) -> &[SubjectFrames] {
        match split {
            EvalSplit::UnseenSubjects => &self.unseen_subjects,
            EvalSplit::SeenSubjectsUnseenPoses => &self.seen_subjects_unseen_poses,
            EvalSplit::SeenSubjectsSeenPoses => &self.seen_subjects_seen_poses,
        }
    }

    /// Test input views for a subject with `num_cameras` cameras.
    pub fn input_views_for(&self, num_cameras: usize) -> Vec<usize> {
        self.input_views.resolve(num_cameras, &[])
    }

    /// Test target views for `subject` with `num_cameras` cameras.
    pub fn target_views_for(&self, subject: &str, num_cameras: usize) -> Vec<usize> {
        let inputs = self.input_views_for(num_cameras);
        self.target_views_by_subject
            .get(subject)
            .unwrap_or(&self.target_views)
            .resolve(num_cameras, &inputs)
    }

    /// Training frames of `subject` (empty when it is not a training subject).
    pub fn train_frames(&self, subject: &str, num_frames: usize) -> Vec<usize> {
        self.train
            .iter()
            .filter(|s| s.subject == subject)
            .flat_map(|s| s.frames.frames(num_frames))
            .collect()
    }

    /// Checks the definition itself (no data needed), including that no explicit target view
    /// of an evaluated subject is an explicit input view ([`ProtocolError::TargetIsInput`]).
    pub fn validate(&self) -> Result<(), ProtocolError> {
        let bad = |field: &str, msg: &str| ProtocolError::Invalid {
            protocol: self.name.clone(),
            field: field.into(),
            msg: msg.into(),
        };
        if self.test_frame_stride == 0 {
            return Err(bad("test_frame_stride", "must be >= 1"));
        }
        if self.train_num_input_views == 0 {
            return Err(bad("train_num_input_views", "must be >= 1"));
        }
        let ranges = self
            .train
            .iter()
            .chain(&self.unseen_subjects)
            .chain(&self.seen_subjects_unseen_poses)
            .chain(&self.seen_subjects_seen_poses);
        for s in ranges {
            if s.frames.interval == 0 {
                return Err(bad(
                    &format!("{}.frames.interval", s.subject),
                    "must be >= 1",
                ));
            }
            if s.frames.count == Some(0) {
                return Err(bad(&format!("{}.frames.count", s.subject), "must be >= 1"));
            }
        }
        for (field, set) in std::iter::once(("input_views", &self.input_views))
            .chain(std::iter::once(("target_views", &self.target_views)))
            .chain(
                self.target_views_by_subject
                    .values()
                    .map(|v| ("target_views_by_subject", v)),
            )
        {
            match set {
                ViewSet::Explicit { views } if views.is_empty() => {
                    return Err(bad(field, "an explicit view list must not be empty"))
                }
                ViewSet::Evenly { count: 0 } => return Err(bad(field, "count must be >= 1")),
                ViewSet::OthersThanInputs { stride: 0 } => {
                    return Err(bad(field, "stride must be >= 1"))
                }
                _ => {}
            }
        }
        self.check_targets_held_out()?;
        for s in &self.train {
            if self.unseen_subjects.iter().any(|u| u.subject == s.subject) {
                return Err(bad(
                    "unseen_subjects",
                    &format!("`{}` is also a training subject", s.subject),
                ));
            }
        }
        Ok(())
    }

    /// The data-free part of the held-out check: where the input views and a subject's target
    /// views are both explicit lists, no target may be an input. Checked for every subject of
    /// an evaluation split and every subject with its own target views; sets that depend on
    /// the number of cameras are checked per subject by [`Self::check_subject`] and
    /// [`Self::eval_items`].
    fn check_targets_held_out(&self) -> Result<(), ProtocolError> {
        let ViewSet::Explicit { views: inputs } = &self.input_views else {
            return Ok(());
        };
        let subjects = EvalSplit::ALL
            .iter()
            .flat_map(|&split| self.split(split))
            .map(|s| s.subject.as_str())
            .chain(self.target_views_by_subject.keys().map(String::as_str));
        for subject in subjects {
            let targets = self
                .target_views_by_subject
                .get(subject)
                .unwrap_or(&self.target_views);
            if let ViewSet::Explicit { views } = targets {
                self.check_held_out(subject, inputs, views)?;
            }
        }
        Ok(())
    }

    /// `targets` of `subject` hold none of `inputs`.
    fn check_held_out(
        &self,
        subject: &str,
        inputs: &[usize],
        targets: &[usize],
    ) -> Result<(), ProtocolError> {
        match targets.iter().find(|v| inputs.contains(v)) {
            Some(&view) => Err(ProtocolError::TargetIsInput {
                protocol: self.name.clone(),
                subject: subject.into(),
                view,
                inputs: inputs.to_vec(),
            }),
            None => Ok(()),
        }
    }

    fn check_views(&self, subject: &str, num_cameras: usize) -> Result<(), ProtocolError> {
        let inputs = self.input_views_for(num_cameras);
        let targets = self.target_views_for(subject, num_cameras);
        for (field, views) in [("input_views", &inputs), ("target_views", &targets)] {
            if let Some(&view) = views.iter().find(|v| **v >= num_cameras) {
                return Err(ProtocolError::ViewOutOfRange {
                    protocol: self.name.clone(),
                    subject: subject.into(),
                    field,
                    view,
                    num_cameras,
                });
            }
        }
        self.check_held_out(subject, &inputs, &targets)
    }

    fn check_range(&self, entry: &SubjectFrames, num_frames: usize) -> Result<(), ProtocolError> {
        if entry.frames.begin >= num_frames {
            return Err(ProtocolError::FramesOutOfRange {
                protocol: self.name.clone(),
                subject: entry.subject.clone(),
                begin: entry.frames.begin,
                num_frames,
            });
        }
        Ok(())
    }

    /// Checks that `subject`'s views exist, that none of its target views is an input view,
    /// that it has enough cameras to train on, and that every frame range naming it starts
    /// inside the data.
    pub fn check_subject(
        &self,
        subject: &str,
        num_cameras: usize,
        num_frames: usize,
    ) -> Result<(), ProtocolError> {
        self.check_views(subject, num_cameras)?;
        if self.train.iter().any(|s| s.subject == subject)
            && num_cameras < self.train_num_input_views
        {
            return Err(ProtocolError::Invalid {
                protocol: self.name.clone(),
                field: "train_num_input_views".into(),
                msg: format!(
                    "subject `{subject}` has {num_cameras} cameras, fewer than {}",
                    self.train_num_input_views
                ),
            });
        }
        let all = self
            .train
            .iter()
            .chain(&self.unseen_subjects)
            .chain(&self.seen_subjects_unseen_poses)
            .chain(&self.seen_subjects_seen_poses);
        for s in all.filter(|s| s.subject == subject) {
            self.check_range(s, num_frames)?;
        }
        Ok(())
    }

    /// The evaluation images of `split`: for each subject, every `test_frame_stride`-th frame
    /// of its range and each target view, rendered from the input views. `num_frames` and
    /// `num_cameras` give each subject's size (from its annotations). A view out of range or a
    /// target view among the input views ([`ProtocolError::TargetIsInput`]) is an error.
    pub fn eval_items(
        &self,
        split: EvalSplit,
        mut size_of: impl FnMut(&str) -> (usize, usize),
    ) -> Result<Vec<EvalItem>, ProtocolError> {
        let mut items = Vec::new();
        for s in self.split(split) {
            let (num_cameras, num_frames) = size_of(&s.subject);
            self.check_views(&s.subject, num_cameras)?;
            self.check_range(s, num_frames)?;
            let inputs = self.input_views_for(num_cameras);
            let targets = self.target_views_for(&s.subject, num_cameras);
            for frame in s
                .frames
                .frames(num_frames)
                .into_iter()
                .step_by(self.test_frame_stride)
            {
                for &target_view in &targets {
                    items.push(EvalItem {
                        subject: s.subject.clone(),
                        frame,
                        input_views: inputs.clone(),
                        target_view,
                    });
                }
            }
        }
        Ok(items)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nhp_views_and_frames() {
        let p = Protocol::nhp();
        p.validate().unwrap();
        assert_eq!(p.input_views_for(23), vec![0, 7, 15]);
        assert_eq!(
            ViewSet::Evenly { count: 3 }.resolve(23, &[]),
            vec![0, 7, 15]
        );
        assert_eq!(
            p.target_views_for("CoreView_387", 23),
            vec![3, 5, 10, 12, 18, 20]
        );
        assert_eq!(
            p.target_views_for("CoreView_313", 23),
            vec![3, 5, 10, 12, 18, 21]
        );
        assert_eq!(p.train_frames("CoreView_377", 10_000).len(), 10);
        let items = p
            .eval_items(EvalSplit::UnseenSubjects, |_| (23, 654))
            .unwrap();
        // 654 frames -> frames 0, 30, ..., 630 = 22 frames, 6 targets each, x 3 subjects.
        assert_eq!(items.len(), 3 * 22 * 6);
        assert_eq!(items[6].frame, 30);
        let err = p.eval_items(EvalSplit::UnseenSubjects, |_| (4, 654));
        assert!(matches!(
            err,
            Err(ProtocolError::ViewOutOfRange { view: 7, .. })
        ));
    }

    #[test]
    fn protocol_round_trips_through_json_and_overrides() {
        let p = Protocol::nhp();
        let json = serde_json::to_string(&p).unwrap();
        let back: Protocol = serde_json::from_str(&json).unwrap();
        assert_eq!(p, back);
        let mut v: serde_json::Value = serde_json::from_str(&json).unwrap();
        v["input_views"] = serde_json::json!({"kind": "explicit", "views": [1, 2]});
        let o: Protocol = serde_json::from_value(v).unwrap();
        assert_eq!(o.input_views_for(23), vec![1, 2]);
        let spec = SynthSpec {
            subjects: 4,
            frames: 6,
            cameras: 6,
            ..SynthSpec::default()
        };
        let s = Protocol::synthetic(&spec, 2);
        s.validate().unwrap();
        assert_eq!(s.train.len(), 3);
        assert_eq!(s.unseen_subjects[0].subject, "CoreView_4");
        assert_eq!(s.input_views_for(6), spec.input_views());
        assert_eq!(s.train_frames("CoreView_1", 6), vec![0, 1, 2, 3]);
        let items = s.eval_items(EvalSplit::UnseenSubjects, |_| (6, 6)).unwrap();
        assert_eq!(items.len(), 3 * 3, "frames 0, 2, 4 x 3 targets");
    }
}
