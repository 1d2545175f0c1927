//! Whole target images: the pixels of a camera whose rays cross the body's ray box, rendered in
//! chunks of rays with bounded memory, reusing one [`SceneEncoding`] for every chunk.
//!
//! Pixels whose ray misses the box never reach the network: they keep the black background
//! (NHP/NIA's convention) with zero opacity and zero blend weights.

use burn::prelude::*;
use nia_data::camera::Camera;
use nia_data::rays::{near_far, pixel_centre, pixel_ray, Aabb};

use crate::model::{ModelError, NiaModel, RayBatch, SceneEncoding};
use crate::renderer::RenderOutput;
use crate::reposing::Reposer;
use crate::scene::SceneGeometry;
use crate::timing::StageTimes;

/// The rays of one target image that cross the ray box.
#[derive(Debug, Clone)]
pub struct ImageRays {
    pub width: usize,
    pub height: usize,
    /// [R] pixel index `y * width + x` of each ray.
    pub pixels: Vec<usize>,
    /// [R] the rays, clipped to the box.
    pub rays: RayBatch,
}

impl ImageRays {
    /// The rays of `camera`'s pixels (all, or those where `mask` is true: [H * W]) that cross
    /// `ray_box` over a positive length, in pixel order.
    pub fn new(camera: &Camera, ray_box: &Aabb, mask: Option<&[bool]>) -> Self {
        let (width, height) = (camera.width as usize, camera.height as usize);
        let mut pixels = Vec::new();
        let mut rays = RayBatch::default();
        for p in 0..width * height {
            if mask.is_some_and(|m| !m.get(p).copied().unwrap_or(false)) {
                continue;
            }
            let ray = pixel_ray(camera, pixel_centre(p % width, p / width));
            if let Some((near, far)) = near_far(&ray, ray_box) {
                if far > near {
                    rays.origins.push(ray.origin);
                    rays.dirs.push(ray.dir);
                    rays.near.push(near);
                    rays.far.push(far);
                    pixels.push(p);
                }
            }
        }
        ImageRays {
            width,
            height,
            pixels,
            rays,
        }
    }

    /// Rays `start..end` as their own batch.
    fn chunk(&self, start: usize, end: usize) -> RayBatch {
        let r = &self.rays;
        RayBatch {
            origins: r.origins[start..end].to_vec(),
            dirs: r.dirs[start..end].to_vec(),
            near: r.near[start..end].to_vec(),
            far: r.far[start..end].to_vec(),
        }
    }
}

/// A rendered image and what it cost.
#[derive(Debug, Clone)]
pub struct RenderedImage {
    pub width: usize,
    pub height: usize,
    /// [H * W * 3] interleaved blended colour C in [0, 1] (black background).
    pub rgb: Vec<f32>,
    /// [H * W * 3] interleaved NeRF colour C0.
    pub rgb0: Vec<f32>,
    /// [H * W] accumulated opacity.
    pub acc: Vec<f32>,
    /// [H * W] expected depth, metres (0 where no ray was cast).
    pub depth: Vec<f32>,
    /// Blend channels K = N + 1 (channel 0 = NeRF colour c0, 1..=N = source views).
    pub blend_channels: usize,
    /// [H * W * K] blend weights accumulated along each ray (zero where no ray was cast).
    pub blend_weights: Vec<f32>,
    /// Rays sent to the network.
    pub rays: usize,
    /// Points the network evaluated (rays x samples, less the samples skipped as empty space).
    pub point_evaluations: u64,
    /// Time per stage (only filled when timing was asked for).
    pub times: StageTimes,
}

/// How to render an image.
#[derive(Debug, Clone, Copy)]
pub struct ImageRenderOptions {
    /// Stratified samples per ray (bin centres, no jitter).
    pub samples: usize,
    /// Rays per network call: bounds memory (about `chunk * samples` points in flight).
    pub chunk: usize,
    /// Charge the time of every stage to [`RenderedImage::times`] (synchronises the device).
    pub timed: bool,
}

