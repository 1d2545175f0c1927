//! Appearance blending F_B (NIA section 3.2, "neural appearance blending").
//!
//! F_B is an 8-layer ReLU MLP applied to N + 1 tokens per point, with shared weights, so any
//! number of views N >= 1 works:
//!
//! - token n = 1..N (source view n): `[p_n, d_hat_n, o_n, flag = 0 ; h, psi]`
//! - token 0 (the NeRF colour c0): `[mean_n p_n, (0, 0, 0, 1), mean_n o_n, flag = 1 ; h, psi]`
//!   (d_hat of a view looking exactly along the target ray is (0, 0, 0, 1); the flag channel
//!   tells the two kinds of token apart)
//!
//! Each token gives one logit: `blend_logits = [w_0, w_1..w_N]`, and the point's colour is
//! `c = softmax(w) . [c0, c_1..c_N]`. The softmax subtracts the (detached) maximum before `exp`,
//! so logits of +-1e4 stay finite, and the denominator is >= 1 (the max term is exp(0)): there is
//! no division by zero even when every view is invisible (o_n = 0). Visibility is an input of
//! F_B, not a hard mask: token 0 always takes part, so a point seen by no view falls back on c0
//! as far as F_B has learned to.
//!
//! The first layer is split in two linear maps that are summed, `W_t [p, d_hat, o, flag] + b +
//! W_p [h, psi]`, which is exactly one linear layer on the concatenated token; the per-point part
//! `W_p [h, psi]` is computed once per point instead of N + 1 times (h is the widest input).
//! The paper gives the depth (8), not the width: `d_hidden` defaults to 128.
//!
//! View statistics (switchable, `ModelConfig::blend_view_statistics`; not in the paper): in the
//! paper's F_B a view's token meets the other views only through h and psi, so F_B cannot tell
//! a source colour that agrees with the other views (the point is where the views say it is)
//! from one that does not (occlusion, misregistration). With statistics on, every token also
//! carries its colour (c_n, or c0 for token 0), and the per-point part the across-view mean and
//! variance of the pixel features and of the source colours, weighted by visibility (IBRNet's
//! global context): `W_t [p, d_hat, o, flag, c] + b + W_p [h, psi, mean p, var p, mean c, var c]`.
//!
//! Without features (switchable, `ModelConfig::blend_reads_features`; not in the paper) F_B
//! reads neither p_n nor h, nor their statistics: `W_t [d_hat, o, flag (, c)] + b + W_p [psi
//! (, mean c, var c)]`. The rationale: p_n and h describe the person's texture and shape, so an
//! F_B that reads them can fit its trust in each source to the few people it trains on; without
//! them its trust rests on where the views look from, whether they see the point, and whether
//! their colours agree. What it measured (a small gain; trained longer, F_B still drifts towards
//! c0) is in docs/results.md, "The learned blend under each flaw".

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

use super::c0_weight_scale::rescale_c0_weight;
use super::view_statistics::{mean_and_variance, view_weights};
use super::{cosine_weights, simple_average_weights};
use crate::kernels::linear_host::linear;
use crate::kernels::linear_rows::linear_rows;
use crate::shape::ShapeError;
use crate::softmax::stable_softmax;
use crate::variant::Variant;
use nia_data::scene::VIEW_DIR_FEATURE_DIM;

/// Number of linear layers of F_B (paper).
pub const BLENDER_LAYERS: usize = 8;

/// Per-token channels besides p_n: d_hat (4), o (1), flag (1).
pub const TOKEN_EXTRA_DIM: usize = VIEW_DIR_FEATURE_DIM + 2;

/// Configuration of [`Blender`] (F_B).
#[derive(Config, Debug)]
pub struct BlenderConfig {
    /// Width d of the pixel feature p_n.
    #[config(default = 128)]
    pub d_pixel: usize,
    /// Width d_h of F_c0's hidden feature h.
    #[config(default = 256)]
    pub d_h: usize,
    /// Hidden width of the MLP.
    #[config(default = 128)]
    pub d_hidden: usize,
    /// Give the tokens their colours and the across-view statistics (module docs).
    #[config(default = false)]
    pub view_statistics: bool,
    /// F_B reads p_n and h (module docs).
    #[config(default = true)]
    pub reads_features: bool,
}

