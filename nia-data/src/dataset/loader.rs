//! The prefetching scene loader: worker threads (`std::thread` + channels) decode, undistort
//! and resize images, look up cached visibility and sample rays ahead of the training loop, so
//! a step never waits on decoding.
//!
//! A *scene* is one frame of one subject seen from N input views plus a target: training rays
//! of one target view, or the whole target image for evaluation. The loader takes a list of
//! [`SceneRequest`]s (see [`train_requests`] and [`eval_requests`]) and yields their scenes
//! **in request order**, whatever the thread timing; every random choice comes from the
//! request's own seed, so a run is reproducible for any number of threads.
//!
//! Back-pressure: at most `prefetch` scenes are in flight or waiting; a worker takes the next
//! request only when the consumer has released a slot.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::mpsc::{self, Receiver, SyncSender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::body::{BodyModel, SmplParams};
pub use crate::dataset::requests::{eval_requests, train_requests};
use crate::dataset::sampling::{BoxPadding, RaySamplingConfig, SamplingError, TrainRays};
pub use crate::dataset::scene_load::load_scene;
use crate::dataset::vis_cache::VisibilityCache;
use crate::dataset::{DatasetError, Subject, ViewImage};
use crate::fitting::align::{PoseRefinement, RigidCorrection};
use crate::fitting::{FitError, SmplAlignment};
use crate::geometry::rays::Aabb;
use crate::geometry::sparse::VoxelGridSpec;
use crate::geometry::visibility::DEFAULT_DEPTH_TOL_M;

/// A loader error.
#[derive(Debug, thiserror::Error)]
pub enum LoaderError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{subject}: frame {frame}, target view {view}: {source}")]
    Sampling {
        subject: String,
        frame: usize,
        view: usize,
        source: SamplingError,
    },
    #[error("request {index}: {msg}")]
    Request { index: usize, msg: String },
    #[error(
        "the protocol names subject `{subject}` but no such subject was opened (opened: {opened})"
    )]
    UnknownSubject { subject: String, opened: String },
    #[error("{subject}: frame {frame}: {source}")]
    Alignment {
        subject: String,
        frame: usize,
        source: FitError,
    },
    #[error("loader setting `smpl_alignment`: {0}")]
    AlignmentConfig(FitError),
    #[error("loader setting `{field}`: expected {expected}, got {got}")]
    Config {
        field: &'static str,
        expected: &'static str,
        got: String,
    },
    #[error("the loader's worker threads stopped before producing request {index}")]
    WorkersStopped { index: usize },
    #[error("{}: {stored} vertices, but the SMPL model's faces use {expected} (the vertices come from another body model: check the SMPL model path)", vertices.display())]
    VertexCount {
        vertices: PathBuf,
        stored: usize,
        expected: usize,
    },
}

/// Loader settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoaderConfig {
    /// Worker threads (>= 1).
    pub threads: usize,
    /// Scenes decoded ahead of the consumer (>= 1; at least `threads` keeps every worker busy).
    pub prefetch: usize,
    #[serde(default)]
    pub sampling: RaySamplingConfig,
    #[serde(default)]
    pub box_padding: BoxPadding,
    /// Visibility depth tolerance, metres.
    #[serde(default = "default_tol")]
    pub visibility_depth_tol_m: f32,
    /// Largest SMPL jitter of training scenes, metres ([`jitter_smpl`]; 0: off). Scenes of
    /// whole images (evaluation) are never jittered.
    #[serde(default)]
    pub smpl_jitter_m: f32,
    /// Every scene's fitted SMPL moved rigidly onto the person its source masks show
    /// ([`crate::fitting::align_to_masks`]) before anything else reads it (training and evaluation; then the
    /// jitter). `None`: the stored fit.
    #[serde(default)]
    pub smpl_alignment: Option<SmplAlignment>,
    /// The band sampler's occupancy grid (`threshold_m`, `cell_m`) of every training scene's
    /// mesh, built on the worker thread into the process-wide memo
    /// ([`crate::geometry::occupancy_memo::shared_grid`]) while the consumer trains on earlier
    /// scenes; the training step then finds it there instead of building it. With
    /// `smpl_jitter_m` every scene's mesh is new, and the build (40-50 ms for a 12k-face
    /// body at 2 cm cells) was the largest host item of the quickstart's step. `None`: off.
    #[serde(default)]
    pub band_grid: Option<BandGrid>,
    /// The body volume's grid: with it, the workers also build every training scene's site
    /// pyramid (voxelised vertices, sites and rulebooks of levels `0..=levels`) into the
    /// process-wide memo ([`crate::geometry::sparse::shared_pyramid`]), as they build its
    /// nearest-surface index ([`crate::geometry::surface_memo::shared_surface`]) whatever this
    /// says; the step then finds both there. `None`: no pyramid ahead.
    #[serde(default)]
    pub body_volume: Option<BodyVolumeGrid>,
}

