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
//! `h₀ = rad(p) + rad` of `p`'s tangent plane with a normal within 60° of `n` is `p`'s
//! own surface as that view sampled it (with its noise and registration error), and is
//! ignored; a wall meeting the surface (a normal far from `n`) still counts.
//!
//! Far-face rule: a view in whose solid depth `p` lies, facing away from it, infers nothing
//! for `p`'s rays: `p` is then the far face of an element thinner than that depth, and the
//! view knows nothing of the space beyond it.
//!
//! Cost: a ray's samples fall scattered over the maps, and most of them, in most views, are
//! in front of every stored surface, deep behind one (a view that sees the point's surface
//! from behind), or over empty pixels. On orthographic and pinhole maps each view keeps per
//! tile of 8 × 8 pixels which pixels hold a point and the range of their depths
//! (`front.rs`), and every six samples of a ray are first tested together: the image of the
//! segment holding them is a segment, so the tiles it touches settle the run without
//! projecting the samples between; a sample that is not settled is still told in front or
//! deep from its own tile without reading its pixel. The answers are the ones reading every
//! pixel gives (a unit test checks runs against each sample; outputs are byte-identical).
//! Equirectangular maps read every sample: their segments' images are arcs.

use super::{View, ViewMaps};
use crate::falloff::Falloff;
use crate::projection::{floor_i64, Model, Projected, Projection};
use crate::rng::Rng;
use glam::{Affine3A, DMat4, Vec3, Vec3A, Vec4};
use rayon::prelude::*;
use serde::Serialize;

mod filter;
mod front;
mod mode;
mod site;

use front::{FrontTiles, Seen, Span};
pub use mode::{Occlusion, AUTO_RAYS, UNION_RAYS};
use site::Bounds;

/// Bytes per pixel of each view the union packs for itself while it shades a scan (the stored
/// depths and radii, [`Lens`]).
pub const BYTES_PER_VIEW_PIXEL: u64 = 8;

/// Default radius in pixels of the union's edge-aware smoothing ([`UnionParams::filter`]).
pub const FILTER_RADIUS: u32 = 3;

/// Default of [`UnionParams::views`]. At `t_max = ∞` every all-round station holds every
/// point's image, so without a cap a point's cost grows with the site; on open scenes of six
/// and eight stations four scored within −6 % to +4 % of every view's e_A at about half the
/// time (`docs/accuracy.md`).
pub const MAX_VIEWS: u32 = 4;

/// Height over `p`'s tangent plane, in `rad(p) + rad` of the stored point, below which a
/// stored point of a surface turned less than 60° from `p`'s is `p`'s own surface. Scored
/// against true surfaces (`docs/accuracy.md`): 2 hid the gentle relief of the real bunny
/// (too open), 1/2 let its registration residue occlude it.
const SAME_BAND: f32 = 1.0;

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
    /// Most views a point's rays are marched through ([`view_rank`] chooses; 0: every view
    /// that holds the point's image).
    pub views: u32,
}

/// One view as the rays see it: its maps and the transform from the target's frame.
#[derive(Clone, Copy)]
struct Lens<'a> {
    proj: &'a Projection,
    maps: &'a ViewMaps,
    rel: Affine3A,
    /// A pixel's size in metres at depth `d` is `pixel.0 + pixel.1 · d` (at the map's centre).
    pixel: (f32, f32),
    /// What a sample's pixel holds, known without reading the pixel; only on maps where
    /// [`Lens::run`] settles runs of samples (elsewhere the pixel is read: without runs the
    /// tiles cost more than they save, measured on equirectangular maps of 360×180 and
    /// 1024×512).
    front: Option<&'a FrontTiles>,
    /// Each pixel's stored depth and radius (radius −∞: empty), packed apart from the
    /// positions: the rays read pixels all over the map, and half the bytes per pixel keep
    /// twice as many of them in cache.
    stored: &'a [[f32; 2]],
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

/// [`Lens::depth`] of `p` in a view projecting with `proj`.
#[inline]
fn depth_in(proj: &Projection, p: Vec3) -> f32 {
    match proj.model {
        Model::Ortho { toward, depth0, .. } => depth0 - toward.dot(p),
        _ => p.length(),
    }
}

/// The depth and radius stored at each pixel of `maps` seen by `proj` ([`Lens::stored`]).
fn pack_stored(proj: &Projection, maps: &ViewMaps) -> Vec<[f32; 2]> {
    maps.near
        .par_iter()
        .map(|q| match q.w {
            f32::NEG_INFINITY => [0.0, f32::NEG_INFINITY],
            w => [depth_in(proj, q.truncate()), w.max(1e-6)],
        })
        .collect()
}

