//! The settings of the fits: [`SmplAlignment`] for the loader's alignment to the source masks
//! (`[data] smpl_alignment`) and [`FitConfig`] for `nia-train prepare`'s fitter. Pixel
//! quantities are in the cameras' own pixels.

use serde::{Deserialize, Serialize};

use super::FitError;

/// The alignment's settings (`[data] smpl_alignment`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SmplAlignment {
    /// Levenberg-Marquardt iterations (accepted or refused steps), at most.
    #[serde(default = "default_iterations")]
    pub iterations: usize,
    /// The robust scale `sigma`, metres at the body's depth (module docs).
    #[serde(default = "default_robust_m")]
    pub robust_m: f32,
    /// Largest translation of the correction, metres.
    #[serde(default = "default_max_translation_m")]
    pub max_translation_m: f32,
    /// Largest rotation of the correction, degrees.
    #[serde(default = "default_max_rotation_deg")]
    pub max_rotation_deg: f32,
    /// Boundary pixels sampled per mask.
    #[serde(default = "default_boundary_samples")]
    pub boundary_samples: usize,
    /// Vertices used (every k-th of the mesh so that at most this many remain).
    #[serde(default = "default_vertex_samples")]
    pub vertex_samples: usize,
    /// Levenberg-Marquardt iterations of the pose refinement after the rigid alignment
    /// ([`super::align`]); 0: rigid only.
    #[serde(default)]
    pub pose_iterations: usize,
    /// The same for training scenes (`None`: `pose_iterations`). A model trained on the rigid
    /// alignment alone still learns the fits' joint errors; the refinement then runs where
    /// images are rendered.
    #[serde(default)]
    pub train_pose_iterations: Option<usize>,
    /// The pose prior's scale `s`, degrees: a joint turned this far from the fit costs as much
    /// as one view's vertex term fully saturated.
    #[serde(default = "default_pose_prior_deg")]
    pub pose_prior_deg: f32,
    /// Largest rotation of a joint away from the fit, degrees.
    #[serde(default = "default_max_joint_deg")]
    pub max_joint_deg: f32,
}

fn default_iterations() -> usize {
    20
}
fn default_robust_m() -> f32 {
    0.03
}
fn default_max_translation_m() -> f32 {
    0.1
}
fn default_max_rotation_deg() -> f32 {
    10.0
}
fn default_boundary_samples() -> usize {
    400
}
fn default_vertex_samples() -> usize {
    2000
}
fn default_pose_prior_deg() -> f32 {
    40.0
}
fn default_max_joint_deg() -> f32 {
    15.0
}

impl Default for SmplAlignment {
    fn default() -> Self {
        SmplAlignment {
            iterations: default_iterations(),
            robust_m: default_robust_m(),
            max_translation_m: default_max_translation_m(),
            max_rotation_deg: default_max_rotation_deg(),
            boundary_samples: default_boundary_samples(),
            vertex_samples: default_vertex_samples(),
            pose_iterations: 0,
            train_pose_iterations: None,
            pose_prior_deg: default_pose_prior_deg(),
            max_joint_deg: default_max_joint_deg(),
        }
    }
}

/// `value` in `(0, max]` (NaN is not), else an error naming `field`.
fn in_range(field: &str, value: f32, max: f32, unit: &str) -> Result<(), FitError> {
    if value > 0.0 && value <= max {
        Ok(())
    } else {
        Err(FitError::invalid(
            field,
            format!("{unit} in (0, {max}]"),
            value,
        ))
    }
}

impl SmplAlignment {
    /// The settings a training scene is aligned with: `pose_iterations` replaced by
    /// `train_pose_iterations` where that is given.
    pub fn for_training(&self) -> SmplAlignment {
        SmplAlignment {
            pose_iterations: self.train_pose_iterations.unwrap_or(self.pose_iterations),
            ..*self
        }
    }

    /// The pose refinement runs for some scenes (training or rendered ones).
    pub fn refines_pose(&self) -> bool {
        self.pose_iterations > 0 || self.train_pose_iterations.is_some_and(|n| n > 0)
    }

    /// Every field in its range.
    pub fn validate(&self) -> Result<(), FitError> {
        if !(1..=1000).contains(&self.iterations) {
            return Err(FitError::invalid("iterations", "1..=1000", self.iterations));
        }
        in_range("robust_m", self.robust_m, 1.0, "metres")?;
        in_range("max_translation_m", self.max_translation_m, 1.0, "metres")?;
        in_range("max_rotation_deg", self.max_rotation_deg, 90.0, "degrees")?;
        if !(1..=100_000).contains(&self.boundary_samples) {
            return Err(FitError::invalid(
                "boundary_samples",
                "1..=100000",
                self.boundary_samples,
            ));
        }
        if !(1..=100_000).contains(&self.vertex_samples) {
            return Err(FitError::invalid(
                "vertex_samples",
                "1..=100000",
                self.vertex_samples,
            ));
        }
        if self.pose_iterations > 1000 {
            return Err(FitError::invalid(
                "pose_iterations",
                "0..=1000",
                self.pose_iterations,
            ));
        }
        if let Some(n) = self.train_pose_iterations.filter(|&n| n > 1000) {
            return Err(FitError::invalid("train_pose_iterations", "0..=1000", n));
        }
        in_range("pose_prior_deg", self.pose_prior_deg, 180.0, "degrees")?;
        in_range("max_joint_deg", self.max_joint_deg, 90.0, "degrees")?;
        Ok(())
    }
}