/// The body volume's grid ([`LoaderConfig::body_volume`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BodyVolumeGrid {
    /// How the voxel box is made around a body.
    pub grid: VoxelGridSpec,
    /// The coarsest level (level l: 1 / 2^l of the voxels).
    pub levels: usize,
    /// Also every rulebook's neighbour maps (`SitePyramid::warm_neighbour_maps`), which the
    /// host sparse convolution of the CPU backends reads and a GPU does not.
    #[serde(default)]
    pub neighbour_maps: bool,
}

/// The distances of a band sampler's occupancy grid ([`LoaderConfig::band_grid`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BandGrid {
    /// Distance from the surface the grid keeps, metres.
    pub threshold_m: f32,
    /// Cell edge, metres.
    pub cell_m: f32,
}

fn default_tol() -> f32 {
    DEFAULT_DEPTH_TOL_M
}

impl Default for LoaderConfig {
    fn default() -> Self {
        LoaderConfig {
            threads: 2,
            prefetch: 4,
            sampling: RaySamplingConfig::default(),
            box_padding: BoxPadding::default(),
            visibility_depth_tol_m: DEFAULT_DEPTH_TOL_M,
            smpl_jitter_m: 0.0,
            smpl_alignment: None,
            band_grid: None,
            body_volume: None,
        }
    }
}

/// What a scene's target is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum TargetKind {
    /// Training rays ([`RaySamplingConfig::rays_per_image`]) of the target view.
    Rays,
    /// The whole target image and its `mask_at_box` (evaluation).
    Image,
}

/// One scene to load.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SceneRequest {
    /// Index into [`SceneSource::subjects`].
    pub subject: usize,
    /// Index into the subject's frames.
    pub frame: usize,
    pub input_views: Vec<usize>,
    pub target_view: usize,
    pub target: TargetKind,
    /// Seed of the ray sampling.
    pub seed: u64,
}

/// What the workers read from: the opened subjects, the body's faces (for visibility) and an
/// optional visibility cache.
#[derive(Debug)]
pub struct SceneSource {
    pub subjects: Vec<Subject>,
    /// [F] SMPL triangles (from the user's model).
    pub faces: Vec<[u32; 3]>,
    pub cache: Option<VisibilityCache>,
    /// The body model the fits were posed with: the pose refinement
    /// ([`SmplAlignment::pose_iterations`]) poses it again. `None`: no refinement possible.
    pub body_model: Option<Arc<BodyModel>>,
}

/// An input view of a loaded scene: the dataset image (with its camera) and the rasterised
/// vertex visibility. [`crate::scene::SourceView`] is the same view as the network reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedView {
    pub view: usize,
    pub image: ViewImage,
    /// [V] 0/1 visibility of each SMPL vertex in this view.
    pub visibility: Vec<u8>,
}

/// A scene's target.
#[derive(Debug, Clone, PartialEq)]
pub enum SceneTarget {
    Rays(TrainRays),
    Image {
        image: ViewImage,
        /// [H * W] pixels whose ray hits the body box (the metrics' region).
        mask_at_box: Vec<bool>,
    },
}

/// A loaded scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Position in the request list.
    pub index: usize,
    pub subject: String,
    pub frame: usize,
    /// [V] world vertices, metres.
    pub vertices: Vec<Vec3>,
    pub params: SmplParams,
    /// The padded SMPL box rays are clipped to.
    pub body_box: Aabb,
    pub sources: Vec<LoadedView>,
    pub target_view: usize,
    pub target: SceneTarget,
    /// The rigid correction the fit was moved by ([`LoaderConfig::smpl_alignment`]; `None`
    /// when off).
    pub alignment: Option<RigidCorrection>,
    /// The pose refinement that followed it (`None` when not asked for).
    pub pose_refinement: Option<PoseRefinement>,
}