/// A point in a view's frame and its projection there.
#[derive(Debug, Clone, Copy)]
struct Spot {
    qj: Vec3,
    pr: Projected,
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

impl Reading {
    /// In front of the stored surface, or behind it by no more than its noise.
    #[inline]
    fn in_front(&self) -> bool {
        self.s <= 0.25 * self.rad
    }
}

impl Lens<'_> {
    /// Depth of the point stored at pixel `idx`, and its radius (`None`: empty).
    #[inline]
    fn stored(&self, idx: usize) -> Option<(f32, f32)> {
        let &[depth, rad] = self.stored.get(idx)?;
        (rad != f32::NEG_INFINITY).then_some((depth, rad))
    }

    /// The depth `project` gives `p` (view frame), without the angles: the distance to the
    /// sensor, or the distance along an orthographic view's axis.
    #[inline]
    fn depth(&self, p: Vec3) -> f32 {
        depth_in(self.proj, p)
    }

    /// `q` (target frame) in the view's frame and projected (`None`: no image, or no finite
    /// depth).
    #[inline]
    fn spot(&self, q: Vec3) -> Option<Spot> {
        let qj: Vec3 = self.rel.transform_point3a(Vec3A::from(q)).into();
        let pr = self.proj.project(qj)?;
        pr.depth.is_finite().then_some(Spot { qj, pr })
    }

    /// The pixel of a spot, its index and its depth.
    #[inline]
    fn pixel_of(&self, Spot { pr, .. }: Spot) -> Option<((i64, i64), usize, f32)> {
        let px = (floor_i64(pr.x), floor_i64(pr.y));
        let idx = self.proj.pixel_at(px.0, px.1)?;
        Some((px, idx, pr.depth))
    }

    /// The reading of a point at depth `d` in pixel `idx` (at `px`).
    #[inline]
    fn at(&self, px: (i64, i64), idx: usize, d: f32) -> Option<Reading> {
        let (dd, rad) = self.stored(idx)?;
        Some(Reading {
            s: d - dd,
            d,
            rad,
            idx,
            px,
        })
    }

    /// The view's reading at `q` (target frame).
    #[inline]
    fn read(&self, q: Vec3) -> Option<Reading> {
        self.read_spot(self.spot(q))
    }

    /// [`Lens::read`] of a point already projected.
    #[inline]
    fn read_spot(&self, spot: Option<Spot>) -> Option<Reading> {
        let (px, idx, d) = self.pixel_of(spot?)?;
        self.at(px, idx, d)
    }

    /// What the view says of a ray's sample projected at `spot`: the tiles, where there are
    /// any, tell most samples in front of every stored surface, or deep behind (more than
    /// the solid depth for `thickness`), apart without reading their pixel.
    #[inline(always)]
    fn probe_spot(&self, spot: Option<Spot>, thickness: f32) -> Probe {
        let Some((px, idx, d)) = spot.and_then(|s| self.pixel_of(s)) else {
            return Probe::Nothing;
        };
        let solid = || solid_depth(thickness, self.pixel_size(d));
        let seen = match self.front {
            Some(f) => f.seen(idx, px.1 as usize, d, solid),
            None => Seen::Unknown,
        };
        match seen {
            Seen::Empty => Probe::Nothing,
            Seen::Front => Probe::Front,
            Seen::Deep => Probe::Deep,
            Seen::Unknown => self.at(px, idx, d).map_or(Probe::Nothing, Probe::At),
        }
    }

    /// The size of a pixel (metres) at depth `d`: the finest detail the view resolves there.
    #[inline]
    fn pixel_size(&self, d: f32) -> f32 {
        self.pixel.0 + self.pixel.1 * d
    }

