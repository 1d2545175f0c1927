//! The matrix products of the host kernels, on the `gemm` crate: one checked entry instead of an
//! `unsafe` call in every kernel. A product first checks that its slices hold the extents it
//! reads and writes; a mismatch is a bug in the caller and panics, never a read or write past a
//! slice.

use std::mem::MaybeUninit;

/// A strided `[rows, cols]` matrix: element `(i, j)` at `i * row_stride + j * col_stride`.
#[derive(Clone, Copy)]
pub struct Strided<'a> {
    pub values: &'a [f32],
    pub row_stride: usize,
    pub col_stride: usize,
}

impl<'a> Strided<'a> {
    /// `values` as a row-major `[_, cols]` matrix.
    pub fn rows(values: &'a [f32], cols: usize) -> Self {
        Self::rows_every(values, cols)
    }

    /// Rows `row_stride` values apart, each read from its start (a row-major matrix, or the
    /// first columns of a wider one).
    pub fn rows_every(values: &'a [f32], row_stride: usize) -> Self {
        Strided {
            values,
            row_stride,
            col_stride: 1,
        }
    }

    /// The transpose of a row-major `[_, cols]` matrix.
    pub fn transposed(values: &'a [f32], cols: usize) -> Self {
        Strided {
            values,
            row_stride: 1,
            col_stride: cols,
        }
    }

    /// Whether element `(rows - 1, cols - 1)` lies inside the slice.
    pub fn holds(&self, rows: usize, cols: usize) -> bool {
        rows == 0
            || cols == 0
            || (rows - 1) * self.row_stride + (cols - 1) * self.col_stride < self.values.len()
    }
}

/// `dst = lhs rhs`, or `dst += lhs rhs` when `accumulate`, on `threads`: `dst` `[m, n]`
/// row-major (exactly `m n` values), `lhs` `[m, k]`, `rhs` `[k, n]`.
///
/// # Panics
/// When `dst` does not hold `m n` values or `lhs` and `rhs` their extents.
pub fn product_into(
    dst: &mut [f32],
    [m, n, k]: [usize; 3],
    lhs: Strided<'_>,
    rhs: Strided<'_>,
    accumulate: bool,
    threads: gemm::Parallelism,
) {
    assert!(
        dst.len() == m * n && lhs.holds(m, k) && rhs.holds(k, n),
        "host product: [{m}, {k}] x [{k}, {n}] on slices of {}, {} and {} values",
        dst.len(),
        lhs.values.len(),
        rhs.values.len()
    );
    if dst.is_empty() {
        return;
    }
    // SAFETY: the assert above checked that `dst` holds the row-major [m, n] result and that
    // `lhs` and `rhs` hold every element the product reads.
    unsafe { raw_product(dst.as_mut_ptr(), [m, n, k], lhs, rhs, accumulate, threads) }
}

/// `lhs [m, k] x rhs [k, n]` into a new row-major `[m, n]` buffer, on `threads`.
///
/// # Panics
/// When `lhs` or `rhs` does not hold its extent.
pub fn product(
    [m, n, k]: [usize; 3],
    lhs: Strided<'_>,
    rhs: Strided<'_>,
    threads: gemm::Parallelism,
) -> Vec<f32> {
    assert!(
        lhs.holds(m, k) && rhs.holds(k, n),
        "host product: [{m}, {k}] x [{k}, {n}] on slices of {} and {} values",
        lhs.values.len(),
        rhs.values.len()
    );
    let len = m * n;
    let mut out: Vec<f32> = Vec::with_capacity(len);
    if len > 0 {
        let dst: &mut [MaybeUninit<f32>] = &mut out.spare_capacity_mut()[..len];
        // SAFETY: `dst` has room for the row-major [m, n] result; `lhs` and `rhs` hold the
        // extents the assert checked. Without `accumulate` gemm stores every element of the
        // destination without reading it (zeros when k is 0), so all `len` values are
        // initialised before `set_len`.
        unsafe {
            raw_product(dst.as_mut_ptr().cast(), [m, n, k], lhs, rhs, false, threads);
            out.set_len(len);
        }
    }
    out
}

/// gemm's product into the row-major `[m, n]` destination at `dst` (`dst += lhs rhs` when
/// `accumulate`, else `dst = lhs rhs` without reading it).
///
/// # Safety
/// `dst` must be valid for writes (and, with `accumulate`, reads) of `m n` values, and `lhs`
/// and `rhs` must hold `[m, k]` and `[k, n]` ([`Strided::holds`]).
unsafe fn raw_product(
    dst: *mut f32,
    [m, n, k]: [usize; 3],
    lhs: Strided<'_>,
    rhs: Strided<'_>,
    accumulate: bool,
    threads: gemm::Parallelism,
) {
    // SAFETY: the caller's contract; the strides are those `lhs` and `rhs` were checked with.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst,
            1,
            n as isize,
            accumulate,
            lhs.values.as_ptr(),
            lhs.col_stride as isize,
            lhs.row_stride as isize,
            rhs.values.as_ptr(),
            rhs.col_stride as isize,
            rhs.row_stride as isize,
            if accumulate { 1.0 } else { 0.0 },
            1.0,
            false,
            false,
            false,
            threads,
        );
    }
}
