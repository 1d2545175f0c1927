//! Voxel grids in SMPL coordinates: the body box, the grid levels the sparse convolution
//! produces, and the voxelisation of the SMPL vertices into active sites.
//!
//! Convention (one for every level): voxel `i` (integer, per axis) of level 0 covers
//! `[min + i s, min + (i + 1) s)` and its value sits at its centre `min + (i + 0.5) s`.
//! A stride-2, kernel-3, padding-1 convolution (spconv `SparseConv3d(.., 3, 2, padding=1)`)
//! centres coarse voxel `o` on fine voxel `2 o`, so the site `o` of level `l` sits at
//! `origin + o * 2^l s` with the same `origin = min + 0.5 s` on every level, and level `l + 1`
//! has `floor((D_l - 1) / 2) + 1` voxels along an axis of `D_l`.

use super::rulebook::SiteIndex;
use super::SparseGridError;

/// The voxel size of the paper (5 mm), metres.
pub const PAPER_VOXEL_SIZE_M: f32 = 0.005;

/// The paper's box enlargement: the SMPL bounds grown by 2.5% (each extent times 1.025, about
/// the centre of the bounds).
pub const PAPER_BOX_ENLARGE: f32 = 0.025;

/// Largest number of voxels along one axis (coordinates are packed in 21 bits per axis).
pub const MAX_GRID_DIM: usize = 1 << 20;

/// How the body volume's voxel box is made around a body: the voxel edge and the growth of
/// the SMPL bounds (the paper: 5 mm, 2.5 %).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VoxelGridSpec {
    /// Voxel edge, metres.
    pub voxel_size_m: f32,
    /// The SMPL bounds are grown by this fraction of their extent.
    pub box_enlarge: f32,
}

impl VoxelGridSpec {
    /// The paper's grid: [`PAPER_VOXEL_SIZE_M`], [`PAPER_BOX_ENLARGE`].
    pub fn paper() -> Self {
        VoxelGridSpec {
            voxel_size_m: PAPER_VOXEL_SIZE_M,
            box_enlarge: PAPER_BOX_ENLARGE,
        }
    }

    /// [`VoxelBox::enclosing`] `vertices` ([V, 3] metres, SMPL frame) with this spec.
    pub fn enclosing(&self, vertices: &[[f32; 3]]) -> Result<VoxelBox, SparseGridError> {
        VoxelBox::enclosing(vertices, self.box_enlarge, self.voxel_size_m)
    }
}

/// An axis-aligned voxel grid in SMPL coordinates (level 0, the finest).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelBox {
    /// [3] metres, the min corner of voxel (0, 0, 0).
    pub min_m: [f32; 3],
    /// Edge of one voxel, metres.
    pub voxel_size_m: f32,
    /// [3] voxels along x, y, z.
    pub dims: [usize; 3],
}

/// A voxel edge length must be finite and positive; `field` names it in the error.
fn check_voxel_size(field: &'static str, voxel_size_m: f32) -> Result<(), SparseGridError> {
    if voxel_size_m.is_finite() && voxel_size_m > 0.0 {
        Ok(())
    } else {
        Err(SparseGridError::invalid(
            field,
            "a finite size > 0 (metres)",
            voxel_size_m,
        ))
    }
}

impl VoxelBox {
    /// A grid with the given corner, voxel size and size, validated.
    pub fn new(
        min_m: [f32; 3],
        voxel_size_m: f32,
        dims: [usize; 3],
    ) -> Result<Self, SparseGridError> {
        if !min_m.iter().all(|v| v.is_finite()) {
            return Err(SparseGridError::invalid(
                "VoxelBox.min_m",
                "finite coordinates",
                min_m,
            ));
        }
        check_voxel_size("VoxelBox.voxel_size_m", voxel_size_m)?;
        if dims.iter().any(|&d| d == 0 || d > MAX_GRID_DIM) {
            return Err(SparseGridError::invalid(
                "VoxelBox.dims",
                format!("between 1 and {MAX_GRID_DIM} voxels per axis"),
                dims,
            ));
        }
        Ok(VoxelBox {
            min_m,
            voxel_size_m,
            dims,
        })
    }

