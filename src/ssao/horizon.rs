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
//! `f` is positive on one arc `[lo, hi]` of `[0, π]` (for a surface facing the sensor, `lo = 0`
//! and `hi` is where the half-plane meets the tangent plane), with antiderivative
//! `G(γ) = −(a/4) cos 2γ + (b/2) γ − (b/4) sin 2γ`. The open value of a half-plane is
//! `T(ψ) = G(hi) − G(lo)`, and `(1/π) ∫ T dψ = 1`.
//!
//! A half-plane through the sensor direction is seen by the sensor as a half-line of the image
//! starting at `p`'s pixel (exactly for pinhole and orthographic sensors; on an equirectangular
//! map the image of the plane is a great circle and the straight line is its tangent, which is
//! a close approximation inside a `t_max` disk away from the poles). Marching that half-line
//! outward gives samples `s_k` with in-plane coordinates `X_k = (s_k − p)·u > 0` (outward) and
//! `Y_k = (s_k − p)·V` (towards the sensor), i.e. at angle `γ_k = atan2(X_k, Y_k)` from `V`. The
//! horizon `h` starts at `hi` (the tangent plane). A sample with `γ_k < h` is visible from `p`;
//! a depth map only says that the surface continues away from the sensor behind each sample
//! (Timonen 2013 §4: a "slab" from `s_k` along `−V`), so the sample blocks the directions
//! `[γ_k, h]`, which meet its slab at distance `r(γ) = X_k / sin γ`. Then `h = γ_k`. Hence
//!
//! ```text
//! S ≈ Σ_k ∫_{γ_k}^{h_{k−1}} ρ(X_k / sin γ) f(γ) dγ  +  (G(h_final) − G(lo)),
//! ```
//!
//! where each slab term is computed as `(G(h_{k−1}) − G(γ_k))` times the `f`-weighted mean of
//! `ρ(X_k / sin γ)` over the interval (3-point Gauss–Legendre; exact when `ρ` is constant on it).
//! When the surface faces the sensor (`n = V`: `a = 1`, `b = 0`, `hi = π/2`) and with the
//! elevation `θ = π/2 − γ` above the tangent plane, `S/T = Σ ρ_k (sin²θ_k − sin²h_{k−1}) +
//! (1 − sin²h_final)`: the normal-centred horizon integral. Taking the half-planes around the
//! *view* direction rather than around `n` is what keeps obliquely seen surfaces right: a screen
//! line is the image of a plane through the sensor, which contains `n` only when `n` does; the
//! projected-normal integrand `f` accounts for the tilt exactly.
//!
//! # Estimator
//!
//! `K = directions` half-planes per pixel at `ψ_j = ψ₀ + 2πj/K` with a per-pixel random
//! rotation `ψ₀`; the screen direction of `u(ψ_j)` is found by projecting `p + ε u` and `p`
//! (`ε = 10⁻³ ×` the point's depth or distance). Each half-line is marched up to the pixel radius
//! of a sphere of radius `t_max` at `p`'s depth along that direction (the `(r_x, r_y)` ellipse of
//! [`Projection::disk_radius`]), clipped to the map, starting where it leaves `p`'s own pixel, with
//! `min(steps, ⌊length⌋)` (at least 1) jittered, evenly stratified samples, so consecutive samples
//! are at least a pixel apart. Samples on `p`'s pixel, on empty pixels or outside the map are
//! skipped; a sample at 3-D distance `≥ t_max` or not above the tangent plane (`n·(s−p) ≤ 0`) is
//! ignored (it does not raise the horizon: beyond `t_max`, `ρ = 1` and farther occluders do not
//! change `A`). The pixel's value is `a = Σ_j S_j / Σ_j T_j` (the same limit as `(1/π)·2π·mean S`,
//! but exactly 1 when nothing rises above the tangent plane), clamped to `[0, 1]`.
//!
//! A sample pixel's point is not exactly on the half-plane (pixels are quantized): it is moved
//! within `p`'s tangent plane onto the half-plane, keeping its height `n·(s−p)` above that plane,
//! `v' = v + (v·m)(n(n·m) − m)/(1 − (n·m)²)` with `m = V × u` (the denominator is floored at
//! 0.01 for surfaces seen edge-on). A point of the tangent plane thus stays on it: a plane never
//! occludes itself whatever the viewing angle.
//!
//! Conventions shared with the paper estimator: a pixel none of whose samples landed on a valid
//! neighbouring pixel keeps `a = 1` and is flagged (`no_sample`), as is a pixel whose normal is
//! zero or not finite, or whose point has no image. Each pixel's random numbers come from
//! `Rng::new(seed, pixel)`, so maps do not depend on the thread count.
//!
//! Limits: the estimator converges to the obscurance of the surface the *map* describes, a
//! height field over the image in which everything behind a visible sample (away from the
//! sensor) is solid. Occluders the sensor does not see (under overhangs, behind foreground
//! objects, outside the map) are missing, and a foreground edge casts its slab over the
//! background behind it (limited to `t_max` by ignoring samples farther than `t_max`).

