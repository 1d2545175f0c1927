//! The source views' colours made comparable before anything reads them (not in the paper;
//! `ModelConfig::source_colour_balance`).
//!
//! Every camera of a real capture has its own colour response (gain and white balance), so
//! the same point of the person reads brighter or redder in one source view than in another,
//! and a blend of the views mixes the responses. Each view's per-channel gain against the
//! others is estimated where the views agree on what they see: the SMPL vertices that two
//! views both see (per-vertex visibility) and whose pixels are on the person in both. For each
//! pair of views `(n, m)` and channel `c`, the log-ratio of their responses is the median over
//! their shared vertices `v`,
//!
//! ```text
//! d_nmc = median_v (ln I_n(pi_n(v))_c - ln I_m(pi_m(v))_c),
//! ```
//!
//! (pixels darker than [`MIN_LEVEL`] left out: their logarithm is noise; pairs sharing fewer
//! than [`MIN_SHARED`] vertices left out), and the views' log-responses `l_nc` are the least
//! squares solution of `l_n - l_m = d_nm` with `sum_n l_n = 0` (the consensus keeps its
//! brightness). The gain is `g_nc = exp(-l_nc)`, clamped to [[`MIN_GAIN`], [`MAX_GAIN`]]. The
//! median ignores what one view alone gets wrong: a misregistered edge, a hole in a mask, hair
//! off the body. A view in no pair keeps gain 1.

use glam::Vec2;

use super::{SceneInput, SourceView};
use crate::geometry::camera::PIXEL_CENTRE_OFFSET;

/// Channel values below this (in [0, 1]) do not enter a ratio.
pub const MIN_LEVEL: f32 = 0.02;
/// Fewest shared vertices a view needs for a gain of its own.
pub const MIN_SHARED: usize = 50;
/// Bounds of a gain: a camera's response differs by tens of percent, not by a factor of two.
pub const MIN_GAIN: f32 = 0.5;
pub const MAX_GAIN: f32 = 2.0;

/// `[N][3]` per-view, per-channel gains of `input`'s source views (module docs).
pub fn source_gains(input: &SceneInput) -> Vec<[f32; 3]> {
    let n = input.views.len();
    let vertices = &input.body.vertices;
    // [V][N] the colour each view reads at each vertex, where it sees it on the person.
    let reads: Vec<Vec<Option<[f32; 3]>>> = vertices
        .iter()
        .enumerate()
        .map(|(v, &x)| {
            input
                .views
                .iter()
                .map(|view| {
                    if view.vertex_visibility.get(v).copied().unwrap_or(0.0) < 0.5 {
                        return None;
                    }
                    let (uv, _) = view.camera.project(x)?;
                    read_on_person(view, uv)
                })
                .collect()
        })
        .collect();
    // Least squares over the pairs: (L + 1 1^T) l = b, L the pairs' graph Laplacian, b the
    // signed sums of their log-ratios (the 1 1^T term fixes sum l = 0).
    let mut laplacian = vec![0.0f64; n * n];
    let mut rhs = vec![[0.0f64; 3]; n];
    let mut paired = vec![false; n];
    for a in 0..n {
        for b in a + 1..n {
            let mut ratios: [Vec<f32>; 3] = Default::default();
            for views in &reads {
                let (Some(ca), Some(cb)) = (views[a], views[b]) else {
                    continue;
                };
                for c in 0..3 {
                    if ca[c] >= MIN_LEVEL && cb[c] >= MIN_LEVEL {
                        ratios[c].push(ca[c].ln() - cb[c].ln());
                    }
                }
            }
            if ratios.iter().any(|r| r.len() < MIN_SHARED) {
                continue;
            }
            paired[a] = true;
            paired[b] = true;
            laplacian[a * n + a] += 1.0;
            laplacian[b * n + b] += 1.0;
            laplacian[a * n + b] -= 1.0;
            laplacian[b * n + a] -= 1.0;
            for (c, r) in ratios.iter_mut().enumerate() {
                let d = f64::from(median(r));
                rhs[a][c] += d;
                rhs[b][c] -= d;
            }
        }
    }
    let mut log_responses = vec![[0.0f32; 3]; n];
    let views: Vec<usize> = (0..n).filter(|&v| paired[v]).collect();
    let k = views.len();
    if k >= 2 {
        // The paired views' system, (L + 1 1^T) restricted to them.
        let mut a = vec![0.0f64; k * k];
        for (i, &vi) in views.iter().enumerate() {
            for (j, &vj) in views.iter().enumerate() {
                a[i * k + j] = laplacian[vi * n + vj] + 1.0;
            }
        }
        for c in 0..3 {
            let b: Vec<f64> = views.iter().map(|&v| rhs[v][c]).collect();
            if let Some(l) = solve(&a, &b, k) {
                for (i, &v) in views.iter().enumerate() {
                    log_responses[v][c] = l[i] as f32;
                }
            }
        }
    }
    log_responses
        .iter()
        .map(|l| l.map(|x| (-x).exp().clamp(MIN_GAIN, MAX_GAIN)))
        .collect()
}

/// `a x = b` for a `k x k` system by Gaussian elimination with partial pivoting; `None` when
/// singular.
fn solve(a: &[f64], b: &[f64], k: usize) -> Option<Vec<f64>> {
    let mut m: Vec<f64> = (0..k)
        .flat_map(|i| a[i * k..(i + 1) * k].iter().copied().chain([b[i]]))
        .collect();
    let cols = k + 1;
    for col in 0..k {
        let pivot = (col..k)
            .max_by(|&p, &q| m[p * cols + col].abs().total_cmp(&m[q * cols + col].abs()))?;
        if m[pivot * cols + col].abs() < 1e-12 {
            return None;
        }
        for j in 0..cols {
            m.swap(col * cols + j, pivot * cols + j);
        }
        for row in 0..k {
            if row != col {
                let f = m[row * cols + col] / m[col * cols + col];
                for j in col..cols {
                    m[row * cols + j] -= f * m[col * cols + j];
                }
            }
        }
    }
    Some((0..k).map(|i| m[i * cols + k] / m[i * cols + i]).collect())
}

/// `input` with every source image multiplied by its view's gains (clamped to [0, 1]).
pub fn balance_source_colours(input: &mut SceneInput) {
    let gains = source_gains(input);
    for (view, g) in input.views.iter_mut().zip(&gains) {
        let plane = view.image.len() / 3;
        for (c, &gain) in g.iter().enumerate() {
            for x in &mut view.image[c * plane..(c + 1) * plane] {
                *x = (*x * gain).min(1.0);
            }
        }
    }
}

/// The colour at pixel `uv` (nearest pixel) where the view's mask says person.
fn read_on_person(view: &SourceView, uv: Vec2) -> Option<[f32; 3]> {
    let (w, h) = (view.camera.width as usize, view.camera.height as usize);
    let p = (uv - Vec2::splat(PIXEL_CENTRE_OFFSET) + Vec2::splat(0.5)).floor();
    if p.x < 0.0 || p.y < 0.0 || p.x >= w as f32 || p.y >= h as f32 {
        return None;
    }
    let i = p.y as usize * w + p.x as usize;
    if view.mask.get(i).copied().unwrap_or(0.0) < 0.5 {
        return None;
    }
    let plane = w * h;
    Some([
        view.image[i],
        view.image[plane + i],
        view.image[2 * plane + i],
    ])
}

fn median(values: &mut [f32]) -> f32 {
    values.sort_by(f32::total_cmp);
    let m = values.len() / 2;
    if values.len() % 2 == 1 {
        values[m]
    } else {
        0.5 * (values[m - 1] + values[m])
    }
}
