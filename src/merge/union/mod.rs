//! Union occlusion: a point's occlusion evaluated against the geometry of every view that
//! overlaps it, direction by direction, instead of averaging the views' finished AO values.
//!
//! For a point `p` with normal `n`, `rays` cosine-weighted directions `ω` (stratified in
//! elevation, a golden-angle lattice in azimuth turned per point by the seeded generator,
//! and paired with their mirror `φ + π` so an open plane's mean direction is exactly `n`)
//! are marched from `p` out to the reach (`t_max`, or the scene's extent at `t_max = ∞`),
//! `steps` samples per ray spaced quadratically (finer near `p`, where ρ changes fastest).
//! Each sample `q` is projected into every view `j` whose map holds `p`'s image; with `d` the
//! depth of `q` in view j and `D` the depth view j stored at that pixel, `s = d − D` says:
//!
//! - `s < −m`: view j saw through `q` (free-space evidence);
//! - a change of side since the previous sample (`s` from negative to above `m/4`), the
//!   segment halved four times around it, with both ends within `m` plus the depth they
//!   span of the stored surface: the ray crossed the surface view j observed (surface
//!   evidence, at the interpolated crossing). Otherwise the segment is halved on until its
//!   ends fall in neighbouring pixels, and it is a crossing when their stored points lie on
//!   one surface (normals within 30°, the segment between them within about 17° of both
//!   tangent planes and no longer than a pixel or two stretched by the incidence): a surface
//!   seen at grazing incidence steps in depth by far more than its noise from pixel to pixel.
//!   A change across a jump in depth is the ray passing into the shadow of a surface from
//!   the side, not a crossing;
//! - otherwise `m/4 < s ≤ max(T, P)`: behind the observed surface within the thickness `T`,
//!   or within one pixel `P` of view j at that depth where its pixels are coarser (a map
//!   cannot tell a solid from a shell thinner than its pixels), and behind the stored surface
//!   of the four neighbouring pixels too (inferred evidence; beside a silhouette, where a
//!   neighbour saw past the sample or is empty, the space behind is not inferred solid);
//! - beyond, or an empty pixel, or outside the map: unknown.
//!
//! `m` is the stored point's radius (its spacing). A candidate hit is the nearest
//! sample with surface or inferred evidence; at the candidate point every other view votes
//! with weight `1 / rad` of its pixel (sharp near views outweigh coarse far ones): free
//! where it saw past the point (in its pixel and the four neighbours, so a silhouette
//! quantised by one pixel does not veto), occupied where the point lies from `m` in front of
//! its surface to `max(T, P)` behind.
//! Surface evidence holds when the occupied weight is at least the free weight; inferred
//! evidence holds only where no view saw through the point (seeing through is an
//! observation, occupancy behind a surface a guess). The ray's hit distance is the first
//! candidate that holds; `A(p)` is the mean of `ρ(t_hit)` over the rays, then pooled with the
//! values of neighbouring points of the same surface (`filter.rs`).
//!
//! Same-surface rule: evidence from a pixel whose stored point lies within
//! `h₀ = 2 (rad(p) + rad)` of `p`'s tangent plane with a normal within 60° of `n` is `p`'s
//! own surface as that view sampled it (with its noise and registration error), and is
//! ignored; a wall meeting the surface (a normal far from `n`) still counts.
//!
//! Far-face rule: a view in whose solid depth `p` lies, facing away from it, infers nothing
//! for `p`'s rays: `p` is then the far face of an element thinner than that depth, and the
//! view knows nothing of the space beyond it.

use super::{View, ViewMaps};
use crate::falloff::Falloff;
use crate::projection::{floor_i64, Model, Projection};
use crate::rng::Rng;
use glam::{Affine3A, DMat4, Vec3, Vec3A, Vec4};
use rayon::prelude::*;
use serde::Serialize;

mod filter;

/// Default radius in pixels of the union's edge-aware smoothing ([`UnionParams::filter`]).
pub const FILTER_RADIUS: u32 = 3;

/// How the merge combines the views.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Occlusion {
    /// The views' finished AO averaged at each point (eq. 6–12).
    #[default]
    Average,
    /// Each point's rays marched through every overlapping view's geometry.
    Union,
}

