//! Calibrated cameras of one's own capture: COLMAP's text model and a small JSON format. (ZJU-MoCap's
//! `annots.npy` is read by [`crate::dataset::zju::read_annots`].) Every reader returns the
//! cameras as `(name, Camera)` pairs in the project's convention
//! ([`crate::geometry::camera`]: world-to-camera `x_c = R x_w + T`, metres, OpenCV pixels).
//!
//! # COLMAP text model (`cameras.txt`, `images.txt`)
//!
//! As `colmap model_converter --output_type TXT` writes it. `cameras.txt`, one camera a line:
//! `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...` with the models
//! - `SIMPLE_PINHOLE f cx cy`,
//! - `PINHOLE fx fy cx cy`,
//! - `OPENCV fx fy cx cy k1 k2 p1 p2` (OpenCV's distortion with `k3 = 0`, the same `D` as
//!   ZJU-MoCap's `annots.npy`: the images are undistorted when loaded).
//!
//! Any other model (`SIMPLE_RADIAL`, `RADIAL`, `FULL_OPENCV`, fisheye models, ...) is an
//! error naming the file, the line and the model. `images.txt`, two lines per image:
//! `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then the image's 2D points (ignored, may
//! be empty). `(QW, QX, QY, QZ)` is the world-to-camera rotation as a unit quaternion (Hamilton
//! convention, normalised here), `(TX, TY, TZ)` the translation, in the reconstruction's unit:
//! the cameras must be in metres (a checkerboard calibration, or `colmap model_aligner` to
//! known camera positions), since the body model is. Lines starting with `#` are comments.
//!
//! COLMAP puts the centre of the top-left pixel at `(0.5, 0.5)` (its documentation, "Output
//! format"); the project, as OpenCV, at `(0, 0)`. The reader subtracts 0.5 from `cx, cy` and
//! [`write_colmap_text`] adds it back. The cameras come in the order of `images.txt`, named by
//! `NAME` (e.g. `Camera_B1/000000.jpg` or `cam01.png`).
//!
//! # JSON (`cameras.json`)
//!
//! ```json
//! {"cameras": {
//!   "Camera_B1": {"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
//!                 "R": [[r00, r01, r02], [r10, r11, r12], [r20, r21, r22]],
//!                 "T": [tx, ty, tz],
//!                 "D": [k1, k2, p1, p2, k3],
//!                 "width": 1024, "height": 1024}}}
//! ```
//!
//! `K` and `R` row-major (`K[row][col]`, as numpy and OpenCV print them), `R`, `T`
//! world-to-camera with `T` in metres (ZJU-MoCap's `annots.npy` stores millimetres; this file
//! does not), `D` optional (4 or 5 OpenCV coefficients, default none), `T` and `D` also as
//! column vectors (`[[tx], [ty], [tz]]`). Pixels in OpenCV's convention. The cameras come in
//! file order, named by their key. Unknown keys are errors (a misspelt `"D"` would otherwise
//! drop the distortion silently).

use std::path::Path;

use glam::{Mat3, Quat, Vec3};
use serde::de::{Deserializer, MapAccess, Visitor};
use serde::Deserialize;
use serde_json::Value;

use super::error::{show, OwnCaptureError};
use crate::geometry::camera::Camera;

/// COLMAP's pixel-centre offset: its top-left pixel centre is at `(0.5, 0.5)`, the project's
/// at `(0, 0)` (module docs).
pub const COLMAP_PIXEL_CENTRE: f32 = 0.5;

/// The COLMAP camera models the reader takes, with their parameter names.
pub const COLMAP_MODELS: [(&str, &[&str]); 3] = [
    ("SIMPLE_PINHOLE", &["f", "cx", "cy"]),
    ("PINHOLE", &["fx", "fy", "cx", "cy"]),
    ("OPENCV", &["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"]),
];

/// The keys of one camera in `cameras.json`.
pub const JSON_CAMERA_KEYS: [&str; 6] = ["K", "R", "T", "D", "width", "height"];

/// Intrinsics of one COLMAP camera, in the project's pixel convention.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Intrinsics {
    k: Mat3,
    dist: [f32; 5],
    width: u32,
    height: u32,
}

