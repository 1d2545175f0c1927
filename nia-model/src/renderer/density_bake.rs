//! Baking the density of a scene's pose on a [`DensityGrid`] (`renderer::density_grid`):
//! F_sigma's half of the network at the grid's nodes, in calls of the scene's
//! `points_per_call`, with the visibility o_n of every source view there (the nearest-face
//! visibility the colour half reads), once per pose and kept in the encoding's
//! [`DensityMemo`](crate::renderer::density_grid::DensityMemo).

use std::sync::Arc;

use glam::Vec3;
use nia_data::geometry::rays::Aabb;
use nia_data::scene::InputsFor;
use rayon::prelude::*;

use crate::error::ModelError;
use crate::field::query::{upload_padded, Carving};
use crate::field::PointTensors;
use crate::kernels::readback::host_values;
use crate::model::NiaModel;
use crate::renderer::density_grid::{DensityGrid, NodeValues};
use crate::renderer::shape_buckets::CallRows;
use crate::scene_encoding::SceneEncoding;
use crate::timing::Stopwatch;

impl NiaModel {
    /// [`Self::baked_density`] without stage timings, for callers outside the renderer (which
    /// bakes through `renderer::view::render_view`): the grid of `scene`'s pose over `bounds`
    /// at `cell_m`, to read with [`SceneEncoding::with_density_grid`].
    pub fn bake_density(
        &self,
        scene: &SceneEncoding,
        bounds: &Aabb,
        cell_m: f32,
    ) -> Result<Arc<DensityGrid>, ModelError> {
        let device = scene.images.device();
        self.baked_density(scene, bounds, cell_m, &mut Stopwatch::new(None, &device))
    }

    /// The density of `scene`'s pose baked over `bounds` (the body's ray box in that pose) at
    /// `cell_m`, or the grid its memo holds from an earlier call with the same box and cell.
    /// Nodes next to a cell the scene's occupancy grid keeps are evaluated (every node without
    /// skipping); the density half of the network runs on them in calls of the scene's
    /// `points_per_call`. `watch` charges the point inputs, sampling and MLP stages.
    pub(crate) fn baked_density(
        &self,
        scene: &SceneEncoding,
        bounds: &Aabb,
        cell_m: f32,
        watch: &mut Stopwatch<'_>,
    ) -> Result<Arc<DensityGrid>, ModelError> {
        let mut memo = scene.density_memo.0.lock().map_err(|_| {
            ModelError::Input("density grid: a render panicked while baking".into())
        })?;
        if let Some(grid) = memo.as_ref().filter(|g| g.covers(bounds, cell_m)) {
            return Ok(grid.clone());
        }
        let half = 0.5 * cell_m;
        let wanted = |x: Vec3| match &scene.occupancy {
            None => true,
            // A node is read by the 8 cells around it: evaluated if any of them may hold
            // density (the occupancy grid's cells are tested at the corners' midpoints).
            Some(occupancy) => (0..8).any(|k| {
                let corner = Vec3::new(
                    if k & 1 == 0 { -half } else { half },
                    if k & 2 == 0 { -half } else { half },
                    if k & 4 == 0 { -half } else { half },
                );
                occupancy.occupied(x + corner)
            }),
        };
        let device = scene.images.device();
        let rows = CallRows::on(&device);
        let views = scene.num_views();
        let grid = DensityGrid::bake(bounds, cell_m, views, wanted, |points| {
            let call = scene.points_per_call.max(1);
            let m = points.len();
            let mut sigma = Vec::with_capacity(m);
            // [N, M] view-major, filled chunk by chunk.
            let mut visibility = vec![0.0f32; views * m];
            for (c, chunk) in points.chunks(call).enumerate() {
                // The density half reads no direction; any unit vector serves (the
                // view-direction features computed with the visibility go unused).
                let dirs = vec![Vec3::Z; chunk.len()];
                let inputs = self.point_inputs_for(scene, chunk, &dirs, InputsFor::Network)?;
                let k = chunk.len();
                for (view, o) in inputs.visibility.chunks_exact(k).enumerate() {
                    visibility[view * m + c * call..][..k].copy_from_slice(o);
                }
                let tensors = upload_padded(scene, inputs, rows, watch)?;
                let pass = self.query_density(scene, &tensors, watch)?;
                let values = host_values(pass.sigma)
                    .map_err(|e| ModelError::Input(format!("reading baked densities: {e}")))?;
                sigma.extend_from_slice(&values[..k]);
            }
            Ok(NodeValues { sigma, visibility })
        })?;
        let grid = Arc::new(grid);
        *memo = Some(grid.clone());
        Ok(grid)
    }

    /// The whole network's inputs at `points` ([M] world, in the rendered pose; `dirs` their
    /// unit target directions) with the visibility o_n read from `grid`'s baked visibility
    /// ([`DensityGrid::visibility_at`]) instead of a nearest-face query per point; the
    /// ordinary inputs ([`Self::point_tensors`]) when the grid holds no visibility of the
    /// scene's views.
    pub(crate) fn point_tensors_on_grid(
        &self,
        scene: &SceneEncoding,
        grid: &DensityGrid,
        points: &[Vec3],
        dirs: &[Vec3],
        rows: CallRows,
        watch: &mut Stopwatch<'_>,
    ) -> Result<PointTensors, ModelError> {
        let n = scene.num_views();
        if grid.visibility_views() != n {
            return self.point_tensors(scene, points, dirs, rows, watch);
        }
        let m = points.len();
        // The baked density holds the carving: the colour half reads none.
        let mut inputs = self.point_inputs_with(
            scene,
            points,
            dirs,
            InputsFor::NetworkWithoutVisibility,
            Carving::None,
        )?;
        // [M, N] point-major reads, stored [N, M] as the inputs hold o_n.
        let mut read = vec![0.0f32; m * n];
        read.par_chunks_mut(n.max(1))
            .zip(points.par_iter())
            .for_each(|(o, &x)| grid.visibility_at(x, o));
        for (view, o) in inputs.visibility.chunks_exact_mut(m.max(1)).enumerate() {
            o.iter_mut()
                .zip(read.chunks_exact(n))
                .for_each(|(o, point)| *o = point[view]);
        }
        upload_padded(scene, inputs, rows, watch)
    }
}
