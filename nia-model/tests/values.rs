//! Value tests of the image-based path, beyond shapes and finiteness: a point on a vertex's
//! line of sight reads that view's own pixel (colour and encoder feature), and the whole
//! forward (sampler -> field -> renderer) renders a source view's own pixels with the values
//! the quadrature and the colour rule predict, with source colours per sample and at the
//! expected surface point.

mod common;

use burn::prelude::*;
use common::{assert_close, assert_finite, device, scene, values};
use glam::{Vec2, Vec3};
use nia_data::geometry::camera::Camera;
use nia_data::geometry::rays::{pixel_ray, Aabb, Ray, RayBundle};
use nia_data::scene::{projection_grid, PointInputs, SceneInput, RAY_BOX_PADDING_M};
use nia_model::config::SourceColoursAt;
use nia_model::field::PointTensors;
use nia_model::ibr::c0_weight_scale::rescale_c0_weight;
use nia_model::ibr::fetch_source_colours;
use nia_model::ibr::surface::{surface_colours, surface_grid, surface_points, SURFACE_ACC_FLOOR};
use nia_model::renderer::image::{render_image, ImageRenderOptions, RenderedImage};
use nia_model::renderer::RenderOutput;
use nia_model::scene_encoding::SceneEncoding;
use nia_model::variant::Variant;
use nia_model::{ModelConfig, NiaModel};

/// f32 values through bilinear sampling and one linear layer.
const VALUE_TOL: f32 = 1e-4;
const SIZE: u32 = 32;

/// The world point on the ray through image position `pixel` of `camera` at camera depth `z`.
fn point_at_pixel(camera: &Camera, pixel: Vec2, z: f32) -> Vec3 {
    let ray = pixel_ray(camera, pixel);
    let z_per_metre = (camera.r * ray.dir).z;
    ray.origin + ray.dir * (z / z_per_metre)
}

/// Pixel (x, y) of channel c of a `[3, H, W]` image.
fn pixel(image: &[f32], c: usize, x: usize, y: usize) -> f32 {
    let s = SIZE as usize;
    image[(c * s + y) * s + x]
}

/// The rays through every pixel of source view 0 that cross the body's box.
fn rays_through_view_0(input: &SceneInput) -> RayBundle {
    let ray_box = Aabb::from_points(&input.body.vertices)
        .unwrap()
        .padded(RAY_BOX_PADDING_M);
    RayBundle::through_pixels(&input.views[0].camera, &ray_box, None)
}

/// Three views of `SIZE` px encoded by the tiny network on the CPU: (device, scene, network,
/// encoding).
fn tiny_encoded() -> (Device, SceneInput, NiaModel, SceneEncoding) {
    tiny_encoded_on(device())
}

/// [`tiny_encoded`] on `dev` (e.g. its autodiff form).
fn tiny_encoded_on(dev: Device) -> (Device, SceneInput, NiaModel, SceneEncoding) {
    let input = scene(3, SIZE);
    let model = ModelConfig::tiny().init(&dev);
    let encoded = model.encode(&input, None, &dev, None).unwrap();
    (dev, input, model, encoded)
}

/// Variant (c) over `views` source views, rendering the rays of view 0 with 16 samples.
fn variant_c_renders_view_0(
    views: usize,
    at: SourceColoursAt,
) -> (SceneInput, SceneEncoding, RayBundle, RenderOutput) {
    let dev = device();
    let input = scene(views, SIZE);
    let mut config = ModelConfig::tiny();
    config.variant = Variant::SimpleAverage;
    config.source_colours_at = Some(at);
    let model = config.init(&dev);
    let encoded = model.encode(&input, None, &dev, None).unwrap();
    let rays = rays_through_view_0(&input);
    let out = model.render(&encoded, &rays, 16, None, None).unwrap();
    (input, encoded, rays, out)
}

