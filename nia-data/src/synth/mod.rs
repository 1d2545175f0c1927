//! The synthetic multi-view human generator: subjects written in the exact ZJU-MoCap layout
//! (docs/method.md "Data"), so every reader, the protocol and the trainer run on them unchanged.
//!
//! Each subject is the procedural SMPL-compatible body with its own proportions (betas), skin
//! tone and clothes: a shirt and trousers offset from the body surface (so the clothed surface
//! is not the SMPL surface), patterned with high-frequency detail (stripes, checks, dots,
//! glyph-like prints, seams with stitches) defined on the canonical body so it moves with it.
//! The subject walks in place while slowly turning, seen by a ring of cameras.
//!
//! ```text
//! OUT/body_model.npz                  the body model every subject uses (SMPL key set)
//! OUT/synth.json                      the spec and a suggested train / test subject split
//! OUT/CoreView_<id>/annots.npy, params/, vertices/, Camera_B<k>/, mask/Camera_B<k>/
//! OUT/CoreView_<id>/clothed_vertices/<frame>.npy   the clothed surface the images show (not ZJU's)
//! OUT/CoreView_<id>/keypoints/Camera_B<k>/<frame:06>_keypoints.json   with `keypoints` only
//! ```
//!
//! Same spec and seed give byte-identical files. Rendering runs in parallel (rayon) over frames
//! and cameras; every file depends only on its own inputs, so the thread count changes nothing.
//! The library never prints: [`generate`] reports progress through a callback.

pub mod cameras;
pub mod capture;
pub mod clothing;
pub mod config;
mod frames;
pub mod keypoints;
pub mod render;
pub mod subject;
pub mod texture;
pub mod writer;

pub use config::SynthSection;

use crate::body::{BodyError, BodyModel, ProceduralBody, ProceduralSpec};
use crate::formats::FormatError;
use crate::geometry::camera::CameraError;
use crate::geometry::raster::MeshError;
use crate::rng::Rng;
use capture::CaptureFlaws;
use frames::{generate_subject, ImageProgress};
pub use keypoints::KeypointSpec;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// File name of the body model every subject uses, in the output root.
pub const BODY_MODEL_FILE: &str = "body_model.npz";
/// File name of the dataset description, in the output root.
pub const DESCRIPTION_FILE: &str = "synth.json";

/// Smallest image size that still shows a person, pixels.
pub const MIN_SIZE: u32 = 16;
/// Largest supported image size, pixels.
pub const MAX_SIZE: u32 = 4096;
/// Largest supersampled render edge (`size * supersample`), pixels: the rasteriser's buffers
/// take 20 bytes per sample, 335 MB per view at this size.
pub const MAX_RENDER_SIZE: u32 = 4096;
/// Largest supersampling factor per axis.
pub const MAX_SUPERSAMPLE: u32 = 4;

/// What to generate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SynthSpec {
    /// Number of subjects.
    pub subjects: usize,
    /// Frames per subject.
    pub frames: usize,
    /// Cameras per subject (`Camera_B1..B<cameras>`).
    pub cameras: usize,
    /// Square image size, pixels.
    pub size: u32,
    /// Seed of everything random.
    pub seed: u64,
    /// Id of the first subject (`CoreView_<id>`); the others follow consecutively.
    pub first_subject_id: u32,
    /// Samples per pixel along each axis (anti-aliasing): 2 renders 4 samples per pixel.
    pub supersample: u32,
    /// Frame rate of the motion, frames per second (how far the gait moves between frames).
    pub fps: f32,
    /// Fraction of the subjects suggested as unseen test subjects in `synth.json`.
    pub test_fraction: f32,
    /// Capture flaws ([`capture`]); none by default, and then not written to `synth.json`, so
    /// a clean spec writes the same bytes as before the flaws existed.
    #[serde(skip_serializing_if = "CaptureFlaws::is_none")]
    pub capture: CaptureFlaws,
    /// The 2D keypoints a detector would report ([`keypoints`]), written when set; not
    /// written to `synth.json` when unset, so the set without them is the same bytes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub keypoints: Option<KeypointSpec>,
}

impl Default for SynthSpec {
    fn default() -> Self {
        SynthSpec {
            subjects: 4,
            frames: 30,
            cameras: 8,
            size: 512,
            seed: 0,
            first_subject_id: 1,
            supersample: 2,
            fps: 10.0,
            test_fraction: 0.25,
            capture: CaptureFlaws::default(),
            keypoints: None,
        }
    }
}

