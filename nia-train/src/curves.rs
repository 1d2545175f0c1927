//! Training curves from a run's `metrics.jsonl`: the loss (raw per step and smoothed, log
//! scale) and the PSNR (training rays smoothed, held-out validation, the final evaluation)
//! against steps, as one SVG (`curves.svg`, written at the end of training and by `nia-train
//! curves`).

use std::path::{Path, PathBuf};

use nia_eval::plot::{panels_svg, Curve, Panel, PlotError};
use plotters::style::RGBColor;

use crate::events::TrainEvent;

/// Weight of the newest value in the exponential moving average of the plotted step series.
pub const SMOOTHING: f64 = 0.05;

/// The curves could not be made.
#[derive(Debug, thiserror::Error)]
pub enum CurvesError {
    #[error("{}: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: line {line}: not a training event: {message}", path.display())]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{}: no training steps or validations to plot", path.display())]
    Empty { path: PathBuf },
    #[error(transparent)]
    Plot(#[from] PlotError),
}

/// The series of a run's log.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct RunCurves {
    /// (step, loss, training PSNR dB) of every taken step.
    pub steps: Vec<(u64, f64, f64)>,
    /// (step, held-out PSNR dB) of every validation.
    pub validation: Vec<(u64, f64)>,
    /// (step, PSNR dB) of the final evaluation(s).
    pub evaluation: Vec<(u64, f64)>,
}

impl RunCurves {
    /// Collects the series of `events` (a resumed run's log may repeat steps: the later
    /// record wins).
    pub fn of(events: &[TrainEvent]) -> Self {
        let mut c = RunCurves::default();
        for e in events {
            match e {
                TrainEvent::Step(s) => {
                    c.steps.retain(|kept| kept.0 < s.step);
                    c.steps.push((s.step, s.loss, s.psnr));
                }
                TrainEvent::Validation { step, psnr, .. } => {
                    c.validation.retain(|s| s.0 < *step);
                    c.validation.push((*step, *psnr));
                }
                TrainEvent::Evaluation { step, psnr, .. } => c.evaluation.push((*step, *psnr)),
                _ => {}
            }
        }
        c
    }

    /// Reads `metrics.jsonl`.
    pub fn read(path: &Path) -> Result<Self, CurvesError> {
        let text = std::fs::read_to_string(path).map_err(|source| CurvesError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let mut events = Vec::new();
        for (i, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let event = serde_json::from_str(line).map_err(|e| CurvesError::Parse {
                path: path.to_path_buf(),
                line: i + 1,
                message: e.to_string(),
            })?;
            events.push(event);
        }
        let curves = RunCurves::of(&events);
        if curves.steps.is_empty() && curves.validation.is_empty() && curves.evaluation.is_empty() {
            return Err(CurvesError::Empty {
                path: path.to_path_buf(),
            });
        }
        Ok(curves)
    }

    /// The two panels as SVG.
    pub fn svg(&self) -> Result<String, CurvesError> {
        let step_x = |s: &(u64, f64, f64)| (s.0 + 1) as f64;
        let loss: Vec<(f64, f64)> = self.steps.iter().map(|s| (step_x(s), s.1)).collect();
        let psnr: Vec<(f64, f64)> = self.steps.iter().map(|s| (step_x(s), s.2)).collect();
        let grey = RGBColor(200, 200, 200);
        let blue = RGBColor(31, 119, 180);
        let line = |name: &str, colour, points, width| Curve {
            name: name.into(),
            colour,
            points,
            dots: false,
            width,
        };
        let dots = |name: &str, colour, points: &[(u64, f64)]| Curve {
            name: name.into(),
            colour,
            points: points.iter().map(|&(s, v)| (s as f64, v)).collect(),
            dots: true,
            width: 1,
        };
        let panels = [
            Panel {
                title: "training loss".into(),
                y_label: "loss (mse + mse0)".into(),
                log_y: true,
                curves: vec![
                    line("per step", grey, loss.clone(), 1),
                    line("smoothed", blue, smooth(&loss), 2),
                ],
            },
            Panel {
                title: "PSNR".into(),
                y_label: "PSNR (dB)".into(),
                log_y: false,
                curves: vec![
                    line("training rays, smoothed", blue, smooth(&psnr), 2),
                    dots(
                        "held-out validation",
                        RGBColor(255, 127, 14),
                        &self.validation,
                    ),
                    dots("final evaluation", RGBColor(44, 160, 44), &self.evaluation),
                ],
            },
        ];
        Ok(panels_svg("step", &panels)?)
    }
}

/// Exponential moving average of the y values (non-finite values are skipped).
pub fn smooth(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut average: Option<f64> = None;
    points
        .iter()
        .filter(|p| p.1.is_finite())
        .map(|&(x, y)| {
            let a = average.map_or(y, |a| a + SMOOTHING * (y - a));
            average = Some(a);
            (x, a)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothing_is_an_exponential_average() {
        let s = smooth(&[(1.0, 1.0), (2.0, f64::NAN), (3.0, 3.0)]);
        assert_eq!(s.len(), 2);
        assert_eq!(s[0], (1.0, 1.0));
        assert!((s[1].1 - (1.0 + SMOOTHING * 2.0)).abs() < 1e-12);
    }

    #[test]
    fn later_records_of_a_resumed_run_replace_earlier_ones() {
        let step = |step, loss| {
            TrainEvent::Step(crate::events::StepReport {
                step,
                loss,
                mse: loss,
                mse0: 0.0,
                psnr: 20.0,
                rays_per_s: 1.0,
                lr: 1e-3,
                readbacks: 1,
            })
        };
        let c = RunCurves::of(&[step(0, 1.0), step(1, 0.9), step(1, 0.8), step(2, 0.7)]);
        let losses: Vec<f64> = c.steps.iter().map(|s| s.1).collect();
        assert_eq!(losses, vec![1.0, 0.8, 0.7]);
    }
}
