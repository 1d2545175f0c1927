//! One subject folder, opened: its cameras, frames and the files of each frame, and the
//! loading of a view the way NHP prepares it (docs/method.md "Data"):
//!
//! 1. the RGB image, `u8 / 255` as float;
//! 2. the foreground mask, the union of `mask/` and `mask_cihp/` (value != 0);
//! 3. both undistorted with the camera's `K`, `D` (`cv2.undistort`: bilinear, black border;
//!    the mask is undistorted as 0/1 and rounded, i.e. kept where the bilinear weight of
//!    foreground is >= 0.5);
//! 4. resized by `ratio`: image by area resampling (`INTER_AREA`), mask by nearest neighbour;
//!    `K`'s first two rows scaled by `ratio`, size `int(size * ratio)`;
//! 5. background (mask 0) set to black.
//!
//! ZJU-MoCap, MonoCap and the synthetic set all go through this reader; only defaults differ
//! ([`DatasetFormat`]).

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use glam::Vec3;

use super::error::DatasetError;
use super::image_io;
use super::monocap::MonoCapLbs;
use super::zju::{self, Annots};
use super::{DatasetConfig, DatasetFormat};
use crate::body::{BodyModel, SmplParams};
use crate::geometry::camera::{Camera, UndistortMap};

/// Undistorted masks are kept where the bilinear weight of foreground reaches this value:
/// `cv2.undistort` of a 0/1 `uint8` mask rounds the interpolated value to the nearest integer.
pub const MASK_UNDISTORT_KEEP: f32 = 0.5;

/// One frame of a subject.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameFiles {
    /// [N] image file of each camera.
    pub images: Vec<PathBuf>,
    /// [N] the entries of `annots['ims']` the images came from.
    pub entries: Vec<String>,
    /// The number of the params/vertices files (`<number>.npy`).
    pub number: usize,
}

/// A loaded view, ready for the network.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewImage {
    /// The camera of the returned (undistorted, resized) image: `K` scaled, no distortion.
    pub camera: Camera,
    /// [H * W * 3] RGB in [0, 1], black where `mask` is false.
    pub image: Vec<f32>,
    /// [H * W] foreground (union of the subject's mask folders).
    pub mask: Vec<bool>,
}

impl ViewImage {
    pub fn width(&self) -> u32 {
        self.camera.width
    }
    pub fn height(&self) -> u32 {
        self.camera.height
    }
    /// Fraction of pixels in the mask.
    pub fn mask_coverage(&self) -> f64 {
        self.mask.iter().filter(|m| **m).count() as f64 / self.mask.len().max(1) as f64
    }
}

/// An opened subject folder.
#[derive(Debug)]
pub struct Subject {
    /// The folder name (`CoreView_313`).
    pub name: String,
    /// The subject folder.
    pub root: PathBuf,
    pub format: DatasetFormat,
    /// Image resize ratio (ZJU-MoCap 0.5, MonoCap 1).
    pub ratio: f32,
    /// [N] cameras of the raw (distorted, full-size) images; `T` in metres.
    pub raw_cameras: Vec<Camera>,
    /// [N] cameras of the images [`Subject::load_view`] returns (undistorted, resized).
    pub cameras: Vec<Camera>,
    /// [F] frames, in `annots['ims']` order.
    pub frames: Vec<FrameFiles>,
    /// The SMPL parameters folder (`params/` or `new_params/`).
    pub params_dir: PathBuf,
    /// The SMPL vertices folder (`vertices/` or `new_vertices/`).
    pub vertices_dir: PathBuf,
    /// Mask folder names searched, relative to the root.
    pub mask_dirs: Vec<String>,
    /// MonoCap's `lbs/` folder contents.
    pub lbs: Option<MonoCapLbs>,
    undistort: Vec<OnceLock<Arc<UndistortMap>>>,
}

