//! One scene as the network sees it: N source views (camera, image, per-vertex visibility) and
//! the posed body, validated once and turned into the per-scene CPU geometry that every ray
//! batch reuses (SMPL frame, ray box, nearest-surface index, voxel box).

pub mod point_inputs;
pub mod source_masks;
pub mod visual_hull;

pub use point_inputs::{
    projection_grid, view_direction_feature, InputsFor, PointInputs, OUTSIDE_GRID,
    VIEW_DIR_FEATURE_DIM,
};
pub use source_masks::{masks_with_body, MaskError, SourceMasks};
pub use visual_hull::VisualHull;

use std::sync::Arc;

use glam::{Mat3, Vec3};

use crate::body::rodrigues;
use crate::dataset::loader::Scene;
use crate::geometry::camera::Camera;
use crate::geometry::rays::Aabb;
use crate::geometry::sparse::{SparseGridError, VoxelBox, VoxelGridSpec};
use crate::geometry::surface::SurfaceIndex;
use crate::geometry::surface_memo::shared_surface;

/// Rays are clipped to the world box of the posed body padded by this much (NHP pads by 5 cm
/// so loose clothing and hair stay inside).
pub const RAY_BOX_PADDING_M: f32 = 0.05;

/// Errors in a scene's inputs, naming the input and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("scene: {field}: expected {expected}, got {got}")]
    Invalid {
        field: String,
        expected: String,
        got: String,
    },
    #[error("scene: body mesh: {0}")]
    Mesh(#[from] crate::geometry::raster::MeshError),
    #[error("scene: {0}")]
    Grid(#[from] SparseGridError),
    #[error("scene: {0}")]
    Masks(#[from] MaskError),
}

fn invalid(
    field: impl Into<String>,
    expected: impl Into<String>,
    got: impl std::fmt::Debug,
) -> SceneError {
    SceneError::Invalid {
        field: field.into(),
        expected: expected.into(),
        got: format!("{got:?}"),
    }
}

/// One source view.
#[derive(Debug, Clone)]
pub struct SourceView {
    /// Undistorted pinhole camera at the image's resolution.
    pub camera: Camera,
    /// [3, H, W] RGB in [0, 1], black outside the person.
    pub image: Vec<f32>,
    /// [H * W] the person's mask in [0, 1] (read by the visual hull only).
    pub mask: Vec<f32>,
    /// [V] per-vertex visibility in this view (0 or 1).
    pub vertex_visibility: Vec<f32>,
}

/// The posed body of the scene.
#[derive(Debug, Clone)]
pub struct SceneBody {
    /// [V] world vertices, metres.
    pub vertices: Vec<Vec3>,
    /// [F] triangles.
    pub faces: Vec<[u32; 3]>,
    /// Global orientation (axis-angle) and translation: `world = R(Rh) x_smpl + Th`.
    pub rh: Vec3,
    pub th: Vec3,
}

/// Everything one scene provides.
#[derive(Debug, Clone)]
pub struct SceneInput {
    pub views: Vec<SourceView>,
    pub body: SceneBody,
}

impl SceneInput {
    /// The network's view of a loaded scene: planar source images, 0/1 visibility as floats,
    /// and the posed body with the model's `faces`.
    pub fn from_loaded(scene: &Scene, faces: &[[u32; 3]]) -> Self {
        let views = scene
            .sources
            .iter()
            .map(|s| {
                let (w, h) = (s.image.width() as usize, s.image.height() as usize);
                // [H * W * 3] interleaved -> [3, H, W] planar.
                let mut planar = vec![0.0f32; 3 * w * h];
                for (p, rgb) in s.image.image.chunks_exact(3).enumerate() {
                    for c in 0..3 {
                        planar[c * w * h + p] = rgb[c];
                    }
                }
                SourceView {
                    camera: s.image.camera,
                    image: planar,
                    mask: s.image.mask.iter().map(|&m| m as u8 as f32).collect(),
                    vertex_visibility: s.visibility.iter().map(|&v| v as f32).collect(),
                }
            })
            .collect();
        SceneInput {
            views,
            body: SceneBody {
                vertices: scene.vertices.clone(),
                faces: faces.to_vec(),
                rh: scene.params.rh,
                th: scene.params.th,
            },
        }
    }
}

/// World vertices ([V] metres) in the SMPL frame of `rh` (axis-angle) and `th` (metres):
/// `R(rh)^T (p - th)`, [V, 3]. The body volume's vertices; the loader's workers compute them
/// the same way to build a training scene's site pyramid ahead of its step.
pub fn vertices_in_smpl_frame(vertices: &[Vec3], rh: Vec3, th: Vec3) -> Vec<[f32; 3]> {
    let rt = rodrigues(rh).transpose();
    vertices
        .iter()
        .map(|&p| (rt * (p - th)).to_array())
        .collect()
}

/// Per-scene CPU geometry, built once and reused by every target view and ray chunk.
#[derive(Debug)]
pub struct SceneGeometry {
    /// [N] source cameras.
    pub cameras: Vec<Camera>,
    /// Source image size (H, W), equal for all views.
    pub image_hw: [usize; 2],
    /// R(Rh): `x_smpl = R^T (x_world - Th)`.
    pub smpl_rotation: Mat3,
    /// Th, metres.
    pub smpl_translation: Vec3,
    /// World box rays are clipped to.
    pub ray_box: Aabb,
    /// Nearest-surface index of the posed body (for o_n).
    pub surface: Arc<SurfaceIndex>,
    /// [N][V] per-vertex visibility.
    pub vertex_visibility: Vec<Vec<f32>>,
    /// [V] vertices in the SMPL frame.
    pub vertices_smpl: Vec<[f32; 3]>,
    /// [V] world vertices.
    pub vertices_world: Vec<Vec3>,
    /// [F] the body model's triangles (indices into the vertices).
    pub faces: Vec<[u32; 3]>,
    /// The voxel grid of the body volume (SMPL frame).
    pub voxel_box: VoxelBox,
}

impl SceneGeometry {
    /// Validates `input` and builds its geometry, with the body volume's voxel box made by
    /// `grid`.
    pub fn new(input: &SceneInput, grid: VoxelGridSpec) -> Result<Self, SceneError> {
        let n = input.views.len();
        if n == 0 {
            return Err(invalid("views", "at least one source view", 0));
        }
        let body = &input.body;
        let v = body.vertices.len();
        if v < 4 || body.faces.is_empty() {
            return Err(invalid(
                "body",
                "a mesh with at least 4 vertices and 1 face",
                (v, body.faces.len()),
            ));
        }
        if let Some(i) = body.vertices.iter().position(|p| !p.is_finite()) {
            return Err(invalid(
                format!("body.vertices[{i}]"),
                "finite coordinates",
                body.vertices[i],
            ));
        }
        if !body.rh.is_finite() || !body.th.is_finite() {
            return Err(invalid("body Rh/Th", "finite values", (body.rh, body.th)));
        }
        let (w0, h0) = (
            input.views[0].camera.width as usize,
            input.views[0].camera.height as usize,
        );
        for (i, view) in input.views.iter().enumerate() {
            let (w, h) = (view.camera.width as usize, view.camera.height as usize);
            if (w, h) != (w0, h0) || w == 0 || h == 0 {
                return Err(invalid(
                    format!("views[{i}].camera size"),
                    format!("{w0}x{h0} like view 0, non-empty"),
                    (w, h),
                ));
            }
            if view.image.len() != 3 * w * h {
                return Err(invalid(
                    format!("views[{i}].image"),
                    format!("[3, {h}, {w}] = {} values", 3 * w * h),
                    view.image.len(),
                ));
            }
            if view.image.iter().any(|x| !x.is_finite()) {
                return Err(invalid(
                    format!("views[{i}].image"),
                    "finite values",
                    "NaN or infinity",
                ));
            }
            if view.vertex_visibility.len() != v {
                return Err(invalid(
                    format!("views[{i}].vertex_visibility"),
                    format!("[{v}] (one per vertex)"),
                    view.vertex_visibility.len(),
                ));
            }
            if view.mask.len() != w * h {
                return Err(invalid(
                    format!("views[{i}].mask"),
                    format!("[{h} * {w}] = {} values", w * h),
                    view.mask.len(),
                ));
            }
            if view.mask.iter().any(|m| !(0.0..=1.0).contains(m)) {
                return Err(invalid(
                    format!("views[{i}].mask"),
                    "values in [0, 1]",
                    "a value outside [0, 1] or NaN",
                ));
            }
        }
        let smpl_rotation = rodrigues(body.rh);
        let vertices_smpl = vertices_in_smpl_frame(&body.vertices, body.rh, body.th);
        let world_box = Aabb::from_points(&body.vertices)
            .ok_or_else(|| invalid("body.vertices", "a non-empty point set", v))?;
        let voxel_box = grid.enclosing(&vertices_smpl)?;
        Ok(SceneGeometry {
            cameras: input.views.iter().map(|s| s.camera).collect(),
            image_hw: [h0, w0],
            smpl_rotation,
            smpl_translation: body.th,
            ray_box: world_box.padded(RAY_BOX_PADDING_M),
            surface: shared_surface(&body.vertices, &body.faces)?,
            vertex_visibility: input
                .views
                .iter()
                .map(|s| s.vertex_visibility.clone())
                .collect(),
            vertices_smpl,
            vertices_world: body.vertices.clone(),
            faces: body.faces.clone(),
            voxel_box,
        })
    }

    /// Number of source views N.
    pub fn num_views(&self) -> usize {
        self.cameras.len()
    }

    /// World point to the SMPL frame.
    pub fn to_smpl(&self, p: Vec3) -> [f32; 3] {
        (self.smpl_rotation.transpose() * (p - self.smpl_translation)).to_array()
    }
}
