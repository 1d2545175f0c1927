//! Baking the density of a scene's pose on a [`DensityGrid`] (`renderer::density_grid`):
//! F_sigma's half of the network at the grid's nodes, in calls of the scene's
//! `points_per_call`, once per pose and kept in the encoding's
//! [`DensityMemo`](crate::renderer::density_grid::DensityMemo).

use std::sync::Arc;

use glam::Vec3;
use nia_data::geometry::rays::Aabb;
use nia_data::scene::InputsFor;

use crate::error::ModelError;
use crate::kernels::readback::host_values;
use crate::model::NiaModel;
use crate::renderer::density_grid::DensityGrid;
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
        let grid = DensityGrid::bake(bounds, cell_m, wanted, |points| {
            let call = scene.points_per_call.max(1);
            let mut sigma = Vec::with_capacity(points.len());
            for chunk in points.chunks(call) {
                // The density half reads no direction; any unit vector serves.
                let dirs = vec![Vec3::Z; chunk.len()];
                let inputs =
                    self.point_tensors_for(scene, chunk, &dirs, rows, InputsFor::Density, watch)?;
                let pass = self.query_density(scene, &inputs, watch)?;
                let values = host_values(pass.sigma)
                    .map_err(|e| ModelError::Input(format!("reading baked densities: {e}")))?;
                sigma.extend_from_slice(&values[..chunk.len()]);
            }
            Ok(sigma)
        })?;
        let grid = Arc::new(grid);
        *memo = Some(grid.clone());
        Ok(grid)
    }
}