impl Subject {
    /// Opens `root` with `config`: reads `annots.npy`, checks that every camera folder and
    /// every image it lists exists, reads each camera's image size from its first frame, finds
    /// the params/vertices folders, and (MonoCap) reads `lbs/`. Per-frame files (params,
    /// vertices, masks) are checked when loaded.
    pub fn open(root: &Path, config: &DatasetConfig) -> Result<Subject, DatasetError> {
        if !root.is_dir() {
            return Err(DatasetError::NotADirectory {
                path: root.to_path_buf(),
            });
        }
        let ratio = config.ratio();
        if !(ratio.is_finite() && ratio > 0.0 && ratio <= 1.0) {
            return Err(DatasetError::Config {
                field: "ratio",
                expected: "a resize ratio in (0, 1]".into(),
                found: format!("{ratio}"),
            });
        }
        let name = root
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| root.display().to_string());
        let annots_path = root.join("annots.npy");
        let Annots { cams, ims } = zju::read_annots(&annots_path)?;

        let mut frames = Vec::with_capacity(ims.len());
        for (f, entries) in ims.into_iter().enumerate() {
            let mut images = Vec::with_capacity(entries.len());
            for (c, entry) in entries.iter().enumerate() {
                match zju::resolve_image(root, entry) {
                    Some(p) => images.push(p),
                    None => {
                        let direct = root.join(entry);
                        let folder = direct.parent().map(Path::to_path_buf).unwrap_or_default();
                        if !folder.is_dir() {
                            return Err(DatasetError::CameraFolderMissing {
                                folder,
                                frame: f,
                                camera: c,
                                entry: entry.clone(),
                            });
                        }
                        return Err(DatasetError::ImageMissing {
                            path: direct,
                            frame: f,
                            camera: c,
                            entry: entry.clone(),
                        });
                    }
                }
            }
            let number = entries
                .first()
                .and_then(|e| zju::frame_number(e))
                .unwrap_or(f);
            frames.push(FrameFiles {
                images,
                entries,
                number,
            });
        }

        let mut raw_cameras = Vec::with_capacity(cams.len());
        let mut cameras = Vec::with_capacity(cams.len());
        for (c, cam) in cams.iter().enumerate() {
            let first = &frames[0].images[c];
            let (w, h) = image_io::dimensions(first)?;
            let raw = cam.camera(w, h).map_err(|source| DatasetError::Camera {
                path: annots_path.clone(),
                camera: c,
                source,
            })?;
            let scaled = raw.scaled(ratio).map_err(|source| DatasetError::Camera {
                path: annots_path.clone(),
                camera: c,
                source,
            })?;
            raw_cameras.push(raw);
            cameras.push(Camera {
                dist: [0.0; 5],
                ..scaled
            });
        }

