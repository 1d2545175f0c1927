//! Writing one subject in the ZJU-MoCap layout (docs/method.md "Data"):
//!
//! ```text
//! CoreView_<id>/annots.npy                 np.save of {'cams': {'K','D','R','T'}, 'ims': [...]}
//! CoreView_<id>/params/<i>.npy             np.save of {'poses','Rh','Th','shapes'} (float64)
//! CoreView_<id>/vertices/<i>.npy           [V, 3] float32 world vertices, metres
//! CoreView_<id>/Camera_B<k>/<i:06>.jpg     RGB, black background
//! CoreView_<id>/mask/Camera_B<k>/<i:06>.png  8-bit gray, 0 / 255
//! ```
//!
//! `T` in `annots.npy` is in millimetres, as in ZJU-MoCap; everything else is in metres.

use super::SynthError;
use crate::formats::{npy, ArrayData, NdArray, PyValue};
use crate::geometry::camera::Camera;
use glam::Vec3;
use image::codecs::jpeg::JpegEncoder;
use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder};
use std::path::{Path, PathBuf};

/// JPEG quality of the camera images (ZJU-MoCap's are high-quality JPEGs).
pub const JPEG_QUALITY: u8 = 95;

/// Millimetres per metre (`annots['cams']['T']` is in millimetres).
pub const MM_PER_M: f64 = 1000.0;

/// `CoreView_<id>`.
pub fn subject_dir_name(id: u32) -> String {
    format!("CoreView_{id}")
}

/// `Camera_B<k>` for camera index `camera` (0-based; ZJU numbers cameras from 1).
pub fn camera_dir_name(camera: usize) -> String {
    format!("Camera_B{}", camera + 1)
}

/// The image path as `annots['ims'][frame]['ims'][camera]` lists it: `Camera_B1/000000.jpg`.
pub fn image_rel_path(camera: usize, frame: usize) -> String {
    format!("{}/{frame:06}.jpg", camera_dir_name(camera))
}

/// `<subject>/Camera_B<k>/<frame:06>.jpg`.
pub fn image_path(subject_dir: &Path, camera: usize, frame: usize) -> PathBuf {
    subject_dir
        .join(camera_dir_name(camera))
        .join(format!("{frame:06}.jpg"))
}

/// `<subject>/mask/Camera_B<k>/<frame:06>.png`.
pub fn mask_path(subject_dir: &Path, camera: usize, frame: usize) -> PathBuf {
    subject_dir
        .join("mask")
        .join(camera_dir_name(camera))
        .join(format!("{frame:06}.png"))
}

/// `<subject>/params/<frame>.npy`.
pub fn params_path(subject_dir: &Path, frame: usize) -> PathBuf {
    subject_dir.join("params").join(format!("{frame}.npy"))
}

/// `<subject>/vertices/<frame>.npy`.
pub fn vertices_path(subject_dir: &Path, frame: usize) -> PathBuf {
    subject_dir.join("vertices").join(format!("{frame}.npy"))
}

/// Folder of the clothed surface the images show, one `<frame>.npy` per frame ([V, 3] world
/// metres, SMPL's triangles): not in ZJU-MoCap, written for studies of where the density sits
/// (`nia_eval::diagnostics`, `depth_error_true_m`).
pub const CLOTHED_VERTICES_DIR: &str = "clothed_vertices";

/// `<subject>/clothed_vertices/<frame>.npy`.
pub fn clothed_vertices_path(subject_dir: &Path, frame: usize) -> PathBuf {
    subject_dir
        .join(CLOTHED_VERTICES_DIR)
        .join(format!("{frame}.npy"))
}

/// Create the subject's directories (`params`, `vertices`, `clothed_vertices`, `Camera_B*`,
/// `mask/Camera_B*`).
pub fn create_subject_dirs(subject_dir: &Path, cameras: usize) -> Result<(), SynthError> {
    let mut dirs = vec![
        subject_dir.join("params"),
        subject_dir.join("vertices"),
        subject_dir.join(CLOTHED_VERTICES_DIR),
    ];
    for c in 0..cameras {
        dirs.push(subject_dir.join(camera_dir_name(c)));
        dirs.push(subject_dir.join("mask").join(camera_dir_name(c)));
    }
    for dir in dirs {
        std::fs::create_dir_all(&dir).map_err(|source| SynthError::Io { path: dir, source })?;
    }
    Ok(())
}

