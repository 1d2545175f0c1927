//! What the body volume's tests share: random features and sites, the dense grid of sparse
//! features, and random points in a voxel box.

use nia_data::geometry::sparse::{SiteIndex, VoxelBox};
use nia_data::rng::Rng;

/// Trilinear vs the dense reference: 8 products of O(1) values, weights from the same f32
/// coordinates computed along two formulas (normalise/unnormalise vs direct).
pub const TRILINEAR_TOL: f32 = 1e-4;

/// `n` draws of the standard normal.
pub fn normals(rng: &mut Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.normal()).collect()
}

/// Sites of a `dims` grid, each cell taken with probability `fraction`, in shuffled order.
pub fn random_sites(rng: &mut Rng, dims: [usize; 3], fraction: f32) -> SiteIndex {
    let mut sites = Vec::new();
    for x in 0..dims[0] {
        for y in 0..dims[1] {
            for z in 0..dims[2] {
                if rng.uniform() < fraction {
                    sites.push([x as i32, y as i32, z as i32]);
                }
            }
        }
    }
    // Shuffled order: the rulebooks must not rely on sorted inputs.
    rng.shuffle(&mut sites);
    SiteIndex::new(dims, sites).unwrap()
}

/// A dense `[N, C, X, Y, Z]` grid holding `features` `[N, P, C]` at the sites, zero elsewhere.
pub fn densify(features: &[f32], n: usize, c: usize, sites: &SiteIndex) -> Vec<f32> {
    let [dx, dy, dz] = sites.dims();
    let mut grid = vec![0.0; n * c * dx * dy * dz];
    let p = sites.len();
    for v in 0..n {
        for (s, site) in sites.sites().iter().enumerate() {
            for ch in 0..c {
                let [x, y, z] = site.map(|a| a as usize);
                grid[(((v * c + ch) * dx + x) * dy + y) * dz + z] = features[(v * p + s) * c + ch];
            }
        }
    }
    grid
}

/// `m` points drawn uniformly in `vb` grown by `margin` on every side.
pub fn random_points(rng: &mut Rng, vb: &VoxelBox, m: usize, margin: f32) -> Vec<[f32; 3]> {
    let max = vb.max_m();
    (0..m)
        .map(|_| std::array::from_fn(|a| rng.range(vb.min_m[a] - margin, max[a] + margin)))
        .collect()
}
