//! The site pyramid of a body: the voxelised vertices, every level's active sites and
//! placement, and the rulebooks between them. The body volume's host geometry, a pure
//! function of the SMPL-frame vertices and the voxel box; [`shared_pyramid`] remembers the
//! most recent ones, so the loader's workers build a training scene's pyramid ahead of its step
//! (the rulebooks were 2-3 % of the quickstart's step, on the thread that trains).

use std::sync::Arc;

use glam::Vec3;

use super::rulebook::Rulebook;
use super::voxelize::{voxelize, ScaleGeometry, VoxelBox, Voxelization};
use super::SparseGridError;
use crate::geometry::mesh_memo::MeshMemo;

/// Pyramids the memo keeps (a few MB each at 1 cm voxels).
pub const MEMO_ENTRIES: usize = 8;

static MEMO: MeshMemo<SitePyramid> = MeshMemo::new(MEMO_ENTRIES);

/// The sparse grids of levels `0..=L` of one body.
#[derive(Debug, Clone)]
pub struct SitePyramid {
    /// The vertices in the level-0 grid.
    pub voxels: Voxelization,
    /// [L + 1] sites and placement of every level (level l: 1 / 2^l).
    pub levels: Vec<Arc<ScaleGeometry>>,
    /// [L + 1] submanifold rulebook of every level.
    pub submanifold_rules: Vec<Rulebook>,
    /// [L] strided rulebook from level l to level l + 1.
    pub strided_rules: Vec<Rulebook>,
}

impl SitePyramid {
    /// Voxelises `vertices_smpl` ([V, 3] metres, SMPL frame) in `voxel_box` and builds the
    /// sites and rulebooks of levels `0..=coarsest`.
    pub fn build(
        vertices_smpl: &[[f32; 3]],
        voxel_box: &VoxelBox,
        coarsest: usize,
    ) -> Result<Self, SparseGridError> {
        let voxels = voxelize(vertices_smpl, voxel_box)?;
        let mut levels = Vec::with_capacity(coarsest + 1);
        let mut submanifold_rules = Vec::with_capacity(coarsest + 1);
        let mut strided_rules = Vec::with_capacity(coarsest);
        let mut sites = voxels.sites.clone();
        for level in 0..=coarsest {
            if level > 0 {
                let (coarse, rules) = Rulebook::strided(&sites)?;
                strided_rules.push(rules);
                sites = coarse;
            }
            submanifold_rules.push(Rulebook::submanifold(&sites));
            levels.push(Arc::new(ScaleGeometry::new(
                voxel_box,
                level as u32,
                sites.clone(),
            )?));
        }
        Ok(SitePyramid {
            voxels,
            levels,
            submanifold_rules,
            strided_rules,
        })
    }
}

impl SitePyramid {
    /// Builds every rulebook's [`super::NeighbourMaps`] now (they are kept with the rulebooks
    /// and shared by the memo's copies), so that a training step on the CPU's host
    /// convolution finds them built ([`crate::dataset::loader::BodyVolumeGrid::neighbour_maps`]).
    pub fn warm_neighbour_maps(&self) {
        for rulebook in self.submanifold_rules.iter().chain(&self.strided_rules) {
            rulebook.neighbour_maps();
        }
    }
}

/// The memo's key: the vertices as points, the box and the depth as bits.
fn memo_key(
    vertices_smpl: &[[f32; 3]],
    voxel_box: &VoxelBox,
    coarsest: usize,
) -> (Vec<Vec3>, Vec<u32>) {
    let points = vertices_smpl.iter().map(|&p| Vec3::from_array(p)).collect();
    let mut settings: Vec<u32> = voxel_box.min_m.map(f32::to_bits).to_vec();
    settings.push(voxel_box.voxel_size_m.to_bits());
    settings.extend(voxel_box.dims.map(|d| d as u32));
    settings.push(coarsest as u32);
    (points, settings)
}

/// [`SitePyramid::build`], remembered: the pyramid built before for exactly these vertices,
/// this box and this depth ([`crate::geometry::mesh_memo`], compared bit for bit), else a new
/// one. Errors are [`SitePyramid::build`]'s (not remembered).
pub fn shared_pyramid(
    vertices_smpl: &[[f32; 3]],
    voxel_box: &VoxelBox,
    coarsest: usize,
) -> Result<Arc<SitePyramid>, SparseGridError> {
    let (points, settings) = memo_key(vertices_smpl, voxel_box, coarsest);
    MEMO.get_or_build(&points, &[], &settings, || {
        SitePyramid::build(vertices_smpl, voxel_box, coarsest)
    })
}

/// The pyramid [`shared_pyramid`] remembers for exactly these vertices, this box and this
/// depth, without building one (`None` when it holds none).
pub fn remembered_pyramid(
    vertices_smpl: &[[f32; 3]],
    voxel_box: &VoxelBox,
    coarsest: usize,
) -> Option<Arc<SitePyramid>> {
    let (points, settings) = memo_key(vertices_smpl, voxel_box, coarsest);
    MEMO.remembered(&points, &[], &settings)
}
