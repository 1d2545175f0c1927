//! The ZJU-MoCap `CoreView_XXX` layout, read as the dataset ships it (docs/method.md "Data"):
//!
//! ```text
//! annots.npy                   np.save of {'cams': {'K','D','R','T'}, 'ims': [{'ims': [...]}]}
//! params/<n>.npy (new_params/) np.save of {'poses' [1,72], 'Rh' [1,3], 'Th' [1,3], 'shapes' [1,10]}
//! vertices/<n>.npy (new_vertices/)  [6890, 3] world vertices, metres
//! Camera_B1/000000.jpg ...     (313 and 315: `Camera (1)/CoreView_313_Camera_(1)_0001_....jpg`)
//! mask/<image path>.png, mask_cihp/<image path>.png
//! ```
//!
//! - `annots['cams']` holds per-camera lists (or stacked arrays) of `K` [3,3], `D` [5,1],
//!   `R` [3,3] and `T` [3,1] **in millimetres** (converted to metres here).
//! - `annots['ims'][f]['ims'][c]` is the image of frame `f` in camera `c`, relative to the
//!   subject folder.
//! - The params/vertices file of a frame is numbered by the image file name: `000123.jpg` ->
//!   `123.npy`; 313/315 names carry the number in their fifth `_` field
//!   (`CoreView_313_Camera_(1)_0001_2019-...jpg` -> `1.npy`). Names without a number fall
//!   back to the frame's position in `annots['ims']`.
//! - NHP renames the 313/315 images to `Camera (k)/0001.jpg` without touching `annots.npy`;
//!   both the original and the renamed names are found.

use std::path::{Path, PathBuf};

use glam::Vec3;

use super::error::DatasetError;
use crate::body::SmplParams;
use crate::formats::{self, PyValue};
use crate::geometry::camera::Camera;

/// Millimetres per metre: `annots['cams']['T']` is stored in millimetres.
pub const MM_PER_M: f64 = 1000.0;

/// Mask folders whose union is the foreground mask, in the order they are searched.
pub const MASK_DIRS: [&str; 2] = ["mask", "mask_cihp"];

/// Extensions a mask file may have (the image's extension is replaced).
pub const MASK_EXTENSIONS: [&str; 2] = ["png", "jpg"];

/// `(params folder, vertices folder)` pairs in order of preference: NHP's default config reads
/// `params/` and `vertices/`; later releases ship `new_params/` and `new_vertices/`.
pub const BODY_DIRS: [(&str, &str); 2] = [("params", "vertices"), ("new_params", "new_vertices")];

/// One camera as `annots.npy` stores it.
#[derive(Debug, Clone, PartialEq)]
pub struct AnnotCamera {
    /// Row-major `K[row][col]`, pixels.
    pub k: [[f32; 3]; 3],
    /// Row-major world-to-camera rotation.
    pub r: [[f32; 3]; 3],
    /// Translation, metres (the file stores millimetres).
    pub t: [f32; 3],
    /// OpenCV `[k1, k2, p1, p2, k3]`.
    pub dist: [f32; 5],
}

impl AnnotCamera {
    /// The camera for images of `width x height` pixels (raw, distorted).
    pub fn camera(
        &self,
        width: u32,
        height: u32,
    ) -> Result<Camera, crate::geometry::camera::CameraError> {
        Camera::from_rows(self.k, self.r, self.t, self.dist, width, height)
    }
}

/// The decoded `annots.npy`.
#[derive(Debug, Clone, PartialEq)]
pub struct Annots {
    /// [N] cameras.
    pub cams: Vec<AnnotCamera>,
    /// [F][N] image paths relative to the subject folder, as stored.
    pub ims: Vec<Vec<String>>,
}

/// `(shape, values)` of a numeric array.
pub(crate) type Numeric = (Vec<usize>, Vec<f64>);

/// Numeric values of an array-like value (ndarray, chumpy `Ch`, nested lists of numbers):
/// `(shape, values)`.
fn numeric(value: &PyValue) -> Option<Numeric> {
    if let Some(a) = formats::dense_array(value) {
        return a.to_f64_vec().map(|v| (a.shape.clone(), v));
    }
    match value {
        PyValue::Int(i) => Some((vec![], vec![*i as f64])),
        PyValue::Float(f) => Some((vec![], vec![*f])),
        PyValue::List(items) | PyValue::Tuple(items) => {
            let mut shape = None;
            let mut out = Vec::new();
            for item in items {
                let (s, v) = numeric(item)?;
                if shape.get_or_insert_with(|| s.clone()) != &s {
                    return None;
                }
                out.extend(v);
            }
            let mut full = vec![items.len()];
            full.extend(shape.unwrap_or_default());
            Some((full, out))
        }
        _ => None,
    }
}

