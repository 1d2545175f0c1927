//! NeRF positional encoding gamma (Mildenhall et al. 2020, eq. 4), used on the view direction d.
//!
//! `gamma(p) = (p, sin(2^0 pi p), cos(2^0 pi p), ..., sin(2^(L-1) pi p), cos(2^(L-1) pi p))`
//!
//! Layout of the output (the nerf-pytorch ordering): the input itself (3 channels, when
//! `include_input`), then for each frequency k = 0..L a block of 3 sines followed by a block of
//! 3 cosines. For L = 4 (the paper's value for directions) the width is 3 + 2 * 3 * 4 = 27.
//! The frequencies carry the factor pi, as in the paper's formula (the nerf-pytorch code omits
//! it; with unit directions either choice is fine, the network learns the rest).
//!
//! The same encoding exists in plain Rust ([`PositionalEncoding::encode_into`], for the CPU
//! precompute of `PointInputs::dir_encoding`) and as a tensor op ([`PositionalEncoding::forward`]);
//! the tests check they agree.

use burn::prelude::*;

use crate::shape::ShapeError;

/// Configuration of [`PositionalEncoding`].
#[derive(Config, Debug)]
pub struct PositionalEncodingConfig {
    /// Number of frequencies L (the paper uses 4 for view directions).
    #[config(default = 4)]
    pub num_frequencies: usize,
    /// Whether p itself is the first block of the encoding.
    #[config(default = true)]
    pub include_input: bool,
}

/// The NeRF positional encoding gamma of 3-vectors. No parameters.
#[derive(Module, Debug)]
pub struct PositionalEncoding {
    /// Number of frequencies L.
    pub num_frequencies: usize,
    /// Whether p itself is the first block of the encoding.
    pub include_input: bool,
}

impl PositionalEncodingConfig {
    /// The encoding (no parameters, so the device is unused; kept for the usual `init` shape).
    pub fn init(&self, _device: &Device) -> PositionalEncoding {
        PositionalEncoding {
            num_frequencies: self.num_frequencies,
            include_input: self.include_input,
        }
    }
}

impl PositionalEncoding {
    /// Width of gamma(p) for a 3-vector: `3 * include_input + 2 * 3 * L`.
    pub fn output_dim(&self) -> usize {
        3 * usize::from(self.include_input) + 6 * self.num_frequencies
    }

    /// Angular frequency of band k: `2^k * pi` (radians per unit of p).
    pub fn frequency(k: usize) -> f32 {
        // 2^k exactly in f32 for every k < 128.
        (k as f32).exp2() * std::f32::consts::PI
    }

    /// Appends gamma(p) (`output_dim()` values) to `out`, in plain Rust.
    pub fn encode_into(&self, p: [f32; 3], out: &mut Vec<f32>) {
        let start = out.len();
        out.resize(start + self.output_dim(), 0.0);
        self.encode_to(p, &mut out[start..]);
    }

    /// Writes gamma(p) into `out`, whose length must be `output_dim()`, in plain Rust.
    pub fn encode_to(&self, p: [f32; 3], out: &mut [f32]) {
        debug_assert_eq!(out.len(), self.output_dim(), "gamma's output width");
        let (input, bands) = out.split_at_mut(3 * usize::from(self.include_input));
        input.copy_from_slice(&p[..input.len()]);
        for (k, band) in bands
            .chunks_exact_mut(6)
            .take(self.num_frequencies)
            .enumerate()
        {
            let w = Self::frequency(k);
            for (c, &x) in p.iter().enumerate() {
                band[c] = (w * x).sin();
                band[3 + c] = (w * x).cos();
            }
        }
    }

    /// gamma of every row of `points`.
    ///
    /// # Shapes
    /// - `points`: `[M, 3]`
    /// - output: `[M, output_dim()]` (27 for L = 4 with the input included)
    pub fn forward(&self, points: Tensor<2>) -> Result<Tensor<2>, ShapeError> {
        let [m, c] = points.dims();
        ShapeError::check("gamma input `points`", &[m, c], &[None, Some(3)])?;
        let device = points.device();
        let l = self.num_frequencies;
        let mut blocks = Vec::with_capacity(2);
        if self.include_input {
            blocks.push(points.clone());
        }
        if l > 0 {
            let freqs: Vec<f32> = (0..l).map(Self::frequency).collect();
            let freqs =
                Tensor::<1>::from_data(TensorData::new(freqs, [l]), &device).reshape([1, l, 1]);
            // [M, L, 3] angles, then [M, L, 2, 3] = (sin block, cos block) per band.
            let angles = points.reshape([m, 1, 3]) * freqs;
            let bands = Tensor::stack::<4>(vec![angles.clone().sin(), angles.cos()], 2);
            blocks.push(bands.reshape([m, 6 * l]));
        }
        if blocks.is_empty() {
            return Ok(Tensor::zeros([m, 0], &device));
        }
        Ok(Tensor::cat(blocks, 1))
    }
}
