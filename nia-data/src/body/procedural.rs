//! A procedural SMPL-compatible body: SMPL's 24-joint skeleton (names, order, parents), a
//! closed, outward-oriented triangle mesh of a human in SMPL's rest T-pose, smooth skinning
//! weights, a joint regressor that reproduces the skeleton, and 10 shape components.
//!
//! The surface is an implicit body (a smooth union of tapered capsules and ellipsoids along the
//! bones, [`implicit`]) polygonised by marching tetrahedra ([`polygonise`]), reduced by edge
//! collapses and relaxed onto the surface ([`simplify`]). Everything is a pure function of the
//! [`ProceduralSpec`]: no random state.
//!
//! Coordinates follow SMPL: metres, y up, facing +z, the body's left at +x, pelvis near the
//! origin. Pose blend shapes (`posedirs`) are all zero: the body deforms by skinning alone.

pub mod implicit;
pub mod polygonise;
pub mod rig;
pub mod simplify;

use glam::Vec3;

pub use super::motion::{pose_for_motion, MotionKind};

use super::error::BodyError;
use super::smpl::{BodyModel, NUM_JOINTS, NUM_POSE_FEATURES};
use implicit::{ImplicitBody, Primitive};
use polygonise::{marching_tetrahedra, Grid};

/// Standing height (sole to top of head) of the reference design below, metres.
const REFERENCE_HEIGHT_M: f32 = 1.705;

/// Grid samples kept outside the body's bounds on every side, so the grid border is outside.
const GRID_MARGIN_STEPS: f32 = 2.0;

/// At most this many grid samples (about 2 GB of f32 values) before the spec is refused.
const MAX_GRID_SAMPLES: usize = 500_000_000;

/// Rest joints of the reference design (SMPL order, T-pose), metres.
const REFERENCE_JOINTS: [[f32; 3]; NUM_JOINTS] = [
    [0.000, -0.225, 0.020],   // pelvis
    [0.080, -0.310, 0.010],   // L_hip
    [-0.080, -0.310, 0.010],  // R_hip
    [0.000, -0.110, 0.000],   // spine1
    [0.105, -0.690, 0.010],   // L_knee
    [-0.105, -0.690, 0.010],  // R_knee
    [0.000, 0.030, 0.005],    // spine2
    [0.100, -1.080, -0.030],  // L_ankle
    [-0.100, -1.080, -0.030], // R_ankle
    [0.000, 0.090, 0.020],    // spine3
    [0.115, -1.140, 0.090],   // L_foot
    [-0.115, -1.140, 0.090],  // R_foot
    [0.000, 0.290, -0.010],   // neck
    [0.075, 0.200, 0.000],    // L_collar
    [-0.075, 0.200, 0.000],   // R_collar
    [0.000, 0.360, 0.040],    // head
    [0.175, 0.230, -0.015],   // L_shoulder
    [-0.175, 0.230, -0.015],  // R_shoulder
    [0.430, 0.220, -0.030],   // L_elbow
    [-0.430, 0.220, -0.030],  // R_elbow
    [0.680, 0.225, -0.030],   // L_wrist
    [-0.680, 0.225, -0.030],  // R_wrist
    [0.770, 0.220, -0.040],   // L_hand
    [-0.770, 0.220, -0.040],  // R_hand
];

/// A part of the reference design: `(primitive, blend width)`, metres; `mirror` adds the
/// right-hand copy (x -> -x) of a left-side part.
struct Part {
    primitive: Primitive,
    blend: f32,
    mirror: bool,
}

fn cone(a: [f32; 3], b: [f32; 3], ra: f32, rb: f32, blend: f32, mirror: bool) -> Part {
    Part {
        primitive: Primitive::RoundCone {
            a: Vec3::from(a),
            b: Vec3::from(b),
            ra,
            rb,
        },
        blend,
        mirror,
    }
}

fn ellipsoid(centre: [f32; 3], radii: [f32; 3], blend: f32, mirror: bool) -> Part {
    Part {
        primitive: Primitive::Ellipsoid {
            centre: Vec3::from(centre),
            radii: Vec3::from(radii),
        },
        blend,
        mirror,
    }
}