/// The per-camera entries of `cams[field]`: a list with one array per camera, or one stacked
/// array whose first axis is the camera.
fn per_camera(cams: &PyValue, field: &str, path: &Path) -> Result<Vec<Numeric>, DatasetError> {
    let name = format!("cams['{field}']");
    let value = cams.get(field).ok_or_else(|| {
        DatasetError::field(
            path,
            &name,
            "a per-camera list of arrays",
            format!("no such key (keys: {})", cams.keys().join(", ")),
        )
    })?;
    match value {
        PyValue::List(items) | PyValue::Tuple(items) => items
            .iter()
            .enumerate()
            .map(|(i, item)| {
                numeric(item).ok_or_else(|| {
                    DatasetError::field(
                        path,
                        format!("{name}[{i}]"),
                        "a numeric array",
                        item.type_name(),
                    )
                })
            })
            .collect(),
        other => {
            let (shape, values) = numeric(other).ok_or_else(|| {
                DatasetError::field(
                    path,
                    &name,
                    "a per-camera list of arrays",
                    other.type_name(),
                )
            })?;
            let Some((&n, rest)) = shape.split_first() else {
                return Err(DatasetError::field(
                    path,
                    &name,
                    "an array with a leading camera axis",
                    "a scalar",
                ));
            };
            let per = rest.iter().product::<usize>();
            Ok((0..n)
                .map(|i| (rest.to_vec(), values[i * per..(i + 1) * per].to_vec()))
                .collect())
        }
    }
}

