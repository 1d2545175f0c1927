//! Geometry off SMPL: real people carry hair and loose clothes that SMPL does not model. Hair has
//! volume on the head, and loose garments (a coat or shirt hem, wide sleeves, wide trousers or
//! shorts) stand centimetres off the body and swing as the person moves. The written SMPL stays
//! the naked body; the images show the body with this extra geometry, so they differ from what
//! SMPL says about them, as several ZJU-MoCap subjects' loose shorts and trousers and a few
//! subjects' long hair do.
//!
//! The extra geometry is an outward offset (metres) per vertex and frame, added to the garment
//! offset of [`crate::synth::clothing::garment_offset_m`] before the body is clothed, so it
//! moves vertices along their posed normals and keeps the mesh's topology. It is a smooth
//! function of the canonical position: it grows from zero inside a garment, rolls back in over
//! [`HEM_ROLL_M`] at the garment's cut edge, and is zero on bare skin, the belt and the shoes.
//!
//! Magnitudes at level 1 (`zju_like`), scaled linearly with the level:
//! - hair volume up to [`HAIR_M`] on the top and back of the head (half that for the shortest
//!   hair, [`FRONT_SHARE`] of it at the front), fading in over [`HAIR_FADE_M`] above the
//!   hairline: never on the face;
//! - trouser legs (and shorts) flare from zero at the knee (higher up for shorts) to
//!   [`TROUSER_M`] at the hem;
//! - sleeves flare from zero at the elbow (higher for short sleeves) to [`SLEEVE_M`] at the cuff;
//! - an untucked shirt or coat flares over the [`HEM_RISE_M`] above its hem to [`HEM_M`];
//! - the flares (not the hair) swing: each is scaled by `1 + SWING * sin(2 pi t / period +
//!   phase)`, with a period drawn per subject in [`PERIOD_S`] and a phase per body part, blended
//!   by the skinning weights so the surface stays smooth.
//!
//! These are estimates (hair 2-4 cm thick, loose trousers and skirts several centimetres off the
//! legs, as ZJU-MoCap's subjects show), not measurements of the dataset. On the quickstart spec's
//! subjects level 1 takes the clothed surface's mean distance from its SMPL vertex from 0.9-1.1
//! cm (the garments alone) to 1.4-1.6 cm, its maximum from 2.4-2.8 cm to 5.7-7.4 cm.

use std::f32::consts::TAU;

use glam::Vec3;

use crate::rng::Rng;
use crate::synth::clothing::{
    classify, smoothstep, BodyFrame, Cut, Garment, GarmentPoint, Part, PART_COUNT,
};

/// Hair volume on the top and back of the head at level 1 (longest hair), metres.
pub const HAIR_M: f32 = 0.03;
/// Share of the hair volume over the forehead (the front of the hairline).
pub const FRONT_SHARE: f32 = 0.4;
/// Height above the hairline over which the hair volume fades in, metres.
pub const HAIR_FADE_M: f32 = 0.06;
/// Trouser flare at the hem at level 1, metres.
pub const TROUSER_M: f32 = 0.04;
/// Sleeve flare at the cuff at level 1, metres.
pub const SLEEVE_M: f32 = 0.03;
/// Shirt or coat flare at the hem at level 1, metres.
pub const HEM_M: f32 = 0.03;
/// Height above the shirt's hem over which its flare grows, metres.
pub const HEM_RISE_M: f32 = 0.15;
/// Width of the band at a garment's cut edge over which the flare rolls back in to the body
/// (keeps the offset continuous where the garment ends), metres.
pub const HEM_ROLL_M: f32 = 0.03;
/// Relative amplitude of the swing of the flares.
pub const SWING: f32 = 0.3;
/// Range of the swing's period, seconds (drawn per subject).
pub const PERIOD_S: (f32, f32) = (0.8, 1.25);
/// Limb chain length over which a sleeve or trouser leg flares before its cuff or hem (about
/// the forearm or the shin: the flare starts at the elbow or knee of a long garment).
const FLARE_CHAIN: f32 = 0.85;
/// Earliest chain coordinate a sleeve's flare starts at (the shoulder stays on the body).
const ARM_FLARE_START: f32 = 0.25;
/// Earliest chain coordinate a trouser leg's flare starts at (the hip stays on the body).
const LEG_FLARE_START: f32 = 0.3;

