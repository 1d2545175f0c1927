//! Where each OpenPose keypoint lies on an SMPL-compatible body: at one of SMPL's 24 joints,
//! midway between two joints, or at one surface vertex.
//!
//! # Body keypoints: SMPL joints
//!
//! Neck, shoulders, elbows, wrists, hips, knees and ankles are SMPL's joints of the same name
//! (`neck` 12, `R_shoulder` 17, ...; [`crate::body::JOINT_NAMES`]); OpenPose's MidHip is the
//! midpoint of SMPL's hips (1, 2). This is the assignment of SMPLify-X's
//! `smpl_to_openpose` (Pavlakos et al. 2019, `smplifyx/utils.py`) and of SPIN's `JOINT_MAP`
//! (Kolotouros et al. 2019, `constants.py`), except MidHip, which both take from SMPL's
//! pelvis (joint 0): the pelvis lies several centimetres above the hip joints, where OpenPose's
//! MidHip (the midpoint of its two hips) does not.
//!
//! Known offsets (why a fitter should trust these keypoints less than the others): a detector
//! trained on COCO-style annotations puts the hips higher and further apart than SMPL's hip
//! joints, which sit inside the pelvis (SMPLify, Bogo et al. 2016, down-weights the hips for
//! this reason; SMPLify-X exposes `use_hips`), and its shoulders near the top of the shoulder,
//! above and outside SMPL's shoulder joints (the gleno-humeral joint). Elbows, wrists, knees and
//! ankles agree with SMPL's joints to about their radius. On the synthetic test bed
//! (`nia-train synth --keypoints`) the keypoints are made with this very map, so no offset
//! exists there.
//!
//! # Face and foot keypoints: surface vertices
//!
//! For a real SMPL model (6890 vertices, SMPL's topology) the vertices are those published by
//! SMPL-X's `smplx/vertex_ids.py` (`vertex_ids['smplh']`, shared by SMPL and SMPL+H; used by
//! SMPLify-X, SPIN, VIBE, EasyMocap): nose 332, eyes 6260 (right) / 2800 (left), ears 4071 /
//! 583, big toes 6617 / 3216, small toes 6624 / 3226, heels 6787 / 3387. See
//! [`SMPL_LANDMARK_VERTICES`].
//!
//! Any other SMPL-compatible body (the procedural body of [`crate::body::procedural`], whose
//! vertices are numbered by its own meshing) gets its vertices geometrically, in the rest pose
//! (`v_template`, SMPL coordinates: y up, facing +z, the body's left at +x): each landmark is a
//! target point at an offset from a joint, in units of the body's height `H` (the extent of
//! `v_template` along y), placed just outside the surface; its vertex is the one nearest to the
//! target among the vertices skinned mostly to the part it belongs to (head and neck for the
//! face, ankle and foot of that side for the feet), the lowest index among equals. Deterministic,
//! and it follows the body's proportions. The offsets are in [`GEOMETRIC_LANDMARKS`].

use glam::Vec3;

use super::keypoints::{keypoint_names, KeypointLayout};
use crate::body::BodyModel;

/// Vertices of SMPL's mesh (the topology [`SMPL_LANDMARK_VERTICES`] indexes).
pub const SMPL_NUM_VERTICES: usize = 6890;

/// SMPL vertex of each OpenPose face and foot keypoint, from SMPL-X's `smplx/vertex_ids.py`
/// (`vertex_ids['smplh']`; SMPL shares SMPL+H's body topology).
pub const SMPL_LANDMARK_VERTICES: [(&str, usize); 11] = [
    ("Nose", 332),
    ("REye", 6260),
    ("LEye", 2800),
    ("REar", 4071),
    ("LEar", 583),
    ("LBigToe", 3216),
    ("LSmallToe", 3226),
    ("LHeel", 3387),
    ("RBigToe", 6617),
    ("RSmallToe", 6624),
    ("RHeel", 6787),
];

/// How a landmark vertex is found on a body without SMPL's topology (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeometricLandmark {
    /// OpenPose keypoint name.
    pub name: &'static str,
    /// SMPL joint the target is placed from.
    pub joint: usize,
    /// Target offset from the joint in units of body height: (x = the body's left, y = up,
    /// z = front), rest pose.
    pub offset_h: [f32; 3],
    /// SMPL joints whose skinning region the vertex must belong to (largest weight).
    pub parts: [usize; 2],
}

const fn landmark(
    name: &'static str,
    joint: usize,
    offset_h: [f32; 3],
    parts: [usize; 2],
) -> GeometricLandmark {
    GeometricLandmark {
        name,
        joint,
        offset_h,
        parts,
    }
}

/// The face and foot landmarks of a body without SMPL's topology. Joints: 15 head, 12 neck,
/// 7 / 8 left / right ankle, 10 / 11 left / right foot. Right-side offsets mirror the left's
/// (x negated).
pub const GEOMETRIC_LANDMARKS: [GeometricLandmark; 11] = [
    landmark("Nose", 15, [0.0, 0.035, 0.10], [15, 12]),
    landmark("REye", 15, [-0.018, 0.05, 0.10], [15, 12]),
    landmark("LEye", 15, [0.018, 0.05, 0.10], [15, 12]),
    landmark("REar", 15, [-0.08, 0.035, 0.0], [15, 12]),
    landmark("LEar", 15, [0.08, 0.035, 0.0], [15, 12]),
    landmark("LBigToe", 10, [-0.012, -0.01, 0.06], [10, 7]),
    landmark("LSmallToe", 10, [0.015, -0.01, 0.05], [10, 7]),
    landmark("LHeel", 7, [0.0, -0.04, -0.06], [7, 10]),
    landmark("RBigToe", 11, [0.012, -0.01, 0.06], [11, 8]),
    landmark("RSmallToe", 11, [-0.015, -0.01, 0.05], [11, 8]),
    landmark("RHeel", 8, [0.0, -0.04, -0.06], [8, 11]),
];

