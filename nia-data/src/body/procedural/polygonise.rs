//! Marching tetrahedra: the zero set of a sampled field as a closed, outward-oriented triangle
//! mesh.
//!
//! Each grid cube is split into the six tetrahedra of the Freudenthal (Kuhn) triangulation,
//! `(0,0,0) -> e_a -> e_a + e_b -> (1,1,1)` for every axis order `(a, b, c)`, which neighbouring
//! cubes share face for face. Inside is `value < 0`, so no sample lies on the surface and the
//! piecewise-linear zero set is a closed 2-manifold whenever the grid border is outside. One
//! vertex per cut edge (shared through a map keyed by the edge), triangles oriented by integer
//! geometry of the tetrahedron so that normals point from inside to outside.

use std::collections::HashMap;

use glam::Vec3;
use rayon::prelude::*;

/// A regular grid of samples, `dims` points per axis, `x` fastest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Position of sample (0, 0, 0), metres.
    pub origin: Vec3,
    /// Spacing, metres.
    pub step: f32,
    /// Number of samples along x, y, z.
    pub dims: [usize; 3],
}

impl Grid {
    fn index(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    fn point(&self, c: [usize; 3]) -> Vec3 {
        self.origin + Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32) * self.step
    }

    /// Evaluate `field` at every sample, skipping blocks far from the surface: a block of
    /// [`BAND_BLOCK`]^3 samples whose centre value exceeds [`BAND_LIPSCHITZ`] times (its
    /// half-diagonal + one step) cannot hold or touch a sign change, so all its samples take the
    /// centre value (same sign; the magnitude of such samples is never interpolated).
    /// `field` must change by at most [`BAND_LIPSCHITZ`] per metre.
    pub fn sample_band(&self, field: impl Fn(Vec3) -> f32 + Sync) -> Vec<f32> {
        let [nx, ny, nz] = self.dims;
        let mut values = vec![0.0f32; nx * ny * nz];
        if nx * ny == 0 {
            return values;
        }
        let b = BAND_BLOCK;
        let half_diagonal = 0.5 * 3f32.sqrt() * (b - 1) as f32 * self.step;
        let far = BAND_LIPSCHITZ * (half_diagonal + self.step);
        values
            .par_chunks_mut(nx * ny * b)
            .enumerate()
            .for_each(|(bz, slab)| {
                let z0 = bz * b;
                let z1 = (z0 + b).min(nz);
                for y0 in (0..ny).step_by(b) {
                    let y1 = (y0 + b).min(ny);
                    for x0 in (0..nx).step_by(b) {
                        let x1 = (x0 + b).min(nx);
                        let centre =
                            (self.point([x0, y0, z0]) + self.point([x1 - 1, y1 - 1, z1 - 1])) * 0.5;
                        let d = field(centre);
                        let skip = d.abs() > far;
                        for z in z0..z1 {
                            for y in y0..y1 {
                                for x in x0..x1 {
                                    slab[x + nx * (y + ny * (z - z0))] = if skip {
                                        d
                                    } else {
                                        field(self.point([x, y, z]))
                                    };
                                }
                            }
                        }
                    }
                }
            });
        values
    }

    /// Evaluate `field` at every sample (in parallel over z slices).
    pub fn sample(&self, field: impl Fn(Vec3) -> f32 + Sync) -> Vec<f32> {
        let [nx, ny, nz] = self.dims;
        let mut values = vec![0.0f32; nx * ny * nz];
        if nx * ny == 0 {
            return values;
        }
        values
            .par_chunks_mut(nx * ny)
            .enumerate()
            .for_each(|(z, slice)| {
                for y in 0..ny {
                    for x in 0..nx {
                        slice[x + nx * y] = field(self.point([x, y, z]));
                    }
                }
            });
        values
    }
}

/// Edge length, in samples, of the blocks [`Grid::sample_band`] may skip.
pub const BAND_BLOCK: usize = 3;

