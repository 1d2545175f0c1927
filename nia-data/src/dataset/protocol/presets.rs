//! The protocols the project ships: NHP's ZJU-MoCap protocol ([`Protocol::nhp`]), the same
//! kind for a synthetic set ([`Protocol::synthetic`]), for subjects a run config names
//! ([`Protocol::subjects`]: a user's own captures) and MonoCap's cross-dataset one
//! ([`Protocol::monocap`]).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::{FrameRange, Protocol, SubjectFrames, ViewSet};
use crate::synth::writer::subject_dir_name;
use crate::synth::SynthSpec;

/// Share of a synthetic training subject's frames used for training; the rest are its unseen
/// poses (NHP's ZJU split trains on 300 of ~600-1400 frames per subject; with the few frames of
/// a synthetic set, two thirds keeps both parts non-empty).
pub const SYNTH_TRAIN_FRAME_FRACTION: f64 = 2.0 / 3.0;

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

/// A split a run config names (`[data.split]` with `protocol = "subjects"`): which subject
/// folders under the data root train and which are held out, for data that carries no split
/// of its own (a user's captures written by `nia-train prepare`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SubjectSplit {
    /// Training subjects (folder names under the data root).
    pub train: Vec<String>,
    /// Held-out test subjects (the unseen-subject evaluation).
    #[serde(default)]
    pub test: Vec<String>,
    /// Test input views (camera indices); default: 3 spread evenly over the cameras.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input_views: Option<Vec<usize>>,
    /// Training frames per training subject (the first N; the rest are its unseen poses);
    /// default: every frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_frames: Option<usize>,
    /// Evaluate every N-th frame of a test range.
    #[serde(default = "one")]
    pub test_frame_stride: usize,
}

fn one() -> usize {
    1
}

impl Protocol {
    /// The protocol of a [`SubjectSplit`]: its training subjects (their first `train_frames`
    /// frames, or all), its test subjects (every frame), its input views (or 3 spread evenly)
    /// and every other camera a target, like [`Protocol::synthetic`].
    pub fn subjects(split: &SubjectSplit) -> Self {
        let train_range = match split.train_frames {
            Some(n) => FrameRange::new(0, n, 1),
            None => FrameRange::all_from(0),
        };
        let each = |names: &[String], range: &FrameRange| -> Vec<SubjectFrames> {
            names
                .iter()
                .map(|s| SubjectFrames::new(s.clone(), range.clone()))
                .collect()
        };
        let input_views = match &split.input_views {
            Some(views) => ViewSet::explicit(views),
            None => ViewSet::Evenly { count: 3 },
        };
        Protocol {
            name: "subjects".into(),
            train: each(&split.train, &train_range),
            train_num_input_views: split.input_views.as_ref().map_or(3, |v| v.len().max(1)),
            train_target_may_be_input: true,
            input_views,
            target_views: ViewSet::OthersThanInputs { stride: 1 },
            target_views_by_subject: BTreeMap::new(),
            test_frame_stride: split.test_frame_stride,
            unseen_subjects: each(&split.test, &FrameRange::all_from(0)),
            seen_subjects_unseen_poses: match split.train_frames {
                Some(n) => each(&split.train, &FrameRange::all_from(n)),
                None => Vec::new(),
            },
            seen_subjects_seen_poses: each(&split.train, &train_range),
        }
    }

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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::protocol::{EvalSplit, ProtocolError};

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

    /// configs/own_capture.toml's split on the quickstart's shape is the synthetic protocol's;
    /// without the optional keys every frame trains and 3 views spread evenly are the inputs.
    #[test]
    fn named_subjects_split() {
        let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let split = SubjectSplit {
            train: names(&["CoreView_1", "CoreView_2", "CoreView_3"]),
            test: names(&["CoreView_4"]),
            input_views: Some(vec![0, 2, 4]),
            train_frames: Some(4),
            test_frame_stride: 1,
        };
        let p = Protocol::subjects(&split);
        p.validate().unwrap();
        let spec = SynthSpec {
            subjects: 4,
            frames: 6,
            cameras: 6,
            ..SynthSpec::default()
        };
        let s = Protocol::synthetic(&spec, 1);
        let size = |_: &str| (6, 6);
        for split in EvalSplit::ALL {
            assert_eq!(
                p.eval_items(split, size).unwrap(),
                s.eval_items(split, size).unwrap()
            );
        }
        assert_eq!(
            p.train_frames("CoreView_2", 6),
            s.train_frames("CoreView_2", 6)
        );
        let bare = Protocol::subjects(&SubjectSplit {
            input_views: None,
            train_frames: None,
            ..split
        });
        bare.validate().unwrap();
        assert_eq!(
            bare.train_frames("CoreView_1", 6),
            (0..6).collect::<Vec<_>>()
        );
        assert_eq!(bare.input_views_for(8), vec![0, 2, 5]);
        assert!(bare.seen_subjects_unseen_poses.is_empty());
        // A subject both trained on and held out is refused.
        let overlap = Protocol::subjects(&SubjectSplit {
            test: names(&["CoreView_1"]),
            ..bare_split()
        });
        assert!(overlap.validate().is_err());
    }

    fn bare_split() -> SubjectSplit {
        SubjectSplit {
            train: vec!["CoreView_1".into()],
            test: vec![],
            input_views: None,
            train_frames: None,
            test_frame_stride: 1,
        }
    }
}
