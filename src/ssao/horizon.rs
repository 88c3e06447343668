//! Horizon-based obscurance: an estimator of the range map's own ray-traced obscurance
//! `A(p) = (1/π) ∫_Ω ρ(d(p,ω)) max(n·ω, 0) dω` (`ρ = smoothstep(0, t_max, d)`) that converges to
//! it as the budget (directions × steps) grows, and reads exactly 1 on an open plane seen from
//! any angle (unlike eq. 3–5, see the spec's note "Bias of eq. 3–5").
//!
//! # Derivation
//!
//! Let `V` be the unit direction from `p` to the sensor and `u(ψ) = cos ψ e₁ + sin ψ e₂` a unit
//! vector perpendicular to `V`. Every direction `ω ≠ ±V` lies on exactly one half-plane bounded by
//! the line of `V`: `ω = cos γ V + sin γ u(ψ)`, `γ ∈ (0, π)`, `ψ ∈ [0, 2π)`, `dω = sin γ dγ dψ`.
//! With `a = n·V`, `b = n·u`, `n·ω = a cos γ + b sin γ` and
//!
//! ```text
//! A = (1/π) ∫₀^{2π} S(ψ) dψ,   S(ψ) = ∫₀^π ρ(d(γ)) f(γ) dγ,   f(γ) = max(a cos γ + b sin γ, 0) sin γ.
//! ```
//!
//! `f` is positive on one arc `[lo, hi]` of `[0, π]` (for a surface facing the sensor `lo = 0`
//! and `hi` is where the half-plane meets the tangent plane), with antiderivative
//! `G(γ) = −(a/4) cos 2γ + (b/2) γ − (b/4) sin 2γ`. The open value of a half-plane is
//! `T(ψ) = G(hi) − G(lo)`, and `(1/π) ∫ T dψ = 1`.
//!
//! When the surface faces the sensor (`n = V`: `a = 1`, `b = 0`, `hi = π/2`), with the elevation
//! `θ = π/2 − γ` above the tangent plane, `dω = cos θ dθ dψ`, `n·ω = sin θ`, and a half-plane
//! whose horizon rises through elevations `θ_k` at distances `d_k` gives
//! `S/T = Σ ρ(d_k)(sin²θ_k − sin²θ_{k−1}) + (1 − sin²θ_final)`: the normal-centred horizon
//! integral. The half-planes are taken around the *view* direction rather than around `n`
//! because a straight screen line is the image of a plane through the sensor: it contains
//! `n` only when `n` lies in that plane, so slices around `n` would sample the wrong directions
//! on obliquely seen surfaces (on a floor seen at grazing angle most of them never rise more than
//! a few degrees). With view-centred half-planes the tilt is carried exactly by `f`.
//!
//! # Marching a half-plane
//!
//! A half-plane through the sensor direction is seen as a half-line of the image starting at
//! `p`'s pixel (exactly for pinhole and orthographic sensors). On an equirectangular map the
//! image of the plane is a great circle: where the `t_max` sphere spans less than 0.25 rad
//! seen from the sensor, its tangent line is marched (a close approximation); beyond, the
//! circle itself, in equal steps of angle. Seen from the sensor at angle `φ` from `p`, a
//! sample hides only the directions `γ < π − φ` (rays at larger `γ` never come that far
//! round), so on the circle a sample raises the horizon only while `φ ≤ π − h`. Marching it outward gives samples
//! with in-plane coordinates `X` (outward) and `Y` (towards the sensor), at angle
//! `γ = atan2(X, Y)` from `V`. The horizon `h` starts at `hi` (the tangent plane). A sample with
//! `γ_k < h` is visible from `p` and hides the directions `[γ_k, h]` behind it; then `h = γ_k`:
//!
//! ```text
//! S ≈ Σ_k ∫_{γ_k}^{h_{k−1}} ρ(r_k(γ)) f(γ) dγ  +  (G(h_final) − G(lo)).
//! ```
//!
//! `r_k(γ)` is where direction `γ` meets the surface between the previous sample and this one:
//! the segment joining them (the map read as a piecewise-linear profile along the line; the
//! direction passes above the previous sample and below this one, so it crosses the segment),
//! or, for the first sample of the march, the parabola tangent to the tangent plane at `p`
//! through the sample; if neither is hit, the "slab" behind the sample (Timonen 2013 §4),
//! `X_k / sin γ`. Each term is computed exactly for `∫ f` (`G(h_{k−1}) − G(γ_k)`) times the
//! `f`-weighted mean of `ρ(r_k)` over the arc (its midpoint under ~8°, Simpson's rule on the
//! ends and bisector under ~26°, composite Simpson beyond). With `t_max = ∞`, `ρ = 0` in range
//! and the blocked terms vanish.
//!
//! # Estimator
//!
//! `K = directions` half-planes per pixel at `ψ_j = ψ₀ + 2πj/K` with a per-pixel random
//! rotation `ψ₀`; the screen direction of `u(ψ)` is `cos ψ·J e₁ + sin ψ·J e₂` where `J eᵢ` is the
//! image displacement of `p + ε eᵢ` (`ε = 10⁻³ ×` the point's depth or distance). Each half-line
//! is marched up to the pixel radius of a sphere of radius `t_max` at `p`'s depth along that
//! direction (the `(r_x, r_y)` ellipse of [`Projection::disk_radius`]), clipped to the map,
//! starting where it leaves `p`'s own pixel, with `min(steps, ⌊length⌋)` (at least 1) samples
//! evenly stratified with a per-half-plane jitter, so consecutive samples are at least a pixel
//! apart. Samples on `p`'s pixel, on empty pixels or outside the map are skipped; a sample at
//! 3-D distance `≥ t_max` is ignored (beyond `t_max`, `ρ = 1`: it cannot darken `p`), and one
//! within 10⁻⁵ rad of the tangent plane counts as on it (rounding noise of a plane). The pixel's
//! value is `a = Σ_j S_j / Σ_j T_j` (the same limit as `(1/π)·2π·mean S`, but exactly 1 when
//! nothing rises above the tangent plane), clamped to `[0, 1]`.
//!
//! A sample's pixel is not exactly on the half-plane (pixels are quantized): its in-plane
//! coordinates keep its measured position along the half-plane's tangent line
//! `(a u − b V)/R` (`R = √(a² + b²)`) and its height `n·v` above `p`'s tangent plane (scaled to
//! the plane, `÷ R`), i.e. it is moved within the tangent plane onto the half-plane. A point of
//! the tangent plane stays on it: a plane never occludes itself whatever the viewing angle.
//!
//! Conventions shared with the paper estimator: a pixel none of whose samples landed on a valid
//! neighbouring pixel keeps `a = 1` and is flagged (`no_sample`), as is a pixel whose normal is
//! zero or not finite, or whose point has no image. Each pixel's random numbers come from
//! `Rng::new(seed, pixel)`, so maps do not depend on the thread count or the tiling.
//!
//! Limits: the estimator converges to the obscurance of the surface the *map* describes, read as
//! a height field over the image (piecewise linear along each half-line, solid behind every
//! visible sample). Occluders the sensor does not see (under overhangs, behind foreground
//! objects, outside the map) are missing; a foreground edge is joined to the background behind
//! it (limited to `t_max` by ignoring samples farther than `t_max`); the azimuth is sampled at
//! `K` angles, so an occluder seen edge-on between two half-planes is resolved only as `K` grows;
//! the remaining error at full budget is the map's own discretization, first order in the pixel
//! footprint.

use super::rng::Rng;
use super::{AoMap, Falloff, SsaoParams};
use crate::gbuffer::{GBuffer, EMPTY};
use crate::pagebuf::PageBuf;
use crate::projection::{atan2_4, fast_atan2, sqrt4, Projection, SensorModel};
use glam::{BVec4A, Vec3A, Vec4};
use rayon::prelude::*;
use std::f32::consts::{FRAC_PI_2, PI, TAU};

/// Computes the unblurred horizon-based obscurance of every valid pixel.
///
/// `prm.directions` half-planes and up to `prm.steps` samples per half-plane (both at least 1),
/// falloff `prm.tmax`, per-pixel patterns from `prm.seed`. A projection whose size differs from
/// the G-buffer's cannot be marched: every valid pixel is then flagged.
pub fn ssao(g: &GBuffer, proj: &Projection, prm: &SsaoParams) -> AoMap {
    let n = g.width * g.height;
    let mut ao = crate::par::filled(n, 1.0f32);
    let mut flag = crate::par::filled(n, false);
    let consistent = [
        g.point.len(),
        g.position.len(),
        g.normal.len(),
        g.depth.len(),
    ]
    .iter()
    .all(|&l| l == n);
    if g.width == 0 || !consistent {
        return AoMap {
            ao,
            no_sample: flag,
        };
    }
    if proj.width != g.width || proj.height != g.height || n > i32::MAX as usize {
        for (i, f) in flag.iter_mut().enumerate() {
            *f = g.is_valid(i);
        }
        return AoMap {
            ao,
            no_sample: flag,
        };
    }
    let pts = positions(g);
    let ctx = Ctx::new(g, &pts, proj, prm);
    // Bands of BAND rows in parallel, each walked in TILE-wide column blocks: neighbouring
    // pixels read the same neighbourhood, so a block's working set stays in cache even for
    // wide t_max disks.
    const BAND: usize = 16;
    const TILE: usize = 32;
    let w = g.width;
    ao.par_chunks_mut(w * BAND)
        .zip(flag.par_chunks_mut(w * BAND))
        .enumerate()
        .for_each(|(band, (aband, fband))| {
            let rows = aband.len() / w;
            let mut grp = Group::default();
            for x0 in (0..w).step_by(TILE) {
                for r in 0..rows {
                    let y = band * BAND + r;
                    for x in x0..(x0 + TILE).min(w) {
                        let c = y * w + x;
                        if !g.is_valid(c) {
                            continue;
                        }
                        match ctx.pixel(x, y, c, &mut grp) {
                            Some(a) => aband[r * w + x] = a,
                            None => fband[r * w + x] = true,
                        }
                    }
                }
            }
        });
    AoMap {
        ao,
        no_sample: flag,
    }
}

/// One 16-byte load per sample: the G-buffer's positions, NaN where the pixel is empty.
fn positions(g: &GBuffer) -> PageBuf<Vec3A> {
    let mut pts = PageBuf::zeroed(g.position.len());
    pts.par_iter_mut()
        .zip(g.position.par_iter().zip(g.point.par_iter()))
        .for_each(|(q, (&p, &i))| {
            *q = if i == EMPTY {
                Vec3A::NAN
            } else {
                Vec3A::from(p)
            }
        });
    pts
}

/// Half-planes marched together, one per SIMD lane.
const LANES: usize = 4;

/// Up to [`LANES`] half-plane marches of one pixel: lane `l < n` starts at `q[l]` (48.16 fixed
/// point), moves by `step[l]` and takes `count[l]` samples into `hz[l]`; on an
/// equirectangular map it follows the great circle `arc[l]` instead.
#[derive(Debug, Default)]
struct Group {
    n: usize,
    hz: [Horizon; LANES],
    q: [(i64, i64); LANES],
    step: [(i64, i64); LANES],
    arc: [Arc; LANES],
    /// This pixel's marches follow `arc`, not `q` and `step`.
    arc_on: bool,
    count: [u32; LANES],
}

/// A half-plane's image on a spherical map: the great circle of directions
/// `cos φ·d + sin φ·u` from the sensor (`d` towards the pixel's point, `u ⊥ d` the half-plane's
/// direction), sampled at `φ` advancing by a fixed angle.
#[derive(Debug, Clone, Copy, Default)]
struct Arc {
    d: Vec3A,
    u: Vec3A,
    /// `(cos φ, sin φ)` of the next sample.
    cs: (f32, f32),
    /// `(cos, sin)` of the angle between samples.
    rot: (f32, f32),
}