/// Hair volume (metres, level 1) at a classified canonical point: zero off the hair.
pub fn hair_volume_m(frame: &BodyFrame, cut: &Cut, gp: &GarmentPoint) -> f32 {
    if gp.garment != Garment::Hair {
        return 0.0;
    }
    let head = frame.head();
    // The hairline's own front/back blend (`BodyFrame::hairline_y`): 1 over the forehead.
    let front = smoothstep(head.z - 0.02, frame.face_front_z - 0.03, gp.canonical.z);
    let region = 1.0 - (1.0 - FRONT_SHARE) * front;
    let length = 0.5 + 0.5 * cut.hair_length.clamp(0.0, 1.0);
    HAIR_M * length * region * smoothstep(0.0, HAIR_FADE_M, gp.edge_m)
}

/// Ramp along a limb chain from 0 where a sleeve's or trouser leg's flare starts to 1 at its
/// end (`end`, the cuff or hem), starting no earlier than `earliest`.
fn limb_ramp(chain: f32, end: f32, earliest: f32) -> f32 {
    let start = (end - FLARE_CHAIN).max(earliest).min(end - 0.1);
    smoothstep(start, end, chain)
}

/// Flare of a loose garment (metres, level 1, mean of the swing) at a classified canonical
/// point: zero on skin, hair, the belt and the shoes.
pub fn flare_m(frame: &BodyFrame, cut: &Cut, gp: &GarmentPoint) -> f32 {
    let grown = match (gp.garment, gp.part) {
        (Garment::Shirt, Part::LeftArm | Part::RightArm) => {
            SLEEVE_M * limb_ramp(gp.chain, cut.sleeve_end, ARM_FLARE_START)
        }
        // A tucked-in shirt does not flare.
        (Garment::Shirt, _) if cut.hem_below_waist_m > 0.0 => {
            let hem_y = frame.waist_y() - cut.hem_below_waist_m;
            HEM_M * smoothstep(hem_y + HEM_RISE_M, hem_y, gp.canonical.y)
        }
        (Garment::Trousers, Part::LeftLeg | Part::RightLeg) => {
            TROUSER_M * limb_ramp(gp.chain, cut.trouser_end, LEG_FLARE_START)
        }
        _ => 0.0,
    };
    grown * smoothstep(0.0, HEM_ROLL_M, gp.edge_m)
}

/// One subject's geometry off SMPL over its frames.
#[derive(Debug, Clone, PartialEq)]
pub struct LooseGeometry {
    /// The level it was drawn at; 0 adds nothing.
    level: f32,
    /// `[V]` hair volume at this level, metres (fixed in time).
    hair_m: Vec<f32>,
    /// `[V]` flare at this level at the swing's mean, metres.
    flare_m: Vec<f32>,
    /// `[V]` the swing's part phases blended by the skinning weights, as the coefficients of
    /// `sin(w t)` and `cos(w t)`: `sum_p w_p sin(w t + phase_p) = a sin(w t) + b cos(w t)`.
    swing: Vec<[f32; 2]>,
    /// Angular frequency of the swing, radians per second.
    omega: f32,
}

