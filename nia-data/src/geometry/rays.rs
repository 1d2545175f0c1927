//! Camera rays, axis-aligned boxes and their intersection (NeRF's near/far and NHP's
//! `mask_at_box`).
//!
//! A ray leaves the camera centre through a pixel position of the ideal pinhole (undistorted)
//! image. Pixel convention: [`PIXEL_CENTRE_OFFSET`] (OpenCV / ZJU-MoCap, as NHP casts its
//! rays), i.e. pixel `(i, j)` has its centre at image coordinate `(i, j)`; [`image_rays`] and
//! [`mask_at_box`] cast one ray through each such centre, the same points the rasteriser tests
//! coverage at. Directions are unit vectors, so ray parameters `t` are distances in metres
//! along the ray (not camera depths).

use crate::geometry::camera::{Camera, PIXEL_CENTRE_OFFSET};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// Direction components at or below this magnitude make the ray parallel to that slab: the
/// division `(plane - origin) / dir` would give infinities (and `0 / 0 = NaN` for an origin on
/// the plane), so the slab is tested by containment instead.
pub const PARALLEL_EPS: f32 = 1e-12;

/// Margin (pixels) around the bounding rectangle of a box's projected corners within which
/// [`mask_at_box`] still tests pixels: the projection and the per-pixel ray test round
/// differently (f32, ~1e-4 pixels at 512 pixels), so a pixel centre a hair outside the
/// rectangle may still hit; one pixel is far more than that round-off.
pub const BOX_RECT_MARGIN_PX: f32 = 1.0;

/// A ray `origin + t * dir`, `dir` a unit vector, `t` in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// [3] world, metres.
    pub origin: Vec3,
    /// [3] world, unit length.
    pub dir: Vec3,
}

impl Ray {
    /// The point at distance `t` (metres) along the ray.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + t * self.dir
    }
}

/// The ray through a (continuous) pixel position of the ideal pinhole image: pass
/// [`pixel_centre`]`(i, j)` (that is `(i, j)`, see [`PIXEL_CENTRE_OFFSET`]) for the centre of
/// pixel `(i, j)`.
pub fn pixel_ray(camera: &Camera, pixel: Vec2) -> Ray {
    let rt = camera.r.transpose();
    ray_with(camera, rt, camera.centre(), pixel)
}

/// The pixels `[x0, x1) x [y0, y1)` outside which no ray through a pixel's footprint (its
/// square, centre +- 0.5) can meet `aabb`: the bounding rectangle of the box's projected
/// corners, one pixel wider on each side, clipped to the image. When a corner is not in front
/// of the camera (the camera inside or beside the box) the whole image. The projection of a
/// box in front of a pinhole camera is the convex hull of its projected corners, so a ray
/// through a pixel outside the rectangle misses the box: only the ray-box tests are saved.
pub fn box_pixel_bounds(camera: &Camera, aabb: &Aabb) -> ([usize; 2], [usize; 2]) {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let whole = ([0, w], [0, h]);
    let mut lo = Vec2::splat(f32::INFINITY);
    let mut hi = Vec2::splat(f32::NEG_INFINITY);
    for corner in aabb.corners() {
        let p = camera.world_to_camera(corner);
        if !(p.z > BOX_BOUNDS_MIN_DEPTH_M) {
            return whole;
        }
        match camera.project_camera(p) {
            Some(uv) if uv.is_finite() => {
                lo = lo.min(uv);
                hi = hi.max(uv);
            }
            _ => return whole,
        }
    }
    // Pixel x's footprint spans x + PIXEL_CENTRE_OFFSET +- 0.5; one more pixel of margin.
    let lo = lo - Vec2::splat(PIXEL_CENTRE_OFFSET + 1.5);
    let hi = hi - Vec2::splat(PIXEL_CENTRE_OFFSET - 1.5);
    let clip = |v: f32, n: usize| v.clamp(0.0, n as f32) as usize;
    let x = [clip(lo.x.floor(), w), clip(hi.x.ceil() + 1.0, w)];
    let y = [clip(lo.y.floor(), h), clip(hi.y.ceil() + 1.0, h)];
    (x, y)
}

/// Depth in front of the camera every corner of the box must have for [`box_pixel_bounds`]
/// to narrow the pixels, metres.
const BOX_BOUNDS_MIN_DEPTH_M: f32 = 1e-3;

