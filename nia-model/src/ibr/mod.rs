//! Image-based rendering inputs (NIA section 3.2): source colours c_n and pixel features l_n
//! fetched at the projection of x into each source view (the view-direction features d_hat_n
//! are computed with the other point inputs, [`nia_data::scene::PointInputs`]), and the fixed
//! colour rules of the ablation variants (c) and (d).
//!
//! Sampling: `proj_grid[n, m] = (u_norm, v_norm)` with `u_norm = 2 u / W - 1`,
//! `v_norm = 2 v / H - 1` (u, v in pixels of the full-resolution source image, pixel centres at
//! i + 0.5). The bilinear read ([`crate::encoder::bilinear`]; `grid_sample_2d`'s with zero padding and
//! `align_corners = false`) reads pixel (u - 0.5, v - 0.5) of a W x H map, and the same
//! normalised coordinates address the half-resolution feature maps consistently (the feature
//! map covers the same image extent). Points outside a view (or behind its camera, which the
//! CPU precompute maps far outside [-1, 1]) read zeros.

pub mod blend_host;
pub mod blender;
pub mod c0_shuffle;
pub mod c0_weight_scale;
pub mod surface;
pub mod view_statistics;

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use nia_data::scene::VIEW_DIR_FEATURE_DIM;

use crate::encoder::bilinear::ViewRows;
use crate::encoder::FeaturePyramid;
use crate::shape::ShapeError;

/// Bilinearly samples N maps at M points each ([`crate::encoder::bilinear::sample`]: the read of
/// `grid_sample_2d` with bilinear interpolation, zero padding and `align_corners = false`, as
/// four row gathers).
///
/// # Shapes
/// - `maps`: `[N, C, H, W]` (source images or feature maps of view n)
/// - `proj_grid`: `[N, M, 2]`, (x, y) in [-1, 1] (see the module docs)
/// - output: `[N, M, C]`, zeros where the projection falls outside the map
pub fn sample_views(maps: Tensor<4>, proj_grid: Tensor<3>) -> Result<Tensor<3>, ShapeError> {
    crate::encoder::bilinear::sample(maps, proj_grid)
}

/// `Linear(sample(F))` from maps already through the linear map's weights (`W^T F`) and laid
/// out as rows: the sampled maps plus the bias (sampling is linear, and the bias counts once
/// also where the projection falls outside the map).
///
/// # Shapes
/// - `reduced_rows`: maps `[N, d_out, H, W]`; `proj_grid`: `[N, M, 2]`
/// - output: `[N, M, d_out]`
pub fn sample_rows_through(
    linear: &Linear,
    reduced_rows: &ViewRows,
    proj_grid: Tensor<3>,
) -> Result<Tensor<3>, ShapeError> {
    let sampled = reduced_rows.sample(proj_grid)?;
    Ok(match &linear.bias {
        Some(b) => sampled + b.val().unsqueeze::<3>(),
        None => sampled,
    })
}

/// Source colours c_n: the source images sampled at the projections of x.
///
/// # Shapes
/// - `images`: `[N, 3, H, W]` in [0, 1] (black background)
/// - `proj_grid`: `[N, M, 2]`
/// - output c_n: `[N, M, 3]`
pub fn fetch_source_colours(
    images: Tensor<4>,
    proj_grid: Tensor<3>,
) -> Result<Tensor<3>, ShapeError> {
    fetch_source_colours_from(&ViewRows::new(images)?, proj_grid)
}

/// [`fetch_source_colours`] from the source images laid out as rows once per scene
/// ([`crate::SceneEncoding::image_rows`]).
///
/// # Shapes
/// - `image_rows`: images `[N, 3, H, W]`; `proj_grid`: `[N, M, 2]`
/// - output c_n: `[N, M, 3]`
pub fn fetch_source_colours_from(
    image_rows: &ViewRows,
    proj_grid: Tensor<3>,
) -> Result<Tensor<3>, ShapeError> {
    ShapeError::check(
        "IBR `images` [N, 3, H, W]",
        &image_rows.dims(),
        &[None, Some(3), None, None],
    )?;
    image_rows.sample(proj_grid)
}