/// What one direction adds to `Σ T` and `Σ S`.
#[derive(Debug, Clone, Copy)]
enum Term {
    /// No direction of the half-plane is above the tangent plane: nothing.
    None,
    /// Its open value `T` to both (nothing to march).
    Open(f32),
    /// `T`, and `S` from the march in lane `l`.
    March(f32, usize),
}

/// What a pixel's directions share: `a = n·V`, the normal `na`, the view direction `va`, the
/// basis `(e1, e2)` of the plane ⊥ V and its screen images `d` (`None`: no march), the
/// t_max ellipse `x²·irx2 + y²·iry2 = 1`, the march origin `o` and its place `fo` in the pixel.
struct Frame {
    a: f32,
    na: Vec3A,
    va: Vec3A,
    e1: Vec3A,
    e2: Vec3A,
    d: Option<((f32, f32), (f32, f32))>,
    irx2: f32,
    iry2: f32,
    o: (f32, f32),
    fo: (f32, f32),
    /// On a spherical map: the pixels per radian of arc of a unit screen derivative (the
    /// point's distance, over the derivative's metres), and the angle from the point within
    /// which the t_max sphere lies; `None` elsewhere.
    arc: Option<(f32, f32)>,
}

/// The pixel's random numbers and the `(sin, cos)` of the next direction's angle.
struct Dirs {
    rng: Rng,
    sc: (f32, f32),
}

impl Dirs {
    /// The next direction's `(sin, cos)` and jitter, advancing by the angle `rot` between
    /// directions.
    #[inline(always)]
    fn next(&mut self, rot: (f32, f32)) -> ((f32, f32), f32) {
        let jitter = self.rng.next_f32();
        let (s, co) = self.sc;
        let (rot_s, rot_c) = rot;
        self.sc = (s * rot_c + co * rot_s, co * rot_c - s * rot_s);
        ((s, co), jitter)
    }
}

/// Everything a pixel evaluation needs, fixed for the whole map.
struct Ctx<'a> {
    g: &'a GBuffer,
    /// Positions, NaN where empty.
    pts: &'a [Vec3A],
    proj: &'a Projection,
    tmax: f32,
    /// The falloff as the quadrature evaluates it.
    rho: Rho,
    /// `t_max²`, or 0 when `t_max ≤ 0` (every sample then ignored: `ρ ≡ 1`).
    tmax2: f32,
    directions: u32,
    /// `(sin, cos)` of the angle between consecutive directions.
    rot: (f32, f32),
    steps: u32,
    seed: u64,
    /// Map size as integers and floats.
    w: i32,
    h: i32,
    wf: f32,
    hf: f32,
    wrap: bool,
    /// Equirectangular: half-planes that reach far are marched along their great circles.
    sphere: bool,
}

impl<'a> Ctx<'a> {
    fn new(g: &'a GBuffer, pts: &'a [Vec3A], proj: &'a Projection, prm: &SsaoParams) -> Ctx<'a> {
        let tmax2 = if prm.tmax > 0.0 {
            prm.tmax * prm.tmax
        } else {
            0.0
        };
        Ctx {
            g,
            pts,
            proj,
            tmax: prm.tmax,
            rho: Rho::new(prm.falloff, prm.tmax),
            tmax2,
            directions: prm.directions.max(1),
            rot: (TAU / prm.directions.max(1) as f32).sin_cos(),
            steps: prm.steps.max(1),
            seed: prm.seed,
            w: g.width as i32,
            h: g.height as i32,
            wf: g.width as f32,
            hf: g.height as f32,
            wrap: proj.wrap_x,
            sphere: proj.sensor_model() == SensorModel::Equirect,
        }
    }

    /// The pixel holding continuous position `(x, y)` (wrapping x on a full-circle map), or
    /// `None` outside the map. Same as [`Projection::pixel_index`] without the libm `floor`.
    #[inline]
    fn pixel_at(&self, x: f32, y: f32) -> Option<usize> {
        let iy = fast_floor(y);
        if iy < 0 || iy >= self.h {
            return None;
        }
        let mut ix = fast_floor(x);
        if ix < 0 || ix >= self.w {
            if !self.wrap {
                return None;
            }
            ix = ix.rem_euclid(self.w);
        }
        Some(iy as usize * self.w as usize + ix as usize)
    }

    /// Obscurance of valid pixel `c = (x, y)`; `None` when it must be flagged.
    fn pixel(&self, x: usize, y: usize, c: usize, grp: &mut Group) -> Option<f32> {
        self.pixel_with(x, y, c, grp, Self::setup_lanes, Self::march_lanes)
    }

    /// [`Ctx::pixel`] with each group of [`LANES`] directions set up by `setup` and its
    /// half-planes marched by `march` (SIMD lanes in production, one direction at a time in
    /// the tests' references).
    #[inline(always)]
    fn pixel_with(
        &self,
        x: usize,
        y: usize,
        c: usize,
        grp: &mut Group,
        setup: impl Fn(&Self, &Frame, &mut Dirs, &mut Group, &mut [Term; LANES]),
        march: impl Fn(&Self, &mut Group, usize, Vec3A, Vec3A) -> bool,
    ) -> Option<f32> {
        let g = self.g;
        let proj = self.proj;
        let p = g.position[c];
        let len = g.normal[c].length();
        if !(len > 1e-6 && len.is_finite() && p.is_finite()) {
            return None;
        }
        let nrm = g.normal[c] / len;
        let view = proj.toward_sensor(p);
        if !(view.length_squared() > 0.5) {
            return None;
        }
        let pc = proj.project(p)?;
        let (cx, cy) = (x as f32 + 0.5, y as f32 + 0.5);
        // March from the point's own image when it lies in its pixel (it does unless the
        // G-buffer came from a native grid the model does not reproduce exactly).
        let (ox, oy) = if self.pixel_at(pc.x, pc.y) == Some(c) {
            (pc.x, pc.y)
        } else {
            (cx, cy)
        };
        let (rx, ry) = proj.disk_radius(self.tmax, g.depth[c], cx, cy);
        // Screen directions of the basis (e1, e2) of the plane ⊥ V: the image of u(ψ) is
        // cos ψ·d1 + sin ψ·d2 (the projection's derivative at p; V itself does not move).
        let mut eps = 1e-3 * g.depth[c].abs().max(p.length());
        if !(eps > 1e-12 && eps.is_finite()) {
            eps = 1e-3;
        }
        let (e1, e2) = view.any_orthonormal_pair();
        // The directions of d1, d2 set the march; their length (pixels per `per_m` metres)
        // matters only on a spherical map, to turn pixels into angles.
        let (d1, d2, per_m) = match (proj.image_derivative(p, e1), proj.image_derivative(p, e2)) {
            (Some(a), Some(b)) => (Some(a), Some(b), 1.0),
            _ => (
                self.screen_delta(pc.x, pc.y, proj.project(p + e1 * eps)),
                self.screen_delta(pc.x, pc.y, proj.project(p + e2 * eps)),
                eps,
            ),
        };
        // On a spherical map a half-plane's image is a great circle; the straight image line
        // of the march is its tangent, which stays within a small fraction of a radian of it
        // up to ARC_FROM radians from the point and leaves it beyond.
        const ARC_FROM: f32 = 0.25;
        let dist = p.length();
        let angle = if self.tmax < dist {
            (self.tmax / dist).asin()
        } else {
            // The t_max sphere holds the sensor: the whole half circle.
            0.999 * PI
        };
        // The sensor is the map's origin: the point's distance turns metres ⊥ d into radians.
        let arc = (self.sphere && angle > ARC_FROM).then_some((dist / per_m, angle));
        grp.arc_on = arc.is_some();
        let a = nrm.dot(view);
        let (pa, na, va) = (Vec3A::from(p), Vec3A::from(nrm), Vec3A::from(view));
        let (e1, e2) = (Vec3A::from(e1), Vec3A::from(e2));
        // The t_max ellipse x²/rx² + y²/ry² = 1 (no samples at all if degenerate).
        let (irx2, iry2) = (1.0 / (rx * rx), 1.0 / (ry * ry));
        let reach_ok = rx > 0.0 && ry > 0.0;
        // Position inside p's own pixel.
        let (fox, foy) = (ox - fast_floor(ox) as f32, oy - fast_floor(oy) as f32);
        let mut dirs = Dirs {
            rng: Rng::new(self.seed, c as u64),
            sc: (0.0, 0.0),
        };
        dirs.sc = (TAU * dirs.rng.next_f32()).sin_cos();
        let frame = Frame {
            a,
            na,
            va,
            e1,
            e2,
            d: match (d1, d2) {
                (Some(d1), Some(d2)) if reach_ok => Some((d1, d2)),
                _ => None,
            },
            irx2,
            iry2,
            o: (ox, oy),
            fo: (fox, foy),
            arc,
        };
        let (mut sum_s, mut sum_t, mut any) = (0.0f32, 0.0f32, false);
        let mut left = self.directions;
        while left > 0 {
            // A lane's horizon, position and step are set when its count is; until then the
            // lane is idle and what it holds from an earlier group is never read.
            grp.n = left.min(LANES as u32) as usize;
            grp.count = [0; LANES];
            // What each direction of the group adds to Σ T and Σ S: its open value, and
            // either that again (nothing to march) or its lane's march.
            let mut terms = [Term::None; LANES];
            setup(self, &frame, &mut dirs, grp, &mut terms);
            left -= grp.n as u32;
            if grp.count.iter().any(|&k| k > 0) {
                any |= march(self, grp, c, pa, na);
            }
            for term in terms {
                match term {
                    Term::None => {}
                    Term::Open(open) => {
                        sum_t += open;
                        sum_s += open;
                    }
                    Term::March(open, l) => {
                        sum_t += open;
                        sum_s += grp.hz[l].value();
                    }
                }
            }
        }
        if !any {
            return None;
        }
        let a = if sum_t > 0.0 { sum_s / sum_t } else { 1.0 };
        if a.is_finite() {
            Some(a.clamp(0.0, 1.0))
        } else {
            None
        }
    }

    /// Sets up the group's directions, one per lane (`grp.n` of them), with the arithmetic of
    /// [`Slice::new`], [`unit`] and [`exit`] done on all lanes at once (the divisions and
    /// square roots of four directions in one instruction each). Every lane gets the same bits
    /// as [`Ctx::setup_one`] (a test checks it): the same operations in the same order, and
    /// selects where the scalar code branches.
    #[inline(always)]
    fn setup_lanes(&self, f: &Frame, dirs: &mut Dirs, grp: &mut Group, terms: &mut [Term; LANES]) {
        let n = grp.n;
        let (mut sn, mut cs, mut jit, mut bs) =
            ([0.0f32; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES]);
        let mut us = [Vec3A::ZERO; LANES];
        for l in 0..n {
            let ((s, co), j) = dirs.next(self.rot);
            (sn[l], cs[l], jit[l]) = (s, co, j);
            us[l] = f.e1 * co + f.e2 * s;
            bs[l] = f.na.dot(us[l]);
        }
        let lanes = BVec4A::new(n > 0, n > 1, n > 2, n > 3);
        let a = f.a;
        let (av, b) = (Vec4::splat(a), Vec4::from_array(bs));
        // Slice::new on four lanes (a is the pixel's, so its branch is the same for all).
        let r = sqrt4(Vec4::splat(a * a) + b * b);
        let ok = lanes & r.cmpgt(Vec4::splat(1e-6)) & r.is_finite_mask();
        let inv_r = Vec4::ONE / r;
        let (ca, sb) = (av * inv_r, b * inv_r);
        let (lo, lo_s, lo_c, hi, hi_s, hi_c, g_lo, g_hi);
        if a > 0.0 {
            (lo, lo_s, lo_c) = (Vec4::ZERO, Vec4::ZERO, Vec4::ONE);
            hi = atan2_4(b, Vec4::splat(a)) + Vec4::splat(FRAC_PI_2);
            (hi_s, hi_c) = (ca, -sb);
            g_lo = Vec4::splat(-0.25 * a);
            g_hi = Vec4::splat(0.25 * a) + Vec4::splat(0.5) * b * hi;
        } else {
            let gn = Vec4::select(
                b.cmpeq(Vec4::ZERO),
                Vec4::splat(PI),
                atan2_4(b, Vec4::splat(a)),
            );
            lo = Vec4::select(
                gn.cmplt(Vec4::splat(FRAC_PI_2)),
                gn + Vec4::splat(1.5 * PI),
                gn - Vec4::splat(FRAC_PI_2),
            );
            (lo_s, lo_c) = (-ca, sb);
            (hi, hi_s, hi_c) = (Vec4::splat(PI), Vec4::ZERO, Vec4::splat(-1.0));
            let g = |s: Vec4, c: Vec4, gamma: Vec4| {
                Vec4::splat(-0.25 * a) * (c * c - s * s) + Vec4::splat(0.5) * b * (gamma - s * c)
            };
            (g_lo, g_hi) = (g(lo_s, lo_c, lo), g(hi_s, hi_c, hi));
        }
        let ok = ok & hi.cmpgt(lo);
        let open = (g_hi - g_lo).max(Vec4::ZERO);
        // The march: unit screen direction, its length to the t_max ellipse and the map's
        // edges, from where it leaves the pixel.
        let march = f.d.map(|(d1, d2)| {
            let (co, s) = (Vec4::from_array(cs), Vec4::from_array(sn));
            let x = co * d1.0 + s * d2.0;
            let y = co * d1.1 + s * d2.1;
            let len = sqrt4(x * x + y * y);
            let dir_ok = len.cmpgt(Vec4::ZERO) & len.is_finite_mask();
            let (dx, dy) = (x / len, y / len);
            let (idx, idy) = (Vec4::ONE / dx, Vec4::ONE / dy);
            let ellipse =
                Vec4::ONE / sqrt4(dx * dx * Vec4::splat(f.irx2) + dy * dy * Vec4::splat(f.iry2));
            // Pixels per radian of arc along each direction (spherical maps only).
            let ppr = len * Vec4::splat(f.arc.map_or(0.0, |a| a.0));
            let reach = if let Some((_, angle)) = f.arc {
                ppr * Vec4::splat(angle)
            } else {
                let mut reach = min_lanes(ellipse, exit_lanes(f.o.1, idy, self.hf));
                reach = min_lanes(reach, Vec4::splat(self.wf + self.hf));
                if !self.wrap {
                    reach = min_lanes(reach, exit_lanes(f.o.0, idx, self.wf));
                }
                reach
            };
            let t0 = min_lanes(exit_lanes(f.fo.0, idx, 1.0), exit_lanes(f.fo.1, idy, 1.0));
            let span = reach - t0;
            let go = (dir_ok & span.cmpgt(Vec4::ZERO)).bitmask();
            let [dx, dy, t0, span, ppr] = [dx, dy, t0, span, ppr].map(|v| v.to_array());
            (dx, dy, t0, span, ppr, go)
        });
        let okb = ok.bitmask();
        let (b, inv_r, lo, lo_s, lo_c, hi, hi_s, hi_c, g_lo, g_hi, open) = (
            b.to_array(),
            inv_r.to_array(),
            lo.to_array(),
            lo_s.to_array(),
            lo_c.to_array(),
            hi.to_array(),
            hi_s.to_array(),
            hi_c.to_array(),
            g_lo.to_array(),
            g_hi.to_array(),
            open.to_array(),
        );
        for l in 0..n {
            if okb & (1 << l) == 0 {
                continue;
            }
            terms[l] = Term::Open(open[l]);
            let Some((dx, dy, t0, span, ppr, go)) = &march else {
                continue;
            };
            if go & (1 << l) == 0 {
                continue;
            }
            let slice = Slice {
                a,
                b: b[l],
                inv_r: inv_r[l],
                lo: lo[l],
                lo_sc: (lo_s[l], lo_c[l]),
                hi: hi[l],
                hi_sc: (hi_s[l], hi_c[l]),
                g_lo: g_lo[l],
                g_hi: g_hi[l],
            };
            self.start(
                f,
                grp,
                l,
                slice,
                us[l],
                (dx[l], dy[l]),
                (t0[l], span[l]),
                ppr[l],
                jit[l],
            );
            terms[l] = Term::March(open[l], l);
        }
    }

    /// Lane `l`'s march along unit screen direction `dir` from `t0`, over `span` pixels (on
    /// a spherical map along the great circle, `ppr` pixels to the radian).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn start(
        &self,
        f: &Frame,
        grp: &mut Group,
        l: usize,
        slice: Slice,
        u: Vec3A,
        (dx, dy): (f32, f32),
        (t0, span): (f32, f32),
        ppr: f32,
        jitter: f32,
    ) {
        let count = (span as u32).clamp(1, self.steps);
        let step = span / count as f32;
        // In-plane coordinates as linear forms of v = s − p: along the tangent line
        // (a u − b V)/R as measured; across it the height n·v above the tangent plane
        // scaled to the plane (÷ R), so that a point of the tangent plane stays on it:
        // x = v·(a² u − ab V + b n)/R², y = v·(a n − ab u + b² V)/R².
        let (sa, sb) = (slice.a, slice.b);
        let ir2 = slice.inv_r * slice.inv_r;
        let fx = (u * (sa * sa) - f.va * (sa * sb) + f.na * sb) * ir2;
        let fy = (f.na * sa - u * (sa * sb) + f.va * (sb * sb)) * ir2;
        // March in 48.16 fixed point: floor = arithmetic shift, no float → int per sample.
        let t1 = t0 + jitter * step;
        let (ox, oy) = f.o;
        grp.hz[l] = Horizon::new(slice, fx, fy);
        if f.arc.is_some() {
            let (phi, dphi) = (t1 / ppr, step / ppr);
            let ((s1, c1), (sd, cd)) = (phi.sin_cos(), dphi.sin_cos());
            grp.arc[l] = Arc {
                d: -f.va,
                u,
                cs: (c1, s1),
                rot: (cd, sd),
            };
        } else {
            grp.q[l] = (fixed(ox + dx * t1), fixed(oy + dy * t1));
            grp.step[l] = (fixed(dx * step), fixed(dy * step));
        }
        grp.count[l] = count;
    }

