//! Procedural appearance of a subject: skin, hair, fabric patterns (stripes, checks, dots,
//! pinstripes), chest and back prints made of glyph-like strokes and a logo, seams with stitch
//! dashes, hems, a belt and shoes.
//!
//! Colours are evaluated per pixel at a [`GarmentPoint`] (canonical body coordinates interpolated
//! by the rasteriser), so the pattern is attached to the body surface and moves with it. The
//! detail is deliberately high-frequency (millimetre to centimetre scale): it is what image-based
//! rendering keeps and a blurry radiance field loses.

use super::clothing::{smoothstep, BodyFrame, Garment, GarmentPoint, Part, ARM_RADIUS_M};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Width of a seam line, metres.
pub const SEAM_WIDTH_M: f32 = 0.004;
/// Distance of the stitch row from the seam centre, metres.
pub const STITCH_OFFSET_M: f32 = 0.007;
/// Stitch dash width across the seam, and period along it, metres.
pub const STITCH_WIDTH_M: f32 = 0.0025;
pub const STITCH_PERIOD_M: f32 = 0.012;
/// Width of the folded hem band at cuffs and shirt bottoms, metres.
pub const HEM_WIDTH_M: f32 = 0.018;

/// SplitMix64 finaliser: a well-mixed 64-bit hash.
pub(crate) fn mix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// Deterministic hash of a lattice cell to [0, 1).
fn hash_unit(seed: u64, a: i64, b: i64) -> f32 {
    let h = mix64(seed ^ mix64(a as u64 ^ mix64(b as u64).rotate_left(29)));
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// Smooth value noise in [0, 1) with unit cell size.
fn value_noise(seed: u64, p: Vec2) -> f32 {
    let (ix, iy) = (p.x.floor(), p.y.floor());
    let (fx, fy) = (p.x - ix, p.y - iy);
    let (ix, iy) = (ix as i64, iy as i64);
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let a = hash_unit(seed, ix, iy);
    let b = hash_unit(seed, ix + 1, iy);
    let c = hash_unit(seed, ix, iy + 1);
    let d = hash_unit(seed, ix + 1, iy + 1);
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

fn frac(x: f32) -> f32 {
    x - x.floor()
}

/// A fabric pattern over garment coordinates (metres along, metres around).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pattern {
    /// Uniform colour (seams, hems and prints still show).
    Plain,
    /// Bands across the garment, `period_m` apart; `duty` is the accent fraction.
    Stripes { period_m: f32, duty: f32 },
    /// Gingham: accent bands both ways, full accent where they cross.
    Checks { period_m: f32 },
    /// Polka dots on a jittered lattice.
    Dots { spacing_m: f32, radius_m: f32 },
    /// Thin lines running along the garment.
    Pinstripes { period_m: f32, width_m: f32 },
}

/// A fabric: two colours (sRGB in [0, 1]) and a pattern.
#[derive(Debug, Clone, PartialEq)]
pub struct Fabric {
    pub base: Vec3,
    pub accent: Vec3,
    pub pattern: Pattern,
    /// Seed of the jitter and the weave grain.
    pub seed: u64,
}

impl Fabric {
    /// Albedo at garment coordinates, metres.
    pub fn albedo(&self, along_m: f32, around_m: f32) -> Vec3 {
        let colour = match self.pattern {
            Pattern::Plain => self.base,
            Pattern::Stripes { period_m, duty } => {
                if frac(along_m / period_m) < duty {
                    self.accent
                } else {
                    self.base
                }
            }
            Pattern::Checks { period_m } => {
                let a = frac(along_m / period_m) < 0.5;
                let b = frac(around_m / period_m) < 0.5;
                match (a, b) {
                    (true, true) => self.accent,
                    (false, false) => self.base,
                    _ => self.base.lerp(self.accent, 0.5),
                }
            }
            Pattern::Dots {
                spacing_m,
                radius_m,
            } => {
                let q = Vec2::new(around_m, along_m) / spacing_m;
                let cell = q.floor();
                let (cx, cy) = (cell.x as i64, cell.y as i64);
                let jitter = Vec2::new(
                    hash_unit(self.seed, cx, cy * 3 + 1),
                    hash_unit(self.seed ^ 0x55, cx, cy * 3 + 2),
                );
                let centre = cell + Vec2::splat(0.25) + 0.5 * jitter;
                if (q - centre).length() * spacing_m < radius_m {
                    self.accent
                } else {
                    self.base
                }
            }
            Pattern::Pinstripes { period_m, width_m } => {
                let d = (frac(around_m / period_m) - 0.5).abs() * period_m;
                if d < 0.5 * width_m {
                    self.accent
                } else {
                    self.base
                }
            }
        };
        // Weave grain: a faint 3 mm texture.
        let grain = value_noise(self.seed ^ 0x6A6A, Vec2::new(along_m, around_m) / 0.003);
        colour * (0.94 + 0.12 * grain)
    }
}

/// Glyph stroke grid: 3 columns x 5 rows of nodes (column, row from the top); segments join
/// neighbouring nodes, plus the diagonals of the upper and lower squares.
const GLYPH_SEGMENTS: [((u8, u8), (u8, u8)); 18] = [
    ((0, 0), (1, 0)),
    ((1, 0), (2, 0)),
    ((0, 2), (1, 2)),
    ((1, 2), (2, 2)),
    ((0, 4), (1, 4)),
    ((1, 4), (2, 4)),
    ((0, 0), (0, 1)),
    ((0, 1), (0, 2)),
    ((0, 2), (0, 3)),
    ((0, 3), (0, 4)),
    ((2, 0), (2, 1)),
    ((2, 1), (2, 2)),
    ((2, 2), (2, 3)),
    ((2, 3), (2, 4)),
    ((0, 0), (2, 2)),
    ((2, 0), (0, 2)),
    ((0, 2), (2, 4)),
    ((2, 2), (0, 4)),
];

/// Number of strokes a glyph can draw from.
pub const GLYPH_SEGMENT_COUNT: usize = GLYPH_SEGMENTS.len();

/// Glyph cell width / height.
const GLYPH_ASPECT: f32 = 0.6;
/// Gap between glyphs, in glyph heights.
const GLYPH_GAP: f32 = 0.25;
/// Line pitch, in glyph heights.
const LINE_PITCH: f32 = 1.5;

fn segment_distance(p: Vec2, a: Vec2, b: Vec2) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
    (p - (a + ab * t)).length()
}

