//! A summary of a subject folder (what `nia-infer inspect` prints): enough to see at a glance
//! that the folder reads, that the units are right (metres) and that the SMPL model fits it.

use std::path::Path;

use serde::Serialize;

use super::error::DatasetError;
use super::subject::Subject;
use super::DatasetConfig;
use crate::body::BodyModel;
use crate::geometry::rays::Aabb;

/// One camera, row-major, as numpy would print it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CameraSummary {
    /// Intrinsics of the loaded (resized) images, pixels.
    #[serde(rename = "K")]
    pub k: [[f32; 3]; 3],
    /// World-to-camera rotation.
    #[serde(rename = "R")]
    pub r: [[f32; 3]; 3],
    /// World-to-camera translation, metres.
    #[serde(rename = "T")]
    pub t: [f32; 3],
}

/// The `inspect` report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InspectReport {
    /// Folder name.
    pub subject: String,
    pub format: super::DatasetFormat,
    pub ratio: f32,
    pub num_cameras: usize,
    pub num_frames: usize,
    /// `[width, height]` of camera 0's loaded images (after the ratio).
    pub image_size: [u32; 2],
    /// Camera 0 (its `K` scaled by the ratio).
    pub camera0: CameraSummary,
    /// Vertices of frame 0.
    pub num_vertices: usize,
    /// Lower corner of frame 0's vertices, world metres.
    pub bbox_min: [f32; 3],
    /// Upper corner of frame 0's vertices, world metres.
    pub bbox_max: [f32; 3],
    /// Fraction of frame 0 / camera 0 pixels inside the (undistorted, resized) mask.
    pub mask_coverage: f64,
    /// With an SMPL model: the largest distance between LBS of frame 0's params and its stored
    /// vertices, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lbs_max_err_m: Option<f32>,
}

fn rows(m: glam::Mat3) -> [[f32; 3]; 3] {
    let t = m.transpose();
    [
        t.x_axis.to_array(),
        t.y_axis.to_array(),
        t.z_axis.to_array(),
    ]
}

/// Opens `root` with `config` and summarises it; with `config.smpl_model`, also checks the
/// model against frame 0 (vertex count, LBS error).
pub fn inspect(root: &Path, config: &DatasetConfig) -> Result<InspectReport, DatasetError> {
    let subject = Subject::open(root, config)?;
    let vertices = subject.load_vertices(0)?;
    // Frame 0's params must read too (NaN, shapes), even without a model to pose them.
    subject.load_params(0)?;
    let bbox = Aabb::from_points(&vertices).ok_or_else(|| {
        DatasetError::field(
            subject.vertices_path(0).unwrap_or_default(),
            "<array>",
            "finite vertices",
            "an empty or non-finite vertex set",
        )
    })?;
    let view = subject.load_view(0, 0)?;
    let lbs_max_err_m = match &config.smpl_model {
        Some(path) => {
            let model = BodyModel::load(path)?;
            Some(subject.lbs_max_error(&model, path, 0)?)
        }
        None => None,
    };
    let cam = subject.cameras[0];
    Ok(InspectReport {
        subject: subject.name.clone(),
        format: subject.format,
        ratio: subject.ratio,
        num_cameras: subject.num_cameras(),
        num_frames: subject.num_frames(),
        image_size: [cam.width, cam.height],
        camera0: CameraSummary {
            k: rows(cam.k),
            r: rows(cam.r),
            t: cam.t.to_array(),
        },
        num_vertices: vertices.len(),
        bbox_min: bbox.min.to_array(),
        bbox_max: bbox.max.to_array(),
        mask_coverage: view.mask_coverage(),
        lbs_max_err_m,
    })
}
