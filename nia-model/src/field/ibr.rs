//! Image-based rendering inputs (NIA section 3.2): source colours c_n and pixel features l_n
//! fetched at the projection of x into each source view (the view-direction features d_hat_n
//! are computed with the other point inputs, [`nia_data::scene::PointInputs`]), and the fixed
//! colour rules of the ablation variants (c) and (d).
//!
//! Sampling: `proj_grid[n, m] = (u_norm, v_norm)` with `u_norm = 2 u / W - 1`,
//! `v_norm = 2 v / H - 1` (u, v in pixels of the full-resolution source image, pixel centres at
//! i + 0.5). `grid_sample_2d` with bilinear interpolation, zero padding and
//! `align_corners = false` reads pixel (u - 0.5, v - 0.5) of a W x H map, and the same
//! normalised coordinates address the half-resolution feature maps consistently (the feature
//! map covers the same image extent). Points outside a view (or behind its camera, which the
//! CPU precompute maps far outside [-1, 1]) read zeros.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::ops::GridSampleOptions;

use nia_data::scene::VIEW_DIR_FEATURE_DIM;

use crate::shape::ShapeError;
use crate::softmax::stable_softmax;

/// Temperature tau of variant (d), `softmax_n(cos_n / tau)`: with 3 views 120 degrees apart a
/// cosine gap of 0.3 gives a weight ratio of e^3 ~ 20, so the nearest view dominates without
/// discarding the others.
pub const DEFAULT_COSINE_TEMPERATURE: f32 = 0.1;

/// Bilinearly samples N maps at M points each.
///
/// # Shapes
/// - `maps`: `[N, C, H, W]` (source images or feature maps of view n)
/// - `proj_grid`: `[N, M, 2]`, (x, y) in [-1, 1] (see the module docs)
/// - output: `[N, M, C]`, zeros where the projection falls outside the map
pub fn sample_views(maps: Tensor<4>, proj_grid: Tensor<3>) -> Result<Tensor<3>, ShapeError> {
    let [n, c, h, w] = maps.dims();
    let [n_grid, m, two] = proj_grid.dims();
    ShapeError::check(
        "IBR `proj_grid` [N, M, 2]",
        &[n_grid, m, two],
        &[Some(n), None, Some(2)],
    )?;
    if n == 0 || h == 0 || w == 0 {
        return Err(ShapeError::empty("IBR `maps` [N, C, H, W]"));
    }
    let options = GridSampleOptions::default().with_align_corners(false);
    // [N, 1, M, 2] -> [N, C, 1, M] -> [N, C, M] -> [N, M, C]
    let sampled = maps.grid_sample_2d(proj_grid.reshape([n, 1, m, 2]), options);
    Ok(sampled.reshape([n, c, m]).swap_dims(1, 2))
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
    ShapeError::check(
        "IBR `images` [N, 3, H, W]",
        &images.dims(),
        &[None, Some(3), None, None],
    )?;
    sample_views(images, proj_grid)
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
    /// Samples and reduces the per-view feature maps.
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

/// Variant (c): `c = mean_n c_n`.
///
/// # Shapes
/// - `source_colours` c_n: `[N, M, 3]`
/// - output c: `[M, 3]`
pub fn simple_average_colour(source_colours: Tensor<3>) -> Result<Tensor<2>, ShapeError> {
    let [n, m, c] = source_colours.dims();
    ShapeError::check(
        "IBR `source_colours` [N, M, 3]",
        &[n, m, c],
        &[None, None, Some(3)],
    )?;
    if n == 0 {
        return Err(ShapeError::empty("IBR `source_colours` views N"));
    }
    Ok(source_colours.mean_dim(0).reshape([m, 3]))
}

/// Variant (d): `c = sum_n softmax_n(cos_n / tau) c_n`, cos_n = d . d_n (the last channel of
/// d_hat_n). The softmax is max-subtracted, so it is defined for any cosines (a normalised
/// positive-cosine weight would divide by zero when every source view faces away).
///
/// # Shapes
/// - `source_colours` c_n: `[N, M, 3]`
/// - `view_dir_features` d_hat_n: `[N, M, 4]`
/// - output c: `[M, 3]`
pub fn cosine_weighted_colour(
    source_colours: Tensor<3>,
    view_dir_features: Tensor<3>,
    temperature: f32,
) -> Result<Tensor<2>, ShapeError> {
    let [n, m, c] = source_colours.dims();
    ShapeError::check(
        "IBR `source_colours` [N, M, 3]",
        &[n, m, c],
        &[None, None, Some(3)],
    )?;
    ShapeError::check(
        "IBR `view_dir_features` [N, M, 4]",
        &view_dir_features.dims(),
        &[Some(n), Some(m), Some(VIEW_DIR_FEATURE_DIM)],
    )?;
    if n == 0 {
        return Err(ShapeError::empty("IBR `source_colours` views N"));
    }
    if !(temperature.is_finite() && temperature > 0.0) {
        return Err(ShapeError::value(
            "IBR cosine `temperature`",
            format!("a finite value > 0, got {temperature}"),
        ));
    }
    let cosine = view_dir_features.slice(s![.., .., 3..4]); // [N, M, 1]
    let weights = stable_softmax(cosine.div_scalar(temperature), 0);
    Ok((source_colours * weights).sum_dim(0).reshape([m, 3]))
}