/// Parameters of the union occlusion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct UnionParams {
    /// Rays per point (rounded up to even).
    pub rays: u32,
    /// Samples per ray.
    pub steps: u32,
    /// Falloff distance of ρ (`f32::INFINITY` allowed).
    #[serde(serialize_with = "crate::falloff::serialize_tmax")]
    pub tmax: f32,
    /// Shape of ρ.
    pub falloff: Falloff,
    /// How far rays are marched (finite: `t_max`, or the scene's extent).
    pub reach: f32,
    /// Thickness `T` behind an observed surface taken as solid.
    pub thickness: f32,
    /// Seed of the per-point direction patterns.
    pub seed: u64,
    /// Radius in pixels of the edge-aware smoothing of the results over each scan's own map
    /// (0: none).
    pub filter: u32,
}

/// One view as the rays see it: its maps and the transform from the target's frame.
#[derive(Clone, Copy)]
struct Lens<'a> {
    proj: &'a Projection,
    maps: &'a ViewMaps,
    rel: Affine3A,
    /// A pixel's size in metres at depth `d` is `pixel.0 + pixel.1 · d` (at the map's centre).
    pixel: (f32, f32),
}

/// [`Lens::pixel`] of `proj`: a constant for an orthographic view, proportional to the depth
/// for the others.
fn pixel_size(proj: &Projection) -> (f32, f32) {
    let (x, y) = (0.5 * proj.width as f32, 0.5 * proj.height as f32);
    let at = |d: f32| {
        let probe = 0.01 * d;
        let (rx, ry) = proj.disk_radius(probe, d, x, y);
        probe / rx.min(ry).max(1e-9)
    };
    let (s1, s2) = (at(1.0), at(2.0));
    let slope = (s2 - s1).max(0.0);
    ((s1 - slope).max(0.0), slope)
}

/// What one view says about a 3-D point.
#[derive(Debug, Clone, Copy)]
struct Reading {
    /// Depth of the point minus the stored depth at its pixel.
    s: f32,
    /// Depth of the point in the view.
    d: f32,
    /// Radius of the stored point.
    rad: f32,
    /// Pixel index and continuous pixel position.
    idx: usize,
    px: (i64, i64),
}

