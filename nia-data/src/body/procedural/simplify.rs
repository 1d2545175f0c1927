//! Mesh clean-up after marching tetrahedra: shortest-edge-first collapses down to a vertex
//! budget (which also removes the slivers marching tetrahedra leaves near grid samples), then
//! tangential relaxation. Collapses obey the link condition, so a closed 2-manifold stays a
//! closed 2-manifold of the same topology; relaxation moves vertices only.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::Vec3;
use rayon::prelude::*;

/// A collapse is refused if it turns a neighbouring face by more than this (cosine of ~75
/// degrees): a larger turn means the face folds over or becomes a needle.
const MAX_FACE_TURN_COS: f32 = 0.25;

/// Faces with a doubled area below this (m^2) have no meaningful normal to compare (the
/// near-zero-area slivers of marching tetrahedra).
const DEGENERATE_AREA2_M2: f32 = 1e-12;

/// Fraction of the tangential Laplacian step taken per relaxation pass.
const RELAX_RATE: f32 = 0.5;

/// Collapse the shortest edges of a closed manifold mesh until at most `target_vertices`
/// remain (or no edge may be collapsed), merging each pair at its midpoint. Returns the
/// compacted mesh; vertex order follows the input order of the survivors.
pub fn collapse_short_edges(
    mut positions: Vec<Vec3>,
    faces: Vec<[u32; 3]>,
    target_vertices: usize,
) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let n = positions.len();
    let mut faces = faces;
    let mut face_alive = vec![true; faces.len()];
    let mut vertex_faces: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (i, f) in faces.iter().enumerate() {
        for &v in f {
            vertex_faces[v as usize].push(i as u32);
        }
    }
    let mut vertex_alive: Vec<bool> = vertex_faces.iter().map(|f| !f.is_empty()).collect();
    let mut alive = vertex_alive.iter().filter(|&&a| a).count();

    let key = |p: &[Vec3], a: u32, b: u32| {
        Reverse((
            p[a as usize].distance_squared(p[b as usize]).to_bits(),
            a.min(b),
            a.max(b),
        ))
    };
    let mut heap = BinaryHeap::new();
    for f in &faces {
        for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
            if a < b {
                heap.push(key(&positions, a, b));
            }
        }
    }

    let mut nbrs_a = Vec::new();
    let mut nbrs_b = Vec::new();
    while alive > target_vertices.max(4) {
        let Some(Reverse((len_bits, a, b))) = heap.pop() else {
            break;
        };
        let (ai, bi) = (a as usize, b as usize);
        if !vertex_alive[ai] || !vertex_alive[bi] {
            continue;
        }
        if positions[ai].distance_squared(positions[bi]).to_bits() != len_bits {
            continue; // stale: an endpoint moved and a fresh entry was pushed
        }
        vertex_faces[ai].retain(|&f| face_alive[f as usize]);
        vertex_faces[bi].retain(|&f| face_alive[f as usize]);
        let mut shared = [u32::MAX; 2];
        let mut shared_count = 0;
        for &f in &vertex_faces[ai] {
            if faces[f as usize].contains(&b) {
                if shared_count < 2 {
                    shared[shared_count] = f;
                }
                shared_count += 1;
            }
        }
        if shared_count != 2 {
            continue;
        }
        // Link condition: the common neighbours of a and b are exactly the two vertices
        // opposite the edge.
        let opposite = shared.map(|f| {
            faces[f as usize]
                .iter()
                .copied()
                .find(|&v| v != a && v != b)
                .unwrap_or(u32::MAX)
        });
        if opposite[0] == opposite[1] {
            continue;
        }
        neighbours(&faces, &vertex_faces[ai], a, &mut nbrs_a);
        neighbours(&faces, &vertex_faces[bi], b, &mut nbrs_b);
        let common = nbrs_a
            .iter()
            .filter(|v| nbrs_b.binary_search(v).is_ok())
            .count();
        if common != 2 {
            continue;
        }

        let target = (positions[ai] + positions[bi]) * 0.5;
        let turns_too_far = vertex_faces[ai]
            .iter()
            .chain(&vertex_faces[bi])
            .filter(|f| !shared.contains(f))
            .any(|&f| {
                let tri = faces[f as usize];
                let old = tri.map(|v| positions[v as usize]);
                let new = tri.map(|v| {
                    if v == a || v == b {
                        target
                    } else {
                        positions[v as usize]
                    }
                });
                let n0 = (old[1] - old[0]).cross(old[2] - old[0]);
                let n1 = (new[1] - new[0]).cross(new[2] - new[0]);
                n0.length_squared() > DEGENERATE_AREA2_M2 * DEGENERATE_AREA2_M2
                    && n0.dot(n1) <= MAX_FACE_TURN_COS * n0.length() * n1.length()
            });
        if turns_too_far {
            continue;
        }

        for &f in &shared {
            face_alive[f as usize] = false;
        }
        let moved = std::mem::take(&mut vertex_faces[bi]);
        for &f in &moved {
            if shared.contains(&f) {
                continue;
            }
            for v in faces[f as usize].iter_mut() {
                if *v == b {
                    *v = a;
                }
            }
            vertex_faces[ai].push(f);
        }
        vertex_faces[ai].retain(|&f| face_alive[f as usize]);
        vertex_alive[bi] = false;
        positions[ai] = target;
        alive -= 1;
        neighbours(&faces, &vertex_faces[ai], a, &mut nbrs_a);
        for &v in &nbrs_a {
            heap.push(key(&positions, a, v));
        }
    }

    // Compact.
    let mut remap = vec![u32::MAX; n];
    let mut out_positions = Vec::with_capacity(alive);
    for v in 0..n {
        if vertex_alive[v] {
            remap[v] = out_positions.len() as u32;
            out_positions.push(positions[v]);
        }
    }
    let out_faces = faces
        .iter()
        .zip(&face_alive)
        .filter(|(_, &alive)| alive)
        .map(|(f, _)| f.map(|v| remap[v as usize]))
        .collect();
    (out_positions, out_faces)
}