/// Ink of one glyph (bit `i` of `mask` draws segment `i`) at `p` in glyph cell units
/// (x in [0, GLYPH_ASPECT], y in [0, 1] downwards), stroke width `stroke` in the same units.
fn glyph_ink(mask: u32, p: Vec2, stroke: f32) -> bool {
    let node = |(c, r): (u8, u8)| Vec2::new(c as f32 * 0.5 * GLYPH_ASPECT, r as f32 * 0.25);
    GLYPH_SEGMENTS.iter().enumerate().any(|(i, &(a, b))| {
        mask & (1 << i) != 0 && segment_distance(p, node(a), node(b)) < 0.5 * stroke
    })
}

/// A logo shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Logo {
    /// A ring with a filled dot inside.
    Ring,
    /// A star with this many points.
    Star(u32),
    /// A disc split into alternating sectors.
    Sectors(u32),
}

impl Logo {
    /// Whether `p` (relative to the logo centre, in units of the logo radius) is inked.
    fn ink(&self, p: Vec2) -> bool {
        let r = p.length();
        if r > 1.0 {
            return false;
        }
        let theta = p.y.atan2(p.x);
        match *self {
            Logo::Ring => (0.75..=1.0).contains(&r) || r < 0.35,
            Logo::Star(n) => {
                let k = n.max(3) as f32;
                let wave = (frac(theta * k / (2.0 * PI)) - 0.5).abs() * 2.0;
                r < 0.4 + 0.6 * wave * wave
            }
            Logo::Sectors(n) => {
                let k = n.max(2) as f32;
                ((theta + PI) * k / (2.0 * PI)).floor() as i64 % 2 == 0 || r > 0.85
            }
        }
    }
}