/// Where one OpenPose keypoint comes from on the body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeypointSource {
    /// SMPL joint `j` ([`crate::body::JOINT_NAMES`]).
    Joint(usize),
    /// Body vertex `v`.
    Vertex(usize),
    /// Midway between SMPL joints `a` and `b`.
    Midpoint(usize, usize),
    /// Not on the body model (no position).
    Unmapped,
}

/// The SMPL joint (or joint pair) of an OpenPose body keypoint; `None` for face and foot
/// keypoints (vertices) and unknown names.
fn joint_source(name: &str) -> Option<KeypointSource> {
    use KeypointSource::{Joint, Midpoint};
    Some(match name {
        "Neck" => Joint(12),
        "RShoulder" => Joint(17),
        "RElbow" => Joint(19),
        "RWrist" => Joint(21),
        "LShoulder" => Joint(16),
        "LElbow" => Joint(18),
        "LWrist" => Joint(20),
        "MidHip" => Midpoint(1, 2),
        "RHip" => Joint(2),
        "RKnee" => Joint(5),
        "RAnkle" => Joint(8),
        "LHip" => Joint(1),
        "LKnee" => Joint(4),
        "LAnkle" => Joint(7),
        _ => return None,
    })
}

/// `[layout.len()]` the source of each keypoint of `layout` on `model` (module docs): SMPL's
/// published vertices when the model has [`SMPL_NUM_VERTICES`] vertices, else vertices chosen
/// geometrically ([`GEOMETRIC_LANDMARKS`]). Pure function of the model.
pub fn keypoint_sources(layout: KeypointLayout, model: &BodyModel) -> Vec<KeypointSource> {
    let landmarks = landmark_vertices(model);
    keypoint_names(layout)
        .iter()
        .map(|name| {
            joint_source(name)
                .or_else(|| {
                    landmarks
                        .iter()
                        .find(|(n, _)| n == name)
                        .and_then(|(_, v)| v.map(KeypointSource::Vertex))
                })
                .unwrap_or(KeypointSource::Unmapped)
        })
        .collect()
}

/// The vertex of each face and foot landmark on `model` (`None` where the model has no
/// vertex in that part), in the order of [`SMPL_LANDMARK_VERTICES`].
pub fn landmark_vertices(model: &BodyModel) -> Vec<(&'static str, Option<usize>)> {
    let n = model.num_vertices();
    if n == SMPL_NUM_VERTICES {
        return SMPL_LANDMARK_VERTICES
            .iter()
            .map(|&(name, v)| (name, (v < n).then_some(v)))
            .collect();
    }
    let rest_joints = model.regress_joints(&model.v_template);
    let (lo, hi) = model
        .v_template
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v.y), hi.max(v.y))
        });
    let height = (hi - lo).max(0.0);
    // The joint with the largest skinning weight of each vertex (the lowest of equals).
    let part: Vec<usize> = model
        .weights
        .iter()
        .map(|w| {
            w.iter()
                .enumerate()
                .fold((0, f32::NEG_INFINITY), |best, (j, &x)| {
                    if x > best.1 {
                        (j, x)
                    } else {
                        best
                    }
                })
                .0
        })
        .collect();
    GEOMETRIC_LANDMARKS
        .iter()
        .map(|l| {
            let target = rest_joints[l.joint] + Vec3::from(l.offset_h) * height;
            let nearest = model
                .v_template
                .iter()
                .enumerate()
                .filter(|(i, _)| l.parts.contains(&part[*i]))
                .map(|(i, v)| (i, v.distance_squared(target)))
                .fold(None::<(usize, f32)>, |best, (i, d)| match best {
                    Some((_, bd)) if bd <= d => best,
                    _ => Some((i, d)),
                })
                .map(|(i, _)| i);
            (l.name, nearest)
        })
        .collect()
}

/// `[K]` the 3D position of each keypoint: `sources` from [`keypoint_sources`], the posed
/// body's `[V]` vertices and `[24]` joints (world metres, e.g. [`crate::body::Posed`]).
/// `None` for [`KeypointSource::Unmapped`] and indices past the arrays.
pub fn keypoints_3d(
    sources: &[KeypointSource],
    posed_vertices: &[Vec3],
    posed_joints: &[Vec3],
) -> Vec<Option<Vec3>> {
    sources
        .iter()
        .map(|s| match *s {
            KeypointSource::Joint(j) => posed_joints.get(j).copied(),
            KeypointSource::Vertex(v) => posed_vertices.get(v).copied(),
            KeypointSource::Midpoint(a, b) => posed_joints
                .get(a)
                .zip(posed_joints.get(b))
                .map(|(a, b)| 0.5 * (*a + *b)),
            KeypointSource::Unmapped => None,
        })
        .collect()
}
