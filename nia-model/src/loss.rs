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

/// PSNR in dB of images with peak value 1: `-10 log10(mse)`. `mse = 0` gives `+inf`; a negative
/// or NaN mse gives NaN (no such image exists).
pub fn psnr_from_mse(mse: f64) -> f64 {
    -10.0 * mse.log10()
}
