//! The loader's correction of a stored SMPL fit onto the scene's source masks
//! (`[data] smpl_alignment`, not in the paper; docs/robustness.md has what it measured): first
//! the body moved rigidly ([`align_to_masks`], [`Freedom::Rigid`]), then, when asked, its
//! joints bent ([`refine_pose`], [`Freedom::Joints`]), both minimising the silhouette energy of
//! [`super::silhouette`] with the one solver.
//!
//! A capture's SMPL fit is off the person by a centimetre or two of global placement, about a
//! degree of global rotation and a few degrees per joint (docs/data.md, "Capture flaws"), and
//! the network draws the body where the fit says. The robust scale is
//! [`SmplAlignment::robust_m`] at the body's depth, in each view's pixels. The rigid step stays
//! within [`SmplAlignment::max_translation_m`] and [`SmplAlignment::max_rotation_deg`]; the
//! refinement adds a prior that keeps every joint near the fit as given,
//! `sigma^2 sum_k |log(R_k R_k^fit^T)|^2 / s^2` (`s` = [`SmplAlignment::pose_prior_deg`],
//! `sigma^2` the views' mean robust scale squared: a joint turned by `s` costs as much as one
//! view's vertex term fully saturated), and keeps every joint within
//! [`SmplAlignment::max_joint_deg`] of the fit. A twist about a bone changes no silhouette: the
//! prior keeps it where the fit had it. The stored vertices' own offsets from the model's LBS
//! of the stored params are kept.
//!
//! Only the scene's source views are read, never its target: the correction is what a user
//! has at test time. Evaluation renders several target views from the same source views of a
//! frame: [`align_fit`]'s result is remembered per exact input (the fit's vertices and params,
//! each view's camera and mask, the settings, all compared bit for bit), so a scene's sources
//! are aligned once.

use std::sync::Arc;

use glam::Vec3;

use super::body::{centroid, BodyPoints, FrameState, Freedom, RigidMotion};
use super::config::SmplAlignment;
use super::priors::{joint_angles_deg, Priors};
use super::problem::{Bounds, FrameTerms, Problem};
use super::projection::Pixels;
use super::silhouette::{SilhouetteTarget, SilhouetteTerms, SilhouetteView};
use super::solver::levenberg_marquardt;
use super::FitError;
use crate::body::{BodyModel, SmplParams};
use crate::geometry::camera::Camera;
use crate::geometry::mesh_memo::MeshMemo;

/// Aligned fits remembered (each a few hundred kB at 512 px: the masks are part of the key).
const MEMO_ENTRIES: usize = 32;

static MEMO: MeshMemo<AlignedFit> = MeshMemo::new(MEMO_ENTRIES);

/// One source view as the alignment reads it.
#[derive(Debug, Clone, Copy)]
pub struct AlignmentView<'a> {
    /// Undistorted pinhole camera of the mask.
    pub camera: &'a Camera,
    /// `[H * W]` row-major, true on the person.
    pub mask: &'a [bool],
}

/// The rigid correction and what it did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidCorrection {
    pub motion: RigidMotion,
    /// The silhouette energy of the fit as given and after the correction (never larger).
    pub energy_before: f32,
    pub energy_after: f32,
    /// Source views that took part (a view with an empty mask does not).
    pub views_used: usize,
}

impl RigidCorrection {
    /// No motion about `centre`.
    pub fn identity(centre: Vec3) -> Self {
        RigidCorrection {
            motion: RigidMotion::identity(centre),
            energy_before: 0.0,
            energy_after: 0.0,
            views_used: 0,
        }
    }
}

/// What the pose refinement did (the refined fit itself is [`refine_pose`]'s vertices and
/// params).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseRefinement {
    /// The energy (module docs) of the fit as given and after the refinement (never larger).
    pub energy_before: f32,
    pub energy_after: f32,
    /// Mean and largest rotation of the 23 body joints away from the fit as given, degrees.
    pub mean_joint_deg: f32,
    pub max_joint_deg: f32,
    /// Accepted steps.
    pub steps: usize,
}