#[test]
fn a_vertex_projected_into_a_view_reads_its_own_pixel_colour_and_feature() {
    let (dev, input, model, encoded) = tiny_encoded();
    let view = &input.views[0];
    let camera = &view.camera;
    // Vertices view 0 sees, projecting well inside the image.
    let seen: Vec<(Vec2, f32)> = input
        .body
        .vertices
        .iter()
        .zip(&view.vertex_visibility)
        .filter(|(_, &o)| o > 0.5)
        .filter_map(|(&v, _)| camera.project(v))
        .filter(|(uv, _)| uv.min_element() > 2.0 && uv.max_element() < SIZE as f32 - 3.0)
        .step_by(97)
        .take(5)
        .collect();
    assert!(seen.len() >= 3, "too few visible vertices: {}", seen.len());
    for (uv, z) in seen {
        // (1) Moved onto the nearest pixel centre (integer coordinates), at the vertex's depth:
        // the colour read is exactly that pixel of view 0.
        let (x, y) = (uv.x.round() as usize, uv.y.round() as usize);
        let p = point_at_pixel(camera, Vec2::new(x as f32, y as f32), z);
        let inputs = PointInputs::compute(&encoded.geometry, &[p], &[Vec3::Z], None);
        let tensors = PointTensors::upload(&inputs, &dev);
        let colours = fetch_source_colours(encoded.images.clone(), tensors.proj_grid).unwrap();
        let got = values(colours.slice(s![0..1, .., ..]));
        let expected: Vec<f32> = (0..3).map(|c| pixel(&view.image, c, x, y)).collect();
        assert_close(&got, &expected, VALUE_TOL, "c_0 at its own pixel centre");

        // (2) At the centre of a 2 x 2 pixel block, (2k + 0.5, 2j + 0.5): the half-resolution
        // feature map is read exactly at its pixel (k, j), and the colour is the block's mean.
        let (k, j) = ((uv.x / 2.0).floor() as usize, (uv.y / 2.0).floor() as usize);
        let block = Vec2::new(2.0 * k as f32 + 0.5, 2.0 * j as f32 + 0.5);
        let p = point_at_pixel(camera, block, z);
        let inputs = PointInputs::compute(&encoded.geometry, &[p], &[Vec3::Z], None);
        let tensors = PointTensors::upload(&inputs, &dev);
        // The concatenated feature map F (the model itself only builds its reductions).
        let feature_maps = model.encoder.forward(encoded.images.clone());
        let l = model
            .pixel_feature
            .forward(feature_maps.clone(), tensors.proj_grid.clone())
            .unwrap();
        let channels = feature_maps.dims()[1];
        let own = feature_maps
            .clone()
            .slice(s![0..1, .., j..j + 1, k..k + 1])
            .reshape([1, 1, channels]);
        let expected = model.pixel_feature.reduce.forward(own);
        assert_close(
            &values(l.slice(s![0..1, .., ..])),
            &values(expected),
            VALUE_TOL,
            "l_0 at its own feature pixel",
        );
        let colours = fetch_source_colours(encoded.images.clone(), tensors.proj_grid).unwrap();
        let mean: Vec<f32> = (0..3)
            .map(|c| {
                (pixel(&view.image, c, 2 * k, 2 * j)
                    + pixel(&view.image, c, 2 * k + 1, 2 * j)
                    + pixel(&view.image, c, 2 * k, 2 * j + 1)
                    + pixel(&view.image, c, 2 * k + 1, 2 * j + 1))
                    / 4.0
            })
            .collect();
        assert_close(
            &values(colours.slice(s![0..1, .., ..])),
            &mean,
            VALUE_TOL,
            "c_0 at a block centre",
        );
    }
}

/// Rendering source view 0 from its own camera with variant (c) and one view: every sample of
/// the ray through pixel p projects onto p, so c_1 = I_0(p) along the whole ray and
/// `rgb = sum_i w_i (c0_i + I_0(p)) / 2 = (rgb0 + acc * I_0(p)) / 2` whatever the weights.
/// The check is not vacuous: some rays gather opacity, and the source pixels vary.
#[test]
fn the_whole_forward_renders_a_source_views_own_pixels() {
    let (input, _, rays, out) = variant_c_renders_view_0(1, SourceColoursAt::Samples);
    let view = &input.views[0];
    assert!(rays.len() > 50, "{} rays cross the box", rays.len());
    let rgb = values(out.rgb);
    let rgb0 = values(out.rgb0);
    let acc = values(out.acc);
    let s = SIZE as usize;
    let mut expected = Vec::with_capacity(rgb.len());
    for (r, &p) in rays.pixels.iter().enumerate() {
        let (x, y) = (p as usize % s, p as usize / s);
        for c in 0..3 {
            expected.push((rgb0[r * 3 + c] + acc[r] * pixel(&view.image, c, x, y)) / 2.0);
        }
    }
    assert_close(&rgb, &expected, VALUE_TOL, "rgb = (rgb0 + acc I_0(p)) / 2");
    assert!(
        acc.iter().any(|&a| a > 0.05),
        "no ray gathered opacity: the check would be vacuous"
    );
}