/// F_B: N + 1 blend logits per point from per-view tokens and the NeRF token.
#[derive(Module, Debug)]
pub struct Blender {
    /// First layer, token part: `[p, d_hat, o, flag] -> d_hidden` (with bias).
    pub token_input: Linear,
    /// First layer, per-point part: `[h, psi] -> d_hidden` (no bias).
    pub point_input: Linear,
    /// Layers 2..8; the last maps to one logit.
    pub layers: Vec<Linear>,
    /// Tokens carry colours and across-view statistics (module docs).
    #[module(skip)]
    pub view_statistics: bool,
    /// F_B reads p_n and h (module docs).
    #[module(skip)]
    pub reads_features: bool,
}

impl BlenderConfig {
    /// Width of the per-token part: `[p, d_hat, o, flag]` (+ `c` with statistics; no p
    /// without features).
    fn token_part_dim(&self) -> usize {
        let p = if self.reads_features { self.d_pixel } else { 0 };
        p + TOKEN_EXTRA_DIM + if self.view_statistics { 3 } else { 0 }
    }

    /// Width of the per-point part: `[h, psi]` (+ `mean p, var p, mean c, var c`; no h, mean p
    /// or var p without features).
    fn point_part_dim(&self) -> usize {
        let (p, h) = if self.reads_features {
            (self.d_pixel, self.d_h)
        } else {
            (0, 0)
        };
        h + 1 + if self.view_statistics { 2 * p + 6 } else { 0 }
    }

    /// A freshly initialised F_B on `device`.
    pub fn init(&self, device: &Device) -> Blender {
        let mut layers = Vec::with_capacity(BLENDER_LAYERS - 1);
        for _ in 1..BLENDER_LAYERS - 1 {
            layers.push(LinearConfig::new(self.d_hidden, self.d_hidden).init(device));
        }
        layers.push(LinearConfig::new(self.d_hidden, 1).init(device));
        Blender {
            token_input: LinearConfig::new(self.token_part_dim(), self.d_hidden).init(device),
            point_input: LinearConfig::new(self.point_part_dim(), self.d_hidden)
                .with_bias(false)
                .init(device),
            layers,
            view_statistics: self.view_statistics,
            reads_features: self.reads_features,
        }
    }
}

/// Everything the colour rules of the variants read, for M points and N views.
#[derive(Debug, Clone)]
pub struct BlendInputs {
    /// NeRF colour c0, `[M, 3]`.
    pub c0: Tensor<2>,
    /// Confidence psi, `[M, 1]`.
    pub confidence: Tensor<2>,
    /// F_c0's hidden feature h, `[M, d_h]`.
    pub h: Tensor<2>,
    /// Source colours c_n, `[N, M, 3]`.
    pub source_colours: Tensor<3>,
    /// Pixel features p_n (= l_n), `[N, M, d]`.
    pub pixel_feature: Tensor<3>,
    /// View-direction features d_hat_n, `[N, M, 4]`.
    pub view_dir_features: Tensor<3>,
    /// Visibility o_n in [0, 1], `[N, M]`.
    pub visibility: Tensor<2>,
}

/// The colour of M points and the weights that mixed it.
#[derive(Debug, Clone)]
pub struct PointColour {
    /// c, `[M, 3]`.
    pub colour: Tensor<2>,
    /// Effective weights over `[c0, c_1..c_N]`, `[M, N + 1]`, rows sum to 1: F_B's softmax for
    /// the blended variants, one-hot on c0 for `NoIbr`, `1 / (N + 1)` each for `SimpleAverage`,
    /// `∝ (1, max(cos_n, 0))` for `CosineWeighted` (`field::ibr`).
    pub blend_weights: Tensor<2>,
}

