//! The line families of the far-field sweeps: where their samples fall, which line and sample a
//! pixel snaps to, the block hulls, and the horizon of a half-plane over them.

use super::{Half, BLOCK, NEAR};
use crate::gbuffer::GBuffer;
use crate::projection::{Model, Projection};
use glam::{Vec2, Vec3, Vec3A, Vec4};
use rayon::prelude::*;
use std::f32::consts::{PI, TAU};

/// Turn below which a hull vertex counts as collinear with its neighbours (radians).
const COLLINEAR: f32 = 1e-4;

/// A sample outside the map or on an empty pixel.
const EMPTY_SAMPLE: u32 = u32::MAX;

/// The golden angle, spreading the circle families' axes evenly in azimuth.
const GOLDEN: f32 = 2.399_963_2;

/// How a family's samples are laid on the map.
#[derive(Debug, Clone, Copy)]
enum Shape {
    /// Straight screen lines along `t`, line `l` at offset `n0 + l` along `nrm`, sample `i` at
    /// `t0 + i` along `t`.
    Screen {
        t: Vec2,
        nrm: Vec2,
        n0: f32,
        t0: f32,
    },
    /// Great circles through the axis `a`: circle `l` holds the directions
    /// `cos φ·a + sin φ·w(β)`, `w(β) = cos β b1 + sin β b2`, `β = l·dbeta`, sample `i` at
    /// `φ = i·step`.
    Circle {
        a: Vec3A,
        b1: Vec3A,
        b2: Vec3A,
        dbeta: f32,
        step: f32,
    },
}

/// The lines of one family: where their samples fall and which line and sample a pixel snaps
/// to. Every valid pixel lies on (next to) one of them.
pub(super) struct Lines {
    shape: Shape,
    /// Number of lines.
    pub(super) count: usize,
    /// Samples per line.
    pub(super) len: usize,
    /// Per line: the normal `m` of its plane, oriented so that the samples advance by rotating
    /// about it (screen lines of an orthographic map: advance along `V × m`).
    normals: Vec<Vec3A>,
}

/// One family of lines with its block hulls, for the walk of [`Family::horizon`].
pub(super) struct Family {
    pub(super) lines: Lines,
    /// `lines × len` sample pixels.
    samples: Vec<u32>,
    /// Level `k` cuts every line into blocks of `BLOCK << k` samples: per level, line and
    /// block, the range of its hull vertices in `verts`.
    levels: Vec<Level>,
    verts: Vec<u32>,
}

/// One level of the block hierarchy.
struct Level {
    /// Blocks per line.
    nblocks: usize,
    /// `lines × nblocks` ranges in [`Family::verts`].
    blocks: Vec<(u32, u32)>,
    /// Per block: a sphere holding its hull vertices' points (centre, radius).
    spheres: Vec<Vec4>,
}

impl Lines {
    /// The lines of family `f` of `k` on a map seen by `proj`.
    pub(super) fn new(proj: &Projection, f: usize, k: usize) -> Lines {
        let (shape, count, len) = layout(proj, f, k);
        let normals = (0..count)
            .map(|l| line_normal(&shape, proj, l, len))
            .collect();
        Lines {
            shape,
            count,
            len,
            normals,
        }
    }

    /// The screen direction along which straight lines advance (`None` on circles).
    pub(super) fn direction(&self) -> Option<Vec2> {
        match self.shape {
            Shape::Screen { t, .. } => Some(t),
            Shape::Circle { .. } => None,
        }
    }

    /// The map pixel of sample `i` of line `l`, if it falls on the map.
    #[inline]
    pub(super) fn pixel(&self, proj: &Projection, l: usize, i: usize) -> Option<usize> {
        sample_pixel(&self.shape, proj, l, i)
    }

