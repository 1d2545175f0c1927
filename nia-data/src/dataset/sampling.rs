//! Training ray sampling (NHP's `sample_ray_h36m`, docs/method.md "Data" and "Protocol").
//!
//! For one target image:
//! 1. the scene box is the SMPL vertex bounds padded ([`BoxPadding`]); a pixel is a candidate
//!    only if its centre ray hits the box (`mask_at_box`), so rays that miss it never reach
//!    the network;
//! 2. the band of `border_px` pixels around the mask border (dilation minus erosion with a
//!    `border_px x border_px` square, as `cv2.erode`/`cv2.dilate`) is excluded: masks are
//!    unreliable there;
//! 3. `floor(n * body_fraction)` rays are drawn (with replacement, like NHP's `randint`) among
//!    the foreground candidates, the rest among all candidates;
//! 4. each ray carries its near/far distances to the box and its ground-truth colour.
//!
//! NHP computes the border band on the 1024-pixel mask before halving it; here it is computed
//! on the image being sampled, so `border_px` is in the pixels of that image.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::geometry::camera::Camera;
use crate::geometry::rays::{mask_at_box, near_far, pixel_ray, Aabb, RayBundle};
use crate::rng::Rng;

/// NHP's border band: a 5x5 erode/dilate kernel.
pub const NHP_BORDER_PX: usize = 5;
/// NHP's share of rays drawn on the body (`body_sample_ratio`).
pub const NHP_BODY_FRACTION: f32 = 0.5;
/// Rays per image per step (NHP and NIA `N_rand`).
pub const NHP_RAYS_PER_IMAGE: usize = 1024;
/// NHP pads the SMPL bounds along the world z axis (up in ZJU-MoCap) by 5 cm
/// (`cfg.big_box = False`: `min_xyz[2] -= 0.05; max_xyz[2] += 0.05`).
pub const NHP_BOX_PADDING_M: [f32; 3] = [0.0, 0.0, 0.05];

/// A sampling error.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SamplingError {
    #[error("ray sampling `{field}`: expected {expected}, got {got}")]
    Invalid {
        field: &'static str,
        expected: String,
        got: String,
    },
    #[error(
        "ray sampling: no pixel of the {width}x{height} image both hits the body box and lies \
         outside the mask border band (box {min:?}..{max:?})"
    )]
    NoCandidates {
        width: u32,
        height: u32,
        min: [f32; 3],
        max: [f32; 3],
    },
}

/// How the SMPL bounds are enlarged into the scene box: first by `fraction` of the extent
/// (per side), then by `metres` per axis (per side).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BoxPadding {
    #[serde(default)]
    pub fraction: f32,
    #[serde(default)]
    pub metres: [f32; 3],
}

impl BoxPadding {
    /// NHP's box: `z` +- 5 cm ([`NHP_BOX_PADDING_M`]).
    pub fn nhp() -> Self {
        BoxPadding {
            fraction: 0.0,
            metres: NHP_BOX_PADDING_M,
        }
    }

    /// The padded box of `vertices` ([V] world metres); `None` for an empty or non-finite set.
    pub fn body_box(&self, vertices: &[Vec3]) -> Option<Aabb> {
        let b = Aabb::from_points(vertices)?.enlarged(self.fraction);
        let m = Vec3::from(self.metres);
        Some(Aabb::new(b.min - m, b.max + m))
    }
}

impl Default for BoxPadding {
    fn default() -> Self {
        Self::nhp()
    }
}

/// Ray sampling settings (NHP defaults).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RaySamplingConfig {
    /// Rays per image.
    pub rays_per_image: usize,
    /// Share of the rays drawn inside the mask, in [0, 1].
    pub body_fraction: f32,
    /// Side of the erode/dilate square whose difference is excluded, pixels (0: none).
    pub border_px: usize,
    /// Rays drawn in square patches of this side (0: one pixel at a time, NHP's): the patches'
    /// pixels in row-major order, patch after patch, each patch inside the body box, for a loss
    /// on patches (`train.ssim_patch_px`). The border band does not apply to patches.
    #[serde(default)]
    pub patch_px: usize,
}