impl Blender {
    /// The blend logits w_0..w_N (index 0 = the NeRF colour c0) of `inputs` (the colours c0
    /// and c_n are read with view statistics only).
    ///
    /// # Shapes
    /// - `inputs`: as [`BlendInputs`]
    /// - output `blend_logits`: `[M, N + 1]`
    pub fn forward(&self, inputs: &BlendInputs) -> Result<Tensor<2>, ShapeError> {
        let (tokens, point) = self.tokens(inputs.clone())?;
        Ok(self.logits(tokens, point))
    }

    /// F_B's inputs: the N + 1 tokens and the per-point part, checked and laid out (see the
    /// module docs).
    ///
    /// # Shapes
    /// - `inputs`: as [`BlendInputs`]
    /// - outputs: tokens `[N + 1, M, d + 6 (+3)]` (token 0 = c0's), per-point part
    ///   `[M, d_h + 1 (+2d + 6)]`
    pub fn tokens(&self, inputs: BlendInputs) -> Result<(Tensor<3>, Tensor<2>), ShapeError> {
        self.check_inputs(&inputs)?;
        let BlendInputs {
            c0,
            confidence,
            h,
            source_colours,
            pixel_feature,
            view_dir_features,
            visibility,
        } = inputs;
        let [n, m, _] = pixel_feature.dims();
        let device = pixel_feature.device();

        let visibility = visibility.reshape([n, m, 1]);
        let mut view_parts = vec![
            view_dir_features,
            visibility.clone(),
            Tensor::zeros([n, m, 1], &device),
        ];
        let nerf_dir =
            Tensor::<1>::from_data(TensorData::new(vec![0.0f32, 0.0, 0.0, 1.0], [4]), &device)
                .reshape([1, 1, 4])
                .expand([1, m, 4]);
        let mut nerf_parts = vec![
            nerf_dir,
            visibility.clone().mean_dim(0),
            Tensor::ones([1, m, 1], &device),
        ];
        let mut point_parts = vec![confidence];
        if self.reads_features {
            view_parts.insert(0, pixel_feature.clone());
            nerf_parts.insert(0, pixel_feature.clone().mean_dim(0));
            point_parts.insert(0, h);
        }
        if self.view_statistics {
            // Visibility-weighted across-view statistics, [M, k] each.
            let omega = view_weights(visibility.clone().reshape([n, m]));
            if self.reads_features {
                let (mean_p, var_p) = mean_and_variance(pixel_feature, omega.clone())?;
                point_parts.extend([mean_p, var_p]);
            }
            let (mean_c, var_c) = mean_and_variance(source_colours.clone(), omega)?;
            point_parts.extend([mean_c, var_c]);
            view_parts.push(source_colours);
            nerf_parts.push(c0.unsqueeze_dim::<3>(0));
        }
        let view_tokens = Tensor::cat(view_parts, 2);
        let nerf_token = Tensor::cat(nerf_parts, 2);
        let tokens = Tensor::cat(vec![nerf_token, view_tokens], 0); // [N + 1, M, d + 6 (+3)]
        Ok((tokens, Tensor::cat(point_parts, 1)))
    }

