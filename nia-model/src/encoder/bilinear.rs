//! Bilinear reads of per-view 2D maps at projected points, as four row gathers.
//!
//! The same read as `grid_sample_2d(bilinear, zeros padding, align_corners = false)`
//! ([`grid_sample_reference`], kept as the reference the tests compare against): for the
//! normalised coordinates (g_x, g_y) of view n the read sits at pixel
//! `x = (g_x + 1) W / 2 - 1/2`, `y = (g_y + 1) H / 2 - 1/2`, and takes the four corners
//! `(floor x + {0, 1}, floor y + {0, 1})` with the weights `(1 - f_x or f_x)(1 - f_y or f_y)`,
//! `f = x - floor x`; a corner outside the map reads zero (so does a non-finite coordinate).
//!
//! Why not `grid_sample_2d`: on the CPU backends it is a gather with a per-element index
//! computation forward and a scatter-add of the same kind backward (about a fifth of the tiny
//! network's training step). Here the maps are laid out channels-last once (`[N H W + 1, C]`,
//! the last row zero), every corner is one `select` of whole rows (a row copy forward, a row
//! scatter-add backward) and the weights multiply rows. [`ViewRows`] holds that layout, so a
//! scene's maps are laid out once and every ray chunk reads them as they are (laid out per
//! read, the copy of the paper-width maps took most of a 512x512 render). The corner indices
//! are computed on the device from the grid, so nothing is read back to the host, and the
//! weights stay differentiable in the grid (the surface read's gradient in the expected depth,
//! see `ibr::surface`). That tensor read runs on every backend and stays the reference; on flex
//! (training included) a read whose grid carries no gradient is instead one weighted gather
//! with its own backward ([`crate::kernels::weighted_rows`]), its taps computed on the host from the
//! grid with the same coordinates and weights. In training on a GPU backend the four corners'
//! gathers run as one operation with its own backward ([`crate::kernels::tap_gather`]).

use std::sync::Arc;

use burn::prelude::*;
use burn::tensor::ops::GridSampleOptions;
use rayon::prelude::*;

use super::channels_last::channels_last_rows;
use crate::device::computes_on_cpu;
use crate::kernels::blocked_rows::select_rows;
use crate::kernels::host_buffer::zeroed;
use crate::kernels::host_op::runs_on_host;
use crate::kernels::readback::host_values_of;
use crate::kernels::tap_gather::tap_gather;
use crate::kernels::weighted_rows::{weighted_rows, Taps};
use crate::shape::ShapeError;

/// Reads N maps at M points each: [`ViewRows::new`] then [`ViewRows::sample`]. A caller that
/// reads the same maps many times (every ray chunk of an image) keeps the [`ViewRows`].
///
/// # Shapes
/// - `maps`: `[N, C, H, W]`
/// - `proj_grid`: `[N, M, 2]`, (x, y) normalised to [-1, 1] over the map's extent
/// - output: `[N, M, C]`, zeros where every corner falls outside the map
pub fn sample(maps: Tensor<4>, proj_grid: Tensor<3>) -> Result<Tensor<3>, ShapeError> {
    ViewRows::new(maps)?.sample(proj_grid)
}

/// N maps laid out channels-last for [`ViewRows::sample`]: the layout change (a copy of the
/// whole maps) is made once, not per read.
///
/// With a host copy ([`ViewRows::with_host_copy`], inference on the CPU backends) a read whose
/// grid carries no gradient is one fused pass on the host: the four corners of every (view,
/// point) accumulated straight into the output, in parallel, instead of four row gathers,
/// four weightings and three sums that burn-flex runs one after the other (most of them on
/// one thread). Same arithmetic in the same order; the tensor read stays the reference.
#[derive(Debug, Clone)]
pub struct ViewRows {
    /// `[N H W + 1, C]`: channels-last rows of every view, then one zero row.
    rows: Tensor<2>,
    /// `[N, C, H, W]` of the maps.
    dims: [usize; 4],
    /// `rows` in host memory, row-major, for the fused read.
    host: Option<Arc<Vec<f32>>>,
}

