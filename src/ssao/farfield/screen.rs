//! One-pass sweeps of straight screen lines (pinhole and orthographic maps).
//!
//! The perspective map `(x, y, 1/Z)` of a pinhole camera (`(x, y, −depth)` of an orthographic
//! sensor) sends the sensor to infinity: the rays from the sensor become vertical lines, planes
//! stay planes, and a line's plane becomes a *chart* `(s, h)`, `s` the screen position along
//! the line and `h` the height towards the sensor. The solid behind each sample is the column
//! below it, so a line is a height field, and seen from a receiver to its right the lowest
//! horizon over the samples to its left is at the tangent from the receiver to their upper
//! convex hull (a projective map keeps lines and tangency). Walking a line once, the hull of
//! the samples passed so far is kept on a stack (each sample pushed and popped at most once)
//! and every receiver snapped to the line finds its tangent vertex by bisection: the cost per
//! pixel and half-plane is `NEAR` samples plus a logarithm of the line's length, against the
//! block walk's hull vertices over the whole line.
//!
//! As in the block walk, samples within [`NEAR`] of the receiver along the line are read one
//! by one in the receiver's own frame (height above its tangent plane), so its own surface
//! never occludes it; the tangent vertex found in the chart and its two hull neighbours are
//! read the same way (the chart ignores how far a sample lies beside the line's plane).
//!
//! The half-planes of a pixel are weighted by half the angle to their neighbours around `V`,
//! as in [`super::weighted`]; on straight lines those are the neighbouring families' lines
//! through the pixel (the lines turn monotonically with the family), so a pixel's sums are
//! accumulated family by family without keeping every half-plane.

use super::sweep::Lines;
use super::{frame, AoMap, Frame, Half, NEAR};
use crate::gbuffer::GBuffer;
use crate::projection::{fast_atan2, Model, Projection};
use glam::{Vec3, Vec3A};
use rayon::prelude::*;
use std::f32::consts::PI;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering::Relaxed};

/// A pixel outside every line (no snap).
const NONE: u64 = u64::MAX;

/// A sample in a line's chart.
#[derive(Debug, Clone, Copy)]
struct Pt {
    s: f64,
    h: f64,
    pixel: u32,
}

/// Per-pixel sums `Σ w S`, `Σ w T` (as `f32` bits) and whether any sample was read. Each pixel
/// snaps to one line of a family, so within a family every pixel is written by one line only;
/// families run one after the other.
struct Sums {
    s: Vec<AtomicU32>,
    t: Vec<AtomicU32>,
    seen: Vec<AtomicBool>,
    /// The distance to the nearest sample that raised a horizon (see [`super::Sweeps::eval`]).
    reach: Vec<AtomicU32>,
}

impl Sums {
    fn new(n: usize) -> Sums {
        let bits = |v: f32| (0..n).map(|_| AtomicU32::new(v.to_bits())).collect();
        Sums {
            s: bits(0.0),
            t: bits(0.0),
            seen: (0..n).map(|_| AtomicBool::new(false)).collect(),
            reach: bits(f32::INFINITY),
        }
    }

    fn add(&self, p: usize, ds: f32, dt: f32, seen: bool, reach: f32) {
        let get = |v: &AtomicU32| f32::from_bits(v.load(Relaxed));
        self.s[p].store((get(&self.s[p]) + ds).to_bits(), Relaxed);
        self.t[p].store((get(&self.t[p]) + dt).to_bits(), Relaxed);
        if reach < get(&self.reach[p]) {
            self.reach[p].store(reach.to_bits(), Relaxed);
        }
        if seen {
            self.seen[p].store(true, Relaxed);
        }
    }
}

/// What the line sweeps read.
struct Ctx<'a> {
    g: &'a GBuffer,
    proj: &'a Projection,
    pts: &'a [Vec3A],
    /// Per pixel: screen position and chart height (`NaN` when it has none).
    chart: &'a [[f32; 3]],
    fams: &'a [Lines],
}

/// The chart position of a local point: its pixel position and height towards the sensor.
fn chart(proj: &Projection, p: Vec3) -> Option<[f32; 3]> {
    let h = match proj.model {
        Model::Perspective { rot, .. } => {
            let z = (rot * p).z;
            if !(z > 0.0) {
                return None;
            }
            1.0 / z
        }
        Model::Ortho { toward, .. } => toward.dot(p),
        Model::Equirect { .. } => return None,
    };
    let pr = proj.project(p)?;
    let c = [pr.x, pr.y, h];
    c.iter().all(|v| v.is_finite()).then_some(c)
}

