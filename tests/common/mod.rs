//! What the cross-crate tests share: one synthetic subject written to disk.
#![allow(dead_code)]

use nia_data::synth::capture::CapturePreset;
use nia_data::synth::{self, SynthSpec, SynthSummary};

/// One synthetic subject (1 frame, 4 cameras of `size` px, no supersampling) made with `seed`
/// into the fresh folder `<tmp>/nia-<name>-<pid>`, which `SynthSummary::out_dir` names.
pub fn one_subject(name: &str, size: u32, seed: u64) -> SynthSummary {
    one_subject_with(name, size, seed, CapturePreset::None)
}

/// [`one_subject`] with the capture flaws of `capture`.
pub fn one_subject_with(name: &str, size: u32, seed: u64, capture: CapturePreset) -> SynthSummary {
    let out = std::env::temp_dir().join(format!("nia-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let spec = SynthSpec {
        size,
        seed,
        subjects: 1,
        frames: 1,
        cameras: 4,
        supersample: 1,
        capture: capture.flaws(),
        ..SynthSpec::default()
    };
    synth::generate(&spec, &out, &mut |_| {}).unwrap()
}
