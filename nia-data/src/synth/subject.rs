//! One synthetic subject: its random draws (proportions, skin tone, outfit, motion, placement)
//! and everything derived from them that stays fixed over the frames (canonical body, garment
//! offsets), plus the per-frame SMPL parameters in ZJU-MoCap's convention.

use super::clothing::{classify, garment_offset_m, part_weights, BodyFrame, Cut, PART_COUNT};
use super::texture::{Fabric, Logo, Look, Pattern, Print, GLYPH_SEGMENT_COUNT};
use super::SynthError;
use crate::body::{pose_for_motion, BodyModel, MotionKind, SmplParams};
use crate::rng::Rng;
use glam::{Quat, Vec3};
use std::f32::consts::{FRAC_PI_2, TAU};

/// Number of shape coefficients written to `params/*.npy` (ZJU-MoCap's `shapes` is (1, 10)).
pub const NUM_BETAS: usize = 10;

/// Standard deviation of the first two betas (overall size and girth) and of the rest.
pub const BETA_MAJOR_STD: f32 = 1.0;
pub const BETA_MINOR_STD: f32 = 0.5;
/// Betas are clipped to +-this many standard units (beyond, bodies stop looking plausible).
pub const BETA_CLIP: f32 = 2.5;

/// Slow turning speed range, radians per second (either direction).
pub const TURN_RATE: (f32, f32) = (0.15, 0.5);
/// Sway of the body while walking in place, metres.
pub const SWAY_M: f32 = 0.04;

/// Skin tones from light to dark (sRGB); a subject's tone is drawn between two neighbours.
const SKIN_TONES: [[f32; 3]; 6] = [
    [0.96, 0.80, 0.69],
    [0.90, 0.71, 0.56],
    [0.78, 0.57, 0.42],
    [0.62, 0.44, 0.30],
    [0.45, 0.31, 0.21],
    [0.30, 0.20, 0.14],
];

const HAIR_COLOURS: [[f32; 3]; 6] = [
    [0.05, 0.04, 0.04],
    [0.18, 0.11, 0.07],
    [0.35, 0.22, 0.12],
    [0.75, 0.60, 0.35],
    [0.50, 0.20, 0.10],
    [0.55, 0.55, 0.55],
];

const TROUSER_COLOURS: [[f32; 3]; 6] = [
    [0.15, 0.22, 0.40],
    [0.08, 0.08, 0.09],
    [0.62, 0.55, 0.40],
    [0.35, 0.36, 0.38],
    [0.28, 0.32, 0.20],
    [0.45, 0.15, 0.12],
];

const SHOE_COLOURS: [[f32; 3]; 5] = [
    [0.08, 0.08, 0.08],
    [0.92, 0.92, 0.90],
    [0.35, 0.20, 0.10],
    [0.60, 0.10, 0.10],
    [0.15, 0.25, 0.55],
];

/// Parameters of a subject's motion (walking in place while slowly turning).
#[derive(Debug, Clone, PartialEq)]
pub struct MotionDesign {
    /// Phase offset of the gait cycle, in cycles [0, 1).
    pub phase: f32,
    /// Which motion of the motion helper the subject performs.
    pub kind: MotionKind,
    /// Cycle duration, seconds (the helper's period, slightly varied per subject).
    pub cycle_s: f32,
    /// Heading at frame 0, radians about world z.
    pub yaw0: f32,
    /// Turning rate, radians per second.
    pub yaw_rate: f32,
    /// Sway phase, radians.
    pub sway_phase: f32,
}

/// A subject's random draws.
#[derive(Debug, Clone, PartialEq)]
pub struct SubjectDesign {
    /// Folder id (`CoreView_<id>`).
    pub id: u32,
    /// [NUM_BETAS] shape coefficients.
    pub betas: Vec<f32>,
    pub look: Look,
    pub cut: Cut,
    pub motion: MotionDesign,
}

fn rgb(c: [f32; 3]) -> Vec3 {
    Vec3::from(c)
}

fn pick(rng: &mut Rng, palette: &[[f32; 3]]) -> Vec3 {
    rgb(palette[rng.below(palette.len())])
}

