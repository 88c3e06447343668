//! Multi-resolution evaluation of the horizon march (`--sampling adaptive`), after the
//! curvature and depth-discontinuity metrics of multiresolution screen-space AO: pixels on flat,
//! continuous surfaces are evaluated once per 2×2 or 4×4 block and filled in by bilinear
//! interpolation inside the block; creases, edges, concave regions and the borders of the data
//! keep one evaluation per pixel.
//!
//! # Why a block may be coarse
//!
//! Obscurance on a smooth open surface changes on the scale of `t_max` (the occluders that
//! matter lie within `t_max`), so a block whose 3-D extent is a small fraction `α` of `t_max`
//! is interpolated with an error of order `α²/8` of the map's curvature over `t_max`. What
//! breaks interpolation is a kink or a jump *inside* the block: a crease (the normals turn), a
//! depth discontinuity (a neighbour leaves the tangent plane) or missing data. So a block of
//! `B × B` pixels, with its closed `(B+1) × (B+1)` neighbourhood of corners, is coarse when
//!
//! - every pixel of the neighbourhood is valid and *continuous*: each of its four neighbours
//!   lies within [`MAX_DISCONTINUITY`] (sine of the angle) of its tangent plane, or less than
//!   [`MIN_STEP`] × `t_max` off it (a step that low barely shades; range noise is of that
//!   order on dense scans, and would otherwise break every block);
//! - its extent (the longer corner diagonal, metres) is at most [`MAX_EXTENT`] × `t_max`;
//! - the normals turn by little across it: curvature × extent (the angle the normal turns over
//!   the block) between −[`MAX_TURN_CONCAVE`] and [`MAX_TURN_CONVEX`], concave regions (where
//!   occlusion gathers) being held to the tighter bound.
//!
//! Both bounds scale with the pixel footprint against `t_max`, not with a dataset's units. The
//! curvature is measured between the block's corners (a baseline of `B` pixels) rather than
//! between adjacent pixels, so that the noise of estimated normals is not divided by a pixel's
//! spacing.
//!
//! The corners are evaluated by the full march with their own per-pixel random numbers, so the
//! map is deterministic for a seed; a block one of whose corners found no sample is evaluated
//! at full rate. An open plane reads exactly 1: every corner does, and the interpolation is
//! written as two linear blends, exact on equal values.
//!
//! # Plain ambient occlusion (`t_max = ∞`)
//!
//! Without a finite `t_max` the march has no scale to compare a block with, and runs every
//! pixel. The far-field sweeps instead report each pixel's *reach*, the distance to the nearest
//! sample that bounds a blocked arc of one of its half-planes: plain obscurance changes on that
//! scale as the pixel moves. A block of up to 16×16 is planned as above with no bound on its
//! extent (steps under [`FAR_STEP`] pixel radii are not discontinuities), its corners are
//! evaluated, and it is split into quarters when its extent exceeds [`MAX_EXTENT`] × the
//! smallest reach of its corners, the same ratio as against `t_max`, down to 2×2 blocks, which
//! then run at full rate. An open plane has infinite reach and reads 1.

use super::{farfield, horizon, AoMap, SsaoParams};
use crate::gbuffer::GBuffer;
use crate::projection::Projection;
use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Largest block extent, as a fraction of `t_max`.
pub const MAX_EXTENT: f32 = 0.25;
/// At `t_max = ∞`, offsets from the tangent plane below this many pixel radii are not
/// discontinuities (range noise of the order of the spacing); a real step is caught by the
/// reach of the block's corners instead.
pub const FAR_STEP: f32 = 2.0;
/// Largest sine of the angle between a pixel's tangent plane and the segment to a neighbour.
pub const MAX_DISCONTINUITY: f32 = 0.15;
/// Offsets from the tangent plane below this fraction of `t_max` are not discontinuities: a
/// step that low shades a region at most about as deep, and range noise is of that order.
pub const MIN_STEP: f32 = 0.02;
/// Largest angle (radians) the normal may turn over a concave block.
pub const MAX_TURN_CONCAVE: f32 = 0.1;
/// Largest angle (radians) the normal may turn over a convex block.
pub const MAX_TURN_CONVEX: f32 = 0.3;

/// Block sizes of the levels: level `l` evaluates one pixel per `SIZES[l]²`.
pub const SIZES: [usize; 5] = [1, 2, 4, 8, 16];

