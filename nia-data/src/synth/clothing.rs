//! The clothed surface: which garment covers each point of the canonical (rest-pose) body, the
//! garment coordinates the patterns are drawn in, and how far each garment stands off the skin.
//!
//! Everything here is a function of the canonical body (rest-pose vertices and joints after the
//! shape blend, SMPL T-pose, y up, +z front), so garments and their patterns move with the body.
//! The clothed mesh has the body's topology: each posed vertex is pushed out along its posed
//! normal by its garment offset ([`clothe`]), which makes the clothed surface differ from the
//! SMPL surface the way a shirt and trousers do.

use glam::Vec3;

/// Number of SMPL joints the body parts are defined over.
pub const SMPL_JOINTS: usize = 24;

/// Body parts the skinning weights are grouped into (argmax picks a point's part).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    Torso,
    Head,
    LeftArm,
    RightArm,
    LeftLeg,
    RightLeg,
}

/// Number of [`Part`]s.
pub const PART_COUNT: usize = 6;

const PARTS: [Part; PART_COUNT] = [
    Part::Torso,
    Part::Head,
    Part::LeftArm,
    Part::RightArm,
    Part::LeftLeg,
    Part::RightLeg,
];

/// SMPL joint index -> part index in [`PARTS`] (pelvis, spine and collars are torso; neck and
/// head are head; shoulder..hand are arms; hip..foot are legs).
const JOINT_PART: [usize; SMPL_JOINTS] = [
    0, // 0 pelvis
    4, // 1 left hip
    5, // 2 right hip
    0, // 3 spine1
    4, // 4 left knee
    5, // 5 right knee
    0, // 6 spine2
    4, // 7 left ankle
    5, // 8 right ankle
    0, // 9 spine3
    4, // 10 left foot
    5, // 11 right foot
    1, // 12 neck
    0, // 13 left collar
    0, // 14 right collar
    1, // 15 head
    2, // 16 left shoulder
    3, // 17 right shoulder
    2, // 18 left elbow
    3, // 19 right elbow
    2, // 20 left wrist
    3, // 21 right wrist
    2, // 22 left hand
    3, // 23 right hand
];

/// Joint chains (shoulder/hip first) the limb coordinates are measured along.
const LEFT_ARM: [usize; 4] = [16, 18, 20, 22];
const RIGHT_ARM: [usize; 4] = [17, 19, 21, 23];
const LEFT_LEG: [usize; 4] = [1, 4, 7, 10];
const RIGHT_LEG: [usize; 4] = [2, 5, 8, 11];

const PELVIS: usize = 0;
const SPINE1: usize = 3;
const SPINE2: usize = 6;
const SPINE3: usize = 9;
const NECK: usize = 12;
const HEAD: usize = 15;

/// Nominal radii (metres) that turn an angle around the torso/limb axis into a length, so
/// patterns have roughly metric periods all round.
pub const TORSO_RADIUS_M: f32 = 0.15;
pub const ARM_RADIUS_M: f32 = 0.045;
pub const LEG_RADIUS_M: f32 = 0.07;

/// Leg chain coordinate above which the shoe starts (2 = ankle joint): a few centimetres above
/// the ankle, like a low boot or trainer.
pub const SHOE_START: f32 = 1.9;

/// Part weights of one vertex: its skinning weights summed per [`Part`].
/// `weights` is one row of the SMPL `weights` matrix (24 entries); extra entries are ignored.
pub fn part_weights(weights: &[f32]) -> [f32; PART_COUNT] {
    let mut out = [0.0; PART_COUNT];
    for (j, &w) in weights.iter().take(SMPL_JOINTS).enumerate() {
        out[JOINT_PART[j]] += w;
    }
    out
}

/// The part with the largest weight (first on ties, so the choice is deterministic).
pub fn dominant_part(parts: &[f32; PART_COUNT]) -> Part {
    let mut best = 0;
    for i in 1..PART_COUNT {
        if parts[i] > parts[best] {
            best = i;
        }
    }
    PARTS[best]
}