/// A colour of random hue, saturation and value drawn from the given ranges (HSV).
fn hue_colour(rng: &mut Rng, saturation: (f32, f32), value: (f32, f32)) -> Vec3 {
    let h = rng.uniform() * 6.0;
    let saturation = rng.range(saturation.0, saturation.1);
    let value = rng.range(value.0, value.1);
    let c = value * saturation;
    let x = c * (1.0 - ((h % 2.0) - 1.0).abs());
    let (r, g, b) = match h as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    Vec3::new(r, g, b) + Vec3::splat(value - c)
}

fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.299, 0.587, 0.114))
}

/// A colour contrasting with `c`: near-white on dark colours, near-black on light ones.
fn contrasting(rng: &mut Rng, c: Vec3) -> Vec3 {
    if luminance(c) < 0.5 {
        Vec3::splat(rng.range(0.85, 0.97))
    } else {
        Vec3::splat(rng.range(0.03, 0.15))
    }
}

/// Ink for the shirt prints: of near-white, near-black and a bright colour, the one farthest
/// from both fabric colours, so the print reads on any pattern.
fn print_ink(rng: &mut Rng, shirt: &Fabric) -> Vec3 {
    let candidates = [
        Vec3::splat(rng.range(0.88, 0.97)),
        Vec3::splat(rng.range(0.03, 0.1)),
        hue_colour(rng, (0.8, 1.0), (0.85, 1.0)),
    ];
    let separation = |c: &Vec3| c.distance(shirt.base).min(c.distance(shirt.accent));
    let mut best = candidates[0];
    for c in &candidates[1..] {
        if separation(c) > separation(&best) {
            best = *c;
        }
    }
    best
}

fn draw_pattern(rng: &mut Rng, allow_bold: bool) -> Pattern {
    match rng.below(if allow_bold { 5 } else { 3 }) {
        0 => Pattern::Plain,
        1 => Pattern::Pinstripes {
            period_m: rng.range(0.015, 0.03),
            width_m: rng.range(0.002, 0.004),
        },
        2 => Pattern::Checks {
            period_m: rng.range(0.02, 0.05),
        },
        3 => Pattern::Stripes {
            period_m: rng.range(0.025, 0.06),
            duty: rng.range(0.3, 0.6),
        },
        _ => Pattern::Dots {
            spacing_m: rng.range(0.03, 0.055),
            radius_m: rng.range(0.006, 0.012),
        },
    }
}

fn draw_glyph(rng: &mut Rng) -> u32 {
    loop {
        let mut mask = 0u32;
        for i in 0..GLYPH_SEGMENT_COUNT {
            if rng.uniform() < 0.28 {
                mask |= 1 << i;
            }
        }
        if (3..=8).contains(&mask.count_ones()) {
            return mask;
        }
    }
}

fn draw_print(rng: &mut Rng, ink: Vec3) -> Print {
    let lines = 1 + rng.below(2);
    let lines = (0..lines)
        .map(|_| (0..3 + rng.below(5)).map(|_| draw_glyph(rng)).collect())
        .collect();
    let glyph_h_m = rng.range(0.03, 0.045);
    let logo = match rng.below(4) {
        0 => None,
        1 => Some(Logo::Ring),
        2 => Some(Logo::Star(5 + rng.below(3) as u32)),
        _ => Some(Logo::Sectors(4 + 2 * rng.below(3) as u32)),
    };
    Print {
        lines,
        glyph_h_m,
        stroke_m: glyph_h_m * rng.range(0.16, 0.24),
        logo,
        logo_radius_m: rng.range(0.03, 0.05),
        ink,
        height_above_waist_m: rng.range(0.22, 0.3),
    }
}

fn draw_back_print(rng: &mut Rng, ink: Vec3) -> Option<Print> {
    if rng.uniform() < 0.5 {
        return None;
    }
    let glyph_h_m = rng.range(0.1, 0.14);
    Some(Print {
        lines: vec![(0..1 + rng.below(2)).map(|_| draw_glyph(rng)).collect()],
        glyph_h_m,
        stroke_m: glyph_h_m * 0.18,
        logo: None,
        logo_radius_m: 0.0,
        ink,
        height_above_waist_m: rng.range(0.18, 0.24),
    })
}

