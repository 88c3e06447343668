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
//! starting where it leaves `p`'s own pixel, with `min(n, ⌊length⌋)` (at least 1) samples
//! evenly stratified with a per-half-plane jitter, so consecutive samples are at least a pixel
//! apart. `n` is `steps`, raised where the ellipse's smaller radius spans more than `steps`
//! strides of [`MAX_STRIDE`] pixels (up to [`MAX_STEP_GAIN`] × `steps`): with a fixed count,
//! at a large `t_max` the samples stride over occluders narrower than a stride (a court's
//! columns, `docs/accuracy.md`, "Large finite `t_max`"). Samples on `p`'s pixel, on empty
//! pixels or outside the map are skipped; a sample at 3-D distance `≥ t_max` is ignored
//! (beyond `t_max`, `ρ = 1`: it cannot darken `p`), and one within 10⁻⁵ rad of the tangent
//! plane counts as on it (rounding noise of a plane). Where `ρ`
//! jumps to 1 at `t_max` (`--falloff none`) the point where the profile leaves the `t_max`
//! sphere between a sample inside and the next one outside is taken as a sample too: the
//! surface blocks fully up to there, however far the last sample inside lies below. The pixel's
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
use crate::projection::{fast_atan2, Projection, SensorModel};
use glam::Vec3A;
use rayon::prelude::*;
use std::f32::consts::{FRAC_PI_2, PI, TAU};

mod lanes;

/// Widest stride of the march, pixels: occluders narrower than a stride can fall between two
/// samples, so where `t_max` spans more than `steps` strides the march takes more samples.
pub const MAX_STRIDE: f32 = 8.0;
/// At most this many times `steps` samples per half-line.
pub const MAX_STEP_GAIN: u32 = 8;

/// Computes the unblurred horizon-based obscurance of every valid pixel.
///
/// `prm.directions` half-planes and `prm.steps` samples per half-plane (both at least 1; more
/// samples where `t_max` spans many pixels, fewer where it spans fewer than `steps`),
/// falloff `prm.tmax`, per-pixel patterns from `prm.seed`. A projection whose size differs from
/// the G-buffer's cannot be marched: every valid pixel is then flagged.
pub fn ssao(g: &GBuffer, proj: &Projection, prm: &SsaoParams) -> AoMap {
    ssao_masked(g, proj, prm, None)
}