        let (params_dir, vertices_dir) = body_dirs(root, config)?;
        let mask_dirs = config
            .mask_dirs
            .clone()
            .unwrap_or_else(|| zju::MASK_DIRS.iter().map(|s| s.to_string()).collect());
        if !mask_dirs.iter().any(|d| root.join(d).is_dir()) {
            return Err(DatasetError::Missing {
                path: root.join(mask_dirs.first().map(String::as_str).unwrap_or("mask")),
                what: format!("a mask folder (one of {})", mask_dirs.join(", ")),
            });
        }
        let lbs = match config.format {
            DatasetFormat::MonoCap => Some(MonoCapLbs::read(&root.join("lbs"))?),
            DatasetFormat::Zju => None,
        };
        let undistort = (0..cameras.len()).map(|_| OnceLock::new()).collect();
        Ok(Subject {
            name,
            root: root.to_path_buf(),
            format: config.format,
            ratio,
            raw_cameras,
            cameras,
            frames,
            params_dir,
            vertices_dir,
            mask_dirs,
            lbs,
            undistort,
        })
    }

    pub fn num_cameras(&self) -> usize {
        self.cameras.len()
    }

    pub fn num_frames(&self) -> usize {
        self.frames.len()
    }

    fn check_frame(&self, frame: usize) -> Result<&FrameFiles, DatasetError> {
        self.frames.get(frame).ok_or(DatasetError::OutOfRange {
            subject: self.name.clone(),
            what: "frame",
            index: frame,
            count: self.frames.len(),
        })
    }

    fn check_view(&self, view: usize) -> Result<(), DatasetError> {
        if view >= self.cameras.len() {
            return Err(DatasetError::OutOfRange {
                subject: self.name.clone(),
                what: "camera",
                index: view,
                count: self.cameras.len(),
            });
        }
        Ok(())
    }

    /// `params_dir/<number>.npy` of a frame.
    pub fn params_path(&self, frame: usize) -> Result<PathBuf, DatasetError> {
        let f = self.check_frame(frame)?;
        Ok(self.params_dir.join(format!("{}.npy", f.number)))
    }

    /// `vertices_dir/<number>.npy` of a frame.
    pub fn vertices_path(&self, frame: usize) -> Result<PathBuf, DatasetError> {
        let f = self.check_frame(frame)?;
        Ok(self.vertices_dir.join(format!("{}.npy", f.number)))
    }

    /// The SMPL parameters of a frame.
    pub fn load_params(&self, frame: usize) -> Result<SmplParams, DatasetError> {
        zju::read_params(&self.params_path(frame)?)
    }

    /// [V] world vertices of a frame, metres.
    pub fn load_vertices(&self, frame: usize) -> Result<Vec<Vec3>, DatasetError> {
        zju::read_vertices(&self.vertices_path(frame)?)
    }

    /// [V] world vertices of the clothed surface a synthetic set's images show
    /// (`<root>/clothed_vertices/<number>.npy`, written by `nia-train synth`); `None` when the
    /// subject has no such folder (every real dataset).
    pub fn load_clothed_vertices(&self, frame: usize) -> Result<Option<Vec<Vec3>>, DatasetError> {
        use crate::synth::writer::{clothed_vertices_path, CLOTHED_VERTICES_DIR};
        let f = self.check_frame(frame)?;
        if !self.root.join(CLOTHED_VERTICES_DIR).is_dir() {
            return Ok(None);
        }
        zju::read_vertices(&clothed_vertices_path(&self.root, f.number)).map(Some)
    }

    /// The mask files of a frame's view that exist (at least one, else an error).
    pub fn mask_paths(&self, frame: usize, view: usize) -> Result<Vec<PathBuf>, DatasetError> {
        self.check_view(view)?;
        let image = &self.check_frame(frame)?.images[view];
        let rel = image.strip_prefix(&self.root).unwrap_or(image);
        let mut found = Vec::new();
        let candidates = zju::mask_candidates(&self.root, &self.mask_dirs, rel);
        // One file per mask folder: the first extension that exists.
        for dir in &self.mask_dirs {
            let base = self.root.join(dir);
            if let Some(p) = candidates
                .iter()
                .filter(|p| p.starts_with(&base))
                .find(|p| p.is_file())
            {
                found.push(p.clone());
            }
        }
        if found.is_empty() {
            return Err(DatasetError::MaskMissing {
                image: image.clone(),
                looked: candidates
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        }
        Ok(found)
    }

    fn undistort_map(&self, view: usize) -> Result<Arc<UndistortMap>, DatasetError> {
        if let Some(m) = self.undistort[view].get() {
            return Ok(m.clone());
        }
        let map =
            self.raw_cameras[view]
                .undistort_map()
                .map_err(|source| DatasetError::Camera {
                    path: self.root.join("annots.npy"),
                    camera: view,
                    source,
                })?;
        Ok(self.undistort[view].get_or_init(|| Arc::new(map)).clone())
    }

    /// The union foreground mask of a frame's view at the raw image size, [H * W].
    pub fn load_raw_mask(&self, frame: usize, view: usize) -> Result<Vec<bool>, DatasetError> {
        let raw = &self.raw_cameras[view];
        let image = &self.check_frame(frame)?.images[view];
        let mut union = vec![false; raw.width as usize * raw.height as usize];
        for path in self.mask_paths(frame, view)? {
            let (w, h, m) = image_io::read_mask(&path)?;
            if (w, h) != (raw.width, raw.height) {
                return Err(DatasetError::Size {
                    path,
                    what: "mask",
                    got_width: w,
                    got_height: h,
                    width: raw.width,
                    height: raw.height,
                    reason: format!("the size of its image {}", image.display()),
                });
            }
            for (u, v) in union.iter_mut().zip(m) {
                *u |= v;
            }
        }
        Ok(union)
    }

    /// Loads a view of a frame as NHP prepares it (module docs).
    pub fn load_view(&self, frame: usize, view: usize) -> Result<ViewImage, DatasetError> {
        self.check_view(view)?;
        let files = self.check_frame(frame)?;
        let raw = self.raw_cameras[view];
        let path = &files.images[view];
        let (w, h, rgb) = image_io::read_rgb_f32(path)?;
        if (w, h) != (raw.width, raw.height) {
            return Err(DatasetError::Size {
                path: path.clone(),
                what: "image",
                got_width: w,
                got_height: h,
                width: raw.width,
                height: raw.height,
                reason: format!(
                    "camera {view}'s size, from {}",
                    self.frames[0].images[view].display()
                ),
            });
        }
        let mask = self.load_raw_mask(frame, view)?;
        let map = self.undistort_map(view)?;
        let to_camera_err = |source| DatasetError::Camera {
            path: self.root.join("annots.npy"),
            camera: view,
            source,
        };
        let rgb = map.remap_f32(&rgb, 3).map_err(to_camera_err)?;
        let mask_f: Vec<f32> = mask.iter().map(|m| *m as u8 as f32).collect();
        let mask = map.remap_f32(&mask_f, 1).map_err(to_camera_err)?;
        let mask: Vec<bool> = mask.iter().map(|v| *v >= MASK_UNDISTORT_KEEP).collect();

        let out = self.cameras[view];
        let (ow, oh) = (out.width as usize, out.height as usize);
        let mut image = image_io::resize_area(&rgb, w as usize, h as usize, 3, ow, oh)?;
        let mask = image_io::resize_nearest(&mask, w as usize, h as usize, ow, oh);
        for (px, m) in image.chunks_exact_mut(3).zip(&mask) {
            if !m {
                px.fill(0.0);
            }
        }
        Ok(ViewImage {
            camera: out,
            image,
            mask,
        })
    }

    /// Checks `model` against the stored data of `frame`: the vertex counts must agree, and
    /// returns the largest distance (metres) between LBS of the stored params and the stored
    /// vertices.
    pub fn lbs_max_error(
        &self,
        model: &BodyModel,
        model_path: &Path,
        frame: usize,
    ) -> Result<f32, DatasetError> {
        let vertices_path = self.vertices_path(frame)?;
        let stored = self.load_vertices(frame)?;
        if model.num_vertices() != stored.len() {
            return Err(DatasetError::VertexCount {
                model: model_path.to_path_buf(),
                vertices: vertices_path,
                model_vertices: model.num_vertices(),
                stored_vertices: stored.len(),
            });
        }
        let params = self.load_params(frame)?;
        let posed = model.lbs(&params);
        Ok(posed
            .vertices
            .iter()
            .zip(&stored)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max))
    }
}