/// Configuration of [`PixelFeature`].
#[derive(Config, Debug)]
pub struct PixelFeatureConfig {
    /// Channels of the encoder's feature maps (512 in the paper).
    #[config(default = 512)]
    pub d_image: usize,
    /// Reduced width d (128).
    #[config(default = 128)]
    pub d_model: usize,
}

/// The pixel-aligned feature l_n = Linear(grid_sample(feature_maps, proj_grid)); it is both the
/// attention's L and the blender's p_n.
#[derive(Module, Debug)]
pub struct PixelFeature {
    /// Channel reduction `d_image -> d_model`.
    pub reduce: Linear,
}

impl PixelFeatureConfig {
    /// A freshly initialised pixel-feature reduction on `device`.
    pub fn init(&self, device: &Device) -> PixelFeature {
        PixelFeature {
            reduce: LinearConfig::new(self.d_image, self.d_model).init(device),
        }
    }
}

impl PixelFeature {
    /// The reduction's weights applied to every pixel of the feature maps, without the bias:
    /// `(W^T F)[n, :, y, x]`. Sampling is linear in the map, so `sample(W^T F) + b` equals
    /// [`Self::forward`]'s `Linear(sample(F))` (zero padding included: the bias is added after
    /// sampling), and reducing the maps once per scene makes every point's gather 4x narrower
    /// (128 channels instead of 512) and lets every ray chunk of an image reuse the reduction.
    /// The reduction is taken on the encoder's pyramid before upsampling
    /// ([`FeaturePyramid::reduce`]), so F itself is never built.
    ///
    /// # Shapes
    /// - `pyramid`: levels with `d_image` channels in all
    /// - output: `[N, d_model, H/2, W/2]`
    pub fn reduce_maps(&self, pyramid: &FeaturePyramid) -> Result<Tensor<4>, ShapeError> {
        pyramid.reduce(self.reduce.weight.val())
    }

    /// l_n from maps reduced by [`Self::reduce_maps`] and laid out as rows: sampled, plus the
    /// bias.
    ///
    /// # Shapes
    /// - `reduced_rows`: maps `[N, d_model, H/2, W/2]`
    /// - `proj_grid`: `[N, M, 2]`
    /// - output l_n: `[N, M, d_model]`
    pub fn sample_reduced(
        &self,
        reduced_rows: &ViewRows,
        proj_grid: Tensor<3>,
    ) -> Result<Tensor<3>, ShapeError> {
        let d_model = self.reduce.weight.dims()[1];
        ShapeError::check(
            "IBR reduced `pixel_maps` [N, d, H/2, W/2]",
            &reduced_rows.dims(),
            &[None, Some(d_model), None, None],
        )?;
        sample_rows_through(&self.reduce, reduced_rows, proj_grid)
    }

    /// Samples and reduces the per-view feature maps (the reference form of
    /// [`Self::reduce_maps`] + [`Self::sample_reduced`], which the renderer uses).
    ///
    /// # Shapes
    /// - `feature_maps`: `[N, d_image, H/2, W/2]`
    /// - `proj_grid`: `[N, M, 2]`
    /// - output `pixel_feature` l_n: `[N, M, d_model]`
    pub fn forward(
        &self,
        feature_maps: Tensor<4>,
        proj_grid: Tensor<3>,
    ) -> Result<Tensor<3>, ShapeError> {
        let d_image = self.reduce.weight.dims()[0];
        ShapeError::check(
            "IBR `feature_maps` [N, C_img, H/2, W/2]",
            &feature_maps.dims(),
            &[None, Some(d_image), None, None],
        )?;
        Ok(self.reduce.forward(sample_views(feature_maps, proj_grid)?))
    }
}