/// [`ssao`] evaluated only at the pixels `only` marks (all valid pixels when `None`); the
/// others keep 1, unflagged.
pub(crate) fn ssao_masked(
    g: &GBuffer,
    proj: &Projection,
    prm: &SsaoParams,
    only: Option<&[bool]>,
) -> AoMap {
    if let Some(map) = super::unmarchable(g, proj) {
        return map;
    }
    let n = g.width * g.height;
    let mut ao = crate::par::filled(n, 1.0f32);
    let mut flag = crate::par::filled(n, false);
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
                        if !g.is_valid(c) || only.is_some_and(|m| !m[c]) {
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
        levels: None,
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
    /// Samples per half-line (before the one-per-pixel bound).
    steps: u32,
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
    /// ρ jumps to 1 at a finite `t_max` (`--falloff none`, or `exp` with a long decay): where
    /// the profile leaves the `t_max` sphere between two samples, the point where it leaves
    /// is offered to the horizon too ([`Ctx::offer_exit`]).
    clip: bool,
    /// How far each receiver is lifted along its normal before its march
    /// ([`receiver_lift`]).
    lift: f32,
}

/// The receiver's lift over its surface, in multiples of the map's range noise along the
/// normals: a neighbour that noise lifted off the surface would otherwise read as an occluder a
/// pixel away, where `ρ` is nearly 0, and noise never brightens (a receiver whose range fell
/// short sees its neighbours above its tangent plane, one that overshot sees nothing below).
/// Three times the noise brings noisy stations back to their noise-free error
/// (`docs/accuracy.md`, "Range noise").
const NOISE_LIFT: f32 = 3.0;
/// The lift never exceeds this share of `t_max` (a rough surface is not all noise).
const MAX_LIFT_SHARE: f32 = 0.05;
/// Pixels sampled for the noise estimate at most.
const NOISE_SAMPLES: usize = 1 << 16;

/// The map's range noise along the normals: the median height of a pixel's right and lower
/// neighbours over its tangent plane, `|n·(q − p)|`, over a sample of pixels, scaled to a
/// standard deviation (÷ 0.6745 for a normal law's median, ÷ √2 for the two noisy ends). The
/// median passes over silhouettes and creases while they are a minority; on a smooth surface
/// the heights are curvature only, `s²/2R` for a pixel span `s`.
fn range_noise(g: &GBuffer, pts: &[Vec3A]) -> f32 {
    let (w, h) = (g.width, g.height);
    let n = w * h;
    if w < 2 || h < 2 {
        return 0.0;
    }
    let stride = (n / NOISE_SAMPLES).max(1);
    let mut hs: Vec<f32> = Vec::with_capacity(2 * n.div_ceil(stride));
    for c in (0..n).step_by(stride) {
        let (x, y) = (c % w, c / w);
        let p = pts[c];
        let nrm = Vec3A::from(g.normal[c]);
        let len = nrm.length();
        if p.x.is_nan() || !(len > 1e-6 && len.is_finite()) {
            continue;
        }
        for q in [(x + 1 < w).then(|| c + 1), (y + 1 < h).then(|| c + w)]
            .into_iter()
            .flatten()
        {
            let d = (pts[q] - p).dot(nrm) / len;
            if d.is_finite() {
                hs.push(d.abs());
            }
        }
    }
    if hs.is_empty() {
        return 0.0;
    }
    let mid = hs.len() / 2;
    let med = *hs.select_nth_unstable_by(mid, f32::total_cmp).1;
    med / (0.6745 * std::f32::consts::SQRT_2)
}

/// [`NOISE_LIFT`] times the map's range noise, at most [`MAX_LIFT_SHARE`] × `t_max`.
fn receiver_lift(g: &GBuffer, pts: &[Vec3A], tmax: f32) -> f32 {
    let lift = NOISE_LIFT * range_noise(g, pts);
    let cap = if tmax.is_finite() {
        MAX_LIFT_SHARE * tmax
    } else {
        lift
    };
    if lift.is_finite() {
        lift.min(cap).max(0.0)
    } else {
        0.0
    }
}

impl<'a> Ctx<'a> {
    /// Samples per half-line of a pixel whose `t_max` ellipse has the smaller radius `radius`
    /// pixels (before the one-per-pixel bound): `steps`, or more where they would stride over
    /// more than [`MAX_STRIDE`] pixels, up to [`MAX_STEP_GAIN`] × `steps`. The smaller radius,
    /// because an equirectangular map's rows shrink towards the poles: there a pixel across is
    /// less than the map resolves.
    #[inline(always)]
    fn steps_over(&self, radius: f32) -> u32 {
        let dense = (radius / MAX_STRIDE).ceil();
        let most = self.steps.saturating_mul(MAX_STEP_GAIN);
        if dense > self.steps as f32 {
            (dense.min(most as f32) as u32).max(self.steps)
        } else {
            self.steps
        }
    }

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
            clip: tmax2 > 0.0
                && prm.tmax.is_finite()
                && prm.falloff.rho(prm.tmax * (1.0 - 1e-6), prm.tmax) < 0.99,
            lift: if g.lift_receivers {
                receiver_lift(g, pts, prm.tmax)
            } else {
                0.0
            },
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
        let arc = if self.sphere {
            let dist = p.length();
            let angle = if self.tmax < dist {
                (self.tmax / dist).asin()
            } else {
                // The t_max sphere holds the sensor: the whole half circle.
                0.999 * PI
            };
            // The sensor is the map's origin: the point's distance turns metres ⊥ d into
            // radians.
            (angle > ARC_FROM).then_some((dist / per_m, angle))
        } else {
            None
        };
        grp.arc_on = arc.is_some();
        let a = nrm.dot(view);
        let (na, va) = (Vec3A::from(nrm), Vec3A::from(view));
        let pa = Vec3A::from(p) + na * self.lift;
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
            steps: self.steps_over(rx.min(ry)),
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

impl Ctx<'_> {
    /// Offers the horizon of a half-plane the point where the profile leaves the `t_max` sphere
    /// between the previous sample (offset `pv`, inside) and this one (`v`, outside), with the
    /// march's tests; returns that point's in-plane coordinates (where the next blocker
    /// starts), `None` when the segment does not leave the sphere. Without it a surface that
    /// crosses the sphere would block only up to its last sample inside, which a falloff that
    /// jumps at `t_max` weighs in full.
    #[inline(never)]
    fn offer_exit(
        &self,
        hz: &mut Horizon,
        (pa, na): (Vec3A, Vec3A),
        (pv, v): (Vec3A, Vec3A),
        prev: (f32, f32),
        arc_on: bool,
    ) -> Option<(f32, f32)> {
        let w = exit_point(pv, v, self.tmax2)?;
        let l2 = w.length_squared();
        let height = na.dot(w);
        let height = if height * height > 1e-10 * l2 {
            height
        } else {
            0.0
        };
        let (x, y) = (w.dot(hz.fx), w.dot(hz.fy));
        if height > 0.0
            && x > 0.0
            && above_horizon(x, y, hz.sc.1)
            && (!arc_on || joins_horizon(pa, w, hz.sc.1))
        {
            hz.raise(x, y, prev.0, prev.1, &self.rho);
        }
        Some((x, y))
    }
}

/// Where the segment from offset `pv` (inside the sphere `|v|² = r2`) to `v` (outside) leaves
/// the sphere.
#[inline]
fn exit_point(pv: Vec3A, v: Vec3A, r2: f32) -> Option<Vec3A> {
    let d = v - pv;
    let a = d.length_squared();
    let b = pv.dot(d);
    let c = pv.length_squared() - r2;
    let disc = b * b - a * c;
    if !(a > 0.0 && c < 0.0 && disc >= 0.0) {
        return None;
    }
    let s = (disc.sqrt() - b) / a;
    (s > 0.0 && s <= 1.0).then(|| pv + d * s)
}

/// Whether a sample at offset `v` from `p` (both relative to the sensor) extends the blocked
/// directions `[h, hi]` of a half-plane on its own: seen from the sensor at angle `φ` from
/// `p`, it hides only the directions `γ < π − φ` from `p` (rays at larger `γ` never come that
/// far round), so it joins the horizon when `φ ≤ π − h`: `p·s ≥ −cos h·|s|·|p|` with
/// `s = p + v`. The same arithmetic as the test in [`Ctx::march_lanes`].
fn joins_horizon(pa: Vec3A, v: Vec3A, cos_h: f32) -> bool {
    let plen = pa.length();
    let (sx, sy, sz) = (v.x + pa.x, v.y + pa.y, v.z + pa.z);
    let dq = (pa.x * sx + pa.y * sy) + pa.z * sz;
    let len = ((sx * sx + sy * sy) + sz * sz).sqrt();
    dq + cos_h * (len * plen) >= 0.0
}

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

/// `(x, y)` normalised; `None` when zero or not finite.
#[inline]
fn unit(x: f32, y: f32) -> Option<(f32, f32)> {
    let l = (x * x + y * y).sqrt();
    (l > 0.0 && l.is_finite()).then(|| (x / l, y / l))
}

/// `floor(x)` as an integer, saturating (no libm call).
#[inline]
fn fast_floor(x: f32) -> i32 {
    let i = x as i32;
    i - ((x < i as f32) as i32)
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
pub(crate) mod tests;