impl Lens<'_> {
    /// Depth of the point stored at pixel `idx`, and its radius (`None`: empty).
    #[inline]
    fn stored(&self, idx: usize) -> Option<(f32, f32)> {
        let near = self.maps.near.get(idx)?;
        if near.w == f32::NEG_INFINITY {
            return None;
        }
        Some((self.depth(near.truncate()), near.w.max(1e-6)))
    }

    /// The depth `project` gives `p` (view frame), without the angles: the distance to the
    /// sensor, or the distance along an orthographic view's axis.
    #[inline]
    fn depth(&self, p: Vec3) -> f32 {
        match self.proj.model {
            Model::Ortho { toward, depth0, .. } => depth0 - toward.dot(p),
            _ => p.length(),
        }
    }

    /// The view's reading at `q` (target frame).
    #[inline]
    fn read(&self, q: Vec3) -> Option<Reading> {
        let qj: Vec3 = self.rel.transform_point3a(Vec3A::from(q)).into();
        let pr = self.proj.project(qj)?;
        if !pr.depth.is_finite() {
            return None;
        }
        let px = (floor_i64(pr.x), floor_i64(pr.y));
        let idx = self.proj.pixel_at(px.0, px.1)?;
        let (dd, rad) = self.stored(idx)?;
        Some(Reading {
            s: pr.depth - dd,
            d: pr.depth,
            rad,
            idx,
            px,
        })
    }

    /// The size of a pixel (metres) at depth `d`: the finest detail the view resolves there.
    #[inline]
    fn pixel_size(&self, d: f32) -> f32 {
        self.pixel.0 + self.pixel.1 * d
    }

    /// Whether the view saw past `r`'s point in its pixel and the four neighbours.
    fn sees_through(&self, r: &Reading) -> bool {
        r.s < -2.0 * r.rad && self.neighbours_past(r) == 4
    }

    /// Whether `r`'s point lies behind the surface in all four neighbouring pixels too: no
    /// neighbour saw past it (a silhouette's neighbour, or an empty one, did).
    fn enclosed(&self, r: &Reading) -> bool {
        self.neighbours_past(r) == 0
    }

    /// How many of the four pixels beside `r`'s saw past its point by more than twice their
    /// radius, or are empty or outside the map.
    fn neighbours_past(&self, r: &Reading) -> usize {
        [(1, 0), (-1, 0), (0, 1), (0, -1)]
            .iter()
            .filter(|&&(dx, dy)| {
                match self
                    .proj
                    .pixel_at(r.px.0 + dx, r.px.1 + dy)
                    .and_then(|i| self.stored(i))
                {
                    Some((dd, rad)) => r.d < dd - 2.0 * rad,
                    None => true,
                }
            })
            .count()
    }

    /// Whether the points stored at two neighbouring readings' pixels lie on one surface:
    /// normals within 30°, and the segment between them within about 17° of both tangent
    /// planes (up to their radii) and no longer than the pixels' footprint there. On a surface
    /// seen at grazing incidence the segment lies in the surface however long; across a
    /// silhouette it runs from the nearer object to what lies behind, along the line of sight,
    /// through one of the tangent planes or longer than a pixel of either surface (two columns
    /// seen one behind the other).
    fn continuous(&self, a: &Reading, b: &Reading) -> bool {
        if a.idx == b.idx {
            return true;
        }
        let m = self.maps;
        let (Some(pa), Some(pb), Some(ra), Some(rb)) = (
            m.near.get(a.idx),
            m.near.get(b.idx),
            m.rest.get(a.idx),
            m.rest.get(b.idx),
        ) else {
            return false;
        };
        let e = pb.truncate() - pa.truncate();
        let len = e.length();
        let (na, nb) = (
            Vec3::new(ra[0], ra[1], ra[2]),
            Vec3::new(rb[0], rb[1], rb[2]),
        );
        let slack = a.rad + b.rad;
        // Neighbouring pixels of one surface are at most a diagonal pixel apart across the
        // line of sight, stretched by the incidence (twice that for noise): a longer segment
        // bridges a gap, as between two columns seen one behind the other.
        let fits = |q: Vec4, n: Vec3| {
            let q = q.truncate();
            let v = match self.proj.model {
                Model::Ortho { toward, .. } => toward,
                _ => q.normalize_or_zero(),
            };
            let px = self.pixel_size(self.depth(q));
            let across = 2.0 * std::f32::consts::SQRT_2 * px / n.dot(v).abs().max(0.02);
            n.dot(e).abs() <= 0.3 * len + slack && len <= across + slack
        };
        na.dot(nb) >= 0.866 && fits(*pa, na) && fits(*pb, nb)
    }

    /// Whether the stored point of pixel `idx` is `p`'s own surface (see the module docs);
    /// `p`, `n` are in the view's frame.
    fn same_surface(&self, idx: usize, p: Vec3, n: Vec3, rad_p: f32) -> bool {
        let (Some(near), Some(rest)) = (self.maps.near.get(idx), self.maps.rest.get(idx)) else {
            return false;
        };
        let nj = Vec3::new(rest[0], rest[1], rest[2]);
        let h0 = 2.0 * (rad_p + near.w.max(0.0));
        nj.dot(n) > 0.5 && (near.truncate() - p).dot(n).abs() < h0
    }
}

/// Kinds of evidence for a hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Evidence {
    Surface,
    Inferred,
}

/// The shaded point as one view sees it.
#[derive(Debug, Clone, Copy)]
struct InView {
    /// The point and its normal in the view's frame.
    p: Vec3,
    n: Vec3,
    /// Whether the view's solid behind its surfaces counts for the point's rays: not when the
    /// point faces away from the view from within that solid, the far face of an element
    /// thinner than the view's solid depth (a door jamb, a thin wall seen from its other
    /// side). Everything above the point's tangent plane is outside that element, and the
    /// view knows nothing of the space beyond it.
    infers: bool,
}

impl InView {
    /// `r` is the view's reading at `p`.
    fn new(l: &Lens<'_>, r: &Reading, p: Vec3, n: Vec3, thickness: f32) -> InView {
        let pj: Vec3 = l.rel.transform_point3a(Vec3A::from(p)).into();
        let nj: Vec3 = l.rel.transform_vector3a(Vec3A::from(n)).into();
        let within = r.s > 0.0 && r.s <= solid_depth(thickness, l.pixel_size(r.d));
        InView {
            p: pj,
            n: nj,
            infers: !(within && nj.dot(l.proj.toward_sensor(pj)) < 0.0),
        }
    }
}