/// The coarsest level of the march at a finite `t_max` (4×4).
const MARCH_TOP: usize = 2;
/// The coarsest level of the far field (16×16): plain obscurance on open ground changes on the
/// scale of the distance to its occluders, metres on a site, so the reach test of a block's
/// corners, not a fixed size, bounds its blocks.
const FAR_TOP: usize = 4;

/// Valid pixels evaluated at each level: full rate, one per 2×2, 4×4, 8×8 and 16×16 (the last
/// two at `t_max = ∞` only).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Levels {
    /// Pixels of each level (`SIZES`).
    pub pixels: [u64; 5],
}

impl Levels {
    /// Every one of `n` valid pixels at full rate.
    pub fn full(n: u64) -> Levels {
        Levels {
            pixels: [n, 0, 0, 0, 0],
        }
    }

    /// Adds `o`'s counts.
    pub fn add(&mut self, o: &Levels) {
        for (a, b) in self.pixels.iter_mut().zip(o.pixels) {
            *a += b;
        }
    }

    /// Shares of the pixels at each level (zeros when there are none).
    pub fn shares(&self) -> [f64; 5] {
        let n: u64 = self.pixels.iter().sum();
        let n = n.max(1) as f64;
        self.pixels.map(|k| k as f64 / n)
    }

    /// "full 41.0 %, 2×2 12.5 %, 4×4 46.5 %", and the coarser levels where any pixel ran at
    /// them.
    pub fn to_text(&self) -> String {
        let s = self.shares();
        let mut text = format!(
            "full {:.1} %, 2×2 {:.1} %, 4×4 {:.1} %",
            100.0 * s[0],
            100.0 * s[1],
            100.0 * s[2]
        );
        for l in 3..SIZES.len() {
            if self.pixels[l] > 0 {
                let b = SIZES[l];
                text += &format!(", {b}×{b} {:.1} %", 100.0 * s[l]);
            }
        }
        text
    }
}

/// Unit normal of pixel `c`, `None` when empty, zero or not finite.
#[inline]
fn normal(g: &GBuffer, c: usize) -> Option<Vec3> {
    if !g.is_valid(c) {
        return None;
    }
    let n = g.normal[c];
    let l = n.length();
    (l > 1e-6 && l.is_finite() && g.position[c].is_finite()).then(|| n / l)
}

/// Normal curvature along the segment from pixel `a` to pixel `b`:
/// `(n_b − n_a)·(p_b − p_a) / ‖p_b − p_a‖²` (`1/R` on a sphere of radius `R` seen from
/// outside, `−1/R` from inside, 0 on a plane); `None` when either is unusable.
#[inline]
fn curvature_between(g: &GBuffer, a: usize, b: usize) -> Option<f32> {
    let (na, nb) = (normal(g, a)?, normal(g, b)?);
    let d = g.position[b] - g.position[a];
    let l2 = d.length_squared();
    let k = (nb - na).dot(d) / l2;
    (l2 > 0.0 && k.is_finite()).then_some(k)
}

/// Per-pixel curvature (1/m): along x and along y by central differences of the neighbours'
/// normals and positions (one-sided where a neighbour is missing), the one of larger
/// magnitude, signed (positive convex, negative concave as seen from the sensor). NaN on
/// empty pixels and where no neighbour is usable.
pub fn curvature(g: &GBuffer) -> Vec<f32> {
    let (w, h) = (g.width, g.height);
    per_pixel(g, |x, y| {
        let c = y * w + x;
        if normal(g, c).is_none() {
            return f32::NAN;
        }
        let axis = |lo: Option<usize>, hi: Option<usize>| -> Option<f32> {
            let lo = lo.filter(|&i| normal(g, i).is_some());
            let hi = hi.filter(|&i| normal(g, i).is_some());
            match (lo, hi) {
                (Some(a), Some(b)) => curvature_between(g, a, b),
                (Some(a), None) => curvature_between(g, a, c),
                (None, Some(b)) => curvature_between(g, c, b),
                (None, None) => None,
            }
        };
        let kx = axis((x > 0).then(|| c - 1), (x + 1 < w).then_some(c + 1));
        let ky = axis((y > 0).then(|| c - w), (y + 1 < h).then_some(c + w));
        match (kx, ky) {
            (Some(a), Some(b)) if b.abs() > a.abs() => b,
            (Some(a), _) => a,
            (None, Some(b)) => b,
            (None, None) => f32::NAN,
        }
    })
}

/// `f(x, y)` for every pixel of `g`'s map, rows in parallel.
fn per_pixel(g: &GBuffer, f: impl Fn(usize, usize) -> f32 + Sync) -> Vec<f32> {
    let w = g.width;
    let mut out = vec![f32::NAN; w * g.height];
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                *o = f(x, y);
            }
        });
    out
}

