//! Geometry core: cameras and undistortion, rays and boxes, the rasteriser, vertex visibility
//! and nearest-surface queries, checked against analytic answers and brute force.

mod camera;
mod raster;
mod rays;
mod sphere;
mod surface;
mod visibility;

pub(crate) use glam::{Mat3, Vec2, Vec3};
pub(crate) use nia_data::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};
pub(crate) use nia_data::geometry::raster::{
    rasterize, rasterize_into, render_textured, Fragments, MeshError, EMPTY_FACE, NEAR_PLANE_M,
};
pub(crate) use nia_data::geometry::rays::{
    box_pixel_bounds, image_rays, mask_at_box, near_far, pixel_centre, pixel_ray, Aabb, Ray,
    RayBundle,
};
pub(crate) use nia_data::geometry::surface::{
    closest_point_on_triangle, interpolate_scalar, interpolate_weights, SurfaceIndex,
};
pub(crate) use nia_data::geometry::visibility::{
    vertex_visibility, visibility, DEFAULT_DEPTH_TOL_M,
};
pub(crate) use nia_data::rng::Rng;
pub(crate) use sphere::{uv_sphere, Mesh};

/// f32 round-off on metre-scale coordinates after a handful of operations.
pub(crate) const GEOM_TOL: f32 = 1e-4;
/// Pixel positions through distortion round trips (f32, 30 fixed-point iterations).
pub(crate) const PIXEL_TOL: f32 = 1e-3;

/// A cube [-1, 1]^3 with each side an n x n grid, outward-facing triangles.
pub(crate) fn cube(n: u32) -> Mesh {
    let mut v: Vec<Vec3> = Vec::new();
    let mut f = Vec::new();
    let mut index = std::collections::HashMap::new();
    let mut vid = |p: Vec3, v: &mut Vec<Vec3>| -> u32 {
        let key = (p * 1000.0).round().as_ivec3().to_array();
        *index.entry(key).or_insert_with(|| {
            v.push(p);
            v.len() as u32 - 1
        })
    };
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let nrm = Vec3::from_array(std::array::from_fn(|k| if k == axis { sign } else { 0.0 }));
            let u = Vec3::from_array(std::array::from_fn(|k| {
                if k == (axis + 1) % 3 {
                    1.0
                } else {
                    0.0
                }
            }));
            let w = nrm.cross(u);
            let at = |i: u32, j: u32| {
                nrm + u * (2.0 * i as f32 / n as f32 - 1.0) + w * (2.0 * j as f32 / n as f32 - 1.0)
            };
            for i in 0..n {
                for j in 0..n {
                    let a = vid(at(i, j), &mut v);
                    let b = vid(at(i + 1, j), &mut v);
                    let c = vid(at(i + 1, j + 1), &mut v);
                    let d = vid(at(i, j + 1), &mut v);
                    // (u, w, nrm) is right-handed, so counter-clockwise in (u, w) faces out.
                    f.push([a, b, c]);
                    f.push([a, c, d]);
                }
            }
        }
    }
    (v, f)
}

/// Camera at the origin looking down +z with identity rotation (x right, y down).
pub(crate) fn front_camera(f: f32, size: u32) -> Camera {
    let c = Camera::look_at(Vec3::ZERO, Vec3::Z, -Vec3::Y, f, f, size, size).unwrap();
    assert!((c.r - Mat3::IDENTITY)
        .abs()
        .to_cols_array()
        .iter()
        .all(|e| *e < 1e-6));
    c
}

pub(crate) fn distorted_camera() -> Camera {
    Camera::from_rows(
        [[300.0, 0.0, 161.3], [0.0, 310.0, 118.7], [0.0, 0.0, 1.0]],
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0, 0.0, 0.0],
        [-0.28, 0.09, 0.0012, -0.0009, -0.01],
        320,
        240,
    )
    .unwrap()
}