/// The point being shaded, in its own frame and in each view's.
struct Shaded<'s> {
    p: Vec3,
    n: Vec3,
    rad: f32,
    in_view: &'s [InView],
    bounds: &'s Bounds,
}

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
struct Bounds {
    lo: Vec3,
    hi: Vec3,
}

impl Bounds {
    /// No bound: every sample is marched.
    const ALL: Bounds = Bounds {
        lo: Vec3::NEG_INFINITY,
        hi: Vec3::INFINITY,
    };

    /// The bounds of `lenses`' stored points for rays of `prm`.
    fn of(lenses: &[Lens<'_>], prm: &UnionParams) -> Bounds {
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
    fn left(&self, q: Vec3, omega: Vec3) -> bool {
        let above = q.cmpgt(self.hi) & omega.cmpge(Vec3::ZERO);
        let below = q.cmplt(self.lo) & omega.cmple(Vec3::ZERO);
        (above | below).any()
    }
}

/// Whether the candidate hit at `q` by view `from` with `ev` holds against the other views.
fn holds(
    lenses: &[Lens<'_>],
    from: usize,
    rad_from: f32,
    q: Vec3,
    ev: Evidence,
    t_occ: f32,
) -> bool {
    let mut free = 0.0f32;
    let mut occ = 1.0 / rad_from;
    for (j, l) in lenses.iter().enumerate() {
        if j == from {
            continue;
        }
        let Some(r) = l.read(q) else { continue };
        if l.sees_through(&r) {
            if ev == Evidence::Inferred {
                return false;
            }
            free += 1.0 / r.rad;
        } else if r.s >= -r.rad && r.s <= solid_depth(t_occ, l.pixel_size(r.d)) {
            occ += 1.0 / r.rad;
        }
    }
    occ >= free
}

/// How far behind a stored surface a view takes space as solid: the thickness, but never less
/// than the view's pixel there (`pixel` metres), the finest detail it resolves: a coarse map
/// cannot tell a solid from a shell thinner than its pixels, and taking every surface as
/// thinner than that lets rays through the corners its pixels straddle.
#[inline]
fn solid_depth(thickness: f32, pixel: f32) -> f32 {
    thickness.max(pixel)
}

/// Where the ray crossed view `l`'s stored surface between a sample in front of it (`a`)
/// and one behind (`b`): the segment is halved four times around the change of side; a
/// change between samples close in depth to the stored surface is a crossing, and so is one
/// between neighbouring pixels whose stored points lie on one surface
/// ([`Lens::continuous`]); one across a jump (the ray passing into a shadow from the side)
/// is not.
fn crossing(
    l: &Lens<'_>,
    p: Vec3,
    omega: Vec3,
    mut a: (f32, Reading),
    mut b: (f32, Reading),
) -> Option<f32> {
    let halve = |a: &mut (f32, Reading), b: &mut (f32, Reading)| -> Option<()> {
        let tm = 0.5 * (a.0 + b.0);
        let m = l.read(p + omega * tm)?;
        if m.s < 0.0 {
            *a = (tm, m);
        } else {
            *b = (tm, m);
        }
        Some(())
    };
    for _ in 0..4 {
        halve(&mut a, &mut b)?;
    }
    let at = |a: &(f32, Reading), b: &(f32, Reading)| {
        let f = (a.1.s / (a.1.s - b.1.s)).clamp(0.0, 1.0);
        a.0 + f * (b.0 - a.0)
    };
    let step = (b.1.d - a.1.d).abs();
    let near = |r: &Reading| r.s.abs() <= r.rad + step;
    if near(&a.1) && near(&b.1) {
        return Some(at(&a, &b));
    }
    // Not close in depth: the ray passed into the shadow of a surface from the side, or
    // crossed a surface seen at grazing incidence, whose stored depth steps by more than its
    // noise from one pixel to the next. Halve on to neighbouring pixels and ask whether their
    // stored points lie on one surface.
    let adjacent =
        |a: &Reading, b: &Reading| (a.px.0 - b.px.0).abs().max((a.px.1 - b.px.1).abs()) <= 1;
    for _ in 0..8 {
        if adjacent(&a.1, &b.1) {
            break;
        }
        halve(&mut a, &mut b)?;
    }
    (adjacent(&a.1, &b.1) && l.continuous(&a.1, &b.1)).then(|| at(&a, &b))
}

/// Distance along `omega` to the first hit that holds (`∞`: none within the reach).
/// `prev` is scratch room for one reading per lens.
fn march(
    lenses: &[Lens<'_>],
    pt: &Shaded<'_>,
    omega: Vec3,
    jit: f32,
    prm: &UnionParams,
    prev: &mut Vec<Option<Reading>>,
) -> f32 {
    let steps = prm.steps.max(1);
    let t0 = pt.rad;
    let span = (prm.reach - t0).max(0.0);
    prev.clear();
    prev.resize(lenses.len(), None);
    let mut t_prev = 0.0f32;
    for k in 0..steps {
        let u = (k as f32 + jit) / steps as f32;
        let t = t0 + span * u * u;
        let q = pt.p + omega * t;
        let mut best: Option<(f32, usize, f32, Evidence)> = None;
        for (j, l) in lenses.iter().enumerate() {
            let cur = l.read(q);
            let Some(c) = cur else {
                prev[j] = None;
                continue;
            };
            let InView {
                p: pj,
                n: nj,
                infers,
            } = pt.in_view[j];
            // Behind the stored surface by more than noise: the ray crossed it since the
            // previous sample (surface evidence at the crossing) or lies within the
            // thickness (inferred).
            let thick = solid_depth(prm.thickness, l.pixel_size(c.d));
            let cand = match prev[j] {
                _ if c.s <= 0.25 * c.rad => None,
                Some(pv) if pv.s < 0.0 => match crossing(l, pt.p, omega, (t_prev, pv), (t, c)) {
                    Some(tc) => Some((tc, Evidence::Surface)),
                    None if infers && c.s <= thick && l.enclosed(&c) => {
                        Some((t, Evidence::Inferred))
                    }
                    None => None,
                },
                _ if infers && c.s <= thick && l.enclosed(&c) => Some((t, Evidence::Inferred)),
                _ => None,
            };
            prev[j] = cur;
            let Some((tc, ev)) = cand else { continue };
            if l.same_surface(c.idx, pj, nj, pt.rad) {
                continue;
            }
            if best.is_none_or(|b| tc < b.0) {
                best = Some((tc, j, c.rad, ev));
            }
        }
        if let Some((tc, j, rad, ev)) = best {
            if holds(lenses, j, rad, pt.p + omega * tc, ev, prm.thickness) {
                return tc;
            }
        }
        if pt.bounds.left(q, omega) {
            break;
        }
        t_prev = t;
    }
    f32::INFINITY
}

/// An orthonormal tangent frame of unit `n`.
fn frame(n: Vec3) -> (Vec3, Vec3) {
    let a = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let t1 = n.cross(a).normalize_or_zero();
    (t1, n.cross(t1))
}

/// What [`shade`] finds at one point.
#[derive(Debug, Clone, Copy)]
struct Shade {
    ao: f32,
    /// Bent normal (its frame; zero when every ray is blocked).
    bent: Vec3,
    /// Distance to the nearest hit of any ray (`∞`: none).
    nearest: f32,
}

/// Occlusion of one point, its bent normal and how near its rays hit.
fn shade(
    lenses: &[Lens<'_>],
    pt: &Shaded<'_>,
    stream: u64,
    prm: &UnionParams,
    prev: &mut Vec<Option<Reading>>,
) -> Shade {
    let half = prm.rays.div_ceil(2).max(1);
    let mut rng = Rng::new(prm.seed, stream);
    let turn = rng.next_f32();
    let (t1, t2) = frame(pt.n);
    const GOLDEN: f32 = 0.618_034;
    let (mut sum, mut bent, mut nearest) = (0.0f32, Vec3::ZERO, f32::INFINITY);
    for r in 0..half {
        let u1 = (r as f32 + rng.next_f32()) / half as f32;
        let phi = std::f32::consts::TAU * (r as f32 * GOLDEN + turn).fract();
        let (sr, cz) = (u1.sqrt(), (1.0 - u1).max(0.0).sqrt());
        for side in [1.0f32, -1.0] {
            let (s, c) = phi.sin_cos();
            let omega =
                (t1 * (side * sr * c) + t2 * (side * sr * s) + pt.n * cz).normalize_or_zero();
            let th = march(lenses, pt, omega, rng.next_f32(), prm, prev);
            nearest = nearest.min(th);
            let v = prm.falloff.rho(th, prm.tmax);
            sum += v;
            bent += omega * v;
        }
    }
    let a = sum / (2 * half) as f32;
    Shade {
        ao: a.clamp(0.0, 1.0),
        bent: bent.normalize_or_zero(),
        nearest,
    }
}

/// The scan being shaded by [`union_scan`].
pub struct UnionTarget<'a> {
    /// Index of the scan (seeds its directions).
    pub index: usize,
    /// Local points.
    pub points: &'a [Vec3],
    /// Radius per point.
    pub radii: &'a [f32],
    /// Pixel of each point in its own map ([`crate::gbuffer::EMPTY`] if outside).
    pub own_pixel: &'a [u32],
    /// Its own view's maps (normals of the points).
    pub own: &'a ViewMaps,
    /// Its own view's projection.
    pub own_proj: &'a Projection,
    /// Local → world.
    pub pose: DMat4,
    /// Fallback AO of points outside their own map.
    pub fallback: &'a [f32],
}

/// Per-thread room of [`union_scan`], so that no point allocates.
#[derive(Default)]
struct Scratch<'a> {
    sub: Vec<Lens<'a>>,
    in_view: Vec<InView>,
    prev: Vec<Option<Reading>>,
}

/// Union occlusion of every point of `t` against `views` (its own among them), and each
/// point's bent normal in its scan's local frame when `bent` is set.
pub fn union_scan(
    t: &UnionTarget<'_>,
    views: &[View<'_>],
    prm: &UnionParams,
    bent: bool,
) -> (Vec<f32>, Option<Vec<Vec3>>) {
    let lenses: Vec<Lens<'_>> = views
        .iter()
        .map(|v| Lens {
            proj: v.proj,
            maps: v.maps,
            rel: Affine3A::from_mat4((v.pose.inverse() * t.pose).as_mat4()),
            pixel: pixel_size(v.proj),
        })
        .collect();
    let bounds = Bounds::of(&lenses, prm);
    let res: Vec<Shade> = (0..t.points.len())
        .into_par_iter()
        .with_min_len(256)
        .map_init(Scratch::default, |sc, i| {
            let ao = t.fallback.get(i).copied().unwrap_or(1.0);
            let unshaded = Shade {
                ao,
                bent: Vec3::ZERO,
                nearest: f32::INFINITY,
            };
            let Some((_, n)) = filter::shaded(t, i) else {
                return unshaded;
            };
            let p = t.points[i];
            let rad = t.radii.get(i).copied().unwrap_or(0.0).max(0.0);
            // Only the views that hold the point's image: the others saw nothing around it.
            sc.sub.clear();
            sc.in_view.clear();
            for l in &lenses {
                if let Some(r) = l.read(p) {
                    sc.sub.push(*l);
                    sc.in_view.push(InView::new(l, &r, p, n, prm.thickness));
                }
            }
            let pt = Shaded {
                p: p + n * (0.5 * rad),
                n,
                rad,
                in_view: &sc.in_view,
                bounds: &bounds,
            };
            let stream = ((t.index as u64) << 40) ^ i as u64;
            shade(&sc.sub, &pt, stream, prm, &mut sc.prev)
        })
        .collect();
    let ao = res.iter().map(|r| r.ao).collect();
    let bn = bent.then(|| res.iter().map(|r| r.bent).collect());
    let nearest: Vec<f32> = res.iter().map(|r| r.nearest).collect();
    filter::smooth(t, ao, bn, &nearest, prm)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ray_has_left_the_bounds_only_outside_and_moving_away() {
        let b = Bounds {
            lo: Vec3::new(-1.0, -2.0, 0.0),
            hi: Vec3::new(1.0, 2.0, 3.0),
        };
        let up = Vec3::Z;
        assert!(!b.left(Vec3::new(0.0, 0.0, 2.9), up), "inside");
        assert!(b.left(Vec3::new(0.0, 0.0, 3.1), up), "above, rising");
        assert!(!b.left(Vec3::new(0.0, 0.0, 3.1), -up), "above, coming back");
        // Outside along x while moving along x towards the box: not yet; once past, yes.
        let d = Vec3::new(1.0, 0.0, 0.1).normalize();
        assert!(!b.left(Vec3::new(-1.5, 0.0, 1.0), d));
        assert!(b.left(Vec3::new(1.5, 0.0, 1.0), d));
        // Parallel to a face beyond it stays beyond it.
        assert!(b.left(Vec3::new(0.0, 2.5, 1.0), Vec3::X));
        assert!(!Bounds::ALL.left(Vec3::splat(1e30), up));
    }
}