/// Per-pixel depth discontinuity: the largest sine of the angle between the pixel's tangent
/// plane and the segment to one of its four neighbours (0 on a plane at any viewing angle, 1
/// across a jump seen head-on); 1 where a neighbour is empty or outside the map, NaN on empty
/// pixels.
pub fn discontinuity(g: &GBuffer) -> Vec<f32> {
    per_pixel(g, |x, y| discontinuity_at(g, x, y, 0.0))
}

/// [`discontinuity`] at `(x, y)`, neighbours less than `slack` metres off the tangent plane
/// counting as on it.
fn discontinuity_at(g: &GBuffer, x: usize, y: usize, slack: f32) -> f32 {
    let (w, h) = (g.width, g.height);
    let c = y * w + x;
    let Some(n) = normal(g, c) else {
        return f32::NAN;
    };
    let p = g.position[c];
    let mut worst = 0.0f32;
    for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
        let (nx, ny) = (x as i64 + dx, y as i64 + dy);
        if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
            return 1.0;
        }
        let b = ny as usize * w + nx as usize;
        if normal(g, b).is_none() {
            return 1.0;
        }
        let d = g.position[b] - p;
        let l = d.length();
        if !(l > 0.0) {
            continue;
        }
        let off = n.dot(d).abs();
        if off <= slack {
            continue;
        }
        let s = off / l;
        if !s.is_finite() {
            return 1.0;
        }
        worst = worst.max(s);
    }
    worst
}

/// The level of every pixel (index into [`SIZES`]; 0 on empty pixels), for falloff
/// distance `tmax`. A coarse pixel belongs to the block of its level that holds it.
pub fn plan(g: &GBuffer, tmax: f32) -> Vec<u8> {
    if !(tmax > 0.0 && tmax.is_finite()) {
        return vec![0u8; g.width * g.height];
    }
    plan_by(g, |_| MIN_STEP * tmax, MAX_EXTENT * tmax, MARCH_TOP)
}

/// The levels of the far field (`t_max = ∞`) before its corners are evaluated: no block
/// extent is ruled out (the corners' reach decides it after), and steps below [`FAR_STEP`]
/// pixel radii are not discontinuities.
fn plan_far(g: &GBuffer) -> Vec<u8> {
    plan_by(g, |c| FAR_STEP * g.radius[c], f32::INFINITY, FAR_TOP)
}

/// The levels of the pixels, at most `top`: neighbours within `slack(pixel)` metres of a
/// pixel's tangent plane are continuous with it, and blocks are at most `max_extent` metres
/// across.
fn plan_by(
    g: &GBuffer,
    slack: impl Fn(usize) -> f32 + Sync,
    max_extent: f32,
    top: usize,
) -> Vec<u8> {
    let (w, h) = (g.width, g.height);
    let mut level = vec![0u8; w * h];
    if w == 0 {
        return level;
    }
    let mut cont = vec![false; w * h];
    cont.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, k) in row.iter_mut().enumerate() {
            let c = y * w + x;
            *k = g.is_valid(c) && discontinuity_at(g, x, y, slack(c)) <= MAX_DISCONTINUITY;
        }
    });
    let b = SIZES[top];
    level
        .par_chunks_mut(w * b)
        .enumerate()
        .for_each(|(by, band)| {
            let place = Place {
                g,
                cont: &cont,
                y0: by * b,
                max_extent,
            };
            for x0 in (0..w).step_by(b) {
                place.block(band, x0, 0, top);
            }
        });
    level
}

/// What [`Place::block`] reads while it sets the levels of one band of rows from `y0`.
struct Place<'a> {
    g: &'a GBuffer,
    cont: &'a [bool],
    y0: usize,
    max_extent: f32,
}

impl Place<'_> {
    /// Gives the block of level `l` at column `x0`, band row `r0` that level when it may be
    /// coarse, else tries its four quarters one level finer (level 0 stays).
    fn block(&self, band: &mut [u8], x0: usize, r0: usize, l: usize) {
        if l == 0 {
            return;
        }
        let (w, b) = (self.g.width, SIZES[l]);
        if coarse(self.g, self.cont, x0, self.y0 + r0, b, self.max_extent) {
            fill(band, w, x0, r0, b, l as u8);
            return;
        }
        let half = b / 2;
        for (sx, sy) in [(0, 0), (half, 0), (0, half), (half, half)] {
            self.block(band, x0 + sx, r0 + sy, l - 1);
        }
    }
}

