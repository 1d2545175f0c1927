//! Pinhole cameras with OpenCV's 5-coefficient lens distortion.
//!
//! World-to-camera is `x_c = R x_w + T` (metres), pixels are `(u, v) = K (x_c / z_c)` with u
//! right and v down; `z_c > 0` is in front of the camera. `K` is upper triangular with last row
//! `(0, 0, 1)`: `[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`. glam matrices are column-major, so
//! `k.x_axis.x == fx`, `k.y_axis.x == s`, `k.z_axis == (cx, cy, 1)`.
//!
//! Distortion follows OpenCV: `dist = [k1, k2, p1, p2, k3]` acting on normalised coordinates
//! `(x, y) = (x_c / z_c, y_c / z_c)`:
//! `x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)`,
//! `y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y`.
//!
//! Pixel convention (OpenCV's and ZJU-MoCap's, used by the whole project): the centre of the
//! pixel with index `(i, j)` (column `i`, row `j`) is at image coordinate
//! `(i, j) + PIXEL_CENTRE_OFFSET = (i, j)`, not `(i + 0.5, j + 0.5)`; the pixel covers
//! `[i - 0.5, i + 0.5) x [j - 0.5, j + 0.5)`. See [`PIXEL_CENTRE_OFFSET`].
//!
//! The datasets' images are undistorted with `cv2.undistort(img, K, D)` when loaded; after that
//! the ideal pinhole [`Camera::project`] describes them. [`UndistortMap`] reproduces
//! `cv2.undistort` (bilinear, constant black border) in the same convention.

use glam::{Mat3, Vec2, Vec3};
use image::RgbImage;
use rayon::prelude::*;

/// Where the centre of a pixel lies relative to its integer index, in pixels: the centre of
/// pixel `(i, j)` (column `i`, row `j`) is at image coordinate `(i + PIXEL_CENTRE_OFFSET,
/// j + PIXEL_CENTRE_OFFSET)`.
///
/// The project follows OpenCV and ZJU-MoCap: the offset is 0, so a pixel's index *is* its
/// centre and the pixel covers `[i - 0.5, i + 0.5)`; the image spans `[-0.5, W - 0.5)`. Real
/// datasets' `K` are calibrated in this convention, NHP casts its rays through integer pixel
/// coordinates, and `cv2.undistort` samples at integer coordinates. The rasteriser tests
/// coverage at these centres and `image_rays` / `mask_at_box` cast rays through them, so a
/// rendered pixel and the ray of the same pixel agree. (OpenGL and `grid_sample` with
/// `align_corners = false` instead put centres at `i + 0.5`; convert at those boundaries.)
pub const PIXEL_CENTRE_OFFSET: f32 = 0.0;

/// Points closer than this to the camera plane (`z_c`, metres) have no pixel: their projection
/// would overflow (subnormal depths) or be meaningless.
pub const PROJECT_MIN_DEPTH_M: f32 = 1e-6;

/// How far a rotation may be from orthonormal (`|R R^T - I|` entrywise) and still be accepted:
/// rotations stored as float32 text round at ~1e-7, hand-edited ones at ~1e-4.
pub const ROTATION_TOL: f32 = 1e-3;

/// Iterations of the fixed-point inverse of the distortion model (OpenCV uses 5 by default;
/// more are needed for strong distortion, and the loop stops at convergence anyway).
pub const UNDISTORT_MAX_ITERS: usize = 30;

/// Convergence threshold of the distortion inverse in normalised units (about 1e-4 pixels at
/// a focal length of 1000 pixels).
pub const UNDISTORT_CONVERGED: f32 = 1e-7;

/// A camera error, naming the offending field and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    #[error("camera field `{field}`: expected {expected}, got {got}")]
    Invalid {
        field: &'static str,
        expected: &'static str,
        got: String,
    },
    #[error(
        "{what}: image is {got_width}x{got_height} with {got_len} values, expected \
         {width}x{height}x{channels} = {} values (camera width x height x channels)",
        *width as usize * *height as usize * *channels
    )]
    ImageSize {
        what: &'static str,
        got_width: u32,
        got_height: u32,
        got_len: usize,
        width: u32,
        height: u32,
        channels: usize,
    },
}

fn invalid(field: &'static str, expected: &'static str, got: impl std::fmt::Debug) -> CameraError {
    CameraError::Invalid {
        field,
        expected,
        got: format!("{got:?}"),
    }
}

