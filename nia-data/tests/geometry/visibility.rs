//! Vertex visibility against front-facing tests and occlusion.

use super::*;

fn front_facing_cos(cam: Vec3, v: Vec3, n: Vec3) -> f32 {
    (cam - v).normalize().dot(n)
}

/// Largest `cos` between the view direction and the normals of the faces around each vertex:
/// on a convex polyhedron a vertex is seen iff one of its faces is front-facing (`cos > 0`).
fn face_cosines(eye: Vec3, v: &[Vec3], f: &[[u32; 3]]) -> Vec<f32> {
    let mut cos = vec![f32::NEG_INFINITY; v.len()];
    for tri in f {
        let [a, b, c] = tri.map(|k| v[k as usize]);
        let n = (b - a).cross(c - a).normalize();
        for k in tri {
            let p = v[*k as usize];
            cos[*k as usize] = cos[*k as usize].max(front_facing_cos(eye, p, n));
        }
    }
    cos
}

/// Agreement with the analytic front-facing set: exact away from the silhouette
/// (`|cos| > 0.2`), and overall above 97% (the rest is a sub-pixel band around the limb).
fn check_visibility(vis: &[u8], cosines: &[f32], name: &str) {
    let mut agree = 0;
    for (i, (&s, &cos)) in vis.iter().zip(cosines).enumerate() {
        if (s == 1) == (cos > 0.0) {
            agree += 1;
        } else {
            assert!(
                cos.abs() <= 0.2,
                "{name}: vertex {i} cos {cos} visibility {s}"
            );
        }
    }
    let frac = agree as f32 / vis.len() as f32;
    assert!(frac > 0.97, "{name}: agreement {frac}");
}

#[test]
fn sphere_and_cube_visibility_match_front_facing() {
    let (sv, sf) = uv_sphere(Vec3::ZERO, 48, 96, |_, _| 1.0);
    let (cv, cf) = cube(16);
    // A generic view, one with both poles of the UV sphere on the silhouette (densest rings in
    // the ambiguous band), one along a cube diagonal. The sphere spans ~200 pixels.
    for dir in [
        Vec3::new(0.7, -0.9, 3.3),
        Vec3::new(0.1, 5.0, 0.3),
        Vec3::new(1.0, 1.0, 1.0),
    ] {
        let eye = dir.normalize() * 4.5;
        let up = if dir.y.abs() > 4.0 { Vec3::Z } else { Vec3::Y };
        let c = Camera::look_at(eye, Vec3::ZERO, up, 450.0, 450.0, 512, 512).unwrap();
        let vis = visibility(&c, &sv, &sf, DEFAULT_DEPTH_TOL_M).unwrap();
        check_visibility(&vis, &face_cosines(eye, &sv, &sf), "sphere (face normals)");
        // The smooth sphere's normals: same guarantee away from the silhouette.
        let smooth: Vec<f32> = sv
            .iter()
            .map(|p| front_facing_cos(eye, *p, p.normalize()))
            .collect();
        for (i, (&s, &cos)) in vis.iter().zip(&smooth).enumerate() {
            assert!(
                cos.abs() <= 0.2 || (s == 1) == (cos > 0.0),
                "sphere vertex {i}"
            );
        }
        let vis = visibility(&c, &cv, &cf, DEFAULT_DEPTH_TOL_M).unwrap();
        check_visibility(&vis, &face_cosines(eye, &cv, &cf), "cube");
    }
}

#[test]
fn occluded_front_facing_vertices_are_invisible() {
    // Sphere B behind sphere A as seen from the camera.
    let eye = Vec3::new(0.0, 0.0, 5.0);
    let c = Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 200.0, 200.0, 192, 192).unwrap();
    let (mut v, mut f) = uv_sphere(Vec3::ZERO, 32, 64, |_, _| 0.6);
    let nb = v.len() as u32;
    let centre_b = Vec3::new(0.5, 0.0, -2.0);
    let (vb, fb) = uv_sphere(centre_b, 32, 64, |_, _| 1.0);
    v.extend(&vb);
    f.extend(fb.iter().map(|t| t.map(|k| k + nb)));
    let fr = rasterize(&c, &v, &f).unwrap();
    let vis = vertex_visibility(&c, &v, &f, &fr, DEFAULT_DEPTH_TOL_M).unwrap();
    let (mut hidden, mut shown) = (0, 0);
    for (i, p) in vb.iter().enumerate() {
        let s = vis[nb as usize + i];
        let cos = front_facing_cos(eye, *p, (*p - centre_b).normalize());
        // Distance from sphere A's centre (origin) to the line eye -> p.
        let d = (p - eye).normalize();
        let line_dist = (-eye - d * (-eye).dot(d)).length();
        // A's silhouette is ~24 px in radius; stay 10% (2.4 px) away from it on both sides,
        // beyond the one-pixel neighbourhood the visibility test consults.
        if line_dist < 0.6 * 0.9 {
            assert_eq!(s, 0, "B vertex {i} behind A is visible");
            hidden += 1;
        } else if line_dist > 0.6 * 1.1 && cos > 0.2 {
            assert_eq!(s, 1, "B vertex {i} in plain view is invisible");
            shown += 1;
        }
    }
    assert!(hidden > 50 && shown > 50, "{hidden} {shown}");
    // Wrong fragment size: an error.
    let other = Camera { width: 10, ..c };
    assert!(vertex_visibility(&other, &v, &f, &fr, 0.01).is_err());
}