/// Landmarks of one canonical (rest-pose, shaped) body that the garments are cut against.
#[derive(Debug, Clone)]
pub struct BodyFrame {
    /// [24] rest-pose joint locations, metres, SMPL order.
    pub joints: [Vec3; SMPL_JOINTS],
    /// Highest point of the head, metres (canonical y).
    pub head_top_y: f32,
    /// Frontmost point of the head (canonical z), metres.
    pub face_front_z: f32,
    /// Lowest point of the body (sole), metres (canonical y).
    pub sole_y: f32,
    /// Canonical z of the torso's vertical axis, metres.
    pub torso_axis_z: f32,
}

impl BodyFrame {
    /// Landmarks from the rest-pose joints `[24]` and vertices `[V]` with their part weights
    /// `[V]`. `None` when there are fewer than 24 joints or no vertices.
    pub fn new(
        rest_joints: &[Vec3],
        rest_vertices: &[Vec3],
        parts: &[[f32; PART_COUNT]],
    ) -> Option<Self> {
        if rest_joints.len() < SMPL_JOINTS || rest_vertices.is_empty() {
            return None;
        }
        let mut joints = [Vec3::ZERO; SMPL_JOINTS];
        joints.copy_from_slice(&rest_joints[..SMPL_JOINTS]);
        let mut head_top_y = f32::NEG_INFINITY;
        let mut face_front_z = f32::NEG_INFINITY;
        let mut sole_y = f32::INFINITY;
        for (v, p) in rest_vertices.iter().zip(parts) {
            sole_y = sole_y.min(v.y);
            if dominant_part(p) == Part::Head {
                head_top_y = head_top_y.max(v.y);
                face_front_z = face_front_z.max(v.z);
            }
        }
        if !head_top_y.is_finite() {
            // No head vertices: fall back to the extent of the whole body.
            head_top_y = rest_vertices
                .iter()
                .map(|v| v.y)
                .fold(f32::NEG_INFINITY, f32::max);
            face_front_z = rest_vertices
                .iter()
                .map(|v| v.z)
                .fold(f32::NEG_INFINITY, f32::max);
        }
        let torso_axis_z =
            (joints[PELVIS].z + joints[SPINE1].z + joints[SPINE2].z + joints[SPINE3].z) / 4.0;
        Some(Self {
            joints,
            head_top_y,
            face_front_z,
            sole_y,
            torso_axis_z,
        })
    }

    /// Natural waist height (between pelvis and spine1), metres.
    pub fn waist_y(&self) -> f32 {
        0.5 * (self.joints[PELVIS].y + self.joints[SPINE1].y)
    }

    /// Chest height (spine3), metres.
    pub fn chest_y(&self) -> f32 {
        self.joints[SPINE3].y
    }

    pub fn neck(&self) -> Vec3 {
        self.joints[NECK]
    }

    pub fn head(&self) -> Vec3 {
        self.joints[HEAD]
    }

    /// Neck-to-chest distance, the unit the neckline is cut in, metres.
    fn neck_drop(&self) -> f32 {
        (self.joints[NECK].y - self.joints[SPINE3].y)
            .abs()
            .max(0.05)
    }

    /// Canonical height at or below which the hair stops, for a point at canonical z.
    /// Front of the head: a forehead hairline; back: down to the nape.
    pub fn hairline_y(&self, z: f32, hair_length: f32) -> f32 {
        let head = self.head();
        let front = head.y + 0.6 * (self.head_top_y - head.y);
        let back = self.neck().y + (0.2 + 0.6 * (1.0 - hair_length)) * (head.y - self.neck().y);
        let t = smoothstep(head.z - 0.02, self.face_front_z - 0.03, z);
        back + (front - back) * t
    }
}

/// How a subject's clothes are cut (drawn per subject in `subject.rs`).
#[derive(Debug, Clone, PartialEq)]
pub struct Cut {
    /// Sleeve end on the arm chain (0 shoulder, 1 elbow, 2 wrist).
    pub sleeve_end: f32,
    /// Trouser end on the leg chain (0 hip, 1 knee, 2 ankle).
    pub trouser_end: f32,
    /// Shirt hem below the natural waist, metres (0 = tucked in, belt visible).
    pub hem_below_waist_m: f32,
    /// Depth of a V neckline at the front, metres (0 = crew neck).
    pub v_neck_m: f32,
    /// Hair length in [0, 1] (how far down the back of the head the hair reaches).
    pub hair_length: f32,
    /// Shirt distance from the skin, metres.
    pub shirt_ease_m: f32,
    /// Extra shirt distance at the hem (a looser, flared shirt), metres.
    pub shirt_flare_m: f32,
    /// Trouser distance from the skin, metres.
    pub trouser_ease_m: f32,
    /// Extra trouser distance at the cuffs, metres.
    pub trouser_flare_m: f32,
    /// Amplitude of the low-frequency folds, metres.
    pub wrinkle_m: f32,
    /// Phase of the folds (radians), so subjects fold differently.
    pub wrinkle_phase: f32,
}