/// A print: a logo above lines of glyph-like text, in its own 2D coordinates (metres; u to the
/// print's right, v up), placed on the chest or the back.
#[derive(Debug, Clone, PartialEq)]
pub struct Print {
    /// Glyph stroke masks (bits over [`GLYPH_SEGMENT_COUNT`] segments), one inner vec per line.
    pub lines: Vec<Vec<u32>>,
    /// Glyph height, metres.
    pub glyph_h_m: f32,
    /// Stroke width, metres.
    pub stroke_m: f32,
    pub logo: Option<Logo>,
    /// Logo radius, metres.
    pub logo_radius_m: f32,
    pub ink: Vec3,
    /// Print centre height above the waist, metres (canonical).
    pub height_above_waist_m: f32,
}

impl Print {
    /// Ink colour at print coordinates (u, v) metres relative to the print's top centre.
    fn ink_at(&self, u: f32, v: f32) -> Option<Vec3> {
        let mut top = 0.0;
        if let Some(logo) = self.logo {
            let centre = Vec2::new(0.0, -self.logo_radius_m);
            if logo.ink((Vec2::new(u, v) - centre) / self.logo_radius_m) {
                return Some(self.ink);
            }
            top = -2.0 * self.logo_radius_m - 0.4 * self.glyph_h_m;
        }
        let h = self.glyph_h_m;
        for (l, line) in self.lines.iter().enumerate() {
            let line_top = top - l as f32 * LINE_PITCH * h;
            let y = (line_top - v) / h;
            if !(0.0..=1.0).contains(&y) || line.is_empty() {
                continue;
            }
            let pitch = GLYPH_ASPECT + GLYPH_GAP;
            let width = line.len() as f32 * pitch - GLYPH_GAP;
            let x = u / h + 0.5 * width;
            if x < 0.0 || x > width {
                return None;
            }
            let k = (x / pitch).floor() as usize;
            let local = Vec2::new(x - k as f32 * pitch, y);
            if k < line.len() && glyph_ink(line[k], local, self.stroke_m / h) {
                return Some(self.ink);
            }
            return None;
        }
        None
    }

    /// Total height of the print (logo plus lines), metres.
    pub fn height_m(&self) -> f32 {
        let logo = if self.logo.is_some() {
            2.0 * self.logo_radius_m + 0.4 * self.glyph_h_m
        } else {
            0.0
        };
        logo + self.lines.len() as f32 * LINE_PITCH * self.glyph_h_m
    }
}

/// A subject's colours and patterns.
#[derive(Debug, Clone, PartialEq)]
pub struct Look {
    pub skin: Vec3,
    pub hair: Vec3,
    pub lips: Vec3,
    pub shirt: Fabric,
    pub trousers: Fabric,
    pub shoes: Vec3,
    pub sole: Vec3,
    pub belt: Vec3,
    pub buckle: Vec3,
    /// Stitch thread colour.
    pub thread: Vec3,
    /// Print on the shirt front.
    pub front_print: Print,
    /// Print on the shirt back (a jersey number), if any.
    pub back_print: Option<Print>,
    /// Seed of the skin and hair variation.
    pub seed: u64,
}

/// Darkening factor of a seam line and the stitch colour weight beside it, at signed distance
/// `d_m` from the seam centre and position `along_m` along it.
fn seam(d_m: f32, along_m: f32) -> Option<f32> {
    let d = d_m.abs();
    if d < 0.5 * SEAM_WIDTH_M {
        return Some(0.55);
    }
    let stitch =
        (d - STITCH_OFFSET_M).abs() < 0.5 * STITCH_WIDTH_M && frac(along_m / STITCH_PERIOD_M) < 0.6;
    if stitch {
        Some(-1.0)
    } else {
        None
    }
}

