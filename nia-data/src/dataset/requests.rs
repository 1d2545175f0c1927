//! The scene requests of a run: one training epoch's (shuffled frames, random input and target
//! views, NHP's rules) and the evaluation protocol's (fixed views, whole images). The loader
//! ([`super::loader`]) turns each into a [`Scene`](super::loader::Scene).

use crate::dataset::loader::{LoaderError, SceneRequest, TargetKind};
use crate::dataset::protocol::{EvalItem, Protocol};
use crate::dataset::Subject;
use crate::rng::Rng;

fn subject_index(subjects: &[Subject], name: &str) -> Result<usize, LoaderError> {
    subjects
        .iter()
        .position(|s| s.name == name)
        .ok_or_else(|| LoaderError::UnknownSubject {
            subject: name.to_string(),
            opened: subjects
                .iter()
                .map(|s| s.name.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        })
}

/// One epoch of training scenes: every training frame of every training subject once, in a
/// shuffled order, each with `train_num_input_views` distinct random input views and a random
/// target view (NHP). Deterministic in `(seed, epoch)`.
pub fn train_requests(
    protocol: &Protocol,
    subjects: &[Subject],
    epoch: u64,
    seed: u64,
) -> Result<Vec<SceneRequest>, LoaderError> {
    let mut rng = Rng::new(seed).fork(epoch);
    let mut out = Vec::new();
    for entry in &protocol.train {
        let si = subject_index(subjects, &entry.subject)?;
        let s = &subjects[si];
        let n = s.num_cameras();
        let k = protocol.train_num_input_views;
        if n < k || (!protocol.train_target_may_be_input && n <= k) {
            return Err(LoaderError::Config {
                field: "train_num_input_views",
                expected: "fewer input views than the subject has cameras",
                got: format!("{k} views for {} with {n} cameras", s.name),
            });
        }
        for frame in entry.frames.frames(s.num_frames()) {
            let mut views: Vec<usize> = (0..n).collect();
            rng.shuffle(&mut views);
            let input_views = views[..k].to_vec();
            let target_view = if protocol.train_target_may_be_input {
                rng.below(n)
            } else {
                views[k + rng.below(n - k)]
            };
            out.push(SceneRequest {
                subject: si,
                frame,
                input_views,
                target_view,
                target: TargetKind::Rays,
                seed: rng.next_u64(),
            });
        }
    }
    rng.shuffle(&mut out);
    Ok(out)
}

/// Evaluation scenes for protocol items (whole target images).
pub fn eval_requests(
    items: &[EvalItem],
    subjects: &[Subject],
) -> Result<Vec<SceneRequest>, LoaderError> {
    items
        .iter()
        .map(|item| {
            Ok(SceneRequest {
                subject: subject_index(subjects, &item.subject)?,
                frame: item.frame,
                input_views: item.input_views.clone(),
                target_view: item.target_view,
                target: TargetKind::Image,
                seed: 0,
            })
        })
        .collect()
}