impl LooseGeometry {
    /// The geometry of a subject whose canonical vertices `[V]` have part weights `parts`
    /// `[V]`, on its `frame` and `cut`, at `level` (module docs); the swing's period and phases
    /// are drawn from `rng`. Level 0 draws nothing and adds nothing.
    pub fn draw(
        level: f32,
        frame: &BodyFrame,
        cut: &Cut,
        canonical: &[Vec3],
        parts: &[[f32; PART_COUNT]],
        rng: &mut Rng,
    ) -> Self {
        if level == 0.0 {
            return LooseGeometry {
                level,
                hair_m: Vec::new(),
                flare_m: Vec::new(),
                swing: Vec::new(),
                omega: 0.0,
            };
        }
        let period_s = rng.range(PERIOD_S.0, PERIOD_S.1);
        let phases: [f32; PART_COUNT] = std::array::from_fn(|_| rng.range(0.0, TAU));
        let (mut hair_m, mut flare) = (Vec::new(), Vec::new());
        let mut swing = Vec::with_capacity(canonical.len());
        for (&p, w) in canonical.iter().zip(parts) {
            let gp = classify(frame, cut, p, w);
            hair_m.push(level * hair_volume_m(frame, cut, &gp));
            flare.push(level * flare_m(frame, cut, &gp));
            let (mut a, mut b) = (0.0, 0.0);
            for (wp, phase) in w.iter().zip(phases) {
                a += wp * phase.cos();
                b += wp * phase.sin();
            }
            swing.push([a, b]);
        }
        LooseGeometry {
            level,
            hair_m,
            flare_m: flare,
            swing,
            omega: TAU / period_s,
        }
    }

    /// True when it adds nothing (level 0).
    pub fn is_off(&self) -> bool {
        self.level == 0.0
    }

    /// The extra outward offset `[V]` at time `t_s` (seconds), metres; all zeros at level 0.
    pub fn offsets_m(&self, t_s: f32, vertices: usize) -> Vec<f32> {
        if self.is_off() {
            return vec![0.0; vertices];
        }
        let (s, c) = (self.omega * t_s).sin_cos();
        self.hair_m
            .iter()
            .zip(&self.flare_m)
            .zip(&self.swing)
            .map(|((&hair, &flare), &[a, b])| hair + flare * (1.0 + SWING * (a * s + b * c)))
            .collect()
    }