    /// The reference for [`Ctx::setup_lanes`]: one direction at a time.
    #[cfg(test)]
    fn setup_one(&self, f: &Frame, dirs: &mut Dirs, grp: &mut Group, terms: &mut [Term; LANES]) {
        for (l, term) in terms.iter_mut().enumerate().take(grp.n) {
            let ((s, co), jitter) = dirs.next(self.rot);
            let u = f.e1 * co + f.e2 * s;
            let Some(slice) = Slice::new(f.a, f.na.dot(u)) else {
                continue;
            };
            let open = slice.open();
            *term = Term::Open(open);
            let Some((x, y)) =
                f.d.map(|(d1, d2)| (co * d1.0 + s * d2.0, co * d1.1 + s * d2.1))
            else {
                continue;
            };
            let len = (x * x + y * y).sqrt();
            if !(len > 0.0 && len.is_finite()) {
                continue;
            }
            let (dx, dy) = (x / len, y / len);
            let (idx, idy) = (1.0 / dx, 1.0 / dy);
            let (ox, oy) = f.o;
            let ppr = len * f.arc.map_or(0.0, |a| a.0);
            let reach = if let Some((_, angle)) = f.arc {
                ppr * angle
            } else {
                let reach = (1.0 / (dx * dx * f.irx2 + dy * dy * f.iry2).sqrt())
                    .min(exit(oy, idy, self.hf))
                    .min(self.wf + self.hf);
                if self.wrap {
                    reach
                } else {
                    reach.min(exit(ox, idx, self.wf))
                }
            };
            let t0 = exit(f.fo.0, idx, 1.0).min(exit(f.fo.1, idy, 1.0));
            let span = reach - t0;
            if !(span > 0.0) {
                continue;
            }
            self.start(f, grp, l, slice, u, (dx, dy), (t0, span), ppr, jitter);
            *term = Term::March(open, l);
        }
    }

    /// The map index of the next sample of lane `l` (advancing it), `None` once the line has
    /// left the map (it leaves once: y is monotone, x wraps or is clipped).
    #[inline(always)]
    fn next_index(&self, grp: &mut Group, l: usize) -> Option<usize> {
        if grp.arc_on {
            return self.next_index_arc(&mut grp.arc[l]);
        }
        let (qx, qy) = grp.q[l];
        let (mut ix, iy) = (qx >> 16, qy >> 16);
        grp.q[l] = (qx + grp.step[l].0, qy + grp.step[l].1);
        if iy as u64 >= self.h as u64 {
            return None;
        }
        if ix as u64 >= self.w as u64 {
            if !self.wrap {
                return None;
            }
            ix = ix.rem_euclid(self.w as i64);
        }
        let i = iy as usize * self.w as usize + ix as usize;
        (i < self.pts.len()).then_some(i)
    }

    /// [`Ctx::next_index`] on a spherical map: the pixel of the arc's next direction, `None`
    /// once it leaves the map (past the top or bottom row of a partial panorama).
    #[inline(always)]
    fn next_index_arc(&self, a: &mut Arc) -> Option<usize> {
        let (c, s) = a.cs;
        let w = a.d * c + a.u * s;
        a.cs = (c * a.rot.0 - s * a.rot.1, s * a.rot.0 + c * a.rot.1);
        let pr = self.proj.project(glam::Vec3::from(w))?;
        let i = self.pixel_at(pr.x, pr.y)?;
        (i < self.pts.len()).then_some(i)
    }