/// Non-empty, non-comment lines of a text file with their 1-based numbers (comments: `#`).
fn read_text(path: &Path) -> Result<Vec<(usize, String)>, OwnCaptureError> {
    let text = std::fs::read_to_string(path).map_err(|e| OwnCaptureError::io(path, "read", e))?;
    Ok(text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim().to_string()))
        .collect())
}

fn parse_f32(path: &Path, line: usize, what: &str, token: &str) -> Result<f32, OwnCaptureError> {
    token
        .parse::<f64>()
        .ok()
        .filter(|x| x.is_finite() && x.abs() <= f32::MAX as f64)
        .map(|x| x as f32)
        .ok_or_else(|| OwnCaptureError::line(path, line, what, "a finite number", token))
}

fn parse_u32(path: &Path, line: usize, what: &str, token: &str) -> Result<u32, OwnCaptureError> {
    token
        .parse::<u32>()
        .map_err(|_| OwnCaptureError::line(path, line, what, "a whole number >= 0", token))
}

/// `cameras.txt`: camera id -> intrinsics (with the line it was defined on).
fn read_colmap_cameras(path: &Path) -> Result<Vec<(u32, usize, Intrinsics)>, OwnCaptureError> {
    let mut out: Vec<(u32, usize, Intrinsics)> = Vec::new();
    for (line, text) in read_text(path)? {
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        let tokens: Vec<&str> = text.split_whitespace().collect();
        if tokens.len() < 4 {
            return Err(OwnCaptureError::line(
                path,
                line,
                "camera",
                "CAMERA_ID MODEL WIDTH HEIGHT PARAMS...",
                &text,
            ));
        }
        let id = parse_u32(path, line, "CAMERA_ID", tokens[0])?;
        let model = tokens[1];
        let width = parse_u32(path, line, "WIDTH", tokens[2])?;
        let height = parse_u32(path, line, "HEIGHT", tokens[3])?;
        let Some((_, names)) = COLMAP_MODELS.iter().find(|(m, _)| *m == model) else {
            return Err(OwnCaptureError::UnsupportedCameraModel {
                path: path.to_path_buf(),
                line,
                camera_id: id,
                model: model.to_string(),
            });
        };
        let params = &tokens[4..];
        if params.len() != names.len() {
            return Err(OwnCaptureError::line(
                path,
                line,
                format!("{model} parameters of camera {id}"),
                format!("{} values ({})", names.len(), names.join(" ")),
                params.join(" "),
            ));
        }
        let p: Vec<f32> = params
            .iter()
            .zip(names.iter())
            .map(|(t, n)| parse_f32(path, line, n, t))
            .collect::<Result<_, _>>()?;
        let (fx, fy, cx, cy, dist) = match model {
            "SIMPLE_PINHOLE" => (p[0], p[0], p[1], p[2], [0.0; 5]),
            "PINHOLE" => (p[0], p[1], p[2], p[3], [0.0; 5]),
            _ => (p[0], p[1], p[2], p[3], [p[4], p[5], p[6], p[7], 0.0]),
        };
        let k = Mat3::from_cols(
            Vec3::new(fx, 0.0, 0.0),
            Vec3::new(0.0, fy, 0.0),
            Vec3::new(cx - COLMAP_PIXEL_CENTRE, cy - COLMAP_PIXEL_CENTRE, 1.0),
        );
        if let Some((_, first, _)) = out.iter().find(|(i, _, _)| *i == id) {
            return Err(OwnCaptureError::line(
                path,
                line,
                "CAMERA_ID",
                format!("an id not defined before (camera {id} is defined on line {first})"),
                tokens[0],
            ));
        }
        out.push((
            id,
            line,
            Intrinsics {
                k,
                dist,
                width,
                height,
            },
        ));
    }
    Ok(out)
}

