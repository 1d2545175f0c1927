//! Image quality metrics as the NHP / NIA evaluation computes them (docs/method.md "Protocol").
//!
//! - **PSNR** over the pixels inside `mask_at_box` (the projection of the enlarged SMPL box):
//!   `-10 log10(mean squared error)` over those pixels and all channels, colours in [0, 1].
//! - **SSIM**: prediction and ground truth set to 0 outside `mask_at_box`, cropped to the
//!   bounding rectangle of the mask (`cv2.boundingRect`), then scikit-image's
//!   `structural_similarity(pred, gt, channel_axis=-1, data_range=2)` (the published numbers
//!   used `compare_ssim(pred, gt, multichannel=True)` of scikit-image 0.16-0.18, whose defaults
//!   are exactly these).
//!
//! ## The SSIM definition, and why these constants
//!
//! scikit-image's default (non-Gaussian) SSIM, which NHP and NIA report:
//! - a **7 x 7 uniform window** ([`SSIM_WIN_SIZE`]): local means `mu`, variances and covariance
//!   are plain averages over the window;
//! - **sample covariance**: variances and covariance are multiplied by `N / (N - 1)`, N = 49;
//! - `C1 = (K1 L)^2`, `C2 = (K2 L)^2` with `K1 = 0.01`, `K2 = 0.03` and `L` the data range;
//! - `S = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x^2 + s_y^2 + C2))` per
//!   pixel, averaged over the pixels at least 3 (the window radius) from the border, i.e. only
//!   windows lying fully inside the image (so scipy's border mode never matters);
//! - computed per channel and averaged over channels.
//!
//! **Data range.** For float images scikit-image 0.16-0.18 took `L` from the dtype's nominal
//! range, -1..1, so `L = 2` although the colours are in [0, 1]. Every published NHP/NIA SSIM was
//! computed that way ([`NHP_SSIM_DATA_RANGE`]); it makes `C1`, `C2` four times larger than with
//! `L = 1` and the scores slightly higher. To compare with the papers use the default
//! ([`SsimOptions::nhp`]); [`SsimOptions::unit_range`] (`L = 1`, [`UNIT_SSIM_DATA_RANGE`]) is the
//! textbook choice for [0, 1] images, offered for reporting alongside, never mixed with it.

use std::fmt;

/// Side of the square SSIM window, pixels (scikit-image's default for `gaussian_weights=False`).
pub const SSIM_WIN_SIZE: usize = 7;
/// SSIM stabiliser `K1` (Wang et al. 2004; scikit-image default).
pub const SSIM_K1: f64 = 0.01;
/// SSIM stabiliser `K2` (Wang et al. 2004; scikit-image default).
pub const SSIM_K2: f64 = 0.03;
/// The data range `L` the published NHP/NIA SSIM used: scikit-image 0.16-0.18 inferred it from
/// the float dtype's nominal range -1..1 (see the module docs).
pub const NHP_SSIM_DATA_RANGE: f64 = 2.0;
/// The data range of colours in [0, 1], for the textbook variant.
pub const UNIT_SSIM_DATA_RANGE: f64 = 1.0;

/// A metrics error: what was wrong with the inputs.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricsError {
    #[error("{what}: expected {expected} values ({width}x{height}x{channels}), got {got}")]
    Size {
        what: &'static str,
        expected: usize,
        got: usize,
        width: usize,
        height: usize,
        channels: usize,
    },
    #[error("images must have at least one channel and a non-empty size")]
    Empty,
    #[error("mask_at_box selects no pixel: PSNR/SSIM are undefined")]
    EmptyMask,
    #[error(
        "SSIM needs images of at least {win}x{win} pixels (the window), got {width}x{height} \
         (after cropping to the mask's bounding rectangle)"
    )]
    TooSmall {
        width: usize,
        height: usize,
        win: usize,
    },
    #[error("{what} holds a non-finite value at index {index}")]
    NonFinite { what: &'static str, index: usize },
    #[error("SSIM data range must be finite and > 0, got {0}")]
    DataRange(f64),
}

/// An interleaved image `[H, W, C]` borrowed as floats, row-major (`(y * width + x) * C + c`).
#[derive(Clone, Copy)]
pub struct ImageView<'a> {
    /// [H * W * C] colours, nominally in [0, 1].
    pub data: &'a [f32],
    pub width: usize,
    pub height: usize,
    pub channels: usize,
}

