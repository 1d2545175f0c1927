//! The implicit procedural body: a smooth union of tapered capsules and ellipsoids, as a signed
//! distance-like field (negative inside, metres), and projection of points onto its surface.

use glam::Vec3;

/// Step of the central differences that estimate the field's gradient, metres: small against
/// the body's features (>= 2 cm) and large against f32 rounding of field values (~1e-8 m).
const GRADIENT_STEP_M: f32 = 1e-4;

/// At most this many Newton steps in [`ImplicitBody::project`]; the field is a near-distance so
/// 4 steps bring a point within ~1e-6 m of the surface from a centimetre away.
const PROJECT_ITERATIONS: usize = 4;

/// [`ImplicitBody::project`] stops once the field is this close to zero, metres (far below the
/// mesh's centimetre scale, above f32 rounding of the field).
const PROJECT_TOL_M: f32 = 1e-6;

/// One solid part of the body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Primitive {
    /// The sweep of a sphere from `a` (radius `ra`) to `b` (radius `rb`), radius linear along
    /// the axis (a tapered capsule), metres.
    RoundCone { a: Vec3, b: Vec3, ra: f32, rb: f32 },
    /// An axis-aligned ellipsoid, metres.
    Ellipsoid { centre: Vec3, radii: Vec3 },
}

impl Primitive {
    /// Distance-like field, negative inside; exact zero set, approximately unit gradient near it.
    pub fn distance(&self, p: Vec3) -> f32 {
        match *self {
            Primitive::RoundCone { a, b, ra, rb } => {
                let t = segment_param(p, a, b);
                (p - (a + (b - a) * t)).length() - (ra + (rb - ra) * t)
            }
            Primitive::Ellipsoid { centre, radii } => {
                // Inigo Quilez's bound: k0 (k0 - 1) / k1 with k0 = |q / r|, k1 = |q / r^2|.
                let q = p - centre;
                let k0 = (q / radii).length();
                let k1 = (q / (radii * radii)).length();
                if k1 < 1e-12 {
                    -radii.min_element()
                } else {
                    k0 * (k0 - 1.0) / k1
                }
            }
        }
    }

    /// Axis-aligned bounds `(min, max)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        match *self {
            Primitive::RoundCone { a, b, ra, rb } => {
                let r = Vec3::splat(ra.max(rb));
                (a.min(b) - r, a.max(b) + r)
            }
            Primitive::Ellipsoid { centre, radii } => (centre - radii, centre + radii),
        }
    }
}

/// Where the point of the segment `a -> b` nearest to `p` lies: `t` in `[0, 1]` with the point at
/// `a + (b - a) t` (0 for a degenerate segment).
pub(super) fn segment_param(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let len2 = ab.length_squared();
    if len2 > 0.0 {
        ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Quadratic smooth minimum: `min(a, b)` rounded over a band of width `k` (metres).
pub fn smooth_min(a: f32, b: f32, k: f32) -> f32 {
    if k <= 0.0 {
        return a.min(b);
    }
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

/// A smooth union of primitives, each blended into the union of those before it.
#[derive(Debug, Clone, PartialEq)]
pub struct ImplicitBody {
    /// `(primitive, blend width k in metres)`, in blending order.
    pub parts: Vec<(Primitive, f32)>,
}

impl ImplicitBody {
    /// Field value at `p`: negative inside the body, metres (approximately).
    pub fn distance(&self, p: Vec3) -> f32 {
        let mut d = f32::INFINITY;
        for (part, k) in &self.parts {
            let di = part.distance(p);
            d = if d.is_finite() {
                smooth_min(d, di, *k)
            } else {
                di
            };
        }
        d
    }

    /// Central-difference gradient of [`ImplicitBody::distance`].
    pub fn gradient(&self, p: Vec3) -> Vec3 {
        let h = GRADIENT_STEP_M;
        let dx = Vec3::X * h;
        let dy = Vec3::Y * h;
        let dz = Vec3::Z * h;
        Vec3::new(
            self.distance(p + dx) - self.distance(p - dx),
            self.distance(p + dy) - self.distance(p - dy),
            self.distance(p + dz) - self.distance(p - dz),
        ) / (2.0 * h)
    }

    /// Move `p` onto the zero set by Newton steps along the gradient, each step at most
    /// `max_step` metres (so a point never jumps across a thin part).
    pub fn project(&self, p: Vec3, max_step: f32) -> Vec3 {
        let mut x = p;
        for _ in 0..PROJECT_ITERATIONS {
            let d = self.distance(x);
            if d.abs() < PROJECT_TOL_M {
                break;
            }
            let g = self.gradient(x);
            let g2 = g.length_squared();
            if g2 < 1e-12 {
                break;
            }
            let step = g * (d / g2);
            let len = step.length();
            x -= if len > max_step {
                step * (max_step / len)
            } else {
                step
            };
        }
        if x.is_finite() {
            x
        } else {
            p
        }
    }

    /// Axis-aligned bounds of all parts `(min, max)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.parts.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), (part, k)| {
                let (a, b) = part.bounds();
                (lo.min(a - Vec3::splat(*k)), hi.max(b + Vec3::splat(*k)))
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Field values of simple shapes at chosen points, exact up to f32 rounding.
    const TOL: f32 = 1e-5;

    #[test]
    fn primitives_have_the_right_zero_sets() {
        let cone = Primitive::RoundCone {
            a: Vec3::ZERO,
            b: Vec3::X,
            ra: 0.2,
            rb: 0.1,
        };
        assert!((cone.distance(Vec3::new(0.5, 0.15, 0.0))).abs() < TOL);
        assert!((cone.distance(Vec3::new(-0.2, 0.0, 0.0))).abs() < TOL);
        assert!(cone.distance(Vec3::new(0.5, 0.0, 0.0)) < 0.0);
        let ell = Primitive::Ellipsoid {
            centre: Vec3::ONE,
            radii: Vec3::new(0.1, 0.2, 0.3),
        };
        for p in [Vec3::X * 0.1, Vec3::Y * 0.2, Vec3::Z * -0.3] {
            assert!(ell.distance(Vec3::ONE + p).abs() < TOL);
        }
        assert!(ell.distance(Vec3::ONE) < 0.0);
        assert!(ell.distance(Vec3::ZERO) > 0.0);
    }

    #[test]
    fn projection_lands_on_the_surface() {
        let body = ImplicitBody {
            parts: vec![(
                Primitive::Ellipsoid {
                    centre: Vec3::ZERO,
                    radii: Vec3::new(0.3, 0.2, 0.1),
                },
                0.0,
            )],
        };
        let p = body.project(Vec3::new(0.25, 0.1, 0.05), 0.05);
        assert!(body.distance(p).abs() < TOL, "{}", body.distance(p));
    }
}
