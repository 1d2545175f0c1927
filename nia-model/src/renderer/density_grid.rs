//! The density baked per pose (adaptive work, inference only; not in the paper,
//! `[render] density_grid_m`): F_sigma evaluated once on a grid of nodes around the body,
//! then read by trilinear interpolation at every ray sample of every view of that pose.
//!
//! NIA's density half (pixel features l_n, body features s_n, attention, F_sigma) does not
//! read the target direction, so `sigma(x)` of one pose is the same field for every target
//! view. An orbit or a viewer drag renders many views of one pose; without this mode each view
//! runs the density half at every kept sample of every ray. This mode runs it once per pose at the
//! nodes of a `cell`-metre grid over the body's box (only nodes next to a cell the occupancy
//! grid keeps, or all of them without skipping), and every view then reads
//!
//! ```text
//! sigma(x) = sum over the 8 nodes n of the cell holding x of  w_n(x) sigma_n   (trilinear)
//! ```
//!
//! A ray's weights come from the grid's densities; the whole network then runs only where the
//! colour is wanted ([`crate::renderer::colour_once`]): at the `K` heaviest samples with
//! `colour_points = K`, else at every sample colour culling keeps (the paper's per-sample
//! colour). Outside the grid's box the density is 0. The grid is baked on the first render that
//! asks for it and kept with the encoding ([`DensityMemo`]), for as long as the encoding is.
//! What it costs in accuracy (the trilinear blur of a thin density shell) is measured in
//! docs/accuracy-time.md, "The density baked per pose".
//!
//! Cost: one density pass over the nodes per pose (`nodes` points; `renderer::density_bake`);
//! memory 4 bytes a node (a 2 m person's box at 1 cm is about 0.8 M nodes, 3 MB).

use std::sync::{Arc, Mutex};

use glam::Vec3;
use nia_data::geometry::rays::Aabb;
use rayon::prelude::*;

use crate::error::ModelError;

/// The most nodes a grid may have (about 64 MB of densities).
pub const MAX_DENSITY_NODES: usize = 16 << 20;

/// Densities at the nodes of a regular grid (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct DensityGrid {
    /// World position of node (0, 0, 0), metres.
    origin: Vec3,
    /// Node spacing, metres.
    cell: f32,
    /// Nodes along x, y, z (at least 2 each).
    dims: [usize; 3],
    /// `[X * Y * Z]` x-fastest, per metre; 0 at nodes not evaluated.
    sigma: Vec<f32>,
    /// Nodes the network evaluated.
    evaluated: usize,
}