    /// Marches the group's half-planes in lock step, one SIMD lane each: the sample tests run
    /// on all lanes at once and only a lane whose sample raises its horizon takes the scalar
    /// [`Horizon::raise`]. Every lane sees the same samples, in the same order, with the same
    /// arithmetic as [`Ctx::march_one`]. Returns whether any sample landed on a neighbouring
    /// valid pixel.
    fn march_lanes(&self, grp: &mut Group, c: usize, pa: Vec3A, na: Vec3A) -> bool {
        let lanes = |f: &dyn Fn(&Horizon) -> f32| {
            Vec4::new(f(&grp.hz[0]), f(&grp.hz[1]), f(&grp.hz[2]), f(&grp.hz[3]))
        };
        let (fxx, fxy, fxz) = (lanes(&|h| h.fx.x), lanes(&|h| h.fx.y), lanes(&|h| h.fx.z));
        let (fyx, fyy, fyz) = (lanes(&|h| h.fy.x), lanes(&|h| h.fy.y), lanes(&|h| h.fy.z));
        let (pax, pay, paz) = (Vec4::splat(pa.x), Vec4::splat(pa.y), Vec4::splat(pa.z));
        let (nax, nay, naz) = (Vec4::splat(na.x), Vec4::splat(na.y), Vec4::splat(na.z));
        let tmax2 = Vec4::splat(self.tmax2);
        let plen = Vec4::splat(pa.length());
        let mut cos_h = [0.0f32; LANES];
        for (ch, h) in cos_h.iter_mut().zip(&grp.hz) {
            *ch = h.sc.1;
        }
        // The previous sample's in-plane coordinates (NaN before the first).
        let (mut prev_x, mut prev_y) = (Vec4::NAN, Vec4::NAN);
        let mut live = [false; LANES];
        for (l, lv) in live.iter_mut().enumerate().take(grp.n) {
            *lv = grp.count[l] > 0;
        }
        let steps = grp.count.iter().copied().max().unwrap_or(0);
        let mut any = false;
        // The samples of a block of steps are all loaded before any is tested, lanes apart
        // (x, y, z) so that a step's lanes load as three vectors. A lane with no sample has
        // x = NaN, which makes every test below fail whatever y and z hold.
        const BLOCK: u32 = 8;
        let mut k0 = 0;
        while k0 < steps {
            let kn = (steps - k0).min(BLOCK);
            let mut qx = [[f32::NAN; LANES]; BLOCK as usize];
            let mut qy = [[0.0f32; LANES]; BLOCK as usize];
            let mut qz = [[0.0f32; LANES]; BLOCK as usize];
            for l in 0..grp.n {
                if !live[l] {
                    continue;
                }
                // The lane's samples left in this block; it is done once they run out.
                let todo = grp.count[l].saturating_sub(k0).min(kn);
                live[l] = k0 + kn < grp.count[l];
                for k in 0..todo as usize {
                    let Some(i) = self.next_index(grp, l) else {
                        live[l] = false;
                        break;
                    };
                    let s = self.pts[i];
                    if i != c && !s.x.is_nan() {
                        any = true;
                        (qx[k][l], qy[k][l], qz[k][l]) = (s.x, s.y, s.z);
                    }
                }
            }
            for k in 0..kn as usize {
                let vx = Vec4::from_array(qx[k]) - pax;
                let vy = Vec4::from_array(qy[k]) - pay;
                let vz = Vec4::from_array(qz[k]) - paz;
                let l2 = (vx * vx + vy * vy) + vz * vz;
                // Lanes without a sample are NaN and fail every test.
                let inside = l2.cmplt(tmax2);
                let height = (nax * vx + nay * vy) + naz * vz;
                let height = Vec4::select((height * height).cmpgt(l2 * 1e-10), height, Vec4::ZERO);
                let x = (vx * fxx + vy * fxy) + vz * fxz;
                let y = (vx * fyx + vy * fyy) + vz * fyz;
                let raise = inside & height.cmpgt(Vec4::ZERO) & x.cmpgt(Vec4::ZERO);
                let mut bits = raise.bitmask();
                if bits != 0 {
                    let ch = Vec4::from_array(cos_h);
                    bits &= above_horizon_lanes(x, y, ch).bitmask();
                    if grp.arc_on && bits != 0 {
                        let (sx, sy, sz) = (vx + pax, vy + pay, vz + paz);
                        let dq = (pax * sx + pay * sy) + paz * sz;
                        let len = sqrt4((sx * sx + sy * sy) + sz * sz);
                        let joins = (dq + ch * (len * plen)).cmpge(Vec4::ZERO);
                        bits &= joins.bitmask();
                    }
                    let (xs, ys) = (x.to_array(), y.to_array());
                    let (pxs, pys) = (prev_x.to_array(), prev_y.to_array());
                    while bits != 0 {
                        let l = bits.trailing_zeros() as usize;
                        bits &= bits - 1;
                        grp.hz[l].raise(xs[l], ys[l], pxs[l], pys[l], &self.rho);
                        cos_h[l] = grp.hz[l].sc.1;
                    }
                }
                prev_x = Vec4::select(inside, x, prev_x);
                prev_y = Vec4::select(inside, y, prev_y);
            }
            k0 += kn;
        }
        any
    }

    /// The reference for [`Ctx::march_lanes`]: each lane's half-plane marched on its own.
    #[cfg(test)]
    fn march_one(&self, grp: &mut Group, c: usize, pa: Vec3A, na: Vec3A) -> bool {
        let mut any = false;
        for l in 0..grp.n {
            let (mut px, mut py) = (f32::NAN, f32::NAN);
            for _ in 0..grp.count[l] {
                let Some(i) = self.next_index(grp, l) else {
                    break;
                };
                let q = self.pts[i];
                if i == c || q.x.is_nan() {
                    continue;
                }
                any = true;
                let v = q - pa;
                let l2 = v.length_squared();
                if !(l2 < self.tmax2) {
                    continue;
                }
                // Heights within 10⁻⁵ rad of the tangent plane count as on it (rounding noise
                // of a plane; the sliver they could block weighs ≤ 10⁻¹⁰).
                let height = na.dot(v);
                let height = if height * height > 1e-10 * l2 {
                    height
                } else {
                    0.0
                };
                let hz = &mut grp.hz[l];
                let (x, y) = (v.dot(hz.fx), v.dot(hz.fy));
                if height > 0.0
                    && x > 0.0
                    && above_horizon(x, y, hz.sc.1)
                    && (!grp.arc_on || joins_horizon(pa, v, hz.sc.1))
                {
                    hz.raise(x, y, px, py, &self.rho);
                }
                (px, py) = (x, y);
            }
        }
        any
    }

    /// Screen offset from `(px, py)` to the projection `q` (x wrapped on a full-circle map).
    #[inline]
    fn screen_delta(
        &self,
        px: f32,
        py: f32,
        q: Option<crate::projection::Projected>,
    ) -> Option<(f32, f32)> {
        let q = q?;
        let mut dx = q.x - px;
        if self.wrap {
            dx -= self.wf * (dx / self.wf).round();
        }
        let d = (dx, q.y - py);
        (d.0.is_finite() && d.1.is_finite()).then_some(d)
    }
}

/// Whether a sample at offset `v` from `p` (both relative to the sensor) extends the blocked
/// directions `[h, hi]` of a half-plane on its own: seen from the sensor at angle `φ` from
/// `p`, it hides only the directions `γ < π − φ` from `p` (rays at larger `γ` never come that
/// far round), so it joins the horizon when `φ ≤ π − h`: `p·s ≥ −cos h·|s|·|p|` with
/// `s = p + v`. The same arithmetic as the test in [`Ctx::march_lanes`].
#[cfg(test)]
fn joins_horizon(pa: Vec3A, v: Vec3A, cos_h: f32) -> bool {
    let plen = pa.length();
    let (sx, sy, sz) = (v.x + pa.x, v.y + pa.y, v.z + pa.z);
    let dq = (pa.x * sx + pa.y * sy) + pa.z * sz;
    let len = ((sx * sx + sy * sy) + sz * sz).sqrt();
    dq + cos_h * (len * plen) >= 0.0
}

#[cfg(test)]
/// True when direction `(x, y)` (`x > 0`) has a larger cosine than `cos_h`, without a square
/// root: `y/√(x²+y²) > cos_h`.
#[inline]
fn above_horizon(x: f32, y: f32, cos_h: f32) -> bool {
    let (y2, k) = (y * y, cos_h * cos_h * (x * x + y * y));
    if cos_h >= 0.0 {
        y > 0.0 && y2 > k
    } else {
        y >= 0.0 || y2 < k
    }
}

/// [`above_horizon`] on four lanes, with the same arithmetic.
#[inline]
fn above_horizon_lanes(x: Vec4, y: Vec4, cos_h: Vec4) -> BVec4A {
    let (y2, k) = (y * y, cos_h * cos_h * (x * x + y * y));
    let facing = y.cmpgt(Vec4::ZERO) & y2.cmpgt(k);
    let beyond = y.cmpge(Vec4::ZERO) | y2.cmplt(k);
    let up = cos_h.cmpge(Vec4::ZERO);
    (up & facing) | (!up & beyond)
}

/// `ρ` as a function of `d/t_max`: `x = clamp(·, 0, 1)`, `x²(3 − 2x)` (same as [`super::rho`]).
#[inline]
fn smooth(x: f32) -> f32 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// `ρ` with what the quadrature needs precomputed.
#[derive(Debug, Clone, Copy)]
struct Rho {
    falloff: Falloff,
    tmax: f32,
    inv_tmax: f32,
    /// `ρ ≡ 0` for every finite distance: blocked directions add nothing.
    blocks_fully: bool,
}

impl Rho {
    fn new(falloff: Falloff, tmax: f32) -> Rho {
        Rho {
            falloff,
            tmax,
            inv_tmax: 1.0 / tmax,
            blocks_fully: falloff.blocks_fully(tmax),
        }
    }

    /// `ρ(d)`; the default falloff by a multiplication, as [`super::rho`] computes it.
    #[inline]
    fn at(&self, d: f32) -> f32 {
        match self.falloff {
            Falloff::Smoothstep => smooth(d * self.inv_tmax),
            f => f.rho(d, self.tmax),
        }
    }
}

/// `f32::min` on four lanes: the non-NaN operand when one is NaN.
#[inline(always)]
fn min_lanes(a: Vec4, b: Vec4) -> Vec4 {
    // minps returns its second operand when either is NaN.
    Vec4::select(b.is_nan_mask(), a, a.min(b))
}

/// [`exit`] on four lanes of `inv`.
#[inline(always)]
fn exit_lanes(o: f32, inv: Vec4, size: f32) -> Vec4 {
    let pos = (Vec4::splat(size) - Vec4::splat(o)) * inv;
    let neg = Vec4::splat(-o) * inv;
    Vec4::select(
        inv.cmpgt(Vec4::ZERO),
        pos,
        Vec4::select(inv.cmplt(Vec4::ZERO), neg, Vec4::INFINITY),
    )
}

/// `(x, y)` normalised; `None` when zero or not finite.
#[inline]
fn unit(x: f32, y: f32) -> Option<(f32, f32)> {
    let l = (x * x + y * y).sqrt();
    (l > 0.0 && l.is_finite()).then(|| (x / l, y / l))
}

/// `x` in 48.16 fixed point (saturating).
#[inline]
fn fixed(x: f32) -> i64 {
    (x * 65536.0) as i64
}

/// `floor(x)` as an integer, saturating (no libm call).
#[inline]
fn fast_floor(x: f32) -> i32 {
    let i = x as i32;
    i - ((x < i as f32) as i32)
}

/// Distance from coordinate `o` to the boundary of `[0, size]` along a direction component
/// of reciprocal `inv` (`±∞` for a zero component).
#[cfg(test)]
#[inline]
fn exit(o: f32, inv: f32, size: f32) -> f32 {
    if inv > 0.0 {
        (size - o) * inv
    } else if inv < 0.0 {
        -o * inv
    } else {
        f32::INFINITY
    }
}

/// One half-plane `ω = cos γ V + sin γ u`, `γ ∈ [0, π]`: the arc `[lo, hi]` where
/// `f(γ) = (a cos γ + b sin γ) sin γ` is positive (`a = n·V`, `b = n·u`).
#[derive(Debug, Clone, Copy, Default)]
struct Slice {
    a: f32,
    b: f32,
    /// `1/R`, `R = √(a² + b²)` the length of `n` projected on the plane.
    inv_r: f32,
    lo: f32,
    /// `(sin lo, cos lo)`.
    lo_sc: (f32, f32),
    hi: f32,
    /// `(sin hi, cos hi)`.
    hi_sc: (f32, f32),
    /// `G(lo)`, `G(hi)`.
    g_lo: f32,
    g_hi: f32,
}

