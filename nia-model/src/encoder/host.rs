//! The image encoder's trunk on the host (inference on the CPU backends): channels-last
//! activations, every batch norm folded into its convolution, bias, residual and ReLU applied
//! to each output tile while it is in cache.
//!
//! [`ImageEncoder::forward_pyramid`] is the reference (and the path with gradients, and the
//! GPU's). On burn-flex each of its convolutions converts its input to channels-last on one
//! thread, builds im2col tiles, runs `gemm`, scatters the result back to channels-first, and
//! every batch norm, ReLU and residual sum is another pass over the activation. Here the
//! activations stay channels-last from the stem to the pyramid: a convolution is, per tile of
//! output pixels, an im2col copy of contiguous channel runs and one `gemm` whose rows are the
//! output pixels' channels, so the result lands in place. Same arithmetic up to float rounding
//! (batch norm folded: `w' = w gamma / sqrt(var + eps)`, `b' = beta - mean gamma /
//! sqrt(var + eps)`); tests compare every level against the tensor trunk.

use burn::nn::conv::Conv2d;
use burn::nn::pool::MaxPool2d;
use burn::nn::{BatchNorm, PaddingConfig2d};
use burn::prelude::*;
use rayon::prelude::*;

use crate::encoder::pyramid_host::{HostMaps, HostPyramid};
use crate::encoder::{BasicBlock, ImageEncoder, IMAGENET_MEAN, IMAGENET_STD};
use crate::kernels::host_gemm::{product_into, Strided};
use crate::kernels::readback::host_values_of;
use crate::shape::ShapeError;

/// Output pixels per tile: one im2col buffer and one `gemm` of `TILE x K x C_out` each.
const TILE: usize = 128;

/// `(top, left, bottom, right)` of a padding the host trunk supports.
fn explicit_padding(what: &str, padding: &PaddingConfig2d) -> Result<[usize; 4], ShapeError> {
    match padding {
        PaddingConfig2d::Explicit(t, l, b, r) => Ok([*t, *l, *b, *r]),
        PaddingConfig2d::Valid => Ok([0; 4]),
        other => Err(ShapeError::value(
            what,
            format!("explicit or no padding for the host trunk, got {other:?}"),
        )),
    }
}

/// A convolution with its batch norm folded in, for channels-last inputs.
#[derive(Debug, Clone)]
pub struct FoldedConv {
    kernel: [usize; 2],
    stride: [usize; 2],
    /// `(top, left, bottom, right)`.
    padding: [usize; 4],
    c_in: usize,
    c_out: usize,
    /// `[kh kw C_in, C_out]`: row `(i kw + j) C_in + c` holds tap (i, j) of input channel c.
    weight: Vec<f32>,
    /// `[C_out]`.
    bias: Vec<f32>,
}

impl FoldedConv {
    /// `bn(conv(x))` as one convolution (running statistics: inference).
    pub fn new(conv: &Conv2d, bn: &BatchNorm) -> Result<Self, ShapeError> {
        if conv.groups != 1 || conv.dilation != [1, 1] {
            return Err(ShapeError::value(
                "host encoder convolution",
                format!(
                    "groups 1 and dilation [1, 1], got {} and {:?}",
                    conv.groups, conv.dilation
                ),
            ));
        }
        let [c_out, c_in, kh, kw] = conv.weight.dims();
        let w = host_values_of("host encoder conv weight", conv.weight.val())?;
        let gamma = host_values_of("batch norm gamma", bn.gamma.val())?;
        let beta = host_values_of("batch norm beta", bn.beta.val())?;
        let mean = host_values_of("batch norm running mean", bn.running_mean.value())?;
        let var = host_values_of("batch norm running var", bn.running_var.value())?;
        let conv_bias = match &conv.bias {
            Some(b) => host_values_of("host encoder conv bias", b.val())?,
            None => vec![0.0; c_out],
        };
        for (name, v) in [
            ("gamma", &gamma),
            ("beta", &beta),
            ("running mean", &mean),
            ("running var", &var),
        ] {
            if v.len() != c_out {
                return Err(ShapeError::value(
                    "host encoder batch norm",
                    format!("{c_out} values of {name}, got {}", v.len()),
                ));
            }
        }
        let eps = bn.epsilon as f32;
        let scale: Vec<f32> = (0..c_out)
            .map(|o| gamma[o] / (var[o] + eps).sqrt())
            .collect();
        let mut weight = vec![0.0f32; kh * kw * c_in * c_out];
        for o in 0..c_out {
            for c in 0..c_in {
                for i in 0..kh {
                    for j in 0..kw {
                        weight[((i * kw + j) * c_in + c) * c_out + o] =
                            w[((o * c_in + c) * kh + i) * kw + j] * scale[o];
                    }
                }
            }
        }
        let bias = (0..c_out)
            .map(|o| beta[o] + (conv_bias[o] - mean[o]) * scale[o])
            .collect();
        Ok(Self {
            kernel: [kh, kw],
            stride: conv.stride,
            padding: explicit_padding("host encoder convolution", &conv.padding)?,
            c_in,
            c_out,
            weight,
            bias,
        })
    }

