//! Combinatorial checks of a triangle mesh: closed (watertight), 2-manifold, consistently
//! oriented, connected, Euler characteristic; and its signed volume (outward orientation).

use std::collections::HashMap;

use glam::Vec3;

/// What [`MeshTopology::analyse`] found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MeshTopology {
    /// Vertices referenced by at least one face.
    pub used_vertices: usize,
    /// Faces, including degenerate ones.
    pub faces: usize,
    /// Faces that repeat a vertex index.
    pub degenerate_faces: usize,
    /// Distinct undirected edges.
    pub edges: usize,
    /// Edges with exactly one face (holes).
    pub boundary_edges: usize,
    /// Edges with three or more faces.
    pub non_manifold_edges: usize,
    /// Directed edges used by more than one face (neighbouring faces disagree on orientation).
    pub inconsistent_edges: usize,
    /// Vertices whose incident faces do not form a single fan (a closed fan for a closed mesh).
    pub non_manifold_vertices: usize,
    /// Connected components (through shared vertices).
    pub components: usize,
    /// `V - E + F` over used vertices; 2 for one closed genus-0 surface.
    pub euler_characteristic: i64,
}

impl MeshTopology {
    /// Analyse `faces` over `num_vertices` vertices (indices out of range count as degenerate).
    pub fn analyse(faces: &[[u32; 3]], num_vertices: usize) -> Self {
        let mut degenerate_faces = 0;
        let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
        let mut incident: Vec<Vec<(u32, u32)>> = vec![Vec::new(); num_vertices];
        let mut parent: Vec<usize> = (0..num_vertices).collect();
        let mut good_faces = 0usize;
        for f in faces {
            let [a, b, c] = *f;
            if a == b || b == c || a == c || f.iter().any(|&i| i as usize >= num_vertices) {
                degenerate_faces += 1;
                continue;
            }
            good_faces += 1;
            for (x, y, z) in [(a, b, c), (b, c, a), (c, a, b)] {
                *directed.entry((x, y)).or_insert(0) += 1;
                incident[x as usize].push((y, z));
            }
            union(&mut parent, a as usize, b as usize);
            union(&mut parent, a as usize, c as usize);
        }
        let mut undirected: HashMap<(u32, u32), u32> = HashMap::new();
        let mut inconsistent_edges = 0;
        for (&(x, y), &n) in &directed {
            if n > 1 {
                inconsistent_edges += 1;
            }
            *undirected.entry((x.min(y), x.max(y))).or_insert(0) += n;
        }
        let boundary_edges = undirected.values().filter(|&&n| n == 1).count();
        let non_manifold_edges = undirected.values().filter(|&&n| n > 2).count();
        let used: Vec<usize> = (0..num_vertices)
            .filter(|&v| !incident[v].is_empty())
            .collect();
        let non_manifold_vertices = used
            .iter()
            .filter(|&&v| !is_single_fan(&incident[v]))
            .count();
        let mut roots: Vec<usize> = used.iter().map(|&v| find(&mut parent, v)).collect();
        roots.sort_unstable();
        roots.dedup();
        MeshTopology {
            used_vertices: used.len(),
            faces: faces.len(),
            degenerate_faces,
            edges: undirected.len(),
            boundary_edges,
            non_manifold_edges,
            inconsistent_edges,
            non_manifold_vertices,
            components: roots.len(),
            euler_characteristic: used.len() as i64 - undirected.len() as i64 + good_faces as i64,
        }
    }

    /// Closed 2-manifold: no holes, no non-manifold edges or vertices, no degenerate faces.
    pub fn is_closed_manifold(&self) -> bool {
        self.degenerate_faces == 0
            && self.boundary_edges == 0
            && self.non_manifold_edges == 0
            && self.non_manifold_vertices == 0
    }

    /// Every edge is used once in each direction by its two faces.
    pub fn is_consistently_oriented(&self) -> bool {
        self.inconsistent_edges == 0
    }
}

