//! A protocol resolved against a subject's size: its input and target views, its training
//! frames, and the evaluation images of a split.

use super::{EvalItem, EvalSplit, Protocol, ProtocolError, SubjectFrames};

impl Protocol {
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
