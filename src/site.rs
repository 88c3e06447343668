//! Site geometry: where the scans lie in the world and which pairs of them may see common
//! surface (so the merge can skip the others).

use crate::scan::occupancy::{diagonal, Occupancy, Reach};
use crate::scan::Scan;
use glam::DVec3;
use rayon::prelude::*;

/// World-space bounding box of a scan: of its points moved by the pose (not of its local box
/// moved, which a rotated pose would inflate).
pub fn world_bounds(s: &Scan) -> (DVec3, DVec3) {
    let pose = s.pose;
    let empty = || (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    let (lo, hi) = s
        .points
        .par_iter()
        .fold(empty, |(lo, hi), p| {
            let w = pose.transform_point3(p.as_dvec3());
            (lo.min(w), hi.max(w))
        })
        .reduce(empty, |a, b| (a.0.min(b.0), a.1.max(b.1)));
    if !(lo.is_finite() && hi.is_finite()) {
        return (DVec3::ZERO, DVec3::ZERO);
    }
    (lo, hi)
}

/// True when two scans with world bounds `a` and `b` may see common surface: eq. 7 accepts
/// partners within 2·rad (`max_rad` = the larger radius of both scans, 0 when unknown) and
/// SSAO reaches `t_max`, so boxes that do not meet when grown by the larger of both (and by
/// rounding) share nothing.
pub fn may_share_surface(a: &(DVec3, DVec3), b: &(DVec3, DVec3), tmax: f32, max_rad: f64) -> bool {
    let scale = (a.1 - a.0).length() + (b.1 - b.0).length();
    overlaps(a, b, pair_margin(tmax, max_rad, scale))
}

/// How close two scans' points must come to pair them (see [`may_share_surface`]); `scale`
/// sizes the allowance for rounding.
fn pair_margin(tmax: f32, max_rad: f64, scale: f64) -> f64 {
    (2.0 * tmax as f64).max(2.0 * max_rad) + 1e-6 * scale + 1e-9
}

/// Which pairs of scans may see common surface: their bounds must meet
/// ([`may_share_surface`]) and so must their occupied cells
/// ([`crate::scan::occupancy`]), which separates scans that only look at each other's
/// surfaces through an opening.
#[derive(Debug, Clone)]
pub struct Pairs {
    bounds: Vec<(DVec3, DVec3)>,
    reach: Reach,
    tmax: f32,
}

impl Pairs {
    /// The pair tests of scans with these world bounds and occupancies, for radii up to
    /// `max_rad` (0 when not known yet).
    pub fn new(bounds: Vec<(DVec3, DVec3)>, occ: &[Occupancy], tmax: f32, max_rad: f64) -> Pairs {
        let scale = 2.0 * bounds.iter().map(diagonal).fold(0.0, f64::max);
        let reach = Reach::new(occ, pair_margin(tmax, max_rad, scale));
        Pairs {
            bounds,
            reach,
            tmax,
        }
    }

    /// Whether scan `i`'s points may correspond to scan `j`'s (always for `i == j`), with
    /// `max_rad` the larger radius of both (at most the one given to [`Pairs::new`]).
    pub fn meets(&self, i: usize, j: usize, max_rad: f64) -> bool {
        i == j
            || (may_share_surface(&self.bounds[i], &self.bounds[j], self.tmax, max_rad)
                && self.reach.meets(i, j))
    }
}

/// True when two boxes, grown by `margin`, intersect.
fn overlaps(a: &(DVec3, DVec3), b: &(DVec3, DVec3), margin: f64) -> bool {
    (a.0 - margin).cmple(b.1).all() && (b.0 - margin).cmple(a.1).all()
}