impl Slice {
    /// `None` when no direction of the half-plane is above the tangent plane. (Production
    /// code runs the same arithmetic on four lanes: [`Ctx::setup_lanes`].)
    #[cfg(test)]
    #[inline]
    fn new(a: f32, b: f32) -> Option<Slice> {
        let r = (a * a + b * b).sqrt();
        if !(r > 1e-6 && r.is_finite()) {
            return None;
        }
        let inv_r = 1.0 / r;
        // (cos γn, sin γn): n·ω = R cos(γ − γn) is positive on (γn − π/2, γn + π/2) mod 2π.
        let (ca, sb) = (a * inv_r, b * inv_r);
        let (lo, lo_sc, hi, hi_sc) = if a > 0.0 {
            (0.0, (0.0, 1.0), fast_atan2(b, a) + FRAC_PI_2, (ca, -sb))
        } else {
            let gn = if b == 0.0 { PI } else { fast_atan2(b, a) };
            let lo = if gn < FRAC_PI_2 {
                gn + 1.5 * PI
            } else {
                gn - FRAC_PI_2
            };
            (lo, (-ca, sb), PI, (0.0, -1.0))
        };
        if !(hi > lo) {
            return None;
        }
        let mut sl = Slice {
            a,
            b,
            inv_r,
            lo,
            lo_sc,
            hi,
            hi_sc,
            g_lo: 0.0,
            g_hi: 0.0,
        };
        if a > 0.0 {
            // G(0) = −a/4; at hi, cos 2hi = (b² − a²)/R², sin 2hi = −2ab/R².
            sl.g_lo = -0.25 * a;
            sl.g_hi = 0.25 * a + 0.5 * b * hi;
        } else {
            sl.g_lo = sl.g(lo_sc.0, lo_sc.1, lo);
            sl.g_hi = sl.g(hi_sc.0, hi_sc.1, hi);
        }
        Some(sl)
    }

    /// Antiderivative of `f`, `G(γ) = −(a/4) cos 2γ + (b/2) γ − (b/4) sin 2γ`, from
    /// `(sin γ, cos γ)` and `γ`.
    #[inline]
    fn g(&self, s: f32, c: f32, gamma: f32) -> f32 {
        -0.25 * self.a * (c * c - s * s) + 0.5 * self.b * (gamma - s * c)
    }

    /// The open value `T = ∫ f` over the arc.
    #[cfg(test)]
    #[inline]
    fn open(&self) -> f32 {
        (self.g_hi - self.g_lo).max(0.0)
    }

    /// `f(γ)` clamped at 0, from `(sin γ, cos γ)`.
    #[inline]
    fn f(&self, s: f32, c: f32) -> f32 {
        (self.a * c + self.b * s).max(0.0) * s
    }

    /// Distance along in-plane direction `(sin γ, cos γ)` to the surface `blocker` models.
    #[inline]
    fn distance(&self, blocker: Blocker, s: f32, c: f32) -> f32 {
        let (r, x) = match blocker {
            Blocker::Segment { px, py, qx, qy } => {
                let (ex, ey) = (qx - px, qy - py);
                ((px * ey - py * ex) / (s * ey - c * ex), qx)
            }
            Blocker::First { tau, eta, x } => {
                // η = κτ² through the sample, tangent to the tangent line at p.
                let tw = (s * self.a - c * self.b) * self.inv_r;
                let ew = (s * self.b + c * self.a) * self.inv_r;
                (ew * tau * tau / (eta * tw * tw), x)
            }
        };
        if r > 0.0 && r.is_finite() {
            r
        } else if s > 0.0 {
            x / s // the slab behind the sample
        } else {
            f32::INFINITY
        }
    }
}

/// The surface between the previous sample and the one raising the horizon.
#[derive(Debug, Clone, Copy)]
enum Blocker {
    /// The segment from the previous sample `(px, py)` to this one `(qx, qy)`.
    Segment { px: f32, py: f32, qx: f32, qy: f32 },
    /// No previous sample: the parabola tangent to the tangent plane at `p` through this
    /// sample, at tangent coordinate `tau` and height `eta` (in the plane) and outward `x`.
    First { tau: f32, eta: f32, x: f32 },
}

/// The running horizon of one half-plane march.
#[derive(Debug, Clone, Copy, Default)]
struct Horizon {
    slice: Slice,
    /// The linear forms giving a sample's in-plane coordinates `x = v·fx` (outward) and
    /// `y = v·fy` (towards the sensor) from its offset `v = s − p`.
    fx: Vec3A,
    fy: Vec3A,
    /// Current horizon angle from `V` (directions in `[h, hi]` are blocked), its
    /// `(sin, cos)` and `G(h)`.
    h: f32,
    sc: (f32, f32),
    g_h: f32,
    /// Σ of the blocked terms so far.
    acc: f32,
}

impl Horizon {
    #[inline]
    fn new(slice: Slice, fx: Vec3A, fy: Vec3A) -> Horizon {
        Horizon {
            slice,
            fx,
            fy,
            h: slice.hi,
            sc: slice.hi_sc,
            g_h: slice.g_hi,
            acc: 0.0,
        }
    }

    /// Raises the horizon to the sample at in-plane `(x, y)`, adding the blocked directions;
    /// `(px, py)` is the previous sample of the march (NaN before the first).
    #[inline(never)]
    fn raise(&mut self, x: f32, y: f32, px: f32, py: f32, rho: &Rho) {
        let sl = &self.slice;
        let il = 1.0 / (x * x + y * y).sqrt();
        let (mut s, mut c) = (x * il, y * il);
        let mut gk = fast_atan2(x, y).min(self.h);
        if gk <= sl.lo {
            (gk, s, c) = (sl.lo, sl.lo_sc.0, sl.lo_sc.1);
        }
        let g_k = sl.g(s, c, gk);
        let full = self.g_h - g_k;
        // ρ ≡ 0 for plain ambient occlusion; a negligible sliver is not worth the quadrature.
        if full > 1e-7 && !rho.blocks_fully {
            let blocker = if px > 0.0 {
                Blocker::Segment {
                    px,
                    py,
                    qx: x,
                    qy: y,
                }
            } else {
                // No previous sample (NaN) or one behind the line of V.
                Blocker::First {
                    tau: (x * sl.a - y * sl.b) * sl.inv_r,
                    eta: (x * sl.b + y * sl.a) * sl.inv_r,
                    x,
                }
            };
            self.acc += full * sl.mean_rho(blocker, (s, c), self.sc, rho);
        }
        self.h = gk;
        self.sc = (s, c);
        self.g_h = g_k;
    }

    /// `S`: the blocked terms plus the open directions above the horizon.
    #[inline]
    fn value(&self) -> f32 {
        self.acc + (self.g_h - self.slice.g_lo).max(0.0)
    }
}