/// A fit moved onto the masks.
#[derive(Debug, Clone, PartialEq)]
pub struct AlignedFit {
    /// `[V]` world vertices, metres.
    pub vertices: Vec<Vec3>,
    pub params: SmplParams,
    pub rigid: RigidCorrection,
    /// `None` when `pose_iterations` is 0.
    pub pose: Option<PoseRefinement>,
}

/// The silhouette targets of `views` for a body about `centre`, and each view's robust scale
/// (`robust_m` at the body's depth, pixels squared). A view with an empty mask takes no part.
fn targets(
    views: &[AlignmentView<'_>],
    centre: Vec3,
    config: &SmplAlignment,
) -> Result<Vec<(usize, SilhouetteTarget, f32)>, FitError> {
    let mut out = Vec::with_capacity(views.len());
    for (n, view) in views.iter().enumerate() {
        let target = SilhouetteTarget::from_mask(
            view.mask,
            view.camera.width,
            view.camera.height,
            config.boundary_samples,
        )
        .map_err(|_| {
            let (w, h) = (view.camera.width, view.camera.height);
            FitError::invalid(
                format!("views[{n}].mask"),
                format!("[{h} * {w}] values (the camera's size, at least 2 x 2)"),
                view.mask.len(),
            )
        })?;
        let depth = view.camera.world_to_camera(centre).z;
        if !(depth > 0.0) {
            return Err(FitError::invalid(
                format!("views[{n}].camera"),
                "the body's centre in front of the camera",
                format!("depth {depth} m"),
            ));
        }
        if let Some(target) = target {
            let sigma = config.robust_m * view.camera.fx() / depth;
            out.push((n, target, sigma * sigma));
        }
    }
    Ok(out)
}

/// The silhouette terms over `targets` (from [`targets`]).
fn terms<'a>(
    views: &[AlignmentView<'a>],
    targets: &'a [(usize, SilhouetteTarget, f32)],
) -> SilhouetteTerms<'a> {
    SilhouetteTerms {
        views: targets
            .iter()
            .map(|(n, target, sigma2)| SilhouetteView {
                target,
                camera: views[*n].camera,
                pixels: Pixels::Pinhole,
                sigma2: *sigma2,
            })
            .collect(),
        weight_out: 1.0,
        weight_in: 1.0,
    }
}

fn check_points(vertices: &[Vec3], expected: Option<usize>) -> Result<(), FitError> {
    let ok = !vertices.is_empty()
        && expected.is_none_or(|n| vertices.len() == n)
        && vertices.iter().all(|v| v.is_finite());
    if ok {
        return Ok(());
    }
    let what = match expected {
        Some(n) => format!("{n} finite world points (the body model's vertices)"),
        None => "a non-empty set of finite world points".into(),
    };
    Err(FitError::invalid(
        "vertices",
        what,
        format!("{} vertices", vertices.len()),
    ))
}

/// The vertex sample a fit reads: every k-th so that at most `samples` remain.
fn sample(count: usize, samples: usize) -> Vec<usize> {
    let stride = count.div_ceil(samples.max(1)).max(1);
    (0..count).step_by(stride).collect()
}