/// Largest rate of change (per metre) [`Grid::sample_band`] assumes of the field, with margin:
/// exact distances change at 1, the tapered capsules and ellipsoid bounds of the body's
/// implicit surface at up to ~1.1.
pub const BAND_LIPSCHITZ: f32 = 1.5;

/// Axis orders of the six Freudenthal tetrahedra of a cube.
const AXIS_ORDERS: [[usize; 3]; 6] = [
    [0, 1, 2],
    [0, 2, 1],
    [1, 0, 2],
    [1, 2, 0],
    [2, 0, 1],
    [2, 1, 0],
];

/// The zero set of `values` (sampled on `grid`, negative inside) as `(vertices, faces)`,
/// faces counter-clockwise seen from outside. `values.len()` must equal the grid's sample count;
/// otherwise the mesh is empty.
pub fn marching_tetrahedra(grid: &Grid, values: &[f32]) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let [nx, ny, nz] = grid.dims;
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    if values.len() != nx * ny * nz || nx < 2 || ny < 2 || nz < 2 {
        return (vertices, faces);
    }
    let mut edge_vertex: HashMap<u64, u32> = HashMap::new();
    let inside = |c: [usize; 3]| values[grid.index(c)] < 0.0;

    for z in 0..nz - 1 {
        for y in 0..ny - 1 {
            for x in 0..nx - 1 {
                let base = [x, y, z];
                let first = inside(base);
                let mixed = (1..8).any(|i| {
                    inside([x + (i & 1), y + ((i >> 1) & 1), z + ((i >> 2) & 1)]) != first
                });
                if !mixed {
                    continue;
                }
                for order in AXIS_ORDERS {
                    let mut corners = [base; 4];
                    for step in 0..3 {
                        corners[step + 1] = corners[step];
                        corners[step + 1][order[step]] += 1;
                    }
                    emit_tetrahedron(
                        grid,
                        values,
                        &corners,
                        &mut edge_vertex,
                        &mut vertices,
                        &mut faces,
                    );
                }
            }
        }
    }
    (vertices, faces)
}

