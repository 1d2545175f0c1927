//! A truer ground truth than the dataset's, for studies on synthetic data
//! (`nia-infer eval --truth-data ROOT`).
//!
//! The protocol scores a render against the dataset's image cut by the dataset's person mask.
//! Where that mask comes from a segmentation network (holes, a lost hand, ragged outlines) the
//! ground truth is itself wrong at those pixels, and a renderer is scored on how well it guesses
//! the target's own mask flaws. A synthetic set generated with the same spec but without the
//! mask flaw holds the same images and cameras cut by the exact masks: the image the flawed
//! ground truth stands for. [`TruthData`] reads the target views from such a set; the eval scores
//! the same render against both ([`crate::diagnostics::BlendDiagnostics`]'s `*_truth` fields).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use nia_data::dataset::{DatasetConfig, DatasetError, Subject, ViewImage};
use nia_data::geometry::camera::Camera;

/// Largest difference of a camera's K, R and T entries between the evaluated set and the truth
/// set that still counts as the same camera (both are written by one generator as f32 values).
const SAME_CAMERA_TOL: f32 = 1e-4;

/// Errors reading the truth set, naming the folder and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum TruthError {
    #[error("truth set {root}: subject {subject}: {source}")]
    Dataset {
        root: PathBuf,
        subject: String,
        source: Box<DatasetError>,
    },
    #[error(
        "truth set {root}: subject {subject}, view {view}: its camera differs from the \
         evaluated set's by {diff:.2e} (expected the same capture, without the mask flaw)"
    )]
    Camera {
        root: PathBuf,
        subject: String,
        view: usize,
        diff: f32,
    },
}

/// The target views of a truth set (module docs), its subjects opened once each.
#[derive(Debug)]
pub struct TruthData {
    root: PathBuf,
    config: DatasetConfig,
    subjects: Mutex<HashMap<String, Arc<Subject>>>,
}

impl TruthData {
    /// The truth set under `root`, read with `config` (the evaluated set's reader: same format
    /// and ratio).
    pub fn new(root: &Path, config: DatasetConfig) -> Self {
        TruthData {
            root: root.to_path_buf(),
            config,
            subjects: Mutex::new(HashMap::new()),
        }
    }

    /// View `view` of `frame` of `subject` in the truth set, checked to be taken by `camera`
    /// (the evaluated image's camera).
    pub fn view(
        &self,
        subject: &str,
        frame: usize,
        view: usize,
        camera: &Camera,
    ) -> Result<ViewImage, TruthError> {
        let dataset = |source| TruthError::Dataset {
            root: self.root.clone(),
            subject: subject.to_string(),
            source: Box::new(source),
        };
        let opened = {
            // A poisoned lock only means another image's open panicked; the map is still valid.
            let mut subjects = self.subjects.lock().unwrap_or_else(|e| e.into_inner());
            match subjects.get(subject) {
                Some(s) => s.clone(),
                None => {
                    let s = Arc::new(
                        Subject::open(&self.root.join(subject), &self.config).map_err(dataset)?,
                    );
                    subjects.insert(subject.to_string(), s.clone());
                    s
                }
            }
        };
        let image = opened.load_view(frame, view).map_err(dataset)?;
        let diff = camera_difference(&image.camera, camera);
        if !(diff <= SAME_CAMERA_TOL) {
            return Err(TruthError::Camera {
                root: self.root.clone(),
                subject: subject.to_string(),
                view,
                diff,
            });
        }
        Ok(image)
    }
}

/// The largest absolute difference between the entries of `a` and `b`'s K, R and T, and
/// infinity when their image sizes differ.
fn camera_difference(a: &Camera, b: &Camera) -> f32 {
    if (a.width, a.height) != (b.width, b.height) {
        return f32::INFINITY;
    }
    let entries = |c: &Camera| -> Vec<f32> {
        let mut v = c.k.to_cols_array().to_vec();
        v.extend(c.r.to_cols_array());
        v.extend(c.t.to_array());
        v
    };
    entries(a)
        .iter()
        .zip(entries(b))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat3, Vec3};

    fn camera(t: Vec3, width: u32) -> Camera {
        Camera {
            k: Mat3::from_cols_array(&[100.0, 0.0, 0.0, 0.0, 100.0, 0.0, 64.0, 64.0, 1.0]),
            r: Mat3::IDENTITY,
            t,
            dist: [0.0; 5],
            width,
            height: 128,
        }
    }

    #[test]
    fn the_same_camera_differs_by_nothing_and_a_moved_one_by_its_move() {
        let a = camera(Vec3::new(0.0, 0.0, 3.0), 128);
        assert_eq!(camera_difference(&a, &a), 0.0);
        let moved = camera(Vec3::new(0.0, 0.01, 3.0), 128);
        assert!((camera_difference(&a, &moved) - 0.01).abs() < 1e-6);
        assert_eq!(
            camera_difference(&a, &camera(Vec3::new(0.0, 0.0, 3.0), 64)),
            f32::INFINITY
        );
    }
}