/// Checks that every value is finite.
pub(crate) fn check_finite(values: &[f64], path: &Path, field: &str) -> Result<(), DatasetError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(DatasetError::NonFinite {
            path: path.to_path_buf(),
            field: field.to_string(),
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}

fn exactly<const N: usize>(
    entry: &Numeric,
    path: &Path,
    field: String,
    expected: &str,
) -> Result<[f64; N], DatasetError> {
    let (shape, values) = entry;
    if values.len() != N {
        return Err(DatasetError::field(
            path,
            field,
            expected,
            format!("shape {shape:?}"),
        ));
    }
    check_finite(values, path, &field)?;
    let mut out = [0.0; N];
    out.copy_from_slice(values);
    Ok(out)
}

fn rows3(v: [f64; 9]) -> [[f32; 3]; 3] {
    [
        [v[0] as f32, v[1] as f32, v[2] as f32],
        [v[3] as f32, v[4] as f32, v[5] as f32],
        [v[6] as f32, v[7] as f32, v[8] as f32],
    ]
}

/// A list of strings: a list/tuple of str, or a numpy str / object array.
fn strings(value: &PyValue) -> Option<Vec<String>> {
    let items: Vec<&PyValue> = match value {
        PyValue::List(v) | PyValue::Tuple(v) => v.iter().collect(),
        PyValue::Array(a) => match &a.data {
            formats::ArrayData::Object(v) => v.iter().collect(),
            _ => return None,
        },
        _ => return None,
    };
    items
        .into_iter()
        .map(|s| s.as_str().map(str::to_string))
        .collect()
}

/// Elements of a list, tuple or object array.
fn sequence(value: &PyValue) -> Option<Vec<&PyValue>> {
    match value {
        PyValue::List(v) | PyValue::Tuple(v) => Some(v.iter().collect()),
        PyValue::Array(a) => match &a.data {
            formats::ArrayData::Object(v) => Some(v.iter().collect()),
            _ => None,
        },
        _ => None,
    }
}

/// The decoded file at `path`; [`DatasetError::Missing`] (saying the file holds `what`) when
/// there is none.
fn load_required(path: &Path, what: &str) -> Result<PyValue, DatasetError> {
    if !path.is_file() {
        return Err(DatasetError::Missing {
            path: path.to_path_buf(),
            what: what.into(),
        });
    }
    Ok(formats::load_any(path)?)
}

/// [`load_required`] for a file holding a dict; `expected` describes it in the error when it
/// holds something else.
fn load_dict(path: &Path, what: &str, expected: &str) -> Result<PyValue, DatasetError> {
    let value = load_required(path, what)?;
    if !matches!(value, PyValue::Dict(_)) {
        return Err(DatasetError::field(
            path,
            "<file>",
            expected,
            value.type_name(),
        ));
    }
    Ok(value)
}

/// Reads and checks `annots.npy`.
pub fn read_annots(path: &Path) -> Result<Annots, DatasetError> {
    let root = load_dict(
        path,
        "annots.npy, the cameras and image list of the subject",
        "a dict with keys 'cams' and 'ims'",
    )?;
    let cams = root
        .get("cams")
        .ok_or_else(|| DatasetError::field(path, "cams", "a dict of K, D, R, T", "no such key"))?;
    let ks = per_camera(cams, "K", path)?;
    let ds = per_camera(cams, "D", path)?;
    let rs = per_camera(cams, "R", path)?;
    let ts = per_camera(cams, "T", path)?;
    let n = ks.len();
    for (field, len) in [("D", ds.len()), ("R", rs.len()), ("T", ts.len())] {
        if len != n {
            return Err(DatasetError::field(
                path,
                format!("cams['{field}']"),
                format!("{n} cameras (as many as cams['K'])"),
                format!("{len}"),
            ));
        }
    }
    if n == 0 {
        return Err(DatasetError::field(
            path,
            "cams['K']",
            "at least one camera",
            "0",
        ));
    }
    let mut out_cams = Vec::with_capacity(n);
    for i in 0..n {
        let k = exactly::<9>(&ks[i], path, format!("cams['K'][{i}]"), "shape [3, 3]")?;
        let r = exactly::<9>(&rs[i], path, format!("cams['R'][{i}]"), "shape [3, 3]")?;
        let t = exactly::<3>(&ts[i], path, format!("cams['T'][{i}]"), "shape [3, 1] (mm)")?;
        let (dshape, dvals) = &ds[i];
        let dfield = format!("cams['D'][{i}]");
        check_finite(dvals, path, &dfield)?;
        // OpenCV accepts 4, 5, 8, 12 or 14 coefficients; the camera model has 5. Extra ones
        // are accepted only when zero (then they change nothing).
        if dvals.len() < 4 || dvals.iter().skip(5).any(|v| *v != 0.0) {
            return Err(DatasetError::field(
                path,
                dfield,
                "4 or 5 distortion coefficients [k1, k2, p1, p2(, k3)]",
                format!("shape {dshape:?}"),
            ));
        }
        let mut dist = [0.0f32; 5];
        for (d, v) in dist.iter_mut().zip(dvals) {
            *d = *v as f32;
        }
        out_cams.push(AnnotCamera {
            k: rows3(k),
            r: rows3(r),
            t: [
                (t[0] / MM_PER_M) as f32,
                (t[1] / MM_PER_M) as f32,
                (t[2] / MM_PER_M) as f32,
            ],
            dist,
        });
    }
    let ims_value = root.get("ims").ok_or_else(|| {
        DatasetError::field(
            path,
            "ims",
            "a list of {'ims': [paths]} per frame",
            "no such key",
        )
    })?;
    let frames = sequence(ims_value).ok_or_else(|| {
        DatasetError::field(
            path,
            "ims",
            "a list of {'ims': [paths]} per frame",
            ims_value.type_name(),
        )
    })?;
    if frames.is_empty() {
        return Err(DatasetError::field(path, "ims", "at least one frame", "0"));
    }
    let mut ims = Vec::with_capacity(frames.len());
    for (f, frame) in frames.iter().enumerate() {
        let list = frame.get("ims").and_then(strings).ok_or_else(|| {
            DatasetError::field(
                path,
                format!("ims[{f}]['ims']"),
                "a list of image paths, one per camera",
                frame.type_name(),
            )
        })?;
        if list.len() != n {
            return Err(DatasetError::field(
                path,
                format!("ims[{f}]['ims']"),
                format!("{n} image paths (one per camera in cams)"),
                format!("{}", list.len()),
            ));
        }
        ims.push(list);
    }
    Ok(Annots {
        cams: out_cams,
        ims,
    })
}

/// The params/vertices file number of an image entry (see the module docs); `None` when the
/// name carries no number.
pub fn frame_number(entry: &str) -> Option<usize> {
    let name = Path::new(entry).file_stem()?.to_str()?;
    if let Ok(n) = name.parse::<usize>() {
        return Some(n);
    }
    name.split('_').nth(4)?.parse::<usize>().ok()
}

/// Where the image of `entry` is: the stored path, else NHP's renamed 313/315 file
/// `<camera folder>/<number>.jpg` (with the number as written in the name).
pub fn resolve_image(root: &Path, entry: &str) -> Option<PathBuf> {
    let direct = root.join(entry);
    if direct.is_file() {
        return Some(direct);
    }
    let p = Path::new(entry);
    let stem = p.file_stem()?.to_str()?;
    let number = stem.split('_').nth(4)?;
    let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("jpg");
    let renamed = root
        .join(p.parent().unwrap_or(Path::new("")))
        .join(format!("{number}.{ext}"));
    renamed.is_file().then_some(renamed)
}

/// The mask candidates of an image (relative path `rel` inside the subject folder), in search
/// order: for each mask folder, the image path with each mask extension.
pub fn mask_candidates(root: &Path, mask_dirs: &[String], rel: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for dir in mask_dirs {
        for ext in MASK_EXTENSIONS {
            out.push(root.join(dir).join(rel).with_extension(ext));
        }
    }
    out
}

/// Reads a `params/<n>.npy` file: `poses` (72), `Rh` (3), `Th` (3, metres), `shapes` (any
/// length), every value finite.
pub fn read_params(path: &Path) -> Result<SmplParams, DatasetError> {
    let value = load_dict(
        path,
        "SMPL parameters of this frame",
        "a dict with keys poses, Rh, Th, shapes",
    )?;
    let get = |key: &str, len: Option<usize>, expected: &str| {
        let v = value.get(key).ok_or_else(|| {
            DatasetError::field(
                path,
                key,
                expected,
                format!("no such key (keys: {})", value.keys().join(", ")),
            )
        })?;
        let (shape, values) =
            numeric(v).ok_or_else(|| DatasetError::field(path, key, expected, v.type_name()))?;
        if len.is_some_and(|n| values.len() != n) {
            return Err(DatasetError::field(
                path,
                key,
                expected,
                format!("shape {shape:?}"),
            ));
        }
        check_finite(&values, path, key)?;
        Ok(values)
    };
    let poses = get("poses", Some(72), "shape [1, 72] (axis-angle per joint)")?;
    let rh = get("Rh", Some(3), "shape [1, 3] (axis-angle)")?;
    let th = get("Th", Some(3), "shape [1, 3] (metres)")?;
    let shapes = get("shapes", None, "shape [1, S] (betas)")?;
    let mut p = [0.0f32; 72];
    for (d, s) in p.iter_mut().zip(&poses) {
        *d = *s as f32;
    }
    Ok(SmplParams {
        poses: p,
        shapes: shapes.iter().map(|v| *v as f32).collect(),
        rh: Vec3::new(rh[0] as f32, rh[1] as f32, rh[2] as f32),
        th: Vec3::new(th[0] as f32, th[1] as f32, th[2] as f32),
    })
}

/// Reads a `vertices/<n>.npy` file: [V, 3] world vertices in metres, every value finite.
pub fn read_vertices(path: &Path) -> Result<Vec<Vec3>, DatasetError> {
    let value = load_required(path, "SMPL vertices of this frame")?;
    let (shape, values) = numeric(&value).ok_or_else(|| {
        DatasetError::field(path, "<array>", "a [V, 3] float array", value.type_name())
    })?;
    if shape.len() != 2 || shape[1] != 3 || shape[0] == 0 {
        return Err(DatasetError::field(
            path,
            "<array>",
            "shape [V, 3] with V >= 1 (world vertices, metres)",
            format!("shape {shape:?}"),
        ));
    }
    check_finite(&values, path, "<array>")?;
    Ok(values
        .chunks_exact(3)
        .map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_numbers_from_zju_names() {
        assert_eq!(frame_number("Camera_B1/000123.jpg"), Some(123));
        assert_eq!(
            frame_number("Camera (1)/CoreView_313_Camera_(1)_0001_2019-08-23_16-08-50.592.jpg"),
            Some(1)
        );
        assert_eq!(frame_number("Camera_B1/frame.jpg"), None);
    }
}