impl DensityGrid {
    /// The nodes covering `bounds` at spacing `cell_m` (at least 2 per axis), before any
    /// density: origin and node counts. Errors when `cell_m` is not a positive distance, the
    /// box is not finite, or the grid would pass [`MAX_DENSITY_NODES`].
    fn layout(bounds: &Aabb, cell_m: f32) -> Result<(Vec3, [usize; 3]), ModelError> {
        if !(cell_m.is_finite() && cell_m > 0.0) {
            return Err(ModelError::Input(format!(
                "density grid: cell = {cell_m}, expected a positive distance (metres)"
            )));
        }
        let size = bounds.max - bounds.min;
        if !(bounds.min.is_finite() && size.is_finite() && size.min_element() >= 0.0) {
            return Err(ModelError::Input(format!(
                "density grid: box {:?}..{:?}, expected finite corners, min <= max",
                bounds.min, bounds.max
            )));
        }
        let nodes = |extent: f32| (extent / cell_m).ceil() as usize + 1;
        let dims = [nodes(size.x), nodes(size.y), nodes(size.z)].map(|n| n.max(2));
        let total = dims.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n));
        match total {
            Some(n) if n <= MAX_DENSITY_NODES => Ok((bounds.min, dims)),
            _ => Err(ModelError::Input(format!(
                "density grid: {dims:?} nodes at {cell_m} m is over the {MAX_DENSITY_NODES} limit \
                 (use a larger `density_grid_m`)"
            ))),
        }
    }

    /// The grid over `bounds` at spacing `cell_m` whose density at node `n` is `sigma(x_n)`
    /// for the nodes `wanted(x_n)` keeps and 0 elsewhere. `sigma` gets every kept node at
    /// once (in x-fastest order) and returns their densities in the same order.
    pub fn bake(
        bounds: &Aabb,
        cell_m: f32,
        wanted: impl Fn(Vec3) -> bool + Sync,
        sigma: impl FnOnce(&[Vec3]) -> Result<Vec<f32>, ModelError>,
    ) -> Result<Self, ModelError> {
        let (origin, dims) = Self::layout(bounds, cell_m)?;
        let [nx, ny, nz] = dims;
        let node = |i: usize| {
            let (x, y, z) = (i % nx, (i / nx) % ny, i / (nx * ny));
            origin + Vec3::new(x as f32, y as f32, z as f32) * cell_m
        };
        let kept: Vec<usize> = (0..nx * ny * nz)
            .into_par_iter()
            .filter(|&i| wanted(node(i)))
            .collect();
        let points: Vec<Vec3> = kept.iter().map(|&i| node(i)).collect();
        let values = if points.is_empty() {
            Vec::new()
        } else {
            sigma(&points)?
        };
        if values.len() != points.len() {
            return Err(ModelError::Input(format!(
                "density grid: {} densities for {} nodes",
                values.len(),
                points.len()
            )));
        }
        let mut grid = vec![0.0f32; nx * ny * nz];
        for (&i, &v) in kept.iter().zip(&values) {
            // A non-finite density is kept as the network gave it: the weights make a NaN or
            // infinite sample opaque, as they do in the walk.
            grid[i] = v;
        }
        Ok(DensityGrid {
            origin,
            cell: cell_m,
            dims,
            sigma: grid,
            evaluated: points.len(),
        })
    }

    /// Trilinear density at `x` (world metres); 0 outside the grid or at a non-finite point.
    pub fn sigma_at(&self, x: Vec3) -> f32 {
        let q = (x - self.origin) / self.cell;
        let [nx, ny, nz] = self.dims;
        let last = Vec3::new((nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32);
        if !(q.cmpge(Vec3::ZERO).all() && q.cmple(last).all()) {
            return 0.0;
        }
        // The lower node of the cell, clamped so that a point on the far face reads the last
        // cell.
        let base = q.floor().min(last - Vec3::ONE);
        let f = q - base;
        let (x0, y0, z0) = (base.x as usize, base.y as usize, base.z as usize);
        let at = |x: usize, y: usize, z: usize| self.sigma[x + nx * (y + ny * z)];
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let c00 = lerp(at(x0, y0, z0), at(x0 + 1, y0, z0), f.x);
        let c10 = lerp(at(x0, y0 + 1, z0), at(x0 + 1, y0 + 1, z0), f.x);
        let c01 = lerp(at(x0, y0, z0 + 1), at(x0 + 1, y0, z0 + 1), f.x);
        let c11 = lerp(at(x0, y0 + 1, z0 + 1), at(x0 + 1, y0 + 1, z0 + 1), f.x);
        lerp(lerp(c00, c10, f.y), lerp(c01, c11, f.y), f.z)
    }

    /// Node spacing, metres.
    pub fn cell_m(&self) -> f32 {
        self.cell
    }

    /// Nodes along x, y, z.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Nodes the network evaluated when baking.
    pub fn evaluated(&self) -> usize {
        self.evaluated
    }

    /// Whether this grid was baked over `bounds` at `cell_m`.
    pub(crate) fn covers(&self, bounds: &Aabb, cell_m: f32) -> bool {
        matches!(Self::layout(bounds, cell_m), Ok((o, d)) if o == self.origin && d == self.dims)
            && self.cell == cell_m
    }
}

