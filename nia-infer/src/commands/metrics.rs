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
}

/// Prints `{"psnr": .., "ssim": ..}` (PSNR `null` when the images are identical: +inf dB).
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
    println!("{}", serde_json::to_string(&metrics)?);
    Ok(())
}