impl SynthSpec {
    /// Check every field's range.
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |field: &'static str, expected: &'static str, got: String| {
            Err(SynthError::Spec {
                field,
                expected,
                got,
            })
        };
        if self.subjects == 0 {
            return bad("subjects", "at least 1", self.subjects.to_string());
        }
        if self.frames == 0 {
            return bad("frames", "at least 1", self.frames.to_string());
        }
        if self.cameras == 0 {
            return bad("cameras", "at least 1", self.cameras.to_string());
        }
        if !(MIN_SIZE..=MAX_SIZE).contains(&self.size) {
            return bad("size", "between 16 and 4096 pixels", self.size.to_string());
        }
        if !(1..=MAX_SUPERSAMPLE).contains(&self.supersample) {
            return bad(
                "supersample",
                "between 1 and 4",
                self.supersample.to_string(),
            );
        }
        if self.size * self.supersample > MAX_RENDER_SIZE {
            return bad(
                "supersample",
                "size * supersample <= 4096 pixels",
                format!("{} * {}", self.size, self.supersample),
            );
        }
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return bad("fps", "a finite frame rate > 0", self.fps.to_string());
        }
        if !(0.0..=1.0).contains(&self.test_fraction) {
            return bad(
                "test_fraction",
                "a fraction in [0, 1]",
                self.test_fraction.to_string(),
            );
        }
        if let Some((field, level)) = self.capture.invalid() {
            return bad(field, "a level in [0, 4] (0: off)", level.to_string());
        }
        if let Some((field, expected, value)) = self.keypoints.and_then(|k| k.invalid()) {
            return bad(field, expected, value.to_string());
        }
        // `subjects >= 1` here; ids first..first + subjects - 1 must fit in u32.
        let last_id = u32::try_from(self.subjects - 1)
            .ok()
            .and_then(|n| self.first_subject_id.checked_add(n));
        if last_id.is_none() {
            return bad(
                "first_subject_id",
                "ids that fit in u32 for every subject",
                self.first_subject_id.to_string(),
            );
        }
        Ok(())
    }

    /// Subject ids, in generation order.
    pub fn subject_ids(&self) -> Vec<u32> {
        (0..self.subjects as u32)
            .map(|i| self.first_subject_id + i)
            .collect()
    }

    /// Suggested split: the last `round(subjects * test_fraction)` subjects (at least one when
    /// there are two or more subjects and the fraction is positive) are unseen test subjects.
    pub fn split(&self) -> (Vec<u32>, Vec<u32>) {
        let ids = self.subject_ids();
        let mut n_test = (self.subjects as f32 * self.test_fraction).round() as usize;
        if self.subjects >= 2 && self.test_fraction > 0.0 {
            n_test = n_test.clamp(1, self.subjects - 1);
        } else {
            n_test = n_test.min(self.subjects.saturating_sub(1));
        }
        let (train, test) = ids.split_at(self.subjects - n_test);
        (train.to_vec(), test.to_vec())
    }

    /// Suggested input views: three cameras a third of the ring apart (ZJU-MoCap uses B1, B8,
    /// B16 of 23), fewer when there are fewer cameras. 0-based indices.
    pub fn input_views(&self) -> Vec<usize> {
        let mut views: Vec<usize> = (0..3)
            .map(|k| (k * self.cameras + 1) / 3)
            .filter(|&v| v < self.cameras)
            .collect();
        views.dedup();
        views
    }

    /// Total number of images (and masks) generated.
    pub fn total_images(&self) -> usize {
        self.subjects * self.frames * self.cameras
    }
}

/// Progress of [`generate`], reported in order on the calling thread.
#[derive(Debug, Clone, PartialEq)]
pub enum SynthEvent {
    /// Generation begins; `total_images` images will be written.
    Started { total_images: usize },
    /// The shared body model was written.
    BodyModelWritten { path: PathBuf },
    /// A subject begins (`index` of `count`).
    SubjectStarted {
        index: usize,
        count: usize,
        id: u32,
        dir: PathBuf,
    },
    /// One image and its mask were written; `done` of `total` overall.
    ImageWritten {
        subject_id: u32,
        frame: usize,
        camera: usize,
        done: usize,
        total: usize,
    },
    /// A subject is complete.
    SubjectFinished { index: usize, id: u32 },
}

/// One generated subject.
#[derive(Debug, Clone, PartialEq)]
pub struct SubjectSummary {
    pub id: u32,
    pub dir: PathBuf,
    pub frames: usize,
    pub cameras: usize,
}

/// What [`generate`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthSummary {
    pub out_dir: PathBuf,
    pub body_model: PathBuf,
    pub description: PathBuf,
    pub subjects: Vec<SubjectSummary>,
    pub train_subjects: Vec<u32>,
    pub test_subjects: Vec<u32>,
    /// Images (and as many masks) written.
    pub images: usize,
    /// Wall time of the whole generation.
    pub elapsed: Duration,
}

impl SynthSummary {
    /// Images rendered and written per second of wall time.
    pub fn images_per_second(&self) -> f64 {
        self.images as f64 / self.elapsed.as_secs_f64().max(1e-9)
    }
}

/// A generation error, naming the spec field, file, subject, frame or camera at fault.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("synth spec field `{field}`: expected {expected}, got {got}")]
    Spec {
        field: &'static str,
        expected: &'static str,
        got: String,
    },
    #[error("{}: cannot write: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: cannot encode the image: {source}", path.display())]
    Image {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error("synthetic body model: {0}")]
    Body(#[from] BodyError),
    #[error("subject {id}: {msg}")]
    Subject { id: u32, msg: String },
    #[error("subject {id}: camera ring: {source}")]
    Camera { id: u32, source: CameraError },
    #[error("subject {id}, frame {frame}, camera {camera}: {source}")]
    Render {
        id: u32,
        frame: usize,
        camera: usize,
        source: MeshError,
    },
    #[error("{}: cannot write the dataset description: {source}", path.display())]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
}

