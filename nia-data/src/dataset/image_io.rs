//! Image decoding and resampling for the dataset readers: RGB images and masks from PNG/JPEG,
//! float conversion, OpenCV-compatible area and nearest-neighbour resizing, PNG writing.
//!
//! Float images are interleaved `[H, W, C]`, row-major (`(y * width + x) * C + c`), colours in
//! [0, 1] (`u8 / 255`, as NHP's `img.astype(np.float32) / 255.`).

use std::path::{Path, PathBuf};

/// JPEG masks carry compression noise around 0 and 255; a pixel counts as foreground above
/// this level (mid-grey). PNG masks use the exact rule `value != 0` (NHP's `msk != 0`).
pub const JPEG_MASK_THRESHOLD: u8 = 128;

/// An image file that could not be read, decoded or written.
#[derive(Debug, thiserror::Error)]
pub enum ImageIoError {
    #[error("{}: cannot read image: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: cannot decode image: {msg}", path.display())]
    Decode { path: PathBuf, msg: String },
    #[error("{}: cannot write image: {msg}", path.display())]
    Write { path: PathBuf, msg: String },
    #[error("{what}: {msg}")]
    Invalid { what: &'static str, msg: String },
}

/// Bytes at the end of a JPEG file searched for its end-of-image marker (some writers pad a
/// little after it).
const JPEG_TAIL_SEARCH: usize = 4096;

/// Whether a JPEG's last bytes hold the end-of-image marker `FF D9`. Inside the entropy-coded
/// data `FF` is always followed by `00` or a restart marker, so `FF D9` there is the real end.
fn has_jpeg_end(bytes: &[u8]) -> bool {
    let tail = &bytes[bytes.len().saturating_sub(JPEG_TAIL_SEARCH)..];
    tail.windows(2).any(|w| w == [0xFF, 0xD9])
}

fn decode(path: &Path) -> Result<image::DynamicImage, ImageIoError> {
    let bytes = std::fs::read(path).map_err(|source| ImageIoError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let format = image::guess_format(&bytes).map_err(|e| ImageIoError::Decode {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })?;
    // The JPEG decoder fills a cut-off file's missing blocks in silently: refuse it instead
    // (a half-downloaded dataset must not train on grey images).
    if format == image::ImageFormat::Jpeg && !has_jpeg_end(&bytes) {
        return Err(ImageIoError::Decode {
            path: path.to_path_buf(),
            msg: "truncated JPEG: no end-of-image marker (FF D9); the file is cut short (incomplete download or copy?)".into(),
        });
    }
    image::load_from_memory_with_format(&bytes, format).map_err(|e| ImageIoError::Decode {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })
}

/// Width and height from the file header, without decoding the pixels.
pub fn dimensions(path: &Path) -> Result<(u32, u32), ImageIoError> {
    image::image_dimensions(path).map_err(|e| match e {
        image::ImageError::IoError(source) => ImageIoError::Io {
            path: path.to_path_buf(),
            source,
        },
        other => ImageIoError::Decode {
            path: path.to_path_buf(),
            msg: other.to_string(),
        },
    })
}

/// An 8-bit RGB image (grey or RGBA files are converted; alpha is dropped).
pub fn read_rgb8(path: &Path) -> Result<image::RgbImage, ImageIoError> {
    Ok(decode(path)?.into_rgb8())
}

/// An RGB image as floats in [0, 1]: `(width, height, [H * W * 3])`.
pub fn read_rgb_f32(path: &Path) -> Result<(u32, u32, Vec<f32>), ImageIoError> {
    let img = read_rgb8(path)?;
    let (w, h) = img.dimensions();
    Ok((w, h, u8_to_unit(img.as_raw())))
}

/// `u8 / 255` as f32 (the division in f32, like numpy's `astype(np.float32) / 255.`).
pub fn u8_to_unit(data: &[u8]) -> Vec<f32> {
    data.iter().map(|&v| v as f32 / 255.0).collect()
}

/// A foreground mask: `(width, height, [H * W])`. A pixel is foreground when any channel is
/// non-zero (PNG and other lossless files) or above [`JPEG_MASK_THRESHOLD`] (JPEG files).
pub fn read_mask(path: &Path) -> Result<(u32, u32, Vec<bool>), ImageIoError> {
    let img = decode(path)?;
    let is_jpeg = matches!(
        image::ImageFormat::from_path(path),
        Ok(image::ImageFormat::Jpeg)
    );
    let threshold = if is_jpeg { JPEG_MASK_THRESHOLD } else { 1 };
    let (w, h) = (img.width(), img.height());
    let mask = match img {
        image::DynamicImage::ImageLuma8(g) => g.as_raw().iter().map(|&v| v >= threshold).collect(),
        other => {
            let rgb = other.into_rgb8();
            rgb.as_raw()
                .chunks_exact(3)
                .map(|p| p.iter().any(|&v| v >= threshold))
                .collect()
        }
    };
    Ok((w, h, mask))
}

/// OpenCV `cv2.resize(..., interpolation=INTER_AREA)` for downscaling an interleaved float
/// image `[H, W, C]` to `[new_h, new_w, C]`: each output pixel is the average of the source
/// area it covers, `[x * sx, (x + 1) * sx) x [y * sy, (y + 1) * sy)` with `sx = W / new_w`,
/// `sy = H / new_h`, partially covered source pixels weighted by their covered fraction.
/// Upscaling is not area resampling and is refused.
pub fn resize_area(
    data: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    new_width: usize,
    new_height: usize,
) -> Result<Vec<f32>, ImageIoError> {
    if data.len() != width * height * channels || channels == 0 {
        return Err(ImageIoError::Invalid {
            what: "resize_area",
            msg: format!(
                "expected {width}x{height}x{channels} values, got {}",
                data.len()
            ),
        });
    }
    if new_width == 0 || new_height == 0 || new_width > width || new_height > height {
        return Err(ImageIoError::Invalid {
            what: "resize_area",
            msg: format!(
                "can only shrink: {width}x{height} -> {new_width}x{new_height} (ratio in (0, 1])"
            ),
        });
    }
    if new_width == width && new_height == height {
        return Ok(data.to_vec());
    }
    let tab_x = area_table(width, new_width);
    let tab_y = area_table(height, new_height);
    // Rows first: [H, new_w, C], then columns.
    let mut rows = vec![0.0f64; height * new_width * channels];
    for y in 0..height {
        for (ox, taps) in tab_x.iter().enumerate() {
            for &(sx, wgt) in taps {
                let src = (y * width + sx) * channels;
                let dst = (y * new_width + ox) * channels;
                for c in 0..channels {
                    rows[dst + c] += data[src + c] as f64 * wgt;
                }
            }
        }
    }
    let mut out = vec![0.0f32; new_height * new_width * channels];
    for (oy, taps) in tab_y.iter().enumerate() {
        for ox in 0..new_width {
            for c in 0..channels {
                let mut acc = 0.0f64;
                for &(sy, wgt) in taps {
                    acc += rows[(sy * new_width + ox) * channels + c] * wgt;
                }
                out[(oy * new_width + ox) * channels + c] = acc as f32;
            }
        }
    }
    Ok(out)
}

/// For each output index, the `(source index, weight)` taps of area resampling from `src` to
/// `dst <= src` samples; weights sum to 1.
fn area_table(src: usize, dst: usize) -> Vec<Vec<(usize, f64)>> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|o| {
            let (a, b) = (o as f64 * scale, ((o + 1) as f64 * scale).min(src as f64));
            let mut taps = Vec::new();
            let mut s = a.floor() as usize;
            while (s as f64) < b && s < src {
                let lo = (s as f64).max(a);
                let hi = ((s + 1) as f64).min(b);
                if hi > lo {
                    taps.push((s, (hi - lo) / (b - a)));
                }
                s += 1;
            }
            taps
        })
        .collect()
}