fn readback(name: &str, tensor: Tensor<2>) -> Result<Vec<f32>, ModelError> {
    tensor
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .map_err(|e| ModelError::Input(format!("reading back {name}: {e:?}")))
}

/// Renders `rays` of a scene encoded by [`NiaModel::encode_scene`]; with `reposer` the body is
/// in the reposer's target pose ([`NiaModel::render_reposed`]; the scene must have been encoded
/// on the target-pose vertices). `progress(done, total)` is called after every chunk.
#[allow(clippy::too_many_arguments)]
pub fn render_image(
    model: &NiaModel,
    encoding: &SceneEncoding,
    geometry: &SceneGeometry,
    reposer: Option<&Reposer>,
    rays: &ImageRays,
    options: ImageRenderOptions,
    device: &Device,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RenderedImage, ModelError> {
    let (w, h) = (rays.width, rays.height);
    let views = encoding.images.dims()[0];
    let k = views + 1;
    let mut out = RenderedImage {
        width: w,
        height: h,
        rgb: vec![0.0; w * h * 3],
        rgb0: vec![0.0; w * h * 3],
        acc: vec![0.0; w * h],
        depth: vec![0.0; w * h],
        blend_channels: k,
        blend_weights: vec![0.0; w * h * k],
        rays: 0,
        point_evaluations: 0,
        times: StageTimes::default(),
    };
    let total = rays.pixels.len();
    let chunk = options.chunk.max(1);
    let mut times = StageTimes::default();
    for start in (0..total).step_by(chunk) {
        let end = (start + chunk).min(total);
        let batch = rays.chunk(start, end);
        let stage_times = options.timed.then_some(&mut times);
        let RenderOutput {
            rgb,
            rgb0,
            acc,
            depth,
            blend_weights,
            point_evaluations,
        } = match reposer {
            Some(reposer) => model.render_reposed(
                encoding,
                geometry,
                reposer,
                &batch,
                options.samples,
                None,
                device,
                stage_times,
            )?,
            None => model.render_timed(
                encoding,
                geometry,
                &batch,
                options.samples,
                None,
                device,
                stage_times,
            )?,
        };
        let n = end - start;
        let rgb = readback("colours", rgb)?;
        let rgb0 = readback("NeRF colours", rgb0)?;
        let acc = readback("opacity", acc.reshape([n, 1]))?;
        let depth = readback("depth", depth.reshape([n, 1]))?;
        let weights = match blend_weights {
            Some(wts) => readback("blend weights", wts)?,
            None => vec![0.0; n * k],
        };
        if rgb.len() != 3 * n || weights.len() != k * n {
            return Err(ModelError::Input(format!(
                "the renderer returned {} colours and {} blend weights for {n} rays of {k} channels",
                rgb.len(),
                weights.len()
            )));
        }
        for (i, &p) in rays.pixels[start..end].iter().enumerate() {
            out.rgb[3 * p..3 * p + 3].copy_from_slice(&rgb[3 * i..3 * i + 3]);
            out.rgb0[3 * p..3 * p + 3].copy_from_slice(&rgb0[3 * i..3 * i + 3]);
            out.acc[p] = acc[i];
            out.depth[p] = depth[i];
            out.blend_weights[k * p..k * p + k].copy_from_slice(&weights[k * i..k * i + k]);
        }
        out.rays += n;
        out.point_evaluations += point_evaluations as u64;
        progress(end, total);
    }
    if let Some(bad) = out.rgb.iter().position(|v| !v.is_finite()) {
        let p = bad / 3;
        return Err(ModelError::Input(format!(
            "non-finite colour at pixel ({}, {}): the network produced {}",
            p % w,
            p / w,
            out.rgb[bad]
        )));
    }
    out.times = times;
    Ok(out)
}