/// Settings of [`super::Fitter`]: Levenberg-Marquardt steps per stage, and the weights of the
/// energy's terms relative to the keypoint term (whose value is a mean squared pixel error where
/// residuals are small).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FitConfig {
    /// Steps of the global stage (the body moved rigidly onto the torso keypoints) of a frame
    /// fitted from scratch.
    pub global_iterations: usize,
    /// Steps of the pose stage of a frame fitted from scratch.
    pub cold_iterations: usize,
    /// Steps of the pose stage of a frame warm-started from the previous one.
    pub warm_iterations: usize,
    /// Steps of the shape stage (betas with the poses of the shape frames, jointly).
    pub shape_iterations: usize,
    /// Frames (evenly spaced) the subject's one shape is fitted on.
    pub shape_frames: usize,
    /// Vertices (a fixed, evenly spaced subset) the silhouette term projects.
    pub silhouette_vertices: usize,
    /// Mask boundary pixels (per view) the silhouette term pulls towards the body.
    pub boundary_samples: usize,
    /// Geman-McClure scale of the keypoint residuals, pixels: residuals well below it count
    /// quadratically, well above it (outliers) hardly at all.
    pub keypoint_sigma_px: f32,
    /// Geman-McClure scale of the silhouette distances, pixels.
    pub silhouette_sigma_px: f32,
    /// Weight of the hips', neck's and shoulders' keypoints in the pose and shape stages, on
    /// top of their confidence: a detector places them centimetres off SMPL's joints
    /// (`KeypointBinding::is_offset_prone`). 1 trusts them as the others; 0.1 was chosen on
    /// generator seed 32 (`zju_like`, offsets and lost runs; 1.0 / 0.3 / 0.1 / 0.03 / 0
    /// gave 3-view MPJPE 2.71 / 2.56 / 2.35 / 2.55 / 2.70 cm), docs/own-capture.md.
    pub offset_prone_weight: f32,
    /// Weight of projected vertices' distance outside the mask (averaged over the views with
    /// a mask).
    pub silhouette_out_weight: f32,
    /// Weight of mask boundary pixels' distance to the nearest projected vertex (averaged over
    /// the views with a mask).
    pub silhouette_in_weight: f32,
    /// Weight of `|theta|^2` (L2 to the mean, zero, pose), per rad^2.
    pub pose_prior_weight: f32,
    /// Weight of the joint-limit hinge `max(0, s theta_j)^2` (knees, elbows bending the wrong
    /// way), per rad^2.
    pub joint_limit_weight: f32,
    /// Weight of `|beta|^2`.
    pub shape_prior_weight: f32,
    /// Weight of `|theta - theta_prev|^2`, per rad^2.
    pub temporal_pose_weight: f32,
    /// Weight of `|Th - Th_prev|^2`, per m^2.
    pub temporal_translation_weight: f32,
}

impl Default for FitConfig {
    fn default() -> Self {
        Self {
            global_iterations: 20,
            cold_iterations: 40,
            warm_iterations: 20,
            shape_iterations: 30,
            shape_frames: 4,
            silhouette_vertices: 600,
            boundary_samples: 150,
            keypoint_sigma_px: 20.0,
            silhouette_sigma_px: 20.0,
            offset_prone_weight: 0.1,
            silhouette_out_weight: 0.2,
            silhouette_in_weight: 0.1,
            pose_prior_weight: 1.0,
            joint_limit_weight: 100.0,
            shape_prior_weight: 1.0,
            temporal_pose_weight: 5.0,
            temporal_translation_weight: 1e4,
        }
    }
}

impl FitConfig {
    /// Checks ranges: positive scales, finite non-negative weights, at least one shape frame,
    /// vertex and boundary sample.
    pub fn validate(&self) -> Result<(), FitError> {
        for (name, v) in [
            ("keypoint_sigma_px", self.keypoint_sigma_px),
            ("silhouette_sigma_px", self.silhouette_sigma_px),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(FitError::invalid(name, "a positive number", v));
            }
        }
        for (name, v) in [
            ("silhouette_out_weight", self.silhouette_out_weight),
            ("silhouette_in_weight", self.silhouette_in_weight),
            ("offset_prone_weight", self.offset_prone_weight),
            ("pose_prior_weight", self.pose_prior_weight),
            ("joint_limit_weight", self.joint_limit_weight),
            ("shape_prior_weight", self.shape_prior_weight),
            ("temporal_pose_weight", self.temporal_pose_weight),
            (
                "temporal_translation_weight",
                self.temporal_translation_weight,
            ),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(FitError::invalid(name, "a finite number >= 0", v));
            }
        }
        for (name, v) in [
            ("shape_frames", self.shape_frames),
            ("silhouette_vertices", self.silhouette_vertices),
            ("boundary_samples", self.boundary_samples),
        ] {
            if v == 0 {
                return Err(FitError::invalid(name, "at least 1", v));
            }
        }
        Ok(())
    }
}