    fn out_size(&self, h: usize, w: usize) -> Result<[usize; 2], ShapeError> {
        let [pt, pl, pb, pr] = self.padding;
        let [kh, kw] = self.kernel;
        let (hp, wp) = (h + pt + pb, w + pl + pr);
        if hp < kh || wp < kw {
            return Err(ShapeError::value(
                "host encoder input",
                format!("at least {kh} x {kw} pixels after padding, got {hp} x {wp}"),
            ));
        }
        Ok([
            (hp - kh) / self.stride[0] + 1,
            (wp - kw) / self.stride[1] + 1,
        ])
    }

    /// `relu?(conv(x) + bias + residual?)`, channels-last.
    ///
    /// # Shapes
    /// - `x`: `[N, C_in, H, W]` maps (channels-last data)
    /// - `residual`: the output's shape
    /// - output: `[N, C_out, H', W']`
    pub fn forward(
        &self,
        x: &HostMaps,
        residual: Option<&HostMaps>,
        relu: bool,
    ) -> Result<HostMaps, ShapeError> {
        let [n, c, h, w] = x.dims();
        if c != self.c_in {
            return Err(ShapeError::value(
                "host encoder convolution input",
                format!("{} channels, got {c}", self.c_in),
            ));
        }
        let [ho, wo] = self.out_size(h, w)?;
        let dims = [n, self.c_out, ho, wo];
        if let Some(r) = residual.filter(|r| r.dims() != dims) {
            return Err(ShapeError::value(
                "host encoder residual",
                format!("maps {dims:?}, got {:?}", r.dims()),
            ));
        }
        let [kh, kw] = self.kernel;
        let [sh, sw] = self.stride;
        let [pt, pl, _, _] = self.padding;
        let k = kh * kw * c;
        let co = self.c_out;
        let pointwise = kh == 1 && kw == 1 && self.stride == [1, 1] && pt == 0 && pl == 0;
        let mut out = vec![0.0f32; n * ho * wo * co];
        // A few jobs per thread, each with one im2col buffer for all its tiles.
        let tiles = (n * ho * wo).div_ceil(TILE);
        let tiles_per_job = tiles.div_ceil(4 * rayon::current_num_threads()).max(1);
        out.par_chunks_mut(TILE * co * tiles_per_job)
            .enumerate()
            .for_each(|(job, job_dst)| {
                let mut col = Vec::new();
                for (t, dst) in job_dst.chunks_mut(TILE * co).enumerate() {
                    let chunk = job * tiles_per_job + t;
                    // A tile's pixels are taken in runs within one map each.
                    let first = chunk * TILE;
                    let pixels = dst.len() / co;
                    let mut done = 0;
                    while done < pixels {
                        let p = first + done;
                        let (b, q) = (p / (ho * wo), p % (ho * wo));
                        let run = (ho * wo - q).min(pixels - done);
                        let image = &x.data()[b * h * w * c..(b + 1) * h * w * c];
                        let dst_run = &mut dst[done * co..(done + run) * co];
                        let (lhs, lhs_rs): (&[f32], usize) = if pointwise {
                            (&image[q * c..(q + run) * c], c)
                        } else {
                            // Every element of the rows is written (padding as zeros), so the
                            // buffer is only grown, never cleared.
                            if col.len() < run * k {
                                col.resize(run * k, 0.0);
                            }
                            for (r, row) in col[..run * k].chunks_mut(k).enumerate() {
                                let (oy, ox) = ((q + r) / wo, (q + r) % wo);
                                for (i, seg) in row.chunks_mut(kw * c).enumerate() {
                                    let y = (oy * sh + i) as isize - pt as isize;
                                    if y < 0 || y >= h as isize {
                                        seg.fill(0.0);
                                        continue;
                                    }
                                    // A kernel row inside the image is one contiguous run.
                                    let x0 = (ox * sw) as isize - pl as isize;
                                    if x0 >= 0 && x0 as usize + kw <= w {
                                        let src = (y as usize * w + x0 as usize) * c;
                                        seg.copy_from_slice(&image[src..src + kw * c]);
                                        continue;
                                    }
                                    for (j, tap) in seg.chunks_mut(c).enumerate() {
                                        let xx = x0 + j as isize;
                                        if xx < 0 || xx >= w as isize {
                                            tap.fill(0.0);
                                        } else {
                                            let src = (y as usize * w + xx as usize) * c;
                                            tap.copy_from_slice(&image[src..src + c]);
                                        }
                                    }
                                }
                            }
                            (&col[..run * k], k)
                        };
                        // The extents the product reads and writes; a mismatch is a bug here,
                        // never a read past a slice.
                        assert!(
                            dst_run.len() == run * co
                                && lhs.len() >= (run - 1) * lhs_rs + k
                                && self.weight.len() == k * co,
                            "host convolution: slices of {}, {} and {} values for \
                             [{run}, {k}] x [{k}, {co}]",
                            dst_run.len(),
                            lhs.len(),
                            self.weight.len()
                        );
                        // dst_run [run, C_out] = lhs [run, K] (rows lhs_rs apart) x weight
                        // [K, C_out].
                        product_into(
                            dst_run,
                            [run, co, k],
                            Strided::rows_every(lhs, lhs_rs),
                            Strided::rows(&self.weight, co),
                            false,
                            gemm::Parallelism::None,
                        );
                        let res = residual.map(|r| &r.data()[p * co..(p + run) * co]);
                        for (i, px) in dst_run.chunks_mut(co).enumerate() {
                            for (o, v) in px.iter_mut().enumerate() {
                                let mut s = *v + self.bias[o];
                                if let Some(res) = res {
                                    s += res[i * co + o];
                                }
                                *v = if relu { s.max(0.0) } else { s };
                            }
                        }
                        done += run;
                    }
                }
            });
        HostMaps::new(out, dims)
    }
}