    /// The line and sample a pixel snaps to, from its centre `(x, y)` and the unit direction
    /// `dir` from the sensor to its point (used on circles).
    pub(super) fn locate(&self, centre: (f32, f32), dir: Vec3A) -> Option<(usize, usize)> {
        match self.shape {
            Shape::Screen { t, nrm, n0, t0 } => {
                let c = Vec2::new(centre.0, centre.1);
                let l = (c.dot(nrm) - n0).round();
                let i = (c.dot(t) - t0).round();
                let ok = l >= 0.0 && (l as usize) < self.count && i >= 0.0;
                (ok && (i as usize) < self.len).then_some((l as usize, i as usize))
            }
            Shape::Circle {
                a,
                b1,
                b2,
                dbeta,
                step,
            } => {
                let z = dir.dot(a);
                let w = dir - a * z;
                let wl = w.length();
                if !(wl > 1e-6) {
                    return None;
                }
                let mut beta = w.dot(b2).atan2(w.dot(b1));
                let mut phi = wl.atan2(z);
                if beta < 0.0 {
                    beta += PI;
                    phi = TAU - phi;
                }
                let mut l = (beta / dbeta).round() as usize;
                if l >= self.count {
                    // β = π is the circle β = 0 run backwards.
                    l = 0;
                    phi = TAU - phi;
                }
                let i = ((phi / step).round() as usize) % self.len;
                Some((l, i))
            }
        }
    }

    /// The normal of line `l`'s plane.
    pub(super) fn normal(&self, l: usize) -> Vec3A {
        self.normals[l]
    }

    /// On circles, `(sin φ, cos φ)` of every sample (the same on every circle of a family).
    fn turns(&self) -> Option<Vec<(f32, f32)>> {
        let Shape::Circle { step, .. } = self.shape else {
            return None;
        };
        Some((0..self.len).map(|i| (step * i as f32).sin_cos()).collect())
    }

    /// The map pixel of every sample of line `l` into `row` ([`EMPTY_SAMPLE`] off the map),
    /// with the samples' turns from [`Lines::turns`] on circles: the same pixels as
    /// [`Lines::pixel`], projected four at a time.
    fn fill_row(&self, proj: &Projection, l: usize, turns: Option<&[(f32, f32)]>, row: &mut [u32]) {
        let (
            Shape::Circle {
                a, b1, b2, dbeta, ..
            },
            Some(turns),
        ) = (self.shape, turns)
        else {
            for (i, s) in row.iter_mut().enumerate() {
                *s = self.pixel(proj, l, i).map_or(EMPTY_SAMPLE, |c| c as u32);
            }
            return;
        };
        let (sb, cb) = (dbeta * l as f32).sin_cos();
        let w = b1 * cb + b2 * sb;
        let pixel = |q: Option<crate::projection::Projected>| {
            q.and_then(|q| proj.pixel_index(q.x, q.y))
                .map_or(EMPTY_SAMPLE, |c| c as u32)
        };
        for (out, t) in row.chunks_mut(4).zip(turns.chunks(4)) {
            let mut d = [Vec3::ZERO; 4];
            for (d, &(sp, cp)) in d.iter_mut().zip(t) {
                *d = Vec3::from(a * cp + w * sp);
            }
            for (o, q) in out.iter_mut().zip(proj.project4(d)) {
                *o = pixel(q);
            }
        }
    }
}

impl Family {
    /// Family `f` of `k` for the map `g` seen by `proj`.
    pub(super) fn new(g: &GBuffer, proj: &Projection, f: usize, k: usize) -> Family {
        let lines = Lines::new(proj, f, k);
        let len = lines.len;
        let mut depth = 1;
        while (BLOCK as usize) << (depth - 1) < len {
            depth += 1;
        }
        let turns = lines.turns();
        let rows: Vec<LineHulls> = (0..lines.count)
            .into_par_iter()
            .map_init(HullScratch::default, |scratch, l| {
                let mut row = vec![EMPTY_SAMPLE; len];
                lines.fill_row(proj, l, turns.as_deref(), &mut row);
                for s in row.iter_mut() {
                    if *s != EMPTY_SAMPLE && !g.is_valid(*s as usize) {
                        *s = EMPTY_SAMPLE;
                    }
                }
                line_hulls(row, lines.normal(l), depth, &g.position, scratch)
            })
            .collect();
        let mut fam = Family {
            samples: Vec::with_capacity(lines.count * len),
            levels: (0..depth)
                .map(|k| {
                    let nblocks = len.div_ceil((BLOCK as usize) << k);
                    Level {
                        nblocks,
                        blocks: Vec::with_capacity(lines.count * nblocks),
                        spheres: Vec::with_capacity(lines.count * nblocks),
                    }
                })
                .collect(),
            verts: Vec::new(),
            lines,
        };
        for line in rows {
            fam.samples.extend_from_slice(&line.row);
            let base = fam.verts.len() as u32;
            fam.verts.extend_from_slice(&line.verts);
            let mut at = 0;
            for level in fam.levels.iter_mut() {
                let n = level.nblocks;
                let ranges = &line.blocks[at..at + n];
                level
                    .blocks
                    .extend(ranges.iter().map(|&(v0, v1)| (base + v0, base + v1)));
                level.spheres.extend_from_slice(&line.spheres[at..at + n]);
                at += n;
            }
        }
        fam
    }

