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
//! The bake also keeps the visibility o_n of every source view at the evaluated nodes, and
//! the colour half then reads o_n there by trilinear interpolation ([`DensityGrid::visibility_at`])
//! instead of a nearest-face query per coloured point (an approximation of the nearest face's
//! visibility; measured with the density in docs/accuracy-time.md).
//!
//! Cost: one density pass and one nearest-face query over the nodes per pose (`nodes` points;
//! `renderer::density_bake`); memory 8 bytes a node and 4 N bytes an evaluated node (a 2 m
//! person's box at 1 cm is about 0.8 M nodes, 6 MB).

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
    /// Source views N of the visibility baked with the density (0: none baked).
    views: usize,
    /// `[X * Y * Z]` each node's row in `visibility`, [`NOT_EVALUATED`] at nodes the bake left
    /// out; empty when `views` is 0.
    slot: Vec<u32>,
    /// `[evaluated, N]` the visibility o_n of the N source views at each evaluated node.
    visibility: Vec<f32>,
}

/// [`DensityGrid`]'s slot of a node the bake left out.
const NOT_EVALUATED: u32 = u32::MAX;

/// What the network gave at a grid's kept nodes ([`DensityGrid::bake`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NodeValues {
    /// `[M]` densities, per metre.
    pub sigma: Vec<f32>,
    /// `[N, M]` (view-major, as the point inputs hold it) visibility o_n of the N source
    /// views; empty to bake no visibility.
    pub visibility: Vec<f32>,
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
    /// for the nodes `wanted(x_n)` keeps and 0 elsewhere. `values` gets every kept node at
    /// once (in x-fastest order) and returns their densities in the same order, and their
    /// visibility in `views` source views (`views` = 0: none).
    pub fn bake(
        bounds: &Aabb,
        cell_m: f32,
        views: usize,
        wanted: impl Fn(Vec3) -> bool + Sync,
        values: impl FnOnce(&[Vec3]) -> Result<NodeValues, ModelError>,
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
        let m = points.len();
        let values = if points.is_empty() {
            NodeValues::default()
        } else {
            values(&points)?
        };
        if values.sigma.len() != m || (m > 0 && values.visibility.len() != views * m) {
            return Err(ModelError::Input(format!(
                "density grid: {} densities and {} visibilities for {m} nodes and {views} views",
                values.sigma.len(),
                values.visibility.len(),
            )));
        }
        let mut grid = vec![0.0f32; nx * ny * nz];
        for (&i, &v) in kept.iter().zip(&values.sigma) {
            // A non-finite density is kept as the network gave it: the weights make a NaN or
            // infinite sample opaque, as they do in the walk.
            grid[i] = v;
        }
        let (mut slot, mut visibility) = (Vec::new(), Vec::new());
        if views > 0 {
            slot = vec![NOT_EVALUATED; nx * ny * nz];
            visibility = vec![0.0f32; m * views];
            for (p, &i) in kept.iter().enumerate() {
                slot[i] = p as u32;
                for (view, o) in visibility[p * views..(p + 1) * views]
                    .iter_mut()
                    .enumerate()
                {
                    *o = values.visibility[view * m + p];
                }
            }
        }
        Ok(DensityGrid {
            origin,
            cell: cell_m,
            dims,
            sigma: grid,
            evaluated: m,
            views,
            slot,
            visibility,
        })
    }

    /// The cell holding `x` (world metres): its lower node `(x, y, z)` and the fractions
    /// along each axis; `None` outside the grid or at a non-finite point. A point on the far
    /// face reads the last cell.
    fn cell_of(&self, x: Vec3) -> Option<([usize; 3], Vec3)> {
        let q = (x - self.origin) / self.cell;
        let [nx, ny, nz] = self.dims;
        let last = Vec3::new((nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32);
        if !(q.cmpge(Vec3::ZERO).all() && q.cmple(last).all()) {
            return None;
        }
        let base = q.floor().min(last - Vec3::ONE);
        Some((
            [base.x as usize, base.y as usize, base.z as usize],
            q - base,
        ))
    }

    /// Trilinear density at `x` (world metres); 0 outside the grid or at a non-finite point.
    pub fn sigma_at(&self, x: Vec3) -> f32 {
        let Some(([x0, y0, z0], f)) = self.cell_of(x) else {
            return 0.0;
        };
        let [nx, ny, _] = self.dims;
        let at = |x: usize, y: usize, z: usize| self.sigma[x + nx * (y + ny * z)];
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let c00 = lerp(at(x0, y0, z0), at(x0 + 1, y0, z0), f.x);
        let c10 = lerp(at(x0, y0 + 1, z0), at(x0 + 1, y0 + 1, z0), f.x);
        let c01 = lerp(at(x0, y0, z0 + 1), at(x0 + 1, y0, z0 + 1), f.x);
        let c11 = lerp(at(x0, y0 + 1, z0 + 1), at(x0 + 1, y0 + 1, z0 + 1), f.x);
        lerp(lerp(c00, c10, f.y), lerp(c01, c11, f.y), f.z)
    }

    /// The visibility o_n of the baked views at `x` into `out` (`[N]`): the trilinear mean of
    /// the cell's evaluated nodes (the weights of nodes the bake left out are dropped and the
    /// rest renormalised). Zeros outside the grid, in a cell with no evaluated node, or when
    /// no visibility was baked. An approximation of the nearest-face visibility at `x` (what
    /// it costs: docs/accuracy-time.md, "The density baked per pose").
    pub fn visibility_at(&self, x: Vec3, out: &mut [f32]) {
        out.fill(0.0);
        let views = self.views.min(out.len());
        let Some(([x0, y0, z0], f)) = self.cell_of(x).filter(|_| views > 0) else {
            return;
        };
        let [nx, ny, _] = self.dims;
        let mut total = 0.0f32;
        for k in 0..8 {
            let (dx, dy, dz) = (k & 1, (k >> 1) & 1, (k >> 2) & 1);
            let slot = self.slot[(x0 + dx) + nx * ((y0 + dy) + ny * (z0 + dz))];
            if slot == NOT_EVALUATED {
                continue;
            }
            let w = [1.0 - f.x, f.x][dx] * [1.0 - f.y, f.y][dy] * [1.0 - f.z, f.z][dz];
            let node = &self.visibility[slot as usize * self.views..][..self.views];
            total += w;
            for (o, v) in out[..views].iter_mut().zip(node) {
                *o += w * v;
            }
        }
        if total > 0.0 {
            out[..views].iter_mut().for_each(|o| *o /= total);
        } else {
            out.fill(0.0);
        }
    }

    /// Source views whose visibility was baked with the density (0: none).
    pub fn visibility_views(&self) -> usize {
        self.views
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
            0,
            |_| true,
            |p| Ok(sigma_only(p.iter().map(|&x| field(x)).collect())),
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
            0,
            |x| x.x <= 0.5,
            |p| Ok(sigma_only(vec![1e30; p.len()])),
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
        let never = |_: &[Vec3]| -> Result<NodeValues, ModelError> { unreachable!() };
        let err = |r: Result<DensityGrid, ModelError>| r.unwrap_err().to_string();
        assert!(err(DensityGrid::bake(&unit_box(), 0.0, 0, |_| true, never)).contains("cell = 0"));
        assert!(err(DensityGrid::bake(&unit_box(), 1e-4, 0, |_| true, never)).contains("limit"));
        let nan = Aabb::new(Vec3::splat(f32::NAN), Vec3::ONE);
        assert!(err(DensityGrid::bake(&nan, 0.1, 0, |_| true, never)).contains("finite"));
        let short = DensityGrid::bake(&unit_box(), 0.5, 0, |_| true, |_| Ok(sigma_only(vec![1.0])));
        assert!(err(short).contains("densities and"));
        // Visibility for the wrong number of views.
        let views = DensityGrid::bake(
            &unit_box(),
            0.5,
            2,
            |_| true,
            |p| {
                Ok(NodeValues {
                    sigma: vec![1.0; p.len()],
                    visibility: vec![1.0; p.len()],
                })
            },
        );
        assert!(err(views).contains("2 views"));
        // Nothing wanted: no network call, an empty grid.
        let empty = DensityGrid::bake(&unit_box(), 0.5, 2, |_| false, never).unwrap();
        assert_eq!(
            (empty.evaluated(), empty.sigma_at(Vec3::splat(0.5))),
            (0, 0.0)
        );
        let mut o = [1.0f32; 2];
        empty.visibility_at(Vec3::splat(0.5), &mut o);
        assert_eq!(o, [0.0, 0.0]);
    }

    #[test]
    fn visibility_is_trilinear_over_the_evaluated_nodes_only() {
        // Two views: o_0 linear in x, o_1 = 1 - o_0; nodes with x > 0.5 left out.
        let field = |x: Vec3| 0.2 + 0.6 * x.x;
        let grid = DensityGrid::bake(
            &unit_box(),
            0.25,
            2,
            |x| x.x <= 0.5,
            |p| {
                let mut visibility: Vec<f32> = p.iter().map(|&x| field(x)).collect();
                visibility.extend(p.iter().map(|&x| 1.0 - field(x)));
                Ok(NodeValues {
                    sigma: vec![1.0; p.len()],
                    visibility,
                })
            },
        )
        .unwrap();
        assert_eq!(grid.visibility_views(), 2);
        let mut o = [0.0f32; 2];
        // Inside the evaluated half: exact on a linear field, the two views summing to 1.
        let x = Vec3::new(0.3, 0.7, 0.1);
        grid.visibility_at(x, &mut o);
        assert!(
            (o[0] - field(x)).abs() < 1e-6 && (o[0] + o[1] - 1.0).abs() < 1e-6,
            "{o:?}"
        );
        // In the cell across x = 0.5, only the x = 0.5 nodes count: the value there, not a
        // mean pulled towards 0 by the nodes left out.
        grid.visibility_at(Vec3::new(0.6, 0.5, 0.5), &mut o);
        assert!((o[0] - field(Vec3::splat(0.5))).abs() < 1e-6, "{o:?}");
        // No evaluated node in the cell, outside the grid, or a non-finite point: zeros.
        for x in [
            Vec3::new(0.9, 0.5, 0.5),
            Vec3::new(1.5, 0.5, 0.5),
            Vec3::new(f32::NAN, 0.5, 0.5),
        ] {
            o = [1.0; 2];
            grid.visibility_at(x, &mut o);
            assert_eq!(o, [0.0, 0.0], "{x}");
        }
        // A grid baked without visibility reads zeros.
        let plain = DensityGrid::bake(
            &unit_box(),
            0.5,
            0,
            |_| true,
            |p| Ok(sigma_only(vec![1.0; p.len()])),
        )
        .unwrap();
        o = [1.0; 2];
        plain.visibility_at(Vec3::splat(0.5), &mut o);
        assert_eq!((plain.visibility_views(), o), (0, [0.0, 0.0]));
    }

    fn sigma_only(sigma: Vec<f32>) -> NodeValues {
        NodeValues {
            sigma,
            visibility: Vec::new(),
        }
    }
}