impl fmt::Debug for ImageView<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "ImageView({}x{}x{})",
            self.width, self.height, self.channels
        )
    }
}

impl<'a> ImageView<'a> {
    /// [H * W] channel `ch` as f64.
    fn plane(&self, ch: usize) -> Vec<f64> {
        self.data
            .iter()
            .skip(ch)
            .step_by(self.channels)
            .map(|v| *v as f64)
            .collect()
    }

    /// A view, checked for size and finiteness (`what` names it in errors).
    pub fn new(
        what: &'static str,
        data: &'a [f32],
        width: usize,
        height: usize,
        channels: usize,
    ) -> Result<Self, MetricsError> {
        if width == 0 || height == 0 || channels == 0 {
            return Err(MetricsError::Empty);
        }
        let expected = width * height * channels;
        if data.len() != expected {
            return Err(MetricsError::Size {
                what,
                expected,
                got: data.len(),
                width,
                height,
                channels,
            });
        }
        if let Some(index) = data.iter().position(|v| !v.is_finite()) {
            return Err(MetricsError::NonFinite { what, index });
        }
        Ok(ImageView {
            data,
            width,
            height,
            channels,
        })
    }
}

/// SSIM settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SsimOptions {
    /// `L` in `C1 = (K1 L)^2`, `C2 = (K2 L)^2`.
    pub data_range: f64,
}

impl SsimOptions {
    /// The published NHP/NIA setting: `data_range = 2` (see the module docs).
    pub fn nhp() -> Self {
        SsimOptions {
            data_range: NHP_SSIM_DATA_RANGE,
        }
    }

    /// The textbook setting for colours in [0, 1]: `data_range = 1`.
    pub fn unit_range() -> Self {
        SsimOptions {
            data_range: UNIT_SSIM_DATA_RANGE,
        }
    }
}

impl Default for SsimOptions {
    fn default() -> Self {
        SsimOptions::nhp()
    }
}

/// PSNR and SSIM of one image, as NHP reports them.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImageMetrics {
    /// dB; `+inf` when the masked pixels are identical.
    pub psnr: f64,
    /// Mean SSIM over the crop, in [-1, 1].
    pub ssim: f64,
}

fn check_mask(mask: &[bool], width: usize, height: usize) -> Result<(), MetricsError> {
    if mask.len() != width * height {
        return Err(MetricsError::Size {
            what: "mask_at_box",
            expected: width * height,
            got: mask.len(),
            width,
            height,
            channels: 1,
        });
    }
    Ok(())
}

fn check_pair(pred: &ImageView<'_>, gt: &ImageView<'_>) -> Result<(), MetricsError> {
    if (pred.width, pred.height, pred.channels) != (gt.width, gt.height, gt.channels) {
        return Err(MetricsError::Size {
            what: "prediction (must match the ground truth)",
            expected: gt.width * gt.height * gt.channels,
            got: pred.data.len(),
            width: gt.width,
            height: gt.height,
            channels: gt.channels,
        });
    }
    Ok(())
}

/// PSNR over the pixels where `mask` is true: `-10 log10(mean((pred - gt)^2))` over those
/// pixels and all channels (colours in [0, 1]). `+inf` for identical pixels.
///
/// `mask`: [H * W] row-major (NHP's `mask_at_box`).
pub fn psnr_masked(
    pred: &ImageView<'_>,
    gt: &ImageView<'_>,
    mask: &[bool],
) -> Result<f64, MetricsError> {
    check_pair(pred, gt)?;
    check_mask(mask, gt.width, gt.height)?;
    let c = gt.channels;
    let mut sum = 0.0f64;
    let mut count = 0usize;
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        for k in 0..c {
            let d = pred.data[i * c + k] as f64 - gt.data[i * c + k] as f64;
            sum += d * d;
        }
        count += c;
    }
    if count == 0 {
        return Err(MetricsError::EmptyMask);
    }
    Ok(-10.0 * (sum / count as f64).log10())
}

/// PSNR over the whole image.
pub fn psnr(pred: &ImageView<'_>, gt: &ImageView<'_>) -> Result<f64, MetricsError> {
    psnr_masked(pred, gt, &vec![true; gt.width * gt.height])
}