/// Triangles of one tetrahedron whose corners are ordered componentwise (`corners[i] <=
/// corners[j]` for `i < j`).
fn emit_tetrahedron(
    grid: &Grid,
    values: &[f32],
    corners: &[[usize; 3]; 4],
    edge_vertex: &mut HashMap<u64, u32>,
    vertices: &mut Vec<Vec3>,
    faces: &mut Vec<[u32; 3]>,
) {
    let value = |i: usize| values[grid.index(corners[i])];
    let ins: Vec<usize> = (0..4).filter(|&i| value(i) < 0.0).collect();
    let outs: Vec<usize> = (0..4).filter(|&i| value(i) >= 0.0).collect();
    // Cut edges as (inside corner, outside corner), in cyclic order around the polygon.
    let mut polygon: Vec<(usize, usize)> = match (ins.as_slice(), outs.as_slice()) {
        ([i], [a, b, c]) => vec![(*i, *a), (*i, *b), (*i, *c)],
        ([a, b, c], [o]) => vec![(*a, *o), (*b, *o), (*c, *o)],
        ([i0, i1], [o0, o1]) => vec![(*i0, *o0), (*i0, *o1), (*i1, *o1), (*i1, *o0)],
        _ => return,
    };

    // Orientation from exact integer geometry: doubled edge midpoints, normal against the
    // direction from the inside corners to the outside corners.
    let coord = |i: usize| corners[i].map(|c| c as i64);
    let mid = |(i, o): (usize, usize)| {
        let (a, b) = (coord(i), coord(o));
        [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
    };
    let sub = |a: [i64; 3], b: [i64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross = |a: [i64; 3], b: [i64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let m: Vec<[i64; 3]> = polygon.iter().map(|&e| mid(e)).collect();
    let normal = if m.len() == 3 {
        cross(sub(m[1], m[0]), sub(m[2], m[0]))
    } else {
        cross(sub(m[2], m[0]), sub(m[3], m[1]))
    };
    let sum = |set: &[usize]| {
        set.iter().fold([0i64; 3], |acc, &i| {
            let c = coord(i);
            [acc[0] + c[0], acc[1] + c[1], acc[2] + c[2]]
        })
    };
    let (si, so) = (sum(&ins), sum(&outs));
    let (ni, no) = (ins.len() as i64, outs.len() as i64);
    let dir = [
        so[0] * ni - si[0] * no,
        so[1] * ni - si[1] * no,
        so[2] * ni - si[2] * no,
    ];
    if normal[0] * dir[0] + normal[1] * dir[1] + normal[2] * dir[2] < 0 {
        polygon.reverse();
    }

    let ids: Vec<u32> = polygon
        .iter()
        .map(|&(i, o)| {
            let (lo, hi) = if i < o { (i, o) } else { (o, i) };
            let (a, b) = (corners[lo], corners[hi]);
            let code = (b[0] - a[0]) + 2 * (b[1] - a[1]) + 4 * (b[2] - a[2]);
            let key = grid.index(a) as u64 * 8 + code as u64;
            *edge_vertex.entry(key).or_insert_with(|| {
                let (fa, fb) = (value(lo), value(hi));
                let t = fa / (fa - fb);
                let p = grid.point(a).lerp(grid.point(b), t);
                vertices.push(p);
                (vertices.len() - 1) as u32
            })
        })
        .collect();
    if ids.len() == 3 {
        faces.push([ids[0], ids[1], ids[2]]);
    } else {
        let p = |k: usize| vertices[ids[k] as usize];
        if p(0).distance_squared(p(2)) <= p(1).distance_squared(p(3)) {
            faces.push([ids[0], ids[1], ids[2]]);
            faces.push([ids[0], ids[2], ids[3]]);
        } else {
            faces.push([ids[1], ids[2], ids[3]]);
            faces.push([ids[1], ids[3], ids[0]]);
        }
    }
}

/// A sphere of radius 0.5 m polygonised on a 25^3 grid of 5 cm: the closed test mesh of this
/// module's tests and of [`super::simplify`]'s.
#[cfg(test)]
pub(crate) fn test_sphere() -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let grid = Grid {
        origin: Vec3::splat(-0.6),
        step: 0.05,
        dims: [25, 25, 25],
    };
    let values = grid.sample(|p| p.length() - 0.5);
    marching_tetrahedra(&grid, &values)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::topology::{signed_volume, MeshTopology};

    #[test]
    fn band_sampling_keeps_every_sign_change() {
        let grid = Grid {
            origin: Vec3::new(-0.61, -0.6, -0.59),
            step: 0.03,
            dims: [41, 40, 42],
        };
        let field = |p: Vec3| (p - Vec3::new(0.05, 0.0, -0.02)).length() - 0.37;
        let full = grid.sample(field);
        let band = grid.sample_band(field);
        let signs = |v: &[f32]| v.iter().map(|&x| x < 0.0).collect::<Vec<_>>();
        assert_eq!(signs(&full), signs(&band));
        let skipped = full.iter().zip(&band).filter(|(a, b)| a != b).count();
        assert!(skipped > full.len() / 3, "only {skipped} skipped");
        assert_eq!(
            marching_tetrahedra(&grid, &full),
            marching_tetrahedra(&grid, &band)
        );
    }

    #[test]
    fn sphere_is_closed_oriented_and_has_the_right_volume() {
        let (v, f) = test_sphere();
        let t = MeshTopology::analyse(&f, v.len());
        assert!(
            t.is_closed_manifold() && t.is_consistently_oriented(),
            "{t:?}"
        );
        assert_eq!((t.euler_characteristic, t.components), (2, 1));
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 0.125;
        // The inscribed polyhedron loses a few percent of the volume at this resolution.
        let volume = signed_volume(&v, &f);
        assert!(
            volume > 0.95 * exact && volume < exact,
            "{volume} vs {exact}"
        );
    }
}