/// Max pooling of channels-last maps (padding never wins: it counts as -inf).
fn max_pool(pool: &MaxPool2d, x: &HostMaps) -> Result<HostMaps, ShapeError> {
    if pool.dilation != [1, 1] || pool.ceil_mode {
        return Err(ShapeError::value(
            "host encoder max pool",
            format!(
                "dilation [1, 1] without ceil mode, got {:?} / {}",
                pool.dilation, pool.ceil_mode
            ),
        ));
    }
    let [pt, pl, pb, pr] = explicit_padding("host encoder max pool", &pool.padding)?;
    let [kh, kw] = pool.kernel_size;
    let [sh, sw] = pool.stride;
    let [n, c, h, w] = x.dims();
    if h + pt + pb < kh || w + pl + pr < kw {
        return Err(ShapeError::value(
            "host encoder max pool input",
            format!("at least {kh} x {kw} pixels after padding, got {h} x {w}"),
        ));
    }
    let ho = (h + pt + pb - kh) / sh + 1;
    let wo = (w + pl + pr - kw) / sw + 1;
    let mut out = vec![f32::NEG_INFINITY; n * ho * wo * c];
    out.par_chunks_mut(wo * c)
        .enumerate()
        .for_each(|(row, dst)| {
            let (b, oy) = (row / ho, row % ho);
            let image = &x.data()[b * h * w * c..(b + 1) * h * w * c];
            for (ox, px) in dst.chunks_mut(c).enumerate() {
                for i in 0..kh {
                    let y = (oy * sh + i) as isize - pt as isize;
                    if y < 0 || y >= h as isize {
                        continue;
                    }
                    for j in 0..kw {
                        let xx = (ox * sw + j) as isize - pl as isize;
                        if xx < 0 || xx >= w as isize {
                            continue;
                        }
                        let src = &image[(y as usize * w + xx as usize) * c..][..c];
                        for (m, s) in px.iter_mut().zip(src) {
                            *m = m.max(*s);
                        }
                    }
                }
            }
        });
    HostMaps::new(out, [n, c, ho, wo])
}

