//! The one optimiser of every fit: Levenberg-Marquardt on reweighted least squares.
//!
//! Each energy term hands its residuals `r` with a weight `w` and a sparse Jacobian row
//! ([`NormalEquations::add`]): `w r^2` for a quadratic term, and for a robust term
//! `rho(r^2)` the weight `rho'(r^2)` of iteratively reweighted least squares. A step solves
//! `(H + lambda diag(H)) delta = -g`; it is accepted only where the energy, evaluated exactly at
//! the candidate, falls and the candidate stays within the caller's bounds; `lambda` falls by
//! 3 after an accepted step and grows by 10 after a refused one.

/// Normal equations `H delta = -g` of a reweighted least-squares step in `n` parameters.
#[derive(Debug, Clone)]
pub(crate) struct NormalEquations {
    n: usize,
    /// `[n * n]` row-major; only the upper triangle is summed.
    h: Vec<f64>,
    /// `[n]`.
    g: Vec<f64>,
}

impl NormalEquations {
    pub fn new(n: usize) -> Self {
        NormalEquations {
            n,
            h: vec![0.0; n * n],
            g: vec![0.0; n],
        }
    }

    /// Adds the residual `r` with weight `w` and the sparse Jacobian row `j` (`(parameter,
    /// dr/dparameter)`, each parameter at most once). Only `H`'s upper triangle is summed
    /// ([`NormalEquations::solve`] mirrors it).
    pub fn add(&mut self, j: &[(usize, f32)], r: f32, w: f32) {
        let (r, w) = (f64::from(r), f64::from(w));
        for (i, &(p, jp)) in j.iter().enumerate() {
            let wjp = w * f64::from(jp);
            self.g[p] += wjp * r;
            for &(q, jq) in &j[i..] {
                self.h[p.min(q) * self.n + p.max(q)] += wjp * f64::from(jq);
            }
        }
    }

    /// `g`, half the energy's gradient in the step's parameters (tests check the rows with
    /// it against finite differences).
    #[cfg(test)]
    pub fn gradient(&self) -> &[f64] {
        &self.g
    }

    /// `(H + lambda diag(H)) delta = -g`, by Gaussian elimination with partial pivoting;
    /// `None` when singular or not finite.
    pub fn solve(&self, lambda: f64) -> Option<Vec<f64>> {
        let n = self.n;
        let cols = n + 1;
        let scale = (0..n)
            .map(|i| self.h[i * n + i])
            .fold(0.0f64, f64::max)
            .max(1e-12);
        let mut a = vec![0.0f64; n * cols];
        for i in 0..n {
            for k in 0..n {
                a[i * cols + k] = self.h[i.min(k) * n + i.max(k)];
            }
            a[i * cols + i] += lambda * self.h[i * n + i].max(1e-9 * scale);
            a[i * cols + n] = -self.g[i];
        }
        for col in 0..n {
            let pivot = (col..n)
                .max_by(|&p, &q| a[p * cols + col].abs().total_cmp(&a[q * cols + col].abs()))?;
            if !(a[pivot * cols + col].abs() >= 1e-12 * scale) {
                return None;
            }
            if pivot != col {
                for k in 0..cols {
                    a.swap(col * cols + k, pivot * cols + k);
                }
            }
            let diag = a[col * cols + col];
            for row in 0..n {
                if row == col {
                    continue;
                }
                let f = a[row * cols + col] / diag;
                if f == 0.0 {
                    continue;
                }
                for k in col..cols {
                    a[row * cols + k] -= f * a[col * cols + k];
                }
            }
        }
        let x: Vec<f64> = (0..n).map(|i| a[i * cols + n] / a[i * cols + i]).collect();
        x.iter().all(|v| v.is_finite()).then_some(x)
    }
}

/// A least-squares problem as the solver drives it: a state `S`, and what an evaluation of a
/// state leaves for its linearisation and its step (`P`: the posed body, say).
pub(crate) trait LeastSquares {
    type State: Clone;
    type Evaluated;
    /// The energy at `state` (not finite: refused) and what linearising it needs.
    fn evaluate(&self, state: &Self::State) -> (f32, Self::Evaluated);
    /// The normal equations at `state`.
    fn linearise(&self, state: &Self::State, at: &Self::Evaluated) -> NormalEquations;
    /// `state` moved by the step `delta`.
    fn step(&self, state: &Self::State, at: &Self::Evaluated, delta: &[f64]) -> Self::State;
    /// Whether `state` stays within the problem's bounds.
    fn within(&self, state: &Self::State, at: &Self::Evaluated) -> bool;
}

