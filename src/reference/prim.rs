//! The two primitive kinds of the reference scene and their ray tests.

use super::bvh::{Primitive, Ray};
use glam::Vec3;

/// A hit on a surfel's back side (the ray leaves through the disk along its normal) closer
/// than `BACK_NEAR · (rad(p) + rad(q))` is taken as the query point's own surface: on a
/// convex or noisy surface a neighbour's tangent disk overhangs the query point, and the
/// overlapping surfels of other scans of the same surface lie a little above or below it.
/// See the module documentation of `reference` for the measured bias.
pub(crate) const BACK_NEAR: f32 = 2.0;

/// Own-patch rule: a hit closer than `SELF_NEAR · rad(p)` on a surface facing within 60° of
/// the query point's normal (`|n_q·n_p| > SELF_COS`) is the query point's own sampled
/// surface — a neighbour tilted by normal error or noise, the co-located samples of another
/// scan a registration residual lifts above it, a grid triangle cutting the corner of a
/// crease — and is ignored. A real occluder that close faces across (a wall in a crease),
/// and is kept. See the module documentation of `reference` for how it was chosen.
pub(crate) const SELF_NEAR: f32 = 2.0;
/// Cosine of the largest angle between the query point's normal and a surface taken as its
/// own (60°).
pub(crate) const SELF_COS: f32 = 0.5;

/// Is a hit at distance `t` near enough to be on the query point's own patch: closer than
/// `SELF_NEAR·rad(p)`, or lower over its tangent plane than the own-surface height (the
/// registration residual between scans, which a grazing ray meets far from the point)?
#[inline(always)]
fn near_self(ray: &Ray, t: f32) -> bool {
    t < SELF_NEAR * ray.r_self || t * ray.rise < ray.h_self
}

/// Is a hit at distance `t` on a surface of unit normal `nq` the query point's own patch?
#[inline(always)]
fn own_patch(ray: &Ray, t: f32, nq: Vec3) -> bool {
    near_self(ray, t) && ray.n_self.dot(nq).abs() > SELF_COS
}
/// An oriented disk (32 bytes).
#[derive(Debug, Clone, Copy)]
#[repr(C)]
pub(crate) struct Surfel {
    pub c: Vec3,
    pub r2: f32,
    pub n: Vec3,
    pub r: f32,
}

impl Primitive for Surfel {
    #[inline]
    fn bounds(&self) -> (Vec3, Vec3) {
        // Exact box of a disk: half-extent along axis k is r·sqrt(1 − n_k²).
        let e = (Vec3::ONE - self.n * self.n).max(Vec3::ZERO).map(f32::sqrt) * self.r;
        (self.c - e, self.c + e)
    }

    #[inline(always)]
    fn hit(&self, ray: &Ray, t_hi: f32) -> Option<f32> {
        let denom = ray.d.dot(self.n);
        let num = (self.c - ray.o).dot(self.n);
        // t = num/denom in (0, t_hi) without dividing first: most candidates fail here or
        // on the back-hit rule. A ray parallel to the disk (denom = 0) fails too.
        if !(num * denom > 0.0 && num.abs() < t_hi * denom.abs()) {
            return None;
        }
        let t = num / denom;
        if !(t < t_hi) {
            return None;
        }
        let q = ray.o + ray.d * t - self.c;
        if q.length_squared() > self.r2 {
            return None;
        }
        if (denom > 0.0 && t < BACK_NEAR * (ray.r_self + self.r)) || own_patch(ray, t, self.n) {
            ray.discard();
            return None;
        }
        Some(t)
    }

    #[inline]
    fn can_hit(&self, o: Vec3, n: Vec3, r_self: f32) -> bool {
        // Entirely below the tangent plane at o?
        let c = n.dot(self.n);
        if !(n.dot(self.c - o) + self.r * (1.0 - c * c).max(0.0).sqrt() > 0.0) {
            return false;
        }
        // With o behind the disk's plane every hit is a back hit, at a distance of at most
        // |c − o| + r: all ignored when that is inside the back-hit range (with a margin
        // for rounding).
        let behind = (o - self.c).dot(self.n) <= 0.0;
        !(behind && (self.c - o).length() + self.r < 0.99 * BACK_NEAR * (r_self + self.r))
    }
}

