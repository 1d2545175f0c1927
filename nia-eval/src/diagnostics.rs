//! Instruments of the hybrid, per evaluated image: does the blend use the source views where
//! they see the surface, what each half of the hybrid would render alone, and how sharp the
//! density is. They go into `eval`'s metrics.json and report.md so every change to sampling,
//! losses or the blender shows its effect there.
//!
//! - `c0_weight_seen` / `c0_weight_unseen`: the mean share of the NeRF colour c0 in the blend
//!   (`w_0 / acc`) over person pixels whose surface some source view sees, and over those none
//!   sees. The surface of a pixel is the posed SMPL mesh rasterised into the target view; it is
//!   seen by view n when the face's nearest vertex (largest barycentric) is visible in n.
//! - `psnr_nerf` / `psnr_ibr`: PSNR of the NeRF-only composite C0 and of the IBR-only composite
//!   (the source colours under the blend weights renormalised over the views), on the same
//!   `mask_at_box` region as the image's PSNR.
//! - `depth_error_m`: mean |z(expected depth) - z(rasterised mesh)| over person pixels the mesh
//!   covers and the render makes opaque (acc > 0.5); camera depth, metres.
//! - `depth_error_true_m` (only where the data holds the true surface: synthetic sets write the
//!   clothed surface their images show, `clothed_vertices/`): the same mean against that surface
//!   rasterised, over the opaque person pixels it covers. Beside `depth_error_m` it says whether
//!   the density sits on the person or on the fitted body where hair and clothes leave it.
//! - `opacity_outside` / `opacity_inside`: mean accumulated opacity over scored pixels off the
//!   person's mask and on it (ideally 0 and 1).
//! - `psnr_silhouette` / `psnr_interior`: the image's PSNR split in two: over the scored pixels
//!   on either side of the person mask's boundary ([`silhouette_band`]: a pixel with an
//!   8-neighbour of the other mask value), and over the rest of the scored region. At 128 px a
//!   person's silhouette band is about a seventh of the scored pixels and, in the quickstart,
//!   half of the squared error: a blurred or shifted outline costs more than blurred prints.
//! - `psnr_truth`, `ssim_truth`, `psnr_ibr_truth` (only with a truth set,
//!   [`crate::truth::TruthData`]): the image's PSNR and SSIM and the IBR-only composite's PSNR
//!   against the truth set's image of the same view, on the same region.

use glam::Vec3;
use nia_data::dataset::loader::Scene;
use nia_data::geometry::camera::Camera;
use nia_data::geometry::raster::{rasterize, Fragments, EMPTY_FACE};
use nia_data::geometry::rays::{image_rays, Ray};
use nia_data::metrics::{evaluate, psnr_masked, ImageView, MetricsError, SsimOptions};
use nia_model::renderer::image::RenderedImage;
use serde::Serialize;

/// Opacity above which a pixel's expected depth is compared with the mesh.
const OPAQUE: f32 = 0.5;

/// The instruments of one image (module docs). `None` where the pixel set is empty.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct BlendDiagnostics {
    pub c0_weight_seen: Option<f64>,
    pub c0_weight_unseen: Option<f64>,
    /// Share of the person's scored pixels whose surface some source view sees.
    pub seen_fraction: Option<f64>,
    pub psnr_nerf: f64,
    pub psnr_ibr: f64,
    pub depth_error_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_error_true_m: Option<f64>,
    pub opacity_outside: Option<f64>,
    pub opacity_inside: Option<f64>,
    pub psnr_silhouette: Option<f64>,
    pub psnr_interior: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psnr_truth: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ssim_truth: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psnr_ibr_truth: Option<f64>,
}

/// The pixels on either side of the boundary of `mask`: those with an 8-neighbour (inside the
/// image) of the other mask value.
///
/// # Shapes
/// - `mask`, output: `[H * W]` row-major
pub fn silhouette_band(mask: &[bool], width: usize, height: usize) -> Vec<bool> {
    let mut band = vec![false; width * height];
    for y in 0..height {
        for x in 0..width {
            let m = mask[y * width + x];
            'around: for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if nx < 0 || ny < 0 || nx >= width as i64 || ny >= height as i64 {
                        continue;
                    }
                    if mask[ny as usize * width + nx as usize] != m {
                        band[y * width + x] = true;
                        break 'around;
                    }
                }
            }
        }
    }
    band
}

