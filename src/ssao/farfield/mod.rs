//! Far-field obscurance by line sweeps (after Timonen 2013): plain ambient occlusion
//! (`ρ ≡ 0` in range, i.e. `t_max = ∞`) from the whole map at a cost that does not depend on how
//! far the occluders are.
//!
//! The estimator is the horizon estimator's (see [`super::horizon`]): half-planes around the
//! view direction `V`, each giving `S = G(h) − G(lo)` for its final horizon `h` and the open
//! value `T = G(hi) − G(lo)`, and `a = Σ w S / Σ w T`. With `ρ ≡ 0` a blocked direction adds
//! nothing whatever its distance, so a half-plane needs only which arcs of directions the map's
//! samples on it block (`S = T − ∫ f` over them), which is what a sweep shares between pixels.
//! A sample at `γ` from `V` and `φ` round from the receiver (seen from the sensor) is solid
//! behind and blocks `[γ, π − φ)` (see `sweep.rs`); on straight lines `φ` is small and this is
//! the horizon estimator's `[γ, hi]`.
//!
//! # Lines
//!
//! A half-plane through the sensor direction is the image of a plane through the sensor. The
//! map is covered by `K = 4 × directions` families (at most 64) of such planes, each family a set of
//! lines one pixel apart, each line sampled once per pixel of length:
//!
//! - pinhole and orthographic maps: parallel straight screen lines at angle `πk/K` (the image
//!   of a plane through the pinhole, or containing the view axis, is a straight line);
//! - equirectangular maps: the great circles through an axis `a_k` (the meridians of a frame
//!   whose pole is `a_k`), `π |s_y|` circles of `2π |s_y|` samples; the axes are spread over a
//!   hemisphere (Fibonacci). A circle is a closed loop through every azimuth, so the seam and
//!   the map's poles are points like any other.
//!
//! Each pixel is snapped to the nearest line of each family and to its nearest sample on it;
//! the line's plane gives two half-planes, backwards and forwards along the line. On a circle a
//! half-plane holds the samples less than π round from the pixel (beyond, the samples are on
//! the other side of `V`).
//!
//! # Peaks of a block
//!
//! A line is cut into blocks of [`BLOCK`] samples, and each block keeps only the vertices of the
//! convex hull of its points in the line's plane. Seen from a pixel outside the block's angular
//! range (every pixel of the line but the block's own), the lowest horizon over the block's
//! points is reached at a hull vertex: the tangent from the pixel to the hull. A hull stands for
//! its block when every sample of the block is within reach of the blocked arc so far (then
//! each only lowers it); otherwise the block's samples are read in order. The vertices are
//! the block's peaks as seen from *any* receiver, exactly, where the paper keeps two receiver
//! angles per interval.
//!
//! # Hand-over
//!
//! Samples within [`NEAR`] pixels of the pixel along the line, and up to the first block
//! boundary beyond, are read one by one (the receiver's own neighbourhood, where a block would
//! hold the receiver or straddle `V`); the rest of the half-plane by block hulls. The cost per
//! pixel and half-plane is at most `NEAR + 2·BLOCK` samples plus the hull vertices of
//! `length / BLOCK` blocks: it depends on the map's size, never on `t_max`.
//!
//! On straight lines (pinhole and orthographic maps) the same horizons are found in one pass
//! per line instead (`screen.rs`): the hull of the samples passed so far, kept on a stack in a
//! chart where the sensor is at infinity, answers every pixel snapped to the line; the block
//! walk stays for great circles.
//!
//! A sample's in-plane coordinates are taken as in the horizon march (its position along the
//! half-plane's tangent line and its height above `p`'s tangent plane), so a sample of `p`'s
//! own plane never occludes `p` even when the snapped line passes beside `p`.
//!
//! # Weights
//!
//! The half-plane directions `ψ` of a pixel are not evenly spaced (straight screen lines image
//! to directions around `V` that depend on the pixel, and so do great circles through fixed
//! axes): each half-plane is weighted by half the angle between its neighbours in `ψ`, the
//! trapezoid rule of `(1/π) ∫ S dψ`.
//!
//! Conventions shared with the horizon estimator: a pixel with a bad normal, or none of whose
//! half-planes held a valid sample, keeps `a = 1` and is flagged. The result does not depend on
//! the seed (no random numbers) nor on the thread count.