/// The density grid an encoding baked, shared by its clones (the viewer's pose cache, every
/// view of an orbit). A new pose, occupancy grid or visual hull starts a new memo
/// (`SceneEncoding::with_occupancy`, `with_visual_hull`, `NiaModel::encode_pose`).
#[derive(Debug, Clone, Default)]
pub struct DensityMemo(pub(crate) Arc<Mutex<Option<Arc<DensityGrid>>>>);

impl DensityMemo {
    /// The grid baked so far (`None` before the first render that asks for one).
    pub fn baked(&self) -> Option<Arc<DensityGrid>> {
        self.0.lock().ok().and_then(|g| g.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box() -> Aabb {
        Aabb::new(Vec3::ZERO, Vec3::ONE)
    }

    #[test]
    fn trilinear_reads_a_linear_field_exactly_and_zero_outside() {
        let field = |x: Vec3| 1.0 + 2.0 * x.x - 3.0 * x.y + 0.5 * x.z;
        let grid = DensityGrid::bake(
            &unit_box(),
            0.25,
            |_| true,
            |p| Ok(p.iter().map(|&x| field(x)).collect()),
        )
        .unwrap();
        assert_eq!(grid.dims(), [5, 5, 5]);
        assert_eq!(grid.evaluated(), 125);
        for x in [
            Vec3::new(0.1, 0.2, 0.3),
            Vec3::new(0.99, 0.5, 0.01),
            Vec3::ONE,
            Vec3::ZERO,
        ] {
            assert!((grid.sigma_at(x) - field(x)).abs() < 1e-5, "{x}");
        }
        assert_eq!(grid.sigma_at(Vec3::new(1.01, 0.5, 0.5)), 0.0);
        assert_eq!(grid.sigma_at(Vec3::new(-0.01, 0.5, 0.5)), 0.0);
        assert_eq!(grid.sigma_at(Vec3::new(f32::NAN, 0.5, 0.5)), 0.0);
        assert_eq!(grid.sigma_at(Vec3::splat(f32::INFINITY)), 0.0);
    }

    #[test]
    fn nodes_not_wanted_stay_empty_and_huge_densities_are_kept() {
        // Only the nodes with x <= 0.5 are evaluated; a huge density there is read as it is.
        let grid = DensityGrid::bake(
            &unit_box(),
            0.5,
            |x| x.x <= 0.5,
            |p| Ok(vec![1e30; p.len()]),
        )
        .unwrap();
        assert_eq!(grid.evaluated(), 2 * 3 * 3);
        assert_eq!(grid.sigma_at(Vec3::new(0.25, 0.5, 0.5)), 1e30);
        assert_eq!(grid.sigma_at(Vec3::new(1.0, 0.5, 0.5)), 0.0);
        let mid = grid.sigma_at(Vec3::new(0.75, 0.5, 0.5));
        assert!(mid.is_finite() && (mid - 0.5e30).abs() < 1e24, "{mid}");
    }

    #[test]
    fn bad_cells_boxes_and_counts_are_errors() {
        let never = |_: &[Vec3]| -> Result<Vec<f32>, ModelError> { unreachable!() };
        let err = |r: Result<DensityGrid, ModelError>| r.unwrap_err().to_string();
        assert!(err(DensityGrid::bake(&unit_box(), 0.0, |_| true, never)).contains("cell = 0"));
        assert!(err(DensityGrid::bake(&unit_box(), 1e-4, |_| true, never)).contains("limit"));
        let nan = Aabb::new(Vec3::splat(f32::NAN), Vec3::ONE);
        assert!(err(DensityGrid::bake(&nan, 0.1, |_| true, never)).contains("finite"));
        let short = DensityGrid::bake(&unit_box(), 0.5, |_| true, |_| Ok(vec![1.0]));
        assert!(err(short).contains("densities for"));
        // Nothing wanted: no network call, an empty grid.
        let empty = DensityGrid::bake(&unit_box(), 0.5, |_| false, never).unwrap();
        assert_eq!(
            (empty.evaluated(), empty.sigma_at(Vec3::splat(0.5))),
            (0, 0.0)
        );
    }
}