/// Sets the `b × b` block at column `x0`, row `r0` of `band` to `l`.
fn fill(band: &mut [u8], w: usize, x0: usize, r0: usize, b: usize, l: u8) {
    for r in r0..r0 + b {
        band[r * w + x0..r * w + x0 + b].fill(l);
    }
}

/// The pixels of the corners of the `b × b` block at `(x0, y0)`.
fn corners(w: usize, x0: usize, y0: usize, b: usize) -> [usize; 4] {
    [
        y0 * w + x0,
        y0 * w + x0 + b,
        (y0 + b) * w + x0,
        (y0 + b) * w + x0 + b,
    ]
}

/// A block's extent: the longer diagonal between its corners `c`, metres.
fn extent(g: &GBuffer, c: [usize; 4]) -> f32 {
    let p = |i: usize| g.position[c[i]];
    (p(3) - p(0)).length().max((p(2) - p(1)).length())
}

/// Whether the `b × b` block at `(x0, y0)` may be evaluated at its corners only (see the
/// module notes), at most `max_extent` metres across.
fn coarse(g: &GBuffer, cont: &[bool], x0: usize, y0: usize, b: usize, max_extent: f32) -> bool {
    let w = g.width;
    if x0 + b >= w || y0 + b >= g.height {
        return false;
    }
    for y in y0..=y0 + b {
        if !cont[y * w + x0..=y * w + x0 + b].iter().all(|&k| k) {
            return false;
        }
    }
    let c = corners(w, x0, y0, b);
    let extent = extent(g, c);
    if !(extent <= max_extent) {
        return false;
    }
    for (i, j) in [(0, 1), (2, 3), (0, 2), (1, 3), (0, 3), (1, 2)] {
        let Some(k) = curvature_between(g, c[i], c[j]) else {
            return false;
        };
        let turn = k * extent;
        if !(-MAX_TURN_CONCAVE..=MAX_TURN_CONVEX).contains(&turn) {
            return false;
        }
    }
    true
}

/// The unblurred horizon march evaluated at the levels [`plan`] chooses, and the pixels
/// evaluated at each level.
pub fn ssao(g: &GBuffer, proj: &Projection, prm: &SsaoParams) -> AoMap {
    if super::unmarchable(g, proj).is_some() {
        return full(g, horizon::ssao(g, proj, prm));
    }
    refine(g, plan(g, prm.tmax), SIZES[MARCH_TOP], |only| {
        (horizon::ssao_masked(g, proj, prm, Some(only)), None)
    })
}

/// The unblurred far-field sweeps (`t_max = ∞`) evaluated at the levels the map and the
/// corners' reach allow, and the pixels evaluated at each level.
pub fn far_field(g: &GBuffer, proj: &Projection, prm: &SsaoParams) -> AoMap {
    if super::unmarchable(g, proj).is_some() {
        return full(g, farfield::ssao(g, proj, prm));
    }
    let sweeps = farfield::Sweeps::new(g, proj, prm);
    // Straight-line sweeps pass over every line that holds a pixel to evaluate, whatever their
    // number: the corners of every block down to 4×4 are evaluated in one pass, not level by
    // level, and a 4×4 block that fails goes to full rate (one more pass, not two).
    let lattice = if sweeps.per_pixel() { 2 } else { 4 };
    refine(g, plan_far(g), lattice, |only| {
        let (map, reach) = sweeps.eval(Some(only));
        (map, Some(reach))
    })
}

/// `map` with every valid pixel of `g` counted at full rate.
fn full(g: &GBuffer, mut map: AoMap) -> AoMap {
    let valid = (0..g.width * g.height).filter(|&c| g.is_valid(c)).count() as u64;
    map.levels = Some(Levels::full(valid));
    map
}

