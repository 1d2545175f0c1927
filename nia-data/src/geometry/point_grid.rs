//! Exact nearest-neighbour queries over a set of 2D points (pixels), bucketed in a uniform
//! grid: what the SMPL alignment asks for every mask boundary pixel (the projected vertex
//! nearest to it) at every evaluation of its energy.
//!
//! A query scans the grid's cells in square rings of growing index distance `r` around its
//! cell (the nearest cell when it lies outside the grid) and stops once the best distance is at
//! most `r * cell`: every point of ring `r + 1` is at least that far along one axis.

use glam::Vec2;

/// Points bucketed by cell (a counting sort of their indices).
#[derive(Debug, Clone)]
pub struct PointGrid {
    cell: f32,
    origin: Vec2,
    nx: usize,
    ny: usize,
    /// `[nx * ny + 1]` offsets into `items` per cell, row-major.
    starts: Vec<u32>,
    /// `[P]` point indices, cell by cell.
    items: Vec<u32>,
    /// `[P]` the points.
    points: Vec<Vec2>,
}

impl PointGrid {
    /// The finite ones of `points` (others are never returned) in cells of `cell` pixels
    /// (> 0). Indices returned by [`Self::nearest`] are into `points`.
    pub fn new(points: &[Vec2], cell: f32) -> Self {
        let cell = if cell > 0.0 && cell.is_finite() {
            cell
        } else {
            1.0
        };
        let finite = points.iter().filter(|p| p.is_finite());
        let (lo, hi) = finite.fold((Vec2::MAX, Vec2::MIN), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        });
        let (origin, nx, ny) = if lo.x <= hi.x {
            let n = ((hi - lo) / cell).floor();
            (lo, n.x as usize + 1, n.y as usize + 1)
        } else {
            (Vec2::ZERO, 1, 1)
        };
        let cell_of = |p: Vec2| -> Option<usize> {
            p.is_finite().then(|| {
                let c = ((p - origin) / cell).floor();
                let (x, y) = ((c.x as usize).min(nx - 1), (c.y as usize).min(ny - 1));
                y * nx + x
            })
        };
        let mut starts = vec![0u32; nx * ny + 1];
        for p in points {
            if let Some(c) = cell_of(*p) {
                starts[c + 1] += 1;
            }
        }
        for c in 0..nx * ny {
            starts[c + 1] += starts[c];
        }
        let mut fill = starts.clone();
        let mut items = vec![0u32; starts[nx * ny] as usize];
        for (i, p) in points.iter().enumerate() {
            if let Some(c) = cell_of(*p) {
                items[fill[c] as usize] = i as u32;
                fill[c] += 1;
            }
        }
        PointGrid {
            cell,
            origin,
            nx,
            ny,
            starts,
            items,
            points: points.to_vec(),
        }
    }

    /// The index of the point nearest to `q` (the first of equals in cell order), `None` when
    /// the grid holds no finite point or `q` is not finite.
    pub fn nearest(&self, q: Vec2) -> Option<usize> {
        if self.items.is_empty() || !q.is_finite() {
            return None;
        }
        let c = ((q - self.origin) / self.cell).floor();
        let clamp = |v: f32, n: usize| v.clamp(0.0, (n - 1) as f32) as i64;
        let (qx, qy) = (clamp(c.x, self.nx), clamp(c.y, self.ny));
        let (nx, ny) = (self.nx as i64, self.ny as i64);
        let mut best: Option<(f32, usize)> = None;
        let max_r = nx.max(ny);
        for r in 0..=max_r {
            // Rings 0..r have been scanned: ring r's points are at least (r - 1) cells away.
            if let Some((d2, _)) = best {
                if r >= 1 && d2 <= ((r - 1) as f32 * self.cell).powi(2) {
                    break;
                }
            }
            for y in (qy - r).max(0)..=(qy + r).min(ny - 1) {
                let mut scan = |x: i64| {
                    let c = (y * nx + x) as usize;
                    for &i in &self.items[self.starts[c] as usize..self.starts[c + 1] as usize] {
                        let d2 = (self.points[i as usize] - q).length_squared();
                        if best.is_none_or(|(b, _)| d2 < b) {
                            best = Some((d2, i as usize));
                        }
                    }
                };
                if (y - qy).abs() == r {
                    // The ring's top or bottom row: every cell of it.
                    ((qx - r).max(0)..=(qx + r).min(nx - 1)).for_each(&mut scan);
                } else {
                    // A row between: the ring's left and right cells (r >= 1, so two).
                    [qx - r, qx + r]
                        .into_iter()
                        .filter(|&x| x >= 0 && x < nx)
                        .for_each(&mut scan);
                }
            }
        }
        best.map(|(_, i)| i)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn brute(points: &[Vec2], q: Vec2) -> Option<f32> {
        points
            .iter()
            .filter(|p| p.is_finite())
            .map(|p| (*p - q).length_squared())
            .min_by(f32::total_cmp)
    }

    #[test]
    fn nearest_is_the_brute_force_nearest() {
        let mut rng = Rng::new(3);
        for (n, cell) in [(1usize, 4.0f32), (7, 0.5), (300, 4.0), (300, 50.0)] {
            let mut points: Vec<Vec2> = (0..n)
                .map(|_| Vec2::new(rng.range(20.0, 90.0), rng.range(10.0, 40.0)))
                .collect();
            points.push(Vec2::NAN);
            let grid = PointGrid::new(&points, cell);
            for _ in 0..2000 {
                // Queries inside, around and far outside the points' box.
                let q = Vec2::new(rng.range(-100.0, 200.0), rng.range(-100.0, 150.0));
                let got = grid.nearest(q).unwrap();
                let d = (points[got] - q).length_squared();
                assert_eq!(Some(d), brute(&points, q), "{n} points, cell {cell}, {q}");
            }
        }
    }

    #[test]
    fn no_finite_point_or_query_finds_nothing() {
        assert_eq!(PointGrid::new(&[], 4.0).nearest(Vec2::ZERO), None);
        assert_eq!(PointGrid::new(&[Vec2::NAN], 4.0).nearest(Vec2::ZERO), None);
        let grid = PointGrid::new(&[Vec2::ONE], 4.0);
        assert_eq!(grid.nearest(Vec2::NAN), None);
        assert_eq!(grid.nearest(Vec2::new(-1e6, 1e6)), Some(0));
    }
}