/// The reference design's parts (torso first, then limbs; left side, mirrored).
fn reference_parts() -> Vec<Part> {
    vec![
        // Torso, neck and head: wide blends give a smooth waist and shoulders.
        ellipsoid([0.0, -0.25, 0.0], [0.155, 0.115, 0.100], 0.0, false),
        ellipsoid([0.0, -0.09, 0.012], [0.140, 0.140, 0.100], 0.08, false),
        ellipsoid([0.0, 0.10, 0.0], [0.155, 0.155, 0.105], 0.08, false),
        cone(
            [0.0, 0.20, -0.01],
            [0.17, 0.225, -0.02],
            0.070,
            0.055,
            0.05,
            true,
        ),
        cone(
            [0.0, 0.22, -0.01],
            [0.0, 0.36, 0.015],
            0.058,
            0.050,
            0.04,
            false,
        ),
        ellipsoid([0.0, 0.43, 0.03], [0.078, 0.105, 0.095], 0.04, false),
        // Legs.
        cone(
            [0.09, -0.27, 0.005],
            [0.105, -0.69, 0.01],
            0.080,
            0.052,
            0.05,
            true,
        ),
        cone(
            [0.105, -0.69, 0.01],
            [0.10, -1.07, -0.03],
            0.050,
            0.036,
            0.03,
            true,
        ),
        ellipsoid([0.103, -0.82, -0.025], [0.048, 0.110, 0.050], 0.03, true),
        cone(
            [0.10, -1.125, -0.045],
            [0.12, -1.14, 0.14],
            0.045,
            0.030,
            0.03,
            true,
        ),
        // Arms.
        cone(
            [0.17, 0.23, -0.015],
            [0.43, 0.22, -0.03],
            0.050,
            0.040,
            0.03,
            true,
        ),
        cone(
            [0.43, 0.22, -0.03],
            [0.68, 0.225, -0.03],
            0.040,
            0.028,
            0.02,
            true,
        ),
        ellipsoid([0.775, 0.222, -0.035], [0.090, 0.022, 0.045], 0.02, true),
    ]
}

/// Parameters of a procedural body. The result is a pure function of these values.
#[derive(Debug, Clone, PartialEq)]
pub struct ProceduralSpec {
    /// Standing height of the template, sole to top of head, metres.
    pub height_m: f32,
    /// Thickness of every body part relative to the reference build (1 = average).
    pub girth: f32,
    /// Spacing of the grid the implicit surface is polygonised on, metres. Smaller is more
    /// faithful and slower (time grows with the inverse cube).
    pub grid_step_m: f32,
    /// Vertex budget of the final mesh (edges are collapsed down to it).
    pub target_vertices: usize,
    /// Passes of tangential relaxation after simplification (evens out the triangles).
    pub relax_iterations: usize,
}

impl Default for ProceduralSpec {
    /// A 1.70 m average build with 6000 vertices (SMPL has 6890).
    fn default() -> Self {
        Self {
            height_m: 1.70,
            girth: 1.0,
            grid_step_m: 0.015,
            target_vertices: 6000,
            relax_iterations: 3,
        }
    }
}

/// The design of a procedural body (skeleton and implicit surface), from which
/// [`ProceduralBody::build`] makes a [`BodyModel`].
#[derive(Debug, Clone, PartialEq)]
pub struct ProceduralBody {
    pub spec: ProceduralSpec,
    /// `[24]` designed rest joints (T-pose), metres; `J_regressor . v_template` reproduces them.
    pub joints: [Vec3; NUM_JOINTS],
    /// The implicit surface the mesh is extracted from.
    pub implicit: ImplicitBody,
}

impl ProceduralBody {
    /// Design the body of `spec` (checks the spec; no meshing yet).
    pub fn new(spec: &ProceduralSpec) -> Result<Self, BodyError> {
        let bad = |field: &str, expected: &str, found: String| BodyError::Spec {
            field: field.into(),
            expected: expected.into(),
            found,
        };
        if !(spec.height_m.is_finite() && (0.3..=3.0).contains(&spec.height_m)) {
            return Err(bad(
                "height_m",
                "a height in 0.3..=3.0 metres",
                spec.height_m.to_string(),
            ));
        }
        if !(spec.girth.is_finite() && (0.6..=1.6).contains(&spec.girth)) {
            return Err(bad(
                "girth",
                "a thickness factor in 0.6..=1.6 (thinner parts would merge or vanish)",
                spec.girth.to_string(),
            ));
        }
        let scale = spec.height_m / REFERENCE_HEIGHT_M;
        // The thinnest part (the hand, 4.4 cm thick at 1.70 m) needs two grid steps across.
        let max_step = 0.022 * scale * spec.girth;
        if !(spec.grid_step_m.is_finite() && spec.grid_step_m > 0.0 && spec.grid_step_m <= max_step)
        {
            return Err(bad(
                "grid_step_m",
                &format!("a grid spacing in (0, {max_step:.4}] metres for this height and girth"),
                spec.grid_step_m.to_string(),
            ));
        }
        if spec.target_vertices < 100 {
            return Err(bad(
                "target_vertices",
                "at least 100 vertices",
                spec.target_vertices.to_string(),
            ));
        }
        let joints = REFERENCE_JOINTS.map(|j| Vec3::from(j) * scale);
        let mut parts = Vec::new();
        for part in reference_parts() {
            let scaled = scale_primitive(part.primitive, scale, spec.girth);
            parts.push((scaled, part.blend * scale));
            if part.mirror {
                parts.push((mirror_x(scaled), part.blend * scale));
            }
        }
        let body = ProceduralBody {
            spec: spec.clone(),
            joints,
            implicit: ImplicitBody { parts },
        };
        let dims = body.grid().dims;
        if dims.iter().product::<usize>() > MAX_GRID_SAMPLES {
            return Err(bad(
                "grid_step_m",
                &format!("at most {MAX_GRID_SAMPLES} grid samples"),
                format!("{dims:?} samples for step {}", spec.grid_step_m),
            ));
        }
        Ok(body)
    }