/// What covers a point of the body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Garment {
    Skin,
    Hair,
    Shirt,
    Trousers,
    Belt,
    Shoes,
}

/// A canonical surface point with its garment and garment coordinates.
#[derive(Debug, Clone, Copy)]
pub struct GarmentPoint {
    pub garment: Garment,
    pub part: Part,
    /// Canonical position, metres.
    pub canonical: Vec3,
    /// Metres along the garment: canonical height y on the torso and legs, arc length from the
    /// shoulder on the arms.
    pub along_m: f32,
    /// Metres around the torso/limb axis (angle times a nominal radius), 0 at the front.
    pub around_m: f32,
    /// Angle around the torso/limb axis, radians in (-pi, pi], 0 facing front (+z), +pi/2 at
    /// the body's left (+x) side on the torso.
    pub angle: f32,
    /// Limb chain coordinate (0 shoulder/hip, 1 elbow/knee, 2 wrist/ankle, 3 hand/foot);
    /// 0 on the torso and head.
    pub chain: f32,
    /// Distance to the garment's nearest cut edge (hem, cuff, neckline, belt edge), metres.
    pub edge_m: f32,
}

/// Where `p` sits along a four-joint chain: (chain coordinate, arc length in metres, the
/// closest point on the chain, that segment's unit axis).
fn chain_coords(
    joints: &[Vec3; SMPL_JOINTS],
    chain: &[usize; 4],
    p: Vec3,
) -> (f32, f32, Vec3, Vec3) {
    let mut best = (f32::INFINITY, 0.0, 0.0, Vec3::ZERO, Vec3::X);
    let mut cum = 0.0;
    for i in 0..3 {
        let a = joints[chain[i]];
        let b = joints[chain[i + 1]];
        let ab = b - a;
        let len2 = ab.length_squared().max(1e-12);
        let len = len2.sqrt();
        let t_raw = (p - a).dot(ab) / len2;
        let closest = a + ab * t_raw.clamp(0.0, 1.0);
        let dist = (p - closest).length();
        // The first and last segments extend past their ends (into the torso, past the hand).
        let t = match i {
            0 => t_raw.min(1.0),
            2 => t_raw.max(0.0),
            _ => t_raw.clamp(0.0, 1.0),
        };
        if dist < best.0 {
            best = (dist, i as f32 + t, cum + t * len, closest, ab / len);
        }
        cum += len;
    }
    (best.1, best.2, best.3, best.4)
}

/// Angle of `p` around the axis through `centre` along `axis`, 0 towards +z (or +y when the
/// axis itself points along z, as the foot does).
fn angle_around(p: Vec3, centre: Vec3, axis: Vec3) -> f32 {
    let reference = if axis.z.abs() > 0.7 { Vec3::Y } else { Vec3::Z };
    let front = (reference - axis * reference.dot(axis)).normalize_or_zero();
    let side = axis.cross(front);
    let d = p - centre;
    d.dot(side).atan2(d.dot(front))
}

