//! A protocol's evaluation target views are held out from its input views: a target that is
//! also an input is an error naming the view and the subject, raised by the data-free check
//! (`Protocol::validate`, explicit view lists) and by the per-subject checks
//! (`check_subject`, `eval_items`) where the sets depend on the number of cameras.

use nia_data::dataset::protocol::{EvalSplit, Protocol, ProtocolError, ViewSet};
use nia_data::synth::SynthSpec;

/// ZJU-MoCap's camera count (NHP's annotations for most subjects).
const ZJU_CAMERAS: usize = 23;
/// Frames per subject: more than any NHP frame range starts at (CoreView_396's 1080).
const ZJU_FRAMES: usize = 2000;

fn assert_target_is_input(err: ProtocolError, subject: &str, view: usize) {
    let message = err.to_string();
    match &err {
        ProtocolError::TargetIsInput {
            subject: s,
            view: v,
            ..
        } => {
            assert_eq!((s.as_str(), *v), (subject, view), "{message}");
        }
        other => panic!("expected TargetIsInput, got {other:?}"),
    }
    assert!(
        message.contains(&format!("target view {view}")) && message.contains(subject),
        "the message names the view and the subject: {message}"
    );
}

#[test]
fn default_protocols_hold_their_targets_out() {
    let spec = SynthSpec {
        subjects: 4,
        frames: 6,
        cameras: 6,
        ..SynthSpec::default()
    };
    for (p, cameras, frames) in [
        (Protocol::nhp(), ZJU_CAMERAS, ZJU_FRAMES),
        (Protocol::monocap(), ZJU_CAMERAS, ZJU_FRAMES),
        (Protocol::synthetic(&spec, 1), spec.cameras, spec.frames),
    ] {
        p.validate().unwrap();
        for split in EvalSplit::ALL {
            let items = p.eval_items(split, |_| (cameras, frames)).unwrap();
            assert!(
                items
                    .iter()
                    .all(|i| !i.input_views.contains(&i.target_view)),
                "{}: {split:?}",
                p.name
            );
        }
    }
}

#[test]
fn explicit_target_among_inputs_is_a_validation_error_naming_view_and_subject() {
    // The shared target list holds input view 7: the first evaluated subject using it is named.
    let mut p = Protocol::nhp();
    p.target_views = ViewSet::explicit(&[3, 7, 10]);
    let err = p.validate().unwrap_err();
    assert_target_is_input(err.clone(), "CoreView_387", 7);
    assert!(err.to_string().contains("nhp_zju_mocap"), "{err}");
    // The same check guards the evaluation items.
    let err = p
        .eval_items(EvalSplit::UnseenSubjects, |_| (ZJU_CAMERAS, ZJU_FRAMES))
        .unwrap_err();
    assert_target_is_input(err, "CoreView_387", 7);

    // A per-subject target list (NHP overrides 313 and 315) is checked for its subject.
    let mut p = Protocol::nhp();
    p.target_views_by_subject
        .insert("CoreView_315".into(), ViewSet::explicit(&[3, 15]));
    assert_target_is_input(p.validate().unwrap_err(), "CoreView_315", 15);
}

#[test]
fn camera_dependent_target_among_inputs_fails_per_subject() {
    // `Evenly { count: 3 }` is [0, 7, 15] with 23 cameras: the definition alone cannot tell,
    // the subject's camera count can.
    let mut p = Protocol::nhp();
    p.input_views = ViewSet::Evenly { count: 3 };
    p.target_views = ViewSet::explicit(&[3, 15]);
    p.target_views_by_subject.clear();
    p.validate().unwrap();
    let err = p
        .check_subject("CoreView_387", ZJU_CAMERAS, ZJU_FRAMES)
        .unwrap_err();
    assert_target_is_input(err, "CoreView_387", 15);
    let err = p
        .eval_items(EvalSplit::UnseenSubjects, |_| (ZJU_CAMERAS, ZJU_FRAMES))
        .unwrap_err();
    assert_target_is_input(err, "CoreView_387", 15);
    // With 20 cameras the inputs are [0, 6, 13]: 15 is held out.
    p.check_subject("CoreView_387", 20, ZJU_FRAMES).unwrap();
}