    /// The checks of [`Self::tokens`]: every input's shape, at least one view, and with view
    /// statistics the colours c0 `[M, 3]` and c_n `[N, M, 3]`.
    pub fn check_inputs(&self, inputs: &BlendInputs) -> Result<(), ShapeError> {
        let [n, m, d] = inputs.pixel_feature.dims();
        let colour_dim = if self.view_statistics { 3 } else { 0 };
        // Without features p_n and h may have any width: F_B reads neither.
        let d_read = if self.reads_features { d } else { 0 };
        let d_token = self.token_input.weight.dims()[0];
        let d_point = self.point_input.weight.dims()[0]
            - if self.view_statistics {
                2 * d_read + 6
            } else {
                0
            };
        let features = |width: usize| self.reads_features.then_some(width);
        ShapeError::check(
            "F_B `pixel_feature` [N, M, d]",
            &[n, m, d],
            &[None, None, features(d_token - TOKEN_EXTRA_DIM - colour_dim)],
        )?;
        if n == 0 {
            return Err(ShapeError::empty("F_B views N"));
        }
        ShapeError::check(
            "F_B `view_dir_features` [N, M, 4]",
            &inputs.view_dir_features.dims(),
            &[Some(n), Some(m), Some(VIEW_DIR_FEATURE_DIM)],
        )?;
        ShapeError::check(
            "F_B `visibility` [N, M]",
            &inputs.visibility.dims(),
            &[Some(n), Some(m)],
        )?;
        ShapeError::check(
            "F_B `h` [M, d_h]",
            &inputs.h.dims(),
            &[Some(m), features(d_point - 1)],
        )?;
        ShapeError::check(
            "F_B `confidence` [M, 1]",
            &inputs.confidence.dims(),
            &[Some(m), Some(1)],
        )?;
        if self.view_statistics {
            ShapeError::check("F_B `c0` [M, 3]", &inputs.c0.dims(), &[Some(m), Some(3)])?;
            ShapeError::check(
                "F_B `source_colours` [N, M, 3]",
                &inputs.source_colours.dims(),
                &[Some(n), Some(m), Some(3)],
            )?;
        }
        Ok(())
    }

    /// F_B's layers on its inputs ([`Self::tokens`]): `relu(W_t token + b + W_p point)`, then
    /// layers 2..8, one logit per token.
    ///
    /// # Shapes
    /// - `tokens`: `[N + 1, M, d_token]`; `point`: `[M, d_point]`
    /// - output `[M, N + 1]`
    pub fn logits(&self, tokens: Tensor<3>, point: Tensor<2>) -> Tensor<2> {
        let [t, m, _] = tokens.dims();
        // point: [1, M, d_hidden]; first: [N + 1, M, d_hidden]
        let point = linear(&self.point_input, point, false).unsqueeze_dim::<3>(0);
        let first = relu(linear_rows(&self.token_input, tokens) + point);
        // Layers 2..8 on the tokens as rows of one matrix: one matmul per layer instead of a
        // batch of N + 1 (the weights are shared).
        let width = first.dims()[2];
        let mut x = first.reshape([t * m, width]);
        let last = self.layers.len() - 1;
        for (i, layer) in self.layers.iter().enumerate() {
            x = linear(layer, x, i < last);
        }
        // [(N + 1) M, 1] -> [M, N + 1]
        x.reshape([t, m]).transpose()
    }

    /// The colour of each point under `variant` (see [`PointColour::blend_weights`]).
    ///
    /// # Shapes
    /// - see [`BlendInputs`]; output colour `[M, 3]`, blend weights `[M, N + 1]`
    pub fn colour(&self, variant: Variant, inputs: BlendInputs) -> Result<PointColour, ShapeError> {
        self.colour_with_c0_scale(variant, inputs, None)
    }

