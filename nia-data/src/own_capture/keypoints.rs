//! 2D keypoints in OpenPose's JSON, the format OpenPose writes with `--write_json` and most
//! other detectors (MMPose, RTMPose, AlphaPose with `--format open`) can write:
//!
//! ```json
//! {"version": 1.3, "people": [{"person_id": [-1],
//!   "pose_keypoints_2d": [x0, y0, c0, x1, y1, c1, ...],
//!   "face_keypoints_2d": [], "hand_left_keypoints_2d": [], "hand_right_keypoints_2d": [],
//!   "pose_keypoints_3d": [], "face_keypoints_3d": [], "hand_left_keypoints_3d": [],
//!   "hand_right_keypoints_3d": []}]}
//! ```
//!
//! One file per image (`<frame>_keypoints.json`). `x, y` are pixels in the image the detector
//! saw, OpenCV's convention (the centre of pixel `(i, j)` is at `(i, j)`), which is the
//! project's [`crate::geometry::camera::Camera`] convention; `c` is the detector's confidence
//! in `[0, 1]`; a keypoint not detected is `(0, 0, 0)`. The layout follows from the count:
//! 25 points are BODY_25, 18 points COCO-18 (OpenPose's `--model_pose COCO`). Files of
//! OpenPose before 1.2 name the array `pose_keypoints`; it is read when `pose_keypoints_2d` is
//! absent. Face and hand arrays are ignored.

use std::path::Path;

use serde::Serialize;
use serde_json::Value;

use super::error::{show, OwnCaptureError};

/// The keypoint sets of OpenPose's body models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KeypointLayout {
    /// OpenPose BODY_25: 25 points, COCO's 18 plus MidHip and six foot points.
    Body25,
    /// OpenPose COCO: 18 points (COCO's 17 plus Neck, in OpenPose's order).
    Coco18,
}

/// OpenPose COCO-18 keypoint names, in file order (`POSE_COCO_BODY_PARTS`).
pub const COCO18_NAMES: [&str; 18] = [
    "Nose",
    "Neck",
    "RShoulder",
    "RElbow",
    "RWrist",
    "LShoulder",
    "LElbow",
    "LWrist",
    "RHip",
    "RKnee",
    "RAnkle",
    "LHip",
    "LKnee",
    "LAnkle",
    "REye",
    "LEye",
    "REar",
    "LEar",
];

/// OpenPose BODY_25 keypoint names, in file order (OpenPose `poseParameters.cpp`,
/// `POSE_BODY_25_BODY_PARTS`): COCO-18's first eight (Nose to LWrist), MidHip, COCO-18's other
/// ten (RHip to LEar), then the six foot points.
pub const BODY25_NAMES: [&str; 25] = body25_names();

/// BODY_25's points after COCO-18's, in file order.
const BODY25_FEET: [&str; 6] = [
    "LBigToe",
    "LSmallToe",
    "LHeel",
    "RBigToe",
    "RSmallToe",
    "RHeel",
];

/// [`BODY25_NAMES`] from COCO-18's names, MidHip and the feet.
const fn body25_names() -> [&'static str; 25] {
    let mut names = [""; 25];
    let mut i = 0;
    while i < names.len() {
        names[i] = match i {
            0..8 => COCO18_NAMES[i],
            8 => "MidHip",
            9..19 => COCO18_NAMES[i - 1],
            _ => BODY25_FEET[i - 19],
        };
        i += 1;
    }
    names
}

/// Values per keypoint in the file: x, y, confidence.
pub const VALUES_PER_KEYPOINT: usize = 3;

/// The OpenPose JSON `version` this module writes.
pub const OPENPOSE_VERSION: f32 = 1.3;

impl KeypointLayout {
    /// Number of keypoints.
    pub fn len(self) -> usize {
        keypoint_names(self).len()
    }

    /// Always false (every layout has keypoints); for clippy's `len_without_is_empty`.
    pub fn is_empty(self) -> bool {
        false
    }

    /// The layout with `count` keypoints, if any.
    pub fn from_count(count: usize) -> Option<Self> {
        [KeypointLayout::Body25, KeypointLayout::Coco18]
            .into_iter()
            .find(|l| l.len() == count)
    }

    /// The name used on the command line and in configs: `body25` or `coco18`.
    pub fn name(self) -> &'static str {
        match self {
            KeypointLayout::Body25 => "body25",
            KeypointLayout::Coco18 => "coco18",
        }
    }

    /// Index of the keypoint called `name` (OpenPose's spelling, e.g. `"LHeel"`).
    pub fn index_of(self, name: &str) -> Option<usize> {
        keypoint_names(self).iter().position(|n| *n == name)
    }
}

