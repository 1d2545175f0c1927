//! Reading a capture folder: the cameras (ZJU-MoCap's `annots.npy`, a COLMAP text model or a
//! `cameras.json`), the views and frames, and per frame and view the image, the mask and the
//! OpenPose keypoints. Every file is found (or its absence reported) before any is decoded.
//!
//! ```text
//! <subject>/annots.npy                            (unless --cameras colmap:DIR / json:FILE)
//! <subject>/<view>/<frame>.jpg                    e.g. Camera_B1/000000.jpg
//! <subject>/mask/<view>/<frame>.png
//! <subject>/keypoints/<view>/<frame>_keypoints.json
//! ```

use std::path::{Path, PathBuf};

use nia_data::dataset::image_io;
use nia_data::dataset::zju::{read_annots, MASK_EXTENSIONS};
use nia_data::geometry::camera::Camera;
use nia_data::own_capture::{
    read_cameras_json, read_colmap_text, read_openpose, KeypointLayout, Keypoints2d,
};

use super::PrepareError;

/// Where the cameras come from (`--cameras`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CameraSource {
    /// `<subject>/annots.npy` (ZJU-MoCap).
    Annots,
    /// A COLMAP text model folder (`cameras.txt`, `images.txt`).
    Colmap(PathBuf),
    /// A `cameras.json`.
    Json(PathBuf),
}

impl std::str::FromStr for CameraSource {
    type Err = String;

    /// `annots`, `colmap:DIR` or `json:FILE`.
    fn from_str(s: &str) -> Result<Self, String> {
        match s.split_once(':') {
            None if s == "annots" => Ok(CameraSource::Annots),
            Some(("colmap", dir)) if !dir.is_empty() => Ok(CameraSource::Colmap(dir.into())),
            Some(("json", file)) if !file.is_empty() => Ok(CameraSource::Json(file.into())),
            _ => Err(format!("`{s}`: expected annots, colmap:DIR or json:FILE")),
        }
    }
}

/// The files of one frame in one view.
#[derive(Debug, Clone)]
pub struct ViewFiles {
    /// The image, relative to the subject folder (`Camera_B1/000000.jpg`).
    pub image_rel: String,
    pub mask: PathBuf,
    pub keypoints: PathBuf,
}

/// A capture folder, every file found.
#[derive(Debug, Clone)]
pub struct Capture {
    pub root: PathBuf,
    /// `[N]` view folder names and cameras.
    pub views: Vec<(String, Camera)>,
    /// `[F][N]` files.
    pub frames: Vec<Vec<ViewFiles>>,
}

/// The view folder a camera name stands for: the first component of `Camera_B1/000000.jpg`,
/// else the name without extension (`cam01.png` -> `cam01`), else the name.
fn view_of(name: &str) -> String {
    let p = Path::new(name);
    let mut parts = p.components();
    match (parts.next(), parts.next()) {
        (Some(first), Some(_)) => first.as_os_str().to_string_lossy().into_owned(),
        _ => p
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| name.to_string()),
    }
}

fn files_for(root: &Path, view: &str, image_rel: &str) -> Result<ViewFiles, PrepareError> {
    let image = root.join(image_rel);
    if !image.is_file() {
        return Err(PrepareError::missing(
            &image,
            format!("the image of view {view}"),
        ));
    }
    let stem = Path::new(image_rel)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let rel_dir = Path::new(image_rel).parent().unwrap_or(Path::new(""));
    let mask = MASK_EXTENSIONS
        .iter()
        .map(|ext| {
            root.join("mask")
                .join(rel_dir)
                .join(format!("{stem}.{ext}"))
        })
        .find(|p| p.is_file())
        .ok_or_else(|| {
            PrepareError::missing(
                root.join("mask").join(rel_dir).join(format!("{stem}.png")),
                format!("the person mask of {image_rel} (8-bit PNG, non-zero = person)"),
            )
        })?;
    let keypoints = root
        .join("keypoints")
        .join(rel_dir)
        .join(format!("{stem}_keypoints.json"));
    if !keypoints.is_file() {
        return Err(PrepareError::missing(
            &keypoints,
            format!("the OpenPose keypoints of {image_rel} (BODY_25 or COCO-18 JSON)"),
        ));
    }
    Ok(ViewFiles {
        image_rel: image_rel.to_string(),
        mask,
        keypoints,
    })
}

/// Image files (jpg, jpeg, png) of a view folder, sorted by name.
fn images_in(dir: &Path) -> Result<Vec<String>, PrepareError> {
    let entries =
        std::fs::read_dir(dir).map_err(|e| PrepareError::io(dir, "list the view's images", e))?;
    let mut names: Vec<String> = entries
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| {
            let lower = n.to_ascii_lowercase();
            lower.ends_with(".jpg") || lower.ends_with(".jpeg") || lower.ends_with(".png")
        })
        .collect();
    names.sort();
    Ok(names)
}