    /// What every sample of a ray between the spots `a` and `b` is in the view, known
    /// from the tiles its image touches without projecting the samples between: on
    /// orthographic and pinhole maps the image of a segment (in front of the camera) is a
    /// segment, monotone in each axis through the warps, so its pixels lie in the box of its
    /// ends' (widened by a pixel for rounding). The depth along it lies between its ends'
    /// (orthographic) or between the distance of the sensor to the segment and the larger of
    /// its ends' (pinhole). `None`: it could not be settled.
    fn run(&self, a: Option<Spot>, b: Option<Spot>, thickness: f32) -> Option<Run> {
        let front = self.front?;
        let (Spot { qj: qa, pr: pa }, Spot { qj: qb, pr: pb }) = (a?, b?);
        let (mut dlo, dhi) = (pa.depth.min(pb.depth), pa.depth.max(pb.depth));
        if let Model::Perspective { .. } = self.proj.model {
            let e = qb - qa;
            let l2 = e.length_squared();
            if l2 > 0.0 {
                let u = (-qa.dot(e) / l2).clamp(0.0, 1.0);
                dlo = dlo.min((qa + e * u).length());
            }
        }
        // Rounding of each sample's own transform and projection.
        let pad = 1e-5 * dhi.abs().max(dlo.abs()) + 1e-6;
        let (dlo, dhi) = (dlo - pad, dhi + pad);
        let Span { any, near, far } = front.span(
            floor_i64(pa.x.min(pb.x)).saturating_sub(1),
            floor_i64(pa.y.min(pb.y)).saturating_sub(1),
            floor_i64(pa.x.max(pb.x)).saturating_add(1),
            floor_i64(pa.y.max(pb.y)).saturating_add(1),
        );
        if !any {
            Some(Run::DeepOrEmpty)
        } else if dhi < near {
            Some(Run::FrontOrEmpty)
        } else if dlo - far > solid_depth(thickness, self.pixel_size(dhi)) {
            Some(Run::DeepOrEmpty)
        } else {
            None
        }
    }

    /// What the view says of the space at `q` (target frame), where a ray's march ends.
    fn end_of(&self, q: Vec3, thickness: f32) -> End {
        let Some((px, idx, d)) = self.spot(q).and_then(|s| self.pixel_of(s)) else {
            return End::Unseen;
        };
        match self.at(px, idx, d) {
            // The sensor found nothing along this line of sight.
            None => End::Open,
            Some(r) if r.in_front() => End::Open,
            Some(r) if r.s > solid_depth(thickness, self.pixel_size(d)) => End::Behind,
            Some(_) => End::Unseen,
        }
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
        let h0 = SAME_BAND * (rad_p + near.w.max(0.0));
        nj.dot(n) > 0.5 && (near.truncate() - p).dot(n).abs() < h0
    }
}

/// A view's reading at a ray's sample as the march keeps it.
#[derive(Debug, Clone, Copy)]
enum Probe {
    /// No reading: outside the map, or an empty pixel.
    Nothing,
    /// In front of the stored surface (not read: [`Lens::read`] gives the reading).
    Front,
    /// Behind the stored surface by more than the solid depth (not read).
    Deep,
    /// [`Probe::Front`] or [`Probe::Nothing`], not told apart ([`Run::FrontOrEmpty`]).
    Unsure,
    At(Reading),
}

/// What a run of a ray's samples is known to be in one view without reading them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Run {
    /// Every sample is in front of its pixel's stored surface, or at an empty pixel.
    FrontOrEmpty,
    /// Every sample is deep behind its pixel's stored surface ([`Seen::Deep`]), at an empty
    /// pixel or outside the map.
    DeepOrEmpty,
}

/// What a view says of the place where a ray's march ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum End {
    /// In front of what the view stored there, or on a line of sight that found nothing.
    Open,
    /// Behind a stored surface by more than the solid depth.
    Behind,
    /// Outside the view's frame, or within the solid depth.
    Unseen,
}

/// Samples of a ray tested together by [`Lens::run`].
const RUN: usize = 6;