/// PSNR of `pred` against `gt` over the scored pixels of the silhouette band of `person_mask`
/// and over the other scored pixels: `(silhouette, interior)`, `None` for an empty set.
///
/// # Shapes
/// - `pred`, `gt`: `[H * W * 3]`; `person_mask`, `mask_at_box`: `[H * W]`
pub fn silhouette_split(
    pred: &ImageView<'_>,
    gt: &ImageView<'_>,
    person_mask: &[bool],
    mask_at_box: &[bool],
) -> Result<(Option<f64>, Option<f64>), MetricsError> {
    let (w, h) = (gt.width, gt.height);
    if person_mask.len() != w * h {
        return Err(MetricsError::Size {
            what: "person mask",
            expected: w * h,
            got: person_mask.len(),
            width: w,
            height: h,
            channels: 1,
        });
    }
    let band = silhouette_band(person_mask, w, h);
    let on_band: Vec<bool> = band
        .iter()
        .zip(mask_at_box)
        .map(|(&b, &m)| b && m)
        .collect();
    let off_band: Vec<bool> = band
        .iter()
        .zip(mask_at_box)
        .map(|(&b, &m)| !b && m)
        .collect();
    let psnr_over = |mask: &[bool]| -> Result<Option<f64>, MetricsError> {
        if mask.iter().any(|&m| m) {
            Ok(Some(psnr_masked(pred, gt, mask)?))
        } else {
            Ok(None)
        }
    };
    Ok((psnr_over(&on_band)?, psnr_over(&off_band)?))
}

/// What [`BlendDiagnostics::measure`] reads.
pub struct DiagnosticsInput<'a> {
    pub rendered: &'a RenderedImage,
    /// The target camera.
    pub camera: &'a Camera,
    /// [H * W * 3] ground truth.
    pub ground_truth: &'a [f32],
    /// [H * W] the person's mask in the target view.
    pub person_mask: &'a [bool],
    /// [H * W] the scored region.
    pub mask_at_box: &'a [bool],
    /// [V] the rendered pose's mesh (world metres) and the model's triangles.
    pub posed_vertices: &'a [Vec3],
    pub faces: &'a [[u32; 3]],
    /// The scene of the source views (its per-view vertex visibility, same vertex indices).
    pub sources: &'a Scene,
    /// [H * W * 3] the truth set's image of the target view ([`crate::truth::TruthData`]).
    pub truth: Option<&'a [f32]>,
    /// [V] the true (clothed) surface of the target frame, world metres, with `faces`
    /// (synthetic sets' `clothed_vertices/`); `None` for real data.
    pub true_surface: Option<&'a [Vec3]>,
}

fn mean(sum: f64, count: usize) -> Option<f64> {
    (count > 0).then(|| sum / count as f64)
}

