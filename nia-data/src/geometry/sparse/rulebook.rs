//! Sparse convolution rulebooks: for a set of active sites and a 3x3x3 kernel, the list of
//! (input site, output site) pairs of every kernel offset. Built once per frame on the CPU and
//! shared by all N views (the sites are the same for every view).
//!
//! Kernel offset `k = (a * 3 + b) * 3 + c` with `a, b, c` in `0..3` the kernel index along
//! x, y, z, the same order as a dense `Conv3d` weight `[C_out, C_in, 3, 3, 3]` applied to a
//! grid laid out `[.., X, Y, Z]`. An output at `o` reads the input at
//! - submanifold (stride 1, padding 1, outputs = inputs): `o + (a - 1, b - 1, c - 1)`;
//! - strided (spconv `SparseConv3d(.., 3, stride 2, padding 1)`): `2 o - 1 + (a, b, c)`, and
//!   the outputs are every coarse voxel inside the coarse grid that some input reaches.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::{Arc, OnceLock};

use super::neighbour_maps::NeighbourMaps;
use super::voxelize::{strided_dim, MAX_GRID_DIM};
use super::SparseGridError;

/// Number of offsets of a 3x3x3 kernel.
pub const KERNEL_VOLUME: usize = 27;

/// The integer offset `(a - 1, b - 1, c - 1)` of kernel offset `k` (0..27).
pub fn kernel_offset(k: usize) -> [i32; 3] {
    [
        (k / 9) as i32 - 1,
        ((k / 3) % 3) as i32 - 1,
        (k % 3) as i32 - 1,
    ]
}

/// A fast hasher for packed voxel keys (a 64-bit finaliser; the keys are not adversarial).
#[derive(Default, Clone, Copy)]
struct VoxelKeyHasher(u64);

impl Hasher for VoxelKeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }

    fn write_u64(&mut self, x: u64) {
        // MurmurHash3's fmix64 mixes every input bit into the low and high bits.
        let mut h = self.0 ^ x;
        h ^= h >> 33;
        h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
        h ^= h >> 33;
        h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
        h ^= h >> 33;
        self.0 = h;
    }
}

type VoxelMap = HashMap<u64, u32, BuildHasherDefault<VoxelKeyHasher>>;

/// The active sites of one grid level and a lookup from voxel coordinates to site index.
#[derive(Debug, Clone)]
pub struct SiteIndex {
    /// [3] voxels of the grid along x, y, z.
    dims: [usize; 3],
    /// [P, 3] integer voxel coordinates of the sites, in site order.
    sites: Vec<[i32; 3]>,
    /// Packed coordinates -> site index.
    map: VoxelMap,
}

impl SiteIndex {
    /// Indexes `sites` ([P, 3], each inside `0..dims`, no duplicates); site `i` is `sites[i]`.
    pub fn new(dims: [usize; 3], sites: Vec<[i32; 3]>) -> Result<Self, SparseGridError> {
        if dims.iter().any(|&d| d == 0 || d > MAX_GRID_DIM) {
            return Err(SparseGridError::invalid(
                "SiteIndex dims",
                format!("between 1 and {MAX_GRID_DIM} voxels per axis"),
                dims,
            ));
        }
        if sites.len() >= u32::MAX as usize {
            return Err(SparseGridError::invalid(
                "SiteIndex sites",
                "fewer than 2^32 - 1 sites",
                sites.len(),
            ));
        }
        let mut map = VoxelMap::with_capacity_and_hasher(sites.len(), Default::default());
        for (i, c) in sites.iter().enumerate() {
            let key = pack(dims, *c).ok_or_else(|| {
                SparseGridError::invalid(
                    "SiteIndex sites",
                    format!("coordinates inside the grid 0..{dims:?} (site {i})"),
                    c,
                )
            })?;
            if map.insert(key, i as u32).is_some() {
                return Err(SparseGridError::invalid(
                    "SiteIndex sites",
                    format!("unique coordinates (site {i} repeats an earlier one)"),
                    c,
                ));
            }
        }
        Ok(SiteIndex { dims, sites, map })
    }