/// A BasicBlock with its three batch norms folded.
#[derive(Debug, Clone)]
struct FoldedBlock {
    conv1: FoldedConv,
    conv2: FoldedConv,
    downsample: Option<FoldedConv>,
}

impl FoldedBlock {
    fn new(block: &BasicBlock) -> Result<Self, ShapeError> {
        Ok(Self {
            conv1: FoldedConv::new(&block.conv1, &block.bn1)?,
            conv2: FoldedConv::new(&block.conv2, &block.bn2)?,
            downsample: block
                .downsample
                .as_ref()
                .map(|d| FoldedConv::new(&d.conv, &d.bn))
                .transpose()?,
        })
    }

    /// `relu(bn2(conv2(relu(bn1(conv1(x))))) + identity)`.
    fn forward(&self, x: HostMaps) -> Result<HostMaps, ShapeError> {
        let identity = match &self.downsample {
            Some(d) => d.forward(&x, None, false)?,
            None => x.clone(),
        };
        let y = self.conv1.forward(&x, None, true)?;
        drop(x);
        self.conv2.forward(&y, Some(&identity), true)
    }
}

/// The trunk of an [`ImageEncoder`] with its batch norms folded, for the host.
#[derive(Debug, Clone)]
pub struct HostTrunk {
    stem: FoldedConv,
    maxpool: MaxPool2d,
    layers: [Vec<FoldedBlock>; 3],
}

impl HostTrunk {
    /// The folded trunk of `encoder` (its running statistics: inference).
    pub fn new(encoder: &ImageEncoder) -> Result<Self, ShapeError> {
        let layer = |blocks: &[BasicBlock]| -> Result<Vec<FoldedBlock>, ShapeError> {
            blocks.iter().map(FoldedBlock::new).collect()
        };
        Ok(Self {
            stem: FoldedConv::new(&encoder.conv1, &encoder.bn1)?,
            maxpool: encoder.maxpool.clone(),
            layers: [
                layer(&encoder.layer1)?,
                layer(&encoder.layer2)?,
                layer(&encoder.layer3)?,
            ],
        })
    }

