//! The fitter's settings: iteration counts, loss weights and robust scales, step sizes.
//! Pixel quantities are in the cameras' own pixels; weights are relative to the keypoint term
//! (whose value is a mean squared pixel error where residuals are small).

use super::FitError;

/// Settings of [`super::Fitter`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FitConfig {
    /// Adam steps of the global stage (orientation and translation on the torso keypoints)
    /// of a frame fitted from scratch.
    pub global_iterations: usize,
    /// Adam steps of the pose stage of a frame fitted from scratch.
    pub cold_iterations: usize,
    /// Adam steps of the pose stage of a frame warm-started from the previous one.
    pub warm_iterations: usize,
    /// Adam steps of the shape stage (betas with the poses of the shape frames, jointly).
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
    /// Weight of projected vertices' distance outside the mask.
    pub silhouette_out_weight: f32,
    /// Weight of mask boundary pixels' distance to the nearest projected vertex.
    pub silhouette_in_weight: f32,
    /// Weight of `|theta|^2` (L2 to the mean, zero, pose), per rad^2.
    pub pose_prior_weight: f32,
    /// Weight of the joint-limit hinge `max(0, -s theta_j)^2` (knees, elbows bending the wrong
    /// way), per rad^2.
    pub joint_limit_weight: f32,
    /// Weight of `|beta|^2`.
    pub shape_prior_weight: f32,
    /// Weight of `|theta - theta_prev|^2`, per rad^2.
    pub temporal_pose_weight: f32,
    /// Weight of `|Th - Th_prev|^2`, per m^2.
    pub temporal_translation_weight: f32,
    /// Adam step size of rotations (body pose and `Rh`), radians.
    pub lr_rotation: f32,
    /// Adam step size of `Th`, metres.
    pub lr_translation: f32,
    /// Adam step size of betas.
    pub lr_shape: f32,
    /// The step size decays linearly to this fraction of itself by a stage's last step.
    pub lr_final_fraction: f32,
}

impl Default for FitConfig {
    fn default() -> Self {
        Self {
            global_iterations: 40,
            cold_iterations: 150,
            warm_iterations: 60,
            shape_iterations: 120,
            shape_frames: 4,
            silhouette_vertices: 600,
            boundary_samples: 150,
            keypoint_sigma_px: 20.0,
            silhouette_sigma_px: 20.0,
            silhouette_out_weight: 0.2,
            silhouette_in_weight: 0.1,
            pose_prior_weight: 1.0,
            joint_limit_weight: 100.0,
            shape_prior_weight: 1.0,
            temporal_pose_weight: 5.0,
            temporal_translation_weight: 1e4,
            lr_rotation: 0.03,
            lr_translation: 0.02,
            lr_shape: 0.05,
            lr_final_fraction: 0.1,
        }
    }
}

impl FitConfig {
    /// Checks ranges: positive scales and step sizes, finite non-negative weights, at least
    /// one shape frame.
    pub fn validate(&self) -> Result<(), FitError> {
        let bad = |what: String| Err(FitError::Config(what));
        for (name, v) in [
            ("keypoint_sigma_px", self.keypoint_sigma_px),
            ("silhouette_sigma_px", self.silhouette_sigma_px),
            ("lr_rotation", self.lr_rotation),
            ("lr_translation", self.lr_translation),
            ("lr_shape", self.lr_shape),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("{name} = {v}, expected a positive number"));
            }
        }
        for (name, v) in [
            ("silhouette_out_weight", self.silhouette_out_weight),
            ("silhouette_in_weight", self.silhouette_in_weight),
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
                return bad(format!("{name} = {v}, expected a finite number >= 0"));
            }
        }
        if !(0.0..=1.0).contains(&self.lr_final_fraction) {
            return bad(format!(
                "lr_final_fraction = {}, expected [0, 1]",
                self.lr_final_fraction
            ));
        }
        if self.shape_frames == 0 {
            return bad("shape_frames = 0, expected at least 1".into());
        }
        Ok(())
    }
}