    /// The box of the paper around SMPL-frame vertices: their bounds, each extent grown by the
    /// factor `1 + enlarge` about the centre of the bounds, cut into voxels of `voxel_size_m`
    /// (the last voxel of an axis may reach a little past the grown bound).
    ///
    /// `vertices`: [V, 3] metres, SMPL frame. Use [`PAPER_BOX_ENLARGE`] and
    /// [`PAPER_VOXEL_SIZE_M`] for the paper setting.
    pub fn enclosing(
        vertices: &[[f32; 3]],
        enlarge: f32,
        voxel_size_m: f32,
    ) -> Result<Self, SparseGridError> {
        let (lo, hi) = bounds(vertices)?;
        if !(enlarge.is_finite() && enlarge >= 0.0) {
            return Err(SparseGridError::invalid(
                "VoxelBox::enclosing enlarge",
                "a finite fraction >= 0",
                enlarge,
            ));
        }
        check_voxel_size("VoxelBox::enclosing voxel_size_m", voxel_size_m)?;
        let mut min_m = [0.0f32; 3];
        let mut dims = [0usize; 3];
        for a in 0..3 {
            let extent = hi[a] - lo[a];
            let grown = extent * (1.0 + enlarge);
            min_m[a] = lo[a] - 0.5 * (grown - extent);
            let n = (grown / voxel_size_m).ceil();
            if !(n.is_finite() && n <= MAX_GRID_DIM as f32) {
                return Err(SparseGridError::invalid(
                    "VoxelBox::enclosing voxel_size_m",
                    format!("a size giving at most {MAX_GRID_DIM} voxels per axis"),
                    voxel_size_m,
                ));
            }
            dims[a] = (n as usize).max(1);
        }
        VoxelBox::new(min_m, voxel_size_m, dims)
    }

    /// [3] metres, the max corner of the last voxel.
    pub fn max_m(&self) -> [f32; 3] {
        std::array::from_fn(|a| self.min_m[a] + self.dims[a] as f32 * self.voxel_size_m)
    }

    /// Whether `p` (metres, SMPL frame) lies in the closed box `[min_m, max_m]`.
    pub fn contains(&self, p: [f32; 3]) -> bool {
        let max = self.max_m();
        (0..3).all(|a| p[a] >= self.min_m[a] && p[a] <= max[a])
    }

    /// The voxel containing `p`, or `None` outside the box (or for a non-finite `p`). Points on
    /// the max face belong to the last voxel.
    pub fn voxel_of(&self, p: [f32; 3]) -> Option<[i32; 3]> {
        if !self.contains(p) {
            return None;
        }
        let mut c = [0i32; 3];
        for a in 0..3 {
            let u = ((p[a] - self.min_m[a]) / self.voxel_size_m).floor();
            c[a] = (u.max(0.0) as i64).min(self.dims[a] as i64 - 1) as i32;
        }
        Some(c)
    }

    /// The geometry of grid level `level` (0 = this grid; each level halves the resolution
    /// like a stride-2 padding-1 convolution), without its active sites.
    pub fn level_placement(&self, level: u32) -> ([f32; 3], f32, [usize; 3]) {
        let origin = std::array::from_fn(|a| self.min_m[a] + 0.5 * self.voxel_size_m);
        let mut dims = self.dims;
        for _ in 0..level {
            dims = dims.map(strided_dim);
        }
        let size = self.voxel_size_m * (1u64 << level) as f32;
        (origin, size, dims)
    }
}

/// Voxels along an axis after a stride-2, kernel-3, padding-1 convolution:
/// `floor((d + 2 - 3) / 2) + 1`.
pub fn strided_dim(d: usize) -> usize {
    (d.saturating_sub(1)) / 2 + 1
}

/// [3], [3] metres: the min and max of the vertices, checked finite and non-empty.
fn bounds(vertices: &[[f32; 3]]) -> Result<([f32; 3], [f32; 3]), SparseGridError> {
    if vertices.is_empty() {
        return Err(SparseGridError::invalid(
            "vertices",
            "at least one vertex [V >= 1, 3]",
            "V = 0",
        ));
    }
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for (i, v) in vertices.iter().enumerate() {
        if !v.iter().all(|x| x.is_finite()) {
            return Err(SparseGridError::invalid(
                "vertices",
                format!("finite coordinates (vertex {i})"),
                v,
            ));
        }
        for a in 0..3 {
            lo[a] = lo[a].min(v[a]);
            hi[a] = hi[a].max(v[a]);
        }
    }
    Ok((lo, hi))
}