/// Evaluates the pixels of `level` with `eval` (the pixels to evaluate → their map, and
/// optionally each one's reach), runs again at full rate every block a corner of which found
/// no sample, splits into quarters every block whose corners reach an occluder nearer than its
/// extent over [`MAX_EXTENT`] (evaluating the quarters' new corners, until blocks of 2×2 go
/// to full rate), and fills in the rest. Blocks split down to `lattice` pixels (a block of that
/// size that fails runs at full rate); the first evaluation takes the lattice of every block
/// when `lattice` is above 2, so that the splits need no further evaluation, and only each
/// block's corners when it is 2, so that a split evaluates only the corners it adds.
fn refine(
    g: &GBuffer,
    mut level: Vec<u8>,
    lattice: usize,
    eval: impl Fn(&[bool]) -> (AoMap, Option<Vec<f32>>),
) -> AoMap {
    let (w, h) = (g.width, g.height);
    // Pixels to evaluate: every full-rate pixel and every coarse block's corners.
    let mut need: Vec<bool> = level
        .iter()
        .enumerate()
        .map(|(c, &l)| l == 0 && g.is_valid(c))
        .collect();
    let mut blocks = blocks(&level, w, h);
    for &(x0, y0, b) in &blocks {
        let step = if lattice > 2 { lattice.min(b) } else { b };
        for y in (y0..=y0 + b).step_by(step) {
            for x in (x0..=x0 + b).step_by(step) {
                need[y * w + x] = true;
            }
        }
    }
    let (mut map, mut reach) = eval(&need);
    let mut done = need.clone();
    loop {
        need.fill(false);
        // Blocks whose corners are all evaluated are settled now (quarters whose corners are
        // too, in turn); the others wait for the next evaluation.
        let mut next = Vec::new();
        while let Some((x0, y0, b)) = blocks.pop() {
            let c = corners(w, x0, y0, b);
            let near = reach.as_ref().is_some_and(|r| {
                let nearest = c.iter().map(|&i| r[i]).fold(f32::INFINITY, f32::min);
                !(extent(g, c) <= MAX_EXTENT * nearest)
            });
            let empty = c.iter().any(|&i| map.no_sample[i]);
            if !(near || empty) {
                continue;
            }
            let half = b / 2;
            let quarter = near && !empty && half >= lattice.max(2);
            for y in y0..y0 + b {
                let row = &mut level[y * w + x0..y * w + x0 + b];
                row.fill(if quarter {
                    half.trailing_zeros() as u8
                } else {
                    0
                });
                if !quarter {
                    for (x, n) in (x0..x0 + b).zip(&mut need[y * w + x0..]) {
                        *n = !done[y * w + x];
                    }
                }
            }
            if quarter {
                for (sx, sy) in [(0, 0), (half, 0), (0, half), (half, half)] {
                    let q = (x0 + sx, y0 + sy, half);
                    let qc = corners(w, q.0, q.1, half);
                    if qc.iter().all(|&i| done[i]) {
                        blocks.push(q);
                    } else {
                        next.push(q);
                        for i in qc {
                            need[i] |= !done[i];
                        }
                    }
                }
            }
        }
        if need.contains(&true) {
            let (again, r) = eval(&need);
            for c in (0..w * h).filter(|&c| need[c]) {
                map.ao[c] = again.ao[c];
                map.no_sample[c] = again.no_sample[c];
                if let (Some(to), Some(from)) = (reach.as_mut(), r.as_ref()) {
                    to[c] = from[c];
                }
                done[c] = true;
            }
        }
        if next.is_empty() {
            break;
        }
        blocks = next;
    }
    interpolate(&mut map.ao, &level, w);
    let mut counts = Levels::default();
    for (c, &l) in level.iter().enumerate() {
        if g.is_valid(c) {
            counts.pixels[l as usize] += 1;
        }
    }
    map.levels = Some(counts);
    map
}

/// The coarse blocks of `level`: `(x0, y0, size)`.
fn blocks(level: &[u8], w: usize, h: usize) -> Vec<(usize, usize, usize)> {
    let mut out = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let l = level[y * w + x] as usize;
            let b = SIZES[l];
            if l > 0 && x % b == 0 && y % b == 0 {
                out.push((x, y, b));
            }
        }
    }
    out
}

/// Fills every coarse pixel from its block's four corners, bilinearly at the pixel centres.
fn interpolate(ao: &mut [f32], level: &[u8], w: usize) {
    let nodes = ao.to_vec();
    ao.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            for (x, a) in row.iter_mut().enumerate() {
                let b = SIZES[level[y * w + x] as usize];
                if b == 1 || (x % b == 0 && y % b == 0) {
                    continue;
                }
                let (x0, y0) = (x - x % b, y - y % b);
                let at = |dx: usize, dy: usize| nodes[(y0 + dy) * w + x0 + dx];
                let (u, v) = ((x - x0) as f32 / b as f32, (y - y0) as f32 / b as f32);
                let top = at(0, 0) + (at(b, 0) - at(0, 0)) * u;
                let bottom = at(0, b) + (at(b, b) - at(0, b)) * u;
                *a = top + (bottom - top) * v;
            }
        });
}

#[cfg(test)]
mod tests;