fn f64_array(shape: Vec<usize>, values: Vec<f64>) -> PyValue {
    PyValue::Array(NdArray::new(shape, ArrayData::F64(values)))
}

fn str_key(key: &str) -> PyValue {
    PyValue::Str(key.to_string())
}

/// Row-major elements of a glam (column-major) 3x3 matrix.
fn rows(m: &glam::Mat3) -> Vec<f64> {
    let r = m.transpose().to_cols_array();
    r.iter().map(|&x| x as f64).collect()
}

/// The `annots.npy` dict: `{'cams': {'K': [3x3], 'D': [5x1], 'R': [3x3], 'T': [3x1 mm]},
/// 'ims': [{'ims': ['Camera_B1/000000.jpg', ...]} per frame]}`, all arrays float64 and every
/// `cams` entry a list with one array per camera, as in ZJU-MoCap.
pub fn annots_value(cameras: &[Camera], frames: usize) -> PyValue {
    let list = |f: &dyn Fn(&Camera) -> PyValue| PyValue::List(cameras.iter().map(f).collect());
    let cams = PyValue::Dict(vec![
        (str_key("K"), list(&|c| f64_array(vec![3, 3], rows(&c.k)))),
        (
            str_key("D"),
            list(&|c| f64_array(vec![5, 1], c.dist.iter().map(|&d| d as f64).collect())),
        ),
        (str_key("R"), list(&|c| f64_array(vec![3, 3], rows(&c.r)))),
        (
            str_key("T"),
            list(&|c| {
                f64_array(
                    vec![3, 1],
                    c.t.to_array()
                        .iter()
                        .map(|&t| t as f64 * MM_PER_M)
                        .collect(),
                )
            }),
        ),
    ]);
    let ims = (0..frames)
        .map(|i| {
            let paths = (0..cameras.len())
                .map(|c| PyValue::Str(image_rel_path(c, i)))
                .collect();
            PyValue::Dict(vec![(str_key("ims"), PyValue::List(paths))])
        })
        .collect();
    PyValue::Dict(vec![
        (str_key("cams"), cams),
        (str_key("ims"), PyValue::List(ims)),
    ])
}

/// Write `<subject>/annots.npy`.
pub fn write_annots(
    subject_dir: &Path,
    cameras: &[Camera],
    frames: usize,
) -> Result<(), SynthError> {
    npy::write_object(
        &subject_dir.join("annots.npy"),
        &annots_value(cameras, frames),
    )?;
    Ok(())
}

/// The `params/<i>.npy` dict: `poses` (1, 72), `Rh` (1, 3), `Th` (1, 3), `shapes` (1, B),
/// float64, in that key order (ZJU-MoCap's).
pub fn params_value(poses: &[f32], rh: Vec3, th: Vec3, shapes: &[f32]) -> PyValue {
    let row = |v: &[f32]| f64_array(vec![1, v.len()], v.iter().map(|&x| x as f64).collect());
    PyValue::Dict(vec![
        (str_key("poses"), row(poses)),
        (str_key("Rh"), row(&rh.to_array())),
        (str_key("Th"), row(&th.to_array())),
        (str_key("shapes"), row(shapes)),
    ])
}

/// Write `<subject>/params/<frame>.npy`.
pub fn write_params(
    subject_dir: &Path,
    frame: usize,
    poses: &[f32],
    rh: Vec3,
    th: Vec3,
    shapes: &[f32],
) -> Result<(), SynthError> {
    npy::write_object(
        &params_path(subject_dir, frame),
        &params_value(poses, rh, th, shapes),
    )?;
    Ok(())
}

