//! The training loss (NIA eq. 6): `L = mean |C0 - C_gt|^2 + mean |C - C_gt|^2`, the NeRF colour
//! C0 supervised alongside the blended colour C, and PSNR for reporting.
//!
//! Means run over every ray and channel (as NeRF's `img2mse`), colours in [0, 1].

use burn::prelude::*;

use crate::shape::ShapeError;

/// The loss and its two terms.
#[derive(Debug, Clone)]
pub struct RenderLoss {
    /// `mse + mse0`, `[1]`: the value to back-propagate.
    pub total: Tensor<1>,
    /// `mean |C - C_gt|^2` of the blended colour, `[1]`.
    pub mse: Tensor<1>,
    /// `mean |C0 - C_gt|^2` of the NeRF colour, `[1]`.
    pub mse0: Tensor<1>,
}

/// `L = mean |rgb0 - gt|^2 + mean |rgb - gt|^2`.
///
/// # Shapes
/// - `rgb` C, `rgb0` C0, `gt` C_gt: `[R, 3]` in [0, 1]
/// - outputs: `[1]`
pub fn render_loss(
    rgb: Tensor<2>,
    rgb0: Tensor<2>,
    gt: Tensor<2>,
) -> Result<RenderLoss, ShapeError> {
    let [r, c] = gt.dims();
    ShapeError::check("loss `gt` [R, 3]", &[r, c], &[None, Some(3)])?;
    ShapeError::check("loss `rgb` [R, 3]", &rgb.dims(), &[Some(r), Some(3)])?;
    ShapeError::check("loss `rgb0` [R, 3]", &rgb0.dims(), &[Some(r), Some(3)])?;
    if r == 0 {
        return Err(ShapeError::empty("loss rays R"));
    }
    let mse = (rgb - gt.clone()).square().mean();
    let mse0 = (rgb0 - gt).square().mean();
    Ok(RenderLoss {
        total: mse.clone() + mse0.clone(),
        mse,
        mse0,
    })
}

/// The target as the prediction's camera would record it (switchable,
/// `train.colour_gain_tolerance`; not in the paper): each channel of `gt` times the gain
/// `k_c = sum_r C_rc C_gt,rc / sum_r C_gt,rc^2` that best maps it onto the prediction `rgb`
/// (least squares over the scene's rays, the prediction detached), clamped to
/// `[1 / (1 + tolerance), 1 + tolerance]`. Real rigs' cameras differ in gain and white balance
/// (docs/data.md, "Capture flaws"): a target view's colours are its own camera's, which no source
/// view shows, and a loss against them teaches the blend to distrust the sources. Against the
/// matched target the loss ignores a per-channel gain within the tolerance. `tolerance <= 0`
/// (or a channel that is black) leaves `gt` unchanged.
///
/// # Shapes
/// - `rgb` C, `gt` C_gt: `[R, 3]`
/// - output: `[R, 3]`
pub fn colour_matched_target(
    rgb: &Tensor<2>,
    gt: Tensor<2>,
    tolerance: f32,
) -> Result<Tensor<2>, ShapeError> {
    let [r, c] = gt.dims();
    ShapeError::check("colour match `gt` [R, 3]", &[r, c], &[None, Some(3)])?;
    ShapeError::check(
        "colour match `rgb` [R, 3]",
        &rgb.dims(),
        &[Some(r), Some(3)],
    )?;
    if !(tolerance > 0.0) || r == 0 {
        return Ok(gt);
    }
    let pred = rgb.clone().detach();
    let cross = (pred * gt.clone()).sum_dim(0); // [1, 3]
    let power = gt.clone().square().sum_dim(0); // [1, 3]
                                                // A black channel (power 0) gets gain 1: 0 / 0 is replaced, not passed on.
    let black = power.clone().lower_equal_elem(1e-12);
    let gain = (cross / power.clamp_min(1e-12))
        .mask_fill(black, 1.0)
        .clamp(1.0 / (1.0 + tolerance), 1.0 + tolerance);
    Ok(gt * gain)
}

/// The mask loss (switchable, `train.mask_loss_weight`; not in the paper, whose "RGB only"
/// means no 3D or depth supervision, while the masks are inputs the reader loads anyway):
/// `mean (acc - m)^2`, with m = 1 on the person's mask and 0 off it. It pulls the opacity off the
/// person to zero and onto it to one, so the density is where the person is.
///
/// # Shapes
/// - `acc`: `[R]` accumulated opacity; `on_body` m: `[R]` in {0, 1}
/// - output: `[1]`
pub fn mask_loss(acc: Tensor<1>, on_body: Tensor<1>) -> Result<Tensor<1>, ShapeError> {
    let [r] = on_body.dims();
    ShapeError::check("mask loss `acc` [R]", &acc.dims(), &[Some(r)])?;
    if r == 0 {
        return Err(ShapeError::empty("mask loss rays R"));
    }
    Ok((acc - on_body).square().mean())
}

/// SSIM's stabilising constants for colours in [0, 1]: `(0.01 L)^2`, `(0.03 L)^2`, `L = 1`.
const SSIM_C1: f32 = 1e-4;
const SSIM_C2: f32 = 9e-4;