/// OpenCV `INTER_NEAREST` resize of an [H * W] grid: output `(x, y)` takes source
/// `(floor(x * W / new_w), floor(y * H / new_h))`.
pub fn resize_nearest<T: Copy>(
    data: &[T],
    width: usize,
    height: usize,
    new_width: usize,
    new_height: usize,
) -> Vec<T> {
    let sx = width as f64 / new_width as f64;
    let sy = height as f64 / new_height as f64;
    let mut out = Vec::with_capacity(new_width * new_height);
    for y in 0..new_height {
        let ys = ((y as f64 * sy).floor() as usize).min(height - 1);
        for x in 0..new_width {
            let xs = ((x as f64 * sx).floor() as usize).min(width - 1);
            out.push(data[ys * width + xs]);
        }
    }
    out
}

/// Writes a float RGB image `[H * W * 3]` (values clamped to [0, 1], rounded) as 8-bit PNG.
pub fn write_rgb_png(
    path: &Path,
    data: &[f32],
    width: u32,
    height: u32,
) -> Result<(), ImageIoError> {
    let bytes: Vec<u8> = data
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let img =
        image::RgbImage::from_raw(width, height, bytes).ok_or_else(|| ImageIoError::Write {
            path: path.to_path_buf(),
            msg: format!(
                "expected {width}x{height}x3 = {} values, got {}",
                width as usize * height as usize * 3,
                data.len()
            ),
        })?;
    img.save(path).map_err(|e| ImageIoError::Write {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn area_halving_is_block_average_and_thirds_weight_partially() {
        let data: Vec<f32> = (0..16).map(|v| v as f32).collect();
        let out = resize_area(&data, 4, 4, 1, 2, 2).unwrap();
        assert_eq!(out, vec![2.5, 4.5, 10.5, 12.5]);
        // 3 -> 2 samples: output 0 covers [0, 1.5): 2/3 of s0 + 1/3 of s1.
        let out = resize_area(&[0.0, 3.0, 6.0], 3, 1, 1, 2, 1).unwrap();
        assert!(
            (out[0] - 1.0).abs() < 1e-6 && (out[1] - 5.0).abs() < 1e-6,
            "{out:?}"
        );
        assert!(resize_area(&data, 4, 4, 1, 8, 8).is_err());
        // Non-integer factors: cv2.resize(np.arange(35, dtype=np.float32).reshape(5, 7),
        // (3, 2), interpolation=cv2.INTER_AREA) in OpenCV 5.0.
        let data: Vec<f32> = (0..35).map(|v| v as f32).collect();
        let out = resize_area(&data, 7, 5, 1, 3, 2).unwrap();
        let cv2 = [6.314286, 8.6, 10.885715, 23.114288, 25.400002, 27.685715];
        for (a, b) in out.iter().zip(cv2) {
            assert!((a - b).abs() < 1e-4, "{out:?}");
        }
        assert_eq!(resize_nearest(&[1, 2, 3, 4], 2, 2, 1, 1), vec![1]);
    }
}