/// Image coordinate of the centre of pixel `(x, y)` (column, row):
/// `(x, y) + PIXEL_CENTRE_OFFSET`, i.e. `(x, y)`.
#[inline]
pub fn pixel_centre(x: usize, y: usize) -> Vec2 {
    Vec2::new(x as f32, y as f32) + Vec2::splat(PIXEL_CENTRE_OFFSET)
}

#[inline]
fn ray_with(camera: &Camera, rt: glam::Mat3, origin: Vec3, pixel: Vec2) -> Ray {
    let n = camera.normalized_from_pixel(pixel);
    let dir = (rt * n.extend(1.0)).normalize_or_zero();
    Ray { origin, dir }
}

/// [H * W] rays through every pixel centre ([`pixel_centre`]), row-major (`y * width + x`).
pub fn image_rays(camera: &Camera) -> Vec<Ray> {
    let rt = camera.r.transpose();
    let origin = camera.centre();
    let w = camera.width as usize;
    let mut rays = vec![
        Ray {
            origin,
            dir: Vec3::Z
        };
        w * camera.height as usize
    ];
    if w == 0 {
        return rays;
    }
    rays.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, ray) in row.iter_mut().enumerate() {
            *ray = ray_with(camera, rt, origin, pixel_centre(x, y));
        }
    });
    rays
}

/// R rays of one camera clipped to a box: the batch type every stage of the ray path takes
/// (training rays, whole-image rays, chunks of either). Structure of arrays, all of length R.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RayBundle {
    /// [R] world origins, metres.
    pub origins: Vec<Vec3>,
    /// [R] unit world directions.
    pub dirs: Vec<Vec3>,
    /// [R] distance to the box entry, metres.
    pub near: Vec<f32>,
    /// [R] distance to the box exit, metres (`>= near`).
    pub far: Vec<f32>,
    /// [R] pixel index `y * width + x` of each ray in its camera's image.
    pub pixels: Vec<u32>,
}