/// Write `<subject>/vertices/<frame>.npy`: [V, 3] float32 world vertices, metres.
pub fn write_vertices(
    subject_dir: &Path,
    frame: usize,
    vertices: &[Vec3],
) -> Result<(), SynthError> {
    write_vertex_array(&vertices_path(subject_dir, frame), vertices)
}

/// Writes the clothed surface of a frame ([`CLOTHED_VERTICES_DIR`]), float32 `[V, 3]`.
pub fn write_clothed_vertices(
    subject_dir: &Path,
    frame: usize,
    vertices: &[Vec3],
) -> Result<(), SynthError> {
    write_vertex_array(&clothed_vertices_path(subject_dir, frame), vertices)
}

fn write_vertex_array(path: &Path, vertices: &[Vec3]) -> Result<(), SynthError> {
    let data = vertices.iter().flat_map(|v| v.to_array()).collect();
    let array = NdArray::new(vec![vertices.len(), 3], ArrayData::F32(data));
    npy::write_array(path, &array)?;
    Ok(())
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), SynthError> {
    std::fs::write(path, bytes).map_err(|source| SynthError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Encode `rgb` ([H * W * 3] row-major, u8) as a JPEG at [`JPEG_QUALITY`] and write it.
pub fn write_jpeg(path: &Path, rgb: &[u8], width: u32, height: u32) -> Result<(), SynthError> {
    write_encoded(path, |bytes| {
        JpegEncoder::new_with_quality(bytes, JPEG_QUALITY).encode(
            rgb,
            width,
            height,
            ExtendedColorType::Rgb8,
        )
    })
}

/// Encode `mask` ([H * W] row-major, 0 or 255) as an 8-bit gray PNG and write it.
pub fn write_mask(path: &Path, mask: &[u8], width: u32, height: u32) -> Result<(), SynthError> {
    write_encoded(path, |bytes| {
        PngEncoder::new(bytes).write_image(mask, width, height, ExtendedColorType::L8)
    })
}

/// An image encoded by `encode` in memory, then written to `path` (errors name the file).
fn write_encoded(
    path: &Path,
    encode: impl FnOnce(&mut Vec<u8>) -> image::ImageResult<()>,
) -> Result<(), SynthError> {
    let mut bytes = Vec::new();
    encode(&mut bytes).map_err(|source| SynthError::Image {
        path: path.to_path_buf(),
        source,
    })?;
    write_file(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_zju() {
        assert_eq!(subject_dir_name(377), "CoreView_377");
        assert_eq!(image_rel_path(0, 12), "Camera_B1/000012.jpg");
        let p = mask_path(Path::new("/x"), 22, 3);
        assert_eq!(p, Path::new("/x/mask/Camera_B23/000003.png"));
        assert_eq!(
            params_path(Path::new("/x"), 7),
            Path::new("/x/params/7.npy")
        );
    }

    #[test]
    fn annots_rows_are_row_major_and_t_in_mm() {
        let cam = Camera::look_at(
            Vec3::new(0.0, -2.5, 1.0),
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::Z,
            100.0,
            100.0,
            64,
            64,
        )
        .unwrap();
        let v = annots_value(&[cam], 2);
        let k = v
            .get("cams")
            .and_then(|c| c.get("K"))
            .and_then(|k| k.as_seq())
            .unwrap();
        let k = k[0].as_array().unwrap().to_f64_vec().unwrap();
        assert_eq!(k[2], 32.0); // K[0][2] = cx
        assert_eq!(k[6], 0.0); // K[2][0]
        let t = v
            .get("cams")
            .and_then(|c| c.get("T"))
            .and_then(|t| t.as_seq())
            .unwrap();
        let t = t[0].as_array().unwrap();
        assert_eq!(t.shape, vec![3, 1]);
        let t = t.to_f64_vec().unwrap();
        assert!((t[2] - cam.t.z as f64 * 1000.0).abs() < 1e-9);
        let ims = v.get("ims").and_then(|i| i.as_seq()).unwrap();
        assert_eq!(ims.len(), 2);
        assert_eq!(
            ims[1].get("ims").and_then(|l| l.as_seq()).unwrap()[0].as_str(),
            Some("Camera_B1/000001.jpg")
        );
    }
}