    /// The garment offsets `garment_m` `[V]` with the extra offset at `t_s` added; at level 0
    /// exactly `garment_m`.
    pub fn clothing_offsets_m(&self, garment_m: &[f32], t_s: f32) -> Vec<f32> {
        if self.is_off() {
            return garment_m.to_vec();
        }
        garment_m
            .iter()
            .zip(self.offsets_m(t_s, garment_m.len()))
            .map(|(g, extra)| g + extra)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::{BodyModel, ProceduralBody, ProceduralSpec, SmplParams};
    use crate::synth::clothing::{dominant_part, part_weights};

    /// Largest change of the offset per metre between neighbouring vertices at level 1: the
    /// roll at a hem is the steepest part (1.5 * TROUSER_M / HEM_ROLL_M = 2), times the swing.
    const MAX_SLOPE: f32 = 1.5 * TROUSER_M / HEM_ROLL_M * (1.0 + SWING) + 0.2;
    /// Points each mesh edge is probed at for jumps of the offset within it.
    const PROBES: usize = 8;

    struct Body {
        model: BodyModel,
        canonical: Vec<Vec3>,
        parts: Vec<[f32; PART_COUNT]>,
        frame: BodyFrame,
    }

    fn body() -> Body {
        let model = ProceduralBody::generate(&ProceduralSpec {
            grid_step_m: 0.02,
            target_vertices: 2500,
            relax_iterations: 1,
            ..ProceduralSpec::default()
        })
        .unwrap();
        let rest = model.lbs(&SmplParams::default());
        let parts: Vec<_> = model.weights.iter().map(|w| part_weights(w)).collect();
        let frame = BodyFrame::new(&rest.rest_joints, &rest.v_shaped, &parts).unwrap();
        Body {
            model,
            canonical: rest.v_shaped,
            parts,
            frame,
        }
    }

    /// Long hair, long sleeves, an untucked shirt and long trousers.
    fn cut() -> Cut {
        Cut {
            sleeve_end: 1.8,
            trouser_end: 1.85,
            hem_below_waist_m: 0.08,
            v_neck_m: 0.0,
            hair_length: 1.0,
            shirt_ease_m: 0.01,
            shirt_flare_m: 0.01,
            trouser_ease_m: 0.01,
            trouser_flare_m: 0.01,
            wrinkle_m: 0.003,
            wrinkle_phase: 0.0,
        }
    }

    fn draw(b: &Body, level: f32, cut: &Cut) -> LooseGeometry {
        LooseGeometry::draw(
            level,
            &b.frame,
            cut,
            &b.canonical,
            &b.parts,
            &mut Rng::new(7),
        )
    }

    /// Along every mesh edge the offset of `g` (drawn at `level` for `cut`) at `t_s` changes
    /// by at most `level * MAX_SLOPE` per metre, between the vertices and between points in
    /// between (the offset as a function of the canonical position and the part weights): a
    /// jump would show as a steep step there.
    fn assert_continuous(b: &Body, cut: &Cut, g: &LooseGeometry, level: f32, t_s: f32) {
        let offsets = g.offsets_m(t_s, b.canonical.len());
        let slope = level * MAX_SLOPE;
        let (s, c) = (g.omega * t_s).sin_cos();
        let lerp = |x: f32, y: f32, u: f32| x + u * (y - x);
        for f in &b.model.faces {
            for k in 0..3 {
                let (i, j) = (f[k] as usize, f[(k + 1) % 3] as usize);
                let d = (b.canonical[i] - b.canonical[j]).length();
                let step = (offsets[i] - offsets[j]).abs();
                let name = |v: usize| classify(&b.frame, cut, b.canonical[v], &b.parts[v]);
                assert!(
                    step <= slope * d + 1e-4,
                    "offset steps {step} m over {d} m between {:?} and {:?}",
                    name(i),
                    name(j)
                );
                let at = |u: f32| {
                    let p = b.canonical[i].lerp(b.canonical[j], u);
                    let w = std::array::from_fn(|q| lerp(b.parts[i][q], b.parts[j][q], u));
                    let gp = classify(&b.frame, cut, p, &w);
                    let [sa, sb] = [0, 1].map(|q| lerp(g.swing[i][q], g.swing[j][q], u));
                    level
                        * (hair_volume_m(&b.frame, cut, &gp)
                            + flare_m(&b.frame, cut, &gp) * (1.0 + SWING * (sa * s + sb * c)))
                };
                let mut before = at(0.0);
                for q in 1..=PROBES {
                    let now = at(q as f32 / PROBES as f32);
                    assert!(
                        (now - before).abs() <= slope * d / PROBES as f32 + 1e-5,
                        "offset jumps {} m within the edge {:?} - {:?}",
                        (now - before).abs(),
                        name(i),
                        name(j)
                    );
                    before = now;
                }
            }
        }
    }

    #[test]
    fn level_zero_adds_nothing() {
        let b = body();
        let g = draw(&b, 0.0, &cut());
        assert!(g.is_off());
        let n = b.canonical.len();
        assert!(g.offsets_m(0.37, n).iter().all(|&o| o == 0.0));
        let garment: Vec<f32> = (0..n).map(|i| 0.001 * (i % 7) as f32).collect();
        assert_eq!(g.clothing_offsets_m(&garment, 1.3), garment);
    }

    /// At level 1 the head's top and the trousers' hem stand off by the stated amounts, bare
    /// skin (face, hands) never moves, the offset is continuous over the mesh, and the swing
    /// moves the flares between frames half a period apart.
    #[test]
    fn level_one_has_the_stated_size_on_garments_only_and_is_smooth() {
        let b = body();
        let cut = cut();
        let g = draw(&b, 1.0, &cut);
        let n = b.canonical.len();
        let classified: Vec<GarmentPoint> = b
            .canonical
            .iter()
            .zip(&b.parts)
            .map(|(&p, w)| classify(&b.frame, &cut, p, w))
            .collect();

        // The top of the head: the highest head vertex, hair all round.
        let top = (0..n)
            .filter(|&i| dominant_part(&b.parts[i]) == Part::Head)
            .max_by(|&i, &j| b.canonical[i].y.total_cmp(&b.canonical[j].y))
            .unwrap();
        assert_eq!(classified[top].garment, Garment::Hair);
        let hair_top = g.offsets_m(0.0, n)[top];
        assert!(
            (0.7 * HAIR_M..=HAIR_M).contains(&hair_top),
            "head top {hair_top} m"
        );
        assert_eq!(
            g.offsets_m(0.4, n)[top],
            hair_top,
            "the hair does not swing"
        );

        // The trouser hems: the largest flare sits near the hem, at about TROUSER_M.
        let (hem, hem_flare) = (0..n)
            .filter(|&i| classified[i].garment == Garment::Trousers)
            .map(|i| (i, g.flare_m[i]))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        assert!(
            (0.8 * TROUSER_M..=TROUSER_M).contains(&hem_flare),
            "trouser hem {hem_flare} m"
        );
        assert!(classified[hem].chain > 1.5, "{:?}", classified[hem]);

        // Bare skin never moves: the face and the hands among it.
        let times = [0.0, 0.21, 0.5];
        let per_time: Vec<Vec<f32>> = times.iter().map(|&t| g.offsets_m(t, n)).collect();
        let (mut face, mut hands) = (0, 0);
        for (i, gp) in classified.iter().enumerate() {
            if gp.garment != Garment::Skin {
                continue;
            }
            let p = gp.canonical;
            face += usize::from(gp.part == Part::Head && p.z > b.frame.head().z + 0.03);
            hands += usize::from(gp.chain > 2.2);
            for offsets in &per_time {
                assert_eq!(offsets[i], 0.0, "skin vertex {i} at {p} moved");
            }
        }
        assert!(face > 10 && hands > 10, "face {face}, hands {hands}");

        // Continuity, at the times the skin was checked at.
        for &t in &times {
            assert_continuous(&b, &cut, &g, 1.0, t);
        }

        // Half a period apart, the flares move by a good part of their swing.
        let half = std::f32::consts::PI / g.omega;
        let (a, c) = (g.offsets_m(0.3, n), g.offsets_m(0.3 + half, n));
        let moved = (0..n).map(|i| (a[i] - c[i]).abs()).fold(0.0, f32::max);
        assert!(
            moved > 0.5 * SWING * TROUSER_M,
            "the swing moved at most {moved} m"
        );
        assert!(a
            .iter()
            .zip(&c)
            .all(|(x, y)| (x - y).abs() <= 2.0 * SWING * TROUSER_M + 1e-6));
    }

    /// Short sleeves and shorts: the bare forearms and shins never move; a tucked-in shirt does
    /// not flare.
    #[test]
    fn bare_limbs_and_a_tucked_shirt_stay_on_the_body() {
        let b = body();
        let cut = Cut {
            sleeve_end: 0.5,
            trouser_end: 0.6,
            hem_below_waist_m: 0.0,
            hair_length: 0.0,
            ..cut()
        };
        let g = draw(&b, 2.0, &cut);
        let offsets = g.offsets_m(0.1, b.canonical.len());
        let mut flared = 0;
        for (i, (&p, w)) in b.canonical.iter().zip(&b.parts).enumerate() {
            let gp = classify(&b.frame, &cut, p, w);
            let arm_or_leg = matches!(
                gp.part,
                Part::LeftArm | Part::RightArm | Part::LeftLeg | Part::RightLeg
            );
            if gp.garment == Garment::Skin || gp.garment == Garment::Shoes {
                assert_eq!(offsets[i], 0.0, "{gp:?}");
            } else if gp.garment == Garment::Shirt && !arm_or_leg {
                assert_eq!(g.flare_m[i], 0.0, "a tucked shirt flared at {p}");
            }
            flared += usize::from(arm_or_leg && offsets[i] > 0.01);
        }
        assert!(flared > 0, "the short sleeves and shorts flare too");
        assert_continuous(&b, &cut, &g, 2.0, 0.1);
        // Short hair: half the volume.
        let hair = g.hair_m.iter().fold(0.0, |m: f32, &h| m.max(h));
        assert!(
            hair <= 2.0 * 0.5 * HAIR_M + 1e-6 && hair > 0.5 * HAIR_M,
            "{hair}"
        );
    }
}