/// The bounding rectangle `(x, y, w, h)` of the true pixels of an [H * W] mask
/// (`cv2.boundingRect`); `None` when the mask is empty.
pub fn bounding_rect(
    mask: &[bool],
    width: usize,
    height: usize,
) -> Option<(usize, usize, usize, usize)> {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0usize, 0usize);
    for y in 0..height {
        for x in 0..width {
            if mask[y * width + x] {
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x);
                y1 = y1.max(y);
            }
        }
    }
    (x0 != usize::MAX).then(|| (x0, y0, x1 - x0 + 1, y1 - y0 + 1))
}

/// scikit-image's `structural_similarity(a, b, channel_axis=-1, data_range=L)` with its other
/// defaults (see the module docs), computed in f64.
pub fn ssim(
    a: &ImageView<'_>,
    b: &ImageView<'_>,
    options: SsimOptions,
) -> Result<f64, MetricsError> {
    check_pair(a, b)?;
    if !(options.data_range.is_finite() && options.data_range > 0.0) {
        return Err(MetricsError::DataRange(options.data_range));
    }
    let (w, h, c) = (a.width, a.height, a.channels);
    if w < SSIM_WIN_SIZE || h < SSIM_WIN_SIZE {
        return Err(MetricsError::TooSmall {
            width: w,
            height: h,
            win: SSIM_WIN_SIZE,
        });
    }
    let mut total = 0.0f64;
    for ch in 0..c {
        let (x, y) = (a.plane(ch), b.plane(ch));
        total += ssim_plane(&x, &y, w, h, options.data_range);
    }
    Ok(total / c as f64)
}

/// Summed-area table `[(H + 1) * (W + 1)]` of `f(i)` over an [H * W] plane.
fn integral(width: usize, height: usize, f: impl Fn(usize) -> f64) -> Vec<f64> {
    let stride = width + 1;
    let mut s = vec![0.0f64; stride * (height + 1)];
    for y in 0..height {
        let mut row = 0.0;
        for x in 0..width {
            row += f(y * width + x);
            s[(y + 1) * stride + x + 1] = s[y * stride + x + 1] + row;
        }
    }
    s
}

/// Mean SSIM of one channel over the pixels whose 7x7 window lies inside the image.
fn ssim_plane(x: &[f64], y: &[f64], width: usize, height: usize, data_range: f64) -> f64 {
    let sx = integral(width, height, |i| x[i]);
    let sy = integral(width, height, |i| y[i]);
    let sxx = integral(width, height, |i| x[i] * x[i]);
    let syy = integral(width, height, |i| y[i] * y[i]);
    let sxy = integral(width, height, |i| x[i] * y[i]);
    let stride = width + 1;
    let r = SSIM_WIN_SIZE / 2;
    let np = (SSIM_WIN_SIZE * SSIM_WIN_SIZE) as f64;
    let cov_norm = np / (np - 1.0);
    let c1 = (SSIM_K1 * data_range).powi(2);
    let c2 = (SSIM_K2 * data_range).powi(2);
    let window = |s: &[f64], cy: usize, cx: usize| {
        let (y0, y1, x0, x1) = (cy - r, cy + r + 1, cx - r, cx + r + 1);
        (s[y1 * stride + x1] - s[y0 * stride + x1] - s[y1 * stride + x0] + s[y0 * stride + x0]) / np
    };
    let mut sum = 0.0f64;
    let mut count = 0usize;
    for cy in r..height - r {
        for cx in r..width - r {
            let ux = window(&sx, cy, cx);
            let uy = window(&sy, cy, cx);
            let vx = cov_norm * (window(&sxx, cy, cx) - ux * ux);
            let vy = cov_norm * (window(&syy, cy, cx) - uy * uy);
            let vxy = cov_norm * (window(&sxy, cy, cx) - ux * uy);
            let num = (2.0 * ux * uy + c1) * (2.0 * vxy + c2);
            let den = (ux * ux + uy * uy + c1) * (vx + vy + c2);
            sum += num / den;
            count += 1;
        }
    }
    sum / count as f64
}