/// The surface form of the colour (`source_colours_at = surface`): every view's colour is read
/// once per ray at x_s = o + d depth / acc. With variant (c) over three views every sample's
/// blend weight is 1 / 4, so W_n = acc / 4 and `rgb = (rgb0 + acc sum_n I_n(x_s)) / 4`, with
/// I_n(x_s) read here independently of the renderer (projection + bilinear fetch of x_s).
#[test]
fn the_surface_form_reads_every_view_once_at_the_expected_surface_point() {
    let dev = device();
    let (_, encoded, rays, out) = variant_c_renders_view_0(3, SourceColoursAt::Surface);
    let (rgb, rgb0) = (values(out.rgb), values(out.rgb0));
    let (acc, depth) = (values(out.acc), values(out.depth));
    assert!(
        acc.iter().any(|&a| a > 0.05),
        "no ray gathered opacity: the check would be vacuous"
    );
    let points: Vec<Vec3> = (0..rays.len())
        .map(|r| {
            let t = if acc[r] >= SURFACE_ACC_FLOOR {
                depth[r] / acc[r]
            } else {
                0.5 * (rays.near[r] + rays.far[r])
            };
            rays.origins[r] + rays.dirs[r] * t
        })
        .collect();
    let inputs = PointInputs::compute(&encoded.geometry, &points, &rays.dirs, None);
    let tensors = PointTensors::upload(&inputs, &dev);
    let colours = values(fetch_source_colours(encoded.images.clone(), tensors.proj_grid).unwrap());
    let r_count = rays.len();
    let mut expected = Vec::with_capacity(rgb.len());
    for r in 0..r_count {
        for c in 0..3 {
            let sum: f32 = (0..3).map(|n| colours[(n * r_count + r) * 3 + c]).sum();
            expected.push((rgb0[r * 3 + c] + acc[r] * sum) / 4.0);
        }
    }
    assert_close(
        &rgb,
        &expected,
        VALUE_TOL,
        "rgb = (rgb0 + acc sum_n I_n(x_s)) / 4",
    );
    // The IBR-only composite is the plain mean of the three surface colours, over black.
    let ibr = values(out.rgb_ibr.unwrap());
    let mean: Vec<f32> = (0..r_count)
        .flat_map(|r| {
            let (colours, acc) = (&colours, &acc);
            (0..3).map(move |c| {
                acc[r]
                    * (0..3)
                        .map(|n| colours[(n * r_count + r) * 3 + c])
                        .sum::<f32>()
                    / 3.0
            })
        })
        .collect();
    assert_close(&ibr, &mean, VALUE_TOL, "IBR-only = acc mean_n I_n(x_s)");
}

/// Training's surface grid (`surface_grid`, on the device, no read back) is the host's
/// projection (`projection_grid`) of the host's surface points (`surface_points`): rays with
/// opacity at a depth inside, before and beyond their interval (clamped), rays under the
/// opacity floor and a NaN depth (the interval's middle).
#[test]
fn the_training_surface_grid_is_the_hosts_projection_of_the_surface_point() {
    let (ad, input, _, encoded) = tiny_encoded_on(device().autodiff());
    let rays = rays_through_view_0(&input);
    let r = rays.len();
    let (mut depth, mut acc) = (Vec::with_capacity(r), Vec::with_capacity(r));
    for i in 0..r {
        let (near, far) = (rays.near[i], rays.far[i]);
        let (t, a) = match i % 6 {
            0 => (near + 0.37 * (far - near), 0.8),
            1 => (near - 0.5, 0.5),
            2 => (far + 0.5, 1.0),
            3 => (near + 0.6 * (far - near), SURFACE_ACC_FLOOR * 0.5),
            4 => (f32::NAN, 0.7),
            _ => (near + 0.9 * (far - near), 0.3),
        };
        depth.push(t * a);
        acc.push(a);
    }
    let tensor = |v: &[f32]| Tensor::<1>::from_data(TensorData::new(v.to_vec(), [r]), &ad);
    let grid = values(surface_grid(&encoded, &rays, tensor(&depth), tensor(&acc)).unwrap());
    let host = projection_grid(&encoded.geometry, &surface_points(&rays, &depth, &acc));
    assert!(
        grid.iter().all(|g| g.is_finite()),
        "a NaN depth reads the middle"
    );
    assert_close(&grid, &host, 1e-4, "device surface grid = host projection");
    // Some grid points land inside the images: the comparison is not of padding alone.
    assert!(
        grid.chunks(2)
            .filter(|g| g[0].abs() < 1.0 && g[1].abs() < 1.0)
            .count()
            > r
    );
}