/// The rigid correction of `vertices` ([V] world metres) that best fits the masks of `views`
/// (module docs). A view with an empty mask takes no part; with none left the correction is
/// the identity (`views_used` 0). Errors name a mask of the wrong size or a body behind a
/// camera.
pub fn align_to_masks(
    vertices: &[Vec3],
    views: &[AlignmentView<'_>],
    config: &SmplAlignment,
) -> Result<RigidCorrection, FitError> {
    config.validate()?;
    check_points(vertices, None)?;
    let centre = centroid(vertices);
    let targets = targets(views, centre, config)?;
    if targets.is_empty() {
        return Ok(RigidCorrection::identity(centre));
    }
    let points: Vec<Vec3> = sample(vertices.len(), config.vertex_samples)
        .into_iter()
        .map(|i| vertices[i])
        .collect();
    let body = BodyPoints::rigid_points(points);
    let pivot = body.pose(&FrameState {
        params: SmplParams::default(),
        rigid: RigidMotion::identity(Vec3::ZERO),
    });
    let start = vec![FrameState {
        params: SmplParams::default(),
        rigid: RigidMotion::identity(pivot.centre),
    }];
    let problem = Problem {
        freedom: Freedom::Rigid,
        frames: vec![FrameTerms {
            body,
            silhouettes: terms(views, &targets),
            keypoints: None,
            priors: Priors::default(),
        }],
        shape_prior: 0.0,
        bounds: None,
    }
    .bounded(
        &start,
        Bounds {
            max_translation_m: config.max_translation_m,
            max_rotation_rad: config.max_rotation_deg.to_radians(),
            max_joint_rad: 0.0,
        },
    );
    let solution = levenberg_marquardt(&problem, start, config.iterations);
    // The motion about the sample's centroid, re-expressed about the vertices' (the same map).
    let m = solution.state[0].rigid;
    let motion = RigidMotion {
        rotation: m.rotation,
        centre,
        translation: m.apply_point(centre) - centre,
    };
    Ok(RigidCorrection {
        motion,
        energy_before: solution.energy_before,
        energy_after: solution.energy,
        views_used: targets.len(),
    })
}

/// Refines the pose of the fit `vertices` ([V] world metres, the model's vertex order) with
/// parameters `params` onto the masks of `views` (module docs): the refined vertices, the
/// refined parameters (shape untouched) and what was done. A view with an empty mask takes no
/// part; with none left the fit is returned as it is (`steps` 0). Errors name a vertex count
/// that is not the model's, a mask of the wrong size or a body behind a camera.
pub fn refine_pose(
    model: &BodyModel,
    vertices: &[Vec3],
    params: &SmplParams,
    views: &[AlignmentView<'_>],
    config: &SmplAlignment,
) -> Result<(Vec<Vec3>, SmplParams, PoseRefinement), FitError> {
    config.validate()?;
    check_points(vertices, Some(model.v_template.len()))?;
    let finite = params
        .poses
        .iter()
        .chain(&params.shapes)
        .all(|x| x.is_finite())
        && params.rh.is_finite()
        && params.th.is_finite();
    if !finite {
        return Err(FitError::invalid(
            "params",
            "finite poses, shapes, Rh and Th",
            "a NaN or infinite value",
        ));
    }
    let unchanged = PoseRefinement {
        energy_before: 0.0,
        energy_after: 0.0,
        mean_joint_deg: 0.0,
        max_joint_deg: 0.0,
        steps: 0,
    };
    if config.pose_iterations == 0 {
        return Ok((vertices.to_vec(), params.clone(), unchanged));
    }
    let indices = sample(vertices.len(), config.vertex_samples);
    let body = BodyPoints::with_model(model, &indices, &[], params, Some(vertices));
    let start = vec![FrameState {
        params: params.clone(),
        rigid: RigidMotion::identity(Vec3::ZERO),
    }];
    let targets = targets(views, body.pose(&start[0]).centre, config)?;
    if targets.is_empty() {
        return Ok((vertices.to_vec(), params.clone(), unchanged));
    }
    let silhouettes = terms(views, &targets);
    let s = config.pose_prior_deg.to_radians();
    let prior = silhouettes.mean_sigma2() / (s * s);
    let problem = Problem {
        freedom: Freedom::Joints,
        frames: vec![FrameTerms {
            body,
            silhouettes,
            keypoints: None,
            priors: Priors {
                pose: Some((params.clone(), prior)),
                ..Priors::default()
            },
        }],
        shape_prior: 0.0,
        bounds: None,
    }
    .bounded(
        &start,
        Bounds {
            max_translation_m: config.max_translation_m,
            max_rotation_rad: config.max_rotation_deg.to_radians(),
            max_joint_rad: config.max_joint_deg.to_radians(),
        },
    );
    let solution = levenberg_marquardt(&problem, start, config.pose_iterations);
    let refined = solution.state[0].params.clone();
    let offsets_kept: Vec<Vec3> = {
        let stored = model.lbs(params);
        let posed = model.lbs(&refined);
        vertices
            .iter()
            .zip(stored.vertices.iter().zip(&posed.vertices))
            .map(|(v, (s, p))| *p + (*v - *s))
            .collect()
    };
    let (max_joint_deg, mean_joint_deg) = joint_angles_deg(&refined, params);
    Ok((
        offsets_kept,
        refined,
        PoseRefinement {
            energy_before: solution.energy_before,
            energy_after: solution.energy,
            mean_joint_deg,
            max_joint_deg,
            steps: solution.steps,
        },
    ))
}

/// Everything but the vertices that the result depends on, as `u32` words: the settings, the
/// params, each view's camera and its mask (packed 32 pixels a word).
fn key(params: &SmplParams, views: &[AlignmentView<'_>], config: &SmplAlignment) -> Vec<u32> {
    let mut key: Vec<u32> = [
        config.iterations as u32,
        config.robust_m.to_bits(),
        config.max_translation_m.to_bits(),
        config.max_rotation_deg.to_bits(),
        config.boundary_samples as u32,
        config.vertex_samples as u32,
        config.pose_iterations as u32,
        config.pose_prior_deg.to_bits(),
        config.max_joint_deg.to_bits(),
    ]
    .to_vec();
    key.extend(params.poses.iter().map(|x| x.to_bits()));
    key.push(params.shapes.len() as u32);
    key.extend(params.shapes.iter().map(|x| x.to_bits()));
    key.extend(params.rh.to_array().map(f32::to_bits));
    key.extend(params.th.to_array().map(f32::to_bits));
    for view in views {
        let c = view.camera;
        key.extend([c.width, c.height, view.mask.len() as u32]);
        key.extend(c.k.to_cols_array().map(f32::to_bits));
        key.extend(c.r.to_cols_array().map(f32::to_bits));
        key.extend(c.t.to_array().map(f32::to_bits));
        key.extend(c.dist.map(f32::to_bits));
        key.extend(view.mask.chunks(32).map(|bits| {
            bits.iter()
                .enumerate()
                .fold(0u32, |word, (i, &on)| word | (u32::from(on) << i))
        }));
    }
    key
}

/// The fit `vertices` ([V] world metres) with `params`, moved onto the masks of `views` by
/// `config` (`model`: the body model, needed when `config.pose_iterations > 0`; without it
/// that is an error naming `pose_iterations`). Remembered per exact input (module docs).
pub fn align_fit(
    vertices: &[Vec3],
    params: &SmplParams,
    model: Option<&BodyModel>,
    views: &[AlignmentView<'_>],
    config: &SmplAlignment,
) -> Result<Arc<AlignedFit>, FitError> {
    let model = match (model, config.pose_iterations) {
        (_, 0) => None,
        (Some(model), _) => Some(model),
        (None, n) => return Err(FitError::no_body_model(n.to_string())),
    };
    let settings = key(params, views, config);
    MEMO.get_or_build(vertices, &[], &settings, || {
        let rigid = align_to_masks(vertices, views, config)?;
        let mut moved = vertices.to_vec();
        let mut params = params.clone();
        rigid.motion.apply(&mut moved, &mut params);
        let pose = match model {
            Some(model) => {
                let (refined, refined_params, pose) =
                    refine_pose(model, &moved, &params, views, config)?;
                moved = refined;
                params = refined_params;
                Some(pose)
            }
            None => None,
        };
        Ok(AlignedFit {
            vertices: moved,
            params,
            rigid,
            pose,
        })
    })
}
