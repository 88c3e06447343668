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
/// the query point's normal (`n_q·n_p > SELF_COS`; facing back, see [`own_patch`]) is the
/// query point's own sampled surface — a neighbour tilted by normal error or noise, the
/// co-located samples of another scan a registration residual lifts above it, a grid
/// triangle cutting the corner of a crease — and is ignored. A real occluder that close
/// faces across (a wall in a crease), and is kept. See the module documentation of
/// `reference` for how it was chosen.
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

/// Tangent of the largest elevation over the query point's tangent plane (30°) at which a
/// primitive facing it can still be a mis-oriented sample of its own surface.
pub(crate) const FACING_TAN: f32 = 0.577;
/// Height over the tangent plane, in `rad(p)`, below which a primitive facing the query point
/// is its own surface wherever it lies: nearer than half a sample spacing the sampling cannot
/// tell two surfaces apart (the triangle through the point itself with its front turned by
/// normals that disagree, the other side of a sheet seen from both sides).
pub(crate) const FACING_LIFT: f32 = 0.5;

/// Is a hit at distance `t` on a surface of unit normal `nq` the query point's own patch? A
/// surface facing the point's way is; one facing back at it only when it lies in the point's
/// own surface: `at()`, where the primitive is (a disk's centre, a triangle's point nearest
/// the ray's origin), at most `FACING_TAN` steep over the tangent plane or lower than the
/// own-surface height plus `FACING_LIFT · rad(p)`. Across a narrow groove the facing wall
/// stands over the point.
#[inline(always)]
fn own_patch(ray: &Ray, t: f32, nq: Vec3, at: impl FnOnce() -> Vec3) -> bool {
    if !near_self(ray, t) {
        return false;
    }
    let cos = ray.n_self.dot(nq);
    if cos > SELF_COS {
        return true;
    }
    if !(cos < -SELF_COS) {
        return false;
    }
    let v = at() - ray.o;
    let h = v.dot(ray.n_self);
    let flat2 = (v.length_squared() - h * h).max(0.0);
    h <= ray.h_self + FACING_LIFT * ray.r_self || h * h <= FACING_TAN * FACING_TAN * flat2
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
        if (denom > 0.0 && t < BACK_NEAR * (ray.r_self + self.r))
            || own_patch(ray, t, self.n, || self.c)
        {
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

impl Triangle {
    /// The point of the triangle nearest `p` (by the Voronoi regions of its vertices, edges
    /// and face). `synth` has its own in f64: the ground truth shares no code with the
    /// reference it checks.
    fn nearest(&self, p: Vec3) -> Vec3 {
        let (a, ab, ac) = (self.v0, self.e1, self.e2);
        let ap = p - a;
        let (d1, d2) = (ab.dot(ap), ac.dot(ap));
        if d1 <= 0.0 && d2 <= 0.0 {
            return a;
        }
        let bp = ap - ab;
        let (d3, d4) = (ab.dot(bp), ac.dot(bp));
        if d3 >= 0.0 && d4 <= d3 {
            return a + ab;
        }
        let vc = d1 * d4 - d3 * d2;
        if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
            return a + ab * (d1 / (d1 - d3));
        }
        let cp = ap - ac;
        let (d5, d6) = (ab.dot(cp), ac.dot(cp));
        if d6 >= 0.0 && d5 <= d6 {
            return a + ac;
        }
        let vb = d5 * d2 - d1 * d6;
        if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
            return a + ac * (d2 / (d2 - d6));
        }
        let va = d3 * d6 - d5 * d4;
        if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
            return a + ab + (ac - ab) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
        }
        // Inside the face; the denominator is the squared area, positive for a triangle the
        // builder kept.
        let den = va + vb + vc;
        if !(den > 0.0) {
            return a;
        }
        a + ab * (vb / den) + ac * (vc / den)
    }
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
        let nq = self.e1.cross(self.e2).normalize_or_zero();
        if own_patch(ray, t, nq, || self.nearest(ray.o)) {
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

    #[test]
    fn nearest_point_of_a_triangle_in_each_region() {
        let t = Triangle {
            v0: Vec3::ZERO,
            e1: Vec3::X,
            e2: Vec3::Y,
        };
        let cases = [
            (Vec3::new(0.2, 0.3, 5.0), Vec3::new(0.2, 0.3, 0.0)),
            (Vec3::new(-1.0, -2.0, 1.0), Vec3::ZERO),
            (Vec3::new(3.0, -1.0, 0.0), Vec3::X),
            (Vec3::new(-1.0, 4.0, 0.0), Vec3::Y),
            (Vec3::new(0.5, -1.0, 2.0), Vec3::new(0.5, 0.0, 0.0)),
            (Vec3::new(-1.0, 0.25, 0.0), Vec3::new(0.0, 0.25, 0.0)),
            (Vec3::new(1.0, 1.0, -3.0), Vec3::new(0.5, 0.5, 0.0)),
        ];
        for (p, want) in cases {
            let got = t.nearest(p);
            assert!(got.distance(want) < 1e-6, "{p}: {got} against {want}");
        }
    }
}
