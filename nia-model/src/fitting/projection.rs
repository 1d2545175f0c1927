//! The cameras of a frame as constant tensors: world points to raw (distorted) pixels, all
//! views at once (OpenCV's model: `x_c = R x_w + T`, normalised `(x_c / z_c, y_c / z_c)`,
//! radial-tangential distortion `[k1, k2, p1, p2, k3]`, then `K`).

use burn::prelude::*;
use nia_data::geometry::camera::Camera;

/// Depth (metres) below which a point counts as at the camera plane; its projection is
/// computed at this depth instead (finite, and far off in the image).
pub const MIN_DEPTH_M: f32 = 1e-2;

/// `N` cameras on one device.
#[derive(Debug, Clone)]
pub struct ViewTensors {
    /// `N`.
    pub count: usize,
    /// `[3, 3N]`: `R_n^T` side by side, so `x [P, 3] @ rot` gives every view's `R_n x`.
    rot: Tensor<2>,
    /// `[1, 3N]`: `T_n` side by side.
    trans: Tensor<2>,
    /// `[1, 1, N]` each: fx, fy, cx, cy, skew, k1, k2, p1, p2, k3.
    intrinsics: [Tensor<3>; 10],
    distorted: bool,
}

/// Projected pixels.
#[derive(Debug, Clone)]
pub struct Projected {
    /// `[B, P, N]` pixel x.
    pub u: Tensor<3>,
    /// `[B, P, N]` pixel y.
    pub v: Tensor<3>,
}

impl ViewTensors {
    pub fn new(cameras: &[Camera], device: &Device) -> Self {
        let n = cameras.len();
        let mut rot = vec![0.0f32; 9 * n];
        let mut trans = Vec::with_capacity(3 * n);
        for (i, c) in cameras.iter().enumerate() {
            for row in 0..3 {
                for col in 0..3 {
                    // rot[col_in, 3i + row] = R[row][col]  (x @ R^T)
                    rot[col * 3 * n + 3 * i + row] = c.r.col(col)[row];
                }
            }
            trans.extend(c.t.to_array());
        }
        let per_view = |f: &dyn Fn(&Camera) -> f32| {
            let v: Vec<f32> = cameras.iter().map(f).collect();
            Tensor::<3>::from_data(TensorData::new(v, [1, 1, n]), device)
        };
        let intrinsics = [
            per_view(&|c| c.fx()),
            per_view(&|c| c.fy()),
            per_view(&|c| c.cx()),
            per_view(&|c| c.cy()),
            per_view(&|c| c.skew()),
            per_view(&|c| c.dist[0]),
            per_view(&|c| c.dist[1]),
            per_view(&|c| c.dist[2]),
            per_view(&|c| c.dist[3]),
            per_view(&|c| c.dist[4]),
        ];
        Self {
            count: n,
            rot: Tensor::from_data(TensorData::new(rot, [3, 3 * n]), device),
            trans: Tensor::from_data(TensorData::new(trans, [1, 3 * n]), device),
            intrinsics,
            distorted: cameras.iter().any(|c| c.dist.iter().any(|&d| d != 0.0)),
        }
    }

    /// Projects world points into every view.
    ///
    /// # Shapes
    /// - `points`: `[B, P, 3]` world, metres
    /// - output: `[B, P, N]` pixels
    pub fn project(&self, points: Tensor<3>) -> Projected {
        let [b, p, _] = points.dims();
        let n = self.count;
        let cam = (points.reshape([b * p, 3]).matmul(self.rot.clone()) + self.trans.clone())
            .reshape([b, p, n, 3]);
        let part = |i: usize| cam.clone().narrow(3, i, 1).reshape([b, p, n]);
        let z = part(2).clamp_min(MIN_DEPTH_M);
        let mut x = part(0) / z.clone();
        let mut y = part(1) / z;
        let [fx, fy, cx, cy, skew, k1, k2, p1, p2, k3] = self.intrinsics.clone();
        if self.distorted {
            let r2 = x.clone().square() + y.clone().square();
            let radial = (k3 * r2.clone() + k2) * r2.clone() * r2.clone() + k1 * r2.clone() + 1.0;
            let xy = x.clone() * y.clone();
            let xd = x.clone() * radial.clone()
                + p1.clone() * xy.clone() * 2.0
                + p2.clone() * (r2.clone() + x.clone().square() * 2.0);
            let yd = y.clone() * radial + p1 * (r2 + y.square() * 2.0) + p2 * xy * 2.0;
            x = xd;
            y = yd;
        }
        Projected {
            u: fx * x + skew * y.clone() + cx,
            v: fy * y + cy,
        }
    }
}
