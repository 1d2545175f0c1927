//! The band sampler's march: where a ray lies inside the band ([`band_segments`]), in steps of a
//! quarter of the band's cell, with the empty space on either side passed over a cell at a time.

use nia_data::geometry::occupancy::OccupancyGrid;
use nia_data::geometry::rays::RayBundle;

/// The `(t_in, t_out)` segments of ray `r` of `rays` inside `band`, in order, into `segments`:
/// the ray's `step`-long steps from near to far whose middle is occupied, adjacent ones
/// merged.
///
/// The ray is cut into runs of marked and of empty cells first
/// ([`OccupancyGrid::runs_along`], one walk step per cell); a step whose middle lies inside
/// a run by more than a margin takes the run's answer, an empty run's steps passed over at
/// once, and only the steps near a run's ends ask [`OccupancyGrid::occupied`]. The same
/// segments as testing every step (a test compares them bit for bit), with a test for a few
/// steps per run instead of every step.
pub(super) fn band_segments(
    rays: &RayBundle,
    r: usize,
    step: f32,
    band: &OccupancyGrid,
    buffers: &mut BandBuffers,
) {
    let (origin, dir) = (rays.origins[r], rays.dirs[r]);
    let (near, far) = (rays.near[r], rays.far[r]);
    let BandBuffers { segments, runs } = buffers;
    segments.clear();
    band.runs_along(origin, dir, near, far, runs);
    let steps = ((far - near) / step).ceil().max(0.0) as usize;
    let bounds = |k: usize| {
        let a = near + k as f32 * step;
        (a, (a + step).min(far))
    };
    let middle = |k: usize| {
        let (a, b) = bounds(k);
        0.5 * (a + b)
    };
    let add = |k: usize, segments: &mut Vec<(f32, f32)>| {
        let (a, b) = bounds(k);
        match segments.last_mut() {
            Some(last) if last.1 >= a => last.1 = b,
            _ => segments.push((a, b)),
        }
    };
    let test = |k: usize, segments: &mut Vec<(f32, f32)>| {
        if band.occupied(origin + dir * middle(k)) {
            add(k, segments);
        }
    };
    // The walk's bounds are a few ulps of the distances off: middles within this of a run's
    // ends are tested.
    let margin = EMPTY_RUN_MARGIN * band.cell_m() + 1e-5 * near.abs().max(far.abs());
    let mut k = 0;
    for &(t0, t1, marked) in runs.iter() {
        let (lo, hi) = (t0 + margin, t1 - margin);
        if !(lo < hi) {
            continue;
        }
        while k < steps && middle(k) < lo {
            test(k, segments);
            k += 1;
        }
        if marked {
            while k < steps && middle(k) <= hi {
                add(k, segments);
                k += 1;
            }
        } else {
            // Middles are non-decreasing in k: jump near the first past `hi`, then settle.
            let estimate = ((hi - near) / step - 0.5).floor().max(0.0) as usize;
            let mut past = estimate.clamp(k, steps);
            while past > k && middle(past - 1) > hi {
                past -= 1;
            }
            while past < steps && middle(past) <= hi {
                past += 1;
            }
            k = past;
        }
    }
    while k < steps {
        test(k, segments);
        k += 1;
    }
}

/// Middles of band steps within this many cell edges of a run's ends are tested rather than
/// given the run's answer (the walk's rounding is about 1e-6 of a cell).
const EMPTY_RUN_MARGIN: f32 = 1e-3;

/// A band-sampling task's reused buffers: a ray's band segments and its runs of cells.
#[derive(Default)]
pub(super) struct BandBuffers {
    pub(super) segments: Vec<(f32, f32)>,
    pub(super) runs: Vec<(f32, f32, bool)>,
}

