//! The benchmark's scene: a procedural body, patterned source images, rays that hit the box.

use anyhow::Context;
use glam::{Vec2, Vec3};
use nia_data::body::{ProceduralBody, ProceduralSpec, SmplParams};
use nia_data::geometry::camera::Camera;
use nia_data::geometry::raster::rasterize;
use nia_data::geometry::rays::{near_far, pixel_ray, Aabb, RayBundle};
use nia_data::geometry::visibility::visibility;
use nia_data::rng::Rng;
use nia_data::scene::{SceneBody, SceneInput, SourceView, RAY_BOX_PADDING_M};

/// The benchmark scene: the procedural body in its rest pose seen by `views` cameras on a ring
/// around it (`size` x `size` pixels of uniform noise each, the body's silhouette as the mask),
/// and `rays` rays of a target camera between them that hit the ray box.
pub(super) fn bench_scene(
    size: u32,
    views: usize,
    rays: usize,
) -> anyhow::Result<(SceneInput, RayBundle)> {
    let model = ProceduralBody::generate(&ProceduralSpec::default())?;
    let vertices = model.lbs(&SmplParams::default()).vertices;
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for v in &vertices {
        lo = lo.min(*v);
        hi = hi.max(*v);
    }
    let centre = (lo + hi) * 0.5;
    let f = size as f32 * 1.4;
    let camera_at = |angle: f32| {
        let eye = centre + Vec3::new(2.5 * angle.sin(), 0.1, 2.5 * angle.cos());
        Camera::look_at(eye, centre, Vec3::Y, f, f, size, size)
    };
    let mut rng = Rng::new(7);
    let mut sources = Vec::new();
    for i in 0..views {
        let camera = camera_at(i as f32 * std::f32::consts::TAU / views as f32)?;
        let vis = visibility(&camera, &vertices, &model.faces, 0.02)?;
        let image = (0..3 * (size * size) as usize)
            .map(|_| rng.uniform())
            .collect();
        // The body's silhouette: what a person mask would be (read by the visual hull only).
        let mask = rasterize(&camera, &vertices, &model.faces)?
            .mask()
            .iter()
            .map(|&m| m as u8 as f32)
            .collect();
        sources.push(SourceView {
            camera,
            image,
            mask,
            vertex_visibility: vis.iter().map(|&b| b as f32).collect(),
        });
    }
    let input = SceneInput {
        views: sources,
        body: SceneBody {
            vertices,
            faces: model.faces.clone(),
            rh: Vec3::ZERO,
            th: Vec3::ZERO,
        },
    };
    let ray_box = Aabb::from_points(&input.body.vertices)
        .context("the procedural body has no finite vertices")?
        .padded(RAY_BOX_PADDING_M);
    let target = camera_at(0.9)?;
    let mut bundle = RayBundle::default();
    let mut tries = 0;
    while bundle.len() < rays {
        tries += 1;
        anyhow::ensure!(
            tries < 1_000_000,
            "could not find {rays} rays hitting the body box"
        );
        let px = Vec2::new(rng.range(0.0, size as f32), rng.range(0.0, size as f32));
        let ray = pixel_ray(&target, px);
        if let Some((near, far)) = near_far(&ray, &ray_box) {
            let pixel = px.y as u32 * size + px.x as u32;
            bundle.push(ray, near, far, pixel);
        }
    }
    Ok((input, bundle))
}