impl BlendDiagnostics {
    /// Measures one image (module docs).
    pub fn measure(input: &DiagnosticsInput<'_>) -> Result<Self, MetricsError> {
        let r = input.rendered;
        let (w, h) = (r.width, r.height);
        let k = r.blend_channels;
        let psnr_of = |rgb: &[f32], name: &'static str| -> Result<f64, MetricsError> {
            let pv = ImageView::new(name, rgb, w, h, 3)?;
            let gv = ImageView::new("ground truth", input.ground_truth, w, h, 3)?;
            Ok(evaluate(&pv, &gv, input.mask_at_box, SsimOptions::nhp())?.psnr)
        };
        let psnr_nerf = psnr_of(&r.rgb0, "NeRF-only composite")?;
        let psnr_ibr = psnr_of(&r.rgb_ibr, "IBR-only composite")?;
        let against_truth = |rgb: &[f32], name: &'static str| -> Result<_, MetricsError> {
            match input.truth {
                Some(truth) => {
                    let pv = ImageView::new(name, rgb, w, h, 3)?;
                    let tv = ImageView::new("truth set's image", truth, w, h, 3)?;
                    Ok(Some(evaluate(
                        &pv,
                        &tv,
                        input.mask_at_box,
                        SsimOptions::nhp(),
                    )?))
                }
                None => Ok(None),
            }
        };
        let truth = against_truth(&r.rgb, "prediction")?;
        let ibr_truth = against_truth(&r.rgb_ibr, "IBR-only composite")?;
        let (psnr_silhouette, psnr_interior) = silhouette_split(
            &ImageView::new("prediction", &r.rgb, w, h, 3)?,
            &ImageView::new("ground truth", input.ground_truth, w, h, 3)?,
            input.person_mask,
            input.mask_at_box,
        )?;

        // The mesh in the target view, and which source view sees each pixel's surface.
        let frags = rasterize(input.camera, input.posed_vertices, input.faces).ok();
        let seen_by_some = |p: usize| -> Option<bool> {
            let frags = frags.as_ref()?;
            let face = *frags.face.get(p)?;
            if face == EMPTY_FACE {
                return None;
            }
            let tri = input.faces.get(face as usize)?;
            let b = frags.bary[p];
            let corner = (0..3).fold(0, |best, i| if b[i] > b[best] { i } else { best });
            let v = tri[corner] as usize;
            Some(
                input
                    .sources
                    .sources
                    .iter()
                    .any(|s| s.visibility.get(v).is_some_and(|&x| x > 0)),
            )
        };
        let (mut seen_sum, mut seen_n, mut unseen_sum, mut unseen_n) = (0.0, 0, 0.0, 0);
        let (mut out_sum, mut out_n, mut in_sum, mut in_n) = (0.0, 0, 0.0, 0);
        for p in 0..w * h {
            if !input.mask_at_box[p] {
                continue;
            }
            let acc = r.acc[p];
            if !input.person_mask[p] {
                out_sum += acc as f64;
                out_n += 1;
                continue;
            }
            in_sum += acc as f64;
            in_n += 1;
            let seen = seen_by_some(p);
            if acc > 1e-3 {
                let share = (r.blend_weights[k * p] / acc).clamp(0.0, 1.0) as f64;
                match seen {
                    Some(true) => {
                        seen_sum += share;
                        seen_n += 1;
                    }
                    Some(false) => {
                        unseen_sum += share;
                        unseen_n += 1;
                    }
                    None => {}
                }
            }
        }
        // Opaque person pixels: where the expected depth is compared with a surface.
        let opaque = |p: usize| input.mask_at_box[p] && input.person_mask[p] && r.acc[p] > OPAQUE;
        let rays = image_rays(input.camera);
        let depth_error = |surface: Option<&[Vec3]>| {
            let frags = rasterize(input.camera, surface?, input.faces).ok()?;
            mean_depth_error(input.camera, &rays, &r.depth, &r.acc, &frags, &opaque)
        };
        let depth_error_m = frags
            .as_ref()
            .and_then(|f| mean_depth_error(input.camera, &rays, &r.depth, &r.acc, f, &opaque));
        let depth_error_true_m = depth_error(input.true_surface);
        Ok(BlendDiagnostics {
            c0_weight_seen: mean(seen_sum, seen_n),
            c0_weight_unseen: mean(unseen_sum, unseen_n),
            seen_fraction: mean(seen_n as f64, seen_n + unseen_n),
            psnr_nerf,
            psnr_ibr,
            depth_error_m,
            depth_error_true_m,
            opacity_outside: mean(out_sum, out_n),
            opacity_inside: mean(in_sum, in_n),
            psnr_silhouette,
            psnr_interior,
            psnr_truth: truth.map(|m| m.psnr),
            ssim_truth: truth.map(|m| m.ssim),
            psnr_ibr_truth: ibr_truth.map(|m| m.psnr),
        })
    }

    /// The mean of each instrument over `all` (over the images where it is defined).
    pub fn mean_of<'a>(all: impl Iterator<Item = &'a BlendDiagnostics> + Clone) -> Self {
        let avg = |f: &dyn Fn(&BlendDiagnostics) -> Option<f64>| {
            let v: Vec<f64> = all.clone().filter_map(f).collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        };
        BlendDiagnostics {
            c0_weight_seen: avg(&|d| d.c0_weight_seen),
            c0_weight_unseen: avg(&|d| d.c0_weight_unseen),
            seen_fraction: avg(&|d| d.seen_fraction),
            psnr_nerf: avg(&|d| Some(d.psnr_nerf)).unwrap_or(f64::NAN),
            psnr_ibr: avg(&|d| Some(d.psnr_ibr)).unwrap_or(f64::NAN),
            depth_error_m: avg(&|d| d.depth_error_m),
            depth_error_true_m: avg(&|d| d.depth_error_true_m),
            opacity_outside: avg(&|d| d.opacity_outside),
            opacity_inside: avg(&|d| d.opacity_inside),
            psnr_silhouette: avg(&|d| d.psnr_silhouette),
            psnr_interior: avg(&|d| d.psnr_interior),
            psnr_truth: avg(&|d| d.psnr_truth),
            ssim_truth: avg(&|d| d.ssim_truth),
            psnr_ibr_truth: avg(&|d| d.psnr_ibr_truth),
        }
    }
}

