//! LPIPS in evaluation: the user's weight files (`[train] lpips = { ... }` in a run config,
//! `--lpips-*` flags of `nia-infer eval` and `metrics`), and the distance of one evaluated
//! image on the same `mask_at_box` crop as SSIM ([`nia_data::metrics::masked_crop`]).

use std::path::{Path, PathBuf};

use burn::prelude::*;
use nia_data::metrics::{masked_crop, ImageView, MetricsError};
use nia_model::lpips::load::LpipsLoadError;
use nia_model::lpips::{Lpips, LpipsConfig, LpipsError, LpipsNet};

use serde::{Deserialize, Serialize};

/// Which LPIPS network and where its weights are (nothing is downloaded): the trunk from
/// torchvision (`alexnet-owt-7be5be79.pth` or `vgg16-397923af.pth`) and the linear heads from
/// the `lpips` package (`lpips/weights/v0.1/alex.pth` or `vgg.pth`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LpipsFiles {
    /// `alex` (the usual choice of NHP-line papers) or `vgg`.
    pub net: LpipsNet,
    /// The torchvision state dict of the trunk.
    pub backbone: PathBuf,
    /// The `lpips` package's linear heads of the same network.
    pub heads: PathBuf,
    /// Trunk conv widths, for narrow test networks only (default: torchvision's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub widths: Option<Vec<usize>>,
}

impl LpipsFiles {
    /// Loads the metric onto `device`.
    pub fn load(&self, device: &Device) -> Result<Lpips, LpipsLoadError> {
        let config = LpipsConfig {
            net: self.net,
            widths: self.widths.clone(),
        };
        Lpips::load(&config, &self.backbone, &self.heads, device)
    }

    /// The files that are missing, for config checks.
    pub fn missing(&self) -> Vec<&Path> {
        [&self.backbone, &self.heads]
            .into_iter()
            .filter(|p| !p.is_file())
            .map(PathBuf::as_path)
            .collect()
    }
}

/// Why an image could not be scored with LPIPS.
#[derive(Debug, thiserror::Error)]
pub enum PerceptualError {
    #[error("LPIPS crop: {0}")]
    Crop(#[from] MetricsError),
    #[error("LPIPS ({net}) on the {width}x{height} (padded) mask_at_box crop: {source}")]
    Distance {
        net: &'static str,
        width: usize,
        height: usize,
        source: LpipsError,
    },
}

/// [H * W * 3] HWC values as a [1, 3, H, W] tensor.
fn chw(values: &[f32], width: usize, height: usize, device: &Device) -> Tensor<4> {
    Tensor::<3>::from_data(TensorData::new(values.to_vec(), [height, width, 3]), device)
        .permute([2, 0, 1])
        .unsqueeze::<4>()
}

/// `values` ([h * w * 3]) zero-padded on the right and bottom to at least `min` x `min`.
fn pad_to(values: Vec<f32>, w: usize, h: usize, min: usize) -> (Vec<f32>, usize, usize) {
    let (pw, ph) = (w.max(min), h.max(min));
    if (pw, ph) == (w, h) {
        return (values, w, h);
    }
    let mut out = vec![0.0; pw * ph * 3];
    for y in 0..h {
        out[y * pw * 3..(y * pw + w) * 3].copy_from_slice(&values[y * w * 3..(y + 1) * w * 3]);
    }
    (out, pw, ph)
}

/// LPIPS between `pred` and `gt` ([H * W * 3] in [0, 1]), both zeroed outside `mask` and
/// cropped to its bounding rectangle, as SSIM is scored. A crop smaller than the network
/// takes ([`LpipsNet::min_image_size`]: 31 px for AlexNet, 16 for VGG; only tiny test images
/// have one) is zero-padded on the right and bottom to that size, the value outside the mask.
pub fn lpips_masked_crop(
    lpips: &Lpips,
    pred: &ImageView<'_>,
    gt: &ImageView<'_>,
    mask: &[bool],
    device: &Device,
) -> Result<f64, PerceptualError> {
    let min = lpips.net().min_image_size();
    let (p, w, h) = masked_crop(pred, mask)?;
    let (g, _, _) = masked_crop(gt, mask)?;
    let (p, _, _) = pad_to(p, w, h, min);
    let (g, w, h) = pad_to(g, w, h, min);
    let d = lpips
        .distance(chw(&p, w, h, device), chw(&g, w, h, device))
        .map_err(|source| PerceptualError::Distance {
            net: lpips.net().name(),
            width: w,
            height: h,
            source,
        })?;
    Ok(d.into_scalar::<f32>() as f64)
}