impl std::str::FromStr for KeypointLayout {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "body25" | "body_25" | "BODY_25" => Ok(KeypointLayout::Body25),
            "coco18" | "coco" | "COCO" => Ok(KeypointLayout::Coco18),
            other => Err(format!("`{other}`: expected body25 or coco18")),
        }
    }
}

impl std::fmt::Display for KeypointLayout {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The keypoint names of `layout`, in file order.
pub fn keypoint_names(layout: KeypointLayout) -> &'static [&'static str] {
    match layout {
        KeypointLayout::Body25 => &BODY25_NAMES,
        KeypointLayout::Coco18 => &COCO18_NAMES,
    }
}

/// One person's 2D keypoints in one image.
#[derive(Debug, Clone, PartialEq)]
pub struct Keypoints2d {
    pub layout: KeypointLayout,
    /// `[layout.len()]` `(x, y, confidence)`: pixels (OpenCV convention, as
    /// [`crate::geometry::camera::Camera`]) and a confidence in `[0, 1]`; `(0, 0, 0)` is a
    /// keypoint not detected.
    pub points: Vec<[f32; 3]>,
}

impl Keypoints2d {
    /// Every keypoint undetected.
    pub fn undetected(layout: KeypointLayout) -> Self {
        Keypoints2d {
            layout,
            points: vec![[0.0; 3]; layout.len()],
        }
    }

    /// Sum of the confidences (how [`read_openpose`] picks one person among several).
    pub fn total_confidence(&self) -> f32 {
        self.points.iter().map(|p| p[2]).sum()
    }

    /// True when keypoint `i` was detected (confidence > 0).
    pub fn detected(&self, i: usize) -> bool {
        self.points.get(i).is_some_and(|p| p[2] > 0.0)
    }
}

/// Reads one OpenPose JSON file. `None` when `people` is empty (nobody detected); with several
/// people, the one with the largest summed confidence (the first of equals). Every person's
/// array is checked: a count that is not 25 x 3 or 18 x 3 values, a non-number or a negative
/// confidence is an error naming the file and the field.
pub fn read_openpose(path: &Path) -> Result<Option<Keypoints2d>, OwnCaptureError> {
    let text = std::fs::read_to_string(path).map_err(|e| OwnCaptureError::io(path, "read", e))?;
    let root: Value = serde_json::from_str(&text).map_err(|source| OwnCaptureError::Json {
        path: path.to_path_buf(),
        expected: "an OpenPose keypoint file {\"people\": [{\"pose_keypoints_2d\": [...]}]}",
        source,
    })?;
    let people = root
        .get("people")
        .ok_or_else(|| {
            OwnCaptureError::field(
                path,
                "people",
                "a list of people (OpenPose JSON)",
                "no such field",
            )
        })?
        .as_array()
        .ok_or_else(|| {
            OwnCaptureError::field(path, "people", "a list of people", show(&root["people"]))
        })?;
    let mut best: Option<Keypoints2d> = None;
    for (i, person) in people.iter().enumerate() {
        let kp = read_person(path, i, person)?;
        if best
            .as_ref()
            .is_none_or(|b| kp.total_confidence() > b.total_confidence())
        {
            best = Some(kp);
        }
    }
    Ok(best)
}

fn read_person(path: &Path, i: usize, person: &Value) -> Result<Keypoints2d, OwnCaptureError> {
    if !person.is_object() {
        return Err(OwnCaptureError::field(
            path,
            format!("people[{i}]"),
            "an object with `pose_keypoints_2d`",
            show(person),
        ));
    }
    let (key, values) =
        match (
            person.get("pose_keypoints_2d"),
            person.get("pose_keypoints"),
        ) {
            (Some(v), _) => ("pose_keypoints_2d", v),
            (None, Some(v)) => ("pose_keypoints", v),
            (None, None) => return Err(OwnCaptureError::field(
                path,
                format!("people[{i}].pose_keypoints_2d"),
                "a flat list [x0, y0, c0, x1, y1, c1, ...] of 75 (BODY_25) or 54 (COCO-18) numbers",
                "no such field",
            )),
        };
    let field = format!("people[{i}].{key}");
    let list = values.as_array().ok_or_else(|| {
        OwnCaptureError::field(
            path,
            &field,
            "a flat list of numbers [x0, y0, c0, ...]",
            show(values),
        )
    })?;
    let layout = (list.len() % VALUES_PER_KEYPOINT == 0)
        .then(|| KeypointLayout::from_count(list.len() / VALUES_PER_KEYPOINT))
        .flatten()
        .ok_or_else(|| OwnCaptureError::KeypointCount {
            path: path.to_path_buf(),
            field: field.clone(),
            values: list.len(),
        })?;
    let mut flat = Vec::with_capacity(list.len());
    for (j, v) in list.iter().enumerate() {
        let x = v
            .as_f64()
            .filter(|x| x.is_finite() && x.abs() <= f32::MAX as f64)
            .ok_or_else(|| {
                OwnCaptureError::field(path, format!("{field}[{j}]"), "a number", show(v))
            })?;
        flat.push(x as f32);
    }
    let points: Vec<[f32; 3]> = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    if let Some(k) = points.iter().position(|p| p[2] < 0.0) {
        return Err(OwnCaptureError::field(
            path,
            format!("{field}[{}]", k * 3 + 2),
            format!(
                "a confidence >= 0 for keypoint {k} ({})",
                keypoint_names(layout)[k]
            ),
            points[k][2].to_string(),
        ));
    }
    Ok(Keypoints2d { layout, points })
}