/// Sorted distinct neighbours of `v` through the faces `incident`.
fn neighbours(faces: &[[u32; 3]], incident: &[u32], v: u32, out: &mut Vec<u32>) {
    out.clear();
    for &f in incident {
        out.extend(faces[f as usize].iter().copied().filter(|&u| u != v));
    }
    out.sort_unstable();
    out.dedup();
}

/// `iterations` passes of tangential Laplacian relaxation: each vertex moves part of the way
/// towards the centroid of its neighbours within its tangent plane, then `project` puts it
/// back on the surface. Jacobi updates, so the result does not depend on vertex order.
pub fn relax(
    positions: &mut [Vec3],
    faces: &[[u32; 3]],
    iterations: usize,
    project: impl Fn(Vec3) -> Vec3 + Sync,
) {
    let n = positions.len();
    let mut nbrs: Vec<Vec<u32>> = vec![Vec::new(); n];
    for f in faces {
        for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
            nbrs[a as usize].push(b);
            nbrs[b as usize].push(a);
        }
    }
    for list in &mut nbrs {
        list.sort_unstable();
        list.dedup();
    }
    for _ in 0..iterations {
        let normals = vertex_normals(positions, faces);
        let updated: Vec<Vec3> = (0..n)
            .into_par_iter()
            .map(|v| {
                let p = positions[v];
                if nbrs[v].is_empty() {
                    return p;
                }
                let centroid = nbrs[v].iter().map(|&u| positions[u as usize]).sum::<Vec3>()
                    / nbrs[v].len() as f32;
                let delta = centroid - p;
                let normal = normals[v];
                let tangential = delta - normal * normal.dot(delta);
                project(p + tangential * RELAX_RATE)
            })
            .collect();
        positions.copy_from_slice(&updated);
    }
}

/// Area-weighted vertex normals (unit, zero for isolated vertices).
pub fn vertex_normals(positions: &[Vec3], faces: &[[u32; 3]]) -> Vec<Vec3> {
    let mut normals = vec![Vec3::ZERO; positions.len()];
    for f in faces {
        let [a, b, c] = f.map(|v| positions[v as usize]);
        let n = (b - a).cross(c - a);
        for &v in f {
            normals[v as usize] += n;
        }
    }
    normals.iter().map(|n| n.normalize_or_zero()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::procedural::polygonise::test_sphere;
    use crate::body::topology::MeshTopology;

    #[test]
    fn collapsing_a_sphere_keeps_it_a_sphere() {
        let (v, f) = test_sphere();
        let before = v.len();
        let (mut v, f) = collapse_short_edges(v, f, 400);
        assert!(before > 1000 && v.len() == 400, "{before} -> {}", v.len());
        relax(&mut v, &f, 3, |p| p.normalize() * 0.5);
        let t = MeshTopology::analyse(&f, v.len());
        assert!(
            t.is_closed_manifold() && t.is_consistently_oriented(),
            "{t:?}"
        );
        assert_eq!(t.euler_characteristic, 2);
        assert!(crate::body::topology::signed_volume(&v, &f) > 0.0);
    }
}
