//! F_sigma, F_c0 and F_B with their weights on the host, fused and in parallel (inference on
//! the CPU backends).
//!
//! The three MLP stacks run as [`HostMlp`]s: each task carries its rows through every layer in
//! cache, where the tensor path allocates, zeroes, copies and revisits every layer's output on
//! the calling thread ([`crate::kernels::host_mlp`]). F_B's tokens and per-point part are laid out on
//! the host as [`Blender::tokens`] lays them out (with the view statistics' weighted means and
//! variances); after F_B the softmax, c0's rescaled odds, the mix and the IBR-only colour
//! run in one host pass too ([`crate::ibr::blend_host`]). The activations of F_sigma and F_c0
//! (softplus, sigmoid) stay tensor operations. [`crate::SceneEncoding::with_host_reads`] reads
//! the weights once per scene; the tensor path stays the reference, the path with gradients and
//! the one on the GPU (`nia-model/tests/host_network.rs` and `tests/model.rs` compare them).

use burn::prelude::*;
use burn::tensor::activation::{sigmoid, softplus};

use super::heads::{ColourHead, ColourHeadOutput, DensityHead};
use super::positional_encoding::PositionalEncoding;
use rayon::prelude::*;

use crate::ibr::blend_host::blend_on_host;
use crate::ibr::blender::{BlendInputs, Blender, PointColour, TOKEN_EXTRA_DIM};
use crate::ibr::view_statistics::STATISTICS_FLOOR;
use crate::kernels::host_buffer::zeroed;
use crate::kernels::host_mlp::{FirstLayerAddend, HostMlp, ROWS_PER_TASK};
use crate::kernels::readback::host_view_of;
use crate::shape::ShapeError;
use nia_data::scene::VIEW_DIR_FEATURE_DIM;

/// F_c0's layer whose ReLU activation is h (the third of four).
const H_LAYER: usize = 2;

/// F_sigma, F_c0 and F_B's two parts on the host.
#[derive(Debug, Clone)]
pub struct HostNetwork {
    /// F_sigma's four layers.
    density: HostMlp,
    /// F_sigma's shift before softplus.
    density_shift: f64,
    /// F_c0's four layers.
    colour: HostMlp,
    /// F_B's per-point part `W_p [h, psi]` (one layer, no bias).
    blend_point: HostMlp,
    /// F_B's token layer and layers 2..8.
    blend_tokens: HostMlp,
}

impl HostNetwork {
    /// Reads the heads' and the blender's weights back.
    pub fn read(
        density: &DensityHead,
        colour: &ColourHead,
        blender: &Blender,
    ) -> Result<Self, ShapeError> {
        let mut tokens = vec![blender.token_input.clone()];
        tokens.extend(blender.layers.iter().cloned());
        Ok(HostNetwork {
            density: HostMlp::read("host F_sigma", &density.layers)?,
            density_shift: density.density_shift,
            colour: HostMlp::read("host F_c0", &colour.layers)?,
            blend_point: HostMlp::read(
                "host F_B per-point layer",
                std::slice::from_ref(&blender.point_input),
            )?,
            blend_tokens: HostMlp::read("host F_B token layers", &tokens)?,
        })
    }

    /// [`DensityHead::forward`]: `sigma = softplus(F_sigma(mean_n z_n) + density_shift)`.
    ///
    /// # Shapes
    /// - `mean_feature`: `[M, d]`; output `[M]`
    pub fn density(&self, mean_feature: Tensor<2>) -> Result<Tensor<1>, ShapeError> {
        let [m, _] = mean_feature.dims();
        let device = mean_feature.device();
        let x = host_view_of("host F_sigma input", mean_feature)?;
        let raw = self.density.forward("host F_sigma", &x, m, None, None)?;
        let raw = Tensor::<1>::from_data(TensorData::new(raw.output, [m]), &device);
        Ok(softplus(raw.add_scalar(self.density_shift), 1.0))
    }