struct Shared {
    source: Arc<SceneSource>,
    requests: Vec<SceneRequest>,
    config: LoaderConfig,
    /// Slot tickets and the next request index, taken together so requests are started in
    /// order.
    next: Mutex<(Receiver<()>, usize)>,
}

/// Iterator over the scenes of a request list, loaded ahead by worker threads.
pub struct SceneLoader {
    results: Option<Receiver<(usize, Result<Scene, LoaderError>)>>,
    tickets: Option<SyncSender<()>>,
    workers: Vec<JoinHandle<()>>,
    buffer: BTreeMap<usize, Result<Scene, LoaderError>>,
    next: usize,
    total: usize,
}

impl SceneLoader {
    /// Starts `config.threads` workers over `requests`.
    pub fn new(
        source: Arc<SceneSource>,
        requests: Vec<SceneRequest>,
        config: LoaderConfig,
    ) -> Result<SceneLoader, LoaderError> {
        if config.threads == 0 {
            return Err(LoaderError::Config {
                field: "threads",
                expected: ">= 1",
                got: "0".into(),
            });
        }
        if config.prefetch == 0 {
            return Err(LoaderError::Config {
                field: "prefetch",
                expected: ">= 1",
                got: "0".into(),
            });
        }
        if let Some(alignment) = &config.smpl_alignment {
            alignment.validate().map_err(LoaderError::AlignmentConfig)?;
            if alignment.refines_pose() && source.body_model.is_none() {
                return Err(LoaderError::AlignmentConfig(FitError::no_body_model(
                    format!(
                        "{} ({:?} for training)",
                        alignment.pose_iterations, alignment.train_pose_iterations
                    ),
                )));
            }
        }
        let total = requests.len();
        let (ticket_tx, ticket_rx) = mpsc::sync_channel::<()>(config.prefetch);
        for _ in 0..config.prefetch {
            // The channel has exactly `prefetch` slots, so these never block.
            let _ = ticket_tx.send(());
        }
        let (result_tx, result_rx) = mpsc::sync_channel(config.prefetch);
        let shared = Arc::new(Shared {
            source,
            requests,
            config,
            next: Mutex::new((ticket_rx, 0)),
        });
        let workers = (0..config.threads)
            .map(|_| {
                let shared = shared.clone();
                let tx = result_tx.clone();
                std::thread::spawn(move || worker(&shared, &tx))
            })
            .collect();
        Ok(SceneLoader {
            results: Some(result_rx),
            tickets: Some(ticket_tx),
            workers,
            buffer: BTreeMap::new(),
            next: 0,
            total,
        })
    }

    /// Number of scenes this loader yields in all.
    pub fn len(&self) -> usize {
        self.total
    }

    pub fn is_empty(&self) -> bool {
        self.total == 0
    }
}

fn worker(shared: &Shared, tx: &SyncSender<(usize, Result<Scene, LoaderError>)>) {
    loop {
        let index = {
            let Ok(mut guard) = shared.next.lock() else {
                return;
            };
            if guard.0.recv().is_err() {
                return;
            }
            let index = guard.1;
            if index >= shared.requests.len() {
                return;
            }
            guard.1 += 1;
            index
        };
        let result = load_scene(
            &shared.source,
            &shared.requests[index],
            index,
            &shared.config,
        );
        if tx.send((index, result)).is_err() {
            return;
        }
    }
}

impl Iterator for SceneLoader {
    type Item = Result<Scene, LoaderError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.next >= self.total {
            return None;
        }
        loop {
            if let Some(item) = self.buffer.remove(&self.next) {
                self.next += 1;
                if let Some(t) = &self.tickets {
                    let _ = t.send(());
                }
                return Some(item);
            }
            let received = self.results.as_ref().map(|r| r.recv());
            match received {
                Some(Ok((index, item))) => {
                    self.buffer.insert(index, item);
                }
                _ => {
                    let index = self.next;
                    self.next = self.total;
                    return Some(Err(LoaderError::WorkersStopped { index }));
                }
            }
        }
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let left = self.total - self.next;
        (left, Some(left))
    }
}

impl Drop for SceneLoader {
    fn drop(&mut self) {
        // Closing both channels wakes every worker: blocked on a ticket (sender gone) or on
        // sending a result (receiver gone).
        self.tickets.take();
        self.results.take();
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}