impl ViewRows {
    /// The rows of `maps`.
    ///
    /// # Shapes
    /// - `maps`: `[N, C, H, W]`, N, H, W > 0
    pub fn new(maps: Tensor<4>) -> Result<Self, ShapeError> {
        let [n, c, h, w] = maps.dims();
        if n == 0 || h == 0 || w == 0 {
            return Err(ShapeError::empty("IBR `maps` [N, C, H, W]"));
        }
        let device = maps.device();
        let rows = if runs_on_host(&device) {
            // flex: one pass, and a backward that hands the maps their gradient in their own
            // layout (no transposed view for the pyramid's reshapes to copy).
            channels_last_rows(maps)
        } else {
            Tensor::cat(
                vec![
                    maps.permute([0, 2, 3, 1]).reshape([n * h * w, c]),
                    Tensor::zeros([1, c], &device),
                ],
                0,
            )
        };
        Ok(Self {
            rows,
            dims: [n, c, h, w],
            host: None,
        })
    }

    /// Rows computed on the host, channels-last (`values[((n H + y) W + x) C + c]` for
    /// maps `[N, C, H, W]` = `dims`), with that host copy: no layout change, no read-back.
    pub fn from_channels_last(
        mut values: Vec<f32>,
        dims: [usize; 4],
        device: &Device,
    ) -> Result<Self, ShapeError> {
        let [n, c, h, w] = dims;
        if n == 0 || h == 0 || w == 0 {
            return Err(ShapeError::empty("IBR `maps` [N, C, H, W]"));
        }
        if values.len() != n * h * w * c {
            return Err(ShapeError::value(
                "channels-last IBR rows",
                format!(
                    "{} values for maps {dims:?}, got {}",
                    n * h * w * c,
                    values.len()
                ),
            ));
        }
        values.extend(std::iter::repeat_n(0.0, c));
        let rows = Tensor::from_data(TensorData::new(values.clone(), [n * h * w + 1, c]), device);
        Ok(Self {
            rows,
            dims,
            host: Some(Arc::new(values)),
        })
    }

    /// `[N H W + 1, C]`: the channels-last rows of every view, then one zero row.
    pub fn rows(&self) -> Tensor<2> {
        self.rows.clone()
    }

    /// These rows as a leaf of the autodiff graph: the same values, detached from what
    /// computed them, gradients required; no host copy (a read with gradients takes the
    /// tensor path). The chunked backward's cut ([`crate::scene_encoding::cut`]).
    pub fn detached_leaf(&self) -> Self {
        Self {
            rows: self.rows.clone().detach().require_grad(),
            dims: self.dims,
            host: None,
        }
    }

    /// These rows with a host copy (read back once) for the fused read of grids without
    /// gradients; on a GPU backend the copy is a transfer, so the renderers ask for it on the
    /// CPU backends only.
    pub fn with_host_copy(mut self) -> Result<Self, ShapeError> {
        let values = host_values_of("IBR rows", self.rows.clone())?;
        self.host = Some(Arc::new(values));
        Ok(self)
    }

    /// These rows without a host copy (every read with tensor operations).
    pub fn without_host_copy(mut self) -> Self {
        self.host = None;
        self
    }

    /// Whether reads without gradients run on the host.
    pub fn has_host_copy(&self) -> bool {
        self.host.is_some()
    }

    /// `[N, C, H, W]` of the maps these rows hold.
    pub fn dims(&self) -> [usize; 4] {
        self.dims
    }

    /// The device the rows live on.
    pub fn device(&self) -> Device {
        self.rows.device()
    }