impl Look {
    /// Albedo (sRGB in [0, 1]) at a classified canonical surface point.
    pub fn albedo(&self, frame: &BodyFrame, gp: &GarmentPoint) -> Vec3 {
        let p = gp.canonical;
        match gp.garment {
            Garment::Skin => self.skin_albedo(frame, gp),
            Garment::Hair => {
                // Strands: fine streaks around the head, broken by noise along them.
                let strand = value_noise(
                    self.seed ^ 0x4A1,
                    Vec2::new(gp.around_m / 0.002, p.y / 0.03),
                );
                let shine = smoothstep(0.55, 0.95, strand);
                (self.hair * (0.75 + 0.35 * strand))
                    .lerp(self.hair * 1.6 + Vec3::splat(0.05), 0.25 * shine)
            }
            Garment::Shirt => self.shirt_albedo(frame, gp),
            Garment::Trousers => self.trouser_albedo(frame, gp),
            Garment::Belt => {
                let front = gp.angle.abs() * 0.15;
                let mid = (gp.edge_m - 0.5 * super::clothing::BELT_WIDTH_M).abs();
                if front < 0.025 && mid < 0.016 {
                    // Buckle: a frame with a darker centre.
                    if front < 0.014 && mid < 0.007 {
                        self.belt
                    } else {
                        self.buckle
                    }
                } else {
                    let holes =
                        (front - 0.06).abs() < 0.025 && frac(front / 0.012) < 0.35 && mid < 0.003;
                    if holes {
                        self.belt * 0.3
                    } else {
                        self.belt
                    }
                }
            }
            Garment::Shoes => {
                if p.y < frame.sole_y + 0.022 {
                    self.sole
                } else {
                    // Laces: a zigzag on the top of the foot.
                    let top = gp.angle.abs() < 0.5 && gp.chain > 2.15 && gp.chain < 2.75;
                    let zig = (frac(gp.chain * 9.0) - 0.5).abs() * 2.0;
                    if top && (gp.angle.abs() / 0.5 - zig).abs() < 0.22 {
                        self.sole
                    } else {
                        self.shoes
                    }
                }
            }
        }
    }

    fn skin_albedo(&self, frame: &BodyFrame, gp: &GarmentPoint) -> Vec3 {
        let p = gp.canonical;
        let blotch = value_noise(self.seed ^ 0x5C1, Vec2::new(p.x + p.z, p.y) / 0.04);
        let skin = self.skin * (0.93 + 0.1 * blotch);
        if gp.part != Part::Head {
            return skin;
        }
        // Face features on the front of the head, placed relative to the head joint and top.
        let head = frame.head();
        let hh = (frame.head_top_y - head.y).max(0.05);
        let front = p.z > frame.face_front_z - 0.35 * hh;
        if !front {
            return skin;
        }
        let dx = p.x - head.x;
        let eye_y = head.y + 0.36 * hh;
        let eye = Vec2::new(
            (dx.abs() - 0.19 * hh) / (0.085 * hh),
            (p.y - eye_y) / (0.045 * hh),
        );
        if eye.length() < 1.0 {
            return if eye.length() < 0.5 {
                Vec3::splat(0.05)
            } else {
                Vec3::splat(0.9)
            };
        }
        let brow = Vec2::new(
            (dx.abs() - 0.19 * hh) / (0.11 * hh),
            (p.y - eye_y - 0.11 * hh) / (0.025 * hh),
        );
        if brow.length() < 1.0 {
            return self.hair;
        }
        let mouth = Vec2::new(dx / (0.13 * hh), (p.y - (head.y - 0.04 * hh)) / (0.03 * hh));
        if mouth.length() < 1.0 {
            return self.lips;
        }
        skin
    }

    fn shirt_albedo(&self, frame: &BodyFrame, gp: &GarmentPoint) -> Vec3 {
        let p = gp.canonical;
        let mut c = self.shirt.albedo(gp.along_m, gp.around_m);
        // Prints on the torso front and back.
        if gp.part == Part::Torso {
            let u = p.x - frame.joints[0].x;
            let front = p.z > frame.torso_axis_z;
            let print = if front {
                Some(&self.front_print)
            } else {
                self.back_print.as_ref()
            };
            if let Some(print) = print {
                let top = frame.waist_y() + print.height_above_waist_m + 0.5 * print.height_m();
                let u = if front { u } else { -u };
                if let Some(ink) = print.ink_at(u, p.y - top) {
                    c = ink;
                }
            }
        }
        // Seams: torso side seams and centre back, sleeve armhole and underarm seams.
        let seam_hit = match gp.part {
            Part::Torso => {
                let side = (gp.angle.abs() - 0.5 * PI) * super::clothing::TORSO_RADIUS_M;
                let back = (PI - gp.angle.abs()) * super::clothing::TORSO_RADIUS_M;
                seam(side, gp.along_m).or_else(|| seam(back, gp.along_m))
            }
            Part::LeftArm | Part::RightArm => {
                let under = (PI - gp.angle.abs()) * ARM_RADIUS_M;
                seam(gp.along_m - 0.03, gp.around_m).or_else(|| seam(under, gp.along_m))
            }
            _ => None,
        };
        c = self.apply_seam(c, seam_hit);
        self.hem(c, gp)
    }

