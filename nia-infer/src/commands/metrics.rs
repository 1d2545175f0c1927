//! `nia-infer metrics --pred P.png --gt G.png [--mask M.png] [--ssim-data-range 2|1]`.
//!
//! PSNR over the mask pixels and SSIM on the mask's bounding-rectangle crop with both images
//! zeroed outside it: NHP's evaluation with the mask as `mask_at_box`. Without `--mask` the
//! whole image is used. See `nia_data::metrics` for the SSIM definition and why its data range
//! is 2 by default.

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::Args;
use nia_data::dataset::image_io::{read_mask, read_rgb_f32};
use nia_data::metrics::{evaluate, ImageView, SsimOptions, NHP_SSIM_DATA_RANGE};
use nia_eval::perceptual::lpips_masked_crop;

use crate::model_load::LpipsArgs;

/// Arguments of `metrics`.
#[derive(Args, Debug)]
pub struct MetricsArgs {
    /// The predicted image (PNG or JPEG, RGB).
    #[arg(long)]
    pub pred: PathBuf,
    /// The ground-truth image, same size.
    #[arg(long)]
    pub gt: PathBuf,
    /// The evaluation region (`mask_at_box`): non-zero pixels count. Default: every pixel.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// SSIM data range: 2 reproduces the published NHP/NIA numbers (scikit-image 0.16-0.18
    /// on float images), 1 is the textbook value for colours in [0, 1].
    #[arg(long, default_value_t = NHP_SSIM_DATA_RANGE)]
    pub ssim_data_range: f64,
    /// Also LPIPS on the same crop as SSIM (all three `--lpips-*` flags).
    #[command(flatten)]
    pub lpips: LpipsArgs,
}

/// Prints `{"psnr": .., "ssim": ..}` (PSNR `null` when the images are identical: +inf dB),
/// with `"lpips"` and `"lpips_net"` when LPIPS weights are given.
pub fn run(args: &MetricsArgs) -> anyhow::Result<()> {
    let (pw, ph, pred) = read_rgb_f32(&args.pred)?;
    let (gw, gh, gt) = read_rgb_f32(&args.gt)?;
    if (pw, ph) != (gw, gh) {
        bail!(
            "{}: prediction is {pw}x{ph} but the ground truth {} is {gw}x{gh}",
            args.pred.display(),
            args.gt.display()
        );
    }
    let (w, h) = (gw as usize, gh as usize);
    let mask = match &args.mask {
        Some(path) => {
            let (mw, mh, m) = read_mask(path)?;
            if (mw, mh) != (gw, gh) {
                bail!(
                    "{}: mask is {mw}x{mh} but the images are {gw}x{gh}",
                    path.display()
                );
            }
            m
        }
        None => vec![true; w * h],
    };
    let pv = ImageView::new("prediction", &pred, w, h, 3)
        .with_context(|| args.pred.display().to_string())?;
    let gv = ImageView::new("ground truth", &gt, w, h, 3)
        .with_context(|| args.gt.display().to_string())?;
    let options = SsimOptions {
        data_range: args.ssim_data_range,
    };
    let metrics = evaluate(&pv, &gv, &mask, options).with_context(|| {
        format!(
            "metrics of {} against {}",
            args.pred.display(),
            args.gt.display()
        )
    })?;
    let mut out = serde_json::json!({ "psnr": metrics.psnr, "ssim": metrics.ssim });
    #[allow(deprecated)] // burn 0.22 spells the CPU reference device this way.
    let device = burn::prelude::Device::ndarray();
    if let Some((files, net)) = args.lpips.load(None, &device)? {
        let d = lpips_masked_crop(&net, &pv, &gv, &mask, &device)
            .with_context(|| format!("LPIPS of {}", args.pred.display()))?;
        out["lpips"] = d.into();
        out["lpips_net"] = files.net.name().into();
    }
    println!("{out}");
    Ok(())
}