    /// Reads the N maps at M points each.
    ///
    /// # Shapes
    /// - `proj_grid`: `[N, M, 2]`, (x, y) normalised to [-1, 1] over the map's extent
    /// - output: `[N, M, C]`, zeros where every corner falls outside the map
    pub fn sample(&self, proj_grid: Tensor<3>) -> Result<Tensor<3>, ShapeError> {
        let [n, c, h, w] = self.dims;
        let m = check_grid(n, &proj_grid)?;
        let device = self.rows.device();
        if m == 0 {
            return Ok(Tensor::zeros([n, 0, c], &device));
        }
        if let (Some(host), false) = (&self.host, proj_grid.is_autodiff()) {
            let grid = host_values_of("IBR `proj_grid`", proj_grid)?;
            let out = host_read(host, self.dims, &grid, m);
            return Ok(Tensor::from_data(TensorData::new(out, [n, m, c]), &device));
        }
        if runs_on_host(&device) && !proj_grid.is_tracked() {
            // One weighted gather with its own backward (training on flex).
            let grid = host_values_of("IBR `proj_grid`", proj_grid)?;
            let taps = bilinear_taps(self.dims, &grid, m);
            return Ok(weighted_rows(self.rows.clone(), taps).reshape([n, m, c]));
        }
        let zero_row = (n * h * w) as f32;
        // Pixel coordinates [N, M] and the first row of each view, as floats: indices up to
        // N H W stay exact in f32 for every map this model reads (below 2^24 pixels in all).
        let x = (proj_grid.clone().narrow(2, 0, 1).reshape([n, m]) + 1.0) * (w as f32 / 2.0) - 0.5;
        let y = (proj_grid.narrow(2, 1, 1).reshape([n, m]) + 1.0) * (h as f32 / 2.0) - 0.5;
        let x0 = x.clone().detach().floor();
        let y0 = y.clone().detach().floor();
        let fx = x - x0.clone();
        let fy = y - y0.clone();
        let view_base = Tensor::<1, Int>::arange(0..n as i64, &device)
            .float()
            .mul_scalar((h * w) as f32)
            .reshape([n, 1]);
        // Whether a corner coordinate lies on the map, `0 <= v <= extent - 1`, as one
        // comparison, `|v - c| <= c` with c the middle: a boolean AND is a kernel launch of its
        // own on the GPU backends, where a comparison fuses with the arithmetic around it (one
        // AND per corner instead of three: 588 fewer launches in a three-image render,
        // docs/speed.md). Comparisons with NaN are false: a non-finite coordinate is outside.
        let within = |v: Tensor<2>, extent: usize| {
            let middle = (extent - 1) as f32 / 2.0;
            v.sub_scalar(middle).abs().lower_equal_elem(middle)
        };
        let (x1, y1) = (x0.clone() + 1.0, y0.clone() + 1.0);
        let x_inside = [within(x0.clone(), w), within(x1.clone(), w)];
        let y_inside = [within(y0.clone(), h), within(y1.clone(), h)];
        // One corner (x0 + dx, y0 + dy): its row `[N M]` (the zero row off the map) and
        // weight `[N M]` (zero off the map).
        let corner = |dx: usize, dy: usize, wx: Tensor<2>, wy: Tensor<2>| {
            let xi = [&x0, &x1][dx].clone();
            let yi = [&y0, &y1][dy].clone();
            let inside = x_inside[dx].clone().bool_and(y_inside[dy].clone());
            let outside = inside.bool_not();
            let index = (yi * (w as f32) + xi + view_base.clone())
                .mask_fill(outside.clone(), zero_row)
                .int()
                .reshape([n * m]);
            let weight = (wy * wx).mask_fill(outside, 0.0).reshape([n * m]);
            (index, weight)
        };
        let (gx, gy) = (fx.clone().neg() + 1.0, fy.clone().neg() + 1.0);
        let corners = [
            corner(0, 0, gx.clone(), gy.clone()),
            corner(1, 0, fx.clone(), gy),
            corner(0, 1, gx, fy.clone()),
            corner(1, 1, fx, fy),
        ];
        let training = self.rows.is_tracked() || corners[0].1.is_tracked();
        let out = if training && !computes_on_cpu(&device) {
            // Training on a GPU backend: one operation whose backward zeroes one buffer the
            // size of the maps for all four corners, not one per corner.
            let (index, weight): (Vec<_>, Vec<_>) = corners.into_iter().unzip();
            tap_gather(
                self.rows.clone(),
                Tensor::stack(index, 0),
                Tensor::stack(weight, 0),
                n * m,
            )
        } else {
            corners
                .into_iter()
                .map(|(index, weight)| {
                    select_rows(self.rows.clone(), index) * weight.reshape([n * m, 1])
                })
                .reduce(|sum, term| sum + term)
                .expect("four corners")
        };
        Ok(out.reshape([n, m, c]))
    }
}

/// Points per parallel task of [`host_read`].
const POINTS_PER_TASK: usize = 128;

/// The four corners of a read at the normalised grid point `(gx, gy)` of an `h x w` map, in
/// the tensor read's order (x0 y0, x1 y0, x0 y1, x1 y1) and with its coordinates and weights:
/// each corner's pixel `y w + x` (`None` off the map) and weight.
#[inline]
fn corners(gx: f32, gy: f32, h: usize, w: usize) -> [(Option<usize>, f32); 4] {
    let x = (gx + 1.0) * (w as f32 / 2.0) - 0.5;
    let y = (gy + 1.0) * (h as f32 / 2.0) - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (gx, gy) = (-fx + 1.0, -fy + 1.0);
    [
        (0.0, 0.0, gx, gy),
        (1.0, 0.0, fx, gy),
        (0.0, 1.0, gx, fy),
        (1.0, 1.0, fx, fy),
    ]
    .map(|(dx, dy, wx, wy)| {
        let (xi, yi) = (x0 + dx, y0 + dy);
        // Comparisons with NaN are false: a non-finite coordinate is outside.
        let inside = xi >= 0.0 && xi <= (w - 1) as f32 && yi >= 0.0 && yi <= (h - 1) as f32;
        (inside.then(|| yi as usize * w + xi as usize), wy * wx)
    })
}