    /// The blocked part `∫ f` of the half-plane `half` of pixel `c` at `pa`, snapped to sample
    /// `i` of line `l`, by the samples before it (`dir = −1`) or after it (`dir = 1`), each
    /// solid behind as the sensor sees it; whether any valid sample was read; and the distance
    /// to the nearest sample that bounds a blocked arc (see [`super::Sweeps::eval`]).
    ///
    /// A sample at `γ` from `V` and `φ` round from the receiver (seen from the sensor) blocks
    /// the arc `[γ, π − φ)`: the directions that pass below it and cross the ray from the
    /// sensor beyond it. In order of `φ` the arcs' upper ends fall, so the union is a stack
    /// of disjoint arcs of which only the lowest grows: a sample whose arc reaches it lowers
    /// it to `γ`, one that does not starts a new lowest arc. On straight lines `φ` stays small
    /// and every arc reaches `hi`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn horizon(
        &self,
        l: usize,
        i: usize,
        dir: i64,
        c: usize,
        pa: Vec3A,
        half: &Half,
        pts: &[Vec3A],
    ) -> (f32, bool, f32) {
        let n = self.lines.len as i64;
        let i = i as i64;
        let circle = matches!(self.lines.shape, Shape::Circle { .. });
        // On a circle, samples at π or more round are on the other side of V.
        let reach = match (circle, dir < 0) {
            (true, _) => (n - 1) / 2,
            (false, true) => i,
            (false, false) => n - 1 - i,
        };
        let row = &self.samples[l * self.lines.len..(l + 1) * self.lines.len];
        // Seen from the sensor at angle φ round a circle from the receiver, a sample hides
        // only directions γ < π − φ (rays at larger γ never come that far round): it raises
        // the horizon h only while φ ≤ π − h, i.e. cos φ ≥ −cos h.
        let step = match self.lines.shape {
            Shape::Circle { step, .. } => step,
            Shape::Screen { .. } => 0.0,
        };
        let reaches = |d: i64, cos_h: f32| !circle || (d as f32 * step).cos() >= -cos_h;
        let (mut cur, mut upper, mut closed, mut seen) = (half.cos_hi, half.hi, 0.0f32, false);
        // The sample bounding the current arc, and the nearest distance of closed arcs'.
        let (mut by, mut near) = (EMPTY_SAMPLE, f32::INFINITY);
        let dist = |s: u32| (pts[s as usize] - pa).length();
        let gamma = |s: u32| -> Option<f32> {
            if s == EMPTY_SAMPLE || s as usize == c {
                return None;
            }
            Some(
                half.cos_gamma(pts[s as usize] - pa)
                    .unwrap_or(f32::NEG_INFINITY),
            )
        };
        let mut d = 1i64;
        while d <= reach {
            // |i ± d| < 2n (d ≤ reach < n): one wrap instead of a division per sample.
            let j = match i + dir * d {
                j if j < 0 => j + n,
                j if j >= n => j - n,
                j => j,
            };
            if d > NEAR {
                if let Some((v0, v1, span, sph)) =
                    self.block_at(l, j, d, dir, reach, |e| reaches(e, cur))
                {
                    if !half.may_raise(sph, pa, cur) {
                        // No vertex of the block rises above the horizon so far.
                        seen |= v1 > v0;
                        d += span;
                        continue;
                    }
                    for &s in &self.verts[v0..v1] {
                        if let Some(cg) = gamma(s) {
                            seen = true;
                            if cg > cur {
                                (cur, by) = (cg, s);
                            }
                        }
                    }
                    d += span;
                    continue;
                }
            }
            let s = row[j as usize];
            if let Some(cg) = gamma(s) {
                seen = true;
                if reaches(d, cur) {
                    if cg > cur {
                        (cur, by) = (cg, s);
                    }
                } else {
                    // Out of reach of the blocked arc: the sample blocks its own arc
                    // [γ, π − φ), below every arc so far (later samples are farther round).
                    let e = PI - d as f32 * step;
                    if cg.clamp(-1.0, 1.0).acos() < e {
                        let b = half.blocked(cur, upper);
                        if b > 0.0 && by != EMPTY_SAMPLE {
                            near = near.min(dist(by));
                        }
                        closed += b;
                        (cur, upper, by) = (cg, e, s);
                    }
                }
            }
            d += 1;
        }
        let last = half.blocked(cur, upper);
        let raised = upper < half.hi || cur > half.cos_hi + super::RAISE;
        if last > 0.0 && raised && by != EMPTY_SAMPLE {
            near = near.min(dist(by));
        }
        (last + closed, seen, near)
    }
}

