//! Adam (Kingma and Ba 2015) on the host over the fitter's few parameters (tens per frame):
//! the gradients come from burn's autodiff, the update is a loop over a flat vector.

/// PyTorch's Adam constants.
const BETA1: f32 = 0.9;
const BETA2: f32 = 0.999;
const EPSILON: f32 = 1e-8;

/// Adam state over a flat parameter vector with a step size per entry.
#[derive(Debug, Clone)]
pub(crate) struct HostAdam {
    lr: Vec<f32>,
    m: Vec<f32>,
    v: Vec<f32>,
    t: i32,
}

impl HostAdam {
    /// `lr[i]` is entry `i`'s step size (0 freezes it).
    pub fn new(lr: Vec<f32>) -> Self {
        let n = lr.len();
        Self {
            lr,
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        }
    }

    /// One step: `x -= scale * lr * m_hat / (sqrt(v_hat) + eps)`.
    pub fn step(&mut self, x: &mut [f32], grad: &[f32], scale: f32) {
        self.t += 1;
        let c1 = 1.0 - BETA1.powi(self.t);
        let c2 = 1.0 - BETA2.powi(self.t);
        for i in 0..x.len() {
            if self.lr[i] == 0.0 {
                continue;
            }
            let g = grad[i];
            self.m[i] = BETA1 * self.m[i] + (1.0 - BETA1) * g;
            self.v[i] = BETA2 * self.v[i] + (1.0 - BETA2) * g * g;
            let m_hat = self.m[i] / c1;
            let v_hat = self.v[i] / c2;
            x[i] -= scale * self.lr[i] * m_hat / (v_hat.sqrt() + EPSILON);
        }
    }
}