use super::{AoMap, SsaoParams};
use crate::gbuffer::GBuffer;
use crate::projection::{fast_atan2, Model, Projection};
use glam::Vec3A;
use rayon::prelude::*;
use std::f32::consts::{FRAC_PI_2, PI, TAU};

mod screen;
mod sweep;
#[cfg(test)]
pub(crate) mod tests;

use sweep::Family;

/// Samples read one by one around the receiver before block hulls take over.
const NEAR: i64 = 8;
/// Samples per block.
const BLOCK: i64 = 16;
const _: () = assert!(
    BLOCK > 0 && BLOCK.count_ones() == 1,
    "blocks are aligned by masks"
);
/// A horizon counts as raised (for a pixel's reach) when its cosine exceeds the tangent
/// plane's by this much: samples of the pixel's own plane differ from it by rounding only.
const RAISE: f32 = 1e-4;
/// A sample whose offset from the receiver lies within the half-plane by less than this share
/// of its length is beside it, not in it (a neighbour across the line of a pixel the line
/// passes beside).
const BESIDE: f32 = 0.05;
/// Largest number of line families.
const MAX_FAMILIES: usize = 64;
/// Bytes a family and its block hulls hold per pixel of an equirectangular map (each sample's
/// pixel, the hull vertices, each block's range and sphere at every level): 10.1 measured on
/// a 1024×512 court; the straight-line sweeps hold less.
pub const BYTES_PER_PIXEL_AND_FAMILY: u64 = 11;
/// Rows and columns of the pixel tiles evaluated family by family: neighbouring receivers
/// snap to neighbouring lines and read the same blocks, which stay in cache across the tile.
const TILE_H: usize = 8;
const TILE_W: usize = 32;

/// Whether `prm` asks for plain ambient occlusion, the quantity the sweeps compute: a falloff
/// that blocks every direction at a finite distance (`t_max = ∞`). Every other falloff is left
/// to the horizon march.
pub fn applies(prm: &SsaoParams) -> bool {
    prm.falloff.blocks_fully(prm.tmax)
}

/// Computes the unblurred plain ambient occlusion of every valid pixel from `4 × directions`
/// line families (at most 64). A projection whose size differs from the G-buffer's flags every
/// valid pixel.
pub fn ssao(g: &GBuffer, proj: &Projection, prm: &SsaoParams) -> AoMap {
    Sweeps::new(g, proj, prm).eval(None).0
}

/// Line families of the sweeps: `4 × directions`, at most 64.
pub fn families(prm: &SsaoParams) -> usize {
    (4 * prm.directions.max(1) as usize).min(MAX_FAMILIES)
}

/// The sweeps of one map, set up once for evaluations of several sets of pixels (the levels of
/// [`super::multires`]): on equirectangular maps the circle families with their block hulls,
/// which cost as much to build as a coarse evaluation of the whole map.
pub(crate) struct Sweeps<'a> {
    g: &'a GBuffer,
    proj: &'a Projection,
    /// Line families.
    k: usize,
    /// The map's AO when it cannot be marched (see [`super::unmarchable`]).
    unmarchable: Option<AoMap>,
    /// The families with their hulls (equirectangular maps only) and the points they index.
    circles: Option<(Vec<Family>, Vec<Vec3A>)>,
}

