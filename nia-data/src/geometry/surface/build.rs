//! The BVH's build: binned SAH splits over the triangles' centroids (the median where SAH
//! finds none or the tree is deep), into the flat node array [`super::SurfaceIndex`] walks.

use glam::Vec3;

use super::Node;

/// Triangles per leaf: small leaves prune better, large ones amortise the box tests; 4 is the
/// usual sweet spot for closest-point queries.
const MAX_LEAF: usize = 4;

/// SAH bins per axis.
const SAH_BINS: usize = 16;

/// Below this depth splits use SAH; deeper (rare, very unbalanced inputs) they use the median,
/// which halves the count, so the tree depth stays below [`super::STACK_DEPTH`] for any F < 2^31.
const SAH_MAX_DEPTH: usize = 30;

/// Per-triangle build record.
#[derive(Debug, Clone, Copy)]
pub(super) struct BuildRef {
    pub(super) min: Vec3,
    pub(super) max: Vec3,
    pub(super) centroid: Vec3,
}

/// Builds the flat BVH, reordering `order` into leaf order. Root is node 0.
pub(super) fn build(refs: &[BuildRef], order: &mut [u32]) -> Vec<Node> {
    let mut nodes = Vec::with_capacity(2 * refs.len().div_ceil(MAX_LEAF) + 1);
    nodes.push(Node {
        min: Vec3::ZERO,
        index: 0,
        max: Vec3::ZERO,
        count: 0,
    });
    // (node, start, end, depth)
    let mut tasks = vec![(0usize, 0usize, order.len(), 0usize)];
    while let Some((ni, start, end, depth)) = tasks.pop() {
        let range = &mut order[start..end];
        let (mut bmin, mut bmax) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let (mut cmin, mut cmax) = (bmin, bmax);
        for &t in range.iter() {
            let r = &refs[t as usize];
            bmin = bmin.min(r.min);
            bmax = bmax.max(r.max);
            cmin = cmin.min(r.centroid);
            cmax = cmax.max(r.centroid);
        }
        nodes[ni].min = bmin;
        nodes[ni].max = bmax;
        let count = end - start;
        if count <= MAX_LEAF {
            nodes[ni].index = start as u32;
            nodes[ni].count = count as u32;
            continue;
        }
        let split = if depth < SAH_MAX_DEPTH {
            sah_split(refs, range, cmin, cmax)
        } else {
            None
        }
        .unwrap_or_else(|| median_split(refs, range, cmin, cmax));
        let mid = start + split;
        let left = nodes.len();
        for _ in 0..2 {
            nodes.push(Node {
                min: Vec3::ZERO,
                index: 0,
                max: Vec3::ZERO,
                count: 0,
            });
        }
        nodes[ni].index = left as u32;
        nodes[ni].count = 0;
        tasks.push((left + 1, mid, end, depth + 1));
        tasks.push((left, start, mid, depth + 1));
    }
    nodes
}

fn surface_area(min: Vec3, max: Vec3) -> f32 {
    let e = (max - min).max(Vec3::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// Binned SAH over the three axes; partitions `range` and returns the split position (both
/// sides non-empty), or `None` if no bin boundary separates the centroids.
fn sah_split(refs: &[BuildRef], range: &mut [u32], cmin: Vec3, cmax: Vec3) -> Option<usize> {
    #[derive(Clone, Copy)]
    struct Bin {
        min: Vec3,
        max: Vec3,
        count: usize,
    }
    let empty = Bin {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
        count: 0,
    };
    let extent = cmax - cmin;
    let mut best: Option<(f32, usize, usize)> = None; // (cost, axis, bins left of the split)
    for axis in 0..3 {
        if !(extent[axis] > 0.0) {
            continue;
        }
        let scale = SAH_BINS as f32 / extent[axis];
        let bin_of = |c: f32| (((c - cmin[axis]) * scale) as usize).min(SAH_BINS - 1);
        let mut bins = [empty; SAH_BINS];
        for &t in range.iter() {
            let r = &refs[t as usize];
            let b = &mut bins[bin_of(r.centroid[axis])];
            b.min = b.min.min(r.min);
            b.max = b.max.max(r.max);
            b.count += 1;
        }
        // Suffix sweeps: right side areas and counts for each split k (left = bins[..k]).
        let mut right_area = [0.0f32; SAH_BINS];
        let mut right_count = [0usize; SAH_BINS];
        let mut acc = empty;
        for k in (1..SAH_BINS).rev() {
            acc.min = acc.min.min(bins[k].min);
            acc.max = acc.max.max(bins[k].max);
            acc.count += bins[k].count;
            right_area[k] = surface_area(acc.min, acc.max);
            right_count[k] = acc.count;
        }
        let mut acc = empty;
        for k in 1..SAH_BINS {
            acc.min = acc.min.min(bins[k - 1].min);
            acc.max = acc.max.max(bins[k - 1].max);
            acc.count += bins[k - 1].count;
            if acc.count == 0 || right_count[k] == 0 {
                continue;
            }
            let cost = acc.count as f32 * surface_area(acc.min, acc.max)
                + right_count[k] as f32 * right_area[k];
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, k));
            }
        }
    }
    let (_, axis, k) = best?;
    let scale = SAH_BINS as f32 / extent[axis];
    let bin_of = |c: f32| (((c - cmin[axis]) * scale) as usize).min(SAH_BINS - 1);
    // In-place partition: bins < k to the left.
    let mut i = 0;
    let mut j = range.len();
    while i < j {
        if bin_of(refs[range[i] as usize].centroid[axis]) < k {
            i += 1;
        } else {
            j -= 1;
            range.swap(i, j);
        }
    }
    (i > 0 && i < range.len()).then_some(i)
}

/// Splits at the median centroid along the widest centroid axis (any split when they coincide).
fn median_split(refs: &[BuildRef], range: &mut [u32], cmin: Vec3, cmax: Vec3) -> usize {
    let extent = cmax - cmin;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let mid = range.len() / 2;
    range.select_nth_unstable_by(mid, |a, b| {
        refs[*a as usize].centroid[axis].total_cmp(&refs[*b as usize].centroid[axis])
    });
    mid
}
