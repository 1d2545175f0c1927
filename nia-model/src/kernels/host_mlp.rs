//! Stacks of linear layers evaluated on the host, fused and in parallel (inference on the CPU
//! backends).
//!
//! On flex, every `Linear::forward` allocates its `[rows, d_out]` output (zeroed, then copied
//! once more to align it), adds the bias in a second pass and takes the ReLU in a third, each
//! on the calling thread, while only the matrix product itself runs in rayon's pool. For
//! F_sigma, F_c0 and F_B (narrow layers over thousands of rows) those passes cost about as
//! much as the products (docs/speed.md, "The MLPs on the host"). Here a stack runs in tasks of
//! [`ROWS_PER_TASK`] rows: each task carries its rows through every layer in two scratch
//! buffers that stay in cache, starting each layer's output from its bias and letting the
//! product accumulate into it, with the ReLU in the same task. The result is the same formula
//! to rounding (`nia-model/tests/host_network.rs` checks it against the tensor path, which
//! stays the reference, the path with gradients and the one on the GPU).

use burn::nn::Linear;
use rayon::prelude::*;

use crate::kernels::host_buffer::zeroed;
use crate::kernels::host_gemm::{self, Strided};
use crate::kernels::readback::host_values_of;
use crate::shape::ShapeError;

/// Rows per parallel task: a task's two scratch buffers of 256 rows x 256 channels are 512 KiB,
/// inside a core's L2.
pub const ROWS_PER_TASK: usize = 256;

/// One linear layer `y = x W + b` with its parameters on the host.
#[derive(Debug, Clone)]
pub struct HostLinear {
    /// W, `[d_in, d_out]` row-major (burn's layout).
    weight: Vec<f32>,
    /// b, `[d_out]` (zeros for a layer without bias).
    bias: Vec<f32>,
    d_in: usize,
    d_out: usize,
}

impl HostLinear {
    /// The parameters of `linear`, read back; `what` names the layer in errors.
    pub fn read(what: &str, linear: &Linear) -> Result<Self, ShapeError> {
        let [d_in, d_out] = linear.weight.dims();
        let weight = host_values_of(what, linear.weight.val())?;
        let bias = match &linear.bias {
            Some(b) => host_values_of(what, b.val())?,
            None => vec![0.0; d_out],
        };
        Self::new(what, weight, bias, d_in, d_out)
    }

    /// A layer from its parameters: `weight` `[d_in, d_out]` row-major, `bias` `[d_out]`.
    pub fn new(
        what: &str,
        weight: Vec<f32>,
        bias: Vec<f32>,
        d_in: usize,
        d_out: usize,
    ) -> Result<Self, ShapeError> {
        if weight.len() != d_in * d_out || bias.len() != d_out {
            return Err(ShapeError::value(
                what,
                format!(
                    "a [{d_in}, {d_out}] weight and a bias of {d_out}, got {} and {} values",
                    weight.len(),
                    bias.len()
                ),
            ));
        }
        Ok(HostLinear {
            weight,
            bias,
            d_in,
            d_out,
        })
    }

    /// The bias b, `[d_out]`.
    pub fn bias(&self) -> &[f32] {
        &self.bias
    }

    /// `dst = src W + b` on `rows` rows, on the calling thread (for callers that run their
    /// own tasks).
    ///
    /// # Shapes
    /// - `src`: `[rows, d_in]`; `dst`: `[rows, d_out]`, both row-major
    pub fn apply(&self, src: &[f32], rows: usize, dst: &mut [f32]) {
        for row in dst.chunks_mut(self.d_out) {
            row.copy_from_slice(&self.bias);
        }
        product_into(dst, src, self.d_in, self, rows);
    }

    /// `dst += src[.., ..d_in] W` on `rows` rows whose inputs start every `src_stride` values
    /// (the first `d_in` channels of wider rows), on the calling thread; no bias.
    ///
    /// # Shapes
    /// - `src`: `[rows, src_stride]` (`src_stride >= d_in`); `dst`: `[rows, d_out]`
    pub fn accumulate(&self, src: &[f32], src_stride: usize, rows: usize, dst: &mut [f32]) {
        product_into(dst, src, src_stride, self, rows);
    }
}

/// A per-row addend of the first layer, repeating every `period` rows: row r gets
/// `values[r % period]` (F_B's per-point part `W_p [h, psi]`, shared by the point's N + 1
/// tokens, which are laid out token-major).
#[derive(Debug, Clone, Copy)]
pub struct FirstLayerAddend<'a> {
    /// `[period, d_out of the first layer]` row-major.
    pub values: &'a [f32],
    /// Rows after which the addend repeats.
    pub period: usize,
}

/// What [`HostMlp::forward`] returns for `rows` input rows.
#[derive(Debug, Clone)]
pub struct HostMlpOutput {
    /// The last layer's output (no ReLU), `[rows, d_out]` row-major.
    pub output: Vec<f32>,
    /// The ReLU activation after the layer asked for (`tap`), `[rows, width]` row-major.
    pub tapped: Option<Vec<f32>>,
}

/// Linear layers with a ReLU after every one but the last.
#[derive(Debug, Clone)]
pub struct HostMlp {
    layers: Vec<HostLinear>,
}

impl HostMlp {
    /// The layers, in order; each one's input width must be the previous one's output width.
    pub fn new(what: &str, layers: Vec<HostLinear>) -> Result<Self, ShapeError> {
        if layers.is_empty() {
            return Err(ShapeError::empty(what));
        }
        if let Some(l) = layers.iter().find(|l| l.d_in == 0 || l.d_out == 0) {
            return Err(ShapeError::value(
                what,
                format!("layers at least 1 wide, got [{}, {}]", l.d_in, l.d_out),
            ));
        }
        for pair in layers.windows(2) {
            if pair[0].d_out != pair[1].d_in {
                return Err(ShapeError::value(
                    what,
                    format!(
                        "each layer's input as wide as the previous output, got {} then {}",
                        pair[0].d_out, pair[1].d_in
                    ),
                ));
            }
        }
        Ok(HostMlp { layers })
    }

