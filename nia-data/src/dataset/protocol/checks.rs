//! Checks of a protocol: of the definition alone ([`Protocol::validate`]) and of a subject's
//! cameras and frames against it ([`Protocol::check_subject`]), including that no target view
//! is among the input views.

use super::{EvalSplit, Protocol, ProtocolError, SubjectFrames, ViewSet};

impl Protocol {
    /// Every frame range of the protocol: the training ones, then those of each evaluation
    /// split.
    fn all_ranges(&self) -> impl Iterator<Item = &SubjectFrames> {
        self.train
            .iter()
            .chain(&self.unseen_subjects)
            .chain(&self.seen_subjects_unseen_poses)
            .chain(&self.seen_subjects_seen_poses)
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
        for s in self.all_ranges() {
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

    pub(super) fn check_views(
        &self,
        subject: &str,
        num_cameras: usize,
    ) -> Result<(), ProtocolError> {
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

    pub(super) fn check_range(
        &self,
        entry: &SubjectFrames,
        num_frames: usize,
    ) -> Result<(), ProtocolError> {
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
        for s in self.all_ranges().filter(|s| s.subject == subject) {
            self.check_range(s, num_frames)?;
        }
        Ok(())
    }
}