    /// [`ColourHead::forward`]: c0, psi and h from `[mean_n z_n ; gamma(d)]`.
    ///
    /// # Shapes
    /// - `mean_feature`: `[M, d]`; `dir_encoding`: `[M, d_direction]`
    /// - outputs: c0 `[M, 3]`, confidence `[M, 1]`, h `[M, d_h]`
    pub fn colour(
        &self,
        mean_feature: Tensor<2>,
        dir_encoding: Tensor<2>,
    ) -> Result<ColourHeadOutput, ShapeError> {
        let [m, _] = mean_feature.dims();
        ShapeError::check(
            "host F_c0 `dir_encoding` [M, 27]",
            &[dir_encoding.dims()[0]],
            &[Some(m)],
        )?;
        let device = mean_feature.device();
        let x = host_view_of(
            "host F_c0 input",
            Tensor::cat(vec![mean_feature, dir_encoding], 1),
        )?;
        self.colour_rows(&x, m, &device)
    }

    /// [`Self::colour`] with gamma(d) written on the host, each row's encoding straight after
    /// its mean feature in F_c0's input (the tensor encoding and the concatenation ran on the
    /// calling thread).
    ///
    /// # Shapes
    /// - `mean_feature`: `[M, d]`; `dirs`: `[M, 3]` unit directions
    /// - outputs: as [`Self::colour`]
    pub fn colour_of_directions(
        &self,
        mean_feature: Tensor<2>,
        dirs: Tensor<2>,
        encoding: &PositionalEncoding,
    ) -> Result<ColourHeadOutput, ShapeError> {
        let [m, d] = mean_feature.dims();
        ShapeError::check("host F_c0 `dirs` [M, 3]", &dirs.dims(), &[Some(m), Some(3)])?;
        let device = mean_feature.device();
        let mean = host_view_of("host F_c0 mean feature", mean_feature)?;
        let dirs = host_view_of("host F_c0 directions", dirs)?;
        let width = d + encoding.output_dim();
        let mut x = zeroed(m * width);
        x.par_chunks_mut(ROWS_PER_TASK * width)
            .enumerate()
            .for_each(|(task, block)| {
                for (r, row) in block.chunks_mut(width).enumerate() {
                    let i = task * ROWS_PER_TASK + r;
                    let (feature, gamma) = row.split_at_mut(d);
                    feature.copy_from_slice(&mean[i * d..(i + 1) * d]);
                    encoding.encode_to([dirs[3 * i], dirs[3 * i + 1], dirs[3 * i + 2]], gamma);
                }
            });
        self.colour_rows(&x, m, &device)
    }

    /// F_c0 on its input rows `[M, d + d_direction]` and the heads' activations.
    fn colour_rows(
        &self,
        x: &[f32],
        m: usize,
        device: &Device,
    ) -> Result<ColourHeadOutput, ShapeError> {
        let out = self
            .colour
            .forward("host F_c0", x, m, None, Some(H_LAYER))?;
        let tapped = out.tapped.ok_or_else(|| {
            ShapeError::value("host F_c0", "h, the third layer's activation".into())
        })?;
        let d_h = self.colour.width_after(H_LAYER).unwrap_or(0);
        let h = Tensor::<2>::from_data(TensorData::new(tapped, [m, d_h]), device);
        let out = Tensor::<2>::from_data(TensorData::new(out.output, [m, 4]), device);
        Ok(ColourHeadOutput {
            c0: sigmoid(out.clone().slice(s![.., 0..3])),
            confidence: sigmoid(out.slice(s![.., 3..4])),
            h,
        })
    }