/// `synth.json`: the spec, the layout, and the suggested split.
#[derive(Serialize)]
struct Description<'a> {
    generator: &'static str,
    layout: &'static str,
    body_model: &'static str,
    translation_units: &'static str,
    spec: &'a SynthSpec,
    subjects: Vec<String>,
    train_subjects: Vec<u32>,
    test_subjects: Vec<u32>,
    input_views: Vec<usize>,
    target_views: Vec<usize>,
}

/// Generate `spec` under `out_dir` (created if needed) with the default procedural body
/// ([`ProceduralSpec::default`]), reporting progress through `progress` (on this thread, in
/// order). Existing files of the same names are overwritten.
pub fn generate(
    spec: &SynthSpec,
    out_dir: &Path,
    progress: &mut dyn FnMut(SynthEvent),
) -> Result<SynthSummary, SynthError> {
    spec.validate()?;
    let body = ProceduralBody::generate(&ProceduralSpec::default())?;
    generate_with_body(spec, &body, out_dir, progress)
}

/// [`generate`] with a given body model (e.g. the real SMPL model, or a procedural body of
/// another [`ProceduralSpec`]) instead of the default procedural body. The model is written to
/// `OUT/body_model.npz` and every subject's `vertices` are its LBS. The summary's `elapsed`
/// counts from here (building the default body in [`generate`] is not included).
pub fn generate_with_body(
    spec: &SynthSpec,
    body: &BodyModel,
    out_dir: &Path,
    progress: &mut dyn FnMut(SynthEvent),
) -> Result<SynthSummary, SynthError> {
    let start = Instant::now();
    spec.validate()?;
    body.validate()?;
    create_dir(out_dir)?;
    let total = spec.total_images();
    progress(SynthEvent::Started {
        total_images: total,
    });
    let rng = Rng::new(spec.seed);
    let body_model = out_dir.join(BODY_MODEL_FILE);
    let arrays = body.to_arrays();
    let named: Vec<(&str, &crate::formats::NdArray)> =
        arrays.iter().map(|(k, a)| (k.as_str(), a)).collect();
    crate::formats::npz::write(&body_model, &named)?;
    progress(SynthEvent::BodyModelWritten {
        path: body_model.clone(),
    });

    let mut images = ImageProgress {
        done: 0,
        total,
        report: progress,
    };
    let mut subjects = Vec::with_capacity(spec.subjects);
    for (index, id) in spec.subject_ids().into_iter().enumerate() {
        let dir = out_dir.join(writer::subject_dir_name(id));
        (images.report)(SynthEvent::SubjectStarted {
            index,
            count: spec.subjects,
            id,
            dir: dir.clone(),
        });
        let mut subject_rng = rng.fork(index as u64 + 1);
        generate_subject(spec, body, id, &dir, &mut subject_rng, &mut images)?;
        (images.report)(SynthEvent::SubjectFinished { index, id });
        subjects.push(SubjectSummary {
            id,
            dir,
            frames: spec.frames,
            cameras: spec.cameras,
        });
    }

    let (train_subjects, test_subjects) = spec.split();
    let description = out_dir.join(DESCRIPTION_FILE);
    write_description(spec, &description, &train_subjects, &test_subjects)?;
    Ok(SynthSummary {
        out_dir: out_dir.to_path_buf(),
        body_model,
        description,
        subjects,
        train_subjects,
        test_subjects,
        images: images.done,
        elapsed: start.elapsed(),
    })
}

fn create_dir(dir: &Path) -> Result<(), SynthError> {
    std::fs::create_dir_all(dir).map_err(|source| SynthError::Io {
        path: dir.to_path_buf(),
        source,
    })
}

fn write_description(
    spec: &SynthSpec,
    path: &Path,
    train: &[u32],
    test: &[u32],
) -> Result<(), SynthError> {
    let input_views = spec.input_views();
    let description = Description {
        generator: "nia-data synth",
        layout: "zju-mocap",
        body_model: BODY_MODEL_FILE,
        translation_units: "annots.npy cams.T in millimetres; params, vertices in metres",
        spec,
        subjects: spec
            .subject_ids()
            .into_iter()
            .map(writer::subject_dir_name)
            .collect(),
        train_subjects: train.to_vec(),
        test_subjects: test.to_vec(),
        target_views: (0..spec.cameras)
            .filter(|v| !input_views.contains(v))
            .collect(),
        input_views,
    };
    let mut bytes = serde_json::to_vec_pretty(&description).map_err(|source| SynthError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    bytes.push(b'\n');
    std::fs::write(path, bytes).map_err(|source| SynthError::Io {
        path: path.to_path_buf(),
        source,
    })
}
