//! Pictures people look at: PNGs of rendered images, comparison grids (sources | prediction |
//! ground truth | error map), blend-weight maps and animated GIFs.

use std::path::Path;

use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, Rgb, RgbImage, RgbaImage};

use crate::eval::{EvaluatedImage, ImageResult};

/// Mean absolute error (over RGB, in [0, 1]) that maps to the top of the error colour scale.
pub const ERROR_MAP_MAX: f32 = 0.5;
/// Colour of pixels outside the scored region in error maps.
const OUTSIDE: Rgb<u8> = Rgb([40, 40, 48]);

fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// [H * W * 3] interleaved floats in [0, 1] (clamped) to an 8-bit image.
pub fn rgb8(rgb: &[f32], width: usize, height: usize) -> RgbImage {
    RgbImage::from_fn(width as u32, height as u32, |x, y| {
        let p = 3 * (y as usize * width + x as usize);
        Rgb([to_u8(rgb[p]), to_u8(rgb[p + 1]), to_u8(rgb[p + 2])])
    })
}

/// [H * W] floats in [0, 1] to grey.
pub fn grey8(values: &[f32], width: usize, height: usize) -> RgbImage {
    RgbImage::from_fn(width as u32, height as u32, |x, y| {
        let v = to_u8(values[y as usize * width + x as usize]);
        Rgb([v, v, v])
    })
}

/// The "hot" scale: black, red, yellow, white over [0, 1].
fn hot(t: f32) -> Rgb<u8> {
    let t = t.clamp(0.0, 1.0) * 3.0;
    Rgb([to_u8(t), to_u8(t - 1.0), to_u8(t - 2.0)])
}

/// Per-pixel mean absolute error of `pred` against `gt` ([H * W * 3] each) on the hot scale
/// (0 to [`ERROR_MAP_MAX`]); pixels outside `mask` ([H * W]) are dark grey.
pub fn error_map(pred: &[f32], gt: &[f32], mask: &[bool], width: usize, height: usize) -> RgbImage {
    RgbImage::from_fn(width as u32, height as u32, |x, y| {
        let p = y as usize * width + x as usize;
        if !mask[p] {
            return OUTSIDE;
        }
        let e = (0..3)
            .map(|c| (pred[3 * p + c] - gt[3 * p + c]).abs())
            .sum::<f32>()
            / 3.0;
        hot(e / ERROR_MAP_MAX)
    })
}

/// Blend weights ([H * W * K], channel 0 = NeRF colour, 1..K = source views) as K grey panels
/// side by side, in channel order.
pub fn blend_weight_maps(
    weights: &[f32],
    channels: usize,
    width: usize,
    height: usize,
) -> RgbImage {
    let panels: Vec<RgbImage> = (0..channels)
        .map(|k| {
            let plane: Vec<f32> = (0..width * height)
                .map(|p| weights[p * channels + k])
                .collect();
            grey8(&plane, width, height)
        })
        .collect();
    row(&panels)
}

/// Images side by side, top-aligned, with a 2-pixel black gap.
pub fn row(images: &[RgbImage]) -> RgbImage {
    const GAP: u32 = 2;
    let width =
        images.iter().map(|i| i.width()).sum::<u32>() + GAP * images.len().saturating_sub(1) as u32;
    let height = images.iter().map(|i| i.height()).max().unwrap_or(0);
    let mut out = RgbImage::new(width.max(1), height.max(1));
    let mut x0 = 0;
    for img in images {
        image::imageops::replace(&mut out, img, x0 as i64, 0);
        x0 += img.width() + GAP;
    }
    out
}

/// A picture could not be written; names the file.
#[derive(Debug, thiserror::Error)]
#[error("writing {}: {message}", path.display())]
pub struct PictureError {
    pub path: std::path::PathBuf,
    pub message: String,
}

fn picture_error(path: &Path) -> impl Fn(image::ImageError) -> PictureError + '_ {
    move |e| PictureError {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Writes a PNG, naming the file on failure.
pub fn save_png(path: &Path, img: &RgbImage) -> Result<(), PictureError> {
    img.save(path).map_err(picture_error(path))
}

/// Writes an endlessly looping animated GIF, `delay_ms` per frame.
pub fn save_gif(path: &Path, frames: &[RgbImage], delay_ms: u32) -> Result<(), PictureError> {
    let file = std::fs::File::create(path).map_err(|e| PictureError {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut encoder = GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
    encoder
        .set_repeat(Repeat::Infinite)
        .map_err(picture_error(path))?;
    for f in frames {
        let rgba: RgbaImage = image::DynamicImage::ImageRgb8(f.clone()).into_rgba8();
        encoder
            .encode_frame(Frame::from_parts(
                rgba,
                0,
                0,
                Delay::from_numer_denom_ms(delay_ms, 1),
            ))
            .map_err(picture_error(path))?;
    }
    Ok(())
}

/// The comparison grid of one evaluated image: sources | prediction | ground truth | error map.
pub fn comparison_grid(e: &EvaluatedImage<'_>) -> RgbImage {
    let (w, h) = (e.rendered.width, e.rendered.height);
    let mut tiles: Vec<RgbImage> = e
        .sources
        .sources
        .iter()
        .map(|s| {
            rgb8(
                &s.image.image,
                s.image.width() as usize,
                s.image.height() as usize,
            )
        })
        .collect();
    tiles.push(rgb8(&e.rendered.rgb, w, h));
    tiles.push(rgb8(&e.ground_truth.image, w, h));
    tiles.push(error_map(
        &e.rendered.rgb,
        &e.ground_truth.image,
        e.mask_at_box,
        w,
        h,
    ));
    row(&tiles)
}

/// The file stem of an evaluated image: `SUBJECT_frameFFFF_viewVV`.
pub fn image_stem(r: &ImageResult) -> String {
    format!("{}_frame{:04}_view{:02}", r.subject, r.frame, r.target_view)
}

/// The hybrid's parts of one evaluated image: NeRF colour C0 | IBR-only composite | blended
/// prediction C | ground truth | opacity (black = 0, white = 1).
pub fn parts_grid(e: &EvaluatedImage<'_>) -> RgbImage {
    let (w, h) = (e.rendered.width, e.rendered.height);
    row(&[
        rgb8(&e.rendered.rgb0, w, h),
        rgb8(&e.rendered.rgb_ibr, w, h),
        rgb8(&e.rendered.rgb, w, h),
        rgb8(&e.ground_truth.image, w, h),
        grey8(&e.rendered.acc, w, h),
    ])
}

/// Writes `STEM_grid.png` ([`comparison_grid`]), `STEM_parts.png` ([`parts_grid`]) and
/// `STEM_blend.png` (blend weights, NeRF colour first) of an evaluated image into `folder`.
pub fn save_evaluated(folder: &Path, e: &EvaluatedImage<'_>) -> Result<(), PictureError> {
    let stem = image_stem(e.result);
    let (w, h) = (e.rendered.width, e.rendered.height);
    save_png(
        &folder.join(format!("{stem}_grid.png")),
        &comparison_grid(e),
    )?;
    save_png(&folder.join(format!("{stem}_parts.png")), &parts_grid(e))?;
    save_png(
        &folder.join(format!("{stem}_blend.png")),
        &blend_weight_maps(&e.rendered.blend_weights, e.rendered.blend_channels, w, h),
    )
}