    /// Design and build in one step.
    pub fn generate(spec: &ProceduralSpec) -> Result<BodyModel, BodyError> {
        Self::new(spec)?.build()
    }

    /// The sampling grid: the parts' bounds plus a margin, centred on x = 0 so the samples are
    /// mirror-symmetric.
    fn grid(&self) -> Grid {
        let step = self.spec.grid_step_m;
        let (lo, hi) = self.implicit.bounds();
        let margin = Vec3::splat(GRID_MARGIN_STEPS * step);
        let (lo, hi) = (lo - margin, hi + margin);
        let half_x = lo.x.abs().max(hi.x.abs());
        let count = |extent: f32| (extent / step).ceil() as usize + 1;
        let nx = 2 * count(half_x) - 1;
        Grid {
            origin: Vec3::new(-(count(half_x) as f32 - 1.0) * step, lo.y, lo.z),
            step,
            dims: [nx, count(hi.y - lo.y), count(hi.z - lo.z)],
        }
    }

    /// The template mesh `(vertices [V], faces [F])`: closed, 2-manifold, genus 0, faces
    /// counter-clockwise seen from outside.
    pub fn mesh(&self) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let grid = self.grid();
        let values = grid.sample_band(|p| self.implicit.distance(p));
        let (vertices, faces) = marching_tetrahedra(&grid, &values);
        let (mut vertices, faces) =
            simplify::collapse_short_edges(vertices, faces, self.spec.target_vertices);
        let max_step = self.spec.grid_step_m;
        let project = |p: Vec3| self.implicit.project(p, max_step);
        for p in vertices.iter_mut() {
            *p = project(*p);
        }
        simplify::relax(&mut vertices, &faces, self.spec.relax_iterations, project);
        (vertices, faces)
    }

    /// Mesh and rig the body: skinning weights, joint regressor, shape blend shapes
    /// ([`rig::BETA_NAMES`]), zero pose blend shapes.
    pub fn build(&self) -> Result<BodyModel, BodyError> {
        let (vertices, faces) = self.mesh();
        let weights = rig::skinning_weights(&vertices, &self.joints, self.spec.height_m);
        let j_regressor =
            rig::joint_regressor(&vertices, &self.joints).ok_or_else(|| BodyError::Spec {
                field: "grid_step_m".into(),
                expected: "a mesh that surrounds every joint (finer grid or more vertices)".into(),
                found: format!("{} vertices", vertices.len()),
            })?;
        let shapedirs = rig::shape_blend_shapes(&vertices, &weights, &self.joints);
        let posedirs = vec![0.0; vertices.len() * 3 * NUM_POSE_FEATURES];
        BodyModel::new(
            vertices,
            shapedirs,
            posedirs,
            j_regressor,
            weights,
            super::smpl::SMPL_PARENTS.to_vec(),
            faces,
        )
    }
}

fn scale_primitive(p: Primitive, scale: f32, girth: f32) -> Primitive {
    match p {
        Primitive::RoundCone { a, b, ra, rb } => Primitive::RoundCone {
            a: a * scale,
            b: b * scale,
            ra: ra * scale * girth,
            rb: rb * scale * girth,
        },
        Primitive::Ellipsoid { centre, radii } => Primitive::Ellipsoid {
            centre: centre * scale,
            // Girth thickens across the body (x, z); height comes from `scale` alone.
            radii: radii * scale * Vec3::new(girth, 1.0, girth),
        },
    }
}

fn mirror_x(p: Primitive) -> Primitive {
    let m = |v: Vec3| Vec3::new(-v.x, v.y, v.z);
    match p {
        Primitive::RoundCone { a, b, ra, rb } => Primitive::RoundCone {
            a: m(a),
            b: m(b),
            ra,
            rb,
        },
        Primitive::Ellipsoid { centre, radii } => Primitive::Ellipsoid {
            centre: m(centre),
            radii,
        },
    }
}
