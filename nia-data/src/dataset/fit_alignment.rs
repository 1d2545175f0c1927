//! The stored SMPL fit moved onto the source masks as the loader does it: the rigid alignment
//! ([`super::smpl_alignment`]), then, when asked, the pose refinement
//! ([`super::smpl_pose_refinement`]). Evaluation renders several target views from the same
//! source views of a frame: the result is remembered per exact input (the fit's vertices and
//! params, each view's camera and mask, the settings, all compared bit for bit), so a scene's
//! sources are aligned once.

use std::sync::Arc;

use glam::Vec3;

use crate::body::{BodyModel, SmplParams};
use crate::dataset::smpl_alignment::{
    align_to_masks, AlignmentError, AlignmentView, RigidCorrection, SmplAlignment,
};
use crate::dataset::smpl_pose_refinement::{refine_pose, PoseRefinement};
use crate::geometry::mesh_memo::MeshMemo;

/// Aligned fits remembered (each a few hundred kB at 512 px: the masks are part of the key).
const MEMO_ENTRIES: usize = 32;

static MEMO: MeshMemo<AlignedFit> = MeshMemo::new(MEMO_ENTRIES);

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
) -> Result<Arc<AlignedFit>, AlignmentError> {
    let model = match (model, config.pose_iterations) {
        (_, 0) => None,
        (Some(model), _) => Some(model),
        (None, n) => return Err(AlignmentError::no_body_model(n.to_string())),
    };
    let settings = key(params, views, config);
    MEMO.get_or_build(vertices, &[], &settings, || {
        let rigid = align_to_masks(vertices, views, config)?;
        let mut moved = vertices.to_vec();
        let mut params = params.clone();
        rigid.apply(&mut moved, &mut params);
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