/// The surface read is differentiable in the expected depth: d/dt of the colours read at
/// x_s = o + d t (autodiff through the device projection and the bilinear fetch) matches a
/// central finite difference of the colours read at t +- h, ray by ray.
#[test]
fn the_surface_read_has_the_finite_difference_gradient_in_depth() {
    let (ad, input, _, encoded) = tiny_encoded_on(device().autodiff());
    let rays = rays_through_view_0(&input);
    let r = rays.len();
    // Depths off the middle of each ray's box interval (the middle of a central ray lies on the
    // ring's axis, which projects onto pixel centres of the other views, where the bilinear
    // fetch has a kink and no derivative), acc = 1.
    let t: Vec<f32> = (0..r)
        .map(|i| rays.near[i] + 0.37 * (rays.far[i] - rays.near[i]))
        .collect();
    let ones = Tensor::<1>::ones([r], &ad);
    let weights: Vec<f32> = (0..3 * r * 3)
        .map(|i| ((i * 7919) % 13) as f32 / 13.0 - 0.4)
        .collect();
    let weights_t = Tensor::<3>::from_data(TensorData::new(weights.clone(), [3, r, 3]), &ad);
    let depth = Tensor::<1>::from_data(TensorData::new(t.clone(), [r]), &ad).require_grad();
    let colours = surface_colours(&encoded, &rays, depth.clone(), ones.clone()).unwrap();
    let grads = (colours * weights_t).sum().backward();
    let got = values(depth.grad(&grads).unwrap());
    // Per-ray weighted sums at t +- h.
    let h = 1e-4f32;
    let per_ray = |shift: f32| -> Vec<f32> {
        let shifted: Vec<f32> = t.iter().map(|&x| x + shift).collect();
        let depth = Tensor::<1>::from_data(TensorData::new(shifted, [r]), &ad);
        let c = values(surface_colours(&encoded, &rays, depth, ones.clone()).unwrap());
        (0..r)
            .map(|ray| {
                (0..3)
                    .flat_map(|n| (0..3).map(move |ch| (n * r + ray) * 3 + ch))
                    .map(|i| c[i] * weights[i])
                    .sum()
            })
            .collect()
    };
    let (plus, minus) = (per_ray(h), per_ray(-h));
    let expected: Vec<f32> = plus
        .iter()
        .zip(&minus)
        .map(|(p, m)| (p - m) / (2.0 * h))
        .collect();
    assert!(got.iter().all(|g| g.is_finite()));
    let informative = expected.iter().filter(|e| e.abs() > 0.05).count();
    assert!(
        informative > 10,
        "only {informative} rays see an image slope"
    );
    // A bilinear fetch is piecewise linear: rays whose +-h step crosses a pixel-cell edge have
    // a one-sided slope that differs from the central difference; allow a few of them.
    let off = got
        .iter()
        .zip(&expected)
        .filter(|(g, e)| (*g - *e).abs() > 0.05 * (1.0 + e.abs()))
        .count();
    assert!(
        off * 50 <= informative,
        "{off} of {informative} informative rays ({r} in all) disagree with the finite difference"
    );
}

/// The body's silhouette in the hull (`[render] hull_body_erode_px`): a band cut across view
/// 0's mask (rows 12..=15 of 32, as a segmentation network cuts one) has the plain hull carve
/// the body's vertices behind it; with the silhouette counted as person few of them are carved
/// (fewer than before when it is shrunk by 1 px), and no point is carved more than by the plain
/// hull.
#[test]
fn the_body_in_the_hull_keeps_what_a_cut_mask_would_carve() {
    let (_, mut input, _, scene) = tiny_encoded();
    let s = SIZE as usize;
    for y in 12..=15 {
        for x in 0..s {
            input.views[0].mask[y * s + x] = 0.0;
        }
    }
    let hull_of = |body| {
        scene
            .clone()
            .with_visual_hull(&input, true, body)
            .unwrap()
            .visual_hull
            .expect("a hull")
    };
    let (plain, with_body, eroded) = (hull_of(None), hull_of(Some(0)), hull_of(Some(1)));
    let cameras = &scene.geometry.cameras;
    let vertices = &input.body.vertices;
    let centre = common::body_centre(vertices);
    let off: Vec<Vec3> = vertices
        .iter()
        .map(|&v| v + Vec3::new(v.x - centre.x, 0.0, v.z - centre.z).normalize_or_zero() * 0.15)
        .collect();
    for x in vertices.iter().chain(&off) {
        let (a, b) = (plain.carving(cameras, *x), with_body.carving(cameras, *x));
        assert!(
            b.is_finite() && b >= a,
            "the body only adds: {b} < {a} at {x}"
        );
    }
    let carved = |h: &nia_data::scene::VisualHull| {
        vertices
            .iter()
            .filter(|&&x| h.carving(cameras, x) == 0.0)
            .count()
    };
    let (by_plain, by_body, by_eroded) = (carved(&plain), carved(&with_body), carved(&eroded));
    assert!(by_plain >= 50, "the cut carves {by_plain} vertices");
    // Measured 39 of 171: vertices on the silhouette's rim, whose four pixels' centres the
    // rasteriser leaves outside the body.
    assert!(
        by_body * 3 <= by_plain,
        "with the body {by_body} of the {by_plain} vertices the cut carves stay carved"
    );
    // At 32 px a limb is a few pixels wide: shrunk by 1 px, 91 of 171 stay carved.
    assert!(
        by_eroded < by_plain,
        "shrunk by 1 px: {by_eroded} of {by_plain} stay carved"
    );
}