    /// The four feature maps, channels-last: [`ImageEncoder::forward_pyramid`] on the host.
    ///
    /// # Shapes
    /// - `images`: `[N, 3, H, W]`, RGB in [0, 1]
    /// - levels: `[N, w, H/2, W/2]`, `[N, w, H/4, W/4]`, `[N, 2w, H/8, W/8]`, `[N, 4w, H/16, W/16]`
    pub fn forward(&self, images: Tensor<4>) -> Result<HostPyramid, ShapeError> {
        let [n, c, h, w] = images.dims();
        if c != 3 {
            return Err(ShapeError::value(
                "host encoder images",
                format!("3 channels (RGB), got {c}"),
            ));
        }
        let rgb = host_values_of("host encoder images", images)?;
        // Channels-last and ImageNet-normalised in one pass.
        let mut data = vec![0.0f32; n * h * w * 3];
        for b in 0..n {
            for ch in 0..3 {
                let src = &rgb[(b * 3 + ch) * h * w..][..h * w];
                for (p, v) in src.iter().enumerate() {
                    data[(b * h * w + p) * 3 + ch] = (v - IMAGENET_MEAN[ch]) / IMAGENET_STD[ch];
                }
            }
        }
        let x = HostMaps::new(data, [n, 3, h, w])?;
        let f1 = self.stem.forward(&x, None, true)?;
        let mut x = max_pool(&self.maxpool, &f1)?;
        let mut levels = vec![f1];
        for layer in &self.layers {
            for block in layer {
                x = block.forward(x)?;
            }
            levels.push(x.clone());
        }
        let levels: [HostMaps; 4] = levels
            .try_into()
            .map_err(|_| ShapeError::empty("host encoder levels"))?;
        HostPyramid::new(levels)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoder::pyramid_host::HostPyramid;
    use crate::encoder::ImageEncoderConfig;
    use burn::module::{Param, RunningState};
    use burn::tensor::Distribution;

    /// Batch norms with non-trivial statistics (a fresh one is the identity up to eps).
    fn randomise(bn: &mut BatchNorm, device: &Device) {
        let [c] = bn.gamma.dims();
        bn.gamma = Param::from_tensor(Tensor::random([c], Distribution::Uniform(0.5, 1.5), device));
        bn.beta = Param::from_tensor(Tensor::random([c], Distribution::Normal(0.0, 0.2), device));
        bn.running_mean =
            RunningState::new(Tensor::random([c], Distribution::Normal(0.0, 0.3), device));
        bn.running_var =
            RunningState::new(Tensor::random([c], Distribution::Uniform(0.2, 2.0), device));
    }

    fn encoder(device: &Device) -> ImageEncoder {
        let mut e = ImageEncoderConfig::new().with_base_width(8).init(device);
        randomise(&mut e.bn1, device);
        for block in e
            .layer1
            .iter_mut()
            .chain(&mut e.layer2)
            .chain(&mut e.layer3)
        {
            randomise(&mut block.bn1, device);
            randomise(&mut block.bn2, device);
            if let Some(d) = &mut block.downsample {
                randomise(&mut d.bn, device);
            }
        }
        e
    }

    /// Every level of the host trunk equals the tensor trunk's (batch norm at inference), for
    /// image sizes that are and are not multiples of 16.
    #[test]
    #[allow(deprecated)] // burn-ndarray: the tests' reference backend
    fn host_trunk_matches_the_tensor_trunk() {
        let device = Device::ndarray();
        let e = encoder(&device);
        let trunk = HostTrunk::new(&e).unwrap();
        for [h, w] in [[32, 48], [37, 29]] {
            let images =
                Tensor::<4>::random([2, 3, h, w], Distribution::Uniform(0.0, 1.0), &device);
            let want = HostPyramid::from_tensors(&e.forward_pyramid(images.clone())).unwrap();
            let got = trunk.forward(images).unwrap();
            for (l, (g, r)) in got.levels().iter().zip(want.levels()).enumerate() {
                assert_eq!(g.dims(), r.dims(), "level {l}");
                let scale = r.data().iter().fold(1.0f32, |m, v| m.max(v.abs()));
                for (i, (a, b)) in g.data().iter().zip(r.data()).enumerate() {
                    assert!(a.is_finite(), "level {l} value {i}: {a}");
                    assert!(
                        (a - b).abs() <= 1e-4 * scale,
                        "level {l} value {i}: host {a} vs tensor {b}"
                    );
                }
            }
        }
    }

    #[test]
    #[allow(deprecated)] // burn-ndarray: the tests' reference backend
    fn images_that_are_not_rgb_are_an_error() {
        let device = Device::ndarray();
        let trunk = HostTrunk::new(&encoder(&device)).unwrap();
        let err = trunk
            .forward(Tensor::zeros([1, 4, 32, 32], &device))
            .unwrap_err();
        assert!(err.to_string().contains("3 channels"), "{err}");
    }
}