    /// [`Self::colour`] with c0's odds in F_B's softmax multiplied by `c0_weight_scale`
    /// before the mix (inference only, `[render] c0_weight_scale`: [`rescale_c0_weight`]);
    /// the fixed rules of (b)-(d) ignore it.
    ///
    /// # Shapes
    /// - as [`Self::colour`]
    pub fn colour_with_c0_scale(
        &self,
        variant: Variant,
        inputs: BlendInputs,
        c0_weight_scale: Option<f32>,
    ) -> Result<PointColour, ShapeError> {
        let [n, m] = inputs.visibility.dims();
        ShapeError::check("blend `c0` [M, 3]", &inputs.c0.dims(), &[Some(m), Some(3)])?;
        if n == 0 {
            return Err(ShapeError::empty("blend views N"));
        }
        if variant != Variant::NoIbr {
            ShapeError::check(
                "blend `source_colours` [N, M, 3]",
                &inputs.source_colours.dims(),
                &[Some(n), Some(m), Some(3)],
            )?;
        }
        let device = inputs.c0.device();
        match variant {
            Variant::NoIbr => {
                let one_hot = Tensor::cat(
                    vec![
                        Tensor::ones([m, 1], &device),
                        Tensor::zeros([m, n], &device),
                    ],
                    1,
                );
                Ok(PointColour {
                    colour: inputs.c0,
                    blend_weights: one_hot,
                })
            }
            Variant::SimpleAverage => mix(
                simple_average_weights(m, n, &device)?,
                inputs.c0,
                inputs.source_colours,
            ),
            Variant::CosineWeighted => {
                ShapeError::check(
                    "blend `view_dir_features` [N, M, 4]",
                    &inputs.view_dir_features.dims(),
                    &[Some(n), Some(m), Some(VIEW_DIR_FEATURE_DIM)],
                )?;
                mix(
                    cosine_weights(inputs.view_dir_features)?,
                    inputs.c0,
                    inputs.source_colours,
                )
            }
            Variant::NoBody | Variant::Full => {
                // The colours are cloned: the blend below reads them again.
                let (tokens, point) = self.tokens(BlendInputs {
                    c0: inputs.c0.clone(),
                    source_colours: inputs.source_colours.clone(),
                    ..inputs
                })?;
                let blend_logits = self.logits(tokens, point);
                match c0_weight_scale {
                    None => blend(blend_logits, inputs.c0, inputs.source_colours),
                    Some(scale) => {
                        let weights = stable_softmax(blend_logits, 1);
                        let weights = rescale_c0_weight(weights, scale)?;
                        mix(weights, inputs.c0, inputs.source_colours)
                    }
                }
            }
        }
    }
}

/// `c = softmax(w) . [c0, c_1..c_N]`, max-subtracted.
///
/// # Shapes
/// - `blend_logits` w: `[M, N + 1]` (index 0 = c0)
/// - `c0`: `[M, 3]`
/// - `source_colours` c_n: `[N, M, 3]`
/// - output: colour `[M, 3]`, blend weights `[M, N + 1]`
///
/// The softmax keeps the logits' shape, so [`mix`] checks all three inputs.
pub fn blend(
    blend_logits: Tensor<2>,
    c0: Tensor<2>,
    source_colours: Tensor<3>,
) -> Result<PointColour, ShapeError> {
    mix(stable_softmax(blend_logits, 1), c0, source_colours)
}

/// `c = weights . [c0, c_1..c_N]`.
///
/// # Shapes
/// - `blend_weights`: `[M, N + 1]` (index 0 = c0), rows summing to 1
/// - `c0`: `[M, 3]`; `source_colours` c_n: `[N, M, 3]`
/// - output: colour `[M, 3]` and the weights
pub fn mix(
    blend_weights: Tensor<2>,
    c0: Tensor<2>,
    source_colours: Tensor<3>,
) -> Result<PointColour, ShapeError> {
    let [n, m, three] = source_colours.dims();
    ShapeError::check(
        "mix `source_colours` [N, M, 3]",
        &[n, m, three],
        &[None, None, Some(3)],
    )?;
    ShapeError::check("mix `c0` [M, 3]", &c0.dims(), &[Some(m), Some(3)])?;
    ShapeError::check(
        "mix `blend_weights` [M, N + 1]",
        &blend_weights.dims(),
        &[Some(m), Some(n + 1)],
    )?;
    // [N + 1, M, 3] candidates, weighted by [N + 1, M, 1].
    let candidates = Tensor::cat(vec![c0.unsqueeze_dim::<3>(0), source_colours], 0);
    let weights = blend_weights.clone().transpose().reshape([n + 1, m, 1]);
    let colour = (candidates * weights).sum_dim(0).reshape([m, 3]);
    Ok(PointColour {
        colour,
        blend_weights,
    })
}