impl Default for RaySamplingConfig {
    fn default() -> Self {
        RaySamplingConfig {
            rays_per_image: NHP_RAYS_PER_IMAGE,
            body_fraction: NHP_BODY_FRACTION,
            border_px: NHP_BORDER_PX,
            patch_px: 0,
        }
    }
}

/// A batch of training rays of one image with their ground truth.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TrainRays {
    /// [N] the rays (camera centre origins, clipped to the box, with their pixels).
    pub rays: RayBundle,
    /// [N] ground-truth colour in [0, 1].
    pub rgb: Vec<[f32; 3]>,
    /// [N] whether the pixel is foreground.
    pub on_body: Vec<bool>,
}

impl TrainRays {
    pub fn len(&self) -> usize {
        self.rays.len()
    }
    pub fn is_empty(&self) -> bool {
        self.rays.is_empty()
    }
}

/// The pixels within the mask's border band: dilation minus erosion of `mask` ([H * W]) with a
/// `border_px x border_px` square centred on the pixel (for even sizes OpenCV's anchor, the
/// square spans `-size/2 .. size - 1 - size/2`). Pixels outside the image do not take part
/// (`cv2.erode`/`cv2.dilate` default borders). An even size gives a one-sided band: with 2 it
/// is the ring just outside the mask on the bottom and right edges and the ring just inside
/// on the top and left, so the model never sees the background next to half of the outline;
/// odd sizes (NHP's 5) are symmetric.
pub fn border_band(mask: &[bool], width: usize, height: usize, border_px: usize) -> Vec<bool> {
    if border_px == 0 {
        return vec![false; mask.len()];
    }
    let lo = (border_px / 2) as isize;
    let hi = (border_px - 1 - border_px / 2) as isize;
    // Separable: per row, any/all over the horizontal window; then over the vertical window.
    let (row_any, row_all) = window_any_all(mask, mask, width, height, [lo, hi], 0);
    let (any, all) = window_any_all(&row_any, &row_all, width, height, [lo, hi], 1);
    any.iter()
        .zip(&all)
        .map(|(&any, &all)| any && !all)
        .collect()
}

/// One pass of [`border_band`]: per pixel of a `width x height` image, whether any of `any_in`
/// and whether all of `all_in` hold over the pixels at offsets `-lo..=hi` (`[lo, hi]`) along
/// `axis` (0: x, 1: y) that lie inside the image.
fn window_any_all(
    any_in: &[bool],
    all_in: &[bool],
    width: usize,
    height: usize,
    [lo, hi]: [isize; 2],
    axis: usize,
) -> (Vec<bool>, Vec<bool>) {
    let (w, h) = (width as isize, height as isize);
    let mut any_out = vec![false; any_in.len()];
    let mut all_out = vec![false; any_in.len()];
    for y in 0..h {
        for x in 0..w {
            let (mut any, mut all) = (false, true);
            for d in -lo..=hi {
                let (xx, yy) = if axis == 0 { (x + d, y) } else { (x, y + d) };
                if xx < 0 || xx >= w || yy < 0 || yy >= h {
                    continue;
                }
                any |= any_in[(yy * w + xx) as usize];
                all &= all_in[(yy * w + xx) as usize];
            }
            any_out[(y * w + x) as usize] = any;
            all_out[(y * w + x) as usize] = all;
        }
    }
    (any_out, all_out)
}