/// Whether the link of a vertex, given as the edges opposite to it in its faces, is one
/// connected chain or cycle in which every link vertex has degree at most 2.
fn is_single_fan(link: &[(u32, u32)]) -> bool {
    let mut degree: HashMap<u32, u32> = HashMap::new();
    for &(a, b) in link {
        *degree.entry(a).or_insert(0) += 1;
        *degree.entry(b).or_insert(0) += 1;
    }
    if degree.values().any(|&d| d > 2) {
        return false;
    }
    // Connected: walk from the first edge through shared link vertices.
    let mut seen = vec![false; link.len()];
    let mut stack = vec![0usize];
    seen[0] = true;
    let mut count = 1;
    while let Some(i) = stack.pop() {
        let (a, b) = link[i];
        for (j, &(c, d)) in link.iter().enumerate() {
            if !seen[j] && (c == a || c == b || d == a || d == b) {
                seen[j] = true;
                count += 1;
                stack.push(j);
            }
        }
    }
    count == link.len()
}

fn find(parent: &mut [usize], mut x: usize) -> usize {
    while parent[x] != x {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    x
}

fn union(parent: &mut [usize], a: usize, b: usize) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        parent[ra.max(rb)] = ra.min(rb);
    }
}

/// Signed volume enclosed by a closed mesh (m^3 for metres), positive when the faces are
/// counter-clockwise seen from outside (normals outward). Accumulated in f64.
pub fn signed_volume(vertices: &[Vec3], faces: &[[u32; 3]]) -> f64 {
    faces
        .iter()
        .filter_map(|f| {
            let a = vertices.get(f[0] as usize)?.as_dvec3();
            let b = vertices.get(f[1] as usize)?.as_dvec3();
            let c = vertices.get(f[2] as usize)?.as_dvec3();
            Some(a.dot(b.cross(c)) / 6.0)
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube, 12 triangles, normals outward.
    fn cube() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let v = (0..8)
            .map(|i| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32))
            .collect();
        let quads = [
            [0, 2, 3, 1], // z = 0, normal -z
            [4, 5, 7, 6], // z = 1, normal +z
            [0, 1, 5, 4], // y = 0, normal -y
            [2, 6, 7, 3], // y = 1, normal +y
            [0, 4, 6, 2], // x = 0, normal -x
            [1, 3, 7, 5], // x = 1, normal +x
        ];
        let f = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        (v, f)
    }

    #[test]
    fn cube_is_a_closed_oriented_sphere() {
        let (v, f) = cube();
        let t = MeshTopology::analyse(&f, v.len());
        assert!(
            t.is_closed_manifold() && t.is_consistently_oriented(),
            "{t:?}"
        );
        assert_eq!((t.euler_characteristic, t.components, t.edges), (2, 1, 18));
        assert!((signed_volume(&v, &f) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn holes_flips_and_pinches_are_reported() {
        let (v, mut f) = cube();
        f.pop();
        let open = MeshTopology::analyse(&f, v.len());
        assert_eq!(open.boundary_edges, 3);
        assert!(!open.is_closed_manifold());

        let (v, mut f) = cube();
        f[0].swap(1, 2);
        let flipped = MeshTopology::analyse(&f, v.len());
        assert!(flipped.is_closed_manifold() && !flipped.is_consistently_oriented());

        // Two cubes sharing one vertex: every edge has two faces, but the shared vertex has two
        // separate fans.
        let (mut v2, mut f2) = cube();
        let shift = v2.len() as u32 - 1;
        v2.extend(cube().0.iter().skip(1).map(|p| *p + Vec3::ONE));
        f2.extend(
            cube()
                .1
                .iter()
                .map(|t| t.map(|i| if i == 0 { 7 } else { i + shift })),
        );
        let pinched = MeshTopology::analyse(&f2, v2.len());
        assert_eq!(pinched.boundary_edges + pinched.non_manifold_edges, 0);
        assert_eq!(pinched.non_manifold_vertices, 1);
        assert!(!pinched.is_closed_manifold());
    }
}
