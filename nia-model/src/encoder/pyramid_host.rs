//! The encoder pyramid's channel reduction on the host, straight into channels-last rows
//! (inference on the CPU backends), from the channels-last pyramid of the host trunk
//! ([`crate::encoder::host`]).
//!
//! [`FeaturePyramid::reduce`] is the reference: per level a matrix product `W_l^T f_l`, then a
//! bilinear upsampling written as two dense matrix products (`A_h f A_w^T`) so that it has a
//! backward on every backend. Those matrices hold two non-zeros per row, so at the paper's
//! sizes the upsampling multiplies ~15 GFLOP of zeros per reduction, and the result is then
//! copied channels-last for [`ViewRows`]. Here each level's product is one `gemm` call that
//! writes channels-last, and the upsampling reads the two taps per axis directly, summing the
//! four levels into the rows in one parallel pass: the same weights (the rule of
//! [`bilinear_matrix`]) and the same result to float rounding (tests below).

use burn::prelude::*;
use rayon::prelude::*;

use crate::encoder::bilinear::ViewRows;
use crate::encoder::{bilinear_matrix, check_reduction_weight, FeaturePyramid};
use crate::kernels::host_gemm::{product_into, Strided};
use crate::kernels::readback::host_values_of;
use crate::shape::ShapeError;

/// One output index's two source taps along an axis: `(i0, i1, lambda)`, value
/// `(1 - lambda) s[i0] + lambda s[i1]` (the non-zeros of a [`bilinear_matrix`] row).
fn taps(input: usize, output: usize) -> Vec<(usize, usize, f32)> {
    let m = bilinear_matrix(input, output);
    (0..output)
        .map(|i| {
            let row = &m[i * input..(i + 1) * input];
            let mut nz = row.iter().enumerate().filter(|(_, w)| **w != 0.0);
            match (nz.next(), nz.next()) {
                (Some((i0, &w0)), Some((i1, &w1))) => (i0, i1, w1 / (w0 + w1)),
                (Some((i0, _)), None) => (i0, i0, 0.0),
                // A row without weight cannot occur (the weights of a row sum to one).
                _ => (0, 0, 0.0),
            }
        })
        .collect()
}

/// Maps `[N, C, H, W]` held channels-last on the host: `data[((n H + y) W + x) C + c]`.
/// The fields are private: [`HostMaps::new`] checks that `data` holds exactly `N C H W`
/// values, which the `gemm` calls that read it rely on.
#[derive(Debug, Clone)]
pub struct HostMaps {
    data: Vec<f32>,
    /// `[N, C, H, W]`.
    dims: [usize; 4],
}

impl HostMaps {
    /// Maps of `dims` (`[N, C, H, W]`, none of them 0) from channels-last `data`; an error
    /// unless `data` holds exactly `N C H W` values.
    pub fn new(data: Vec<f32>, dims: [usize; 4]) -> Result<Self, ShapeError> {
        let expected = dims.iter().product::<usize>();
        if expected == 0 || data.len() != expected {
            return Err(ShapeError::value(
                "host maps",
                format!(
                    "{expected} values for maps {dims:?} (channels-last), got {}",
                    data.len()
                ),
            ));
        }
        Ok(HostMaps { data, dims })
    }

    /// The values, channels-last.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// `[N, C, H, W]`.
    pub fn dims(&self) -> [usize; 4] {
        self.dims
    }
}

/// The encoder's four feature maps on the host, channels-last (finest first, at H/2): what
/// [`crate::encoder::host::HostTrunk`] computes.
#[derive(Debug, Clone)]
pub struct HostPyramid {
    levels: [HostMaps; 4],
}

impl HostPyramid {
    /// The pyramid of four levels (finest first); an error unless every level holds the same
    /// number of maps N.
    pub fn new(levels: [HostMaps; 4]) -> Result<Self, ShapeError> {
        let n = levels[0].dims[0];
        if let Some((l, level)) = levels.iter().enumerate().find(|(_, f)| f.dims[0] != n) {
            return Err(ShapeError::value(
                "feature pyramid levels",
                format!("{n} maps on every level (level {l} has {})", level.dims[0]),
            ));
        }
        Ok(HostPyramid { levels })
    }

    /// The four levels, finest first.
    pub fn levels(&self) -> &[HostMaps; 4] {
        &self.levels
    }

