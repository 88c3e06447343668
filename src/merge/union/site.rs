//! Where a ray has left the site: the box beyond which no view can report a hit.

use super::{solid_depth, Lens, UnionParams};
use glam::{Vec3, Vec3A};
use rayon::prelude::*;

/// A box (the target's frame) outside which no view holds evidence: every stored point of
/// every view, widened by how far from a stored point a hit can be found: the solid depth
/// behind it and two pixels across (an inferred hit, or a crossing between neighbouring
/// pixels, which lies between their stored points), twice its radius, and a sixteenth of a
/// gap between samples (a crossing is accepted once four halvings bring both ends within
/// the radius and that length of the stored depth). A ray outside it and moving away along
/// one axis stays outside: its remaining samples can find nothing, and it ends there. At
/// `t_max = ∞`, where rays reach twice the site's depth, many of an upward ray's samples lie
/// above the site.
#[derive(Debug, Clone, Copy)]
pub(super) struct Bounds {
    pub(super) lo: Vec3,
    pub(super) hi: Vec3,
}

impl Bounds {
    /// No bound: every sample is marched.
    pub(super) const ALL: Bounds = Bounds {
        lo: Vec3::NEG_INFINITY,
        hi: Vec3::INFINITY,
    };

    /// The bounds of `lenses`' stored points for rays of `prm`.
    pub(super) fn of(lenses: &[Lens<'_>], prm: &UnionParams) -> Bounds {
        // The last gap between samples is under 2·reach/steps.
        let gap = 2.0 * prm.reach / prm.steps.max(1) as f32;
        let mut b = Bounds {
            lo: Vec3::INFINITY,
            hi: Vec3::NEG_INFINITY,
        };
        for l in lenses {
            // The solid depth grows with the depth it is taken at; with pixels under about
            // 6° a sample within it of a stored point is at most 11 % deeper than that point,
            // and the margins below hold. Coarser maps bound nothing.
            if !(l.pixel.1 <= 0.1) {
                return Bounds::ALL;
            }
            // Local box of the stored points, each widened by twice its radius (a crossing
            // is accepted within its radius of the stored depth), and their largest depth.
            let empty = || (Vec3::INFINITY, Vec3::NEG_INFINITY, 0.0f32);
            let (lo, hi, deep) = l
                .maps
                .near
                .par_iter()
                .filter(|q| q.w != f32::NEG_INFINITY)
                .fold(empty, |(lo, hi, d), q| {
                    let p = q.truncate();
                    let w = Vec3::splat(2.0 * q.w.max(0.0));
                    (lo.min(p - w), hi.max(p + w), d.max(l.depth(p)))
                })
                .reduce(empty, |a, b| (a.0.min(b.0), a.1.max(b.1), a.2.max(b.2)));
            if lo.x > hi.x {
                continue; // nothing stored
            }
            let px = l.pixel_size(deep + prm.reach);
            let m = solid_depth(prm.thickness, px) + 2.0 * px + gap / 16.0;
            let (lo, hi) = (lo - Vec3::splat(m), hi + Vec3::splat(m));
            let back = l.rel.inverse();
            for c in 0..8 {
                let corner = Vec3::new(
                    if c & 1 == 0 { lo.x } else { hi.x },
                    if c & 2 == 0 { lo.y } else { hi.y },
                    if c & 4 == 0 { lo.z } else { hi.z },
                );
                let q: Vec3 = back.transform_point3a(Vec3A::from(corner)).into();
                b.lo = b.lo.min(q);
                b.hi = b.hi.max(q);
            }
        }
        // Rounding of the transforms: a relative margin; anything not finite bounds nothing.
        let slack = Vec3::splat(1e-4 * (b.lo.abs().max(b.hi.abs()).max_element() + 1.0));
        let b = Bounds {
            lo: b.lo - slack,
            hi: b.hi + slack,
        };
        if b.lo.is_finite() && b.hi.is_finite() {
            b
        } else {
            Bounds::ALL
        }
    }

    /// Whether a ray at `q` going along `omega` is outside and moving away along some axis.
    #[inline]
    pub(super) fn left(&self, q: Vec3, omega: Vec3) -> bool {
        let above = q.cmpgt(self.hi) & omega.cmpge(Vec3::ZERO);
        let below = q.cmplt(self.lo) & omega.cmple(Vec3::ZERO);
        (above | below).any()
    }
}
