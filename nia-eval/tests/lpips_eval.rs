#![allow(deprecated)] // Device::ndarray(): burn deprecates it; it is the reference CPU backend.

//! LPIPS as evaluation scores it ([`nia_eval::perceptual`]): on the full image it is the
//! `lpips` package's distance (nia-model's fixtures: narrow random trunks, the package's own
//! forward); on a mask it is the distance of the zeroed, cropped (and, below the network's
//! minimum size, zero-padded) pair, as SSIM is scored.

use std::path::{Path, PathBuf};

use burn::prelude::*;
use nia_data::metrics::ImageView;
use nia_eval::perceptual::{lpips_masked_crop, LpipsFiles};
use nia_model::lpips::LpipsNet;

/// nia-model's LPIPS tolerance against the package (f32 through up to 13 convs).
const TOLERANCE: f64 = 3e-6;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../nia-model/tests/fixtures/lpips")
        .join(name)
}

fn files(net: &str) -> LpipsFiles {
    let widths: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("widths.json")).unwrap()).unwrap();
    LpipsFiles {
        net: net.parse::<LpipsNet>().unwrap(),
        backbone: fixture(&format!("{net}_trunk.pth")),
        heads: fixture(&format!("{net}_heads.pth")),
        widths: Some(
            widths[net]
                .as_array()
                .unwrap()
                .iter()
                .map(|w| w.as_u64().unwrap() as usize)
                .collect(),
        ),
    }
}

/// Image `i` of an [N, 3, 64, 64] fixture as [64 * 64 * 3] HWC values.
fn hwc(name: &str, i: usize) -> Vec<f32> {
    let array = nia_data::formats::npy::read(&fixture(name)).unwrap();
    let v = array.to_f32_vec().unwrap();
    let (h, w) = (64, 64);
    let plane = h * w;
    let base = i * 3 * plane;
    (0..plane)
        .flat_map(|p| (0..3).map(move |c| (c, p)))
        .map(|(c, p)| v[base + c * plane + p])
        .collect()
}

#[test]
fn full_mask_gives_the_package_distance_and_a_mask_scores_the_crop() {
    let device = Device::ndarray();
    for net in ["alex", "vgg"] {
        let lpips = files(net).load(&device).unwrap();
        let want = nia_data::formats::npy::read(&fixture(&format!("{net}_distances_f64.npy")))
            .unwrap()
            .to_f32_vec()
            .unwrap();
        for (i, want) in want.iter().enumerate() {
            let (a, b) = (hwc("a.npy", i), hwc("b.npy", i));
            let av = ImageView::new("a", &a, 64, 64, 3).unwrap();
            let bv = ImageView::new("b", &b, 64, 64, 3).unwrap();
            let d = lpips_masked_crop(&lpips, &av, &bv, &vec![true; 64 * 64], &device).unwrap();
            assert!(
                (d - *want as f64).abs() < TOLERANCE,
                "{net} pair {i}: {d} vs {want}"
            );
        }
        // A mask: the rectangle 40x36 at (10, 20) with one pixel off inside it. The score is
        // the distance of the crops with that pixel zeroed in both.
        let (a, b) = (hwc("a.npy", 0), hwc("b.npy", 0));
        let mut mask = vec![false; 64 * 64];
        for y in 20..56 {
            for x in 10..50 {
                mask[y * 64 + x] = true;
            }
        }
        mask[30 * 64 + 30] = false;
        let crop = |img: &[f32]| -> Vec<f32> {
            let mut out = Vec::new();
            for y in 20..56 {
                for x in 10..50 {
                    for c in 0..3 {
                        out.push(if mask[y * 64 + x] {
                            img[(y * 64 + x) * 3 + c]
                        } else {
                            0.0
                        });
                    }
                }
            }
            out
        };
        let tensor = |v: Vec<f32>| {
            Tensor::<3>::from_data(TensorData::new(v, [36, 40, 3]), &device)
                .permute([2, 0, 1])
                .unsqueeze::<4>()
        };
        let direct = lpips
            .distance(tensor(crop(&a)), tensor(crop(&b)))
            .unwrap()
            .into_scalar::<f32>() as f64;
        let av = ImageView::new("a", &a, 64, 64, 3).unwrap();
        let bv = ImageView::new("b", &b, 64, 64, 3).unwrap();
        let masked = lpips_masked_crop(&lpips, &av, &bv, &mask, &device).unwrap();
        assert!(
            (masked - direct).abs() < 1e-6,
            "{net}: {masked} vs {direct}"
        );
        // A crop below AlexNet's 31 px is padded, not refused: finite and non-negative.
        let mut small = vec![false; 64 * 64];
        for y in 5..15 {
            for x in 5..25 {
                small[y * 64 + x] = true;
            }
        }
        let d = lpips_masked_crop(&lpips, &av, &bv, &small, &device).unwrap();
        assert!(d.is_finite() && d >= 0.0, "{net}: {d}");
        // An empty mask is an error, not a number.
        assert!(lpips_masked_crop(&lpips, &av, &bv, &vec![false; 64 * 64], &device).is_err());
    }
}