/// Draws training rays from one image (module docs). `image`: [H * W * 3] in [0, 1]; `mask`:
/// [H * W] foreground; `body_box`: the padded SMPL box ([`BoxPadding::body_box`]). The same
/// `rng` state gives the same rays.
pub fn sample_rays(
    camera: &Camera,
    image: &[f32],
    mask: &[bool],
    body_box: &Aabb,
    config: &RaySamplingConfig,
    rng: &mut Rng,
) -> Result<TrainRays, SamplingError> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    if image.len() != w * h * 3 {
        return Err(SamplingError::Invalid {
            field: "image",
            expected: format!("{w}x{h}x3 = {} values", w * h * 3),
            got: format!("{}", image.len()),
        });
    }
    if mask.len() != w * h {
        return Err(SamplingError::Invalid {
            field: "mask",
            expected: format!("{w}x{h} = {} values", w * h),
            got: format!("{}", mask.len()),
        });
    }
    if !(0.0..=1.0).contains(&config.body_fraction) {
        return Err(SamplingError::Invalid {
            field: "body_fraction",
            expected: "a share in [0, 1]".into(),
            got: format!("{}", config.body_fraction),
        });
    }
    let in_box = mask_at_box(camera, body_box);
    let band = border_band(mask, w, h, config.border_px);
    let mut body = Vec::new();
    let mut anywhere = Vec::new();
    for i in 0..w * h {
        if in_box[i] && !band[i] {
            anywhere.push(i as u32);
            if mask[i] {
                body.push(i as u32);
            }
        }
    }
    if anywhere.is_empty() {
        return Err(SamplingError::NoCandidates {
            width: camera.width,
            height: camera.height,
            min: body_box.min.to_array(),
            max: body_box.max.to_array(),
        });
    }
    if config.patch_px > 0 {
        let candidates = Candidates {
            in_box: &in_box,
            body: &body,
            anywhere: &anywhere,
        };
        return sample_patches(camera, image, mask, body_box, config, &candidates, rng);
    }
    let n = config.rays_per_image;
    let n_body = if body.is_empty() {
        0
    } else {
        (n as f32 * config.body_fraction).floor() as usize
    };
    let mut rays = TrainRays::default();
    for k in 0..n {
        let pool = if k < n_body { &body } else { &anywhere };
        let pixel = pool[rng.below(pool.len())];
        let (x, y) = (pixel as usize % w, pixel as usize / w);
        let ray = pixel_ray(camera, crate::geometry::rays::pixel_centre(x, y));
        // Candidates come from the same ray/box test, so this always hits; a miss (it cannot
        // happen) would only shorten the batch rather than produce a bad ray.
        let Some((near, far)) = near_far(&ray, body_box) else {
            continue;
        };
        let p = pixel as usize * 3;
        rays.rays.push(ray, near, far, pixel);
        rays.rgb.push([image[p], image[p + 1], image[p + 2]]);
        rays.on_body.push(mask[pixel as usize]);
    }
    Ok(rays)
}

/// Where rays may start: `[H * W]` inside the body box, and the pixels (indices) on the
/// person and anywhere in the box.
struct Candidates<'a> {
    in_box: &'a [bool],
    body: &'a [u32],
    anywhere: &'a [u32],
}

/// Tries for a patch whose every pixel lies in the body box before the draw gives up.
const PATCH_TRIES: usize = 1000;