/// A triangle `v0 + s·e1 + q·e2` (36 bytes), hit from either side.
#[derive(Debug, Clone, Copy)]
#[repr(C)]
pub(crate) struct Triangle {
    pub v0: Vec3,
    pub e1: Vec3,
    pub e2: Vec3,
}

impl Primitive for Triangle {
    #[inline]
    fn bounds(&self) -> (Vec3, Vec3) {
        let (a, b, c) = (self.v0, self.v0 + self.e1, self.v0 + self.e2);
        (a.min(b).min(c), a.max(b).max(c))
    }

    #[inline(always)]
    fn hit(&self, ray: &Ray, t_hi: f32) -> Option<f32> {
        // Möller–Trumbore.
        let p = ray.d.cross(self.e2);
        let det = self.e1.dot(p);
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let inv = 1.0 / det;
        let s = ray.o - self.v0;
        let u = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(self.e1);
        let v = ray.d.dot(q) * inv;
        if !(v >= 0.0 && u + v <= 1.0) {
            return None;
        }
        let t = self.e2.dot(q) * inv;
        if !(t > 0.0 && t < t_hi) {
            return None;
        }
        if near_self(ray, t) && own_patch(ray, t, self.e1.cross(self.e2).normalize_or_zero()) {
            ray.discard();
            return None;
        }
        Some(t)
    }

    #[inline]
    fn can_hit(&self, o: Vec3, n: Vec3, _r_self: f32) -> bool {
        let a = n.dot(self.v0 - o);
        a > 0.0 || a + n.dot(self.e1) > 0.0 || a + n.dot(self.e2) > 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surfel_hits_inside_and_skips_outside_and_near_back() {
        let s = Surfel {
            c: Vec3::new(0.0, 0.0, 1.0),
            r2: 0.25,
            n: Vec3::NEG_Z,
            r: 0.5,
        };
        let up = Ray::new(Vec3::ZERO, Vec3::Z, 0.0);
        assert_eq!(s.hit(&up, 10.0), Some(1.0));
        assert_eq!(s.hit(&up, 0.5), None);
        let off = Ray::new(Vec3::new(0.6, 0.0, 0.0), Vec3::Z, 0.0);
        assert_eq!(s.hit(&off, 10.0), None);
        // Same disk seen from its back: within 2·(r_p + r_q) = 2·(0.1 + 0.5) it is ignored.
        let back = Surfel { n: Vec3::Z, ..s };
        assert_eq!(back.hit(&Ray::new(Vec3::ZERO, Vec3::Z, 0.1), 10.0), None);
        let far = Surfel {
            c: Vec3::new(0.0, 0.0, 2.0),
            ..back
        };
        assert_eq!(
            far.hit(&Ray::new(Vec3::ZERO, Vec3::Z, 0.1), 10.0),
            Some(2.0)
        );
        let (lo, hi) = s.bounds();
        assert_eq!(lo, Vec3::new(-0.5, -0.5, 1.0));
        assert_eq!(hi, Vec3::new(0.5, 0.5, 1.0));
    }

    #[test]
    fn triangle_hits_both_sides() {
        let t = Triangle {
            v0: Vec3::new(-1.0, -1.0, 2.0),
            e1: Vec3::new(3.0, 0.0, 0.0),
            e2: Vec3::new(0.0, 3.0, 0.0),
        };
        assert_eq!(t.hit(&Ray::new(Vec3::ZERO, Vec3::Z, 0.0), 9.0), Some(2.0));
        let from_above = Ray::new(Vec3::new(0.0, 0.0, 5.0), Vec3::NEG_Z, 0.0);
        assert_eq!(t.hit(&from_above, 9.0), Some(3.0));
        let miss = Ray::new(Vec3::new(1.5, 1.5, 0.0), Vec3::Z, 0.0);
        assert_eq!(t.hit(&miss, 9.0), None);
    }
}