impl<'a> Sweeps<'a> {
    /// Sets up the sweeps of `g` seen by `proj` with `4 × directions` families (at most 64).
    pub(crate) fn new(g: &'a GBuffer, proj: &'a Projection, prm: &SsaoParams) -> Sweeps<'a> {
        let k = families(prm);
        let unmarchable = super::unmarchable(g, proj);
        let circles =
            (unmarchable.is_none() && matches!(proj.model, Model::Equirect { .. })).then(|| {
                let fams: Vec<Family> = (0..k).map(|f| Family::new(g, proj, f, k)).collect();
                let pts: Vec<Vec3A> = g.position.iter().map(|&p| Vec3A::from(p)).collect();
                (fams, pts)
            });
        Sweeps {
            g,
            proj,
            k,
            unmarchable,
            circles,
        }
    }

    /// Whether an evaluation costs in proportion to the pixels it evaluates (the walk over
    /// circles), not a pass over every line that holds one (straight lines).
    pub(crate) fn per_pixel(&self) -> bool {
        self.circles.is_some()
    }

    /// The plain ambient occlusion of the valid pixels `only` marks (all when `None`; the
    /// others keep 1, unflagged), and each pixel's *reach*: the distance to the nearest sample
    /// that bounds the blocked arc of one of its half-planes (∞ where no horizon rises above
    /// the tangent plane). Obscurance changes on the scale of the reach as the pixel moves.
    pub(crate) fn eval(&self, only: Option<&[bool]>) -> (AoMap, Vec<f32>) {
        if let Some(map) = &self.unmarchable {
            let map = map.clone();
            let reach = vec![f32::INFINITY; map.ao.len()];
            return (map, reach);
        }
        match &self.circles {
            Some((fams, pts)) => walk(self.g, self.proj, fams, pts, only),
            None => screen::ssao(self.g, self.proj, self.k, only),
        }
    }
}

/// The far field of the pixels `only` marks by each one's own walk along the lines of the
/// families `fams` (over `pts`, the map's points), over block hulls.
fn walk(
    g: &GBuffer,
    proj: &Projection,
    fams: &[Family],
    pts: &[Vec3A],
    only: Option<&[bool]>,
) -> (AoMap, Vec<f32>) {
    let n = g.width * g.height;
    let mut reach = crate::par::filled(n, f32::INFINITY);
    let mut ao = crate::par::filled(n, 1.0f32);
    let mut flag = crate::par::filled(n, false);
    let ctx = Ctx {
        g,
        proj,
        pts,
        fams,
        only,
    };
    let w = g.width;
    ao.par_chunks_mut(w * TILE_H)
        .zip(flag.par_chunks_mut(w * TILE_H))
        .zip(reach.par_chunks_mut(w * TILE_H))
        .enumerate()
        .for_each(|(band, ((aband, fband), rband))| {
            let mut tile = Tile::new(2 * fams.len());
            for x0 in (0..w).step_by(TILE_W) {
                let x1 = (x0 + TILE_W).min(w);
                tile.run(&ctx, band * TILE_H, x0..x1, aband, fband, rband);
            }
        });
    let map = AoMap {
        ao,
        no_sample: flag,
        levels: None,
    };
    (map, reach)
}

/// What every pixel evaluation reads.
struct Ctx<'a> {
    g: &'a GBuffer,
    proj: &'a Projection,
    pts: &'a [Vec3A],
    fams: &'a [Family],
    only: Option<&'a [bool]>,
}

/// One half-plane's contribution: its direction `ψ` around `V`, `S` and `T`.
#[derive(Debug, Clone, Copy, Default)]
struct Node {
    psi: f32,
    s: f32,
    t: f32,
}

/// What a pixel's half-planes share: its point, normal and frame around `V`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Frame {
    c: usize,
    centre: (f32, f32),
    pa: Vec3A,
    nrm: Vec3A,
    view: Vec3A,
    e1: Vec3A,
    e2: Vec3A,
    /// `n·V`.
    a: f32,
}

