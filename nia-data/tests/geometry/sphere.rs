//! The UV sphere test mesh, shared by these tests and by `benches/geometry.rs` (which
//! includes this file as a module), so it uses nothing but `glam`.

use glam::Vec3;

/// Vertices and outward-facing triangles.
pub(crate) type Mesh = (Vec<Vec3>, Vec<[u32; 3]>);

/// A UV sphere with outward-facing triangles; `radius(theta, phi)` allows bumpy shapes.
pub(crate) fn uv_sphere(
    centre: Vec3,
    n_lat: u32,
    n_lon: u32,
    radius: impl Fn(f32, f32) -> f32,
) -> Mesh {
    let mut v = vec![centre + Vec3::new(0.0, 0.0, radius(0.0, 0.0))];
    for i in 1..n_lat {
        let theta = std::f32::consts::PI * i as f32 / n_lat as f32;
        for j in 0..n_lon {
            let phi = std::f32::consts::TAU * j as f32 / n_lon as f32;
            let r = radius(theta, phi);
            v.push(
                centre
                    + r * Vec3::new(
                        theta.sin() * phi.cos(),
                        theta.sin() * phi.sin(),
                        theta.cos(),
                    ),
            );
        }
    }
    v.push(centre + Vec3::new(0.0, 0.0, -radius(std::f32::consts::PI, 0.0)));
    let south = v.len() as u32 - 1;
    let ring = |i: u32, j: u32| 1 + (i - 1) * n_lon + (j % n_lon);
    let mut f = Vec::new();
    for j in 0..n_lon {
        f.push([0, ring(1, j), ring(1, j + 1)]);
        f.push([south, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)]);
    }
    for i in 1..n_lat - 1 {
        for j in 0..n_lon {
            let (a, b, c, d) = (
                ring(i, j),
                ring(i, j + 1),
                ring(i + 1, j),
                ring(i + 1, j + 1),
            );
            f.push([a, c, d]);
            f.push([a, d, b]);
        }
    }
    (v, f)
}