/// [`sample_rays`] in `patch_px`-square patches (see [`RaySamplingConfig::patch_px`]):
/// `rays_per_image / patch_px^2` patches (at least one), `body_fraction` of them centred on
/// the person.
fn sample_patches(
    camera: &Camera,
    image: &[f32],
    mask: &[bool],
    body_box: &Aabb,
    config: &RaySamplingConfig,
    candidates: &Candidates<'_>,
    rng: &mut Rng,
) -> Result<TrainRays, SamplingError> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let p = config.patch_px;
    if p > w.min(h) {
        return Err(SamplingError::Invalid {
            field: "patch_px",
            expected: format!("at most the image's shorter side ({})", w.min(h)),
            got: p.to_string(),
        });
    }
    let patches = (config.rays_per_image / (p * p)).max(1);
    let n_body = if candidates.body.is_empty() {
        0
    } else {
        (patches as f32 * config.body_fraction).floor() as usize
    };
    let mut rays = TrainRays::default();
    for k in 0..patches {
        let pool = if k < n_body {
            candidates.body
        } else {
            candidates.anywhere
        };
        let corner = (0..PATCH_TRIES).find_map(|_| {
            let centre = pool[rng.below(pool.len())] as usize;
            let x0 = (centre % w).saturating_sub(p / 2).min(w - p);
            let y0 = (centre / w).saturating_sub(p / 2).min(h - p);
            let inside = (0..p).all(|j| (0..p).all(|i| candidates.in_box[(y0 + j) * w + x0 + i]));
            inside.then_some((x0, y0))
        });
        let Some((x0, y0)) = corner else {
            return Err(SamplingError::Invalid {
                field: "patch_px",
                expected: "patches that fit inside the body box's image".into(),
                got: format!("{p} (no such patch in {PATCH_TRIES} draws)"),
            });
        };
        for j in 0..p {
            for i in 0..p {
                let (x, y) = (x0 + i, y0 + j);
                let pixel = (y * w + x) as u32;
                let ray = pixel_ray(camera, crate::geometry::rays::pixel_centre(x, y));
                // In the box's image, so the ray hits the box; a miss (it cannot happen) would
                // break the patch, so it is refused rather than skipped.
                let Some((near, far)) = near_far(&ray, body_box) else {
                    return Err(SamplingError::Invalid {
                        field: "patch_px",
                        expected: "patch rays that hit the body box".into(),
                        got: format!("a miss at pixel ({x}, {y})"),
                    });
                };
                let q = pixel as usize * 3;
                rays.rays.push(ray, near, far, pixel);
                rays.rgb.push([image[q], image[q + 1], image[q + 2]]);
                rays.on_body.push(mask[pixel as usize]);
            }
        }
    }
    Ok(rays)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w x h` mask holding the square `3..9 x 3..9`.
    fn square_mask(w: usize, h: usize) -> Vec<bool> {
        (0..w * h)
            .map(|i| (3..9).contains(&(i % w)) && (3..9).contains(&(i / w)))
            .collect()
    }

    #[test]
    fn band_of_a_square_is_two_pixels_each_side() {
        let (w, h) = (12, 12);
        let mask = square_mask(w, h);
        let band = border_band(&mask, w, h, 5);
        // Row 6: x = 1..=4 (outside 1, 2; inside 3, 4) and 7..=10 are in the band.
        let row: Vec<bool> = (0..w).map(|x| band[6 * w + x]).collect();
        let expect: Vec<bool> = (0..w)
            .map(|x| (1..=4).contains(&x) || (7..=10).contains(&x))
            .collect();
        assert_eq!(row, expect);
        assert!(!band[6 * w + 5], "the square's centre is not border");
    }

    /// An even window is one-sided (OpenCV's anchor): with 2 px the band is the ring just
    /// outside the square on its bottom and right, and the ring just inside on its top and left.
    #[test]
    fn an_even_band_is_one_sided() {
        let (w, h) = (12, 12);
        let mask = square_mask(w, h);
        let band = border_band(&mask, w, h, 2);
        let in_band = |x: usize, y: usize| band[y * w + x];
        // Row 6 crosses the left edge (x = 3 inside) and the right edge (x = 9 outside).
        let row: Vec<usize> = (0..w).filter(|&x| in_band(x, 6)).collect();
        assert_eq!(row, vec![3, 9]);
        // Column 6 crosses the top edge (y = 3 inside) and the bottom edge (y = 9 outside).
        let column: Vec<usize> = (0..h).filter(|&y| in_band(6, y)).collect();
        assert_eq!(column, vec![3, 9]);
        // The pixels just outside the top and left edges train; those inside the bottom and
        // right edges do too.
        assert!(!in_band(6, 2) && !in_band(2, 6) && !in_band(6, 8) && !in_band(8, 6));
        assert!(border_band(&mask, w, h, 0).iter().all(|b| !b));
    }
}