    /// Reads `layers` back from their module.
    pub fn read(what: &str, layers: &[Linear]) -> Result<Self, ShapeError> {
        let layers = layers
            .iter()
            .map(|l| HostLinear::read(what, l))
            .collect::<Result<Vec<_>, _>>()?;
        Self::new(what, layers)
    }

    /// The output width of layer `i` (0-based).
    pub fn width_after(&self, i: usize) -> Option<usize> {
        self.layers.get(i).map(|l| l.d_out)
    }

    /// The stack on `rows` rows of `x` (`[rows, d_in]` row-major), with `addend` added to the
    /// first layer's pre-activation and, with `tap = Some(i)`, the activation after layer i
    /// (0-based, before the last) returned as well.
    ///
    /// # Shapes
    /// - `x`: `[rows, d_in]`; `addend.values`: `[period, d_1]`
    /// - output `[rows, d_out]`, tapped `[rows, d_(i+1)]`
    pub fn forward(
        &self,
        what: &str,
        x: &[f32],
        rows: usize,
        addend: Option<FirstLayerAddend<'_>>,
        tap: Option<usize>,
    ) -> Result<HostMlpOutput, ShapeError> {
        let first = &self.layers[0];
        let last = self.layers.len() - 1;
        if x.len() != rows * first.d_in {
            return Err(ShapeError::value(
                what,
                format!("{rows} x {} input values, got {}", first.d_in, x.len()),
            ));
        }
        if let Some(a) = addend {
            if a.period == 0 || a.values.len() != a.period * first.d_out {
                return Err(ShapeError::value(
                    what,
                    format!(
                        "a first-layer addend of period x {} values (period > 0), got {} \
                         values for period {}",
                        first.d_out,
                        a.values.len(),
                        a.period
                    ),
                ));
            }
        }
        let tap_width = match tap {
            Some(i) if i < last => Some(self.layers[i].d_out),
            Some(i) => {
                return Err(ShapeError::value(
                    what,
                    format!("a tapped layer before the last ({last}), got {i}"),
                ))
            }
            None => None,
        };
        let d_out = self.layers[last].d_out;
        let widest = self.layers.iter().map(|l| l.d_out).max().unwrap_or(0);
        let mut output = zeroed(rows * d_out);
        let mut tapped = tap_width.map(|w| zeroed(rows * w));

        let task = |t: usize, out: &mut [f32], mut tap_out: Option<&mut [f32]>| {
            let row0 = t * ROWS_PER_TASK;
            let n = out.len() / d_out;
            let mut buffers = [vec![0.0f32; n * widest], vec![0.0f32; n * widest]];
            for (i, layer) in self.layers.iter().enumerate() {
                let [a, b] = &mut buffers;
                let (src, dst): (&[f32], &mut [f32]) = if i == 0 {
                    (&x[row0 * layer.d_in..(row0 + n) * layer.d_in], &mut a[..])
                } else if i % 2 == 1 {
                    (&a[..n * layer.d_in], &mut b[..])
                } else {
                    (&b[..n * layer.d_in], &mut a[..])
                };
                let dst = if i == last {
                    &mut *out
                } else {
                    &mut dst[..n * layer.d_out]
                };
                for (r, row) in dst.chunks_mut(layer.d_out).enumerate() {
                    row.copy_from_slice(&layer.bias);
                    if let (0, Some(add)) = (i, addend) {
                        let p = (row0 + r) % add.period;
                        for (v, a) in row.iter_mut().zip(&add.values[p * layer.d_out..]) {
                            *v += a;
                        }
                    }
                }
                product_into(dst, src, layer.d_in, layer, n);
                if i < last {
                    for v in dst.iter_mut() {
                        *v = v.max(0.0);
                    }
                    if tap == Some(i) {
                        if let Some(t) = tap_out.as_deref_mut() {
                            t.copy_from_slice(dst);
                        }
                    }
                }
            }
        };
        match (&mut tapped, tap_width) {
            (Some(tapped), Some(w)) => output
                .par_chunks_mut(ROWS_PER_TASK * d_out)
                .zip(tapped.par_chunks_mut(ROWS_PER_TASK * w))
                .enumerate()
                .for_each(|(t, (out, tap_out))| task(t, out, Some(tap_out))),
            _ => output
                .par_chunks_mut(ROWS_PER_TASK * d_out)
                .enumerate()
                .for_each(|(t, out)| task(t, out, None)),
        }
        Ok(HostMlpOutput { output, tapped })
    }
}

/// `dst += src W` for `n` rows: `dst` `[n, d_out]` row-major, `src` rows of `d_in` values
/// every `stride` values.
fn product_into(dst: &mut [f32], src: &[f32], stride: usize, layer: &HostLinear, n: usize) {
    let (k, co) = (layer.d_in, layer.d_out);
    // The extents the product reads and writes; a mismatch is a bug here, never a read past a
    // slice.
    assert!(
        dst.len() == n * co
            && stride >= k
            && (n == 0 || src.len() >= (n - 1) * stride + k)
            && layer.weight.len() == k * co,
        "host linear: slices of {}, {} (stride {stride}) and {} values for [{n}, {k}] x [{k}, {co}]",
        dst.len(),
        src.len(),
        layer.weight.len()
    );
    host_gemm::product_into(
        dst,
        [n, co, k],
        Strided::rows_every(src, stride),
        Strided::rows(&layer.weight, co),
        true,
        gemm::Parallelism::None,
    );
}