    /// The site at voxel `c`, or `None` when `c` is inactive or outside the grid.
    #[inline]
    pub fn get(&self, c: [i32; 3]) -> Option<u32> {
        pack(self.dims, c).and_then(|k| self.map.get(&k).copied())
    }

    /// Number of active sites P.
    pub fn len(&self) -> usize {
        self.sites.len()
    }

    /// Whether there is no active site.
    pub fn is_empty(&self) -> bool {
        self.sites.is_empty()
    }

    /// [P, 3] the coordinates of the sites.
    pub fn sites(&self) -> &[[i32; 3]] {
        &self.sites
    }

    /// [3] voxels of the grid along x, y, z.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }
}

/// Packs in-grid coordinates into one key (21 bits per axis; x most significant, so keys sort
/// like linear indices), `None` outside `0..dims`.
#[inline]
fn pack(dims: [usize; 3], c: [i32; 3]) -> Option<u64> {
    let mut key = 0u64;
    for a in 0..3 {
        if c[a] < 0 || c[a] as usize >= dims[a] {
            return None;
        }
        key = (key << 21) | c[a] as u64;
    }
    Some(key)
}

fn unpack(key: u64) -> [i32; 3] {
    let mask = (1u64 << 21) - 1;
    [
        ((key >> 42) & mask) as i32,
        ((key >> 21) & mask) as i32,
        (key & mask) as i32,
    ]
}

/// Which convolution a rulebook serves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RulebookKind {
    /// Stride 1, padding 1, outputs at the input sites (spconv `SubMConv3d`).
    Submanifold,
    /// Stride 2, padding 1 (spconv `SparseConv3d(.., 3, 2, padding=1)`).
    Strided,
}

/// The (input, output) site pairs of a 3x3x3 sparse convolution, grouped by kernel offset:
/// group `k` is `in_index[group_start[k]..group_start[k + 1]]` (and the same range of
/// `out_index`), `out[out_index[t]] += in[in_index[t]] @ W[k]`. Within a group, pairs are sorted
/// by output site (submanifold) or input site (strided); every (output, offset) appears at
/// most once.
#[derive(Debug, Clone)]
pub struct Rulebook {
    pub kind: RulebookKind,
    /// Number of input sites P_in.
    pub n_in: usize,
    /// Number of output sites P_out.
    pub n_out: usize,
    /// [T] input site of every pair.
    pub in_index: Vec<u32>,
    /// [T] output site of every pair.
    pub out_index: Vec<u32>,
    /// [28] start of every offset's group, `group_start[27] = T`.
    pub group_start: [usize; KERNEL_VOLUME + 1],
    /// [`Self::neighbour_maps`], built on first use (clones made after share them).
    maps: OnceLock<Arc<NeighbourMaps>>,
}

/// Rulebooks are equal when their pairs are: whether the maps were built yet does not count.
impl PartialEq for Rulebook {
    fn eq(&self, other: &Self) -> bool {
        (self.kind, self.n_in, self.n_out, self.group_start)
            == (other.kind, other.n_in, other.n_out, other.group_start)
            && self.in_index == other.in_index
            && self.out_index == other.out_index
    }
}

impl Eq for Rulebook {}

impl Rulebook {
    /// Total number of pairs T.
    pub fn num_pairs(&self) -> usize {
        self.in_index.len()
    }