/// The visual hull (`[render] visual_hull`) on one encoding: the density is the plain density
/// times the hull of the source masks (here the body's rasterised silhouettes),
/// about 1 on the body and exactly 0 for more than half of the points 15 cm off it. At 128 px,
/// the quickstart's size: at 32 px most vertices sit on a silhouette's rim pixel, where the
/// bilinear read of the mask is about half.
#[test]
fn the_visual_hull_zeroes_the_density_off_the_person_and_keeps_it_on_the_body() {
    let dev = device();
    let input = scene(3, 128);
    let model = ModelConfig::tiny().init(&dev);
    let plain_scene = model.encode(&input, None, &dev, None).unwrap();
    let hulled_scene = plain_scene
        .clone()
        .with_visual_hull(&input, true, None)
        .unwrap();
    let hull = hulled_scene.visual_hull.clone().expect("a hull");
    let vertices = &input.body.vertices;
    let centre = common::body_centre(vertices);
    // 15 cm further out, horizontally away from the body's vertical axis.
    let off: Vec<Vec3> = vertices
        .iter()
        .map(|&v| {
            let out = Vec3::new(v.x - centre.x, 0.0, v.z - centre.z).normalize_or_zero();
            v + out * 0.15
        })
        .collect();
    for (points, on_body) in [(&vertices[..], true), (&off[..], false)] {
        let dirs = vec![Vec3::Z; points.len()];
        let geometry = &plain_scene.geometry;
        let inputs = PointInputs::compute(geometry, points, &dirs, None);
        assert!(inputs.hull.is_none(), "no hull without carving");
        let hull = inputs
            .carved(&hull, &geometry.cameras, points)
            .hull
            .expect("a hull");
        let sigma = |s: &SceneEncoding| values(model.field(s, points, &dirs, None).unwrap().sigma);
        let (a, b) = (sigma(&plain_scene), sigma(&hulled_scene));
        assert!(
            hull.iter().all(|h| (0.0..=1.0).contains(h)),
            "hull in [0, 1]"
        );
        let expected: Vec<f32> = a.iter().zip(&hull).map(|(a, h)| a * h).collect();
        assert_close(&b, &expected, VALUE_TOL, "sigma = plain sigma * hull");
        let carved = hull.iter().filter(|&&h| h == 0.0).count() as f32 / hull.len() as f32;
        let mean = hull.iter().sum::<f32>() / hull.len() as f32;
        // Measured at 128 px: on the vertices a mean of 0.70, 0.34 of them at 1 (rim vertices
        // read about half of a mask pixel in some view) and 0.004 carved to 0; 15 cm off the
        // body 0.87 carved to 0 (the hull is loose between views).
        if on_body {
            assert!(mean > 0.6, "mean hull {mean} on the vertices");
            assert!(carved < 0.03, "{carved} of the vertices carved");
        } else {
            assert!(carved > 0.5, "{carved} of the points 15 cm off carved to 0");
            assert!(
                b.iter().zip(&hull).all(|(s, h)| *h > 0.0 || *s == 0.0),
                "carved points have density 0"
            );
        }
    }
}

/// The colour half alone (`NiaModel::colour_field`, what a baked density's coloured points run)
/// gives the whole network's colours to the bit on a scene with a visual hull, points on and
/// off the body, and no density (zeros: F_sigma does not run).
#[test]
fn the_colour_half_alone_gives_the_whole_networks_colours() {
    let dev = device();
    let input = scene(3, 64);
    let model = ModelConfig::tiny().init(&dev);
    let scene = model
        .encode(&input, None, &dev, None)
        .unwrap()
        .with_visual_hull(&input, true, None)
        .unwrap();
    let vertices = &input.body.vertices;
    let centre = common::body_centre(vertices);
    let points: Vec<Vec3> = vertices
        .iter()
        .enumerate()
        .map(|(i, &v)| v + (v - centre).normalize_or_zero() * 0.02 * (i % 5) as f32)
        .collect();
    let dirs: Vec<Vec3> = points
        .iter()
        .map(|&p| (p - Vec3::new(0.0, 0.0, 3.0)).normalize())
        .collect();
    let whole = model.field(&scene, &points, &dirs, None).unwrap();
    let half = model.colour_field(&scene, &points, &dirs, None).unwrap();
    assert!(values(whole.sigma.clone()).iter().any(|&s| s > 0.0));
    assert!(values(half.sigma).iter().all(|&s| s == 0.0), "no density");
    for (what, a, b) in [
        ("colour", whole.colour, half.colour),
        ("c0", whole.c0, half.c0),
        ("blend weights", whole.blend_weights, half.blend_weights),
        ("IBR-only colour", whole.ibr_colour, half.ibr_colour),
    ] {
        let (a, b) = (values(a), values(b));
        assert_finite(&b, what);
        assert_eq!(a, b, "{what}");
    }
}