    /// The tensor pyramid read back channels-last.
    pub fn from_tensors(pyramid: &FeaturePyramid) -> Result<Self, ShapeError> {
        let level = |f: &Tensor<4>| -> Result<HostMaps, ShapeError> {
            let dims = f.dims();
            let data = host_values_of("feature pyramid level", f.clone().permute([0, 2, 3, 1]))?;
            HostMaps::new(data, dims)
        };
        let [a, b, c, d] = &pyramid.levels;
        Self::new([level(a)?, level(b)?, level(c)?, level(d)?])
    }

    /// Channels of the concatenated map, `sum_l C_l`.
    pub fn channels(&self) -> usize {
        self.levels.iter().map(|f| f.dims[1]).sum()
    }
}

/// `W^T F` of `pyramid` as channels-last rows (`[N, d, H/2, W/2]` maps), computed on the host:
/// equal to `ViewRows::new(pyramid.reduce(weight))` of the tensor pyramid to float rounding,
/// with its host copy.
///
/// # Shapes
/// - `weight`: `[sum_l C_l, d]` (a `Linear`'s weight, input-major)
/// - output: rows of maps `[N, d, H/2, W/2]`
pub fn reduce_to_rows(pyramid: &HostPyramid, weight: Tensor<2>) -> Result<ViewRows, ShapeError> {
    let d = check_reduction_weight(&weight, pyramid.channels())?;
    let device = weight.device();
    let weight = host_values_of("pyramid reduction weight", weight)?;
    let [n, _, h2, w2] = pyramid.levels[0].dims;
    let mut out = vec![0.0f32; n * h2 * w2 * d];
    // The coarser levels' reductions with their taps, upsampled together below.
    let mut coarse = Vec::new();
    let mut offset = 0;
    for (l, level) in pyramid.levels.iter().enumerate() {
        // Every level holds N maps (`HostPyramid::new`) of exactly `c h w` values each
        // (`HostMaps::new`).
        let [_, c, h, w] = level.dims;
        let f = &level.data;
        let w_l = &weight[offset * d..(offset + c) * d];
        offset += c;
        let full = (h, w) == (h2, w2);
        // [N, h w, d]: per map, f ([h w, C], channels-last) times W_l; a
        // level at full size goes straight into the rows (accumulated after the first).
        let mut reduced = if full {
            std::mem::take(&mut out)
        } else {
            vec![0.0f32; n * h * w * d]
        };
        let read_dst = full && l > 0;
        for (map, dst) in f.chunks(c * h * w).zip(reduced.chunks_mut(h * w * d)) {
            // The extents the product reads and writes; a mismatch is a bug here, never a read
            // past a slice.
            assert!(
                map.len() == h * w * c && dst.len() == h * w * d && w_l.len() == c * d,
                "pyramid reduction: slices of {}, {} and {} values for [{h}x{w}, {c}] x [{c}, {d}]",
                map.len(),
                dst.len(),
                w_l.len()
            );
            // dst [h w, d] (+)= map [h w, c] x w_l [c, d].
            product_into(
                dst,
                [h * w, d, c],
                Strided::rows(map, c),
                Strided::rows(w_l, d),
                read_dst,
                gemm::Parallelism::Rayon(0),
            );
        }
        if full {
            out = reduced;
        } else {
            coarse.push((reduced, h, w, taps(h, h2), taps(w, w2)));
        }
    }
    // One pass over the rows: every coarser level's two taps per axis added per pixel.
    out.par_chunks_mut(w2 * d)
        .enumerate()
        .for_each(|(row, dst)| {
            let (m, y) = (row / h2, row % h2);
            for (reduced, h, w, ty, tx) in &coarse {
                let src = &reduced[m * h * w * d..(m + 1) * h * w * d];
                let (y0, y1, ly) = ty[y];
                for (x, px) in dst.chunks_mut(d).enumerate() {
                    let (x0, x1, lx) = tx[x];
                    let a = &src[(y0 * w + x0) * d..][..d];
                    let b = &src[(y0 * w + x1) * d..][..d];
                    let c = &src[(y1 * w + x0) * d..][..d];
                    let e = &src[(y1 * w + x1) * d..][..d];
                    for k in 0..d {
                        let top = (1.0 - lx) * a[k] + lx * b[k];
                        let bottom = (1.0 - lx) * c[k] + lx * e[k];
                        px[k] += (1.0 - ly) * top + ly * bottom;
                    }
                }
            }
        });
    ViewRows::from_channels_last(out, [n, d, h2, w2], &device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoder::ImageEncoderConfig;
    use crate::kernels::readback::host_values;
    use burn::tensor::Distribution;

    fn close(a: &[f32], b: &[f32], tol: f32) {
        assert_eq!(a.len(), b.len());
        let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1.0);
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!(x.is_finite(), "value {i} not finite: {x}");
            assert!(
                (x - y).abs() <= tol * scale,
                "value {i}: host {x} vs tensor {y}"
            );
        }
    }

    #[test]
    fn taps_are_the_bilinear_matrix_rows() {
        for (input, output) in [(4, 8), (3, 8), (5, 9), (7, 7), (1, 4), (16, 64)] {
            let m = bilinear_matrix(input, output);
            for (i, (i0, i1, l)) in taps(input, output).into_iter().enumerate() {
                let mut row = vec![0.0f32; input];
                row[i0] += 1.0 - l;
                row[i1] += l;
                close(&row, &m[i * input..(i + 1) * input], 1e-6);
            }
        }
    }

    /// The host rows equal the tensor reduction laid out as rows, for even and odd image
    /// sizes (odd sizes give levels whose upsampling is not an exact factor of two).
    #[test]
    #[allow(deprecated)] // burn-ndarray: the tests' reference backend
    fn host_rows_match_the_tensor_reduction() {
        let device = Device::ndarray();
        for [h, w] in [[32, 48], [40, 24], [36, 52]] {
            let encoder = ImageEncoderConfig::new().with_base_width(8).init(&device);
            let images =
                Tensor::<4>::random([2, 3, h, w], Distribution::Uniform(0.0, 1.0), &device);
            let pyramid = encoder.forward_pyramid(images);
            let weight = Tensor::<2>::random([64, 12], Distribution::Normal(0.0, 0.3), &device);
            let reference = ViewRows::new(pyramid.reduce(weight.clone()).unwrap()).unwrap();
            let host =
                reduce_to_rows(&HostPyramid::from_tensors(&pyramid).unwrap(), weight).unwrap();
            assert_eq!(host.dims(), reference.dims());
            assert!(host.has_host_copy());
            let want = host_values(reference.rows()).unwrap();
            let got = host_values(host.rows()).unwrap();
            close(&got, &want, 1e-5);
        }
    }

    #[test]
    #[allow(deprecated)] // burn-ndarray: the tests' reference backend
    fn a_weight_of_the_wrong_width_is_an_error() {
        let device = Device::ndarray();
        let encoder = ImageEncoderConfig::new().with_base_width(8).init(&device);
        let pyramid = encoder.forward_pyramid(Tensor::zeros([1, 3, 32, 32], &device));
        let pyramid = HostPyramid::from_tensors(&pyramid).unwrap();
        let err = reduce_to_rows(&pyramid, Tensor::zeros([63, 4], &device)).unwrap_err();
        assert!(err.to_string().contains("[C_img, d]"), "{err}");
    }

    /// Maps whose data does not hold `N C H W` values (short, long, or of an empty shape) are
    /// an error naming the shape, so the reduction's `gemm` can never read past them; and so is
    /// a pyramid whose levels disagree on N.
    #[test]
    fn host_maps_of_the_wrong_size_are_an_error_not_a_read() {
        let short = HostMaps::new(vec![0.0; 23], [1, 2, 3, 4]).unwrap_err();
        assert!(short.to_string().contains("24 values") && short.to_string().contains("got 23"));
        assert!(HostMaps::new(vec![0.0; 25], [1, 2, 3, 4]).is_err());
        assert!(HostMaps::new(Vec::new(), [1, 0, 3, 4]).is_err());
        let maps = HostMaps::new(vec![1.0; 24], [1, 2, 3, 4]).unwrap();
        assert_eq!((maps.dims(), maps.data().len()), ([1, 2, 3, 4], 24));
        let two = HostMaps::new(vec![1.0; 48], [2, 2, 3, 4]).unwrap();
        let mixed = [maps.clone(), two, maps.clone(), maps];
        let err = HostPyramid::new(mixed).unwrap_err();
        assert!(err.to_string().contains("level 1 has 2"), "{err}");
    }
}