/// `img` set to 0 outside `mask` ([H * W]) and cropped to the mask's bounding rectangle, as
/// NHP scores SSIM (and nia-rs LPIPS): ([h * w * C] values, w, h).
pub fn masked_crop(
    img: &ImageView<'_>,
    mask: &[bool],
) -> Result<(Vec<f32>, usize, usize), MetricsError> {
    check_mask(mask, img.width, img.height)?;
    let (x0, y0, cw, ch) =
        bounding_rect(mask, img.width, img.height).ok_or(MetricsError::EmptyMask)?;
    let c = img.channels;
    let mut out = Vec::with_capacity(cw * ch * c);
    for y in y0..y0 + ch {
        for x in x0..x0 + cw {
            let i = y * img.width + x;
            let keep = mask[i];
            for k in 0..c {
                out.push(if keep { img.data[i * c + k] } else { 0.0 });
            }
        }
    }
    Ok((out, cw, ch))
}

/// NHP's SSIM: both images set to 0 outside `mask` (`mask_at_box`, [H * W]), cropped to the
/// mask's bounding rectangle ([`masked_crop`]), then [`ssim`].
pub fn ssim_masked_crop(
    pred: &ImageView<'_>,
    gt: &ImageView<'_>,
    mask: &[bool],
    options: SsimOptions,
) -> Result<f64, MetricsError> {
    check_pair(pred, gt)?;
    let (pc, cw, ch) = masked_crop(pred, mask)?;
    let (gc, _, _) = masked_crop(gt, mask)?;
    let c = gt.channels;
    let pv = ImageView::new("prediction crop", &pc, cw, ch, c)?;
    let gv = ImageView::new("ground-truth crop", &gc, cw, ch, c)?;
    ssim(&pv, &gv, options)
}

/// PSNR over `mask_at_box` and SSIM on its bounding-rectangle crop, as NHP/NIA report them.
pub fn evaluate(
    pred: &ImageView<'_>,
    gt: &ImageView<'_>,
    mask_at_box: &[bool],
    options: SsimOptions,
) -> Result<ImageMetrics, MetricsError> {
    Ok(ImageMetrics {
        psnr: psnr_masked(pred, gt, mask_at_box)?,
        ssim: ssim_masked_crop(pred, gt, mask_at_box, options)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Identical images: SSIM is 1 up to rounding of the window sums.
    const IDENTITY_TOL: f64 = 1e-12;

    #[test]
    fn identical_images_score_one_and_infinite_psnr() {
        let data: Vec<f32> = (0..10 * 9 * 3).map(|i| (i % 17) as f32 / 17.0).collect();
        let a = ImageView::new("a", &data, 10, 9, 3).unwrap();
        let s = ssim(&a, &a, SsimOptions::nhp()).unwrap();
        assert!((s - 1.0).abs() < IDENTITY_TOL, "{s}");
        assert_eq!(psnr(&a, &a).unwrap(), f64::INFINITY);
    }

    #[test]
    fn psnr_of_constant_offset() {
        let a = vec![0.5f32; 4 * 4];
        let b = vec![0.6f32; 4 * 4];
        let av = ImageView::new("a", &a, 4, 4, 1).unwrap();
        let bv = ImageView::new("b", &b, 4, 4, 1).unwrap();
        let mut mask = vec![false; 16];
        mask[5] = true;
        let p = psnr_masked(&av, &bv, &mask).unwrap();
        // mse = 0.01 -> 20 dB (f32 rounding of 0.6 - 0.5 gives ~1e-6 dB).
        assert!((p - 20.0).abs() < 1e-4, "{p}");
    }

    #[test]
    fn bad_inputs_are_typed_errors() {
        let a = vec![0.0f32; 5 * 5];
        assert!(matches!(
            ImageView::new("a", &a, 5, 4, 1),
            Err(MetricsError::Size { .. })
        ));
        let v = ImageView::new("a", &a, 5, 5, 1).unwrap();
        assert!(matches!(
            ssim(&v, &v, SsimOptions::nhp()),
            Err(MetricsError::TooSmall { .. })
        ));
        assert!(matches!(
            psnr_masked(&v, &v, &[false; 25]),
            Err(MetricsError::EmptyMask)
        ));
        let nan = vec![f32::NAN; 25];
        assert!(matches!(
            ImageView::new("nan", &nan, 5, 5, 1),
            Err(MetricsError::NonFinite { index: 0, .. })
        ));
        assert_eq!(
            bounding_rect(&[false, true, true, false], 2, 2),
            Some((0, 0, 2, 2))
        );
    }
}