/// Shape-bucket padding pads the computed inputs (`PointInputs::padded`): the same arrays,
/// to the bit, as computing the inputs of the points with the last one repeated, body-volume
/// corners and the visual hull's carving included.
#[test]
fn padded_point_inputs_are_the_inputs_of_the_repeated_last_point() {
    let (_, input, _, scene) = tiny_encoded();
    let hull = scene.with_visual_hull(&input, true, None).unwrap();
    let geometry = &hull.geometry;
    let cameras = &geometry.cameras;
    let scales = &hull
        .volume
        .as_ref()
        .expect("a body volume")
        .0
        .pyramid
        .levels[1..];
    let centre = common::body_centre(&input.body.vertices);
    // Points on the body and 15 cm off it, so that visibility, corners and carving all vary.
    let points: Vec<Vec3> = input.body.vertices[..40]
        .iter()
        .enumerate()
        .map(|(i, &v)| v + (v - centre).normalize_or_zero() * 0.15 * (i % 2) as f32)
        .collect();
    let dirs: Vec<Vec3> = (0..points.len())
        .map(|i| Vec3::new(0.1 * i as f32, 0.2, 1.0).normalize())
        .collect();
    let inputs = |points: &[Vec3], dirs: &[Vec3]| {
        let smpl: Vec<[f32; 3]> = points.iter().map(|&p| geometry.to_smpl(p)).collect();
        PointInputs::compute(geometry, points, dirs, Some((scales, &smpl))).carved(
            hull.visual_hull.as_deref().expect("a hull"),
            cameras,
            points,
        )
    };
    let len = 57;
    let repeat = |items: &[Vec3]| {
        let mut out = items.to_vec();
        out.resize(len, *items.last().unwrap());
        out
    };
    let padded = inputs(&points, &dirs).padded(len);
    let expected = inputs(&repeat(&points), &repeat(&dirs));
    assert_eq!(padded.num_points, len);
    assert_eq!(padded.proj_grid, expected.proj_grid);
    assert_eq!(padded.view_dir_features, expected.view_dir_features);
    assert_eq!(padded.visibility, expected.visibility);
    assert_eq!(padded.dirs, expected.dirs);
    assert_eq!(padded.hull, expected.hull);
    assert_eq!(padded.corners.len(), scales.len());
    for (a, b) in padded.corners.iter().zip(&expected.corners) {
        assert_eq!((&a.index, &a.weight), (&b.index, &b.weight));
    }
    // Already long enough, or no points: unchanged.
    assert_eq!(inputs(&points, &dirs).padded(10).num_points, points.len());
    assert_eq!(inputs(&[], &[]).padded(len).num_points, 0);
}

/// `rays` of a `SIZE`-px image of `scene`, 16 samples each, in chunks of `chunk` rays.
fn image_of(
    model: &NiaModel,
    scene: &SceneEncoding,
    rays: &RayBundle,
    chunk: usize,
) -> RenderedImage {
    let options = ImageRenderOptions {
        samples: 16,
        chunk,
        timed: false,
    };
    render_image(
        model,
        scene,
        rays,
        [SIZE as usize; 2],
        options,
        &mut |_, _| {},
    )
    .unwrap()
}

/// A pixel with several rays (supersampling) is the mean of its rays: the same ray twice gives
/// the one-ray image, and a ray with a zero-length partner (a sub-ray that misses the box)
/// gives half its colour, opacity, depth and blend weights.
#[test]
fn a_pixel_is_the_mean_of_its_rays() {
    let (_, input, model, encoded) = tiny_encoded();
    let all = rays_through_view_0(&input);
    let one = all.slice(all.len() / 2..all.len() / 2 + 48);
    let (mut twice, mut with_blank) = (RayBundle::default(), RayBundle::default());
    for i in 0..one.len() {
        let ray = Ray {
            origin: one.origins[i],
            dir: one.dirs[i],
        };
        let (near, far, p) = (one.near[i], one.far[i], one.pixels[i]);
        twice.push(ray, near, far, p);
        twice.push(ray, near, far, p);
        with_blank.push(ray, near, far, p);
        with_blank.push(ray, near, near, p);
    }
    let render = |rays: &RayBundle| image_of(&model, &encoded, rays, 20);
    let (a, b, c) = (render(&one), render(&twice), render(&with_blank));
    assert!(a.acc.iter().any(|&v| v > 0.05), "some opacity to compare");
    assert_eq!((b.rays, c.rays), (2 * a.rays, 2 * a.rays));
    for (got, expected, what) in [
        (&b.rgb, &a.rgb, "colour"),
        (&b.acc, &a.acc, "opacity"),
        (&b.depth, &a.depth, "depth"),
        (&b.blend_weights, &a.blend_weights, "blend weights"),
    ] {
        assert_close(got, expected, 1e-6, what);
    }
    let half = |v: &[f32]| v.iter().map(|x| 0.5 * x).collect::<Vec<_>>();
    for (got, full, what) in [
        (&c.rgb, &a.rgb, "colour"),
        (&c.rgb0, &a.rgb0, "NeRF colour"),
        (&c.acc, &a.acc, "opacity"),
        (&c.depth, &a.depth, "depth"),
        (&c.blend_weights, &a.blend_weights, "blend weights"),
    ] {
        assert_close(got, &half(full), 1e-6, what);
    }
}