    fn trouser_albedo(&self, frame: &BodyFrame, gp: &GarmentPoint) -> Vec3 {
        let p = gp.canonical;
        let mut c = self.trousers.albedo(gp.along_m, gp.around_m);
        let seam_hit = match gp.part {
            Part::LeftLeg | Part::RightLeg => {
                let out = (gp.angle.abs() - 0.5 * PI) * super::clothing::LEG_RADIUS_M;
                seam(out, gp.along_m)
            }
            _ => {
                // Fly at the front centre, back pockets behind.
                let fly = (p.x - frame.joints[0].x) - 0.012;
                let front = p.z > frame.torso_axis_z && p.y > frame.joints[0].y - 0.06;
                let fly_hit = if front { seam(fly, p.y) } else { None };
                fly_hit.or_else(|| {
                    if p.z >= frame.torso_axis_z {
                        return None;
                    }
                    let u = (p.x - frame.joints[0].x).abs() - 0.09;
                    let v = p.y - (frame.waist_y() - 0.13);
                    let (hw, hh) = (0.06, 0.065);
                    let edge = (u.abs() - hw).max(v.abs() - hh);
                    if edge.abs() < 0.5 * SEAM_WIDTH_M {
                        Some(0.6)
                    } else if (edge + STITCH_OFFSET_M).abs() < 0.5 * STITCH_WIDTH_M
                        && frac((u + v) / STITCH_PERIOD_M) < 0.6
                    {
                        Some(-1.0)
                    } else {
                        None
                    }
                })
            }
        };
        c = self.apply_seam(c, seam_hit);
        self.hem(c, gp)
    }

    /// Seam darkening (a factor) or stitch thread (-1).
    fn apply_seam(&self, c: Vec3, hit: Option<f32>) -> Vec3 {
        match hit {
            Some(f) if f < 0.0 => self.thread,
            Some(f) => c * f,
            None => c,
        }
    }

    /// Hem band at cut edges: slightly darker, with a stitch row.
    fn hem(&self, c: Vec3, gp: &GarmentPoint) -> Vec3 {
        if gp.edge_m < HEM_WIDTH_M {
            let stitch = (gp.edge_m - 0.6 * HEM_WIDTH_M).abs() < 0.5 * STITCH_WIDTH_M
                && frac(gp.around_m / STITCH_PERIOD_M) < 0.6;
            if stitch {
                return self.thread;
            }
            return c * 0.82;
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stripes_alternate_with_the_period() {
        let f = Fabric {
            base: Vec3::ZERO,
            accent: Vec3::ONE,
            pattern: Pattern::Stripes {
                period_m: 0.04,
                duty: 0.5,
            },
            seed: 1,
        };
        assert!(f.albedo(0.01, 0.0).x > 0.5);
        assert!(f.albedo(0.03, 0.0).x < 0.1);
        assert!(f.albedo(0.05, 0.0).x > 0.5);
    }

    #[test]
    fn glyph_strokes_ink_their_segments_only() {
        // Segment 0: top bar from column 0 to 1.
        let on = glyph_ink(1, Vec2::new(0.15, 0.0), 0.1);
        let off = glyph_ink(1, Vec2::new(0.15, 0.5), 0.1);
        assert!(on && !off);
    }

    #[test]
    fn print_text_sits_below_the_logo() {
        let print = Print {
            lines: vec![vec![u32::MAX; 3]],
            glyph_h_m: 0.05,
            stroke_m: 0.01,
            logo: Some(Logo::Ring),
            logo_radius_m: 0.04,
            ink: Vec3::ONE,
            height_above_waist_m: 0.2,
        };
        // Logo centre (a dot) and the top bar of the middle glyph.
        assert!(print.ink_at(0.0, -0.04).is_some());
        let line_top = -0.08 - 0.02;
        assert!(print.ink_at(0.0, line_top - 0.001).is_some());
        assert!(print.ink_at(0.5, line_top).is_none());
    }
}