/// Variant (c), the paper's "simple average of the different colour predictions": equal
/// weights `1 / (N + 1)` over `[c0, c_1..c_N]`.
///
/// # Shapes
/// - output weights: `[M, N + 1]` (index 0 = c0), rows sum to 1
pub fn simple_average_weights(
    m: usize,
    n: usize,
    device: &Device,
) -> Result<Tensor<2>, ShapeError> {
    if n == 0 {
        return Err(ShapeError::empty("IBR views N"));
    }
    Ok(Tensor::full([m, n + 1], 1.0 / (n + 1) as f32, device))
}

/// Variant (d), the paper's average "weighted by the cosine similarity" of the target ray to
/// each prediction's view direction: `w ∝ [1, max(cos_1, 0) .. max(cos_N, 0)]` over
/// `[c0, c_1..c_N]`, cos_n = d . d_n (the last channel of d_hat_n). c0 is predicted for the
/// target ray itself (cos = 1, as F_B's NeRF token has d_hat = (0, 0, 0, 1)). A source view
/// facing away gets weight 0, and the denominator is >= 1, so no input divides by zero.
///
/// # Shapes
/// - `view_dir_features` d_hat_n: `[N, M, 4]`
/// - output weights: `[M, N + 1]` (index 0 = c0), rows sum to 1
pub fn cosine_weights(view_dir_features: Tensor<3>) -> Result<Tensor<2>, ShapeError> {
    let [n, m, k] = view_dir_features.dims();
    ShapeError::check(
        "IBR `view_dir_features` [N, M, 4]",
        &[n, m, k],
        &[None, None, Some(VIEW_DIR_FEATURE_DIM)],
    )?;
    if n == 0 {
        return Err(ShapeError::empty("IBR `view_dir_features` views N"));
    }
    let device = view_dir_features.device();
    let cosine = view_dir_features
        .slice(s![.., .., 3..4])
        .reshape([n, m])
        .transpose()
        .clamp_min(0.0); // [M, N]
    let raw = Tensor::cat(vec![Tensor::ones([m, 1], &device), cosine], 1); // [M, N + 1]
    let total = raw.clone().sum_dim(1); // [M, 1], >= 1
    Ok(raw / total)
}

#[cfg(test)]
mod reduced_maps_tests {
    use super::*;

    /// f32 sums of 512 products in another order: measured ~1e-6 on values of ~1.
    const TOL: f32 = 1e-5;

    #[test]
    #[allow(deprecated)] // Device::ndarray(): the reference CPU backend.
    fn reduce_then_sample_equals_sample_then_reduce_outside_the_map_too() {
        let device = Device::ndarray();
        let feature = PixelFeatureConfig::new()
            .with_d_image(24)
            .with_d_model(8)
            .init(&device);
        // Four levels of 6 channels at one resolution: F is their concatenation.
        let level = || {
            Tensor::<4>::random(
                [2, 6, 5, 7],
                burn::tensor::Distribution::Normal(0.0, 1.0),
                &device,
            )
        };
        let pyramid = FeaturePyramid {
            levels: [level(), level(), level(), level()],
        };
        let maps = pyramid.clone().concatenated();
        // Inside, on the border, outside (zero padding, where the bias still counts once).
        let grid = Tensor::<3>::from_floats(
            [
                [[0.1, -0.3], [0.99, 0.99], [1.5, 0.0], [-3.0, -3.0]],
                [[-0.7, 0.4], [0.0, 1.0], [0.3, -1.2], [0.5, 0.5]],
            ],
            &device,
        );
        let reference = feature.forward(maps.clone(), grid.clone()).unwrap();
        let reduced = feature.reduce_maps(&pyramid).unwrap();
        assert_eq!(reduced.dims(), [2, 8, 5, 7]);
        let rows = ViewRows::new(reduced).unwrap();
        let fast = feature.sample_reduced(&rows, grid).unwrap();
        let diff = (reference - fast).abs().max().into_scalar::<f32>();
        assert!(diff < TOL, "{diff}");
    }
}
