//! The band sampler: every sample lies in the band, the intervals add up to the band's length
//! along the ray, a ray that misses the band is not evaluated, and the band quadrature of a
//! density that is constant in the band and zero elsewhere gives the analytic opacity.

mod common;

use common::{device, tensor, values};
use glam::Vec3;
use nia_data::geometry::occupancy::OccupancyGrid;
use nia_data::geometry::rays::{Ray, RayBundle};
use nia_model::renderer::{render_rays, render_rays_delta};
use nia_model::sampler::{RaySampler, RaySamples};

/// A closed octahedron of "radius" 0.2 m around the origin (a body stand-in).
fn octahedron() -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let r = 0.2;
    let v = vec![
        Vec3::new(r, 0.0, 0.0),
        Vec3::new(-r, 0.0, 0.0),
        Vec3::new(0.0, r, 0.0),
        Vec3::new(0.0, -r, 0.0),
        Vec3::new(0.0, 0.0, r),
        Vec3::new(0.0, 0.0, -r),
    ];
    // Around the equator (+x, +y, -x, -y), each edge with the top (+z) and the bottom (-z)
    // apex, wound outwards.
    let ring = [(0, 2), (2, 1), (1, 3), (3, 0)];
    let top = ring.map(|(a, b)| [a, b, 4]);
    let bottom = ring.map(|(a, b)| [b, a, 5]);
    (v, [top, bottom].concat())
}

/// Rays along +z from z = -1, at lateral offsets `xs`, over t in [0, 2].
fn rays(xs: &[f32]) -> RayBundle {
    let mut bundle = RayBundle::default();
    for (i, &x) in xs.iter().enumerate() {
        let ray = Ray {
            origin: Vec3::new(x, 0.01, -1.0),
            dir: Vec3::Z,
        };
        bundle.push(ray, 0.0, 2.0, i as u32);
    }
    bundle
}

fn band() -> OccupancyGrid {
    let (v, f) = octahedron();
    let sampler = RaySampler::Band {
        margin_m: 0.05,
        cell_m: 0.02,
    };
    match sampler.band(&v, &f).unwrap() {
        Some(grid) => (*grid).clone(),
        None => panic!("a band sampler builds a grid"),
    }
}

#[test]
fn band_samples_lie_in_the_band_and_their_intervals_cover_it() {
    let grid = band();
    let bundle = rays(&[0.0, 0.1, 0.9]);
    let s = 16;
    let jitter: Vec<f32> = (0..bundle.len() * s)
        .map(|i| ((i * 7919) % 97) as f32 / 97.0)
        .collect();
    for jitter in [None, Some(jitter.as_slice())] {
        let samples = RaySamples::in_band(&bundle, s, jitter, &grid, None).unwrap();
        assert_eq!(samples.total(), bundle.len() * s);
        // The far ray (x = 0.9 m) misses the band: none of its samples is evaluated.
        let kept = samples.kept.as_ref().expect("the missing ray is left out");
        assert!(kept.iter().all(|&i| i / s < 2), "{kept:?}");
        assert_eq!(samples.evaluated(), 2 * s);
        for r in 0..2 {
            let t = &samples.t[r * s..(r + 1) * s];
            let delta = &samples.delta[r * s..(r + 1) * s];
            assert!(
                t.windows(2).all(|w| w[0] <= w[1]),
                "ray {r}: t sorted: {t:?}"
            );
            for &ti in t {
                let p = bundle.origins[r] + bundle.dirs[r] * ti;
                assert!(
                    grid.occupied(p),
                    "ray {r}: sample at t = {ti} outside the band"
                );
            }
            // The band along the ray, measured by fine marching.
            let fine = 20_000;
            let length: f32 = (0..fine)
                .filter(|&k| {
                    let ti = 2.0 * (k as f32 + 0.5) / fine as f32;
                    grid.occupied(bundle.origins[r] + bundle.dirs[r] * ti)
                })
                .count() as f32
                * 2.0
                / fine as f32;
            let total: f32 = delta.iter().sum();
            // The sampler marches at a quarter cell (5 mm) and the band can be several
            // segments along the ray (cells of 2 cm): each boundary is found to within a step.
            assert!(
                (total - length).abs() <= 0.02,
                "ray {r}: intervals {total} vs band length {length}"
            );
            assert!(
                length > 0.3 && length < 0.6,
                "ray {r}: band length {length}"
            );
            assert!(delta.iter().all(|d| *d >= 0.0 && d.is_finite()));
        }
        let missing = &samples.delta[2 * s..];
        assert!(missing.iter().all(|&d| d == 0.0), "{missing:?}");
    }
}