impl Capture {
    /// Finds every file of the capture in `root`; `max_frames` keeps the first frames only.
    pub fn find(
        root: &Path,
        cameras: &CameraSource,
        max_frames: Option<usize>,
    ) -> Result<Self, PrepareError> {
        if !root.is_dir() {
            return Err(PrepareError::missing(root, "the capture's subject folder"));
        }
        let (views, mut entries) = match cameras {
            CameraSource::Annots => {
                let path = root.join("annots.npy");
                if !path.is_file() {
                    return Err(PrepareError::missing(
                        &path,
                        "ZJU-MoCap cameras (or pass --cameras colmap:DIR or json:FILE)",
                    ));
                }
                let annots = read_annots(&path)?;
                let first = annots
                    .ims
                    .first()
                    .ok_or_else(|| PrepareError::invalid(&path, "'ims' lists no frames"))?;
                let mut views = Vec::with_capacity(annots.cams.len());
                for (c, cam) in annots.cams.iter().enumerate() {
                    let rel = first.get(c).ok_or_else(|| {
                        PrepareError::invalid(
                            &path,
                            format!(
                                "'ims'[0] lists {} images for {} cameras",
                                first.len(),
                                annots.cams.len()
                            ),
                        )
                    })?;
                    let image = root.join(rel);
                    if !image.is_file() {
                        return Err(PrepareError::missing(
                            &image,
                            format!("the image of camera {c} in frame 0 (annots.npy)"),
                        ));
                    }
                    let (w, h) = image_io::dimensions(&image)?;
                    let camera = cam
                        .camera(w, h)
                        .map_err(|e| PrepareError::invalid(&path, format!("camera {c}: {e}")))?;
                    views.push((view_of(rel), camera));
                }
                for (f, frame) in annots.ims.iter().enumerate() {
                    if frame.len() != views.len() {
                        return Err(PrepareError::invalid(
                            &path,
                            format!(
                                "'ims'[{f}] lists {} images, expected one per camera ({})",
                                frame.len(),
                                views.len()
                            ),
                        ));
                    }
                }
                (views, annots.ims)
            }
            CameraSource::Colmap(_) | CameraSource::Json(_) => {
                let (source, list) = match cameras {
                    CameraSource::Colmap(dir) => (dir.clone(), read_colmap_text(dir)?),
                    CameraSource::Json(file) => (file.clone(), read_cameras_json(file)?),
                    CameraSource::Annots => unreachable!("handled above"),
                };
                let mut views: Vec<(String, Camera)> = Vec::new();
                for (name, camera) in list {
                    let view = view_of(&name);
                    if !views.iter().any(|(v, _)| *v == view) {
                        views.push((view, camera));
                    }
                }
                if views.is_empty() {
                    return Err(PrepareError::invalid(&source, "no cameras"));
                }
                for (view, _) in &views {
                    if !root.join(view).is_dir() {
                        return Err(PrepareError::missing(
                            root.join(view),
                            format!("the image folder of camera `{view}` ({})", source.display()),
                        ));
                    }
                }
                let names = images_in(&root.join(&views[0].0))?;
                let entries = names
                    .iter()
                    .map(|n| views.iter().map(|(v, _)| format!("{v}/{n}")).collect())
                    .collect();
                (views, entries)
            }
        };
        if let Some(n) = max_frames {
            entries.truncate(n);
        }
        if entries.is_empty() {
            return Err(PrepareError::missing(
                root.join(&views[0].0),
                "at least one frame's images",
            ));
        }
        let mut frames = Vec::with_capacity(entries.len());
        for frame in &entries {
            let files = frame
                .iter()
                .zip(&views)
                .map(|(rel, (view, _))| files_for(root, view, rel))
                .collect::<Result<Vec<_>, _>>()?;
            frames.push(files);
        }
        for (view, camera) in &views {
            let image = root
                .join(&frames[0][views.iter().position(|(v, _)| v == view).unwrap_or(0)].image_rel);
            let (w, h) = image_io::dimensions(&image)?;
            if (w, h) != (camera.width, camera.height) {
                return Err(PrepareError::invalid(
                    &image,
                    format!(
                        "{w}x{h} pixels, the camera of view {view} is {}x{}",
                        camera.width, camera.height
                    ),
                ));
            }
        }
        Ok(Self {
            root: root.to_path_buf(),
            views,
            frames,
        })
    }
}

/// A view's keypoints of one frame, checked against the capture's layout (`layout` is set by
/// the first file read). `None`: nobody detected.
pub fn read_keypoints(
    path: &Path,
    layout: &mut Option<KeypointLayout>,
) -> Result<Option<Keypoints2d>, PrepareError> {
    let Some(kp) = read_openpose(path)? else {
        return Ok(None);
    };
    match layout {
        Some(l) if *l != kp.layout => Err(PrepareError::invalid(
            path,
            format!(
                "{} keypoints, the other files of this capture are {} (one layout per capture)",
                kp.layout.name(),
                l.name()
            ),
        )),
        _ => {
            *layout = Some(kp.layout);
            Ok(Some(kp))
        }
    }
}

/// A mask as bytes (non-zero = person), checked against its camera's image size.
pub fn read_mask_bytes(path: &Path, camera: &Camera) -> Result<Vec<u8>, PrepareError> {
    let (w, h, mask) = image_io::read_mask(path)?;
    if (w, h) != (camera.width, camera.height) {
        return Err(PrepareError::invalid(
            path,
            format!(
                "mask is {w}x{h} pixels, expected {}x{} (the view's image size)",
                camera.width, camera.height
            ),
        ));
    }
    if !mask.iter().any(|&m| m) {
        return Err(PrepareError::invalid(
            path,
            "the mask is empty (no person pixel)",
        ));
    }
    Ok(mask.iter().map(|&m| if m { 255 } else { 0 }).collect())
}