/// The fused read: `out[n, m] = sum over the four corners of weight * row`, the corners in the
/// tensor read's order and with its coordinates and weights ([`corners`]).
///
/// # Shapes
/// - `rows`: `[N H W + 1, C]` row-major; `grid`: `[N, M, 2]` row-major
/// - output: `[N, M, C]` row-major
fn host_read(rows: &[f32], dims: [usize; 4], grid: &[f32], m: usize) -> Vec<f32> {
    let [n, c, h, w] = dims;
    let mut out = zeroed(n * m * c);
    out.par_chunks_mut(POINTS_PER_TASK * c)
        .enumerate()
        .for_each(|(task, block)| {
            for (r, acc) in block.chunks_mut(c).enumerate() {
                let flat = task * POINTS_PER_TASK + r; // view * M + point
                let view = flat / m;
                for (pixel, weight) in corners(grid[2 * flat], grid[2 * flat + 1], h, w) {
                    let Some(pixel) = pixel else { continue };
                    let row = view * h * w + pixel;
                    for (a, &v) in acc.iter_mut().zip(&rows[row * c..(row + 1) * c]) {
                        *a += v * weight;
                    }
                }
            }
        });
    out
}

/// The taps of a read for [`weighted_rows`]: four per (view, point), row `view M + point`, in
/// [`corners`]' order; a corner off the map reads the zero row `N H W` with weight 0, as the
/// tensor read does.
///
/// # Shapes
/// - `grid`: `[N, M, 2]` row-major
fn bilinear_taps(dims: [usize; 4], grid: &[f32], m: usize) -> Taps {
    let [n, _, h, w] = dims;
    let zero_row = (n * h * w) as u32;
    let mut index = Vec::with_capacity(n * m * 4);
    let mut weight = Vec::with_capacity(n * m * 4);
    for flat in 0..n * m {
        let view = flat / m;
        for (pixel, wt) in corners(grid[2 * flat], grid[2 * flat + 1], h, w) {
            match pixel {
                Some(p) => {
                    index.push((view * h * w + p) as u32);
                    weight.push(wt);
                }
                None => {
                    index.push(zero_row);
                    weight.push(0.0);
                }
            }
        }
    }
    Taps::new(4, index, weight)
}

/// `grid_sample_2d` (bilinear, zero padding, `align_corners = false`): the reference
/// [`sample`] is tested against.
///
/// # Shapes
/// - as [`sample`]
pub fn grid_sample_reference(
    maps: Tensor<4>,
    proj_grid: Tensor<3>,
) -> Result<Tensor<3>, ShapeError> {
    let [n, c, _, _] = check(&maps, &proj_grid)?;
    let m = proj_grid.dims()[1];
    let options = GridSampleOptions::default().with_align_corners(false);
    // [N, 1, M, 2] -> [N, C, 1, M] -> [N, C, M] -> [N, M, C]
    let sampled = maps.grid_sample_2d(proj_grid.reshape([n, 1, m, 2]), options);
    Ok(sampled.reshape([n, c, m]).swap_dims(1, 2))
}

/// M of a grid `[N, M, 2]` for N maps.
fn check_grid(n: usize, proj_grid: &Tensor<3>) -> Result<usize, ShapeError> {
    let [n_grid, m, two] = proj_grid.dims();
    ShapeError::check(
        "IBR `proj_grid` [N, M, 2]",
        &[n_grid, m, two],
        &[Some(n), None, Some(2)],
    )?;
    Ok(m)
}

/// `[N, C, H, W]` of `maps` after checking the grid against it.
fn check(maps: &Tensor<4>, proj_grid: &Tensor<3>) -> Result<[usize; 4], ShapeError> {
    let [n, c, h, w] = maps.dims();
    check_grid(n, proj_grid)?;
    if n == 0 || h == 0 || w == 0 {
        return Err(ShapeError::empty("IBR `maps` [N, C, H, W]"));
    }
    Ok([n, c, h, w])
}