use super::rng::Rng;
use super::{rho, AoMap, SsaoParams};
use crate::gbuffer::GBuffer;
use crate::projection::Projection;
use rayon::prelude::*;
use std::f32::consts::{FRAC_PI_2, PI, TAU};

/// Computes the unblurred horizon-based obscurance of every valid pixel.
///
/// `prm.directions` half-planes and up to `prm.steps` samples per half-plane (both at least 1),
/// falloff `prm.tmax`, per-pixel patterns from `prm.seed`. A projection whose size differs from
/// the G-buffer's cannot be marched: every valid pixel is then flagged.
pub fn ssao(g: &GBuffer, proj: &Projection, prm: &SsaoParams) -> AoMap {
    let n = g.width * g.height;
    let mut ao = vec![1.0f32; n];
    let mut flag = vec![false; n];
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
    if proj.width != g.width || proj.height != g.height {
        for (i, f) in flag.iter_mut().enumerate() {
            *f = g.is_valid(i);
        }
        return AoMap {
            ao,
            no_sample: flag,
        };
    }
    let ctx = Ctx::new(g, proj, prm);
    ao.par_chunks_mut(g.width)
        .zip(flag.par_chunks_mut(g.width))
        .enumerate()
        .for_each(|(y, (arow, frow))| {
            for x in 0..g.width {
                let c = y * g.width + x;
                if !g.is_valid(c) {
                    continue;
                }
                match ctx.pixel(x, y, c) {
                    Some(a) => arow[x] = a,
                    None => frow[x] = true,
                }
            }
        });
    AoMap {
        ao,
        no_sample: flag,
    }
}

/// Everything a pixel evaluation needs, fixed for the whole map.
struct Ctx<'a> {
    g: &'a GBuffer,
    proj: &'a Projection,
    tmax: f32,
    /// `t_max²`, or 0 when `t_max ≤ 0` (every sample then ignored: `ρ ≡ 1`).
    tmax2: f32,
    directions: u32,
    steps: u32,
    seed: u64,
    width: f32,
    height: f32,
}