pub(crate) fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Height of the neckline at canonical x offset `dx` from the neck axis (the shirt covers
/// points below it); the V neck lowers it at the front.
fn neckline_y(frame: &BodyFrame, cut: &Cut, p: Vec3) -> f32 {
    let neck = frame.neck();
    let drop = frame.neck_drop();
    let dx = (p.x - neck.x).abs();
    let base = neck.y - 0.35 * drop + 1.6 * dx;
    let front = smoothstep(neck.z - 0.01, neck.z + 0.04, p.z);
    base - cut.v_neck_m * front * (1.0 - dx / (0.6 * drop).max(1e-3)).max(0.0)
}

/// Classify a canonical point with part weights `parts` (interpolated per pixel or per vertex).
pub fn classify(frame: &BodyFrame, cut: &Cut, p: Vec3, parts: &[f32; PART_COUNT]) -> GarmentPoint {
    let part = dominant_part(parts);
    let j = &frame.joints;
    let hem_y = frame.waist_y() - cut.hem_below_waist_m;
    let torso_angle = (p.x - j[PELVIS].x).atan2(p.z - frame.torso_axis_z);
    let mut gp = GarmentPoint {
        garment: Garment::Skin,
        part,
        canonical: p,
        along_m: p.y,
        around_m: torso_angle * TORSO_RADIUS_M,
        angle: torso_angle,
        chain: 0.0,
        edge_m: f32::INFINITY,
    };
    match part {
        Part::Head => {
            let hairline = frame.hairline_y(p.z, cut.hair_length);
            if p.y > hairline {
                gp.garment = Garment::Hair;
                gp.edge_m = p.y - hairline;
            }
            let head = frame.head();
            gp.angle = (p.x - head.x).atan2(p.z - head.z);
            gp.around_m = gp.angle * ARM_RADIUS_M * 2.0;
        }
        Part::Torso => {
            let neckline = neckline_y(frame, cut, p);
            if p.y > neckline {
                gp.garment = Garment::Skin;
            } else if p.y >= hem_y {
                gp.garment = Garment::Shirt;
                gp.edge_m = (neckline - p.y).min(p.y - hem_y);
            } else {
                gp.garment = trouser_top(cut, hem_y - p.y);
                gp.edge_m = hem_y - p.y;
            }
        }
        Part::LeftArm | Part::RightArm => {
            let chain = if part == Part::LeftArm {
                &LEFT_ARM
            } else {
                &RIGHT_ARM
            };
            let (s, arc, centre, axis) = chain_coords(j, chain, p);
            gp.chain = s;
            gp.along_m = arc;
            gp.angle = angle_around(p, centre, axis);
            gp.around_m = gp.angle * ARM_RADIUS_M;
            let upper = (j[chain[1]] - j[chain[0]]).length();
            if s < cut.sleeve_end {
                gp.garment = Garment::Shirt;
                gp.edge_m = (cut.sleeve_end - s) * upper;
            }
        }
        Part::LeftLeg | Part::RightLeg => {
            let chain = if part == Part::LeftLeg {
                &LEFT_LEG
            } else {
                &RIGHT_LEG
            };
            let (s, _arc, centre, axis) = chain_coords(j, chain, p);
            gp.chain = s;
            gp.angle = angle_around(p, centre, axis);
            gp.around_m = gp.angle * LEG_RADIUS_M;
            let thigh = (j[chain[1]] - j[chain[0]]).length();
            if s > SHOE_START {
                gp.garment = Garment::Shoes;
            } else if p.y >= hem_y {
                // Under an untucked shirt's hem.
                gp.garment = Garment::Shirt;
                gp.edge_m = p.y - hem_y;
            } else if s < cut.trouser_end {
                gp.garment = trouser_top(cut, hem_y - p.y);
                gp.edge_m = ((cut.trouser_end - s) * thigh).min(hem_y - p.y);
            }
        }
    }
    gp
}

/// Belt width, metres.
pub const BELT_WIDTH_M: f32 = 0.035;

/// Trousers, or the belt when the shirt is tucked in and the point is in the top band.
fn trouser_top(cut: &Cut, below_top_m: f32) -> Garment {
    if cut.hem_below_waist_m <= 0.0 && below_top_m < BELT_WIDTH_M {
        Garment::Belt
    } else {
        Garment::Trousers
    }
}

/// Distance (metres) the garment at `gp` stands off the skin, along the vertex normal.
pub fn garment_offset_m(frame: &BodyFrame, cut: &Cut, gp: &GarmentPoint) -> f32 {
    let p = gp.canonical;
    let folds = cut.wrinkle_m
        * ((p.y * 37.0 + (p.x * 23.0).sin() * 1.7 + cut.wrinkle_phase).sin()
            * (p.x * 19.0 - p.z * 13.0 + cut.wrinkle_phase).cos());
    match gp.garment {
        Garment::Skin => 0.0,
        Garment::Hair => {
            let top = smoothstep(frame.head().y, frame.head_top_y, p.y);
            0.004 + 0.012 * top * smoothstep(0.0, 0.03, gp.edge_m)
        }
        Garment::Shirt => {
            let (ease, flare) = match gp.part {
                Part::LeftArm | Part::RightArm => {
                    let t = (gp.chain / cut.sleeve_end.max(0.1)).clamp(0.0, 1.0);
                    (cut.shirt_ease_m * 0.8, cut.shirt_flare_m * 0.5 * t)
                }
                _ => {
                    let hem_y = frame.waist_y() - cut.hem_below_waist_m;
                    let t = smoothstep(frame.chest_y(), hem_y, p.y);
                    (cut.shirt_ease_m, cut.shirt_flare_m * t * t)
                }
            };
            // The collar hugs the neck.
            let collar = if gp.part == Part::Torso {
                smoothstep(0.0, 0.05, gp.edge_m)
            } else {
                1.0
            };
            ((ease + flare) * (0.35 + 0.65 * collar) + folds).max(0.002)
        }
        Garment::Trousers => {
            let flare = match gp.part {
                Part::LeftLeg | Part::RightLeg => {
                    cut.trouser_flare_m * smoothstep(0.8, cut.trouser_end.max(0.9), gp.chain)
                }
                _ => 0.0,
            };
            (cut.trouser_ease_m + flare + 0.6 * folds).max(0.002)
        }
        Garment::Belt => cut.trouser_ease_m + 0.004,
        Garment::Shoes => 0.008,
    }
}

/// The clothed surface: each posed vertex `[V]` pushed out along its unit posed normal `[V]` by
/// its offset `[V]` (metres).
pub fn clothe(posed: &[Vec3], normals: &[Vec3], offsets_m: &[f32]) -> Vec<Vec3> {
    posed
        .iter()
        .zip(normals)
        .zip(offsets_m)
        .map(|((&v, &n), &o)| v + n * o)
        .collect()
}

/// Area-weighted unit vertex normals `[V]` of a mesh with vertices `[V]` and faces `[F][3]`
/// (counter-clockwise seen from outside gives outward normals). Vertices without faces get +z.
pub fn vertex_normals(vertices: &[Vec3], faces: &[[u32; 3]]) -> Vec<Vec3> {
    let mut acc = vec![Vec3::ZERO; vertices.len()];
    for f in faces {
        let [a, b, c] = f.map(|i| i as usize);
        if a >= vertices.len() || b >= vertices.len() || c >= vertices.len() {
            continue;
        }
        // The cross product's length is twice the face area: area weighting for free.
        let n = (vertices[b] - vertices[a]).cross(vertices[c] - vertices[a]);
        acc[a] += n;
        acc[b] += n;
        acc[c] += n;
    }
    acc.into_iter()
        .map(|n| n.try_normalize().unwrap_or(Vec3::Z))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn part_weights_sum_per_group() {
        let mut w = [0.0f32; SMPL_JOINTS];
        w[16] = 0.3;
        w[18] = 0.3;
        w[9] = 0.4;
        let p = part_weights(&w);
        assert!((p[2] - 0.6).abs() < 1e-6);
        assert!((p[0] - 0.4).abs() < 1e-6);
        assert_eq!(dominant_part(&p), Part::LeftArm);
    }

    #[test]
    fn chain_coordinate_counts_segments() {
        let mut joints = [Vec3::ZERO; SMPL_JOINTS];
        for (k, &j) in LEFT_ARM.iter().enumerate() {
            joints[j] = Vec3::new(0.2 + 0.25 * k as f32, 0.3, 0.0);
        }
        // Halfway between elbow and wrist, 4 cm in front of the arm.
        let (s, arc, _, axis) = chain_coords(&joints, &LEFT_ARM, Vec3::new(0.575, 0.3, 0.04));
        assert!((s - 1.5).abs() < 1e-5, "s = {s}");
        assert!((arc - 0.375).abs() < 1e-5);
        assert!((axis - Vec3::X).length() < 1e-6);
        let front = angle_around(
            Vec3::new(0.575, 0.3, 0.04),
            Vec3::new(0.575, 0.3, 0.0),
            axis,
        );
        assert!(front.abs() < 1e-6);
    }

    #[test]
    fn normals_of_a_ccw_triangle_point_up() {
        let v = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let n = vertex_normals(&v, &[[0, 1, 2]]);
        assert!(n.iter().all(|n| (*n - Vec3::Z).length() < 1e-6));
    }
}