/// Unblurred plain ambient occlusion of the valid pixels `only` marks (all when `None`) of a
/// pinhole or orthographic map from `k` families of straight lines, and each pixel's reach
/// (see [`super::Sweeps::eval`]).
pub(super) fn ssao(
    g: &GBuffer,
    proj: &Projection,
    k: usize,
    only: Option<&[bool]>,
) -> (AoMap, Vec<f32>) {
    let n = g.width * g.height;
    let fams: Vec<Lines> = (0..k).map(|f| Lines::new(proj, f, k)).collect();
    let pts: Vec<Vec3A> = g.position.iter().map(|&p| Vec3A::from(p)).collect();
    let chart: Vec<[f32; 3]> = (0..n)
        .into_par_iter()
        .map(|c| {
            let none = [f32::NAN; 3];
            if g.is_valid(c) {
                chart(proj, g.position[c]).unwrap_or(none)
            } else {
                none
            }
        })
        .collect();
    let ctx = Ctx {
        g,
        proj,
        pts: &pts,
        chart: &chart,
        fams: &fams,
    };
    let sums = Sums::new(n);
    let wanted = |c: usize| g.is_valid(c) && only.is_none_or(|m| m[c]);
    let mut keys = vec![NONE; n];
    let mut order = Vec::new();
    let mut starts = Vec::new();
    for f in 0..k {
        ctx.bucket(f, &wanted, &mut keys, &mut order, &mut starts);
        let buckets = split(&order, &starts);
        buckets
            .into_par_iter()
            .enumerate()
            .for_each_init(Scratch::default, |scratch, (l, recv)| {
                ctx.sweep(f, l, recv, &keys, &sums, scratch)
            });
    }
    let mut ao = crate::par::filled(n, 1.0f32);
    let mut flag = crate::par::filled(n, false);
    ao.par_iter_mut()
        .zip(flag.par_iter_mut())
        .enumerate()
        .for_each(|(c, (a, fl))| {
            if !wanted(c) {
                return;
            }
            let s = f32::from_bits(sums.s[c].load(Relaxed));
            let t = f32::from_bits(sums.t[c].load(Relaxed));
            // A pixel without a frame adds nothing, so it is never seen.
            if !sums.seen[c].load(Relaxed) {
                *fl = true;
            } else if t > 0.0 {
                let v = s / t;
                if v.is_finite() {
                    *a = v.clamp(0.0, 1.0);
                } else {
                    *fl = true;
                }
            }
        });
    let reach = sums
        .reach
        .iter()
        .map(|r| f32::from_bits(r.load(Relaxed)))
        .collect();
    let map = AoMap {
        ao,
        no_sample: flag,
        levels: None,
    };
    (map, reach)
}

/// `order` cut into the runs of `starts` (one per line).
fn split<'o>(order: &'o [u32], starts: &[usize]) -> Vec<&'o [u32]> {
    starts.windows(2).map(|w| &order[w[0]..w[1]]).collect()
}

/// Reused per thread.
#[derive(Default)]
struct Scratch {
    row: Vec<Option<Pt>>,
    stack: Vec<Pt>,
    /// Per receiver, from the walk up the line.
    back: Vec<Back>,
}

/// A receiver's frame and its back half-plane: the half-plane with its blocked part, whether it
/// read a sample, and its reach.
type Back = (Option<Frame>, Option<(Half, f32)>, bool, f32);