/// The pixels of one tile, their frames and the half-plane nodes gathered so far.
struct Tile {
    frames: Vec<Option<Frame>>,
    /// `per` nodes per pixel, `count` of them filled.
    nodes: Vec<Node>,
    count: Vec<usize>,
    any: Vec<bool>,
    per: usize,
}

impl Tile {
    fn new(per: usize) -> Tile {
        let n = TILE_H * TILE_W;
        Tile {
            frames: Vec::with_capacity(n),
            nodes: vec![Node::default(); n * per],
            count: Vec::with_capacity(n),
            any: Vec::with_capacity(n),
            per,
        }
    }

    /// Evaluates the valid pixels of columns `xs` in the rows of a band starting at row `y0`
    /// (`aband` and `fband` hold the band's AO and flags), every family in turn over the tile.
    fn run(
        &mut self,
        ctx: &Ctx,
        y0: usize,
        xs: std::ops::Range<usize>,
        aband: &mut [f32],
        fband: &mut [bool],
        rband: &mut [f32],
    ) {
        let w = ctx.g.width;
        let rows = aband.len() / w;
        self.frames.clear();
        for dy in 0..rows {
            for x in xs.clone() {
                let c = (y0 + dy) * w + x;
                if ctx.g.is_valid(c) && ctx.only.is_none_or(|m| m[c]) {
                    let f = frame(ctx.g, ctx.proj, x, y0 + dy, c);
                    if f.is_none() {
                        fband[dy * w + x] = true;
                    }
                    self.frames.push(f);
                }
            }
        }
        let n = self.frames.len();
        self.count.clear();
        self.count.resize(n, 0);
        self.any.clear();
        self.any.resize(n, false);
        for fam in ctx.fams {
            for (j, f) in self.frames.iter().enumerate() {
                let Some(f) = f else { continue };
                let at = j * self.per + self.count[j];
                let (added, seen, reach) = ctx.half_planes(f, fam, &mut self.nodes[at..at + 2]);
                self.count[j] += added;
                self.any[j] |= seen;
                let r = &mut rband[f.c - y0 * w];
                *r = r.min(reach);
            }
        }
        for (j, f) in self.frames.iter().enumerate() {
            let Some(f) = f else { continue };
            let i = f.c - y0 * w;
            if !self.any[j] {
                fband[i] = true;
                continue;
            }
            let nodes = &mut self.nodes[j * self.per..j * self.per + self.count[j]];
            let a = weighted(nodes);
            if a.is_finite() {
                aband[i] = a.clamp(0.0, 1.0);
            } else {
                fband[i] = true;
            }
        }
    }
}

impl Ctx<'_> {
    /// The nodes of the two half-planes of `fam`'s line through the pixel, written to `out`:
    /// how many, whether any valid sample was read, and their reach.
    fn half_planes(&self, f: &Frame, fam: &Family, out: &mut [Node]) -> (usize, bool, f32) {
        let none = (0, false, f32::INFINITY);
        let Some((line, i)) = fam.lines.locate(f.centre, -f.view) else {
            return none;
        };
        let m = fam.lines.normal(line);
        let Some(back) = (m.cross(f.view)).try_normalize() else {
            return none;
        };
        let (mut count, mut any, mut reach) = none;
        for (u, dir) in [(back, -1i64), (-back, 1i64)] {
            let b = f.nrm.dot(u);
            let Some(half) = Half::new(f.a, b, u, f.view, f.nrm) else {
                continue;
            };
            let (blocked, seen, r) = fam.horizon(line, i, dir, f.c, f.pa, &half, self.pts);
            any |= seen;
            reach = reach.min(r);
            let t = half.open();
            out[count] = Node {
                psi: u.dot(f.e2).atan2(u.dot(f.e1)),
                s: (t - blocked).max(0.0),
                t,
            };
            count += 1;
        }
        (count, any, reach)
    }
}