/// The band sampler works on rays in parallel (tasks of 64 rays) and keeps the occupied
/// samples in parallel: a bundle of 300 rays, some missing the band, must give each ray's
/// samples exactly as sampling that ray alone does, in ray order.
#[test]
fn band_samples_of_many_rays_are_each_rays_own() {
    let grid = band();
    let xs: Vec<f32> = (0..300).map(|i| -0.3 + 0.6 * (i as f32 / 299.0)).collect();
    let bundle = rays(&xs);
    let s = 16;
    let jitter: Vec<f32> = (0..bundle.len() * s)
        .map(|i| ((i * 7919) % 97) as f32 / 97.0)
        .collect();
    let occupancy = band();
    for jitter in [None, Some(jitter.as_slice())] {
        for occupancy in [None, Some(&occupancy)] {
            let all = RaySamples::in_band(&bundle, s, jitter, &grid, occupancy).unwrap();
            let (mut points, mut kept) = (Vec::new(), Vec::new());
            let (mut missed, mut hit) = (0, 0);
            for (r, &x) in xs.iter().enumerate() {
                let jitter = jitter.map(|j| &j[r * s..(r + 1) * s]);
                let one = RaySamples::in_band(&rays(&[x]), s, jitter, &grid, occupancy).unwrap();
                assert_eq!(&all.t[r * s..(r + 1) * s], &one.t[..], "ray {r}");
                assert_eq!(&all.delta[r * s..(r + 1) * s], &one.delta[..], "ray {r}");
                let one_kept: Vec<usize> = match &one.kept {
                    Some(k) => k.clone(),
                    None => (0..s).collect(),
                };
                if one_kept.is_empty() {
                    missed += 1;
                } else {
                    hit += 1;
                }
                kept.extend(one_kept.iter().map(|&i| r * s + i));
                points.extend(one.points.iter().copied());
            }
            assert!(missed > 0 && hit > 100, "{missed} rays miss, {hit} hit");
            assert_eq!(all.kept.as_deref(), Some(kept.as_slice()));
            assert_eq!(all.points, points);
            assert!(all.dirs.iter().all(|&d| d == Vec3::Z));
        }
    }
}

#[test]
fn band_quadrature_of_a_constant_density_gives_the_analytic_opacity() {
    let grid = band();
    let bundle = rays(&[0.0]);
    let s = 32;
    let samples = RaySamples::in_band(&bundle, s, None, &grid, None).unwrap();
    let length: f32 = samples.delta.iter().sum();
    let dev = device();
    let sigma = 3.0f32;
    let colour = tensor(vec![0.5; s * 3], [1, s, 3], &dev);
    let out = render_rays_delta(
        tensor(vec![sigma; s], [1, s], &dev),
        colour.clone(),
        colour,
        tensor(samples.t.clone(), [1, s], &dev),
        tensor(samples.delta.clone(), [1, s], &dev),
        None,
    )
    .unwrap();
    let acc = values(out.acc)[0];
    let expected = 1.0 - (-sigma * length).exp();
    assert!((acc - expected).abs() < 1e-5, "acc {acc} vs {expected}");
    let rgb = values(out.rgb);
    assert!((rgb[0] - 0.5 * expected).abs() < 1e-5);
    // The stratified quadrature of the same ray agrees with `render_rays` on [near, far]: the
    // delta form with the stratified intervals reproduces it exactly.
    let strat = RaySamples::new(&bundle, s, None, None).unwrap();
    let c = tensor(vec![0.25; s * 3], [1, s, 3], &dev);
    let sig = tensor((0..s).map(|i| i as f32 * 0.3).collect(), [1, s], &dev);
    let a = render_rays(
        sig.clone(),
        c.clone(),
        c.clone(),
        tensor(strat.t.clone(), [1, s], &dev),
        tensor(vec![2.0], [1], &dev),
        None,
    )
    .unwrap();
    let b = render_rays_delta(
        sig,
        c.clone(),
        c,
        tensor(strat.t.clone(), [1, s], &dev),
        tensor(strat.delta.clone(), [1, s], &dev),
        None,
    )
    .unwrap();
    assert_eq!(values(a.acc), values(b.acc));
    assert_eq!(values(a.rgb), values(b.rgb));
}

#[test]
fn band_settings_are_checked() {
    for (margin_m, cell_m) in [(0.0, 0.02), (0.05, f32::NAN), (2.0, 0.02)] {
        let err = RaySampler::Band { margin_m, cell_m }.check().unwrap_err();
        assert!(err.contains("ray_sampler."), "{err}");
    }
    assert!(RaySampler::Stratified.check().is_ok());
    let (v, f) = octahedron();
    assert!(RaySampler::Stratified.band(&v, &f).unwrap().is_none());
}