/// Reads COLMAP's text model from `dir` (`cameras.txt`, `images.txt`; module docs): one
/// `(image name, camera)` per image, in the order of `images.txt`.
pub fn read_colmap_text(dir: &Path) -> Result<Vec<(String, Camera)>, OwnCaptureError> {
    let cameras_path = dir.join("cameras.txt");
    let images_path = dir.join("images.txt");
    let cameras = read_colmap_cameras(&cameras_path)?;
    let path = images_path.as_path();
    let lines = read_text(path)?;
    let mut out: Vec<(String, Camera)> = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let (line, text) = &lines[i];
        i += 1;
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        // The next line holds the image's 2D points (possibly empty): skipped, as COLMAP does.
        i += 1;
        let tokens: Vec<&str> = text.split_whitespace().collect();
        if tokens.len() < 10 {
            return Err(OwnCaptureError::line(
                path,
                *line,
                "image",
                "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME",
                text,
            ));
        }
        parse_u32(path, *line, "IMAGE_ID", tokens[0])?;
        let names = ["QW", "QX", "QY", "QZ", "TX", "TY", "TZ"];
        let v: Vec<f32> = names
            .iter()
            .zip(&tokens[1..8])
            .map(|(n, t)| parse_f32(path, *line, n, t))
            .collect::<Result<_, _>>()?;
        let camera_id = parse_u32(path, *line, "CAMERA_ID", tokens[8])?;
        // NAME is the rest of the line (names may hold spaces).
        let name = tokens[9..].join(" ");
        let q = Quat::from_xyzw(v[1], v[2], v[3], v[0]);
        let norm = q.length();
        if !(norm.is_finite() && norm > 1e-6) {
            return Err(OwnCaptureError::line(
                path,
                *line,
                "QW QX QY QZ",
                "a non-zero quaternion (world-to-camera rotation)",
                tokens[1..5].join(" "),
            ));
        }
        let r = Mat3::from_quat(q / norm);
        let t = Vec3::new(v[4], v[5], v[6]);
        let Some((_, _, intr)) = cameras.iter().find(|(id, _, _)| *id == camera_id) else {
            return Err(OwnCaptureError::UnknownCamera {
                path: path.to_path_buf(),
                line: *line,
                image: name,
                camera_id,
                cameras: cameras_path.clone(),
                defined: cameras.iter().map(|(id, _, _)| *id).collect(),
            });
        };
        if out.iter().any(|(n, _)| *n == name) {
            return Err(OwnCaptureError::line(
                path,
                *line,
                "NAME",
                "each image listed once",
                &name,
            ));
        }
        let camera =
            Camera::new(intr.k, r, t, intr.dist, intr.width, intr.height).map_err(|source| {
                OwnCaptureError::Camera {
                    path: path.to_path_buf(),
                    view: name.clone(),
                    source,
                }
            })?;
        out.push((name, camera));
    }
    Ok(out)
}

/// Writes `cameras` as a COLMAP text model in `dir` (created if needed): one COLMAP camera per
/// image (ids from 1 in order), `PINHOLE` when a camera has no distortion, `OPENCV` when
/// `k3 = 0`; a camera with skew or `k3 != 0` has no COLMAP model here and is an error. The
/// 2D-point lines are empty. [`read_colmap_text`] reads back the same cameras (to f32 text
/// precision).
pub fn write_colmap_text(dir: &Path, cameras: &[(String, Camera)]) -> Result<(), OwnCaptureError> {
    std::fs::create_dir_all(dir).map_err(|e| OwnCaptureError::io(dir, "create", e))?;
    let cameras_path = dir.join("cameras.txt");
    let images_path = dir.join("images.txt");
    let mut cams = String::from(
        "# Camera list with one line of data per camera:\n\
         #   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n",
    );
    cams.push_str(&format!("# Number of cameras: {}\n", cameras.len()));
    let mut ims = String::from(
        "# Image list with two lines of data per image:\n\
         #   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n\
         #   POINTS2D[] as (X, Y, POINT3D_ID)\n",
    );
    ims.push_str(&format!(
        "# Number of images: {}, mean observations per image: 0\n",
        cameras.len()
    ));
    for (i, (name, c)) in cameras.iter().enumerate() {
        let id = i + 1;
        let [k1, k2, p1, p2, k3] = c.dist;
        if c.skew() != 0.0 || k3 != 0.0 {
            return Err(OwnCaptureError::field(
                &cameras_path,
                format!("camera of `{name}`"),
                "no skew and k3 = 0 (COLMAP's PINHOLE or OPENCV model)",
                format!("skew {}, k3 {k3}", c.skew()),
            ));
        }
        let (cx, cy) = (c.cx() + COLMAP_PIXEL_CENTRE, c.cy() + COLMAP_PIXEL_CENTRE);
        let (w, h, fx, fy) = (c.width, c.height, c.fx(), c.fy());
        if c.dist == [0.0; 5] {
            cams.push_str(&format!("{id} PINHOLE {w} {h} {fx} {fy} {cx} {cy}\n"));
        } else {
            cams.push_str(&format!(
                "{id} OPENCV {w} {h} {fx} {fy} {cx} {cy} {k1} {k2} {p1} {p2}\n"
            ));
        }
        let q = Quat::from_mat3(&c.r).normalize();
        let t = c.t;
        ims.push_str(&format!(
            "{id} {} {} {} {} {} {} {} {id} {name}\n\n",
            q.w, q.x, q.y, q.z, t.x, t.y, t.z
        ));
    }
    std::fs::write(&cameras_path, cams)
        .map_err(|e| OwnCaptureError::io(&cameras_path, "write", e))?;
    std::fs::write(&images_path, ims).map_err(|e| OwnCaptureError::io(&images_path, "write", e))
}