/// A calibrated camera: intrinsics `k` (pixels), world-to-camera rotation `r` and translation
/// `t` (metres), OpenCV distortion `dist = [k1, k2, p1, p2, k3]`, image size in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// [3, 3] intrinsics, `[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`, pixels.
    pub k: Mat3,
    /// [3, 3] world-to-camera rotation.
    pub r: Mat3,
    /// [3] world-to-camera translation, metres.
    pub t: Vec3,
    /// OpenCV distortion `[k1, k2, p1, p2, k3]` of the raw (not yet undistorted) images.
    pub dist: [f32; 5],
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl Camera {
    /// A camera from its parts, validated with [`Camera::validate`].
    pub fn new(
        k: Mat3,
        r: Mat3,
        t: Vec3,
        dist: [f32; 5],
        width: u32,
        height: u32,
    ) -> Result<Self, CameraError> {
        let camera = Camera {
            k,
            r,
            t,
            dist,
            width,
            height,
        };
        camera.validate()?;
        Ok(camera)
    }

    /// A camera from row-major `K` and `R` as stored by OpenCV/numpy (`K[row][col]`), validated.
    pub fn from_rows(
        k_rows: [[f32; 3]; 3],
        r_rows: [[f32; 3]; 3],
        t: [f32; 3],
        dist: [f32; 5],
        width: u32,
        height: u32,
    ) -> Result<Self, CameraError> {
        let k = Mat3::from_cols_array_2d(&k_rows).transpose();
        let r = Mat3::from_cols_array_2d(&r_rows).transpose();
        Camera::new(k, r, Vec3::from(t), dist, width, height)
    }

    /// A distortion-free camera at `eye` looking at `target`, with `up` pointing up in the image
    /// (image v grows opposite to `up`), principal point at `(width / 2, height / 2)` (with
    /// [`PIXEL_CENTRE_OFFSET`] = 0 that is half a pixel right of and below the exact image
    /// centre `((width - 1) / 2, (height - 1) / 2)`).
    pub fn look_at(
        eye: Vec3,
        target: Vec3,
        up: Vec3,
        fx: f32,
        fy: f32,
        width: u32,
        height: u32,
    ) -> Result<Self, CameraError> {
        let forward = (target - eye)
            .try_normalize()
            .ok_or_else(|| invalid("target", "a finite point different from eye", target))?;
        let right = forward
            .cross(up)
            .try_normalize()
            .ok_or_else(|| invalid("up", "a finite direction not parallel to the view", up))?;
        let down = forward.cross(right);
        // Rows of R are the camera axes expressed in world coordinates.
        let r = Mat3::from_cols(right, down, forward).transpose();
        let t = -(r * eye);
        let k = Mat3::from_cols(
            Vec3::new(fx, 0.0, 0.0),
            Vec3::new(0.0, fy, 0.0),
            Vec3::new(width as f32 * 0.5, height as f32 * 0.5, 1.0),
        );
        Camera::new(k, r, t, [0.0; 5], width, height)
    }

    /// Checks that every value is finite, `fx, fy > 0`, `K`'s last row is `(0, 0, 1)` and its
    /// second row starts with 0, `R` is a rotation (within [`ROTATION_TOL`]) and the image is
    /// not empty.
    pub fn validate(&self) -> Result<(), CameraError> {
        self.validate_intrinsics()?;
        if !self.r.is_finite() {
            return Err(invalid("r", "finite values", self.r));
        }
        let rrt = self.r * self.r.transpose();
        let off = (rrt - Mat3::IDENTITY).abs().to_cols_array();
        if off.iter().any(|e| *e > ROTATION_TOL) || self.r.determinant() <= 0.0 {
            return Err(invalid("r", "an orthonormal rotation with det +1", self.r));
        }
        if !self.t.is_finite() {
            return Err(invalid("t", "finite values (metres)", self.t));
        }
        Ok(())
    }

    /// The part of [`Camera::validate`] about `k`, `dist` and the image size.
    pub fn validate_intrinsics(&self) -> Result<(), CameraError> {
        let k = &self.k;
        if !k.is_finite() {
            return Err(invalid("k", "finite values", *k));
        }
        if !(self.fx() > 0.0 && self.fy() > 0.0) {
            return Err(invalid("k", "fx > 0 and fy > 0", (self.fx(), self.fy())));
        }
        if k.x_axis.y != 0.0 || k.x_axis.z != 0.0 || k.y_axis.z != 0.0 || k.z_axis.z != 1.0 {
            return Err(invalid(
                "k",
                "K[1][0] = 0 and last row (0, 0, 1)",
                (k.x_axis.y, k.row(2)),
            ));
        }
        if self.dist.iter().any(|d| !d.is_finite()) {
            return Err(invalid("dist", "finite [k1, k2, p1, p2, k3]", self.dist));
        }
        if self.width == 0 || self.height == 0 {
            return Err(invalid(
                "width/height",
                "a non-empty image",
                (self.width, self.height),
            ));
        }
        Ok(())
    }

    /// Focal length along x, pixels.
    pub fn fx(&self) -> f32 {
        self.k.x_axis.x
    }
    /// Focal length along y, pixels.
    pub fn fy(&self) -> f32 {
        self.k.y_axis.y
    }
    /// Principal point x, pixels.
    pub fn cx(&self) -> f32 {
        self.k.z_axis.x
    }
    /// Principal point y, pixels.
    pub fn cy(&self) -> f32 {
        self.k.z_axis.y
    }
    /// Skew `K[0][1]`, pixels.
    pub fn skew(&self) -> f32 {
        self.k.y_axis.x
    }

    /// `R x_w + T`: world point (metres) to camera coordinates (metres).
    pub fn world_to_camera(&self, p_world: Vec3) -> Vec3 {
        self.r * p_world + self.t
    }

    /// `R^T (x_c - T)`: camera coordinates to world.
    pub fn camera_to_world(&self, p_camera: Vec3) -> Vec3 {
        self.r.transpose() * (p_camera - self.t)
    }

    /// The camera centre in world coordinates, `-R^T T` (metres).
    pub fn centre(&self) -> Vec3 {
        -(self.r.transpose() * self.t)
    }

    /// Pixel of a normalised image coordinate `(x_c / z_c, y_c / z_c)`.
    pub fn pixel_from_normalized(&self, n: Vec2) -> Vec2 {
        Vec2::new(
            self.fx() * n.x + self.skew() * n.y + self.cx(),
            self.fy() * n.y + self.cy(),
        )
    }

    /// Normalised image coordinate of a pixel (inverse of [`Camera::pixel_from_normalized`]).
    pub fn normalized_from_pixel(&self, uv: Vec2) -> Vec2 {
        let y = (uv.y - self.cy()) / self.fy();
        let x = (uv.x - self.cx() - self.skew() * y) / self.fx();
        Vec2::new(x, y)
    }

    /// Ideal pinhole pixel of a camera-frame point; `None` when `z_c <= PROJECT_MIN_DEPTH_M`.
    pub fn project_camera(&self, p_camera: Vec3) -> Option<Vec2> {
        if p_camera.z > PROJECT_MIN_DEPTH_M {
            Some(self.pixel_from_normalized(p_camera.truncate() / p_camera.z))
        } else {
            None
        }
    }

    /// Ideal pinhole projection (for undistorted images) of a world point: pixel and camera
    /// depth `z_c` (metres). `None` behind (or on) the camera plane.
    pub fn project(&self, p_world: Vec3) -> Option<(Vec2, f32)> {
        let pc = self.world_to_camera(p_world);
        self.project_camera(pc).map(|uv| (uv, pc.z))
    }

    /// Projection into the raw, distorted image (OpenCV model): pixel and camera depth.
    pub fn project_distorted(&self, p_world: Vec3) -> Option<(Vec2, f32)> {
        let pc = self.world_to_camera(p_world);
        if pc.z > PROJECT_MIN_DEPTH_M {
            let nd = self.distort_normalized(pc.truncate() / pc.z);
            Some((self.pixel_from_normalized(nd), pc.z))
        } else {
            None
        }
    }

    /// True when `0 <= u < width` and `0 <= v < height`. Note this is not the extent of the
    /// image's pixels under [`PIXEL_CENTRE_OFFSET`] = 0, `[-0.5, width - 0.5)`; to find the
    /// pixel a position falls in, round it (`(uv - PIXEL_CENTRE_OFFSET + 0.5).floor()`).
    pub fn contains_pixel(&self, uv: Vec2) -> bool {
        uv.x >= 0.0 && uv.y >= 0.0 && uv.x < self.width as f32 && uv.y < self.height as f32
    }

    /// Applies the OpenCV distortion to a normalised coordinate.
    pub fn distort_normalized(&self, n: Vec2) -> Vec2 {
        let [k1, k2, p1, p2, k3] = self.dist;
        let (x, y) = (n.x, n.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        Vec2::new(
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Inverts [`Camera::distort_normalized`] by fixed-point iteration (as OpenCV's
    /// `undistortPoints`): `x = (x_d - tangential(x)) / radial(x)`, starting at `x_d`, until the
    /// step is below [`UNDISTORT_CONVERGED`] or after [`UNDISTORT_MAX_ITERS`]. If the model
    /// folds over (radial factor <= 0) the distorted coordinate is returned unchanged.
    pub fn undistort_normalized(&self, nd: Vec2) -> Vec2 {
        let [k1, k2, p1, p2, k3] = self.dist;
        if self.dist == [0.0; 5] {
            return nd;
        }
        let mut n = nd;
        for _ in 0..UNDISTORT_MAX_ITERS {
            let (x, y) = (n.x, n.y);
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            if !(radial > 0.0) {
                return nd;
            }
            let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            let next = Vec2::new((nd.x - dx) / radial, (nd.y - dy) / radial);
            let step = (next - n).abs().max_element();
            n = next;
            if !(step > UNDISTORT_CONVERGED) {
                break;
            }
        }
        n
    }

    /// Pixel in the raw image -> pixel an ideal pinhole camera with the same `K` would see
    /// (`cv2.undistortPoints(..., P=K)`).
    pub fn undistort_pixel(&self, uv_distorted: Vec2) -> Vec2 {
        let n = self.undistort_normalized(self.normalized_from_pixel(uv_distorted));
        self.pixel_from_normalized(n)
    }

    /// Inverse of [`Camera::undistort_pixel`]: ideal pixel -> raw (distorted) pixel.
    pub fn distort_pixel(&self, uv_ideal: Vec2) -> Vec2 {
        let n = self.distort_normalized(self.normalized_from_pixel(uv_ideal));
        self.pixel_from_normalized(n)
    }

    /// [`Camera::undistort_pixel`] for a batch of [N] pixels.
    pub fn undistort_points(&self, pixels: &[Vec2]) -> Vec<Vec2> {
        pixels.iter().map(|p| self.undistort_pixel(*p)).collect()
    }

    /// The camera after resizing its images by `ratio` (as NHP does: `K[:2] *= ratio`, size
    /// `int(size * ratio)`, truncated). Distortion is unchanged (it acts on normalised
    /// coordinates).
    pub fn scaled(&self, ratio: f32) -> Result<Camera, CameraError> {
        if !(ratio.is_finite() && ratio > 0.0) {
            return Err(invalid("ratio", "a finite ratio > 0", ratio));
        }
        let width = (self.width as f64 * ratio as f64) as u32;
        let height = (self.height as f64 * ratio as f64) as u32;
        if width == 0 || height == 0 {
            return Err(invalid(
                "ratio",
                "a ratio leaving at least one pixel",
                (ratio, self.width, self.height),
            ));
        }
        let mut k = self.k;
        // First two rows: every column's x and y components.
        for col in [&mut k.x_axis, &mut k.y_axis, &mut k.z_axis] {
            col.x *= ratio;
            col.y *= ratio;
        }
        Ok(Camera {
            k,
            width,
            height,
            ..*self
        })
    }

    /// The map that undistorts this camera's raw images (see [`UndistortMap`]).
    pub fn undistort_map(&self) -> Result<UndistortMap, CameraError> {
        UndistortMap::new(self)
    }

    /// `cv2.undistort(image, K, dist)` for an RGB image of the camera's size.
    pub fn undistort_image(&self, image: &RgbImage) -> Result<RgbImage, CameraError> {
        self.undistort_map()?.remap_rgb(image)
    }

    /// `cv2.undistort` for an interleaved float image `[H, W, channels]` of the camera's size.
    pub fn undistort_channels(
        &self,
        data: &[f32],
        channels: usize,
    ) -> Result<Vec<f32>, CameraError> {
        self.undistort_map()?.remap_f32(data, channels)
    }
}

/// For every pixel of the undistorted output image, the raw-image coordinate it samples
/// (OpenCV `initUndistortRectifyMap` with `newCameraMatrix = K`, no rectification): output
/// pixel `(i, j)` -> normalise with `K` -> distort -> back to pixels with `K`. Coordinates use
/// OpenCV's convention (pixel index = pixel centre). Build once per camera, apply to the image
/// and the masks.
#[derive(Debug, Clone)]
pub struct UndistortMap {
    /// Output width, pixels.
    pub width: u32,
    /// Output height, pixels.
    pub height: u32,
    /// [H * W] raw-image sample position of each output pixel, row-major.
    pub source: Vec<Vec2>,
    /// True when the camera has no distortion (the remap is then a copy).
    pub identity: bool,
}

impl UndistortMap {
    /// Builds the map for `camera` (intrinsics validated).
    pub fn new(camera: &Camera) -> Result<Self, CameraError> {
        camera.validate_intrinsics()?;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut source = vec![Vec2::ZERO; w * h];
        source.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
            for (i, s) in row.iter_mut().enumerate() {
                *s = camera.distort_pixel(Vec2::new(i as f32, j as f32));
            }
        });
        Ok(UndistortMap {
            width: camera.width,
            height: camera.height,
            source,
            identity: camera.dist == [0.0; 5],
        })
    }

    fn check(
        &self,
        what: &'static str,
        got_width: u32,
        got_height: u32,
        got_len: usize,
        channels: usize,
    ) -> Result<(), CameraError> {
        let want = self.width as usize * self.height as usize * channels;
        if got_width != self.width || got_height != self.height || got_len != want || channels == 0
        {
            return Err(CameraError::ImageSize {
                what,
                got_width,
                got_height,
                got_len,
                width: self.width,
                height: self.height,
                channels,
            });
        }
        Ok(())
    }

    /// Undistorts an RGB image (bilinear, black outside, rounded to the nearest level).
    pub fn remap_rgb(&self, image: &RgbImage) -> Result<RgbImage, CameraError> {
        let (w, h) = image.dimensions();
        self.check("undistort rgb image", w, h, image.as_raw().len(), 3)?;
        let out = self.remap_u8(image.as_raw(), 3);
        RgbImage::from_raw(w, h, out).ok_or_else(|| invalid("image", "a consistent buffer", (w, h)))
    }

    /// Undistorts an interleaved float image `[H, W, channels]` (bilinear, 0 outside).
    pub fn remap_f32(&self, data: &[f32], channels: usize) -> Result<Vec<f32>, CameraError> {
        self.check(
            "undistort float image",
            self.width,
            self.height,
            data.len(),
            channels,
        )?;
        if self.identity {
            return Ok(data.to_vec());
        }
        let w = self.width as usize;
        let mut out = vec![0.0f32; data.len()];
        out.par_chunks_mut(w * channels)
            .zip(self.source.par_chunks(w))
            .for_each(|(row, src)| {
                for (px, s) in row.chunks_exact_mut(channels).zip(src) {
                    bilinear_zero_border(data, self.width, self.height, channels, *s, |c, v| {
                        px[c] += v
                    });
                }
            });
        Ok(out)
    }

    fn remap_u8(&self, data: &[u8], channels: usize) -> Vec<u8> {
        if self.identity {
            return data.to_vec();
        }
        let w = self.width as usize;
        let mut out = vec![0u8; data.len()];
        // The caller passes 3 (RGB) channels; `acc` holds up to 4.
        out.par_chunks_mut(w * channels)
            .zip(self.source.par_chunks(w))
            .for_each(|(row, src)| {
                let mut acc = [0.0f32; 4];
                for (px, s) in row.chunks_exact_mut(channels).zip(src) {
                    acc.iter_mut().for_each(|a| *a = 0.0);
                    bilinear_zero_border(data, self.width, self.height, channels, *s, |c, v| {
                        acc[c] += v
                    });
                    for (o, a) in px.iter_mut().zip(acc.iter()) {
                        *o = (a.round()).clamp(0.0, 255.0) as u8;
                    }
                }
            });
        out
    }
}

/// Bilinear sample at `s` (pixel index = centre) of an interleaved image; taps outside the
/// image count as 0 (OpenCV `BORDER_CONSTANT`). Calls `add(channel, weighted value)` per tap.
fn bilinear_zero_border<T: Copy + Into<f32>>(
    data: &[T],
    width: u32,
    height: u32,
    channels: usize,
    s: Vec2,
    mut add: impl FnMut(usize, f32),
) {
    if !s.is_finite() {
        return;
    }
    let (w, h) = (width as i64, height as i64);
    let x0f = s.x.floor();
    let y0f = s.y.floor();
    // Far outside: no tap can land (also keeps the integer conversion in range).
    if x0f < -1.0 || y0f < -1.0 || x0f >= w as f32 || y0f >= h as f32 {
        return;
    }
    let (fx, fy) = (s.x - x0f, s.y - y0f);
    let (x0, y0) = (x0f as i64, y0f as i64);
    let taps = [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x0 + 1, y0, fx * (1.0 - fy)),
        (x0, y0 + 1, (1.0 - fx) * fy),
        (x0 + 1, y0 + 1, fx * fy),
    ];
    for (x, y, wgt) in taps {
        if x < 0 || y < 0 || x >= w || y >= h || wgt == 0.0 {
            continue;
        }
        let base = (y as usize * width as usize + x as usize) * channels;
        for c in 0..channels {
            add(c, data[base + c].into() * wgt);
        }
    }
}
