//! Whole target images: the pixels of a camera whose rays cross the body's ray box
//! ([`RayBundle::through_pixels`]), rendered in chunks of rays with bounded memory, reusing one
//! [`SceneEncoding`] for every chunk.
//!
//! Pixels whose ray misses the box never reach the network: they keep the black background
//! (NHP/NIA's convention) with zero opacity and zero blend weights.
//!
//! A pixel may have several rays (supersampling, [`RayBundle::through_pixel_footprints`]):
//! every value of the image (colours, opacity, depth, blend weights) is then the mean over the
//! pixel's rays in the bundle, the box filter of its footprint. A camera integrates light over
//! the pixel's area, and so do the synthetic images (rendered at twice the size and averaged):
//! one ray through the centre gives the outline's pixels all or nothing where the photograph
//! has a mix (docs/accuracy-time.md, "The savings").

use burn::prelude::*;

use crate::kernels::readback::host_values;
use nia_data::geometry::rays::RayBundle;

use crate::error::ModelError;
use crate::model::NiaModel;
use crate::renderer::RenderOutput;
use crate::scene_encoding::SceneEncoding;
use crate::timing::StageTimes;

/// A rendered image and what it cost.
#[derive(Debug, Clone)]
pub struct RenderedImage {
    pub width: usize,
    pub height: usize,
    /// [H * W * 3] interleaved blended colour C in [0, 1] (black background).
    pub rgb: Vec<f32>,
    /// [H * W * 3] interleaved NeRF colour C0.
    pub rgb0: Vec<f32>,
    /// [H * W * 3] interleaved IBR-only composite (the source colours under the blend weights
    /// renormalised over the views; an instrument, see `field::PointOutput::ibr_colour`).
    pub rgb_ibr: Vec<f32>,
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
    /// Of those, the points the colour half of the network evaluated (fewer with colour
    /// culling).
    pub colour_evaluations: u64,
    /// Time per stage (only filled when timing was asked for).
    pub times: StageTimes,
}

/// How to render an image.
#[derive(Debug, Clone, Copy)]
pub struct ImageRenderOptions {
    /// Stratified samples per ray (bin centres, no jitter).
    pub samples: usize,
    /// Rays rendered together: bounds the per-sample tensors (`chunk * samples` rows); the
    /// network sees their points in calls of at most
    /// [`crate::renderer::call_size::MAX_POINTS_PER_CALL`].
    pub chunk: usize,
    /// Charge the time of every stage to [`RenderedImage::times`] (synchronises the device).
    pub timed: bool,
}

fn readback(name: &str, tensor: Tensor<2>) -> Result<Vec<f32>, ModelError> {
    host_values(tensor).map_err(|e| ModelError::Input(format!("reading back {name}: {e}")))
}