/// The `cameras` object of `cameras.json`, keys in file order.
struct OrderedViews(Vec<(String, Value)>);

impl<'de> Deserialize<'de> for OrderedViews {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = OrderedViews;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("an object {\"<view>\": {camera}, ...}")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<OrderedViews, A::Error> {
                let mut out: Vec<(String, Value)> = Vec::new();
                while let Some((k, v)) = map.next_entry::<String, Value>()? {
                    if out.iter().any(|(n, _)| *n == k) {
                        return Err(serde::de::Error::custom(format!("view `{k}` listed twice")));
                    }
                    out.push((k, v));
                }
                Ok(OrderedViews(out))
            }
        }
        deserializer.deserialize_map(V)
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CamerasFile {
    cameras: OrderedViews,
}

/// Numbers of a JSON value: a flat list, or a list of one-element lists (a column vector).
fn vector(v: &Value) -> Option<Vec<f32>> {
    let list = v.as_array()?;
    list.iter()
        .map(|x| match x {
            Value::Array(inner) if inner.len() == 1 => inner[0].as_f64(),
            other => other.as_f64(),
        })
        .map(|x| {
            x.filter(|x| x.is_finite() && x.abs() <= f32::MAX as f64)
                .map(|x| x as f32)
        })
        .collect()
}

/// A 3x3 row-major matrix of a JSON value (a list of three rows of three numbers).
fn matrix3(v: &Value) -> Option<[[f32; 3]; 3]> {
    let rows = v.as_array().filter(|r| r.len() == 3)?;
    let mut m = [[0.0f32; 3]; 3];
    for (row, out) in rows.iter().zip(m.iter_mut()) {
        let r = row.as_array().filter(|r| r.len() == 3)?;
        for (x, o) in r.iter().zip(out.iter_mut()) {
            *o = x.as_f64().filter(|x| x.is_finite())? as f32;
        }
    }
    Some(m)
}

