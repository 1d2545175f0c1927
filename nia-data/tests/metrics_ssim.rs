//! PSNR / SSIM against reference values computed with real scikit-image
//! (`scripts/fixtures/make_ssim_fixtures.py`, values in `tests/fixtures/ssim/values.json`).

use std::path::{Path, PathBuf};

use nia_data::dataset::image_io::{read_mask, read_rgb8, u8_to_unit};
use nia_data::metrics::{evaluate, ssim, ImageView, SsimOptions};

/// The bar: SSIM within 1e-4 of scikit-image. The remaining differences are f64
/// rounding of window sums (summed-area tables here, running sums in scipy), ~1e-12.
const SSIM_TOL: f64 = 1e-4;
/// PSNR agreement in dB (same formula in f64; only summation order differs).
const PSNR_TOL: f64 = 1e-6;

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ssim")
}

/// An image as floats, `channels` 1 (grey, from the red channel of the decoded RGB, which equals
/// the grey value) or 3.
fn load(name: &str, channels: usize) -> (usize, usize, Vec<f32>) {
    let img = read_rgb8(&dir().join(name)).unwrap();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let all = u8_to_unit(img.as_raw());
    let data = if channels == 3 {
        all
    } else {
        all.chunks_exact(3).map(|p| p[0]).collect()
    };
    (w, h, data)
}

#[test]
fn ssim_and_psnr_match_scikit_image() {
    let text = std::fs::read_to_string(dir().join("values.json")).unwrap();
    let values: serde_json::Value = serde_json::from_str(&text).unwrap();
    let cases = values["cases"].as_array().unwrap();
    assert_eq!(cases.len(), 5);
    let mut masked = 0;
    for case in cases {
        let name = case["name"].as_str().unwrap();
        let c = case["channels"].as_u64().unwrap() as usize;
        let (w, h, gt) = load(case["gt"].as_str().unwrap(), c);
        let (_, _, pred) = load(case["pred"].as_str().unwrap(), c);
        let gv = ImageView::new("gt", &gt, w, h, c).unwrap();
        let pv = ImageView::new("pred", &pred, w, h, c).unwrap();
        for (key, options) in [
            ("ssim_range2", SsimOptions::nhp()),
            ("ssim_range1", SsimOptions::unit_range()),
        ] {
            let want = case[key].as_f64().unwrap();
            let got = ssim(&pv, &gv, options).unwrap();
            assert!(
                (got - want).abs() < SSIM_TOL,
                "{name} {key}: got {got}, scikit-image {want}"
            );
        }
        if let Some(mask_name) = case["mask"].as_str() {
            let (mw, mh, mask) = read_mask(&dir().join(mask_name)).unwrap();
            assert_eq!((mw as usize, mh as usize), (w, h));
            let m = evaluate(&pv, &gv, &mask, SsimOptions::nhp()).unwrap();
            let want_psnr = case["nhp_psnr"].as_f64().unwrap();
            let want_ssim = case["nhp_ssim"].as_f64().unwrap();
            assert!(
                (m.psnr - want_psnr).abs() < PSNR_TOL,
                "{name}: psnr {} vs {want_psnr}",
                m.psnr
            );
            assert!(
                (m.ssim - want_ssim).abs() < SSIM_TOL,
                "{name}: ssim {} vs {want_ssim}",
                m.ssim
            );
            masked += 1;
        }
    }
    assert_eq!(masked, 2, "both masked cases were checked");
}

#[test]
fn data_range_two_scores_higher_than_one_on_dark_images() {
    // The reason the published numbers need data_range = 2: larger C1/C2 raise the score,
    // most where the means are small.
    let (w, h, gt) = load("dark_gt.png", 3);
    let (_, _, pred) = load("dark_pred.png", 3);
    let gv = ImageView::new("gt", &gt, w, h, 3).unwrap();
    let pv = ImageView::new("pred", &pred, w, h, 3).unwrap();
    let two = ssim(&pv, &gv, SsimOptions::nhp()).unwrap();
    let one = ssim(&pv, &gv, SsimOptions::unit_range()).unwrap();
    assert!(two > one + 0.01, "{two} vs {one}");
}