/// Renders `rays` (pixels of a `width x height` image) of `scene` in chunks of
/// `options.chunk` rays. A scene encoded with a reposer renders its target pose.
/// `progress(done, total)` is called after every chunk.
pub fn render_image(
    model: &NiaModel,
    scene: &SceneEncoding,
    rays: &RayBundle,
    size: [usize; 2],
    options: ImageRenderOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RenderedImage, ModelError> {
    render_image_cancellable(model, scene, rays, size, options, progress, &|| false)
        .and_then(|image| image.ok_or(ModelError::Cancelled))
}

/// [`render_image`] that asks `cancelled` before every chunk and gives up (`Ok(None)`) as soon
/// as it answers true: an interactive viewer drops a frame a newer request made stale.
pub fn render_image_cancellable(
    model: &NiaModel,
    scene: &SceneEncoding,
    rays: &RayBundle,
    [w, h]: [usize; 2],
    options: ImageRenderOptions,
    progress: &mut dyn FnMut(usize, usize),
    cancelled: &dyn Fn() -> bool,
) -> Result<Option<RenderedImage>, ModelError> {
    let k = scene.num_views() + 1;
    if let Some(&p) = rays.pixels.iter().find(|&&p| p as usize >= w * h) {
        return Err(ModelError::Rays(format!(
            "pixel index {p} outside the {w}x{h} image"
        )));
    }
    // [H * W] 1 / (rays of the pixel in the bundle): each ray's share of its pixel.
    let mut share = vec![0.0f32; w * h];
    for &p in &rays.pixels {
        share[p as usize] += 1.0;
    }
    for s in share.iter_mut().filter(|s| **s > 0.0) {
        *s = 1.0 / *s;
    }
    let mut out = RenderedImage {
        width: w,
        height: h,
        rgb: vec![0.0; w * h * 3],
        rgb0: vec![0.0; w * h * 3],
        rgb_ibr: vec![0.0; w * h * 3],
        acc: vec![0.0; w * h],
        depth: vec![0.0; w * h],
        blend_channels: k,
        blend_weights: vec![0.0; w * h * k],
        rays: 0,
        point_evaluations: 0,
        colour_evaluations: 0,
        times: StageTimes::default(),
    };
    let total = rays.len();
    let chunk = options.chunk.max(1);
    let mut times = StageTimes::default();
    for start in (0..total).step_by(chunk) {
        if cancelled() {
            return Ok(None);
        }
        let end = (start + chunk).min(total);
        let batch = rays.slice(start..end);
        let RenderOutput {
            rgb,
            rgb0,
            acc,
            depth,
            blend_weights,
            rgb_ibr,
            point_evaluations,
            colour_evaluations,
            ..
        } = model.render(
            scene,
            &batch,
            options.samples,
            None,
            options.timed.then_some(&mut times),
        )?;
        let n = end - start;
        // One transfer per chunk (on a GPU each read back waits for the device): the columns
        // side by side, [n, 3 + 3 + 3 + 1 + 1 + K].
        let device = rgb.device();
        let zeros = |width: usize| Tensor::<2>::zeros([n, width], &device);
        let parts = [
            ("colours", rgb, 3),
            ("NeRF colours", rgb0, 3),
            ("IBR-only colours", rgb_ibr.unwrap_or_else(|| zeros(3)), 3),
            ("opacity", acc.reshape([n, 1]), 1),
            ("depth", depth.reshape([n, 1]), 1),
            (
                "blend weights",
                blend_weights.unwrap_or_else(|| zeros(k)),
                k,
            ),
        ];
        if let Some((name, part, width)) = parts.iter().find(|(_, t, w)| t.dims() != [n, *w]) {
            return Err(ModelError::Input(format!(
                "the renderer returned {name} of shape {:?} for {n} rays (expected [{n}, {width}])",
                part.dims()
            )));
        }
        let columns = Tensor::cat(parts.into_iter().map(|(_, t, _)| t).collect(), 1);
        let width = 11 + k;
        let values = readback("the rendered chunk", columns)?;
        for (i, &p) in batch.pixels.iter().enumerate() {
            let p = p as usize;
            let f = share[p];
            let row = &values[width * i..width * (i + 1)];
            let add = |to: &mut [f32], from: &[f32]| {
                to.iter_mut().zip(from).for_each(|(t, v)| *t += f * v);
            };
            add(&mut out.rgb[3 * p..3 * p + 3], &row[0..3]);
            add(&mut out.rgb0[3 * p..3 * p + 3], &row[3..6]);
            add(&mut out.rgb_ibr[3 * p..3 * p + 3], &row[6..9]);
            add(&mut out.acc[p..p + 1], &row[9..10]);
            add(&mut out.depth[p..p + 1], &row[10..11]);
            add(&mut out.blend_weights[k * p..k * p + k], &row[11..11 + k]);
        }
        out.rays += n;
        out.point_evaluations += point_evaluations as u64;
        out.colour_evaluations += colour_evaluations as u64;
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
    Ok(Some(out))
}