/// One view's state along a ray.
#[derive(Debug, Clone, Copy)]
struct Track {
    /// The previous sample's probe ([`Probe::Unsure`] inside a front run).
    prev: Probe,
    /// The samples from `from` to before `until` are covered by `run`.
    from: usize,
    until: usize,
    run: Run,
    /// The spot of the sample ending the last run tested, which the next one starts from.
    ahead: (usize, Option<Spot>),
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
    tracks: &mut Vec<Track>,
) -> f32 {
    let steps = prm.steps.max(1) as usize;
    let t0 = pt.rad;
    let span = (prm.reach - t0).max(0.0);
    let t_at = |k: usize| {
        let u = (k as f32 + jit) / steps as f32;
        t0 + span * u * u
    };
    tracks.clear();
    tracks.resize(
        lenses.len(),
        Track {
            prev: Probe::Nothing,
            from: 0,
            until: 0,
            run: Run::DeepOrEmpty,
            ahead: (usize::MAX, None),
        },
    );
    let (mut t_prev, mut t_last) = (0.0f32, 0.0f32);
    for k in 0..steps {
        let t = t_at(k);
        let q = pt.p + omega * t;
        let mut best: Option<(f32, usize, f32, Evidence)> = None;
        for (j, (l, tr)) in lenses.iter().zip(tracks.iter_mut()).enumerate() {
            // Runs of samples a view's tiles settle at once: most samples of most views are
            // in front of every surface, or deep behind one.
            let mut here = (tr.ahead.0 == k).then_some(tr.ahead.1);
            if l.front.is_some() && k >= tr.until && k % RUN == 0 && k + 1 < steps {
                // The segment to the next run's first sample (or the last sample) holds
                // this run's samples, and its end is where the next test starts.
                let end = (k + RUN).min(steps - 1);
                let start = *here.get_or_insert_with(|| l.spot(q));
                tr.ahead = (end, l.spot(pt.p + omega * t_at(end)));
                if let Some(run) = l.run(start, tr.ahead.1, prm.thickness) {
                    // Entering a deep run from in front is a crossing: that sample is read.
                    let enters = matches!(tr.prev, Probe::Front | Probe::Unsure)
                        || matches!(tr.prev, Probe::At(r) if r.s < 0.0);
                    let from = if run == Run::DeepOrEmpty && enters {
                        k + 1
                    } else {
                        k
                    };
                    (tr.from, tr.until, tr.run) = (from, (k + RUN).min(steps), run);
                }
            }
            if (tr.from..tr.until).contains(&k) {
                tr.prev = match tr.run {
                    Run::FrontOrEmpty => Probe::Unsure,
                    Run::DeepOrEmpty => Probe::Nothing,
                };
                continue;
            }
            let spot = here.unwrap_or_else(|| l.spot(q));
            let cur = l.probe_spot(spot, prm.thickness);
            let mut before = std::mem::replace(&mut tr.prev, cur);
            if matches!(before, Probe::Unsure) && matches!(cur, Probe::At(_) | Probe::Deep) {
                // In front or over nothing: its reading, or none.
                before = l
                    .read(pt.p + omega * t_prev)
                    .map_or(Probe::Nothing, Probe::At);
            }
            let now = (t, cur, spot);
            let Some((tc, ev, c)) = candidate(l, pt, omega, prm, (t_prev, before), now, j) else {
                continue;
            };
            if best.is_none_or(|b| tc < b.0) {
                best = Some((tc, j, c.rad, ev));
            }
        }
        if let Some((tc, j, rad, ev)) = best {
            if holds(lenses, j, rad, pt.p + omega * tc, ev, prm.thickness) {
                return tc;
            }
        }
        t_last = t;
        if pt.bounds.left(q, omega) {
            break;
        }
        t_prev = t;
    }
    if !prm.tmax.is_finite() && ends_enclosed(lenses, pt.p + omega * t_last, prm.thickness) {
        return t_last;
    }
    f32::INFINITY
}

