//! Per-point inputs of the fields, computed on the CPU from the scene geometry (query points are
//! data: no gradient flows through them): the projections into every source view, the
//! view-direction features d_hat_n, the visibility o_n, the trilinear corners in the body
//! volume, the target directions and (with a visual hull) the density's carving. The model
//! uploads them as a few tensors.

use std::sync::Arc;

use glam::Vec3;
use rayon::prelude::*;

use super::{SceneGeometry, VisualHull};
use crate::geometry::camera::Camera;
use crate::geometry::sparse::{ScaleGeometry, TrilinearCorners, CORNERS};

/// Width of d_hat_n: (d - d_n) (3 channels) and d . d_n (1 channel).
pub const VIEW_DIR_FEATURE_DIM: usize = 4;

/// Normalised grid coordinate of a point behind a camera: far outside [-1, 1], so
/// `grid_sample` with zero padding returns zeros.
pub const OUTSIDE_GRID: f32 = -4.0;

/// Where the body volume is read: the geometry of its scales and the points
/// where it is sampled (`[M]`, SMPL frame of the volume's body).
pub type VolumeSamples<'a> = (&'a [Arc<ScaleGeometry>], &'a [[f32; 3]]);

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
    /// [M] the visual hull's carving of the density, in [0, 1] (`None` without a hull;
    /// [`Self::carved`] sets it).
    pub hull: Option<Vec<f32>>,
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

/// The inputs only the colour half reads: the view-direction features `[N, M, 4]` and, with
/// `what` [`InputsFor::Network`], the visibility `[N, M]` of `image_points`.
fn colour_inputs(
    geometry: &SceneGeometry,
    image_points: &[Vec3],
    dirs: &[Vec3],
    what: InputsFor,
    view_dir_features: &mut [f32],
    visibility: &mut [f32],
) {
    let m = image_points.len();
    const D: usize = VIEW_DIR_FEATURE_DIM;
    for (view, camera) in geometry.cameras.iter().enumerate() {
        let centre = camera.centre();
        let vdf = &mut view_dir_features[view * m * D..(view + 1) * m * D];
        vdf.par_chunks_mut(D)
            .zip(image_points.par_iter().zip(dirs.par_iter()))
            .for_each(|(f, (&x, &d))| {
                let d_n = (x - centre).normalize_or_zero();
                f.copy_from_slice(&view_direction_feature(d, d_n));
            });
    }
    if what != InputsFor::Network {
        return;
    }
    // o_n: one nearest-face query per point serves every view.
    let nearest = geometry.surface.nearest_batch(image_points);
    let faces = geometry.surface.faces();
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
}

/// Which of the network's halves the inputs feed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputsFor {
    /// The whole network: every input.
    Network,
    /// The whole network, but the visibility o_n stays zero for the caller to fill (from a
    /// visibility baked per pose): no nearest-face query.
    NetworkWithoutVisibility,
    /// The density half alone (the projections, the body volume's corners and the carving):
    /// the view-direction features and the visibility, which only the colour half reads, stay
    /// zero and cost nothing (the nearest-face query is most of the inputs' time).
    Density,
}

impl PointInputs {
    /// Inputs for `image_points` ([M] world points where the source views are read; x, or x'
    /// after reposing) with target directions `dirs` ([M] unit), and, when the model uses the
    /// body volume, its scales and the points where it is sampled ([M] SMPL frame of the
    /// volume's body).
    pub fn compute(
        geometry: &SceneGeometry,
        image_points: &[Vec3],
        dirs: &[Vec3],
        volume: Option<VolumeSamples<'_>>,
    ) -> Self {
        Self::compute_for(geometry, image_points, dirs, volume, InputsFor::Network)
    }

