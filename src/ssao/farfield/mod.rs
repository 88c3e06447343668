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
use crate::projection::Projection;
use glam::Vec3A;
use rayon::prelude::*;
use std::f32::consts::{FRAC_PI_2, PI, TAU};

mod sweep;
#[cfg(test)]
mod tests;

use sweep::Family;

/// Samples read one by one around the receiver before block hulls take over.
const NEAR: i64 = 8;
/// Samples per block.
const BLOCK: i64 = 16;
const _: () = assert!(
    BLOCK > 0 && BLOCK.count_ones() == 1,
    "blocks are aligned by masks"
);
/// Largest number of line families.
const MAX_FAMILIES: usize = 64;
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
/// line families (at most 64). A projection whose size differs from the G-buffer's flags every valid pixel.
pub fn ssao(g: &GBuffer, proj: &Projection, prm: &SsaoParams) -> AoMap {
    if let Some(map) = super::unmarchable(g, proj) {
        return map;
    }
    let n = g.width * g.height;
    let mut ao = crate::par::filled(n, 1.0f32);
    let mut flag = crate::par::filled(n, false);
    let k = (4 * prm.directions.max(1) as usize).min(MAX_FAMILIES);
    let fams: Vec<Family> = (0..k).map(|f| Family::new(g, proj, f, k)).collect();
    let pts: Vec<Vec3A> = g.position.iter().map(|&p| Vec3A::from(p)).collect();
    let ctx = Ctx {
        g,
        proj,
        pts: &pts,
        fams: &fams,
    };
    let w = g.width;
    ao.par_chunks_mut(w * TILE_H)
        .zip(flag.par_chunks_mut(w * TILE_H))
        .enumerate()
        .for_each(|(band, (aband, fband))| {
            let mut tile = Tile::new(2 * fams.len());
            for x0 in (0..w).step_by(TILE_W) {
                let x1 = (x0 + TILE_W).min(w);
                tile.run(&ctx, band * TILE_H, x0..x1, aband, fband);
            }
        });
    AoMap {
        ao,
        no_sample: flag,
        levels: None,
    }
}

/// What every pixel evaluation reads.
struct Ctx<'a> {
    g: &'a GBuffer,
    proj: &'a Projection,
    pts: &'a [Vec3A],
    fams: &'a [Family],
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
struct Frame {
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
    ) {
        let w = ctx.g.width;
        let rows = aband.len() / w;
        self.frames.clear();
        for dy in 0..rows {
            for x in xs.clone() {
                let c = (y0 + dy) * w + x;
                if ctx.g.is_valid(c) {
                    let f = ctx.frame(x, y0 + dy, c);
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
                let (added, seen) = ctx.half_planes(f, fam, &mut self.nodes[at..at + 2]);
                self.count[j] += added;
                self.any[j] |= seen;
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
    /// The frame of valid pixel `c = (x, y)`; `None` when it must be flagged.
    fn frame(&self, x: usize, y: usize, c: usize) -> Option<Frame> {
        let p = self.g.position[c];
        let len = self.g.normal[c].length();
        if !(len > 1e-6 && len.is_finite() && p.is_finite()) {
            return None;
        }
        let nrm = Vec3A::from(self.g.normal[c] / len);
        let view = Vec3A::from(self.proj.toward_sensor(p));
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

    /// The nodes of the two half-planes of `fam`'s line through the pixel, written to `out`:
    /// how many, and whether any valid sample was read.
    fn half_planes(&self, f: &Frame, fam: &Family, out: &mut [Node]) -> (usize, bool) {
        let Some((line, i)) = fam.locate(f.centre, -f.view) else {
            return (0, false);
        };
        let m = fam.normal(line);
        let Some(back) = (m.cross(f.view)).try_normalize() else {
            return (0, false);
        };
        let (mut count, mut any) = (0, false);
        for (u, dir) in [(back, -1i64), (-back, 1i64)] {
            let b = f.nrm.dot(u);
            let Some(half) = Half::new(f.a, b, u, f.view, f.nrm) else {
                continue;
            };
            let (blocked, seen) = fam.horizon(line, i, dir, f.c, f.pa, &half, self.pts);
            any |= seen;
            let t = half.open();
            out[count] = Node {
                psi: u.dot(f.e2).atan2(u.dot(f.e1)),
                s: (t - blocked).max(0.0),
                t,
            };
            count += 1;
        }
        (count, any)
    }
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
        let gn = b.atan2(a);
        let (lo, hi) = if a > 0.0 {
            (0.0, gn + FRAC_PI_2)
        } else if gn >= FRAC_PI_2 {
            (gn - FRAC_PI_2, PI)
        } else {
            (gn + 1.5 * PI, PI)
        };
        if !(hi > lo) {
            return None;
        }
        // A sample's position `τ` along the tangent line `(a u − b V)/R` and its height
        // `η = n·v/R` above the tangent plane, turned into coordinates along `u` and `V`.
        let inv = 1.0 / r;
        let tl = (u * a - view * b) * inv;
        let fx = tl * (a * inv) + nrm * (b * inv * inv);
        let fy = tl * (-b * inv) + nrm * (a * inv * inv);
        Some(Half {
            a,
            b,
            lo,
            hi,
            cos_hi: hi.cos(),
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

    /// `G(γ) = −(a/4) cos 2γ + (b/2) γ − (b/4) sin 2γ`, the antiderivative of `f`.
    fn g(&self, gamma: f32) -> f32 {
        let (s, c) = gamma.sin_cos();
        -0.25 * self.a * (c * c - s * s) + 0.5 * self.b * (gamma - s * c)
    }

    /// `T = G(hi) − G(lo)`.
    fn open(&self) -> f32 {
        (self.g(self.hi) - self.g(self.lo)).max(0.0)
    }

    /// `∫ f` over the arc from `l` (given as `cos l`) to `upper`, within `[lo, hi]`. An arc
    /// that ends at `hi` and starts within 10⁻⁵ rad of it is empty (rounding noise of a plane).
    pub(crate) fn blocked(&self, cos_l: f32, upper: f32) -> f32 {
        let l = cos_l.clamp(-1.0, 1.0).acos();
        if upper >= self.hi && l > self.hi - 1e-5 {
            return 0.0;
        }
        let (a, b) = (l.max(self.lo), upper.min(self.hi));
        if b > a {
            (self.g(b) - self.g(a)).max(0.0)
        } else {
            0.0
        }
    }

    /// `cos γ` of a sample at offset `v` from the receiver, `None` when it is not in the
    /// half-plane (behind the line of `V`, or at the receiver).
    #[inline]
    pub(crate) fn cos_gamma(&self, v: Vec3A) -> Option<f32> {
        let (x, y) = (v.dot(self.fx), v.dot(self.fy));
        let l2 = x * x + y * y;
        (x > 0.0 && l2 > 0.0).then(|| y / l2.sqrt())
    }
}