/// Rays are independent, so an image does not depend on how many rays each network call
/// holds (`ImageRenderOptions::chunk`; a GPU render takes far larger chunks than a CPU one,
/// `renderer::call_size`), nor on how many points a network call gets
/// (`SceneEncoding::points_per_call`: a depth segment, or a chunk without termination, of more
/// goes in several calls): chunks of 7, of 64 and one chunk of every ray, and that chunk in
/// calls of 37 or 256 points, give the same colours, opacity, depth and blend weights, with and
/// without early termination and colour culling, and evaluate the same points.
#[test]
fn an_image_does_not_depend_on_its_chunk_size() {
    let (_, input, model, encoded) = tiny_encoded();
    let all = rays_through_view_0(&input);
    let rays = all.slice(all.len() / 2 - 100..all.len() / 2 + 100);
    for adaptive in [false, true] {
        let epsilon = adaptive.then_some(1e-3);
        let scene = encoded
            .clone()
            .with_termination(epsilon)
            .with_colour_culling(epsilon);
        let render = |chunk: usize| image_of(&model, &scene, &rays, chunk);
        let whole = render(rays.len());
        assert!(
            whole.acc.iter().any(|&v| v > 0.05),
            "some opacity to compare"
        );
        // Enough points that each of the 8 depth segments splits into calls of 37.
        assert!(
            whole.point_evaluations > 8 * 2 * 37,
            "{} points",
            whole.point_evaluations
        );
        let in_calls = |points: usize| {
            let scene = scene.clone().with_points_per_call(points);
            (
                format!("calls of {points} points"),
                image_of(&model, &scene, &rays, rays.len()),
            )
        };
        let chunks = [7, 64].map(|chunk| (format!("chunks of {chunk}"), render(chunk)));
        for (what_split, part) in chunks.into_iter().chain([in_calls(37), in_calls(256)]) {
            let chunk = what_split;
            assert_eq!(part.rays, whole.rays);
            assert_eq!(part.point_evaluations, whole.point_evaluations);
            assert_eq!(part.colour_evaluations, whole.colour_evaluations);
            for (got, expected, what) in [
                (&part.rgb, &whole.rgb, "colour"),
                (&part.rgb0, &whole.rgb0, "NeRF colour"),
                (&part.rgb_ibr, &whole.rgb_ibr, "IBR-only colour"),
                (&part.acc, &whole.acc, "opacity"),
                (&part.depth, &whole.depth, "depth"),
                (&part.blend_weights, &whole.blend_weights, "blend weights"),
            ] {
                assert!(got.iter().all(|v| v.is_finite()), "{what}: finite");
                assert_close(got, expected, 1e-5, &format!("{what}, {chunk}"));
            }
        }
    }
}