/// The frame of valid pixel `c = (x, y)`; `None` when it must be flagged.
fn frame(g: &GBuffer, proj: &Projection, x: usize, y: usize, c: usize) -> Option<Frame> {
    let p = g.position[c];
    let len = g.normal[c].length();
    if !(len > 1e-6 && len.is_finite() && p.is_finite()) {
        return None;
    }
    let nrm = Vec3A::from(g.normal[c] / len);
    let view = Vec3A::from(proj.toward_sensor(p));
    if !(view.length_squared() > 0.5) {
        return None;
    }
    let (e1, e2) = view.any_orthonormal_pair();
    Some(Frame {
        c,
        centre: (x as f32 + 0.5, y as f32 + 0.5),
        pa: Vec3A::from(p),
        nrm,
        view,
        e1,
        e2,
        a: nrm.dot(view),
    })
}

/// `G(γ) = −(a/4) cos 2γ + (b/2) γ − (b/4) sin 2γ`, the antiderivative of
/// `f(γ) = (a cos γ + b sin γ) sin γ`, from `γ`, `cos γ` and `sin γ`.
#[inline]
fn g_of(a: f32, b: f32, gamma: f32, c: f32, s: f32) -> f32 {
    -0.25 * a * (c * c - s * s) + 0.5 * b * (gamma - s * c)
}

/// `Σ w S / Σ w T` with each node weighted by half the angle between its neighbours in `ψ`
/// (1 when the sum of `T` is zero: nothing faces away from the surface).
fn weighted(nodes: &mut [Node]) -> f32 {
    let n = nodes.len();
    if n == 0 {
        return 1.0;
    }
    nodes.sort_unstable_by(|p, q| p.psi.total_cmp(&q.psi));
    let (mut s, mut t) = (0.0f32, 0.0f32);
    for j in 0..n {
        let w = if n == 1 {
            1.0
        } else {
            let prev = nodes[(j + n - 1) % n].psi;
            let next = nodes[(j + 1) % n].psi;
            0.5 * (next - prev).rem_euclid(TAU)
        };
        s += w * nodes[j].s;
        t += w * nodes[j].t;
    }
    if t > 0.0 {
        s / t
    } else {
        1.0
    }
}

/// One half-plane `ω = cos γ V + sin γ u` of a pixel: `f(γ) = max(a cos γ + b sin γ, 0) sin γ`
/// is positive on `[lo, hi]`; `fx`, `fy` give a sample's in-plane coordinates from its offset.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Half {
    a: f32,
    b: f32,
    lo: f32,
    pub(crate) hi: f32,
    /// `cos hi`.
    pub(crate) cos_hi: f32,
    /// `G(lo)` and `G(hi)`.
    g_lo: f32,
    g_hi: f32,
    pub(crate) fx: Vec3A,
    pub(crate) fy: Vec3A,
    /// A bound on how far `(v·fx, v·fy)` moves per unit of `v` (`√(|fx|² + |fy|²)`).
    stretch: f32,
}

impl Half {
    /// `None` when the half-plane holds no direction above the tangent plane.
    fn new(a: f32, b: f32, u: Vec3A, view: Vec3A, nrm: Vec3A) -> Option<Half> {
        let r = (a * a + b * b).sqrt();
        if !(r > 1e-6 && r.is_finite()) {
            return None;
        }
        let gn = fast_atan2(b, a);
        let (cn, sn) = (a / r, b / r);
        // Each end as (γ, cos γ, sin γ): γ = gn ± π/2 has cos = ∓ sin gn, sin = ± cos gn.
        let (lo, hi) = if a > 0.0 {
            ((0.0, 1.0, 0.0), (gn + FRAC_PI_2, -sn, cn))
        } else if gn >= FRAC_PI_2 {
            ((gn - FRAC_PI_2, sn, -cn), (PI, -1.0, 0.0))
        } else {
            ((gn + 1.5 * PI, sn, -cn), (PI, -1.0, 0.0))
        };
        if !(hi.0 > lo.0) {
            return None;
        }
        // A sample's position `τ` along the tangent line `(a u − b V)/R` and its height
        // `η = n·v/R` above the tangent plane, turned into coordinates along `u` and `V`.
        let inv = 1.0 / r;
        let tl = (u * a - view * b) * inv;
        let fx = tl * (a * inv) + nrm * (b * inv * inv);
        let fy = tl * (-b * inv) + nrm * (a * inv * inv);
        let g = |(gamma, c, s): (f32, f32, f32)| g_of(a, b, gamma, c, s);
        Some(Half {
            a,
            b,
            lo: lo.0,
            hi: hi.0,
            cos_hi: hi.1,
            g_lo: g(lo),
            g_hi: g(hi),
            fx,
            fy,
            stretch: (fx.length_squared() + fy.length_squared()).sqrt(),
        })
    }