impl<'a> Ctx<'a> {
    fn new(g: &'a GBuffer, proj: &'a Projection, prm: &SsaoParams) -> Ctx<'a> {
        let tmax2 = if prm.tmax > 0.0 {
            prm.tmax * prm.tmax
        } else {
            0.0
        };
        Ctx {
            g,
            proj,
            tmax: prm.tmax,
            tmax2,
            directions: prm.directions.max(1),
            steps: prm.steps.max(1),
            seed: prm.seed,
            width: g.width as f32,
            height: g.height as f32,
        }
    }

    /// Obscurance of valid pixel `c = (x, y)`; `None` when it must be flagged.
    fn pixel(&self, x: usize, y: usize, c: usize) -> Option<f32> {
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
        let (ox, oy) = if proj.pixel_index(pc.x, pc.y) == Some(c) {
            (pc.x, pc.y)
        } else {
            (cx, cy)
        };
        let (rx, ry) = proj.disk_radius(self.tmax, g.depth[c], cx, cy);
        let mut eps = 1e-3 * g.depth[c].abs().max(p.length());
        if !(eps > 1e-12 && eps.is_finite()) {
            eps = 1e-3;
        }
        let (e1, e2) = view.any_orthonormal_pair();
        let a = nrm.dot(view);
        let mut rng = Rng::new(self.seed, c as u64);
        let psi0 = TAU * rng.next_f32();
        let dpsi = TAU / self.directions as f32;
        let (mut sum_s, mut sum_t, mut any) = (0.0f32, 0.0f32, false);
        for j in 0..self.directions {
            let jitter = rng.next_f32();
            let (s, co) = (psi0 + dpsi * j as f32).sin_cos();
            let u = e1 * co + e2 * s;
            let Some(slice) = Slice::new(a, nrm.dot(u)) else {
                continue;
            };
            let open = slice.open();
            sum_t += open;
            let Some((dx, dy)) = self.screen_dir(pc.x, pc.y, proj.project(p + u * eps)) else {
                sum_s += open;
                continue;
            };
            // Length of the march: the t_max ellipse along (dx, dy), clipped to the map.
            let er = 1.0 / ((dx / rx).powi(2) + (dy / ry).powi(2)).sqrt();
            let reach = if rx > 0.0 && ry > 0.0 { er } else { 0.0 };
            let exit_x = if proj.wrap_x {
                f32::INFINITY
            } else {
                exit(ox, dx, self.width)
            };
            let reach = reach
                .min(exit_x)
                .min(exit(oy, dy, self.height))
                .min(self.width + self.height);
            // Where the line leaves p's own pixel.
            let t0 = exit(ox - ox.floor(), dx, 1.0).min(exit(oy - oy.floor(), dy, 1.0));
            let span = reach - t0;
            if !(span > 0.0) {
                sum_s += open;
                continue;
            }
            let count = (span.floor() as u32).clamp(1, self.steps);
            let step = span / count as f32;
            let m = view.cross(u);
            let nm = nrm.dot(m);
            let corr = (nrm * nm - m) / (1.0 - nm * nm).max(0.01);
            let mut hz = Horizon::new(slice);
            for k in 0..count {
                let t = t0 + (k as f32 + jitter) * step;
                // The line leaves the map once (y is monotone; x wraps or is clipped).
                let Some(i) = proj.pixel_index(ox + dx * t, oy + dy * t) else {
                    break;
                };
                if i == c || !g.is_valid(i) {
                    continue;
                }
                any = true;
                let v = g.position[i] - p;
                if !(nrm.dot(v) > 0.0 && v.length_squared() < self.tmax2) {
                    continue;
                }
                let vp = v + corr * v.dot(m);
                hz.add(vp.dot(u), vp.dot(view), self.tmax);
            }
            sum_s += hz.value();
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

    /// Unit screen direction from `(px, py)` to the projection `q` (x difference wrapped on a
    /// full-circle map); `None` when there is no image or no direction.
    #[inline]
    fn screen_dir(
        &self,
        px: f32,
        py: f32,
        q: Option<crate::projection::Projected>,
    ) -> Option<(f32, f32)> {
        let q = q?;
        let mut dx = q.x - px;
        let dy = q.y - py;
        if self.proj.wrap_x {
            dx -= self.width * (dx / self.width).round();
        }
        let l = (dx * dx + dy * dy).sqrt();
        if l > 0.0 && l.is_finite() {
            Some((dx / l, dy / l))
        } else {
            None
        }
    }
}

/// Distance along direction component `d` from coordinate `o` to the boundary of `[0, size]`.
#[inline]
fn exit(o: f32, d: f32, size: f32) -> f32 {
    if d > 0.0 {
        (size - o) / d
    } else if d < 0.0 {
        o / -d
    } else {
        f32::INFINITY
    }
}

/// One half-plane `ω = cos γ V + sin γ u`, `γ ∈ [0, π]`: the arc `[lo, hi]` where
/// `f(γ) = (a cos γ + b sin γ) sin γ` is positive (`a = n·V`, `b = n·u`).
#[derive(Debug, Clone, Copy)]
struct Slice {
    a: f32,
    b: f32,
    lo: f32,
    hi: f32,
}

impl Slice {
    /// `None` when no direction of the half-plane is above the tangent plane.
    #[inline]
    fn new(a: f32, b: f32) -> Option<Slice> {
        // n·ω = R cos(γ − γn): positive on (γn − π/2, γn + π/2) modulo 2π.
        let mut gn = b.atan2(a);
        if gn < -FRAC_PI_2 {
            gn += TAU;
        }
        let lo = (gn - FRAC_PI_2).max(0.0);
        let hi = (gn + FRAC_PI_2).min(PI);
        (hi > lo && a.is_finite() && b.is_finite()).then_some(Slice { a, b, lo, hi })
    }

    /// Antiderivative of `f` (valid inside the arc).
    #[inline]
    fn g(&self, x: f32) -> f32 {
        let (s2, c2) = (2.0 * x).sin_cos();
        -0.25 * self.a * c2 + 0.5 * self.b * x - 0.25 * self.b * s2
    }

    /// `∫ f` over `[x0, x1] ∩ [lo, hi]`.
    #[inline]
    fn integral(&self, x0: f32, x1: f32) -> f32 {
        let x0 = x0.clamp(self.lo, self.hi);
        let x1 = x1.clamp(self.lo, self.hi);
        if x1 > x0 {
            (self.g(x1) - self.g(x0)).max(0.0)
        } else {
            0.0
        }
    }

    /// The open value `T = ∫ f` over the arc.
    #[inline]
    fn open(&self) -> f32 {
        self.integral(self.lo, self.hi)
    }

    /// `f(γ)` clamped at 0, with `sin γ` and `cos γ` given.
    #[inline]
    fn f(&self, s: f32, c: f32) -> f32 {
        (self.a * c + self.b * s).max(0.0) * s
    }

    /// `∫_{x0}^{x1} ρ(X / sin γ) f(γ) dγ`: the exact `∫ f` times the `f`-weighted mean of `ρ`
    /// at the 3 Gauss–Legendre nodes.
    fn slab(&self, x0: f32, x1: f32, big_x: f32, tmax: f32) -> f32 {
        let full = self.integral(x0, x1);
        if !(full > 0.0) || tmax == f32::INFINITY {
            return 0.0;
        }
        if !(big_x < tmax) {
            return full;
        }
        const NODE: f32 = 0.774_596_7; // sqrt(3/5)
        let mid = 0.5 * (x0 + x1);
        let half = 0.5 * (x1 - x0);
        let (mut num, mut den) = (0.0f32, 0.0f32);
        for (off, w) in [(-NODE, 5.0f32 / 9.0), (0.0, 8.0 / 9.0), (NODE, 5.0 / 9.0)] {
            let (s, c) = (mid + off * half).sin_cos();
            let wf = w * self.f(s, c);
            if s > 0.0 {
                num += wf * rho(big_x / s, tmax);
            } else {
                num += wf;
            }
            den += wf;
        }
        if den > 0.0 {
            full * (num / den)
        } else {
            full * rho(big_x / mid.sin().max(1e-6), tmax)
        }
    }
}

/// The running horizon of one half-plane march.
#[derive(Debug, Clone, Copy)]
struct Horizon {
    slice: Slice,
    /// Current horizon angle from `V` (directions in `[h, hi]` are blocked).
    h: f32,
    /// `cos h`.
    cos_h: f32,
    /// Σ of the slab terms so far.
    acc: f32,
}

impl Horizon {
    #[inline]
    fn new(slice: Slice) -> Horizon {
        Horizon {
            slice,
            h: slice.hi,
            cos_h: slice.hi.cos(),
            acc: 0.0,
        }
    }

    /// Adds the next sample outward, at in-plane coordinates `x` (outward, > 0 to count) and
    /// `y` (towards the sensor).
    #[inline]
    fn add(&mut self, x: f32, y: f32, tmax: f32) {
        if !(x > 0.0) {
            return;
        }
        let l = (x * x + y * y).sqrt();
        let c = y / l;
        if !(c > self.cos_h) {
            return;
        }
        let gk = x.atan2(y).clamp(self.slice.lo, self.h);
        self.acc += self.slice.slab(gk, self.h, x, tmax);
        self.h = gk;
        self.cos_h = c;
    }

    /// `S`: the slab terms plus the open directions above the horizon.
    #[inline]
    fn value(&self) -> f32 {
        self.acc + self.slice.integral(self.slice.lo, self.h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gbuffer::rasterize;
    use crate::projection::Model;
    use crate::ssao::Estimator;
    use glam::{Mat2, Mat3, Vec2, Vec3};

    const DEPTH0: f32 = 1000.0;

    fn params(directions: u32, steps: u32, tmax: f32) -> SsaoParams {
        SsaoParams {
            estimator: Estimator::Horizon,
            radius: tmax,
            tmax,
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
        let (w, h) = (256usize, 128usize);
        let model = Model::Equirect {
            rot: Mat3::IDENTITY,
            az_ref: 0.0,
            sx: w as f32 / TAU,
            ox: w as f32 * 0.5,
            sy: -(h as f32) / PI,
            oy: h as f32 * 0.5,
        };
        let proj = Projection::new(model, w, h, true);
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
        assert!(a < 0.1, "{a}");
        assert!(!m.no_sample[10 * 21 + 10]);
    }

    /// A smooth random-looking height field (pixel size 1) and its gradient.
    fn waves(x: f32, y: f32) -> (f32, Vec3) {
        const W: [(f32, f32, f32, f32); 3] = [
            // amplitude, kx, ky, phase
            (5.0, 0.150, 0.045, 0.3),
            (3.5, -0.093, 0.233, 1.7),
            (1.2, 0.341, 0.341, 4.0),
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
        let dirs = cosine_dirs(n, 40, 7);
        let dt = 0.1f32;
        let mut sum = 0.0f32;
        for w in &dirs {
            let below = |t: f32| {
                let q = p + *w * t;
                q.z < waves(q.x, q.y).0
            };
            let mut d = f32::INFINITY;
            let mut t = dt;
            while t < tmax + dt {
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
            sum += rho(d, tmax);
        }
        sum / dirs.len() as f32
    }

    fn mean_abs_error(m: &AoMap, refs: &[(usize, f32)]) -> f32 {
        refs.iter().map(|&(i, r)| (m.ao[i] - r).abs()).sum::<f32>() / refs.len() as f32
    }

    #[test]
    fn converges_to_the_ray_traced_height_field() {
        let (w, tmax) = (160usize, 12.0f32);
        let (g, proj) = heightfield(w, w, 1.0, waves);
        let refs: Vec<(usize, f32)> = (0..16)
            .flat_map(|yy| (0..16).map(move |xx| (16 + 8 * yy) * w + 16 + 8 * xx))
            .map(|i| (i, waves_reference(g.position[i], g.normal[i], tmax)))
            .collect();
        let spread = refs.iter().map(|r| r.1).fold(1.0f32, f32::min);
        assert!(
            spread < 0.8,
            "the field should have some occlusion: min A = {spread}"
        );
        let err = |k: u32, s: u32| mean_abs_error(&ssao(&g, &proj, &params(k, s, tmax)), &refs);
        let (e4, e32, e64) = (err(4, 4), err(32, 32), err(64, 64));
        eprintln!("mean |a − A|: (4,4) {e4:.4}  (32,32) {e32:.4}  (64,64) {e64:.4}");
        assert!(e64 < 0.02, "{e64}");
        assert!(e4 > e32, "{e4} vs {e32}");
    }

    #[test]
    fn oblique_pinhole_view_of_floor_and_wall_matches_the_reference() {
        // Camera at the origin pitched 35° down; floor z = −3, wall y = 4 facing the camera.
        let proj = camera(256, 256, 35f32.to_radians());
        let g = cast(&proj, |o, d| {
            let f = plane(o, d, Vec3::Z, -3.0).map(|t| (t, Vec3::Z));
            let wl = plane(o, d, Vec3::NEG_Y, -4.0).map(|t| (t, Vec3::NEG_Y));
            match (f, wl) {
                (Some(a), Some(b)) => Some(if a.0 < b.0 { a } else { b }),
                (a, b) => a.or(b),
            }
        });
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
        assert!(diff < 0.05, "{diff}");
    }

    /// `∫_{x0}^{x1} ρ(X/sin γ) f(γ) dγ` by a fine midpoint rule.
    fn numeric(sl: &Slice, x0: f32, x1: f32, big_x: f32, tmax: f32) -> f64 {
        let n = 20_000;
        let h = (x1 - x0) as f64 / n as f64;
        (0..n)
            .map(|i| {
                let gm = x0 as f64 + (i as f64 + 0.5) * h;
                let f = ((sl.a as f64) * gm.cos() + (sl.b as f64) * gm.sin()).max(0.0) * gm.sin();
                let r = if big_x.is_finite() {
                    rho(big_x / gm.sin() as f32, tmax)
                } else {
                    1.0
                };
                f * r as f64 * h
            })
            .sum()
    }

    #[test]
    fn hand_computed_slices() {
        // Surface facing the sensor: a = 1, b = 0, the tangent plane at γ = π/2.
        let sl = Slice::new(1.0, 0.0).expect("slice");
        assert!((sl.open() - 0.5).abs() < 1e-6);
        // t_max = ∞ (ρ = 0): the horizon set by (1,1) (45°), (2,1) hidden (63°), then (2,3)
        // (γ = atan(2/3)) raises it: S/T = sin²γ = 4/13, i.e. 1 − sin²(elevation).
        let mut hz = Horizon::new(sl);
        for (x, y) in [(1.0, 1.0), (2.0, 1.0), (2.0, 3.0)] {
            hz.add(x, y, f32::INFINITY);
        }
        assert!(
            (hz.value() / sl.open() - 4.0 / 13.0).abs() < 1e-6,
            "{}",
            hz.value()
        );
        // Finite t_max: slabs at X = 1 over [45°, 90°] and X = 2 over [atan(2/3), 45°].
        let tmax = 4.0;
        let mut hz = Horizon::new(sl);
        for (x, y) in [(1.0, 1.0), (2.0, 1.0), (2.0, 3.0)] {
            hz.add(x, y, tmax);
        }
        let (g1, g2) = (FRAC_PI_2 / 2.0, (2.0f32).atan2(3.0));
        let expect = numeric(&sl, g1, FRAC_PI_2, 1.0, tmax)
            + numeric(&sl, g2, g1, 2.0, tmax)
            + numeric(&sl, 0.0, g2, f32::INFINITY, tmax);
        assert!(
            (hz.value() as f64 - expect).abs() < 1e-3 * expect,
            "{} vs {expect}",
            hz.value()
        );
        // Tilted normal n = 0.8 V + 0.6 u: tangent plane at γ = atan2(0.6, 0.8) + π/2.
        let sl = Slice::new(0.8, 0.6).expect("slice");
        assert!((sl.hi - (0.6f32.atan2(0.8) + FRAC_PI_2)).abs() < 1e-6);
        assert!((sl.open() as f64 - numeric(&sl, 0.0, PI, f32::INFINITY, 1.0)).abs() < 1e-5);
        let mut hz = Horizon::new(sl);
        hz.add(1.0, -0.5, 3.0); // γ = 116.6°, just above the tangent plane (126.9°)
        let gk = 1.0f32.atan2(-0.5);
        let expect = numeric(&sl, gk, sl.hi, 1.0, 3.0) + numeric(&sl, 0.0, gk, f32::INFINITY, 3.0);
        assert!(
            (hz.value() as f64 - expect).abs() < 1e-4,
            "{} vs {expect}",
            hz.value()
        );
        // Behind the line of V, or below the current horizon: ignored.
        let before = hz.value();
        hz.add(-1.0, 1.0, 3.0);
        hz.add(1.0, -0.6, 3.0);
        assert_eq!(hz.value(), before);
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
    fn speed_one_megapixel() {
        let (g, proj) = heightfield(1024, 1024, 1.0, waves);
        let prm = params(8, 8, 12.0);
        let _ = ssao(&g, &proj, &prm);
        let t = std::time::Instant::now();
        let reps = 5;
        for _ in 0..reps {
            let _ = ssao(&g, &proj, &prm);
        }
        let s = t.elapsed().as_secs_f64() / reps as f64;
        eprintln!(
            "1024² px, 8×8: {:.3} s/map, {:.2} Mpx/s on {} threads",
            s,
            1.048576 / s,
            rayon::current_num_threads()
        );
    }
}