/// `rescale_c0_weight` by hand: `w = (0.5, 0.3, 0.2)` at `s = 0.25` gives c0
/// `0.125 / 0.625 = 0.2` and the views `0.48, 0.32` (their ratio kept); `s = 1` changes
/// nothing; a point only c0 colours (`w_0 = 1`) or only the views colour (`w_0 = 0`) keeps its
/// weights at any scale, extreme scales included; a scale out of bounds, NaN and a lone c0
/// column are refused.
#[test]
fn rescaling_c0s_weight_by_hand() {
    let dev = device();
    let weights = |rows: Vec<[f32; 3]>| {
        let m = rows.len();
        let flat: Vec<f32> = rows.into_iter().flatten().collect();
        Tensor::<2>::from_data(TensorData::new(flat, [m, 3]), &dev)
    };
    let w = weights(vec![[0.5, 0.3, 0.2], [1.0, 0.0, 0.0], [0.0, 0.7, 0.3]]);
    let got = values(rescale_c0_weight(w.clone(), 0.25).unwrap());
    let expected = [0.2, 0.48, 0.32, 1.0, 0.0, 0.0, 0.0, 0.7, 0.3];
    assert_close(&got, &expected, 1e-6, "s = 0.25");
    assert_close(
        &values(rescale_c0_weight(w.clone(), 1.0).unwrap()),
        &values(w.clone()),
        1e-7,
        "s = 1",
    );
    for scale in [1e-3, 1e3] {
        let got = values(rescale_c0_weight(w.clone(), scale).unwrap());
        assert!(got.iter().all(|v| v.is_finite()), "s = {scale}: finite");
        assert_close(
            &got[3..],
            &expected[3..],
            1e-6,
            "w_0 in {0, 1} at an extreme scale",
        );
        for row in got.chunks(3) {
            assert!(
                (row.iter().sum::<f32>() - 1.0).abs() < 1e-5,
                "s = {scale}: rows sum to 1"
            );
        }
    }
    for scale in [0.0, -1.0, 1e-4, 1e4, f32::NAN, f32::INFINITY] {
        let err = rescale_c0_weight(w.clone(), scale).unwrap_err().to_string();
        assert!(err.contains("scale"), "s = {scale}: {err}");
    }
    let lone = Tensor::<2>::ones([2, 1], &dev);
    assert!(rescale_c0_weight(lone, 0.5).is_err(), "a c0 column alone");
}

/// `[render] c0_weight_scale` on a render: the opacity, depth, NeRF colour and IBR-only
/// composite do not move; every pixel's c0 weight falls below 1 and rises above it (its
/// weights still sum to its opacity), and the colour is the blend of the rescaled weights.
#[test]
fn rescaling_c0s_weight_moves_only_the_blend() {
    let (_, input, model, encoded) = tiny_encoded();
    let all = rays_through_view_0(&input);
    let rays = all.slice(all.len() / 2 - 100..all.len() / 2 + 100);
    let plain = image_of(&model, &encoded, &rays, 64);
    let k = plain.blend_channels;
    let c0_share =
        |img: &RenderedImage| -> Vec<f32> { img.blend_weights.chunks(k).map(|w| w[0]).collect() };
    let plain_c0 = c0_share(&plain);
    let most = plain_c0.iter().copied().fold(0.0f32, f32::max);
    let acc = plain.acc.iter().copied().fold(0.0f32, f32::max);
    // The untrained tiny network: opacity up to about 0.1, a quarter of it c0's.
    assert!(most > 0.01, "some c0 weight to move: {most}, opacity {acc}");
    let total: f32 = plain_c0.iter().sum();
    for scale in [0.25f32, 4.0] {
        let scene = encoded.clone().with_c0_weight_scale(Some(scale));
        let scaled = image_of(&model, &scene, &rays, 64);
        for (got, expected, what) in [
            (&scaled.acc, &plain.acc, "opacity"),
            (&scaled.depth, &plain.depth, "depth"),
            (&scaled.rgb0, &plain.rgb0, "NeRF colour"),
            (&scaled.rgb_ibr, &plain.rgb_ibr, "IBR-only colour"),
        ] {
            assert_close(got, expected, 1e-5, &format!("{what} at s = {scale}"));
        }
        assert!(
            scaled.rgb.iter().all(|v| v.is_finite()),
            "s = {scale}: finite colour"
        );
        let scaled_c0 = c0_share(&scaled);
        let mut moved = 0.0f32;
        for (p, (&a, &b)) in plain_c0.iter().zip(&scaled_c0).enumerate() {
            let falls = if scale < 1.0 {
                b <= a + 1e-6
            } else {
                b >= a - 1e-6
            };
            assert!(falls, "pixel {p}: c0 weight {a} -> {b} at s = {scale}");
            moved += (a - b).abs();
            let sum: f32 = scaled.blend_weights[p * k..(p + 1) * k].iter().sum();
            assert!(
                (sum - scaled.acc[p]).abs() < 1e-4,
                "pixel {p}: weights {sum}, opacity {}",
                scaled.acc[p]
            );
        }
        // A c0 share near 1/4 moves to about 1/13 at s = 1/4 and to 4/7 at s = 4.
        assert!(
            moved > 0.3 * total,
            "s = {scale}: c0 weights moved by {moved} of {total} in all"
        );
        // The colour is the blend of its weights: C0's and the views' parts recombined. Where
        // c0 loses weight the colour moves toward the IBR-only composite.
        let changed = scaled
            .rgb
            .iter()
            .zip(&plain.rgb)
            .filter(|(a, b)| (*a - *b).abs() > 1e-4)
            .count();
        assert!(changed > 0, "s = {scale}: the colour changes");
    }
}
