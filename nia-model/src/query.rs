//! Per-point inputs of the fields, computed on the CPU from the scene geometry (query points are
//! data: no gradient flows through them) and uploaded as a few tensors: the projections into
//! every source view, the view-direction features d_hat_n, the visibility o_n, the trilinear
//! corners in the body volume, and the target directions.

use burn::prelude::*;
use glam::Vec3;
use rayon::prelude::*;

use crate::body_volume::{BodyVolumeGeometry, TrilinearCorners, TrilinearTensors};
use crate::scene::SceneGeometry;

/// Normalised grid coordinate of a point behind a camera: far outside [-1, 1], so
/// `grid_sample` with zero padding returns zeros.
const OUTSIDE_GRID: f32 = -4.0;

/// Per-point inputs for M points and N views, plain arrays.
#[derive(Debug, Clone)]
pub struct PointInputs {
    /// M.
    pub num_points: usize,
    /// N.
    pub num_views: usize,
    /// [N, M, 2] projections, normalised for `grid_sample` with `align_corners = false`
    /// (OpenCV pixel centres at integer coordinates: x_norm = (2u + 1) / W - 1).
    pub proj_grid: Vec<f32>,
    /// [N, M, 4] d_hat_n = (d - d_n, d . d_n).
    pub view_dir_features: Vec<f32>,
    /// [N, M] o_n: visibility interpolated on the nearest body face.
    pub visibility: Vec<f32>,
    /// [M, 3] unit target directions d (input of gamma(d)).
    pub dirs: Vec<f32>,
    /// Per scale of the body volume, the trilinear corners of the points (empty without one).
    pub corners: Vec<TrilinearCorners>,
}

/// [N, M, 2] projections of `points` ([M] world) into every source view, normalised for
/// `grid_sample` with `align_corners = false`: `x_norm = (2u + 1) / W - 1` with OpenCV pixel
/// centres at integer coordinates. Points behind a camera land far outside [-1, 1] (zeros).
pub fn projection_grid(geometry: &SceneGeometry, points: &[Vec3]) -> Vec<f32> {
    let m = points.len();
    let [h, w] = geometry.image_hw;
    let mut grid = vec![0.0f32; geometry.num_views() * m * 2];
    for (view, camera) in geometry.cameras.iter().enumerate() {
        grid[view * m * 2..(view + 1) * m * 2]
            .par_chunks_mut(2)
            .zip(points.par_iter())
            .for_each(|(g, &x)| match camera.project(x) {
                Some((uv, _depth)) => {
                    g[0] = (2.0 * uv.x + 1.0) / w as f32 - 1.0;
                    g[1] = (2.0 * uv.y + 1.0) / h as f32 - 1.0;
                }
                None => {
                    g[0] = OUTSIDE_GRID;
                    g[1] = OUTSIDE_GRID;
                }
            });
    }
    grid
}

/// [`PointInputs`] on a device.
#[derive(Debug, Clone)]
pub struct PointTensors {
    pub num_points: usize,
    /// [N, M, 2]
    pub proj_grid: Tensor<3>,
    /// [N, M, 4]
    pub view_dir_features: Tensor<3>,
    /// [N, M]
    pub visibility: Tensor<2>,
    /// [M, 3]
    pub dirs: Tensor<2>,
    pub corners: Vec<TrilinearTensors>,
}

impl PointInputs {
    /// Inputs for `image_points` ([M] world points where the source views are read; x, or x'
    /// after reposing) with target directions `dirs` ([M] unit), and, when the model uses the
    /// body volume, the points where it is sampled (`volume_points`, [M] SMPL frame of the
    /// volume's body).
    pub fn compute(
        geometry: &SceneGeometry,
        image_points: &[Vec3],
        dirs: &[Vec3],
        volume: Option<(&BodyVolumeGeometry, &[[f32; 3]])>,
    ) -> Self {
        let m = image_points.len();
        let n = geometry.num_views();
        let proj_grid = projection_grid(geometry, image_points);
        let mut view_dir_features = vec![0.0f32; n * m * 4];
        for (view, camera) in geometry.cameras.iter().enumerate() {
            let centre = camera.centre();
            let vdf = &mut view_dir_features[view * m * 4..(view + 1) * m * 4];
            vdf.par_chunks_mut(4)
                .zip(image_points.par_iter().zip(dirs.par_iter()))
                .for_each(|(f, (&x, &d))| {
                    let d_n = (x - centre).normalize_or_zero();
                    let diff = d - d_n;
                    f[0] = diff.x;
                    f[1] = diff.y;
                    f[2] = diff.z;
                    f[3] = d.dot(d_n);
                });
        }
        // o_n: one nearest-face query per point serves every view.
        let nearest = geometry.surface.nearest_batch(image_points);
        let faces = geometry.surface.faces();
        let mut visibility = vec![0.0f32; n * m];
        for (view, vis) in geometry.vertex_visibility.iter().enumerate() {
            let out = &mut visibility[view * m..(view + 1) * m];
            out.par_iter_mut()
                .zip(nearest.par_iter())
                .for_each(|(o, near)| {
                    *o = if near.is_hit() {
                        let [i, j, k] = faces[near.face as usize];
                        let b = near.bary;
                        vis[i as usize] * b[0] + vis[j as usize] * b[1] + vis[k as usize] * b[2]
                    } else {
                        0.0
                    };
                });
        }
        let corners = match volume {
            Some((vg, points)) => vg.corners(points),
            None => Vec::new(),
        };
        PointInputs {
            num_points: m,
            num_views: n,
            proj_grid,
            view_dir_features,
            visibility,
            dirs: dirs.iter().flat_map(|d| d.to_array()).collect(),
            corners,
        }
    }

    /// Uploads to `device`.
    pub fn to_tensors(&self, device: &Device) -> PointTensors {
        let (n, m) = (self.num_views, self.num_points);
        PointTensors {
            num_points: m,
            proj_grid: Tensor::from_data(
                TensorData::new(self.proj_grid.clone(), [n, m, 2]),
                device,
            ),
            view_dir_features: Tensor::from_data(
                TensorData::new(self.view_dir_features.clone(), [n, m, 4]),
                device,
            ),
            visibility: Tensor::from_data(TensorData::new(self.visibility.clone(), [n, m]), device),
            dirs: Tensor::from_data(TensorData::new(self.dirs.clone(), [m, 3]), device),
            corners: self.corners.iter().map(|c| c.to_tensors(device)).collect(),
        }
    }
}