impl Ctx<'_> {
    /// Sorts the valid pixels by the line of family `f` they snap to, and along it: `keys`
    /// gets each pixel's `(line << 32) | sample`, `order` the pixels, `starts` each line's run.
    fn bucket(
        &self,
        f: usize,
        wanted: &(impl Fn(usize) -> bool + Sync),
        keys: &mut [u64],
        order: &mut Vec<u32>,
        starts: &mut Vec<usize>,
    ) {
        let fam = &self.fams[f];
        let w = self.g.width;
        keys.par_iter_mut().enumerate().for_each(|(c, key)| {
            *key = NONE;
            if wanted(c) {
                let centre = ((c % w) as f32 + 0.5, (c / w) as f32 + 0.5);
                if let Some((l, i)) = fam.locate(centre, Vec3A::ZERO) {
                    *key = ((l as u64) << 32) | i as u64;
                }
            }
        });
        starts.clear();
        starts.resize(fam.count + 1, 0);
        for &key in keys.iter().filter(|&&k| k != NONE) {
            starts[(key >> 32) as usize + 1] += 1;
        }
        for l in 0..fam.count {
            starts[l + 1] += starts[l];
        }
        order.clear();
        order.resize(starts[fam.count], 0);
        let mut next = starts.clone();
        for (c, &key) in keys.iter().enumerate().filter(|(_, &k)| k != NONE) {
            let l = (key >> 32) as usize;
            order[next[l]] = c as u32;
            next[l] += 1;
        }
        let mut runs = Vec::with_capacity(fam.count);
        let mut rest = order.as_mut_slice();
        for wdw in starts.windows(2) {
            let (run, tail) = rest.split_at_mut(wdw[1] - wdw[0]);
            runs.push(run);
            rest = tail;
        }
        runs.into_par_iter()
            .for_each(|run| run.sort_unstable_by_key(|&c| keys[c as usize]));
    }

    /// Sweeps line `l` of family `f` both ways and adds its half-planes to the sums of its
    /// receivers `recv` (sorted along the line).
    fn sweep(&self, f: usize, l: usize, recv: &[u32], keys: &[u64], sums: &Sums, sc: &mut Scratch) {
        if recv.is_empty() {
            return;
        }
        let fam = &self.fams[f];
        let Some(dir) = fam.direction() else {
            return;
        };
        let m = fam.normal(l);
        let along = |c: usize| {
            let q = self.chart[c];
            (q[0] * dir.x + q[1] * dir.y) as f64
        };
        sc.row.clear();
        sc.row.extend((0..fam.len).map(|i| {
            let c = fam.pixel(self.proj, l, i).filter(|&c| self.g.is_valid(c))?;
            let h = self.chart[c][2];
            h.is_finite().then(|| Pt {
                s: along(c),
                h: h as f64,
                pixel: c as u32,
            })
        }));
        let index = |c: u32| (keys[c as usize] & 0xffff_ffff) as usize;
        let w = self.g.width;
        // Back: the samples before the receiver, walking up the line.
        sc.stack.clear();
        sc.back.clear();
        let mut next = 0usize;
        for &c in recv {
            let i = index(c);
            while next + (NEAR as usize) < i {
                if let Some(q) = sc.row[next] {
                    push(&mut sc.stack, q);
                }
                next += 1;
            }
            let cu = c as usize;
            let fr = frame(self.g, self.proj, cu % w, cu / w, cu);
            let near = i.saturating_sub(NEAR as usize)..i;
            let hf = fr.as_ref().and_then(|fr| {
                let back = m.cross(fr.view).try_normalize()?;
                Some((fr, half(fr, back, false)?))
            });
            let (back, seen, reach) = hf.map_or((None, false, f32::INFINITY), |(fr, hf)| {
                let (cur, seen, reach) = self.horizon(fr, &hf, &sc.stack, near, &sc.row, along(cu));
                (Some((hf, hf.blocked(cur, hf.hi))), seen, reach)
            });
            sc.back.push((fr, back, seen, reach));
        }
        // Front: the samples after it, walking down the line in mirrored positions.
        sc.stack.clear();
        let mut next = fam.len;
        for (j, &c) in recv.iter().enumerate().rev() {
            let i = index(c);
            while next > i + NEAR as usize + 1 {
                next -= 1;
                if let Some(q) = sc.row[next] {
                    push(&mut sc.stack, Pt { s: -q.s, ..q });
                }
            }
            let (fr, back, back_seen, mut reach) = sc.back[j];
            let Some((fr, back_u)) =
                fr.and_then(|fr| Some((fr, m.cross(fr.view).try_normalize()?)))
            else {
                continue;
            };
            let mut ds = 0.0;
            let mut dt = 0.0;
            let mut seen = back_seen;
            if let Some((hf, blocked)) = back {
                let t = hf.open();
                ds += (t - blocked).max(0.0);
                dt += t;
            }
            if let Some(hf) = half(&fr, back_u, true) {
                let near = i + 1..(i + 1 + NEAR as usize).min(fam.len);
                let (cur, s, r) =
                    self.horizon(&fr, &hf, &sc.stack, near, &sc.row, -along(c as usize));
                reach = reach.min(r);
                let t = hf.open();
                ds += (t - hf.blocked(cur, hf.hi)).max(0.0);
                dt += t;
                seen |= s;
            }
            let wgt = self.weight(f, &fr, back_u);
            sums.add(c as usize, wgt * ds, wgt * dt, seen, reach);
        }
    }

    /// `cos` of the lowest horizon of half-plane `hf` of the receiver `fr` (chart position
    /// `s`, in the hull's orientation) over the hull `stack` and the samples `near` of `row`,
    /// whether any valid sample was read, and the distance to the sample that set the horizon
    /// (∞ when none rose above the tangent plane by [`super::RAISE`]).
    fn horizon(
        &self,
        fr: &Frame,
        hf: &Half,
        stack: &[Pt],
        near: std::ops::Range<usize>,
        row: &[Option<Pt>],
        s: f64,
    ) -> (f32, bool, f32) {
        let mut cur = hf.cos_hi;
        let mut seen = false;
        let mut by = None;
        let mut read = |pixel: u32| {
            if pixel as usize == fr.c {
                return;
            }
            seen = true;
            let v = self.pts[pixel as usize] - fr.pa;
            if let Some(cg) = hf.cos_gamma(v) {
                if cg > cur {
                    cur = cg;
                    by = Some(v);
                }
            }
        };
        for q in row[near].iter().flatten() {
            read(q.pixel);
        }
        let h = self.chart[fr.c][2] as f64;
        if let Some(k) = tangent(stack, s, h) {
            for q in &stack[k.saturating_sub(1)..(k + 2).min(stack.len())] {
                read(q.pixel);
            }
        }
        let reach = match by {
            Some(v) if cur > hf.cos_hi + super::RAISE => v.length(),
            _ => f32::INFINITY,
        };
        (cur, seen, reach)
    }

    /// Half the angle between the pixel's backward half-plane of family `f` (direction `u`)
    /// and its neighbours' of families `f ± 1` (`π / K` where a neighbour has none).
    fn weight(&self, f: usize, fr: &Frame, u: Vec3A) -> f32 {
        let k = self.fams.len();
        let fallback = PI / k as f32;
        let back = |fam: &Lines| -> Option<Vec3A> {
            let (l, _) = fam.locate(fr.centre, -fr.view)?;
            fam.normal(l).cross(fr.view).try_normalize()
        };
        // Beyond the last family the lines come round reversed: family K is family 0 run
        // backwards.
        let prev = if f > 0 {
            back(&self.fams[f - 1])
        } else {
            back(&self.fams[k - 1]).map(|v| -v)
        };
        let next = if f + 1 < k {
            back(&self.fams[f + 1])
        } else {
            back(&self.fams[0]).map(|v| -v)
        };
        let angle =
            |v: Option<Vec3A>| v.map_or(fallback, |v| fast_atan2(u.cross(v).length(), u.dot(v)));
        0.5 * (angle(prev) + angle(next))
    }
}