/// Whether a ray that ended at `q` without a hit is enclosed all the same: every view holds `q`
/// deep behind a stored surface (it crossed one no view caught, as at a crease, where
/// neighbouring pixels lie on two surfaces). A view that saw `q` open, or misses it, does not.
fn ends_enclosed(lenses: &[Lens<'_>], q: Vec3, thickness: f32) -> bool {
    !lenses.is_empty() && lenses.iter().all(|l| l.end_of(q, thickness) == End::Behind)
}

/// The hit view `l` (the `j`-th) reports on a ray between its previous sample (`before`, at
/// `t_prev`) and this one (`cur`, at `t`, projected at `spot`): a crossing of its stored surface, or a sample
/// within the solid depth behind it; `None` for the point's own surface.
#[inline]
fn candidate(
    l: &Lens<'_>,
    pt: &Shaded<'_>,
    omega: Vec3,
    prm: &UnionParams,
    (t_prev, before): (f32, Probe),
    (t, cur, spot): (f32, Probe, Option<Spot>),
    j: usize,
) -> Option<(f32, Evidence, Reading)> {
    // Deep behind the stored surface, beyond the solid depth: a crossing if the previous
    // sample was in front, and nothing otherwise.
    let c = match (cur, before) {
        (Probe::At(c), _) => c,
        (Probe::Deep, Probe::Front) => l.read_spot(spot)?,
        (Probe::Deep, Probe::At(r)) if r.s < 0.0 => l.read_spot(spot)?,
        _ => return None,
    };
    if c.in_front() {
        return None;
    }
    // The previous sample read again where only its side was kept (the same point, so the
    // same reading).
    let pv = match before {
        Probe::At(r) => Some(r),
        Probe::Front => l.read(pt.p + omega * t_prev),
        // Behind by more than noise, or nothing there: what follows needs only that.
        Probe::Nothing | Probe::Deep | Probe::Unsure => None,
    };
    let InView {
        p: pj,
        n: nj,
        infers,
    } = pt.in_view[j];
    // Behind the stored surface by more than noise: the ray crossed it since the previous
    // sample (surface evidence at the crossing) or lies within the thickness (inferred).
    let thick = solid_depth(prm.thickness, l.pixel_size(c.d));
    let inferred = || infers && c.s <= thick && l.enclosed(&c);
    let cand = match pv {
        Some(pv) if pv.s < 0.0 => match crossing(l, pt.p, omega, (t_prev, pv), (t, c)) {
            Some(tc) => Some((tc, Evidence::Surface)),
            None if inferred() => Some((t, Evidence::Inferred)),
            None => None,
        },
        _ if inferred() => Some((t, Evidence::Inferred)),
        _ => None,
    };
    let (tc, ev) = cand?;
    (!l.same_surface(c.idx, pj, nj, pt.rad)).then_some((tc, ev, c))
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
    prev: &mut Vec<Track>,
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
    prev: Vec<Track>,
    held: Vec<((u8, f32), usize, Reading)>,
}

/// Order in which the views that hold a point's image serve its rays (lower first): its own
/// view, then the views that observed the point (it lies on their stored surface, neither
/// seen through nor hidden deep behind), then the rest; within each, the finer pixel at the
/// point first.
fn view_rank(l: &Lens<'_>, r: &Reading, thickness: f32, own: bool) -> (u8, f32) {
    let px = l.pixel_size(r.d);
    let observed = r.s >= -4.0 * r.rad.max(px) && r.s <= solid_depth(thickness, px);
    (
        if own {
            0
        } else if observed {
            1
        } else {
            2
        },
        px,
    )
}

/// Moves the `cap` best-ranked of `held` (0: all) to its front in view order, so that the
/// result does not depend on the ranking's ties; returns how many are kept.
fn keep_best(held: &mut [((u8, f32), usize, Reading)], cap: usize) -> usize {
    if cap == 0 || held.len() <= cap {
        return held.len();
    }
    // Unstable sorts do not allocate; the index breaks every tie.
    held.sort_unstable_by(|a, b| {
        (a.0 .0.cmp(&b.0 .0))
            .then(a.0 .1.total_cmp(&b.0 .1))
            .then(a.1.cmp(&b.1))
    });
    held[..cap].sort_unstable_by_key(|e| e.1);
    cap
}

/// Union occlusion of every point of `t` against `views` (its own among them), and each
/// point's bent normal in its scan's local frame when `bent` is set.
pub fn union_scan(
    t: &UnionTarget<'_>,
    views: &[View<'_>],
    prm: &UnionParams,
    bent: bool,
) -> (Vec<f32>, Option<Vec<Vec3>>) {
    // Only maps where a segment's image is a segment get tiles (see `Lens::run`).
    let fronts: Vec<Option<FrontTiles>> = views
        .iter()
        .map(|v| {
            let straight = matches!(
                v.proj.model,
                Model::Ortho { .. } | Model::Perspective { .. }
            );
            (straight && !v.proj.wrap_x).then(|| {
                FrontTiles::new(v.maps.width, &v.maps.near, |q| {
                    depth_in(v.proj, q.truncate())
                })
            })
        })
        .collect();
    let stored: Vec<Vec<[f32; 2]>> = views.iter().map(|v| pack_stored(v.proj, v.maps)).collect();
    let lenses: Vec<Lens<'_>> = views
        .iter()
        .zip(&fronts)
        .zip(&stored)
        .map(|((v, front), stored)| Lens {
            proj: v.proj,
            maps: v.maps,
            rel: Affine3A::from_mat4((v.pose.inverse() * t.pose).as_mat4()),
            pixel: pixel_size(v.proj),
            front: front.as_ref(),
            stored,
        })
        .collect();
    let bounds = Bounds::of(&lenses, prm);
    let ranked = prm.views > 0 && lenses.len() > prm.views as usize;
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
            sc.held.clear();
            for (j, l) in lenses.iter().enumerate() {
                if let Some(r) = l.read(p) {
                    // Ranked only where the cap can choose among the site's views.
                    let key = if ranked {
                        view_rank(l, &r, prm.thickness, std::ptr::eq(l.maps, t.own))
                    } else {
                        (0, 0.0)
                    };
                    sc.held.push((key, j, r));
                }
            }
            let kept = keep_best(&mut sc.held, prm.views as usize);
            for &(_, j, r) in &sc.held[..kept] {
                let l = &lenses[j];
                sc.sub.push(*l);
                sc.in_view.push(InView::new(l, &r, p, n, prm.thickness));
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
mod tests;