impl SubjectDesign {
    /// Draw a subject from its own random stream.
    pub fn draw(id: u32, rng: &mut Rng) -> Self {
        let betas = (0..NUM_BETAS)
            .map(|i| {
                let std = if i < 2 {
                    BETA_MAJOR_STD
                } else {
                    BETA_MINOR_STD
                };
                (rng.normal() * std).clamp(-BETA_CLIP * std, BETA_CLIP * std)
            })
            .collect();

        let tone = rng.uniform() * (SKIN_TONES.len() - 1) as f32;
        let (i0, t) = (tone.floor() as usize, tone.fract());
        let skin = rgb(SKIN_TONES[i0]).lerp(rgb(SKIN_TONES[(i0 + 1).min(SKIN_TONES.len() - 1)]), t);
        let hair = pick(rng, &HAIR_COLOURS);

        let shirt_base = hue_colour(rng, (0.3, 0.85), (0.35, 0.95));
        let shirt_accent = if rng.uniform() < 0.5 {
            contrasting(rng, shirt_base)
        } else {
            hue_colour(rng, (0.4, 0.9), (0.3, 0.95))
        };
        let shirt = Fabric {
            base: shirt_base,
            accent: shirt_accent,
            pattern: draw_pattern(rng, true),
            seed: rng.next_u64(),
        };
        let trouser_base = pick(rng, &TROUSER_COLOURS);
        let trousers = Fabric {
            base: trouser_base,
            accent: trouser_base.lerp(contrasting(rng, trouser_base), 0.35),
            pattern: draw_pattern(rng, false),
            seed: rng.next_u64(),
        };
        let ink = print_ink(rng, &shirt);
        let front_print = draw_print(rng, ink);
        let back_print = draw_back_print(rng, ink);
        let shoes = pick(rng, &SHOE_COLOURS);
        let look = Look {
            skin,
            hair,
            lips: skin * Vec3::new(0.85, 0.55, 0.55),
            shirt,
            trousers,
            shoes,
            sole: if luminance(shoes) > 0.5 {
                Vec3::splat(0.25)
            } else {
                Vec3::splat(0.9)
            },
            belt: Vec3::new(
                rng.range(0.1, 0.35),
                rng.range(0.06, 0.2),
                rng.range(0.03, 0.1),
            ),
            buckle: Vec3::new(0.78, 0.74, 0.6),
            thread: shirt_base.lerp(contrasting(rng, shirt_base), 0.6),
            front_print,
            back_print,
            seed: rng.next_u64(),
        };

        let sleeve_end = match rng.below(3) {
            0 => rng.range(0.35, 0.6),
            1 => rng.range(1.2, 1.45),
            _ => rng.range(1.75, 1.9),
        };
        let trouser_end = match rng.below(5) {
            0 => rng.range(0.45, 0.7),
            1 => rng.range(1.3, 1.5),
            _ => rng.range(1.78, 1.88),
        };
        let cut = Cut {
            sleeve_end,
            trouser_end,
            hem_below_waist_m: if rng.uniform() < 0.35 {
                0.0
            } else {
                rng.range(0.04, 0.12)
            },
            v_neck_m: if rng.uniform() < 0.5 {
                0.0
            } else {
                rng.range(0.03, 0.08)
            },
            hair_length: rng.uniform(),
            shirt_ease_m: rng.range(0.006, 0.015),
            shirt_flare_m: rng.range(0.004, 0.015),
            trouser_ease_m: rng.range(0.006, 0.013),
            trouser_flare_m: rng.range(0.0, 0.014),
            wrinkle_m: rng.range(0.002, 0.005),
            wrinkle_phase: rng.range(0.0, TAU),
        };

        let turn = rng.range(TURN_RATE.0, TURN_RATE.1);
        let kind = match rng.below(20) {
            0..=11 => MotionKind::Walk,
            12..=16 => MotionKind::ArmSwing,
            _ => MotionKind::Idle,
        };
        let motion = MotionDesign {
            phase: rng.uniform(),
            kind,
            cycle_s: kind.period_s() * rng.range(0.9, 1.15),
            yaw0: rng.range(0.0, TAU),
            yaw_rate: if rng.uniform() < 0.5 { turn } else { -turn },
            sway_phase: rng.range(0.0, TAU),
        };
        SubjectDesign {
            id,
            betas,
            look,
            cut,
            motion,
        }
    }
}

