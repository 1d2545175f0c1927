//! Procedural motions in SMPL's pose space, for synthetic sequences.
//!
//! Poses are SMPL axis-angle vectors `[24 x 3]` (radians) in the body's local frames: with y up
//! and the body facing +z, a negative rotation about x swings a hanging limb forward, a
//! positive one bends a knee; a rotation about z lowers a T-pose arm (negative for the left
//! arm, positive for the right). The root entry (joint 0) stays zero, as in ZJU-MoCap, whose
//! global orientation and translation live in `Rh`/`Th`.

use std::f32::consts::TAU;

use glam::{Quat, Vec3};

/// Duration of one walking cycle (two steps), seconds.
pub const WALK_PERIOD_S: f32 = 1.1;

/// Duration of one arm-swing cycle (arms up and down once), seconds.
pub const ARM_SWING_PERIOD_S: f32 = 2.0;

/// Duration of one idle cycle (one breath and sway), seconds.
pub const IDLE_PERIOD_S: f32 = 3.0;

/// Angle that brings a T-pose arm down to hang beside the body (a little short of 90 degrees
/// so the hand clears the hip), radians.
const ARM_DOWN_RAD: f32 = 1.25;

/// The motions [`pose_for_motion`] knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionKind {
    /// Walking in place: legs stride, knees bend in the swing phase, arms swing opposite to
    /// the legs, the spine counter-rotates.
    Walk,
    /// Standing, both arms sweeping from beside the hips to above the shoulders and back.
    ArmSwing,
    /// Standing with arms down, breathing and swaying slightly.
    Idle,
}

impl MotionKind {
    /// Cycle length, seconds: poses repeat with this period.
    pub fn period_s(self) -> f32 {
        match self {
            MotionKind::Walk => WALK_PERIOD_S,
            MotionKind::ArmSwing => ARM_SWING_PERIOD_S,
            MotionKind::Idle => IDLE_PERIOD_S,
        }
    }
}

/// SMPL pose `[72]` (axis-angle per joint, radians, root zero) of motion `kind` at time `t`
/// seconds. Smooth and periodic in `t`; a non-finite `t` gives the pose at `t = 0`.
pub fn pose_for_motion(t: f32, kind: MotionKind) -> [f32; 72] {
    let t = if t.is_finite() { t } else { 0.0 };
    let phase = TAU * (t / kind.period_s()).fract();
    let (s, c) = phase.sin_cos();
    let mut pose = [0.0f32; 72];
    let mut set = |joint: usize, axis_angle: Vec3| {
        pose[3 * joint..3 * joint + 3].copy_from_slice(&axis_angle.to_array());
    };
    let arm = |swing_x: f32, down_z: f32| {
        let (axis, angle) =
            (Quat::from_rotation_x(swing_x) * Quat::from_rotation_z(down_z)).to_axis_angle();
        axis * angle
    };
    match kind {
        MotionKind::Walk => {
            let stride = 0.45;
            // Left hip flexes (negative about x) when sin > 0, the right one half a cycle later.
            set(1, Vec3::X * (-stride * s));
            set(2, Vec3::X * (stride * s));
            // Knees bend most while their leg swings forward (left hip flexion grows while
            // cos > 0, fastest at phase 0).
            let knee = |p: f32| 0.1 + 0.6 * (0.5 + 0.5 * (p + 0.3).cos()).powi(2);
            set(4, Vec3::X * knee(phase));
            set(5, Vec3::X * knee(phase + std::f32::consts::PI));
            set(7, Vec3::X * (0.15 * c));
            set(8, Vec3::X * (-0.15 * c));
            // Spine counter-rotation and a slight forward lean.
            set(3, Vec3::new(0.04, 0.0, 0.0));
            set(6, Vec3::Y * (0.08 * s));
            set(9, Vec3::Y * (0.04 * s));
            set(15, Vec3::Y * (-0.08 * s));
            // Arms hang and swing opposite to the legs on the same side.
            set(16, arm(0.35 * s, -ARM_DOWN_RAD));
            set(17, arm(-0.35 * s, ARM_DOWN_RAD));
            set(18, Vec3::Y * (-0.25 - 0.15 * s.max(0.0)));
            set(19, Vec3::Y * (0.25 + 0.15 * (-s).max(0.0)));
        }
        MotionKind::ArmSwing => {
            // Shoulder angle about z from -1.3 (arm down) to +0.5 (raised), left side.
            let raise = -0.4 - 0.9 * c;
            set(16, Vec3::Z * raise);
            set(17, Vec3::Z * -raise);
            set(18, Vec3::Y * (-0.2 - 0.2 * s.abs()));
            set(19, Vec3::Y * (0.2 + 0.2 * s.abs()));
            set(13, Vec3::Z * (0.1 * (raise + 0.4)));
            set(14, Vec3::Z * (-0.1 * (raise + 0.4)));
            set(4, Vec3::X * (0.05 + 0.05 * c));
            set(5, Vec3::X * (0.05 + 0.05 * c));
            set(12, Vec3::X * (0.05 * s));
        }
        MotionKind::Idle => {
            set(3, Vec3::X * (0.03 * s));
            set(9, Vec3::X * (-0.02 * s));
            set(6, Vec3::Z * (0.03 * c));
            set(15, Vec3::new(0.05 * s, 0.15 * c, 0.0));
            set(16, arm(0.05 * c, -ARM_DOWN_RAD - 0.05 * s));
            set(17, arm(-0.05 * c, ARM_DOWN_RAD + 0.05 * s));
            set(18, Vec3::Y * -0.15);
            set(19, Vec3::Y * 0.15);
        }
    }
    pose
}
