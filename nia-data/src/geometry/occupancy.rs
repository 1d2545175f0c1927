//! An occupancy grid of a posed body mesh, for empty-space skipping: which points of space are
//! within a distance of the body (its surface or its inside) and may hold density.
//!
//! Built once per frame (and per target pose) from the posed mesh in a few milliseconds:
//! 1. a cell is marked when its centre is within `threshold + half a cell diagonal` of a
//!    triangle (exact point-triangle distance). Each cell asks the mesh's nearest-surface BVH
//!    whether any triangle is that close, a query that stops at the first one; blocks of
//!    cells with no triangle near any of their centres are passed over with one query.
//!    Conservative: a point within `threshold` of the surface is within half a diagonal of
//!    its cell's centre, so its cell is marked; a marked cell reaches at most `threshold` + a
//!    cell diagonal from the surface;
//! 2. the unmarked cells connected to the grid's border (6-neighbourhood span fill) are
//!    outside; the unmarked cells the fill does not reach are inside the body and are marked
//!    too (the body's inside is never skipped, whatever its size).
//!
//! Points outside the grid are empty: the grid spans the mesh's box grown by the threshold and
//! a cell, so every point within `threshold` of the surface is inside it.

use glam::Vec3;

use crate::geometry::rays::Aabb;
use crate::geometry::surface::{closest_point_on_triangle, AnyWithinHint, SurfaceIndex};
use crate::geometry::surface_memo::shared_surface;

/// Error building an occupancy grid.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum OccupancyError {
    #[error("occupancy grid: {field} = {value}, expected {expected}")]
    Setting {
        field: &'static str,
        value: f32,
        expected: &'static str,
    },
    #[error("occupancy grid: the mesh has no vertices")]
    EmptyMesh,
    #[error("occupancy grid: vertex {vertex} is {value}, expected finite coordinates (metres)")]
    NonFiniteVertex { vertex: usize, value: String },
    #[error("occupancy grid: face {face} names vertex {vertex}, but the mesh has {vertices}")]
    Face {
        face: usize,
        vertex: u32,
        vertices: usize,
    },
    #[error("occupancy grid: {cells} cells at {cell_m} m cells is over the {max} limit (use larger cells)")]
    TooLarge { cells: u64, cell_m: f32, max: u64 },
}

/// Cells along each edge of the blocks that [`OccupancyGrid::build`] passes over when no face
/// is near.
const BLOCK: usize = 2;

/// Most cells a grid may have (a 2 m body at 1 cm cells is about 1.2e6).
pub const MAX_CELLS: u64 = 64 << 20;

/// Cells that may hold density near a posed mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGrid {
    /// World corner of cell (0, 0, 0), metres.
    origin: Vec3,
    /// Cell edge, metres.
    cell: f32,
    /// Cells along x, y, z.
    dims: [usize; 3],
    /// [X * Y * Z] x-fastest.
    occupied: Vec<bool>,
    /// The distance from the surface this grid keeps, metres.
    threshold: f32,
}

impl OccupancyGrid {
    /// The grid of the mesh (`vertices` [V] world metres, `faces` [F]) keeping every point
    /// within `threshold_m` of its surface or inside it, at `cell_m` cells.
    ///
    /// Marks cell by cell: each cell asks the mesh's [`SurfaceIndex`] (the one
    /// [`shared_surface`] remembers for this mesh, which the scene's nearest-surface queries use
    /// too) whether any face lies within reach of its centre. The same test as
    /// [`Self::build_face_by_face`], and the same grid (a test compares them).
    pub fn build(
        vertices: &[Vec3],
        faces: &[[u32; 3]],
        threshold_m: f32,
        cell_m: f32,
    ) -> Result<Self, OccupancyError> {
        let mut grid = Self::unmarked(vertices, faces, threshold_m, cell_m)?;
        if !faces.is_empty() {
            match shared_surface(vertices, faces) {
                Ok(index) => grid.mark_cell_by_cell(&index),
                // The checks above leave the index nothing to refuse; were it to, the faces
                // still mark the grid.
                Err(_) => grid.mark_face_by_face(vertices, faces),
            }
        }
        grid.fill_inside();
        Ok(grid)
    }