impl RayBundle {
    /// Number of rays R.
    pub fn len(&self) -> usize {
        self.origins.len()
    }

    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }

    /// Appends `ray`, clipped to `[near, far]`, cast through pixel `pixel`.
    pub fn push(&mut self, ray: Ray, near: f32, far: f32, pixel: u32) {
        self.origins.push(ray.origin);
        self.dirs.push(ray.dir);
        self.near.push(near);
        self.far.push(far);
        self.pixels.push(pixel);
    }

    /// The rays of `camera`'s pixels (all, or those where `mask` ([H * W]) is true) whose
    /// centre ray crosses `aabb` over a positive length, in pixel order: one ray per pixel
    /// ([`Self::through_pixel_footprints`] with `supersample` 1).
    pub fn through_pixels(camera: &Camera, aabb: &Aabb, mask: Option<&[bool]>) -> Self {
        Self::through_pixel_footprints(camera, aabb, mask, 1)
    }

    /// `s x s` rays per pixel (`s = supersample`, at least 1), through the centres of the
    /// `s x s` equal cells of the pixel's square: offsets `((i + 1/2) / s - 1/2, (j + 1/2) / s -
    /// 1/2)` pixels from its centre, `i, j < s`, row by row (`s = 1`: the centre ray alone). A
    /// pixel (all, or those where `mask` ([H * W]) is true) is kept when at least one of its rays
    /// crosses `aabb` over a positive length; then all `s * s` of them are, those that miss the
    /// box as zero-length rays (`near == far`, which render black with zero opacity), so the
    /// mean over a pixel's rays is the box filter of its square over a black background (the
    /// pixel's value for `nia_model::renderer::image::render_image`). Pixels in order, each pixel's rays
    /// together.
    pub fn through_pixel_footprints(
        camera: &Camera,
        aabb: &Aabb,
        mask: Option<&[bool]>,
        supersample: usize,
    ) -> Self {
        let w = camera.width as usize;
        let s = supersample.max(1);
        let offsets: Vec<Vec2> = (0..s * s)
            .map(|k| {
                let cell = |i: usize| (i as f32 + 0.5) / s as f32 - 0.5;
                Vec2::new(cell(k % s), cell(k / s))
            })
            .collect();
        let mut bundle = RayBundle::default();
        let mut footprint = Vec::with_capacity(s * s);
        let ([x0, x1], [y0, y1]) = box_pixel_bounds(camera, aabb);
        for p in (y0..y1).flat_map(|y| (x0..x1).map(move |x| y * w + x)) {
            if mask.is_some_and(|m| !m.get(p).copied().unwrap_or(false)) {
                continue;
            }
            let centre = pixel_centre(p % w, p / w);
            footprint.clear();
            footprint.extend(offsets.iter().map(|&offset| {
                let ray = pixel_ray(camera, centre + offset);
                let interval = near_far(&ray, aabb).filter(|(near, far)| far > near);
                (ray, interval)
            }));
            if footprint.iter().all(|(_, interval)| interval.is_none()) {
                continue;
            }
            for &(ray, interval) in &footprint {
                let (near, far) = interval.unwrap_or((0.0, 0.0));
                bundle.push(ray, near, far, p as u32);
            }
        }
        bundle
    }

    /// Rays `range` as their own bundle.
    pub fn slice(&self, range: std::ops::Range<usize>) -> RayBundle {
        RayBundle {
            origins: self.origins[range.clone()].to_vec(),
            dirs: self.dirs[range.clone()].to_vec(),
            near: self.near[range.clone()].to_vec(),
            far: self.far[range.clone()].to_vec(),
            pixels: self.pixels[range].to_vec(),
        }
    }

    /// Rays `index` (positions in this bundle, in that order) as their own bundle.
    ///
    /// # Panics
    /// When an index is out of range (as slicing does).
    pub fn select(&self, index: &[usize]) -> RayBundle {
        RayBundle {
            origins: index.iter().map(|&r| self.origins[r]).collect(),
            dirs: index.iter().map(|&r| self.dirs[r]).collect(),
            near: index.iter().map(|&r| self.near[r]).collect(),
            far: index.iter().map(|&r| self.far[r]).collect(),
            pixels: index.iter().map(|&r| self.pixels[r]).collect(),
        }
    }

    /// Checks that every field holds R values and that R > 0; the message names the fields.
    pub fn check(&self) -> Result<(), String> {
        let r = self.len();
        let lengths = [
            self.dirs.len(),
            self.near.len(),
            self.far.len(),
            self.pixels.len(),
        ];
        if r == 0 || lengths.iter().any(|&l| l != r) {
            return Err(format!(
                "expected a non-empty bundle with equal lengths, got origins {r}, dirs {}, near {}, far {}, pixels {}",
                lengths[0], lengths[1], lengths[2], lengths[3]
            ));
        }
        Ok(())
    }
}

/// An axis-aligned box, world metres. `min <= max` componentwise for a non-empty box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// [3] lower corner, metres.
    pub min: Vec3,
    /// [3] upper corner, metres.
    pub max: Vec3,
}

impl Aabb {
    pub fn new(min: Vec3, max: Vec3) -> Self {
        Aabb { min, max }
    }

    /// The tight box of a point set; `None` when it is empty or holds a non-finite point.
    pub fn from_points(points: &[Vec3]) -> Option<Aabb> {
        let first = *points.first()?;
        let mut b = Aabb::new(first, first);
        for p in points {
            if !p.is_finite() {
                return None;
            }
            b.min = b.min.min(*p);
            b.max = b.max.max(*p);
        }
        Some(b)
    }

    /// Each face moved outward by `frac` times the box's extent along its axis, so every extent
    /// grows by `2 * frac` (the centre stays).
    pub fn enlarged(&self, frac: f32) -> Aabb {
        let pad = (self.max - self.min) * frac;
        Aabb::new(self.min - pad, self.max + pad)
    }

    /// Each face moved outward by `margin_m` metres (NHP pads the SMPL box by 0.05 m).
    pub fn padded(&self, margin_m: f32) -> Aabb {
        Aabb::new(
            self.min - Vec3::splat(margin_m),
            self.max + Vec3::splat(margin_m),
        )
    }

    /// `max - min`, metres.
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }

    /// `(min + max) / 2`, metres.
    pub fn centre(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Whether `p` lies in the closed box.
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// The 8 corners, bit `i` of the index picking `max` along axis `i`.
    pub fn corners(&self) -> [Vec3; 8] {
        std::array::from_fn(|i| {
            Vec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            )
        })
    }
}