/// [`band_segments`] testing every step's middle: the reference the tests compare with.
#[cfg(test)]
fn band_segments_marched(
    rays: &RayBundle,
    r: usize,
    step: f32,
    band: &OccupancyGrid,
    segments: &mut Vec<(f32, f32)>,
) {
    let (near, far) = (rays.near[r], rays.far[r]);
    segments.clear();
    let steps = ((far - near) / step).ceil().max(0.0) as usize;
    for k in 0..steps {
        let a = near + k as f32 * step;
        let b = (a + step).min(far);
        if band.occupied(rays.origins[r] + rays.dirs[r] * (0.5 * (a + b))) {
            match segments.last_mut() {
                Some(last) if last.1 >= a => last.1 = b,
                _ => segments.push((a, b)),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A small deterministic generator (no test depends on a crate's random stream).
    struct Lcg(u64);

    impl Lcg {
        fn unit(&mut self) -> f32 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 40) as f32 / (1u64 << 24) as f32
        }
        fn range(&mut self, lo: f32, hi: f32) -> f32 {
            lo + (hi - lo) * self.unit()
        }
    }

    /// A body-sized band: a few large triangles in a 0.8 x 1.6 x 0.5 m box, 3 cm around them
    /// at 2 cm cells (the quickstart's band).
    fn band(rng: &mut Lcg) -> OccupancyGrid {
        let mut vertices = Vec::new();
        let mut faces = Vec::new();
        for f in 0..12u32 {
            for _ in 0..3 {
                vertices.push(Vec3::new(
                    rng.range(-0.4, 0.4),
                    rng.range(-0.8, 0.8),
                    rng.range(-0.25, 0.25),
                ));
            }
            faces.push([3 * f, 3 * f + 1, 3 * f + 2]);
        }
        OccupancyGrid::build(&vertices, &faces, 0.03, 0.02).unwrap()
    }

    fn dir(rng: &mut Lcg) -> Vec3 {
        Vec3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        )
        .try_normalize()
        .unwrap_or(Vec3::Z)
    }

    #[test]
    fn passing_over_empty_runs_gives_the_segments_of_testing_every_step() {
        let mut rng = Lcg(83);
        let grid = band(&mut rng);
        let mut bundle = RayBundle {
            origins: vec![],
            dirs: vec![],
            near: vec![],
            far: vec![],
            pixels: vec![],
        };
        let mut push = |origin: Vec3, dir: Vec3, near: f32, far: f32| {
            bundle.origins.push(origin);
            bundle.dirs.push(dir);
            bundle.near.push(near);
            bundle.far.push(far);
            bundle.pixels.push(bundle.pixels.len() as u32);
        };
        for _ in 0..3000 {
            // Cameras 2-4 m away looking at points of the body's box.
            let target = Vec3::new(
                rng.range(-0.5, 0.5),
                rng.range(-0.9, 0.9),
                rng.range(-0.3, 0.3),
            );
            let origin = target - dir(&mut rng) * rng.range(2.0, 4.0);
            let d = (target - origin).normalize();
            let near = (target - origin).length() - rng.range(0.2, 1.2);
            push(origin, d, near, near + rng.range(0.1, 2.0));
        }
        for axis in [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z] {
            for _ in 0..200 {
                // Axis-aligned rays (two direction components zero), some on cell boundaries.
                let mut origin = Vec3::new(
                    rng.range(-0.5, 0.5),
                    rng.range(-0.9, 0.9),
                    rng.range(-0.3, 0.3),
                ) - axis * 2.0;
                if rng.unit() < 0.3 {
                    origin = (origin / 0.02).round() * 0.02;
                }
                push(origin, axis, 1.0, 3.0);
            }
        }
        // Rays that start inside the band, miss the grid, or have an empty interval.
        push(Vec3::ZERO, Vec3::X, 0.0, 1.0);
        push(Vec3::new(0.0, 5.0, 0.0), Vec3::X, 0.0, 1.0);
        push(Vec3::new(-3.0, 0.0, 0.0), Vec3::X, 2.0, 2.0);
        let step = grid.cell_m() * 0.25;
        let (mut fast, mut marched) = (BandBuffers::default(), Vec::new());
        let mut crossed = 0;
        for r in 0..bundle.len() {
            band_segments(&bundle, r, step, &grid, &mut fast);
            band_segments_marched(&bundle, r, step, &grid, &mut marched);
            assert_eq!(fast.segments, marched, "ray {r}");
            crossed += usize::from(!marched.is_empty());
        }
        // The set is not all misses: many rays cross the band (1,941 of 4,203).
        assert!(crossed > bundle.len() / 4, "{crossed} of {}", bundle.len());
    }

    #[test]
    fn runs_cover_the_ray_and_agree_with_the_cells_inside_them() {
        let mut rng = Lcg(7);
        let grid = band(&mut rng);
        let mut runs = Vec::new();
        let mut marked = 0;
        for _ in 0..500 {
            let origin = -dir(&mut rng) * 3.0;
            let d =
                (Vec3::new(rng.range(-0.3, 0.3), rng.range(-0.7, 0.7), 0.0) - origin).normalize();
            grid.runs_along(origin, d, 1.0, 5.0, &mut runs);
            // From near to far without gaps, kinds alternating, each run's inside its kind.
            assert_eq!(runs.first().map(|r| r.0), Some(1.0));
            assert_eq!(runs.last().map(|r| r.1), Some(5.0));
            for pair in runs.windows(2) {
                assert!(pair[0].1 == pair[1].0 && pair[0].2 != pair[1].2, "{runs:?}");
            }
            for &(t0, t1, kind) in &runs {
                assert!(t1 > t0, "{runs:?}");
                marked += usize::from(kind);
                for f in [0.1, 0.5, 0.9] {
                    let t = t0 + f * (t1 - t0);
                    let margin = 1e-4;
                    if t - t0 > margin && t1 - t > margin {
                        assert_eq!(grid.occupied(origin + d * t), kind, "t = {t} in {runs:?}");
                    }
                }
            }
        }
        assert!(marked > 100, "{marked} marked runs");
        // A ray far from the grid is one empty run; a non-finite one none.
        grid.runs_along(Vec3::new(0.0, 9.0, 0.0), Vec3::X, 0.0, 2.0, &mut runs);
        assert_eq!(runs, vec![(0.0, 2.0, false)]);
        grid.runs_along(Vec3::NAN, Vec3::X, 0.0, 2.0, &mut runs);
        assert!(runs.is_empty());
    }
}