    /// [`Self::build`] face by face: each face tests the cells of its bounding box grown by the
    /// reach. The reference the tests compare [`Self::build`] with (and the benches time).
    pub fn build_face_by_face(
        vertices: &[Vec3],
        faces: &[[u32; 3]],
        threshold_m: f32,
        cell_m: f32,
    ) -> Result<Self, OccupancyError> {
        let mut grid = Self::unmarked(vertices, faces, threshold_m, cell_m)?;
        grid.mark_face_by_face(vertices, faces);
        grid.fill_inside();
        Ok(grid)
    }

    /// The grid's cells over the mesh's box, none marked, after checking the settings and
    /// the faces.
    fn unmarked(
        vertices: &[Vec3],
        faces: &[[u32; 3]],
        threshold_m: f32,
        cell_m: f32,
    ) -> Result<Self, OccupancyError> {
        if !(cell_m.is_finite() && cell_m > 0.0) {
            return Err(OccupancyError::Setting {
                field: "cell_m",
                value: cell_m,
                expected: "a finite size > 0",
            });
        }
        if !(threshold_m.is_finite() && threshold_m >= 0.0) {
            return Err(OccupancyError::Setting {
                field: "threshold_m",
                value: threshold_m,
                expected: "a finite distance >= 0",
            });
        }
        for (f, face) in faces.iter().enumerate() {
            if let Some(&v) = face.iter().find(|&&v| v as usize >= vertices.len()) {
                return Err(OccupancyError::Face {
                    face: f,
                    vertex: v,
                    vertices: vertices.len(),
                });
            }
        }
        if let Some((vertex, v)) = vertices.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(OccupancyError::NonFiniteVertex {
                vertex,
                value: format!("{v}"),
            });
        }
        let bounds = Aabb::from_points(vertices).ok_or(OccupancyError::EmptyMesh)?;
        let reach = threshold_m + Self::half_diagonal(cell_m);
        // One spare cell beyond the reach on every side keeps the border unmarked (the flood
        // fill starts there).
        let origin = bounds.min - Vec3::splat(reach + cell_m);
        let extent = bounds.max + Vec3::splat(reach + cell_m) - origin;
        let dims = [
            (extent.x / cell_m).ceil() as usize + 1,
            (extent.y / cell_m).ceil() as usize + 1,
            (extent.z / cell_m).ceil() as usize + 1,
        ];
        let cells = dims.iter().map(|&d| d as u64).product::<u64>();
        if cells > MAX_CELLS {
            return Err(OccupancyError::TooLarge {
                cells,
                cell_m,
                max: MAX_CELLS,
            });
        }
        Ok(OccupancyGrid {
            origin,
            cell: cell_m,
            dims,
            occupied: vec![false; cells as usize],
            threshold: threshold_m,
        })
    }

    fn half_diagonal(cell_m: f32) -> f32 {
        cell_m * 3f32.sqrt() * 0.5
    }

    /// A cell is marked when its centre is within this distance of a face, metres.
    fn reach(&self) -> f32 {
        self.threshold + Self::half_diagonal(self.cell)
    }

    /// Marks every cell whose centre has a face within reach, asking `index` cell by cell.
    /// Blocks of [`BLOCK`]^3 cells ask first whether any face is within reach of any of their
    /// centres (the reach plus the block's half diagonal, with a margin for rounding, from the
    /// block's middle); a block with none is passed over. Each query tries the face that
    /// answered the last one first.
    fn mark_cell_by_cell(&mut self, index: &SurfaceIndex) {
        /// Metres added to a block's reach: far above f32 rounding at body scale, far below a
        /// cell.
        const MARGIN_M: f32 = 1e-4;
        let reach = self.reach();
        let reach2 = reach * reach;
        let [nx, ny, nz] = self.dims;
        let mut hint = AnyWithinHint::default();
        for bz in (0..nz).step_by(BLOCK) {
            for by in (0..ny).step_by(BLOCK) {
                for bx in (0..nx).step_by(BLOCK) {
                    let (ex, ey, ez) = (
                        (bx + BLOCK).min(nx),
                        (by + BLOCK).min(ny),
                        (bz + BLOCK).min(nz),
                    );
                    let first = self.centre(bx, by, bz);
                    let last = self.centre(ex - 1, ey - 1, ez - 1);
                    let block_reach = reach + 0.5 * (last - first).length() + MARGIN_M;
                    let middle = 0.5 * (first + last);
                    if !index.any_within_squared(middle, block_reach * block_reach, &mut hint) {
                        continue;
                    }
                    for z in bz..ez {
                        for y in by..ey {
                            for x in bx..ex {
                                if index.any_within_squared(self.centre(x, y, z), reach2, &mut hint)
                                {
                                    let i = self.index(x, y, z);
                                    self.occupied[i] = true;
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// Marks every cell whose centre has a face within reach, testing for each face the cells
    /// of its bounding box grown by the reach.
    fn mark_face_by_face(&mut self, vertices: &[Vec3], faces: &[[u32; 3]]) {
        let reach = self.reach();
        let reach2 = reach * reach;
        for face in faces {
            let [a, b, c] = face.map(|v| vertices[v as usize]);
            let lo = a.min(b).min(c) - Vec3::splat(reach);
            let hi = a.max(b).max(c) + Vec3::splat(reach);
            let (l, h) = (self.cell_of_clamped(lo), self.cell_of_clamped(hi));
            for z in l[2]..=h[2] {
                for y in l[1]..=h[1] {
                    for x in l[0]..=h[0] {
                        let i = self.index(x, y, z);
                        if self.occupied[i] {
                            continue;
                        }
                        let centre = self.centre(x, y, z);
                        let (q, _) = closest_point_on_triangle(centre, a, b, c);
                        if (q - centre).length_squared() <= reach2 {
                            self.occupied[i] = true;
                        }
                    }
                }
            }
        }
    }

    fn centre(&self, x: usize, y: usize, z: usize) -> Vec3 {
        self.origin + (Vec3::new(x as f32, y as f32, z as f32) + 0.5) * self.cell
    }

    fn index(&self, x: usize, y: usize, z: usize) -> usize {
        (z * self.dims[1] + y) * self.dims[0] + x
    }

    /// The cell containing `p`, clamped into the grid.
    fn cell_of_clamped(&self, p: Vec3) -> [usize; 3] {
        let q = (p - self.origin) / self.cell;
        [
            (q.x.floor().max(0.0) as usize).min(self.dims[0] - 1),
            (q.y.floor().max(0.0) as usize).min(self.dims[1] - 1),
            (q.z.floor().max(0.0) as usize).min(self.dims[2] - 1),
        ]
    }

    /// Marks the unmarked cells the border cannot reach (the body's inside).
    ///
    /// A span fill: each seed fills its whole run of free cells along x at once, then seeds
    /// the free runs next to it in the four neighbouring rows (6-neighbourhood).
    fn fill_inside(&mut self) {
        let [nx, ny, nz] = self.dims;
        let plane = nx * ny;
        let occupied = &self.occupied;
        let mut outside = vec![false; occupied.len()];
        let free = |outside: &[bool], i: usize| !occupied[i] && !outside[i];
        // Seeds: every border cell (one already filled is passed over when popped).
        let mut stack: Vec<usize> = Vec::new();
        for z in 0..nz {
            for y in 0..ny {
                let row = z * plane + y * nx;
                if z == 0 || y == 0 || z + 1 == nz || y + 1 == ny {
                    stack.extend(row..row + nx);
                } else {
                    stack.extend([row, row + nx - 1]);
                }
            }
        }
        while let Some(i) = stack.pop() {
            if !free(&outside, i) {
                continue;
            }
            let row = i - i % nx;
            let (y, z) = ((i / nx) % ny, i / plane);
            let (mut l, mut r) = (i, i);
            while l > row && free(&outside, l - 1) {
                l -= 1;
            }
            while r + 1 < row + nx && free(&outside, r + 1) {
                r += 1;
            }
            outside[l..=r].fill(true);
            let neighbours = [
                (y > 0).then(|| l - nx),
                (y + 1 < ny).then(|| l + nx),
                (z > 0).then(|| l - plane),
                (z + 1 < nz).then(|| l + plane),
            ];
            for start in neighbours.into_iter().flatten() {
                let mut in_run = false;
                for k in start..=start + (r - l) {
                    let f = free(&outside, k);
                    if f && !in_run {
                        stack.push(k);
                    }
                    in_run = f;
                }
            }
        }
        for (o, out) in self.occupied.iter_mut().zip(&outside) {
            *o = !out;
        }
    }

    /// Whether `p` (world metres) may hold density: inside the grid and in a marked cell.
    /// Non-finite points are empty.
    pub fn occupied(&self, p: Vec3) -> bool {
        let q = (p - self.origin) / self.cell;
        if !(q.x >= 0.0 && q.y >= 0.0 && q.z >= 0.0) {
            return false;
        }
        let (x, y, z) = (q.x as usize, q.y as usize, q.z as usize);
        if x >= self.dims[0] || y >= self.dims[1] || z >= self.dims[2] {
            return false;
        }
        self.occupied[self.index(x, y, z)]
    }

    /// The ray `origin + t dir`, `t` in `[near, far]`, cut into runs of marked cells and of
    /// empty space (outside the grid or unmarked cells), in order, covering the interval,
    /// adjacent cells of one kind merged: pushed onto `runs` (cleared first) as
    /// `(t0, t1, marked)`.
    ///
    /// Found by walking the cells the ray crosses, one step per cell (a 3D DDA, Amanatides and
    /// Woo 1987), instead of testing points along it. The bounds carry the walk's rounding
    /// (a few ulps of the distances along the ray): a caller that needs the exact answer of
    /// [`Self::occupied`] for a point within a small margin of a bound asks it. A non-finite
    /// ray or interval gives no runs.
    pub fn runs_along(
        &self,
        origin: Vec3,
        dir: Vec3,
        near: f32,
        far: f32,
        runs: &mut Vec<(f32, f32, bool)>,
    ) {
        runs.clear();
        if !(origin.is_finite() && dir.is_finite() && near.is_finite() && far.is_finite())
            || far <= near
        {
            return;
        }
        // From `t` on the ray is `marked` (or not): a new run, or the last one goes on.
        let enter = |runs: &mut Vec<(f32, f32, bool)>, t: f32, marked: bool| match runs.last_mut() {
            Some(last) if last.2 == marked => {}
            Some(last) => {
                last.1 = t;
                runs.push((t, t, marked));
            }
            None => runs.push((t, t, marked)),
        };
        // The ray's interval inside the grid's box (slab test).
        let size = Vec3::new(
            self.dims[0] as f32,
            self.dims[1] as f32,
            self.dims[2] as f32,
        ) * self.cell;
        let (mut t_in, mut t_out) = (near, far);
        for axis in 0..3 {
            let (o, d, lo) = (origin[axis], dir[axis], self.origin[axis]);
            let hi = lo + size[axis];
            if d == 0.0 {
                if o < lo || o > hi {
                    t_out = f32::NEG_INFINITY;
                }
                continue;
            }
            let (a, b) = ((lo - o) / d, (hi - o) / d);
            t_in = t_in.max(a.min(b));
            t_out = t_out.min(a.max(b));
        }
        if !(t_in < t_out) {
            runs.push((near, far, false));
            return;
        }
        if t_in > near {
            enter(runs, near, false);
        }
        // The cell where the ray enters, then one cell per step.
        let mut cell = self.cell_of_clamped(origin + dir * t_in);
        let mut step = [0isize; 3];
        let mut t_max = [f32::INFINITY; 3];
        let mut t_delta = [f32::INFINITY; 3];
        for axis in 0..3 {
            let d = dir[axis];
            if d == 0.0 {
                continue;
            }
            step[axis] = if d > 0.0 { 1 } else { -1 };
            let boundary = cell[axis] as f32 + if d > 0.0 { 1.0 } else { 0.0 };
            t_max[axis] = (self.origin[axis] + boundary * self.cell - origin[axis]) / d;
            t_delta[axis] = self.cell / d.abs();
        }
        let mut t = t_in;
        // Where the walk leaves the grid: at `t_out`, or where a step leaves the cells first.
        let t_exit = loop {
            enter(
                runs,
                t,
                self.occupied[self.index(cell[0], cell[1], cell[2])],
            );
            let axis = match (
                t_max[0] <= t_max[1],
                t_max[0] <= t_max[2],
                t_max[1] <= t_max[2],
            ) {
                (true, true, _) => 0,
                (false, _, true) => 1,
                _ => 2,
            };
            let next = t_max[axis];
            if !(next < t_out) {
                break t_out;
            }
            let moved = cell[axis] as isize + step[axis];
            if moved < 0 || moved as usize >= self.dims[axis] {
                break next;
            }
            t = next;
            t_max[axis] += t_delta[axis];
            cell[axis] = moved as usize;
        };
        // Past the last cell, empty space up to `far`.
        if t_exit < far {
            enter(runs, t_exit, false);
        }
        if let Some(last) = runs.last_mut() {
            last.1 = far;
        }
    }

    /// Cells along x, y, z.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The cell edge, metres.
    pub fn cell_m(&self) -> f32 {
        self.cell
    }

    /// The distance from the surface the grid keeps, metres.
    pub fn threshold_m(&self) -> f32 {
        self.threshold
    }
}
