//! The fit against a known body (the generator's true `params/` and `vertices/`): MPJPE over
//! SMPL's 24 joints and the mean vertex distance, in centimetres.

use std::path::Path;

use nia_data::body::{BodyModel, SmplParams};
use nia_data::dataset::zju::{read_params, read_vertices};
use serde::Serialize;

use super::PrepareError;

/// Centimetres per metre.
const CM_PER_M: f32 = 100.0;

/// Errors of a fit against the truth, averaged over frames.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TruthErrors {
    /// Mean per-joint position error over the 24 SMPL joints, cm.
    pub mpjpe_cm: f32,
    /// Mean distance between fitted and true vertices (same index), cm.
    pub vertex_cm: f32,
    /// The worst frame's MPJPE, cm.
    pub worst_frame_mpjpe_cm: f32,
    pub frames: usize,
}

/// Compares fitted frames (`(file number, params, world vertices)`) with
/// `truth/params/<n>.npy` and `truth/vertices/<n>.npy`.
pub fn compare(
    truth: &Path,
    model: &BodyModel,
    fitted: &[(usize, SmplParams, Vec<glam::Vec3>)],
) -> Result<TruthErrors, PrepareError> {
    let (mut joint_sum, mut vertex_sum, mut worst) = (0.0f64, 0.0f64, 0.0f32);
    for (n, params, vertices) in fitted {
        let true_params = read_params(&truth.join("params").join(format!("{n}.npy")))?;
        let vpath = truth.join("vertices").join(format!("{n}.npy"));
        let true_vertices = read_vertices(&vpath)?;
        if true_vertices.len() != vertices.len() {
            return Err(PrepareError::invalid(
                &vpath,
                format!(
                    "{} vertices, the fitted body has {} (another body model?)",
                    true_vertices.len(),
                    vertices.len()
                ),
            ));
        }
        let a = model.lbs(params).joints;
        let b = model.lbs(&true_params).joints;
        let mpjpe = a.iter().zip(&b).map(|(x, y)| x.distance(*y)).sum::<f32>() / a.len() as f32;
        let verr = vertices
            .iter()
            .zip(&true_vertices)
            .map(|(x, y)| x.distance(*y) as f64)
            .sum::<f64>()
            / vertices.len() as f64;
        joint_sum += mpjpe as f64;
        vertex_sum += verr;
        worst = worst.max(mpjpe * CM_PER_M);
    }
    let count = fitted.len().max(1) as f64;
    Ok(TruthErrors {
        mpjpe_cm: (joint_sum / count) as f32 * CM_PER_M,
        vertex_cm: (vertex_sum / count) as f32 * CM_PER_M,
        worst_frame_mpjpe_cm: worst,
        frames: fitted.len(),
    })
}