/// What [`levenberg_marquardt`] ends with.
pub(crate) struct Solution<S, E> {
    pub state: S,
    pub at: E,
    /// The energy at the start and at the end (never larger).
    pub energy_before: f32,
    pub energy: f32,
    /// Accepted steps.
    pub steps: usize,
}

/// Relative fall of the energy below which an accepted step ends the solve.
const CONVERGED: f32 = 1e-6;

/// Levenberg-Marquardt from `start` for at most `iterations` accepted or refused steps
/// (module docs).
pub(crate) fn levenberg_marquardt<P: LeastSquares>(
    problem: &P,
    start: P::State,
    iterations: usize,
) -> Solution<P::State, P::Evaluated> {
    let mut state = start;
    let (energy_before, mut at) = problem.evaluate(&state);
    let mut energy = energy_before;
    let mut steps = 0;
    if iterations == 0 || !energy.is_finite() {
        return Solution {
            state,
            at,
            energy_before,
            energy,
            steps,
        };
    }
    let mut system = problem.linearise(&state, &at);
    let mut lambda = 1e-3f64;
    for _ in 0..iterations {
        let Some(delta) = system.solve(lambda) else {
            break;
        };
        let candidate = problem.step(&state, &at, &delta);
        let (candidate_energy, candidate_at) = problem.evaluate(&candidate);
        let accepted = candidate_energy.is_finite()
            && candidate_energy < energy
            && problem.within(&candidate, &candidate_at);
        if accepted {
            let converged = energy - candidate_energy <= CONVERGED * energy.max(1e-12);
            state = candidate;
            at = candidate_at;
            energy = candidate_energy;
            steps += 1;
            lambda = (lambda / 3.0).max(1e-7);
            if converged {
                break;
            }
            system = problem.linearise(&state, &at);
        } else {
            lambda *= 10.0;
            if lambda > 1e8 {
                break;
            }
        }
    }
    Solution {
        state,
        at,
        energy_before,
        energy,
        steps,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `sum_i (a_i x - b_i)^2` in one parameter, and a bound `x <= limit`.
    struct Line {
        a: Vec<f32>,
        b: Vec<f32>,
        limit: f32,
    }

    impl LeastSquares for Line {
        type State = f32;
        type Evaluated = ();
        fn evaluate(&self, x: &f32) -> (f32, ()) {
            let e = self
                .a
                .iter()
                .zip(&self.b)
                .map(|(a, b)| (a * x - b).powi(2))
                .sum();
            (e, ())
        }
        fn linearise(&self, x: &f32, _: &()) -> NormalEquations {
            let mut system = NormalEquations::new(1);
            for (a, b) in self.a.iter().zip(&self.b) {
                system.add(&[(0, *a)], a * x - b, 1.0);
            }
            system
        }
        fn step(&self, x: &f32, _: &(), delta: &[f64]) -> f32 {
            x + delta[0] as f32
        }
        fn within(&self, x: &f32, _: &()) -> bool {
            *x <= self.limit
        }
    }

    #[test]
    fn a_linear_problem_is_solved_and_a_bound_is_kept() {
        let line = Line {
            a: vec![1.0, 2.0, 3.0],
            b: vec![2.0, 4.1, 5.9],
            limit: 10.0,
        };
        let s = levenberg_marquardt(&line, 0.0, 20);
        // Least squares: x = sum a b / sum a^2 = 27.9 / 14.
        assert!((s.state - 27.9 / 14.0).abs() < 1e-4, "{}", s.state);
        assert!(s.energy < s.energy_before && s.steps > 0);
        let bounded = Line { limit: 1.0, ..line };
        let s = levenberg_marquardt(&bounded, 0.0, 50);
        assert!(s.state <= 1.0 && s.state > 0.5, "{}", s.state);
    }

    #[test]
    fn a_singular_system_stops_without_moving() {
        let flat = Line {
            a: vec![0.0],
            b: vec![1.0],
            limit: 10.0,
        };
        let s = levenberg_marquardt(&flat, 0.5, 10);
        assert_eq!(s.state, 0.5);
        assert_eq!(s.steps, 0);
    }
}