/// Slab intersection of a ray with a closed box: `(near, far)` distances along the ray, with
/// `near` clamped to 0 (a ray starting inside has `near = 0`). `None` when the ray misses, the
/// box is behind the origin, the overlap has zero length (touching an edge or corner), the
/// direction is zero, or anything is NaN. A direction component with
/// `|d| <= PARALLEL_EPS` is handled as parallel to that slab (inside the slab: no constraint;
/// outside: miss), so no NaN arises. Rays sliding inside a face plane count as hits.
pub fn near_far(ray: &Ray, aabb: &Aabb) -> Option<(f32, f32)> {
    let mut near = 0.0f32;
    let mut far = f32::INFINITY;
    let mut any_axis = false;
    for axis in 0..3 {
        let o = ray.origin[axis];
        let d = ray.dir[axis];
        let (lo, hi) = (aabb.min[axis], aabb.max[axis]);
        if d.abs() <= PARALLEL_EPS {
            // `!(a <= b)` rather than `a > b` so that NaN counts as outside.
            if !(o >= lo && o <= hi) {
                return None;
            }
            continue;
        }
        if d.is_nan() {
            return None;
        }
        any_axis = true;
        let inv = 1.0 / d;
        let (mut t0, mut t1) = ((lo - o) * inv, (hi - o) * inv);
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        // `f32::max/min` would silently skip a NaN bound (NaN origin or box): reject it.
        if t0.is_nan() || t1.is_nan() {
            return None;
        }
        near = near.max(t0);
        far = far.min(t1);
        if !(far > near) {
            return None;
        }
    }
    if any_axis && far > near && far.is_finite() {
        Some((near, far))
    } else {
        None
    }
}

/// NHP's `mask_at_box`: [H * W] row-major, true for pixels whose centre ray (through
/// [`pixel_centre`]) hits the box (in front of the camera). This is the projection of the 3D
/// box, i.e. the convex hull of its 8 projected corners when the box is in front of the
/// camera, computed exactly by a ray/box test per pixel. When every corner is in front of the
/// camera only the pixels whose centres lie in the corners' bounding rectangle (plus
/// [`BOX_RECT_MARGIN_PX`]) are tested: no ray outside the hull can hit.
pub fn mask_at_box(camera: &Camera, aabb: &Aabb) -> Vec<bool> {
    let rt = camera.r.transpose();
    let origin = camera.centre();
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut mask = vec![false; w * h];
    if w == 0 || h == 0 {
        return mask;
    }
    let (mut x0, mut x1, mut y0, mut y1) = (0usize, w, 0usize, h);
    let projected: Option<Vec<Vec2>> = aabb
        .corners()
        .iter()
        .map(|c| camera.project(*c).map(|(uv, _)| uv))
        .collect();
    if let Some(uv) = projected.filter(|uv| uv.iter().all(|p| p.is_finite())) {
        let lo = uv.iter().fold(Vec2::INFINITY, |m, p| m.min(*p));
        let hi = uv.iter().fold(Vec2::NEG_INFINITY, |m, p| m.max(*p));
        // Pixel i is tested when its centre i + PIXEL_CENTRE_OFFSET lies in
        // [lo - margin, hi + margin]: i from floor(lo - offset - margin) to
        // floor(hi - offset + margin), the end exclusive after + 1.
        let (lo, hi) = (
            lo - (PIXEL_CENTRE_OFFSET + BOX_RECT_MARGIN_PX),
            hi - (PIXEL_CENTRE_OFFSET - BOX_RECT_MARGIN_PX),
        );
        let clamp = |v: f32, n: usize| v.clamp(0.0, n as f32) as usize;
        x0 = clamp(lo.x.floor(), w);
        x1 = clamp(hi.x.floor() + 1.0, w);
        y0 = clamp(lo.y.floor(), h);
        y1 = clamp(hi.y.floor() + 1.0, h);
    }
    if x0 >= x1 || y0 >= y1 {
        return mask;
    }
    mask[y0 * w..y1 * w]
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(dy, row)| {
            let y = y0 + dy;
            for (x, m) in row.iter_mut().enumerate().take(x1).skip(x0) {
                let ray = ray_with(camera, rt, origin, pixel_centre(x, y));
                *m = near_far(&ray, aabb).is_some();
            }
        });
    mask
}