impl Slice {
    /// The `f`-weighted mean of `ρ(r(γ))` over the arc from direction `e0` to `e1` (as
    /// `(sin, cos)`, at most π apart), by Simpson's rule on the end points and the bisector.
    #[inline]
    fn mean_rho(&self, blocker: Blocker, e0: (f32, f32), e1: (f32, f32), rho: &Rho) -> f32 {
        let m = unit(e0.0 + e1.0, e0.1 + e1.1).unwrap_or((1.0, 0.0));
        let rho_at = |e: (f32, f32)| rho.at(self.distance(blocker, e.0, e.1));
        let rho_m = rho_at(m);
        let cos = e0.0 * e1.0 + e0.1 * e1.1;
        // Under ~8° the midpoint is as good (ρ and f are smooth over the arc).
        if cos > 0.99 {
            return rho_m;
        }
        let (mut num, mut den) = (0.0f32, 0.0f32);
        let mut node = |e: (f32, f32), w: f32, r: f32| {
            let wf = w * self.f(e.0, e.1);
            num += wf * r;
            den += wf;
        };
        node(e0, 1.0, rho_at(e0));
        node(e1, 1.0, rho_at(e1));
        if cos > 0.9 {
            node(m, 4.0, rho_m);
        } else {
            // Over ~26°: composite Simpson on the quarter points too.
            let q0 = unit(e0.0 + m.0, e0.1 + m.1).unwrap_or(m);
            let q1 = unit(m.0 + e1.0, m.1 + e1.1).unwrap_or(m);
            node(m, 2.0, rho_m);
            node(q0, 4.0, rho_at(q0));
            node(q1, 4.0, rho_at(q1));
        }
        if den > 0.0 {
            num / den
        } else {
            rho_m
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gbuffer::rasterize;
    use crate::projection::Model;
    use crate::ssao::rho;
    use crate::ssao::Estimator;
    use glam::{Mat2, Mat3, Vec2, Vec3};

    const DEPTH0: f32 = 1000.0;

    fn params(directions: u32, steps: u32, tmax: f32) -> SsaoParams {
        SsaoParams {
            estimator: Estimator::Horizon,
            radius: tmax,
            tmax,
            falloff: Falloff::Smoothstep,
            samples: 32,
            directions,
            steps,
            seed: 1,
            blur: false,
        }
    }

    /// An orthographic sensor looking down at z = 0 with square pixels of size `step`.
    fn ortho(w: usize, h: usize, step: f32) -> Projection {
        let model = Model::Ortho {
            a: Vec3::new(1.0 / step, 0.0, 0.0),
            a0: 0.0,
            b: Vec3::new(0.0, 1.0 / step, 0.0),
            b0: 0.0,
            toward: Vec3::Z,
            depth0: DEPTH0,
        };
        Projection::new(model, w, h, false)
    }

    /// A height field `z = f(x, y)` (with its normal) seen from above: one point per pixel
    /// centre.
    fn heightfield(
        w: usize,
        h: usize,
        step: f32,
        f: impl Fn(f32, f32) -> (f32, Vec3),
    ) -> (GBuffer, Projection) {
        let (mut pts, mut nrm) = (Vec::new(), Vec::new());
        for i in 0..w * h {
            let x = ((i % w) as f32 + 0.5) * step;
            let y = ((i / w) as f32 + 0.5) * step;
            let (z, n) = f(x, y);
            pts.push(Vec3::new(x, y, z));
            nrm.push(n);
        }
        let px: Vec<u32> = (0..(w * h) as u32).collect();
        let d: Vec<f32> = pts.iter().map(|p| DEPTH0 - p.z).collect();
        let g = rasterize(w, h, &px, &d, &pts, &nrm, &vec![step; w * h]);
        (g, ortho(w, h, step))
    }

    /// The G-buffer of an analytic scene ray cast through every pixel centre (`hit` returns
    /// the ray parameter and normal of the first hit; rays are unit for point sensors).
    fn cast(proj: &Projection, hit: impl Fn(Vec3, Vec3) -> Option<(f32, Vec3)>) -> GBuffer {
        let (mut px, mut d, mut pts, mut nrm) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for i in 0..proj.width * proj.height {
            let (x, y) = ((i % proj.width) as f32 + 0.5, (i / proj.width) as f32 + 0.5);
            let Some((o, dir)) = proj.ray(x, y) else {
                continue;
            };
            if let Some((t, n)) = hit(o, dir) {
                px.push(i as u32);
                d.push(t);
                pts.push(o + dir * t);
                nrm.push(n);
            }
        }
        let r = vec![0.01; pts.len()];
        rasterize(proj.width, proj.height, &px, &d, &pts, &nrm, &r)
    }

    /// A full-circle equirect sensor at the origin, pole along z.
    fn equirect(w: usize, h: usize) -> Projection {
        let model = Model::Equirect {
            rot: Mat3::IDENTITY,
            az_ref: 0.0,
            sx: w as f32 / TAU,
            ox: w as f32 * 0.5,
            sy: -(h as f32) / PI,
            oy: h as f32 * 0.5,
        };
        Projection::new(model, w, h, true)
    }

    /// Corners of a closed 6 × 5 × 3 m room around a scanner 1.5 m above its floor.
    const ROOM: (Vec3, Vec3) = (Vec3::new(-2.5, -2.0, -1.5), Vec3::new(3.5, 3.0, 1.5));

    /// The G-buffer of [`ROOM`] seen by `proj`.
    fn room(proj: &Projection) -> GBuffer {
        cast(proj, |o, d| box_hit(o, d, ROOM.0, ROOM.1))
    }

    /// The G-buffer of the floor z = −3 and the wall y = 4 seen by `proj`.
    fn floor_and_wall(proj: &Projection) -> GBuffer {
        cast(proj, |o, d| {
            let f = plane(o, d, Vec3::Z, -3.0).map(|t| (t, Vec3::Z));
            let wl = plane(o, d, Vec3::NEG_Y, -4.0).map(|t| (t, Vec3::NEG_Y));
            match (f, wl) {
                (Some(a), Some(b)) => Some(if a.0 < b.0 { a } else { b }),
                (a, b) => a.or(b),
            }
        })
    }

    /// A pinhole camera at the origin looking along +y, pitched down by `pitch`, 60° vertical
    /// field of view.
    fn camera(w: usize, h: usize, pitch: f32) -> Projection {
        let z = Vec3::new(0.0, pitch.cos(), -pitch.sin());
        let x = Vec3::X;
        let y = z.cross(x);
        let f = (h as f32 * 0.5) / 30f32.to_radians().tan();
        let model = Model::Perspective {
            rot: Mat3::from_cols(x, y, z).transpose(),
            a: Mat2::from_diagonal(Vec2::splat(f)),
            c: Vec2::new(w as f32 * 0.5, h as f32 * 0.5),
        };
        Projection::new(model, w, h, false)
    }

    /// Ray-plane hit `n·x = c` (normal facing the ray's origin side).
    fn plane(o: Vec3, d: Vec3, n: Vec3, c: f32) -> Option<f32> {
        let den = n.dot(d);
        let t = (c - n.dot(o)) / den;
        (den < 0.0 && t > 0.0).then_some(t)
    }

    /// Cosine-weighted, stratified directions around `n` (Malley), `k × k` of them.
    fn cosine_dirs(n: Vec3, k: usize, seed: u64) -> Vec<Vec3> {
        let (t1, t2) = n.any_orthonormal_pair();
        let mut rng = Rng::new(seed, 0);
        let mut out = Vec::with_capacity(k * k);
        for i in 0..k {
            for j in 0..k {
                let u1 = (i as f32 + rng.next_f32()) / k as f32;
                let u2 = (j as f32 + rng.next_f32()) / k as f32;
                let r = u1.sqrt();
                let (s, c) = (TAU * u2).sin_cos();
                out.push(t1 * (r * c) + t2 * (r * s) + n * (1.0 - u1).max(0.0).sqrt());
            }
        }
        out
    }

    #[test]
    fn open_planes_read_exactly_one() {
        // A level floor from above, for any budget and falloff.
        let (g, proj) = heightfield(48, 40, 0.01, |_, _| (0.0, Vec3::Z));
        for (k, s) in [(1, 1), (3, 5), (8, 8), (32, 64)] {
            for tmax in [0.02, 0.1, 1e6] {
                let m = ssao(&g, &proj, &params(k, s, tmax));
                assert!(
                    m.ao.iter().all(|&a| (a - 1.0).abs() < 1e-6),
                    "({k},{s}) t={tmax}"
                );
                // Only a border pixel can have all its half-lines leave the map at once.
                for (i, &f) in m.no_sample.iter().enumerate() {
                    let (x, y) = (i % 48, i / 48);
                    assert!(!f || x < 3 || y < 3 || x > 44 || y > 36, "{i} flagged");
                }
            }
        }
        // A tilted plane from above: seen obliquely (n ≠ V).
        let n = Vec3::new(-0.6, -0.3, 1.0).normalize();
        let (g, proj) = heightfield(48, 40, 0.01, |x, y| (0.6 * x + 0.3 * y, n));
        for (k, s) in [(1, 1), (5, 7), (32, 64)] {
            let m = ssao(&g, &proj, &params(k, s, 0.1));
            let worst = m.ao.iter().map(|a| (a - 1.0).abs()).fold(0.0, f32::max);
            assert!(worst < 1e-6, "tilted ({k},{s}): {worst}");
        }
        // A floor seen by a pitched pinhole camera, grazing at the top of the image.
        let proj = camera(96, 72, 25f32.to_radians());
        let g = cast(&proj, |o, d| {
            plane(o, d, Vec3::Z, -1.5).map(|t| (t, Vec3::Z))
        });
        let m = ssao(&g, &proj, &params(16, 16, 0.3));
        let worst = m.ao.iter().map(|a| (a - 1.0).abs()).fold(0.0, f32::max);
        assert!(worst < 1e-6, "perspective floor: {worst}");
        assert!(m.no_sample.iter().filter(|&&f| !f).count() > 1000);
        // A floor around a terrestrial scanner (equirectangular, wrapping in azimuth).
        let proj = equirect(256, 128);
        let g = cast(&proj, |o, d| {
            plane(o, d, Vec3::Z, -1.5).map(|t| (t, Vec3::Z))
        });
        let m = ssao(&g, &proj, &params(8, 8, 0.5));
        let worst = m.ao.iter().map(|a| (a - 1.0).abs()).fold(0.0, f32::max);
        assert!(worst < 1e-6, "equirect floor: {worst}");
        assert!(g.filled() > 10_000);
    }

    /// A floor z = 0 for x < 48 and a block of height `hgt` for x ≥ 48 (pixel size 1).
    fn step_scene(hgt: f32) -> (GBuffer, Projection) {
        heightfield(96, 192, 1.0, |x, _| {
            (if x >= 48.0 { hgt } else { 0.0 }, Vec3::Z)
        })
    }

    #[test]
    fn floor_next_to_a_wall_tends_to_half_and_darkens_towards_it() {
        // Infinitely tall wall, ρ ≈ 0 in range: a floor point half a pixel from the step sees
        // half of its cosine-weighted hemisphere blocked.
        let (g, proj) = step_scene(1000.0);
        let m = ssao(&g, &proj, &params(64, 256, 1e6));
        let a = m.ao[96 * 96 + 47];
        eprintln!("δ = 0.5 from an H = 1000 wall: A = {a:.4}");
        assert!((0.45..=0.55).contains(&a), "next to the wall: {a}");
        // Wall of height H = 10 at distance δ (cosine AO, t_max = ∞ in effect):
        // A = 1/2 + k / (2√(1+k²)), k = δ/H.
        let (g, proj) = step_scene(10.0);
        let m = ssao(&g, &proj, &params(64, 256, 1e6));
        let mut prev = 0.0f32;
        let mut worst = 0.0f32;
        for j in 0..16 {
            let a = m.ao[96 * 96 + 47 - j];
            let k = (j as f32 + 0.5) / 10.0;
            let exact = 0.5 + k / (2.0 * (1.0 + k * k).sqrt());
            worst = worst.max((a - exact).abs());
            assert!(
                a > prev,
                "not increasing away from the wall at δ = {}: {a} ≤ {prev}",
                j
            );
            prev = a;
        }
        eprintln!("H = 10 wall, δ = 0.5…15.5: worst |a − exact| = {worst:.4}");
        assert!(worst < 0.03, "off the analytic wall AO by {worst}");
    }

    #[test]
    fn bottom_of_a_narrow_pit_is_dark() {
        let (g, proj) = heightfield(21, 21, 1.0, |x, y| {
            let pit = (x - 10.5).abs() < 0.1 && (y - 10.5).abs() < 0.1;
            (if pit { 0.0 } else { 50.0 }, Vec3::Z)
        });
        let m = ssao(&g, &proj, &params(16, 16, 1e6));
        let a = m.ao[10 * 21 + 10];
        eprintln!("pit bottom: A = {a:.4}");
        assert!(a < 0.1, "{a}");
        assert!(!m.no_sample[10 * 21 + 10]);
    }

    /// A smooth random-looking height field (pixel size 1) and its gradient.
    fn waves(x: f32, y: f32) -> (f32, Vec3) {
        const W: [(f32, f32, f32, f32); 3] = [
            // amplitude, kx, ky, phase
            (7.0, 0.150, 0.045, 0.3),
            (4.5, -0.093, 0.233, 1.7),
            (1.5, 0.341, 0.341, 4.0),
        ];
        let (mut z, mut gx, mut gy) = (0.0f32, 0.0f32, 0.0f32);
        for (a, kx, ky, ph) in W {
            let arg = kx * x + ky * y + ph;
            z += a * arg.sin();
            gx += a * kx * arg.cos();
            gy += a * ky * arg.cos();
        }
        (z, Vec3::new(-gx, -gy, 1.0).normalize())
    }

    /// Ray-traced obscurance of the analytic `waves` field at `p`: stratified cosine rays
    /// marched in steps of 0.1 and refined by bisection.
    fn waves_reference(p: Vec3, n: Vec3, tmax: f32) -> f32 {
        waves_reference_with(p, n, tmax, Falloff::Smoothstep, f32::INFINITY)
    }

    /// [`waves_reference`] with any falloff, the field cut at the square `[0, size]²` (what a
    /// map of that size holds: rays leaving it miss).
    fn waves_reference_with(p: Vec3, n: Vec3, tmax: f32, falloff: Falloff, size: f32) -> f32 {
        let dirs = cosine_dirs(n, 40, 7);
        let dt = 0.1f32;
        let mut sum = 0.0f32;
        for w in &dirs {
            let below = |t: f32| {
                let q = p + *w * t;
                q.z < waves(q.x, q.y).0
            };
            let gone = |t: f32| {
                let q = p + *w * t;
                // Above the highest crest and rising, or off the map: a miss.
                (q.z > 13.5 && w.z >= 0.0)
                    || !(q.x >= 0.0 && q.y >= 0.0 && q.x <= size && q.y <= size)
            };
            let mut d = f32::INFINITY;
            let mut t = dt;
            while t < tmax + dt && !gone(t) {
                if below(t) {
                    let (mut lo, mut hi) = (t - dt, t);
                    for _ in 0..20 {
                        let mid = 0.5 * (lo + hi);
                        if below(mid) {
                            hi = mid;
                        } else {
                            lo = mid;
                        }
                    }
                    d = hi;
                    break;
                }
                t += dt;
            }
            sum += falloff.rho(d, tmax);
        }
        sum / dirs.len() as f32
    }

    #[test]
    fn every_falloff_and_an_infinite_tmax_converge_to_the_ray_traced_height_field() {
        let w = 160usize;
        let (g, proj) = heightfield(w, w, 1.0, waves);
        let picks: Vec<usize> = (0..12)
            .flat_map(|yy| (0..12).map(move |xx| (20 + 10 * yy) * w + 20 + 10 * xx))
            .collect();
        let inf = f32::INFINITY;
        for (tmax, falloff, limit) in [
            (inf, Falloff::Smoothstep, 0.012),
            (inf, Falloff::None, 0.012),
            (inf, Falloff::Exp(20.0), 0.012),
            (16.0, Falloff::Linear, 0.012),
            (16.0, Falloff::None, 0.012),
            (16.0, Falloff::Exp(20.0), 0.012),
        ] {
            let refs: Vec<(usize, f32)> = picks
                .iter()
                .map(|&i| {
                    let a =
                        waves_reference_with(g.position[i], g.normal[i], tmax, falloff, w as f32);
                    (i, a)
                })
                .collect();
            let (lo, hi) = refs
                .iter()
                .fold((1.0f32, 0.0f32), |(a, b), r| (a.min(r.1), b.max(r.1)));
            let prm = SsaoParams {
                falloff,
                ..params(64, 64, tmax)
            };
            let e = mean_abs_error(&ssao(&g, &proj, &prm), &refs);
            eprintln!("t_max {tmax} {falloff}: A in [{lo:.3}, {hi:.3}], mean |a − A| {e:.4}");
            assert!(
                hi - lo > 0.3,
                "{tmax} {falloff}: A should span 0.3, [{lo}, {hi}]"
            );
            assert!(e < limit, "{tmax} {falloff}: {e}");
        }
    }

    fn mean_abs_error(m: &AoMap, refs: &[(usize, f32)]) -> f32 {
        refs.iter().map(|&(i, r)| (m.ao[i] - r).abs()).sum::<f32>() / refs.len() as f32
    }

    #[test]
    fn converges_to_the_ray_traced_height_field() {
        let (w, tmax) = (160usize, 16.0f32);
        let (g, proj) = heightfield(w, w, 1.0, waves);
        let refs: Vec<(usize, f32)> = (0..16)
            .flat_map(|yy| (0..16).map(move |xx| (16 + 8 * yy) * w + 16 + 8 * xx))
            .map(|i| (i, waves_reference(g.position[i], g.normal[i], tmax)))
            .collect();
        let mean = refs.iter().map(|r| r.1).sum::<f32>() / refs.len() as f32;
        let min = refs.iter().map(|r| r.1).fold(1.0f32, f32::min);
        assert!(
            min < 0.7,
            "the field should have some occlusion: min A = {min}"
        );
        let err = |k: u32, s: u32| mean_abs_error(&ssao(&g, &proj, &params(k, s, tmax)), &refs);
        let (e4, e8, e16, e32, e64) = (err(4, 4), err(8, 8), err(16, 16), err(32, 32), err(64, 64));
        eprintln!(
            "reference A: mean {mean:.3}, min {min:.3}; mean |a − A| at (4,4) {e4:.4}, (8,8) {e8:.4}, \
             (16,16) {e16:.4}, (32,32) {e32:.4}, (64,64) {e64:.4}"
        );
        assert!(e64 < 0.02, "{e64}");
        assert!(e4 > e32, "{e4} vs {e32}");
    }

    #[test]
    fn oblique_pinhole_view_of_floor_and_wall_matches_the_reference() {
        // Camera at the origin pitched 35° down; floor z = −3, wall y = 4 facing the camera.
        let proj = camera(256, 256, 35f32.to_radians());
        let g = floor_and_wall(&proj);
        let tmax = 1.0f32;
        let m = ssao(&g, &proj, &params(64, 64, tmax));
        let mut n = 0;
        let mut err = 0.0f32;
        for i in 0..g.width * g.height {
            let p = g.position[i];
            let delta = 4.0 - p.y;
            let on_floor = g.is_valid(i) && g.normal[i] == Vec3::Z && p.x.abs() < 0.5;
            if !(on_floor && (0.15..1.0).contains(&delta)) {
                continue;
            }
            let dirs = cosine_dirs(Vec3::Z, 32, i as u64);
            let reference = dirs
                .iter()
                .map(|w| {
                    rho(
                        if w.y > 0.0 {
                            delta / w.y
                        } else {
                            f32::INFINITY
                        },
                        tmax,
                    )
                })
                .sum::<f32>()
                / dirs.len() as f32;
            err += (m.ao[i] - reference).abs();
            n += 1;
        }
        assert!(n > 100, "{n}");
        let err = err / n as f32;
        eprintln!("oblique floor by a wall: {n} px, mean |a − A| = {err:.4}");
        assert!(err < 0.03, "{err}");
    }

    /// First hit from inside the box `[lo, hi]`: ray parameter and inward normal.
    fn box_hit(o: Vec3, d: Vec3, lo: Vec3, hi: Vec3) -> Option<(f32, Vec3)> {
        let mut best: Option<(f32, Vec3)> = None;
        for axis in 0..3 {
            let (dv, ov) = (d[axis], o[axis]);
            let (t, mut n) = if dv > 0.0 {
                ((hi[axis] - ov) / dv, Vec3::ZERO)
            } else if dv < 0.0 {
                ((lo[axis] - ov) / dv, Vec3::ZERO)
            } else {
                continue;
            };
            n[axis] = -dv.signum();
            if t > 0.0 && best.is_none_or(|b| t < b.0) {
                best = Some((t, n));
            }
        }
        best
    }

    #[test]
    fn equirect_courtyard_under_open_sky_converges_at_infinite_tmax() {
        // A scanner 1.5 m above the floor of a 20 × 20 m court with 8 m walls and no roof:
        // plain ambient occlusion reaches the far walls, tens of degrees round the great
        // circles the half-planes image to.
        let (w, h) = (512usize, 256usize);
        let proj = equirect(w, h);
        let (lo, hi) = (Vec3::new(-10.0, -10.0, -1.5), Vec3::new(10.0, 10.0, 6.5));
        let court = |o: Vec3, d: Vec3| box_hit(o, d, lo, hi).filter(|b| b.1 != Vec3::NEG_Z);
        let g = cast(&proj, court);
        let mut rng = Rng::new(5, 0);
        let mut picks = Vec::new();
        while picks.len() < 300 {
            let i = (rng.next_u64() % (w * h) as u64) as usize;
            if g.is_valid(i) {
                let (p, nrm) = (g.position[i], g.normal[i]);
                let dirs = cosine_dirs(nrm, 24, i as u64);
                let open = dirs
                    .iter()
                    .filter(|&&d| court(p + nrm * 1e-4, d).is_none())
                    .count();
                picks.push((i, open as f32 / dirs.len() as f32));
            }
        }
        let (lo_a, hi_a) = picks
            .iter()
            .fold((1.0f32, 0.0f32), |(a, b), r| (a.min(r.1), b.max(r.1)));
        assert!(hi_a - lo_a > 0.3, "A in [{lo_a}, {hi_a}]");
        let inf = f32::INFINITY;
        let errs: Vec<f32> = [(8, 8), (16, 32), (32, 64)]
            .iter()
            .map(|&(k, st)| mean_abs_error(&ssao(&g, &proj, &params(k, st, inf)), &picks))
            .collect();
        eprintln!("open court at t_max = ∞, A in [{lo_a:.3}, {hi_a:.3}]: mean |a − A| {errs:?}");
        // Straight image lines instead of great circles stay near 0.21 at every budget.
        assert!(errs[1] < 0.08 && errs[2] < 0.04, "{errs:?}");
    }

    #[test]
    fn equirect_room_matches_the_reference() {
        // A terrestrial scanner 1.5 m above the floor of a closed 6 × 5 × 3 m room.
        let (w, h) = (1024usize, 512usize);
        let proj = equirect(w, h);
        let (lo, hi) = ROOM;
        let g = room(&proj);
        let tmax = 0.5f32;
        let m = ssao(&g, &proj, &params(32, 32, tmax));
        // Mean |a − A| over 400 random pixels, and over those with A < 0.9, in a band of
        // elevations (the half-line is the tangent of a great circle: fine away from the poles).
        let sample = |el_range: std::ops::Range<f32>, seed: u64| {
            let (mut err, mut n, mut err_dark, mut dark) = (0.0f32, 0, 0.0f32, 0);
            let mut rng = Rng::new(seed, 0);
            while n < 400 {
                let i = (rng.next_u64() % (w * h) as u64) as usize;
                let el = ((h / 2) as f32 - (i / w) as f32 - 0.5) * PI / h as f32;
                if !g.is_valid(i) || !el_range.contains(&el.abs().to_degrees()) {
                    continue;
                }
                let (p, nrm) = (g.position[i], g.normal[i]);
                let dirs = cosine_dirs(nrm, 24, i as u64);
                let reference = dirs
                    .iter()
                    .map(|&d| {
                        let hit = box_hit(p + nrm * 1e-4, d, lo, hi);
                        rho(hit.map_or(f32::INFINITY, |b| b.0), tmax)
                    })
                    .sum::<f32>()
                    / dirs.len() as f32;
                let e = (m.ao[i] - reference).abs();
                if reference < 0.9 {
                    err_dark += e;
                    dark += 1;
                }
                err += e;
                n += 1;
            }
            (err / n as f32, err_dark / dark.max(1) as f32, dark)
        };
        let (err, err_dark, dark) = sample(0.0..60.0, 3);
        let (err_pole, err_pole_dark, dark_pole) = sample(60.0..90.0, 4);
        eprintln!(
            "equirect room, |el| < 60°: mean |a − A| = {err:.4} ({dark} px with A < 0.9: \
             {err_dark:.4}); |el| ≥ 60°: {err_pole:.4} ({dark_pole} px: {err_pole_dark:.4})"
        );
        assert!(dark > 20, "{dark}");
        assert!(err < 0.02 && err_dark < 0.05, "{err} {err_dark}");
    }

    #[test]
    fn lanes_set_up_and_march_exactly_like_one_half_plane_at_a_time() {
        let (pinhole, scanner) = (camera(96, 96, 35f32.to_radians()), equirect(256, 128));
        // The room again with normals tilted at random, a third of them facing away from the
        // sensor (n·V ≤ 0 takes the other branch of the slice set-up), some exactly ⊥ V.
        let mut tilted = room(&scanner);
        let mut rng = Rng::new(9, 0);
        for (n, p) in tilted.normal.iter_mut().zip(&tilted.position) {
            let r = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
            *n = match rng.next_u64() % 6 {
                0 | 1 => -*n + r * 0.3,
                2 => (-*p).normalize_or_zero().any_orthogonal_vector(),
                _ => *n + r * 0.5,
            };
        }
        let scenes = [
            (heightfield(48, 40, 1.0, waves), 6.0),
            (step_scene(30.0), 20.0),
            ((floor_and_wall(&pinhole), pinhole), 1.0),
            ((room(&scanner), scanner.clone()), 0.5),
            ((tilted, scanner), 0.5),
        ];
        let mut raised = 0;
        for ((g, proj), tmax) in &scenes {
            let pts = positions(g);
            for (d, st, t) in [
                (1, 8, *tmax),
                (3, 5, *tmax),
                (8, 8, *tmax),
                (7, 30, f32::INFINITY),
            ] {
                let prm = params(d, st, t);
                let ctx = Ctx::new(g, &pts, proj, &prm);
                for c in 0..g.width * g.height {
                    if !g.is_valid(c) {
                        continue;
                    }
                    let (x, y) = (c % g.width, c / g.width);
                    let one = ctx.pixel_with(
                        x,
                        y,
                        c,
                        &mut Group::default(),
                        Ctx::setup_one,
                        Ctx::march_one,
                    );
                    let lanes = ctx.pixel_with(
                        x,
                        y,
                        c,
                        &mut Group::default(),
                        Ctx::setup_lanes,
                        Ctx::march_lanes,
                    );
                    assert_eq!(one.map(f32::to_bits), lanes.map(f32::to_bits), "pixel {c}");
                    raised += usize::from(one.is_some_and(|a| a < 1.0));
                }
            }
        }
        assert!(raised > 1000, "{raised}");
    }

    #[test]
    fn deterministic_for_a_seed_and_seeds_differ_a_little() {
        let (g, proj) = heightfield(64, 64, 1.0, waves);
        let a = ssao(&g, &proj, &params(8, 8, 10.0));
        let b = ssao(&g, &proj, &params(8, 8, 10.0));
        assert_eq!(a.ao, b.ao);
        let mut p = params(8, 8, 10.0);
        p.seed = 2;
        let c = ssao(&g, &proj, &p);
        assert_ne!(a.ao, c.ao);
        let diff =
            a.ao.iter()
                .zip(&c.ao)
                .map(|(x, y)| (x - y).abs())
                .sum::<f32>()
                / a.ao.len() as f32;
        eprintln!("seed 1 vs 2: mean |Δa| = {diff:.4}");
        assert!(diff < 0.05, "{diff}");
    }

    /// `∫_{x0}^{x1} ρ(r(γ)) f(γ) dγ` by a fine midpoint rule (f64).
    fn numeric(sl: &Slice, x0: f32, x1: f32, r: impl Fn(f64) -> f64, tmax: f32) -> f64 {
        let n = 20_000;
        let h = (x1 - x0) as f64 / n as f64;
        (0..n)
            .map(|i| {
                let gm = x0 as f64 + (i as f64 + 0.5) * h;
                let f = ((sl.a as f64) * gm.cos() + (sl.b as f64) * gm.sin()).max(0.0) * gm.sin();
                f * rho(r(gm) as f32, tmax) as f64 * h
            })
            .sum()
    }

    /// Open directions: ρ = 1.
    fn open(_: f64) -> f64 {
        f64::INFINITY
    }

    /// A march fed samples by their in-plane coordinates, with the tests of the march loops.
    struct Fed {
        hz: Horizon,
        prev: (f32, f32),
    }

    impl Fed {
        fn new(sl: Slice) -> Fed {
            Fed {
                hz: Horizon::new(sl, Vec3A::X, Vec3A::Y),
                prev: (f32::NAN, f32::NAN),
            }
        }

        /// A sample at `(x, y)`, above `p`'s tangent plane or not.
        fn add(&mut self, x: f32, y: f32, above: bool, tmax: f32) {
            if above && x > 0.0 && above_horizon(x, y, self.hz.sc.1) {
                let rho = Rho::new(Falloff::Smoothstep, tmax);
                self.hz.raise(x, y, self.prev.0, self.prev.1, &rho);
            }
            self.prev = (x, y);
        }

        fn value(&self) -> f32 {
            self.hz.value()
        }
    }

    #[test]
    fn hand_computed_slices() {
        // Surface facing the sensor: a = 1, b = 0, the tangent plane at γ = π/2.
        let sl = Slice::new(1.0, 0.0).expect("slice");
        assert!((sl.open() - 0.5).abs() < 1e-6);
        // t_max = ∞ (ρ = 0): the horizon set by (1,1) (45°), (2,1.5) hidden (53°), then
        // (2.5,3.5) raises it to γ = atan(2.5/3.5): S/T = sin²γ = 6.25/18.5, i.e.
        // 1 − sin²(elevation).
        let samples = [(1.0, 1.0), (2.0, 1.5), (2.5, 3.5)];
        let mut hz = Fed::new(sl);
        for (x, y) in samples {
            hz.add(x, y, true, f32::INFINITY);
        }
        let want = 6.25 / 18.5;
        assert!(
            (hz.value() / sl.open() - want).abs() < 1e-6,
            "{}",
            hz.value()
        );
        // Finite t_max. [45°, 90°]: the parabola η = τ² from p through (1,1) (no earlier
        // sample), r = cos γ / sin²γ. [γ₃, 45°]: the segment (2,1.5)–(2.5,3.5),
        // r = cross(P, D) / cross(ω, D) with D = (0.5, 2). [0, γ₃]: open.
        let tmax = 4.0;
        let mut hz = Fed::new(sl);
        for (x, y) in samples {
            hz.add(x, y, true, tmax);
        }
        let (g1, g3) = (FRAC_PI_2 / 2.0, 2.5f32.atan2(3.5));
        let parabola = |g: f64| g.cos() / (g.sin() * g.sin());
        assert!((parabola(g1 as f64) - 2f64.sqrt()).abs() < 1e-6);
        let segment = |g: f64| (2.0 * 2.0 - 1.5 * 0.5) / (g.sin() * 2.0 - g.cos() * 0.5);
        assert!((segment(g3 as f64) - 18.5f64.sqrt()).abs() < 1e-5);
        let expect = numeric(&sl, g1, FRAC_PI_2, parabola, tmax)
            + numeric(&sl, g3, g1, segment, tmax)
            + numeric(&sl, 0.0, g3, open, tmax);
        let got = hz.value() as f64;
        assert!((got - expect).abs() < 1e-3 * expect, "{got} vs {expect}");
        // Tilted normal n = 0.8 V + 0.6 u: tangent plane at γ = atan2(0.6, 0.8) + π/2.
        let sl = Slice::new(0.8, 0.6).expect("slice");
        assert!((sl.hi - (0.6f32.atan2(0.8) + FRAC_PI_2)).abs() < 1e-6);
        assert!((sl.open() as f64 - numeric(&sl, 0.0, PI, open, 1.0)).abs() < 1e-5);
        let mut hz = Fed::new(sl);
        // γ = 116.6°, above the tangent plane (126.9°): tangent coordinate τ = 1.1, height
        // η = 0.2 (R = 1), parabola η = κτ².
        hz.add(1.0, -0.5, true, 3.0);
        let gk = 1.0f32.atan2(-0.5);
        let parabola = |g: f64| {
            let (tw, ew) = (0.8 * g.sin() - 0.6 * g.cos(), 0.6 * g.sin() + 0.8 * g.cos());
            ew * 1.1 * 1.1 / (0.2 * tw * tw)
        };
        assert!((parabola(gk as f64) - 1.25f64.sqrt()).abs() < 1e-5);
        let expect = numeric(&sl, gk, sl.hi, parabola, 3.0) + numeric(&sl, 0.0, gk, open, 3.0);
        let got = hz.value() as f64;
        assert!((got - expect).abs() < 1e-4, "{got} vs {expect}");
        // Behind the line of V, below the tangent plane or below the current horizon: ignored.
        let before = hz.value();
        hz.add(-1.0, 1.0, true, 3.0);
        hz.add(1.0, 2.0, false, 3.0);
        hz.add(1.0, -0.6, true, 3.0);
        assert_eq!(hz.value(), before);
    }

    #[test]
    fn fast_atan2_matches_std() {
        let mut worst = 0.0f32;
        for i in 0..2000 {
            for j in 0..50 {
                let ang = -PI + TAU * (i as f32 + 0.5) / 2000.0;
                let r = 1e-3 + j as f32;
                let (y, x) = (r * ang.sin(), r * ang.cos());
                worst = worst.max((fast_atan2(y, x) - y.atan2(x)).abs());
            }
        }
        assert!(worst < 5e-7, "{worst}");
        for (y, x) in [
            (0.0f32, 1.0f32),
            (1.0, 0.0),
            (0.0, -1.0),
            (-1.0, 0.0),
            (1.0, 1.0),
            (0.0, 0.0),
        ] {
            assert!((fast_atan2(y, x) - y.atan2(x)).abs() < 5e-7, "{y} {x}");
        }
    }

    #[test]
    fn sub_pixel_reach_and_bad_normals_are_flagged() {
        let (g, proj) = heightfield(21, 21, 0.01, |_, _| (0.0, Vec3::Z));
        let m = ssao(&g, &proj, &params(8, 8, 0.004));
        assert!(m.no_sample[10 * 21 + 10]);
        assert_eq!(m.ao[10 * 21 + 10], 1.0);
        let (mut g, proj) = heightfield(21, 21, 0.01, |_, _| (0.0, Vec3::Z));
        g.normal[5] = Vec3::ZERO;
        g.normal[6] = Vec3::splat(f32::NAN);
        let m = ssao(&g, &proj, &params(8, 8, 0.05));
        assert!(m.no_sample[5] && m.no_sample[6] && !m.no_sample[7]);
        assert!(m.ao.iter().all(|a| a.is_finite()));
    }

    #[test]
    #[ignore]
    fn error_shrinks_with_resolution() {
        // The converged estimate differs from the analytic field's A by the range map's
        // discretization (nearest point per pixel, piecewise-linear profile between samples),
        // which shrinks with the pixel size. Slow-ish: run with --release.
        let tmax = 16.0f32;
        let mut errs = Vec::new();
        for (w, step) in [(160usize, 1.0f32), (320, 0.5), (640, 0.25)] {
            let (g, proj) = heightfield(w, w, step, waves);
            let scale = (1.0 / step) as usize;
            let refs: Vec<(usize, f32)> = (0..16)
                .flat_map(|yy| {
                    (0..16).map(move |xx| ((16 + 8 * yy) * scale) * w + (16 + 8 * xx) * scale)
                })
                .map(|i| (i, waves_reference(g.position[i], g.normal[i], tmax)))
                .collect();
            let e = mean_abs_error(&ssao(&g, &proj, &params(64, 128, tmax)), &refs);
            eprintln!("pixel {step}: mean |a − A| = {e:.4}");
            errs.push(e);
        }
        assert!(errs[2] < errs[0], "{errs:?}");
    }

    /// Process CPU time (user + system) in seconds, from `/proc/self/stat` (Linux).
    fn cpu_seconds() -> f64 {
        let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
        let rest = stat.rsplit(')').next().unwrap_or("");
        let f: Vec<f64> = rest
            .split_whitespace()
            .filter_map(|x| x.parse().ok())
            .collect();
        // After the command name: state is not numeric, so utime/stime are fields 11, 12.
        (f.get(10).copied().unwrap_or(0.0) + f.get(11).copied().unwrap_or(0.0)) / 100.0
    }

    #[test]
    #[ignore]
    fn speed_one_megapixel() {
        // Run alone: `cargo test --release --lib ssao::horizon::tests::speed -- --ignored`.
        // Reports wall time and CPU time (the machine may be shared).
        let n: usize = std::env::var("MVAO_SPEED_N")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(1024);
        let persp = camera(n, n, 35f32.to_radians());
        let g_persp = floor_and_wall(&persp);
        let (g_waves, ortho) = heightfield(n, n, 1.0, waves);
        let cases = [
            ("ortho waves, t_max 12 px", &g_waves, &ortho, 12.0f32),
            ("pinhole floor+wall, t_max 0.3", &g_persp, &persp, 0.3),
        ];
        let only = std::env::var("MVAO_SPEED_CASE").ok();
        for (name, g, proj, tmax) in cases {
            if only.as_deref().is_some_and(|o| !name.starts_with(o)) {
                continue;
            }
            let steps = std::env::var("MVAO_SPEED_STEPS")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(8);
            let dirs = std::env::var("MVAO_SPEED_DIRS")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(8);
            let prm = params(dirs, steps, tmax);
            let _ = ssao(g, proj, &prm);
            let reps = 3;
            let (t, c) = (std::time::Instant::now(), cpu_seconds());
            for _ in 0..reps {
                let _ = ssao(g, proj, &prm);
            }
            let wall = t.elapsed().as_secs_f64() / reps as f64;
            let cpu = (cpu_seconds() - c) / reps as f64;
            let px = g.filled() as f64 * 1e-6;
            eprintln!(
                "{name}: {:.2} Mpx valid, {dirs}×{steps}: wall {:.3} s ({:.2} Mpx/s on {} threads), \
                 CPU {:.3} s ({:.2} Mpx/s per core)",
                px,
                wall,
                px / wall,
                rayon::current_num_threads(),
                cpu,
                px / cpu
            );
            // Baseline on the same machine: the paper estimator with as many samples.
            let mut pp = prm;
            pp.samples = 64;
            let c = cpu_seconds();
            let _ = crate::ssao::paper::ssao(g, proj, &pp);
            eprintln!(
                "  paper estimator, 64 samples: CPU {:.3} s",
                cpu_seconds() - c
            );
        }
    }
}
