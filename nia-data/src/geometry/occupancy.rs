//! An occupancy grid of a posed body mesh, for empty-space skipping: which points of space are
//! within a distance of the body (its surface or its inside) and may hold density.
//!
//! Built once per frame (and per target pose) from the posed mesh in a few milliseconds:
//! 1. a cell is marked when its centre is within `threshold + half a cell diagonal` of a
//!    triangle (exact point-triangle distance, tested for the cells of each triangle's grown
//!    bounding box). Conservative: a point within `threshold` of the surface is within half a
//!    diagonal of its cell's centre, so its cell is marked; a marked cell reaches at most
//!    `threshold` + a cell diagonal from the surface;
//! 2. the unmarked cells connected to the grid's border (6-neighbourhood flood fill) are
//!    outside; the unmarked cells the fill does not reach are inside the body and are marked
//!    too (the body's inside is never skipped, whatever its size).
//!
//! Points outside the grid are empty: the grid spans the mesh's box grown by the threshold and
//! a cell, so every point within `threshold` of the surface is inside it.

use glam::Vec3;

use crate::geometry::rays::Aabb;
use crate::geometry::surface::closest_point_on_triangle;

/// Error building an occupancy grid.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum OccupancyError {
    #[error("occupancy grid: {field} = {value}, expected {expected}")]
    Setting {
        field: &'static str,
        value: f32,
        expected: &'static str,
    },
    #[error("occupancy grid: the mesh has no finite vertices")]
    EmptyMesh,
    #[error("occupancy grid: face {face} names vertex {vertex}, but the mesh has {vertices}")]
    Face {
        face: usize,
        vertex: u32,
        vertices: usize,
    },
    #[error("occupancy grid: {cells} cells at {cell_m} m cells is over the {max} limit (use larger cells)")]
    TooLarge { cells: u64, cell_m: f32, max: u64 },
}

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
    pub fn build(
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
        let bounds = Aabb::from_points(vertices).ok_or(OccupancyError::EmptyMesh)?;
        let half_diagonal = cell_m * 3f32.sqrt() * 0.5;
        let reach = threshold_m + half_diagonal;
        let reach2 = reach * reach;
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
        let mut grid = OccupancyGrid {
            origin,
            cell: cell_m,
            dims,
            occupied: vec![false; cells as usize],
            threshold: threshold_m,
        };
        for face in faces {
            let [a, b, c] = face.map(|v| vertices[v as usize]);
            if !(a.is_finite() && b.is_finite() && c.is_finite()) {
                continue;
            }
            let lo = a.min(b).min(c) - Vec3::splat(reach);
            let hi = a.max(b).max(c) + Vec3::splat(reach);
            let (l, h) = (grid.cell_of_clamped(lo), grid.cell_of_clamped(hi));
            for z in l[2]..=h[2] {
                for y in l[1]..=h[1] {
                    for x in l[0]..=h[0] {
                        let i = grid.index(x, y, z);
                        if grid.occupied[i] {
                            continue;
                        }
                        let centre = grid.centre(x, y, z);
                        let (q, _) = closest_point_on_triangle(centre, a, b, c);
                        if (q - centre).length_squared() <= reach2 {
                            grid.occupied[i] = true;
                        }
                    }
                }
            }
        }
        grid.fill_inside();
        Ok(grid)
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
    fn fill_inside(&mut self) {
        let [nx, ny, nz] = self.dims;
        let mut outside = vec![false; self.occupied.len()];
        let mut stack = Vec::new();
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let border =
                        x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1;
                    let i = self.index(x, y, z);
                    if border && !self.occupied[i] && !outside[i] {
                        outside[i] = true;
                        stack.push((x, y, z));
                    }
                }
            }
        }
        while let Some((x, y, z)) = stack.pop() {
            let mut visit = |x: usize, y: usize, z: usize| {
                let i = (z * ny + y) * nx + x;
                if !self.occupied[i] && !outside[i] {
                    outside[i] = true;
                    stack.push((x, y, z));
                }
            };
            if x > 0 {
                visit(x - 1, y, z);
            }
            if x + 1 < nx {
                visit(x + 1, y, z);
            }
            if y > 0 {
                visit(x, y - 1, z);
            }
            if y + 1 < ny {
                visit(x, y + 1, z);
            }
            if z > 0 {
                visit(x, y, z - 1);
            }
            if z + 1 < nz {
                visit(x, y, z + 1);
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