    /// [`Blender::colour`] for the variants with F_B ((e) full, (a) no body), its logits from
    /// [`Self::blend_logits_token_major`], then the softmax, c0's odds times `c0_weight_scale` (if any),
    /// the mix and the IBR-only colour in one host pass ([`blend_on_host`]).
    ///
    /// # Shapes
    /// - as [`BlendInputs`]; output colour `[M, 3]` and blend weights `[M, N + 1]`, and the
    ///   IBR-only colour `[M, 3]`
    pub fn blend_colour(
        &self,
        blender: &Blender,
        inputs: BlendInputs,
        c0_weight_scale: Option<f32>,
    ) -> Result<(PointColour, Tensor<2>), ShapeError> {
        blender.check_inputs(&inputs)?;
        let [n, m, _] = inputs.source_colours.dims();
        let device = inputs.c0.device();
        let c0 = host_view_of("host F_B c0", inputs.c0.clone())?;
        let c = host_view_of("host F_B c_n", inputs.source_colours.clone())?;
        let logits = self.blend_logits_token_major(blender, &inputs, &c0, &c)?;
        let out = blend_on_host(&logits, &c0, &c, n, m, c0_weight_scale)?;
        let tensor = |values: Vec<f32>, width: usize| {
            Tensor::<2>::from_data(TensorData::new(values, [m, width]), &device)
        };
        Ok((
            PointColour {
                colour: tensor(out.colour, 3),
                blend_weights: tensor(out.blend_weights, n + 1),
            },
            tensor(out.ibr_colour, 3),
        ))
    }