impl Family {
    /// The largest block of line `l` that sample `j` (at `d` samples from the receiver, walking
    /// in direction `dir`) enters first, that is no longer than `d` (blocks grow with the
    /// distance, so a half-plane reads a number of them logarithmic in the line's length),
    /// ends within `reach` and whose last sample `e` passes `within(e)`: the range of its hull
    /// vertices, its length and the sphere holding them. `None` when no block qualifies (the
    /// sample is read alone).
    #[inline]
    fn block_at(
        &self,
        l: usize,
        j: i64,
        d: i64,
        dir: i64,
        reach: i64,
        within: impl Fn(i64) -> bool,
    ) -> Option<(usize, usize, i64, Vec4)> {
        let n = self.lines.len as i64;
        // Blocks are powers of two long and aligned: a block of any level begins (walking up)
        // or ends (walking down) at `j` only where one of the smallest does, so most samples
        // are settled by one mask instead of a division per level.
        let edge = if dir < 0 {
            (j + 1) & (BLOCK - 1) == 0 || j == n - 1
        } else {
            j & (BLOCK - 1) == 0
        };
        if !edge {
            return None;
        }
        for (k, level) in self.levels.iter().enumerate().rev() {
            let size = BLOCK << k;
            if size > d.max(BLOCK) {
                continue;
            }
            let start = j & !(size - 1);
            let end = (start + size).min(n);
            let (first, span) = if dir < 0 {
                (j == end - 1, j - start + 1)
            } else {
                (j == start, end - start)
            };
            let last = d + span - 1;
            // A raise only brings samples nearer reach, so the check on the last sample
            // with the horizon before the block holds for all of them.
            if first && last <= reach && within(last) {
                let b = l * level.nblocks + (start / size) as usize;
                let (v0, v1) = level.blocks[b];
                return Some((v0 as usize, v1 as usize, span, level.spheres[b]));
            }
        }
        None
    }
}

/// Family `f` of `k`: its shape, number of lines and samples per line.
fn layout(proj: &Projection, f: usize, k: usize) -> (Shape, usize, usize) {
    if let Model::Equirect { sx, sy, .. } = proj.model {
        // One sample per pixel of the denser axis.
        let density = sx.abs().max(sy.abs()).max(1e-3);
        let len = ((TAU * density).ceil() as usize).max(8);
        let lines = len.div_ceil(2);
        let z = (f as f32 + 0.5) / k as f32;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let (s, co) = (GOLDEN * f as f32).sin_cos();
        let a = Vec3A::new(r * co, r * s, z);
        let (b1, b2) = a.any_orthonormal_pair();
        let shape = Shape::Circle {
            a,
            b1,
            b2,
            dbeta: PI / lines as f32,
            step: TAU / len as f32,
        };
        return (shape, lines, len);
    }
    let (s, co) = (PI * f as f32 / k as f32).sin_cos();
    let (t, nrm) = (Vec2::new(co, s), Vec2::new(-s, co));
    let (w, h) = (proj.width as f32, proj.height as f32);
    let corners = [
        Vec2::ZERO,
        Vec2::new(w, 0.0),
        Vec2::new(0.0, h),
        Vec2::new(w, h),
    ];
    let span = |d: Vec2| {
        let v = corners.map(|c| c.dot(d));
        (
            v.iter().copied().fold(f32::INFINITY, f32::min),
            v.iter().copied().fold(f32::NEG_INFINITY, f32::max),
        )
    };
    let ((nmin, nmax), (tmin, tmax)) = (span(nrm), span(t));
    let shape = Shape::Screen {
        t,
        nrm,
        n0: nmin + 0.5,
        t0: tmin + 0.5,
    };
    let lines = ((nmax - nmin).ceil() as usize).max(1);
    let len = ((tmax - tmin).ceil() as usize).max(1);
    (shape, lines, len)
}