fn json_camera(path: &Path, view: &str, v: &Value) -> Result<Camera, OwnCaptureError> {
    let field = |key: &str| format!("cameras.{view}.{key}");
    let obj = v.as_object().ok_or_else(|| {
        OwnCaptureError::field(
            path,
            format!("cameras.{view}"),
            "an object with K, R, T, width, height (and optionally D)",
            show(v),
        )
    })?;
    if let Some(unknown) = obj.keys().find(|k| !JSON_CAMERA_KEYS.contains(&k.as_str())) {
        return Err(OwnCaptureError::field(
            path,
            field(unknown),
            format!("one of the keys {JSON_CAMERA_KEYS:?}"),
            "an unknown key",
        ));
    }
    let get = |key: &str, expected: &str| {
        obj.get(key)
            .ok_or_else(|| OwnCaptureError::field(path, field(key), expected, "no such field"))
    };
    let k_expected = "a 3x3 row-major matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]], pixels";
    let k_value = get("K", k_expected)?;
    let k = matrix3(k_value)
        .ok_or_else(|| OwnCaptureError::field(path, field("K"), k_expected, show(k_value)))?;
    let r_expected = "a 3x3 row-major world-to-camera rotation";
    let r_value = get("R", r_expected)?;
    let r = matrix3(r_value)
        .ok_or_else(|| OwnCaptureError::field(path, field("R"), r_expected, show(r_value)))?;
    let t_expected = "3 numbers [tx, ty, tz], world-to-camera translation in metres";
    let t_value = get("T", t_expected)?;
    let t = vector(t_value)
        .filter(|t| t.len() == 3)
        .ok_or_else(|| OwnCaptureError::field(path, field("T"), t_expected, show(t_value)))?;
    let mut dist = [0.0f32; 5];
    if let Some(d_value) = obj.get("D") {
        let d = vector(d_value)
            .filter(|d| d.len() == 4 || d.len() == 5)
            .ok_or_else(|| {
                OwnCaptureError::field(
                    path,
                    field("D"),
                    "4 or 5 OpenCV distortion coefficients [k1, k2, p1, p2(, k3)]",
                    show(d_value),
                )
            })?;
        dist[..d.len()].copy_from_slice(&d);
    }
    let size = |key: &str| -> Result<u32, OwnCaptureError> {
        let expected = "a whole number of pixels >= 1";
        let value = get(key, expected)?;
        value
            .as_u64()
            .and_then(|x| u32::try_from(x).ok())
            .filter(|&x| x >= 1)
            .ok_or_else(|| OwnCaptureError::field(path, field(key), expected, show(value)))
    };
    let (width, height) = (size("width")?, size("height")?);
    Camera::from_rows(k, r, [t[0], t[1], t[2]], dist, width, height).map_err(|source| {
        OwnCaptureError::Camera {
            path: path.to_path_buf(),
            view: view.to_string(),
            source,
        }
    })
}

/// Reads `cameras.json` (module docs): one `(view name, camera)` per entry, in file order.
pub fn read_cameras_json(path: &Path) -> Result<Vec<(String, Camera)>, OwnCaptureError> {
    let text = std::fs::read_to_string(path).map_err(|e| OwnCaptureError::io(path, "read", e))?;
    let file: CamerasFile =
        serde_json::from_str(&text).map_err(|source| OwnCaptureError::Json {
            path: path.to_path_buf(),
            expected: "{\"cameras\": {\"<view>\": {\"K\", \"R\", \"T\", \"width\", \"height\"}}}",
            source,
        })?;
    file.cameras
        .0
        .iter()
        .map(|(view, v)| Ok((view.clone(), json_camera(path, view, v)?)))
        .collect()
}

/// The JSON of one camera (`K`, `R` row-major, `T` metres, `D` 5 coefficients, size).
fn camera_value(c: &Camera) -> Value {
    let rows = |m: &Mat3| -> Value {
        let t = m.transpose();
        serde_json::json!([
            t.x_axis.to_array(),
            t.y_axis.to_array(),
            t.z_axis.to_array()
        ])
    };
    serde_json::json!({
        "K": rows(&c.k),
        "R": rows(&c.r),
        "T": c.t.to_array(),
        "D": c.dist,
        "width": c.width,
        "height": c.height,
    })
}

/// Writes `cameras` as `cameras.json` (pretty-printed, views in the given order; keys within
/// a camera in serde_json's order). [`read_cameras_json`] reads back the same cameras exactly.
pub fn write_cameras_json(
    path: &Path,
    cameras: &[(String, Camera)],
) -> Result<(), OwnCaptureError> {
    // Written by hand around the per-camera objects so the views keep their order whatever
    // serde_json's map type.
    let mut text = String::from("{\n  \"cameras\": {");
    for (i, (view, c)) in cameras.iter().enumerate() {
        let key = Value::String(view.clone()).to_string();
        let body = serde_json::to_string(&camera_value(c)).unwrap_or_default();
        text.push_str(if i == 0 { "\n    " } else { ",\n    " });
        text.push_str(&format!("{key}: {body}"));
    }
    text.push_str("\n  }\n}\n");
    std::fs::write(path, text).map_err(|e| OwnCaptureError::io(path, "write", e))
}