/// The half-plane of `fr` along its line (`back` the unit direction backwards along it):
/// backwards, or forwards when `front`.
fn half(fr: &Frame, back: Vec3A, front: bool) -> Option<Half> {
    let u = if front { -back } else { back };
    Half::new(fr.a, fr.nrm.dot(u), u, fr.view, fr.nrm)
}

/// Adds `q` to the upper hull `st` of points sorted by `s` (a point at or left of the top and
/// no higher is dropped: a sample a pixel's jitter puts out of order).
fn push(st: &mut Vec<Pt>, q: Pt) {
    while let Some(t) = st.last() {
        if t.s < q.s {
            break;
        }
        if t.h >= q.h {
            return;
        }
        st.pop();
    }
    while st.len() >= 2 {
        let (a, b) = (st[st.len() - 2], st[st.len() - 1]);
        // `b` stays only strictly above the chord from `a` to `q`.
        if (b.s - a.s) * (q.h - a.h) - (b.h - a.h) * (q.s - a.s) >= 0.0 {
            st.pop();
        } else {
            break;
        }
    }
    st.push(q);
}

/// The vertex of the upper hull `st` seen highest from `(s, h)` to the right of it: the slope
/// towards the vertices rises to the tangent and falls after it, so bisection finds it.
fn tangent(st: &[Pt], s: f64, h: f64) -> Option<usize> {
    if st.is_empty() {
        return None;
    }
    // Whether vertex k + 1 is seen at least as high as vertex k.
    let rises = |k: usize| {
        let (a, b) = (st[k], st[k + 1]);
        (b.h - h) * (s - a.s) >= (a.h - h) * (s - b.s)
    };
    let (mut lo, mut hi) = (0usize, st.len() - 1);
    while lo < hi {
        let mid = (lo + hi) / 2;
        if rises(mid) {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    Some(lo)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pt(s: f64, h: f64) -> Pt {
        Pt { s, h, pixel: 0 }
    }

    #[test]
    fn tangent_matches_the_largest_slope() {
        let mut st = Vec::new();
        let pts = [
            (0.0, 1.0),
            (1.0, 3.0),
            (2.0, 3.5),
            (3.0, 2.0),
            (3.5, 2.8),
            (5.0, 0.5),
        ];
        for &(s, h) in &pts {
            push(&mut st, pt(s, h));
        }
        for (ps, ph) in [(7.0, 0.0), (6.0, 5.0), (20.0, -3.0), (5.5, 0.4)] {
            let slope = |q: &(f64, f64)| (q.1 - ph) / (ps - q.0);
            let best = pts.iter().map(slope).fold(f64::NEG_INFINITY, f64::max);
            let k = tangent(&st, ps, ph).unwrap();
            let got = (st[k].h - ph) / (ps - st[k].s);
            assert!((got - best).abs() < 1e-12, "{ps},{ph}: {got} vs {best}");
        }
    }
}