    /// F_B's blend logits w_0..w_N from its inputs, the tokens and the per-point part laid out
    /// on the host exactly as [`Blender::tokens`] lays them out (module docs of
    /// [`crate::ibr::blender`]), in parallel, then the layers. The inputs must have passed
    /// [`Blender::check_inputs`]; `c0` and `c` are their c0 and c_n read back.
    ///
    /// # Shapes
    /// - as [`BlendInputs`] (N views, M points); `c0`: `[M, 3]`; `c`: `[N, M, 3]`
    /// - output: `[N + 1, M]`, token-major
    pub(crate) fn blend_logits_token_major(
        &self,
        blender: &Blender,
        inputs: &BlendInputs,
        c0: &[f32],
        c: &[f32],
    ) -> Result<Vec<f32>, ShapeError> {
        let view_statistics = blender.view_statistics;
        let [n, m, d] = inputs.pixel_feature.dims();
        let t = n + 1;
        if m == 0 {
            return Ok(Vec::new());
        }
        let read = |what: &str, x: Tensor<3>| host_view_of(what, x);
        let d_hat = read("host F_B d_hat_n", inputs.view_dir_features.clone())?;
        let o = host_view_of("host F_B o_n", inputs.visibility.clone())?;
        let psi = host_view_of("host F_B psi", inputs.confidence.clone())?;
        // Without features F_B reads neither p_n nor h: both are laid out 0 wide.
        let (p_values, h_values) = if blender.reads_features {
            (
                Some(read("host F_B p_n", inputs.pixel_feature.clone())?),
                Some(host_view_of("host F_B h", inputs.h.clone())?),
            )
        } else {
            (None, None)
        };
        let p: &[f32] = p_values.as_deref().unwrap_or(&[]);
        let h: &[f32] = h_values.as_deref().unwrap_or(&[]);
        let d = if blender.reads_features { d } else { 0 };
        let d_h = h.len() / m;
        let colour_dim = if view_statistics { 3 } else { 0 };
        let d_token = d + TOKEN_EXTRA_DIM + colour_dim;
        let d_point = d_h + 1 + if view_statistics { 2 * d + 6 } else { 0 };
        let inv_n = 1.0 / n as f32;

        // Tokens, token-major [N + 1, M, d_token]: token 0 is c0's.
        let mut tokens = zeroed(t * m * d_token);
        tokens
            .par_chunks_mut(ROWS_PER_TASK * d_token)
            .enumerate()
            .for_each(|(task, block)| {
                for (r, row) in block.chunks_mut(d_token).enumerate() {
                    let (token, i) = (
                        (task * ROWS_PER_TASK + r) / m,
                        (task * ROWS_PER_TASK + r) % m,
                    );
                    let (feature, rest) = row.split_at_mut(d);
                    if token == 0 {
                        // [mean_n p_n, (0, 0, 0, 1), mean_n o_n, 1 (, c0)]
                        feature.fill(0.0);
                        let mut o_sum = 0.0f32;
                        for view in 0..n {
                            let pv = &p[(view * m + i) * d..(view * m + i + 1) * d];
                            for (acc, x) in feature.iter_mut().zip(pv) {
                                *acc += x;
                            }
                            o_sum += o[view * m + i];
                        }
                        for acc in feature.iter_mut() {
                            *acc *= inv_n;
                        }
                        rest[..VIEW_DIR_FEATURE_DIM].copy_from_slice(&NERF_DIRECTION);
                        rest[VIEW_DIR_FEATURE_DIM] = o_sum * inv_n;
                        rest[VIEW_DIR_FEATURE_DIM + 1] = 1.0;
                        if view_statistics {
                            rest[TOKEN_EXTRA_DIM..].copy_from_slice(&c0[i * 3..i * 3 + 3]);
                        }
                    } else {
                        // [p_n, d_hat_n, o_n, 0 (, c_n)]
                        let at = (token - 1) * m + i;
                        feature.copy_from_slice(&p[at * d..(at + 1) * d]);
                        rest[..VIEW_DIR_FEATURE_DIM].copy_from_slice(
                            &d_hat[at * VIEW_DIR_FEATURE_DIM..(at + 1) * VIEW_DIR_FEATURE_DIM],
                        );
                        rest[VIEW_DIR_FEATURE_DIM] = o[at];
                        rest[VIEW_DIR_FEATURE_DIM + 1] = 0.0;
                        if view_statistics {
                            rest[TOKEN_EXTRA_DIM..].copy_from_slice(&c[at * 3..at * 3 + 3]);
                        }
                    }
                }
            });

        // The per-point part [M, d_point]: [h, psi (, mean p, var p, mean c, var c)].
        let mut point = zeroed(m * d_point);
        point
            .par_chunks_mut(ROWS_PER_TASK * d_point)
            .enumerate()
            .for_each(|(task, block)| {
                let mut omega = vec![0.0f32; n];
                for (r, row) in block.chunks_mut(d_point).enumerate() {
                    let i = task * ROWS_PER_TASK + r;
                    row[..d_h].copy_from_slice(&h[i * d_h..(i + 1) * d_h]);
                    row[d_h] = psi[i];
                    if !view_statistics {
                        continue;
                    }
                    // omega_n = (o_n + FLOOR) / sum_k (o_k + FLOOR)
                    let mut total = 0.0f32;
                    for (view, w) in omega.iter_mut().enumerate() {
                        *w = o[view * m + i] + STATISTICS_FLOOR;
                        total += *w;
                    }
                    for w in omega.iter_mut() {
                        *w /= total;
                    }
                    let stats = &mut row[d_h + 1..];
                    let (p_stats, c_stats) = stats.split_at_mut(2 * d);
                    weighted_mean_and_variance(p, d, m, i, &omega, p_stats);
                    weighted_mean_and_variance(c, 3, m, i, &omega, c_stats);
                }
            });

        let point = self
            .blend_point
            .forward("host F_B per-point layer", &point, m, None, None)?
            .output;
        let logits = self.blend_tokens.forward(
            "host F_B token layers",
            &tokens,
            t * m,
            Some(FirstLayerAddend {
                values: &point,
                period: m,
            }),
            None,
        )?;
        Ok(logits.output)
    }
}

/// d_hat of the NeRF token: a view looking exactly along the target ray.
const NERF_DIRECTION: [f32; VIEW_DIR_FEATURE_DIM] = [0.0, 0.0, 0.0, 1.0];

/// `out = [mean, var]` over the views of point `i`'s `k` values in `x` (`[N, M, k]`) under
/// the weights `omega` (`ibr::view_statistics`).
fn weighted_mean_and_variance(
    x: &[f32],
    k: usize,
    m: usize,
    i: usize,
    omega: &[f32],
    out: &mut [f32],
) {
    let (mean, var) = out.split_at_mut(k);
    mean.fill(0.0);
    var.fill(0.0);
    for (view, &w) in omega.iter().enumerate() {
        let xv = &x[(view * m + i) * k..(view * m + i + 1) * k];
        for (acc, v) in mean.iter_mut().zip(xv) {
            *acc += v * w;
        }
    }
    for (view, &w) in omega.iter().enumerate() {
        let xv = &x[(view * m + i) * k..(view * m + i + 1) * k];
        for ((acc, v), mu) in var.iter_mut().zip(xv).zip(mean.iter()) {
            *acc += (v - mu) * (v - mu) * w;
        }
    }
}