    /// Whether any point of the sphere `sph` (centre, radius) may have a `cos γ` above `cur`
    /// as seen from `pa`: false only when the disk it maps to lies wholly below that horizon
    /// (with a margin for rounding).
    #[inline]
    pub(crate) fn may_raise(&self, sph: glam::Vec4, pa: Vec3A, cur: f32) -> bool {
        let v = Vec3A::new(sph.x, sph.y, sph.z) - pa;
        let (x, y) = (v.dot(self.fx), v.dot(self.fy));
        let r = sph.w * self.stretch;
        let d2 = x * x + y * y;
        if !(d2 > r * r) {
            return true;
        }
        let d = d2.sqrt();
        // The disk spans the directions within δ = asin(r/d) of its centre's, at γ0 from V.
        let (cos_g0, sin_g0, sin_d) = (y / d, x.abs() / d, r / d);
        let cos_d = (1.0 - sin_d * sin_d).max(0.0).sqrt();
        cos_g0 >= cos_d || cos_g0 * cos_d + sin_g0 * sin_d > cur - 1e-5
    }

    /// `T = G(hi) − G(lo)`.
    fn open(&self) -> f32 {
        (self.g_hi - self.g_lo).max(0.0)
    }

    /// `∫ f` over the arc from `l` (given as `cos l`) to `upper`, within `[lo, hi]`. An arc
    /// that ends at `hi` and starts within 10⁻⁵ rad of it is empty (rounding noise of a plane).
    pub(crate) fn blocked(&self, cos_l: f32, upper: f32) -> f32 {
        let cl = cos_l.clamp(-1.0, 1.0);
        let sl = (1.0 - cl * cl).max(0.0).sqrt();
        let l = fast_atan2(sl, cl);
        if upper >= self.hi && l > self.hi - 1e-5 {
            return 0.0;
        }
        let (from, g_from) = if l > self.lo {
            (l, g_of(self.a, self.b, l, cl, sl))
        } else {
            (self.lo, self.g_lo)
        };
        let (to, g_to) = if upper >= self.hi {
            (self.hi, self.g_hi)
        } else {
            let (s, c) = upper.sin_cos();
            (upper, g_of(self.a, self.b, upper, c, s))
        };
        if to > from {
            (g_to - g_from).max(0.0)
        } else {
            0.0
        }
    }

    /// `cos γ` of a sample at offset `v` from the receiver, `None` when it is not in the
    /// half-plane (behind the line of `V`, at the receiver, or beside the half-plane: its
    /// offset within it under [`BESIDE`] of its length, where rounding alone would set its
    /// direction).
    #[inline]
    pub(crate) fn cos_gamma(&self, v: Vec3A) -> Option<f32> {
        let (x, y) = (v.dot(self.fx), v.dot(self.fy));
        let l2 = x * x + y * y;
        let beside = !(l2 > BESIDE * BESIDE * v.length_squared());
        (x > 0.0 && !beside).then(|| y / l2.sqrt())
    }
}