/// The map pixel of sample `i` of line `l`, if it falls on the map.
fn sample_pixel(shape: &Shape, proj: &Projection, l: usize, i: usize) -> Option<usize> {
    match *shape {
        Shape::Screen { t, nrm, n0, t0 } => {
            let q = nrm * (n0 + l as f32) + t * (t0 + i as f32);
            let (x, y) = (q.x.floor(), q.y.floor());
            let ok = x >= 0.0 && y >= 0.0 && (x as usize) < proj.width;
            (ok && (y as usize) < proj.height).then(|| y as usize * proj.width + x as usize)
        }
        Shape::Circle {
            a,
            b1,
            b2,
            dbeta,
            step,
        } => {
            let (sb, cb) = (dbeta * l as f32).sin_cos();
            let (sp, cp) = (step * i as f32).sin_cos();
            let d = a * cp + (b1 * cb + b2 * sb) * sp;
            let q = proj.project(Vec3::from(d))?;
            proj.pixel_index(q.x, q.y)
        }
    }
}

/// The normal of line `l`'s plane, oriented so that its samples advance by a positive rotation
/// about it (on an orthographic map: in the direction `V × m`... see [`Family::normals`]).
fn line_normal(shape: &Shape, proj: &Projection, l: usize, len: usize) -> Vec3A {
    match *shape {
        Shape::Circle {
            a, b1, b2, dbeta, ..
        } => {
            let (sb, cb) = (dbeta * l as f32).sin_cos();
            a.cross(b1 * cb + b2 * sb)
        }
        Shape::Screen { t, nrm, n0, t0 } => {
            let at = |i: f32| nrm * (n0 + l as f32) + t * (t0 + i);
            let (p, q) = (at(0.0), at(len.max(2) as f32 - 1.0));
            let (Some((o1, d1)), Some((o2, d2))) = (proj.ray(p.x, p.y), proj.ray(q.x, q.y)) else {
                return Vec3A::ZERO;
            };
            let shift = o2 - o1;
            let m = if shift.length_squared() > 1e-12 * (1.0 + o1.length_squared()) {
                // Parallel rays: the plane holds the view axis and the shift along the line.
                d1.cross(shift)
            } else {
                d1.cross(d2)
            };
            Vec3A::from(m.normalize_or_zero())
        }
    }
}

/// Buffers a thread reuses from block to block and line to line while it builds hulls: the
/// points in the line's plane, the hull chain (positions in `pts`), and two blocks' vertices.
#[derive(Default)]
struct HullScratch {
    pts: Vec<(f32, f32, u32)>,
    chain: Vec<usize>,
    pair: Vec<u32>,
}

/// One line's samples and the hulls of its blocks, level after level: per block the range of
/// its vertices in `verts` and the sphere holding them.
struct LineHulls {
    row: Vec<u32>,
    verts: Vec<u32>,
    blocks: Vec<(u32, u32)>,
    spheres: Vec<Vec4>,
}

/// The block hulls of the line `row` (sample pixels) whose plane has normal `m`, at `depth`
/// levels of blocks.
fn line_hulls(
    row: Vec<u32>,
    m: Vec3A,
    depth: usize,
    pos: &[Vec3],
    scratch: &mut HullScratch,
) -> LineHulls {
    let m = if m.length_squared() > 0.0 {
        m.normalize()
    } else {
        Vec3A::Z
    };
    let plane = m.any_orthonormal_pair();
    let mut out = LineHulls {
        verts: Vec::with_capacity(row.len()),
        blocks: Vec::with_capacity(2 * row.len().div_ceil(BLOCK as usize)),
        spheres: Vec::with_capacity(2 * row.len().div_ceil(BLOCK as usize)),
        row: Vec::new(),
    };
    let push = |out: &mut LineHulls, block: &[u32], scratch: &mut HullScratch| {
        let start = out.verts.len();
        hull(block, plane, pos, scratch, &mut out.verts);
        out.blocks.push((start as u32, out.verts.len() as u32));
        out.spheres.push(sphere(&out.verts[start..], pos));
    };
    for block in row.chunks(BLOCK as usize) {
        push(&mut out, block, scratch);
    }
    // The hull of two blocks' union is the hull of their hulls' vertices, which lie side by
    // side in `verts`.
    let mut below = 0..out.blocks.len();
    let mut pair = std::mem::take(&mut scratch.pair);
    for _ in 1..depth {
        let start = out.blocks.len();
        for b in below.clone().step_by(2) {
            let last = (b + 1).min(below.end - 1);
            let (v0, v1) = (out.blocks[b].0 as usize, out.blocks[last].1 as usize);
            pair.clear();
            pair.extend_from_slice(&out.verts[v0..v1]);
            push(&mut out, &pair, scratch);
        }
        below = start..out.blocks.len();
    }
    scratch.pair = pair;
    out.row = row;
    out
}