/// One person as OpenPose writes it (field order as OpenPose's).
#[derive(Serialize)]
struct PersonOut<'a> {
    person_id: [i32; 1],
    pose_keypoints_2d: &'a [f32],
    face_keypoints_2d: [f32; 0],
    hand_left_keypoints_2d: [f32; 0],
    hand_right_keypoints_2d: [f32; 0],
    pose_keypoints_3d: [f32; 0],
    face_keypoints_3d: [f32; 0],
    hand_left_keypoints_3d: [f32; 0],
    hand_right_keypoints_3d: [f32; 0],
}

#[derive(Serialize)]
struct FileOut<'a> {
    version: f32,
    people: Vec<PersonOut<'a>>,
}

/// The bytes [`write_openpose`] writes (one line of JSON and a newline), for one person or,
/// with `None`, nobody (`"people": []`).
pub fn openpose_json(kp: Option<&Keypoints2d>) -> Vec<u8> {
    let flat: Vec<f32> = kp
        .map(|k| k.points.iter().flatten().copied().collect())
        .unwrap_or_default();
    let people = kp
        .map(|_| PersonOut {
            person_id: [-1],
            pose_keypoints_2d: &flat,
            face_keypoints_2d: [],
            hand_left_keypoints_2d: [],
            hand_right_keypoints_2d: [],
            pose_keypoints_3d: [],
            face_keypoints_3d: [],
            hand_left_keypoints_3d: [],
            hand_right_keypoints_3d: [],
        })
        .into_iter()
        .collect();
    let file = FileOut {
        version: OPENPOSE_VERSION,
        people,
    };
    // Serialising plain numbers and strings cannot fail.
    let mut bytes = serde_json::to_vec(&file).unwrap_or_default();
    bytes.push(b'\n');
    bytes
}

/// Writes one person's keypoints as an OpenPose JSON file (`person_id` -1, empty face and hand
/// arrays). The keypoint count must match the layout, and every value be finite.
pub fn write_openpose(path: &Path, kp: &Keypoints2d) -> Result<(), OwnCaptureError> {
    if kp.points.len() != kp.layout.len() {
        return Err(OwnCaptureError::field(
            path,
            "pose_keypoints_2d",
            format!("{} keypoints ({})", kp.layout.len(), kp.layout),
            format!("{} keypoints", kp.points.len()),
        ));
    }
    if let Some(k) = kp
        .points
        .iter()
        .position(|p| p.iter().any(|v| !v.is_finite()))
    {
        return Err(OwnCaptureError::field(
            path,
            format!("pose_keypoints_2d[{}]", k * 3),
            "finite x, y, confidence",
            format!("{:?}", kp.points[k]),
        ));
    }
    std::fs::write(path, openpose_json(Some(kp))).map_err(|e| OwnCaptureError::io(path, "write", e))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// BODY_25 in OpenPose's order: COCO-18's points around MidHip, then the feet.
    #[test]
    fn body25_is_coco18_with_mid_hip_and_the_feet() {
        let expected = [
            (0, "Nose"),
            (7, "LWrist"),
            (8, "MidHip"),
            (9, "RHip"),
            (18, "LEar"),
            (19, "LBigToe"),
            (24, "RHeel"),
        ];
        for (i, name) in expected {
            assert_eq!(BODY25_NAMES[i], name, "BODY_25 point {i}");
        }
        let unique: std::collections::BTreeSet<_> = BODY25_NAMES.iter().collect();
        assert_eq!(unique.len(), 25, "{BODY25_NAMES:?}");
        assert!(COCO18_NAMES.iter().all(|n| BODY25_NAMES.contains(n)));
    }
}