    /// The (input, output) pairs of kernel offset `k`.
    pub fn pairs(&self, k: usize) -> impl Iterator<Item = (u32, u32)> + '_ {
        let r = self.group_start[k]..self.group_start[k + 1];
        self.in_index[r.clone()]
            .iter()
            .copied()
            .zip(self.out_index[r].iter().copied())
    }

    /// [P_out * 27] the input site read by output `o` at offset `k` at `o * 27 + k`, or `n_in`
    /// where that input is inactive (the index of an appended zero row).
    pub fn neighbour_map(&self) -> Vec<u32> {
        let mut map = vec![self.n_in as u32; self.n_out * KERNEL_VOLUME];
        for k in 0..KERNEL_VOLUME {
            for (i, o) in self.pairs(k) {
                map[o as usize * KERNEL_VOLUME + k] = i;
            }
        }
        map
    }

    /// The neighbour map and its inverse ([`NeighbourMaps`]), built the first time they are
    /// asked for and kept.
    pub fn neighbour_maps(&self) -> Arc<NeighbourMaps> {
        self.maps
            .get_or_init(|| Arc::new(NeighbourMaps::new(self)))
            .clone()
    }

    /// [`Self::neighbour_maps`] if they were built, without building them.
    pub fn built_neighbour_maps(&self) -> Option<Arc<NeighbourMaps>> {
        self.maps.get().cloned()
    }

    /// Fraction of the `P_out * 27` (output, offset) slots that have an input, in [0, 1].
    pub fn fill_ratio(&self) -> f64 {
        if self.n_out == 0 {
            return 0.0;
        }
        self.num_pairs() as f64 / (self.n_out * KERNEL_VOLUME) as f64
    }

    /// The submanifold rulebook of `sites`: outputs = inputs, output `o` reads the active
    /// neighbours `o + (a - 1, b - 1, c - 1)`.
    pub fn submanifold(sites: &SiteIndex) -> Rulebook {
        let mut in_index = Vec::new();
        let mut out_index = Vec::new();
        let mut group_start = [0usize; KERNEL_VOLUME + 1];
        for (k, start) in group_start[..KERNEL_VOLUME].iter_mut().enumerate() {
            *start = in_index.len();
            let d = kernel_offset(k);
            for (o, c) in sites.sites().iter().enumerate() {
                if let Some(i) = sites.get([c[0] + d[0], c[1] + d[1], c[2] + d[2]]) {
                    in_index.push(i);
                    out_index.push(o as u32);
                }
            }
        }
        group_start[KERNEL_VOLUME] = in_index.len();
        Rulebook {
            kind: RulebookKind::Submanifold,
            n_in: sites.len(),
            n_out: sites.len(),
            in_index,
            out_index,
            group_start,
            maps: OnceLock::new(),
        }
    }

    /// The strided rulebook of `sites` and the coarse output sites (every voxel of the coarse
    /// grid, `floor((D - 1) / 2) + 1` per axis, that some input reaches through the kernel,
    /// sorted by linear index). Input `i` reaches output `o = (i + 1 - (a, b, c)) / 2` where that
    /// is an integer inside the coarse grid.
    pub fn strided(sites: &SiteIndex) -> Result<(SiteIndex, Rulebook), SparseGridError> {
        let dims_out = sites.dims().map(strided_dim);
        let reach = |c: [i32; 3], k: usize| -> Option<u64> {
            let d = kernel_offset(k);
            let mut o = [0i32; 3];
            for a in 0..3 {
                // (i + 1 - kernel index) with kernel index = d + 1, i.e. i - d.
                let num = c[a] - d[a];
                if num.rem_euclid(2) != 0 {
                    return None;
                }
                o[a] = num.div_euclid(2);
            }
            pack(dims_out, o)
        };
        let mut keys: Vec<u64> = Vec::with_capacity(sites.len() * 8);
        for c in sites.sites() {
            for k in 0..KERNEL_VOLUME {
                if let Some(key) = reach(*c, k) {
                    keys.push(key);
                }
            }
        }
        keys.sort_unstable();
        keys.dedup();
        let out_sites = SiteIndex::new(dims_out, keys.iter().map(|&k| unpack(k)).collect())?;
        let mut in_index = Vec::new();
        let mut out_index = Vec::new();
        let mut group_start = [0usize; KERNEL_VOLUME + 1];
        for (k, start) in group_start[..KERNEL_VOLUME].iter_mut().enumerate() {
            *start = in_index.len();
            for (i, c) in sites.sites().iter().enumerate() {
                if let Some(key) = reach(*c, k) {
                    // Every reached key is an output site by construction.
                    if let Some(&o) = out_sites.map.get(&key) {
                        in_index.push(i as u32);
                        out_index.push(o);
                    }
                }
            }
        }
        group_start[KERNEL_VOLUME] = in_index.len();
        let rulebook = Rulebook {
            kind: RulebookKind::Strided,
            n_in: sites.len(),
            n_out: out_sites.len(),
            in_index,
            out_index,
            group_start,
            maps: OnceLock::new(),
        };
        Ok((out_sites, rulebook))
    }
}