/// Appends to `out` the pixels of a block's samples that are vertices of the convex hull of
/// their points, projected on the plane spanned by `plane`.
fn hull(
    block: &[u32],
    plane: (Vec3A, Vec3A),
    pos: &[Vec3],
    scratch: &mut HullScratch,
    out: &mut Vec<u32>,
) {
    let HullScratch { pts, chain, .. } = scratch;
    let (ea, eb) = plane;
    // Coordinates relative to one of the block's points keep f32 cancellation small.
    let origin = block
        .iter()
        .find(|&&s| s != EMPTY_SAMPLE)
        .map_or(Vec3A::ZERO, |&s| Vec3A::from(pos[s as usize]));
    pts.clear();
    pts.extend(
        block
            .iter()
            .filter(|&&s| s != EMPTY_SAMPLE)
            .map(|&s| {
                let q = Vec3A::from(pos[s as usize]) - origin;
                (q.dot(ea), q.dot(eb), s)
            })
            .filter(|p| p.0.is_finite() && p.1.is_finite()),
    );
    pts.sort_unstable_by(|p, q| p.0.total_cmp(&q.0).then(p.1.total_cmp(&q.1)));
    pts.dedup_by_key(|p| p.2);
    if pts.len() <= 3 {
        out.extend(pts.iter().map(|p| p.2));
        return;
    }
    // A vertex that turns the boundary by less than COLLINEAR radians is dropped: on a plane
    // seen along a line every sample is a vertex up to rounding, and the tangent through its
    // neighbours is the same within that angle.
    let cross = |o: (f32, f32, u32), a: (f32, f32, u32), b: (f32, f32, u32)| {
        let (ax, ay, bx, by) = (a.0 - o.0, a.1 - o.1, b.0 - o.0, b.1 - o.1);
        let turn = ax * by - ay * bx;
        turn - COLLINEAR * ((ax * ax + ay * ay) * (bx * bx + by * by)).sqrt()
    };
    // The chain holds positions in `pts`; each pass pushes every point once, so it never holds
    // more than 2 n.
    chain.clear();
    chain.resize(2 * pts.len() + 2, 0);
    let mut len = 0usize;
    for pass in 0..2 {
        let base = len;
        for j in 0..pts.len() {
            let i = if pass == 0 { j } else { pts.len() - 1 - j };
            while len >= base + 2 && cross(pts[chain[len - 2]], pts[chain[len - 1]], pts[i]) <= 0.0
            {
                len -= 1;
            }
            chain[len] = i;
            len += 1;
        }
        len -= 1;
    }
    out.extend(chain[..len].iter().map(|&i| pts[i].2));
}

/// A sphere holding the points of `verts` (centre of their bounding box, the largest distance
/// from it), widened for f32 rounding so that a test against it never drops a vertex.
fn sphere(verts: &[u32], pos: &[Vec3]) -> Vec4 {
    let mut lo = Vec3A::splat(f32::INFINITY);
    let mut hi = Vec3A::splat(f32::NEG_INFINITY);
    for &s in verts {
        let p = Vec3A::from(pos[s as usize]);
        lo = lo.min(p);
        hi = hi.max(p);
    }
    if verts.is_empty() || !(lo.is_finite() && hi.is_finite()) {
        // Never culled.
        return Vec4::new(0.0, 0.0, 0.0, f32::INFINITY);
    }
    let c = (lo + hi) * 0.5;
    let r = verts
        .iter()
        .map(|&s| (Vec3A::from(pos[s as usize]) - c).length())
        .fold(0.0f32, f32::max);
    c.extend(r * (1.0 + 1e-4) + 1e-6 * c.length())
}