/// The patch-wise structural loss (switchable, `train.ssim_loss_weight`; not in NIA, whose
/// Limitations suggest a patch-wise loss for the blend): `1 - mean SSIM` over the training
/// rays' `P x P` patches ([`nia_data::dataset::sampling::RaySamplingConfig::patch_px`]), each
/// patch and channel one SSIM window,
///
/// ```text
/// SSIM = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x^2 + s_y^2 + C2))
/// ```
///
/// with the patch's means, variances and covariance. A per-pixel loss is met by a blurred
/// colour that is right on average; this one asks for the patch's contrast and structure too
/// (a print, a stripe, an edge), which is what the fetched source colours carry and c0 does not.
///
/// # Shapes
/// - `rgb` C, `gt` C_gt: `[R, 3]`, `R` a multiple of `patch_px^2`, patch after patch
/// - output: `[1]`
pub fn patch_ssim_loss(
    rgb: Tensor<2>,
    gt: Tensor<2>,
    patch_px: usize,
) -> Result<Tensor<1>, ShapeError> {
    let [r, c] = gt.dims();
    ShapeError::check("SSIM loss `gt` [R, 3]", &[r, c], &[None, Some(3)])?;
    ShapeError::check("SSIM loss `rgb` [R, 3]", &rgb.dims(), &[Some(r), Some(3)])?;
    let area = patch_px * patch_px;
    if patch_px < 2 || r == 0 || r % area != 0 {
        return Err(ShapeError::value(
            "SSIM loss rays R",
            format!("a positive multiple of patch_px^2 = {area} (patch_px >= 2), got {r}"),
        ));
    }
    let b = r / area;
    let x = rgb.reshape([b, area, 3]);
    let y = gt.reshape([b, area, 3]);
    let mu_x = x.clone().mean_dim(1);
    let mu_y = y.clone().mean_dim(1);
    let dx = x - mu_x.clone();
    let dy = y - mu_y.clone();
    // Sample (co)variances (N - 1), as the evaluation's SSIM.
    let n1 = (area - 1) as f32;
    let var_x = dx.clone().square().sum_dim(1) / n1;
    let var_y = dy.clone().square().sum_dim(1) / n1;
    let cov = (dx * dy).sum_dim(1) / n1;
    let luminance =
        (mu_x.clone() * mu_y.clone() * 2.0 + SSIM_C1) / (mu_x.square() + mu_y.square() + SSIM_C1);
    let structure = (cov * 2.0 + SSIM_C2) / (var_x + var_y + SSIM_C2);
    Ok((luminance * structure).mean().neg() + 1.0)
}

/// The distortion loss of mip-NeRF 360 (Barron et al. 2022, eq. 15; switchable,
/// `train.distortion_loss_weight`; not in NIA):
///
/// ```text
/// L_dist = mean_r [ sum_{i,j} w_i w_j |t_i - t_j|  +  1/3 sum_i w_i^2 delta_i ]
/// ```
///
/// It is small when a ray's compositing weights sit in one short interval (a surface) and grows
/// with their spread along the ray, in metres. For NIA this matters beyond geometry: every
/// sample fetches the source colours at its own projection, so weights spread in depth composite
/// colours read at misregistered pixels, and the fetched detail blurs along the epipolar lines.
/// Samples here are points with intervals (band samples are not contiguous), so the pairwise
/// term uses the sample positions t_i, the second term the intervals delta_i. O(S^2) per ray.
///
/// # Shapes
/// - `weights` w: `[R, S]`; `t`: `[R, S]` metres; `delta`: `[R, S]` metres (>= 0)
/// - output: `[1]`
pub fn distortion_loss(
    weights: Tensor<2>,
    t: Tensor<2>,
    delta: Tensor<2>,
) -> Result<Tensor<1>, ShapeError> {
    let [r, s] = weights.dims();
    ShapeError::check("distortion `t` [R, S]", &t.dims(), &[Some(r), Some(s)])?;
    ShapeError::check(
        "distortion `delta` [R, S]",
        &delta.dims(),
        &[Some(r), Some(s)],
    )?;
    if r == 0 || s == 0 {
        return Err(ShapeError::empty("distortion rays R x samples S"));
    }
    // [R, S, 1] - [R, 1, S] -> [R, S, S]
    let gap = (t.clone().reshape([r, s, 1]) - t.reshape([r, 1, s])).abs();
    let pair = weights.clone().reshape([r, s, 1]) * weights.clone().reshape([r, 1, s]);
    let between = (pair * gap).sum_dim(2).sum_dim(1).reshape([r]);
    let within = (weights.square() * delta)
        .sum_dim(1)
        .reshape([r])
        .div_scalar(3.0);
    Ok((between + within).mean())
}

/// PSNR in dB of images with peak value 1: `-10 log10(mse)`. `mse = 0` gives `+inf`; a negative
/// or NaN mse gives NaN (no such image exists).
pub fn psnr_from_mse(mse: f64) -> f64 {
    -10.0 * mse.log10()
}
