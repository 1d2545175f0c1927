//! Per-stage wall-clock timings of a forward pass (encoder, body volume, point inputs, sampling,
//! MLPs, blending, compositing). Timing a stage synchronises the device at its end, so the numbers
//! are real on asynchronous backends too; with timing off nothing is synchronised.

use std::time::{Duration, Instant};

use burn::tensor::Device;
use serde::Serialize;

/// The stages of the NIA forward pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// ResNet-18 feature maps of the source views (per scene).
    Encoder,
    /// Vertex features, voxelisation, rulebooks and the sparse convolutions (per scene).
    BodyVolume,
    /// On the CPU: the ray samples and the points' inputs (projections, o_n, trilinear corners,
    /// the visual hull's carving), the host geometry of every backend.
    PointInputs,
    /// The inputs' upload and the reads at the points: pixel features (bilinear), source
    /// colours and the body volume (trilinear).
    Sampling,
    /// Attention, F_sigma and F_c0.
    Mlps,
    /// F_B and the colour blend.
    Blending,
    /// Volume rendering.
    Compositing,
}

impl Stage {
    pub const ALL: [Stage; 7] = [
        Stage::Encoder,
        Stage::BodyVolume,
        Stage::PointInputs,
        Stage::Sampling,
        Stage::Mlps,
        Stage::Blending,
        Stage::Compositing,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Stage::Encoder => "encoder",
            Stage::BodyVolume => "body_volume",
            Stage::PointInputs => "point_inputs",
            Stage::Sampling => "sampling",
            Stage::Mlps => "mlps",
            Stage::Blending => "blending",
            Stage::Compositing => "compositing",
        }
    }
}

/// Accumulated time per stage.
#[derive(Debug, Clone, Default, Serialize)]
pub struct StageTimes {
    totals: Vec<(Stage, Duration)>,
}

impl StageTimes {
    /// Adds `elapsed` to `stage`.
    pub fn add(&mut self, stage: Stage, elapsed: Duration) {
        match self.totals.iter_mut().find(|(s, _)| *s == stage) {
            Some((_, d)) => *d += elapsed,
            None => self.totals.push((stage, elapsed)),
        }
    }

    /// Time spent in `stage`.
    pub fn get(&self, stage: Stage) -> Duration {
        self.totals
            .iter()
            .find(|(s, _)| *s == stage)
            .map_or(Duration::ZERO, |(_, d)| *d)
    }

    /// Sum over all stages.
    pub fn total(&self) -> Duration {
        self.totals.iter().map(|(_, d)| *d).sum()
    }

    /// Milliseconds per stage that took any time, by stage name.
    pub fn milliseconds(&self) -> std::collections::BTreeMap<String, f64> {
        Stage::ALL
            .iter()
            .map(|&s| (s.name().to_string(), self.get(s).as_secs_f64() * 1e3))
            .filter(|(_, ms)| *ms > 0.0)
            .collect()
    }

    /// Merges another set of timings into this one.
    pub fn merge(&mut self, other: &StageTimes) {
        for (s, d) in &other.totals {
            self.add(*s, *d);
        }
    }
}

/// A stopwatch that charges the time since the last mark to a stage; `None` disables it.
pub(crate) struct Stopwatch<'a> {
    times: Option<&'a mut StageTimes>,
    device: &'a Device,
    last: Instant,
}

impl<'a> Stopwatch<'a> {
    pub(crate) fn new(times: Option<&'a mut StageTimes>, device: &'a Device) -> Self {
        Self {
            times,
            device,
            last: Instant::now(),
        }
    }

    /// Ends the current stage: synchronises the device (only when timing) and charges it.
    pub(crate) fn mark(&mut self, stage: Stage) {
        if let Some(times) = self.times.as_deref_mut() {
            // A failed sync surfaces again at the next read of the results; timing just ends here.
            let _ = self.device.sync();
            let now = Instant::now();
            times.add(stage, now - self.last);
            self.last = now;
        }
    }
}