/// A subject ready to pose and render: its design plus the per-vertex canonical data.
#[derive(Debug, Clone)]
pub struct Subject {
    pub design: SubjectDesign,
    /// [V] shaped rest-pose vertices, metres (SMPL canonical space, y up).
    pub canonical: Vec<Vec3>,
    /// [V] skinning weights summed per body part.
    pub parts: Vec<[f32; PART_COUNT]>,
    /// [V] garment offset along the posed normal, metres.
    pub offsets_m: Vec<f32>,
    pub frame: BodyFrame,
    /// Canonical height of the foot sole below the root, so `Th.z` stands the body on z = 0.
    pub stand_height_m: f32,
    /// Standing height of the body (sole to crown), metres.
    pub body_height_m: f32,
}

impl Subject {
    /// Derive the canonical data of `design` on `body`.
    pub fn prepare(body: &BodyModel, design: SubjectDesign) -> Result<Self, SynthError> {
        let rest = body.lbs(&SmplParams {
            shapes: design.betas.clone(),
            ..SmplParams::default()
        });
        let parts: Vec<[f32; PART_COUNT]> = body.weights.iter().map(|w| part_weights(w)).collect();
        let frame = BodyFrame::new(&rest.rest_joints, &rest.v_shaped, &parts).ok_or_else(|| {
            SynthError::Subject {
                id: design.id,
                msg: format!(
                    "the body model needs 24 joints and at least one vertex (has {} joints, {} vertices)",
                    rest.rest_joints.len(),
                    rest.v_shaped.len()
                ),
            }
        })?;
        let offsets_m = rest
            .v_shaped
            .iter()
            .zip(&parts)
            .map(|(&p, w)| {
                garment_offset_m(&frame, &design.cut, &classify(&frame, &design.cut, p, w))
            })
            .collect();
        let body_height_m = frame.head_top_y - frame.sole_y;
        Ok(Subject {
            stand_height_m: -frame.sole_y,
            body_height_m,
            canonical: rest.v_shaped,
            parts,
            offsets_m,
            frame,
            design,
        })
    }

    /// Body pose `[72]` at time `t_s` (axis-angle per joint, root zero as in ZJU-MoCap: the
    /// global orientation is [`Subject::rh`]).
    pub fn poses(&self, t_s: f32) -> [f32; 72] {
        let m = &self.design.motion;
        let t_motion = (t_s / m.cycle_s + m.phase) * m.kind.period_s();
        let mut poses = pose_for_motion(t_motion, m.kind);
        poses[..3].fill(0.0);
        poses
    }

    /// Global rotation at time `t_s`: SMPL's y-up body stood up in the z-up world
    /// (a +90 degree turn about x) and turned by the heading about world z. Axis-angle.
    pub fn rh(&self, t_s: f32) -> Vec3 {
        let m = &self.design.motion;
        let yaw = m.yaw0 + m.yaw_rate * t_s;
        (Quat::from_rotation_z(yaw) * Quat::from_rotation_x(FRAC_PI_2)).to_scaled_axis()
    }

    /// Global translation at time `t_s`, metres: walking in place with a small sway, feet on
    /// the floor z = 0.
    pub fn th(&self, t_s: f32) -> Vec3 {
        let m = &self.design.motion;
        let w = TAU / (2.0 * m.cycle_s);
        Vec3::new(
            SWAY_M * (w * t_s + m.sway_phase).sin(),
            0.5 * SWAY_M * (0.5 * w * t_s + 1.3 * m.sway_phase).cos(),
            self.stand_height_m,
        )
    }
}