    /// [`Self::compute`] for the network's half `what`.
    pub fn compute_for(
        geometry: &SceneGeometry,
        image_points: &[Vec3],
        dirs: &[Vec3],
        volume: Option<VolumeSamples<'_>>,
        what: InputsFor,
    ) -> Self {
        let m = image_points.len();
        let n = geometry.num_views();
        let proj_grid = projection_grid(geometry, image_points);
        let mut view_dir_features = vec![0.0f32; n * m * VIEW_DIR_FEATURE_DIM];
        let mut visibility = vec![0.0f32; n * m];
        if what != InputsFor::Density {
            colour_inputs(
                geometry,
                image_points,
                dirs,
                what,
                &mut view_dir_features,
                &mut visibility,
            );
        }
        let corners = match volume {
            Some((scales, points)) => scales
                .iter()
                .map(|scale| TrilinearCorners::compute(points, scale))
                .collect(),
            None => Vec::new(),
        };
        PointInputs {
            num_points: m,
            num_views: n,
            proj_grid,
            view_dir_features,
            visibility,
            dirs: dirs.iter().flat_map(|d| d.to_array()).collect(),
            hull: None,
            corners,
        }
    }

    /// These inputs with the carving of `hull` ([`VisualHull::carving`]) at `image_points`
    /// (the points [`Self::compute`] was given), projected by the scene's `cameras`.
    pub fn carved(mut self, hull: &VisualHull, cameras: &[Camera], image_points: &[Vec3]) -> Self {
        self.hull = Some(
            image_points
                .par_iter()
                .map(|&x| hull.carving(cameras, x))
                .collect(),
        );
        self
    }

    /// These inputs for `len` points: the M points', then copies of the last point's up to
    /// `len` (what [`Self::compute`] would give for the points with the last one repeated,
    /// without computing it again). Unchanged when M is 0 or already `len` or more.
    ///
    /// # Shapes
    /// every `[N, M, ..]` / `[M, ..]` array becomes `[N, len, ..]` / `[len, ..]`
    pub fn padded(self, len: usize) -> Self {
        let m = self.num_points;
        if m == 0 || len <= m {
            return self;
        }
        let n = self.num_views;
        PointInputs {
            num_points: len,
            num_views: n,
            proj_grid: pad_rows(&self.proj_grid, n, m, 2, len),
            view_dir_features: pad_rows(&self.view_dir_features, n, m, VIEW_DIR_FEATURE_DIM, len),
            visibility: pad_rows(&self.visibility, n, m, 1, len),
            dirs: pad_rows(&self.dirs, 1, m, 3, len),
            hull: self.hull.as_deref().map(|h| pad_rows(h, 1, m, 1, len)),
            corners: self
                .corners
                .into_iter()
                .map(|c| TrilinearCorners {
                    index: pad_rows(&c.index, 1, m, CORNERS, len),
                    weight: pad_rows(&c.weight, 1, m, CORNERS, len),
                    num_sites: c.num_sites,
                })
                .collect(),
        }
    }
}

/// `[blocks, m, width]` values as `[blocks, len, width]`: each block's m rows, then copies of
/// its last row (m > 0, len >= m).
fn pad_rows<T: Copy>(values: &[T], blocks: usize, m: usize, width: usize, len: usize) -> Vec<T> {
    debug_assert_eq!(values.len(), blocks * m * width);
    let mut out = Vec::with_capacity(blocks * len * width);
    for block in values.chunks_exact(m * width) {
        out.extend_from_slice(block);
        let last = &block[(m - 1) * width..];
        for _ in m..len {
            out.extend_from_slice(last);
        }
    }
    out
}

/// d_hat_n for one point and view: `(d - d_n, d . d_n)`, with `target_dir` d the unit
/// direction of the target ray and `source_dir` d_n the unit direction from source camera n's
/// centre to the point (both in the same frame).
pub fn view_direction_feature(target_dir: Vec3, source_dir: Vec3) -> [f32; VIEW_DIR_FEATURE_DIM] {
    let diff = target_dir - source_dir;
    [diff.x, diff.y, diff.z, target_dir.dot(source_dir)]
}