/// The params/vertices folders: the config's names, else the first pair of
/// [`zju::BODY_DIRS`] whose params folder exists.
fn body_dirs(root: &Path, config: &DatasetConfig) -> Result<(PathBuf, PathBuf), DatasetError> {
    let existing = |name: &str, what: &str| -> Result<PathBuf, DatasetError> {
        let p = root.join(name);
        if !p.is_dir() {
            return Err(DatasetError::Missing {
                path: p,
                what: what.to_string(),
            });
        }
        Ok(p)
    };
    if config.params_dir.is_some() || config.vertices_dir.is_some() {
        let params = config.params_dir.as_deref().unwrap_or(zju::BODY_DIRS[0].0);
        let vertices = config
            .vertices_dir
            .as_deref()
            .unwrap_or(zju::BODY_DIRS[0].1);
        return Ok((
            existing(params, "the SMPL parameters folder named in the config")?,
            existing(vertices, "the SMPL vertices folder named in the config")?,
        ));
    }
    for (params, vertices) in zju::BODY_DIRS {
        if root.join(params).is_dir() {
            let what = format!("the SMPL vertices folder that goes with {params}/");
            return Ok((root.join(params), existing(vertices, &what)?));
        }
    }
    Err(DatasetError::Missing {
        path: root.join("params"),
        what: "the SMPL parameters folder (params/ or new_params/)".into(),
    })
}