/// Mean |z(expected depth) - z(surface)| over the pixels `counted` where `surface` (rasterised
/// into `camera`) covers the pixel; `None` where no pixel counts. The expected depth of pixel p
/// is `depth[p] / acc[p]` along the ray through its centre; camera depth, metres.
///
/// # Shapes
/// - `rays`, `depth`, `acc`: `[H * W]` ([`image_rays`] of `camera`, the render's sums)
pub fn mean_depth_error(
    camera: &Camera,
    rays: &[Ray],
    depth: &[f32],
    acc: &[f32],
    surface: &Fragments,
    counted: &dyn Fn(usize) -> bool,
) -> Option<f64> {
    let (mut sum, mut n) = (0.0, 0);
    for (p, ray) in rays.iter().enumerate() {
        let z_surface = surface.depth[p];
        if !counted(p) || !z_surface.is_finite() {
            continue;
        }
        let point = ray.origin + ray.dir * (depth[p] / acc[p]);
        sum += ((camera.r * point + camera.t).z - z_surface).abs() as f64;
        n += 1;
    }
    mean(sum, n)
}

/// A markdown table of the instruments, one row per `(name, means)`, with a legend.
pub fn diagnostics_table(rows: &[(String, BlendDiagnostics)]) -> String {
    let opt =
        |v: Option<f64>, digits: usize| v.map_or("-".to_string(), |v| format!("{v:.digits$}"));
    let mut md = String::from(
        "| subject | c0 share, seen | c0 share, unseen | seen | PSNR NeRF-only | PSNR IBR-only | depth error (cm) | true-surface depth error (cm) | opacity off person | opacity on person | PSNR silhouette | PSNR interior |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for (name, d) in rows {
        md.push_str(&format!(
            "| {name} | {} | {} | {} | {:.2} | {:.2} | {} | {} | {} | {} | {} | {} |\n",
            opt(d.c0_weight_seen, 3),
            opt(d.c0_weight_unseen, 3),
            opt(d.seen_fraction, 2),
            d.psnr_nerf,
            d.psnr_ibr,
            opt(d.depth_error_m.map(|m| 100.0 * m), 2),
            opt(d.depth_error_true_m.map(|m| 100.0 * m), 2),
            opt(d.opacity_outside, 3),
            opt(d.opacity_inside, 3),
            opt(d.psnr_silhouette, 2),
            opt(d.psnr_interior, 2),
        ));
    }
    md.push_str(
        "\nInstruments of the hybrid (`nia_eval::diagnostics`): c0 share = mean NeRF-colour weight of the blend on person pixels whose surface some source view sees (seen) or none sees (unseen); seen = share of person pixels seen; PSNR of the NeRF-only and IBR-only composites on the scored region; depth error = mean |expected depth - rasterised SMPL depth| on opaque person pixels, and the same against the true clothed surface where the data holds it (synthetic sets); mean opacity off and on the person's mask; the image's PSNR on the scored pixels next to the person mask's boundary (either side, 8-neighbourhood) and on the rest.\n",
    );
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The expected depth of every pixel 0.1 m behind a plane at z = 2 m, seen head-on from
    /// the origin: the mean error is 0.1 m whatever the opacity, over the counted pixels the
    /// plane covers; none counted, or no surface in view: `None`.
    #[test]
    fn depth_error_is_measured_against_the_rasterised_surface() {
        use glam::{Mat3, Vec3};
        let (w, h) = (16u32, 12u32);
        let camera = Camera::new(
            Mat3::from_cols_array(&[40.0, 0.0, 0.0, 0.0, 40.0, 0.0, 8.0, 6.0, 1.0]),
            Mat3::IDENTITY,
            Vec3::ZERO,
            [0.0; 5],
            w,
            h,
        )
        .unwrap();
        let plane = |z: f32| {
            let v = vec![
                Vec3::new(-1.0, -1.0, z),
                Vec3::new(1.0, -1.0, z),
                Vec3::new(1.0, 1.0, z),
                Vec3::new(-1.0, 1.0, z),
            ];
            (v, vec![[0u32, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]])
        };
        let rays = image_rays(&camera);
        let n = (w * h) as usize;
        let acc: Vec<f32> = (0..n).map(|p| 0.6 + 0.3 * (p % 3) as f32 / 2.0).collect();
        // depth = acc * t with the ray's point at camera z = 2.1.
        let depth: Vec<f32> = (0..n).map(|p| acc[p] * 2.1 / rays[p].dir.z).collect();
        let (v, f) = plane(2.0);
        let frags = rasterize(&camera, &v, &f).unwrap();
        let all = |_: usize| true;
        let e = mean_depth_error(&camera, &rays, &depth, &acc, &frags, &all).unwrap();
        assert!((e - 0.1).abs() < 1e-4, "{e}");
        let odd = |p: usize| p % 2 == 1;
        let e = mean_depth_error(&camera, &rays, &depth, &acc, &frags, &odd).unwrap();
        assert!((e - 0.1).abs() < 1e-4, "{e}");
        let none = |_: usize| false;
        assert_eq!(
            mean_depth_error(&camera, &rays, &depth, &acc, &frags, &none),
            None
        );
        // The plane behind the camera: nothing covered.
        let (v, f) = plane(-2.0);
        let behind = rasterize(&camera, &v, &f).unwrap();
        assert_eq!(
            mean_depth_error(&camera, &rays, &depth, &acc, &behind, &all),
            None
        );
    }

    /// A 6x5 mask with a 2x2 square at (2..4, 1..3).
    fn square() -> (Vec<bool>, usize, usize) {
        let (w, h) = (6, 5);
        let mask = (0..w * h)
            .map(|p| (2..4).contains(&(p % w)) && (1..3).contains(&(p / w)))
            .collect();
        (mask, w, h)
    }

    #[test]
    fn the_band_is_both_sides_of_the_boundary() {
        let (mask, w, h) = square();
        let band = silhouette_band(&mask, w, h);
        // The square and its 8-neighbourhood ring (x 1..5, y 0..4) is the band; nothing else.
        assert_eq!(band.len(), w * h);
        for (p, &inside) in band.iter().enumerate() {
            let (x, y) = (p % w, p / w);
            let expected = (1..5).contains(&x) && (0..4).contains(&y);
            assert_eq!(inside, expected, "pixel ({x}, {y})");
        }
        assert!(silhouette_band(&[true; 12], 4, 3).iter().all(|&b| !b));
    }

    #[test]
    fn an_error_on_the_outline_only_lowers_the_silhouette_psnr() {
        let (mask, w, h) = square();
        let gt: Vec<f32> = (0..w * h * 3).map(|i| (i % 7) as f32 / 7.0).collect();
        let band = silhouette_band(&mask, w, h);
        let mut pred = gt.clone();
        for p in (0..w * h).filter(|&p| band[p]) {
            for c in 0..3 {
                pred[p * 3 + c] += 0.1;
            }
        }
        let view = |d| ImageView::new("x", d, w, h, 3).unwrap();
        let all = vec![true; w * h];
        let (sil, int) = silhouette_split(&view(&pred), &view(&gt), &mask, &all).unwrap();
        // Every band pixel is off by 0.1 in each channel: PSNR = -10 log10(0.01) = 20 dB.
        assert!((sil.unwrap() - 20.0).abs() < 1e-4, "{sil:?}");
        assert_eq!(int, Some(f64::INFINITY));
        // A scored region that misses the band leaves the silhouette undefined.
        let off: Vec<bool> = band.iter().map(|&b| !b).collect();
        let (sil, _) = silhouette_split(&view(&pred), &view(&gt), &mask, &off).unwrap();
        assert_eq!(sil, None);
        // A person mask of the wrong size is refused with its name.
        let err = silhouette_split(&view(&pred), &view(&gt), &mask[1..], &all).unwrap_err();
        assert!(err.to_string().contains("person mask"), "{err}");
    }
}