/// The vertices of one frame placed in the level-0 grid.
#[derive(Debug, Clone)]
pub struct Voxelization {
    /// [V, 3] integer voxel coordinates of every vertex.
    pub vertex_voxel: Vec<[i32; 3]>,
    /// [V] the active site (index into `sites`) holding every vertex.
    pub vertex_site: Vec<u32>,
    /// The P active sites (voxels holding at least one vertex), sorted by linear index
    /// `(x * D_y + y) * D_z + z`.
    pub sites: SiteIndex,
    /// [P] number of vertices in every site (>= 1).
    pub site_vertex_count: Vec<u32>,
}

/// Voxelises SMPL-frame vertices ([V, 3] metres) into `voxel_box`. Every vertex must lie in the
/// box (build the box with [`VoxelBox::enclosing`] from the same vertices, or larger).
pub fn voxelize(
    vertices: &[[f32; 3]],
    voxel_box: &VoxelBox,
) -> Result<Voxelization, SparseGridError> {
    bounds(vertices)?;
    let mut vertex_voxel = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        match voxel_box.voxel_of(*v) {
            Some(c) => vertex_voxel.push(c),
            None => {
                return Err(SparseGridError::invalid(
                    "vertices",
                    format!(
                        "every vertex inside the voxel box {:?}..{:?} (vertex {i})",
                        voxel_box.min_m,
                        voxel_box.max_m()
                    ),
                    v,
                ))
            }
        }
    }
    let mut coords = vertex_voxel.clone();
    coords.sort_unstable();
    coords.dedup();
    let sites = SiteIndex::new(voxel_box.dims, coords)?;
    let mut vertex_site = Vec::with_capacity(vertices.len());
    let mut site_vertex_count = vec![0u32; sites.len()];
    for c in &vertex_voxel {
        // Every vertex voxel is a site by construction.
        let s = sites.get(*c).ok_or_else(|| {
            SparseGridError::invalid("vertices", "a voxel among the active sites", c)
        })?;
        vertex_site.push(s);
        site_vertex_count[s as usize] += 1;
    }
    Ok(Voxelization {
        vertex_voxel,
        vertex_site,
        sites,
        site_vertex_count,
    })
}

/// The placement and active sites of one grid level: site `o` (integer coordinates) has its
/// value at `origin_m + o * voxel_size_m`. Trilinear sampling of this level is valid inside
/// `bounds_min_m..=bounds_max_m` (the level-0 box); points outside read zero.
#[derive(Debug, Clone)]
pub struct ScaleGeometry {
    /// Level (0 = full resolution, `l` = 1 / 2^l).
    pub level: u32,
    /// [3] metres, the centre of voxel (0, 0, 0) of this level.
    pub origin_m: [f32; 3],
    /// Edge of one voxel of this level, metres (`2^level` times the level-0 size).
    pub voxel_size_m: f32,
    /// [3] metres, the min corner of the level-0 box.
    pub bounds_min_m: [f32; 3],
    /// [3] metres, the max corner of the level-0 box.
    pub bounds_max_m: [f32; 3],
    /// The P_s active sites of this level (with their grid dims).
    pub sites: SiteIndex,
}

impl ScaleGeometry {
    /// The geometry of `level` of `voxel_box` with the given active sites (whose dims must be
    /// those of that level).
    pub fn new(
        voxel_box: &VoxelBox,
        level: u32,
        sites: SiteIndex,
    ) -> Result<Self, SparseGridError> {
        let (origin_m, voxel_size_m, dims) = voxel_box.level_placement(level);
        if sites.dims() != dims {
            return Err(SparseGridError::invalid(
                "ScaleGeometry sites",
                format!("a site index with the dims {dims:?} of level {level}"),
                sites.dims(),
            ));
        }
        Ok(ScaleGeometry {
            level,
            origin_m,
            voxel_size_m,
            bounds_min_m: voxel_box.min_m,
            bounds_max_m: voxel_box.max_m(),
            sites,
        })
    }

    /// Number of active sites P_s.
    pub fn num_sites(&self) -> usize {
        self.sites.len()
    }

    /// [3] metres, the position of the value of site coordinates `o`.
    pub fn centre_of(&self, o: [i32; 3]) -> [f32; 3] {
        std::array::from_fn(|a| self.origin_m[a] + o[a] as f32 * self.voxel_size_m)
    }

    /// Whether `p` lies in the closed level-0 box (false for non-finite `p`).
    pub fn in_bounds(&self, p: [f32; 3]) -> bool {
        (0..3).all(|a| p[a] >= self.bounds_min_m[a] && p[a] <= self.bounds_max_m[a])
    }
}
