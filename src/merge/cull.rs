//! Leaves out (point, view) pairs that cannot pass eq. 7 before projecting them.
//!
//! Eq. 7 keeps a stored point `p_ij` of view j only within `2·max(rad_i, rad_ij)` of the point
//! of scan i, so a point whose neighbourhood holds no point of view j's G-buffer gets nothing
//! from view j. On a real site most points of a scan are of that kind for most of its partner
//! views (the partner stands in the next room and sees this room through a doorway), yet each
//! one would cost a projection and a G-buffer read. The test runs on world cells instead:
//!
//! - each side keeps its occupied cells at a base level `L` (cube side `2^L`, chosen from its
//!   radii), with the largest radius found in each cell;
//! - a cell with radius `r` is tested at the level `λ` whose cube side exceeds `2r` plus a
//!   rounding allowance, the larger of both sides' levels. Two points closer than `2^λ` along
//!   every axis lie in the same or in neighbouring cells at level `λ`, so a cell of scan i with
//!   no neighbouring cell of view j at that level holds no point eq. 7 could accept.
//!
//! The test may keep a pair that finds nothing (the cells are coarse, keys are hashed), never
//! the reverse: merged values are identical with and without it.

use crate::gbuffer::{GBuffer, EMPTY};
use crate::scan::occupancy::{world_cells_and_runs, RUN_CHUNK};
use glam::{DMat4, DVec3, Vec3};
use rayon::prelude::*;
use std::collections::HashSet;
use std::hash::{BuildHasherDefault, Hasher};

/// Base cube side as a multiple of the median radius: a typical cell holds points of a few
/// radii, so the sets stay small while walls a few cells thick still separate rooms.
const MEDIAN_FACTOR: f64 = 8.0;
/// At most this many base cells along the local box diagonal.
const CELLS_PER_DIAGONAL: f64 = 256.0;
/// The part of a base cell reserved for f32 rounding of the merge's transforms.
const ROUNDING_SHARE: f64 = 1.0 / 64.0;
/// Bound on the f32 rounding of a transformed point, per metre of local extent (about 25×
/// the worst case of a 3×3 transform and translation in f32).
const ROUNDING_PER_EXTENT: f64 = 1e-5;

/// A set of hashed cell keys. Keys are already mixed, so the hasher passes them through.
type KeySet = HashSet<u64, BuildHasherDefault<KeyHasher>>;

/// A list of cells.
type CellList = Vec<[i64; 3]>;

#[derive(Default)]
struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x100_0000_01b3);
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = v;
    }
}

/// A cell's key. Two cells may share one (then the test keeps a pair it could drop).
#[inline]
fn key(c: [i64; 3]) -> u64 {
    let mut h = (c[0] as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    h = (h ^ c[1] as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h = (h ^ c[2] as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^ (h >> 31)
}

/// `c` at `shift` levels coarser.
#[inline]
fn coarsen(c: [i64; 3], shift: i32) -> [i64; 3] {
    let s = shift.clamp(0, 63) as u32;
    [c[0] >> s, c[1] >> s, c[2] >> s]
}

/// The smallest level `λ ≥ base` whose cube side `2^λ` exceeds `2·r` plus `slack`; `None` for
/// a radius that is not finite.
fn level_for(r: f32, base: i32, slack: f64) -> Option<i32> {
    if r.is_nan() {
        return None;
    }
    let need = 2.0 * f64::from(r.max(0.0)) * (1.0 + 1e-5) + slack;
    if !need.is_finite() {
        return None;
    }
    let mut l = base;
    if need > 0.0 {
        l = l.max(need.log2().ceil().clamp(-1100.0, 1100.0) as i32);
        // log2 may round down at an exact power of two.
        while (l as f64).exp2() <= need {
            l += 1;
        }
    }
    Some(l)
}

/// Cells of a point set at a base level, with the largest radius in each.
#[derive(Debug, Clone, Default)]
struct Cells {
    /// Level of the cells.
    base: i32,
    /// f32 rounding allowance of points in this set (metres), from their local extent.
    sigma: f64,
    /// Occupied cells, sorted.
    cells: Vec<[i64; 3]>,
    /// Largest radius in each cell.
    rmax: Vec<f32>,
}

impl Cells {
    /// The cells of `points` (local, with their radii) placed by `pose`. Also returns the cell
    /// of each point when `index` is set.
    fn build(
        points: &[Vec3],
        radii: &[f32],
        pose: DMat4,
        index: bool,
    ) -> (Cells, Option<Vec<u32>>) {
        let n = points.len().min(radii.len());
        let (points, radii) = (&points[..n], &radii[..n]);
        let (lo, hi, ext) = points
            .par_iter()
            .fold(
                || (Vec3::INFINITY, Vec3::NEG_INFINITY, 0.0f32),
                |(lo, hi, e), p| (lo.min(*p), hi.max(*p), e.max(p.abs().max_element())),
            )
            .reduce(
                || (Vec3::INFINITY, Vec3::NEG_INFINITY, 0.0f32),
                |a, b| (a.0.min(b.0), a.1.max(b.1), a.2.max(b.2)),
            );
        let diag = if n > 0 {
            f64::from((hi - lo).length())
        } else {
            0.0
        };
        let base = base_level(radii, diag);
        let sigma = ROUNDING_PER_EXTENT * 3f64.sqrt() * f64::from(ext);
        let (cells, runs) = world_cells_and_runs(points, pose, base);
        // Each point's cell, from the runs of points in the same cell.
        let mut of = vec![0u32; n];
        of.par_chunks_mut(RUN_CHUNK)
            .zip(runs.par_iter())
            .for_each(|(o, runs)| {
                for (r, &(start, c)) in runs.iter().enumerate() {
                    let end = runs.get(r + 1).map_or(o.len(), |x| x.0 as usize);
                    o[start as usize..end].fill(c);
                }
            });
        // A NaN radius must stay: it disables the test for its cell. The result does not
        // depend on the order (the largest radius, or NaN if any), so chunks fold apart.
        let raise = |m: &mut f32, r: f32| {
            if !(r <= *m) && !m.is_nan() {
                *m = r;
            }
        };
        // Two chunks a thread at most: each holds a radius per cell.
        let chunk = n.div_ceil(2 * rayon::current_num_threads()).max(1 << 16);
        let rmax = of
            .par_chunks(chunk)
            .zip(radii.par_chunks(chunk))
            .fold(
                || vec![0.0f32; cells.len()],
                |mut m, (of, radii)| {
                    for (&c, &r) in of.iter().zip(radii) {
                        raise(&mut m[c as usize], r);
                    }
                    m
                },
            )
            .reduce_with(|mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    raise(x, y);
                }
                a
            })
            .unwrap_or_else(|| vec![0.0f32; cells.len()]);
        let cells = Cells {
            base,
            sigma,
            cells,
            rmax,
        };
        (cells, index.then_some(of))
    }
}

/// The base level for points with these radii spread over a box of diagonal `diag`.
fn base_level(radii: &[f32], diag: f64) -> i32 {
    // The median of an even sample is plenty to size cells.
    let stride = (radii.len() / 4096).max(1);
    let mut sample: Vec<f32> = radii
        .iter()
        .step_by(stride)
        .copied()
        .filter(|r| r.is_finite() && *r > 0.0)
        .collect();
    let mut side = 0.0f64;
    if !sample.is_empty() {
        let mid = sample.len() / 2;
        let (_, m, _) = sample.select_nth_unstable_by(mid, f32::total_cmp);
        side = MEDIAN_FACTOR * f64::from(*m);
    }
    if diag.is_finite() && diag > 0.0 {
        side = side.max(diag / CELLS_PER_DIAGONAL);
    }
    if side > 0.0 && side.is_finite() {
        side.log2().ceil().clamp(-40.0, 60.0) as i32
    } else {
        0
    }
}

/// The points of the scan being merged, with the cell of each.
#[derive(Debug, Clone, Default)]
pub struct PointCells {
    cells: Cells,
    /// Index into `cells.cells` of each point.
    cell_of: Vec<u32>,
    /// Each cell's own level ([`level_for`] of its radius; `None`: not finite), the same for
    /// every view it is tested against.
    levels: Vec<Option<i32>>,
}

impl PointCells {
    /// Cells of scan i's local `points` with their radii, placed by `pose`.
    pub fn new(points: &[Vec3], radii: &[f32], pose: DMat4) -> PointCells {
        let (cells, of) = Cells::build(points, radii, pose, true);
        let slack = (cells.base as f64).exp2() * ROUNDING_SHARE;
        let levels = cells
            .rmax
            .par_iter()
            .map(|&r| level_for(r, cells.base, slack))
            .collect();
        PointCells {
            cells,
            cell_of: of.unwrap_or_default(),
            levels,
        }
    }

    /// Index of point `i`'s cell (its entry in [`ViewCells::relevant`]'s answer).
    #[inline]
    pub fn cell_of(&self, i: usize) -> usize {
        self.cell_of.get(i).map_or(0, |&c| c as usize)
    }

    /// Number of cells.
    pub fn cell_count(&self) -> usize {
        self.cells.cells.len()
    }

    /// Cell `c` as a ball in world coordinates, with the largest radius of its points: the
    /// cube's centre, and its half diagonal plus the rounding allowance of its points.
    pub fn ball(&self, c: usize) -> (DVec3, f64, f32) {
        let side = (self.cells.base as f64).exp2();
        let k = self.cells.cells[c];
        let centre = DVec3::new(k[0] as f64 + 0.5, k[1] as f64 + 0.5, k[2] as f64 + 0.5) * side;
        let r = 0.5 * 3f64.sqrt() * side * (1.0 + 1e-9) + self.cells.sigma;
        (centre, r, self.cells.rmax[c])
    }

    /// Number of points indexed.
    pub fn len(&self) -> usize {
        self.cell_of.len()
    }

    /// True when no point is indexed.
    pub fn is_empty(&self) -> bool {
        self.cell_of.is_empty()
    }
}

/// What the test needs of one view: the dilated cell sets of its G-buffer points.
///
/// Cells whose radius fits a cube at most `SET_LEVELS` levels above the base go into sets
/// of hashed keys (Bloom filters) grown by one cell. The few with a larger radius (points at
/// grazing angles or on silhouettes, whose neighbours lie on another surface) would reach far
/// past their radius that way, so they are grown by several cells at a finer level instead.
#[derive(Debug, Clone, Default)]
pub struct ViewCells {
    base: i32,
    sigma: f64,
    /// Too many large radii (or one not finite) for the lists: every pair is kept.
    unbounded: bool,
    /// Per level from the base up: cells whose own level is at most this one, coarsened to it
    /// and grown by one cell.
    upto: Vec<KeyFilter>,
    /// Per level from the base up: cells whose own level is exactly this one, grown likewise.
    exact: Vec<KeyFilter>,
    /// Cells with a radius above the sets' levels: per level (absolute, ascending), the cells
    /// grown by as many cells as their radius needs there.
    wide: Vec<(i32, KeySet)>,
    /// Every cell at the base level with its radius (for target cells with a large radius),
    /// sorted by cell.
    all: Vec<([i64; 3], f32)>,
    /// The radii of `all` in decreasing order, with each one's place in `all`.
    by_radius: Vec<(f32, u32)>,
}

/// Levels above the base that the sets of hashed keys cover.
const SET_LEVELS: i32 = 2;
/// How many levels finer than their own the cells with a large radius are grown at.
const WIDE_FINER: i32 = 3;
/// At most this many cells with a large radius per view (more disable the test for the view:
/// each is grown by up to 17³ cells), and per target (more are kept untested: each is tested
/// against every cell of the view).
const MAX_LISTED: usize = 1024;

impl ViewCells {
    /// The sets of view j's G-buffer, placed by its `pose`.
    pub fn new(g: &GBuffer, pose: DMat4) -> ViewCells {
        let (points, radii): (Vec<Vec3>, Vec<f32>) = g
            .point
            .par_iter()
            .zip(g.position.par_iter().zip(&g.radius))
            .filter(|(p, _)| **p != EMPTY)
            .map(|(_, (q, r))| (*q, *r))
            .unzip();
        let (c, _) = Cells::build(&points, &radii, pose, false);
        let unbounded = ViewCells {
            base: c.base,
            sigma: c.sigma,
            unbounded: true,
            ..ViewCells::default()
        };
        let slack = (c.base as f64).exp2() * ROUNDING_SHARE;
        let mut levels = Vec::with_capacity(c.cells.len());
        let mut large: Vec<(i32, [i64; 3], i64)> = Vec::new();
        for (&k, &r) in c.cells.iter().zip(&c.rmax) {
            match level_for(r, c.base, slack) {
                Some(l) if l - c.base <= SET_LEVELS => levels.push(l - c.base),
                Some(l) if large.len() < MAX_LISTED => {
                    // At WIDE_FINER levels below its own the reach is at most eight cells,
                    // and the grown cube at most 9/8 of the reach along each axis.
                    let at = l - WIDE_FINER;
                    let reach = 2.0 * f64::from(r) * (1.0 + 1e-5) + slack;
                    let cells = (reach / (at as f64).exp2()).ceil() as i64;
                    levels.push(-1);
                    large.push((at, coarsen(k, at - c.base), cells));
                }
                _ => return unbounded,
            }
        }
        // Per level, the cells up to it and the cells of it; their grown sets are built in
        // parallel (the largest, at the base level, alone took a core for tens of ms).
        let mut lists: Vec<(CellList, CellList)> = Vec::new();
        let mut below: Vec<[i64; 3]> = Vec::new();
        for d in 0..=SET_LEVELS {
            let own: Vec<[i64; 3]> = c
                .cells
                .iter()
                .zip(&levels)
                .filter(|(_, &l)| l == d)
                .map(|(&k, _)| coarsen(k, d))
                .collect();
            below = below.iter().map(|&k| coarsen(k, 1)).collect();
            below.extend_from_slice(&own);
            below.sort_unstable();
            below.dedup();
            lists.push((below.clone(), if d > 0 { own } else { Vec::new() }));
        }
        let (upto, exact): (Vec<KeyFilter>, Vec<KeyFilter>) = lists
            .par_iter()
            .map(|(upto, own)| rayon::join(|| grown(upto), || grown(own)))
            .unzip();
        large.sort_unstable_by_key(|e| e.0);
        // Radii are finite here (a NaN or infinite one made the view unbounded above).
        let mut by_radius: Vec<(f32, u32)> = c
            .rmax
            .iter()
            .enumerate()
            .map(|(k, &r)| (r, k as u32))
            .collect();
        by_radius.par_sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut wide: Vec<(i32, KeySet)> = Vec::new();
        for (at, k, n) in large {
            if wide.last().is_none_or(|w| w.0 != at) {
                wide.push((at, KeySet::default()));
            }
            if let Some((_, set)) = wide.last_mut() {
                grow_into(k, n, |h| {
                    set.insert(h);
                });
            }
        }
        ViewCells {
            base: c.base,
            sigma: c.sigma,
            unbounded: false,
            upto,
            exact,
            wide,
            all: c
                .cells
                .iter()
                .copied()
                .zip(c.rmax.iter().copied())
                .collect(),
            by_radius,
        }
    }

    /// Heap bytes held (for the memory budget).
    pub fn heap_bytes(&self) -> u64 {
        let sets: u64 = self
            .upto
            .iter()
            .chain(&self.exact)
            .map(KeyFilter::heap_bytes)
            .sum();
        let wide: u64 = self.wide.iter().map(|w| w.1.capacity() as u64 * 9).sum();
        sets + wide + 32 * self.all.capacity() as u64 + 8 * self.by_radius.capacity() as u64
    }

    /// For each cell of `t`, whether its points may find a partner in this view; `None` when
    /// the test cannot tell (every point is kept).
    pub fn relevant(&self, t: &PointCells) -> Option<Vec<bool>> {
        self.relevant_with(t, true)
    }

    /// [`ViewCells::relevant`], testing a target cell of large radius against the view cells
    /// that can be near it (`indexed`) or against every one (the tests' reference).
    fn relevant_with(&self, t: &PointCells, indexed: bool) -> Option<Vec<bool>> {
        let tc = &t.cells;
        if self.unbounded || self.upto.is_empty() {
            return None;
        }
        let base_side = (self.base.min(tc.base) as f64).exp2();
        let sigma = self.sigma + tc.sigma;
        if !(sigma <= base_side * ROUNDING_SHARE) {
            return None;
        }
        let slack = (tc.base as f64).exp2() * ROUNDING_SHARE;
        let top = self.base + SET_LEVELS;
        let (side_t, side_v) = ((tc.base as f64).exp2(), (self.base as f64).exp2());
        // Whether a target cell and a view cell come closer than eq. 7's reach along every
        // axis (boxes in metres; cell indices times a power of two are exact in f64).
        let near = |a: [i64; 3], ra: f32, b: [i64; 3], rb: f32| {
            let reach =
                2.0 * f64::from(ra.max(rb)) * (1.0 + 1e-5) + slack.max(side_v * ROUNDING_SHARE);
            (0..3).all(|k| {
                let (a0, b0) = (a[k] as f64 * side_t, b[k] as f64 * side_v);
                let gap = (b0 - (a0 + side_t)).max(a0 - (b0 + side_v));
                gap < reach
            })
        };
        // Each target cell's level; those above the sets are tested against every view cell,
        // up to a count (beyond it they are kept).
        let mut own = t.levels.clone();
        let mut listed = 0usize;
        for o in own.iter_mut() {
            if o.is_some_and(|l| l > top) {
                listed += 1;
                if listed > MAX_LISTED {
                    *o = None;
                }
            }
        }
        let answer = tc
            .cells
            .par_iter()
            .zip(&tc.rmax)
            .zip(&own)
            .map(|((&c, &r), own)| {
                let Some(own) = *own else {
                    return true;
                };
                if own > top {
                    if !indexed {
                        return self.all.iter().any(|&(b, rb)| near(c, r, b, rb));
                    }
                    // The view cells of a larger radius, wherever they are…
                    let larger = self.by_radius.iter().take_while(|e| e.0 > r);
                    if larger
                        .clone()
                        .any(|&(rb, k)| near(c, r, self.all[k as usize].0, rb))
                    {
                        return true;
                    }
                    // …and the others where this cell's own reach gets along x (first in
                    // the cells' order), a cell wider on each side for rounding.
                    let reach =
                        2.0 * f64::from(r) * (1.0 + 1e-5) + slack.max(side_v * ROUNDING_SHARE);
                    let a0 = c[0] as f64 * side_t;
                    let lo = ((a0 - side_v - reach) / side_v).floor() as i64 - 1;
                    let hi = ((a0 + side_t + reach) / side_v).ceil() as i64 + 1;
                    let from = self.all.partition_point(|e| e.0[0] < lo);
                    return self.all[from..]
                        .iter()
                        .take_while(|e| e.0[0] <= hi)
                        .any(|&(b, rb)| rb <= r && near(c, r, b, rb));
                }
                let q = own.max(self.base);
                let at = |l: i32| key(coarsen(c, l - tc.base));
                self.upto[(q - self.base) as usize].contains(at(q))
                    || (q + 1..=top).any(|l| {
                        let s = &self.exact[(l - self.base) as usize];
                        !s.is_empty() && s.contains(at(l))
                    })
                    || self.wide.iter().any(|(l, s)| {
                        // A target coarser than the level cannot be refined to it: kept.
                        *l < tc.base || s.contains(&at(*l))
                    })
            });
        Some(answer.collect())
    }
}

/// Hands `insert` the keys of `k` grown by `n` cells in every direction.
fn grow_into(k: [i64; 3], n: i64, mut insert: impl FnMut(u64)) {
    for dx in -n..=n {
        for dy in -n..=n {
            for dz in -n..=n {
                insert(key([
                    k[0].wrapping_add(dx),
                    k[1].wrapping_add(dy),
                    k[2].wrapping_add(dz),
                ]));
            }
        }
    }
}

/// The keys of `cells` and of their 26 neighbours.
fn grown(cells: &[[i64; 3]]) -> KeyFilter {
    let mut s = KeyFilter::for_inserts(cells.len() * 27);
    for &k in cells {
        grow_into(k, 1, |h| s.insert(h));
    }
    s
}

/// A set of cell keys that may say yes to a key it does not hold, never no to one it holds:
/// a Bloom filter with a key's three bits in one 64-bit word. Per lookup one word of a
/// filter a few bits per insert in size, where a hash set of the same keys reads a control
/// group and a slot of a table ten times larger: the view's sets stay in cache while a
/// target's cells are tested. A false yes keeps a cell the test could have left out (the
/// merge then finds nothing there), as a shared key does.
#[derive(Debug, Clone, Default)]
struct KeyFilter {
    words: Vec<u64>,
    inserted: usize,
}

impl KeyFilter {
    /// Fewest words of a filter that holds anything: a handful of cells still gets a few
    /// bits set per word.
    const MIN_WORDS: usize = 1024;

    /// An empty filter for up to about `n` inserts (repeats included) at two to four bits
    /// each: a grown surface repeats each key several times, so a distinct key has ten or
    /// more bits and false yeses stay around a percent.
    fn for_inserts(n: usize) -> KeyFilter {
        let words = if n == 0 {
            0
        } else {
            (n.saturating_mul(2) / 64)
                .max(Self::MIN_WORDS)
                .checked_next_power_of_two()
                .unwrap_or(1 << 40)
        };
        KeyFilter {
            words: vec![0; words],
            inserted: 0,
        }
    }

    /// The word of `k` and its three bits (keys are mixed by [`key`]: the low bits pick the
    /// word, the top ones the bits).
    #[inline]
    fn slot(&self, k: u64) -> (usize, u64) {
        let w = (k as usize) & (self.words.len().wrapping_sub(1));
        let h = k >> 46;
        (
            w,
            1 << (h & 63) | 1 << ((h >> 6) & 63) | 1 << ((h >> 12) & 63),
        )
    }

    fn insert(&mut self, k: u64) {
        if self.words.is_empty() {
            *self = KeyFilter::for_inserts(Self::MIN_WORDS);
        }
        let (w, bits) = self.slot(k);
        self.words[w] |= bits;
        self.inserted += 1;
    }

    #[inline]
    fn contains(&self, k: u64) -> bool {
        if self.words.is_empty() {
            return false;
        }
        let (w, bits) = self.slot(k);
        self.words[w] & bits == bits
    }

    fn is_empty(&self) -> bool {
        self.inserted == 0
    }

    fn heap_bytes(&self) -> u64 {
        8 * self.words.capacity() as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gbuffer::rasterize;
    use glam::DVec3;

    /// A view holding the given points (one pixel each) with their radii.
    fn view(points: &[Vec3], radii: &[f32], pose: DMat4) -> ViewCells {
        let n = points.len();
        let px: Vec<u32> = (0..n as u32).collect();
        let depth: Vec<f32> = points.iter().map(|p| p.length()).collect();
        let g = rasterize(n, 1, &px, &depth, points, &vec![Vec3::Z; n], radii);
        ViewCells::new(&g, pose)
    }

    /// Whether the target's point 0 is kept against `v`.
    fn kept(t: &PointCells, v: &ViewCells) -> bool {
        v.relevant(t).is_none_or(|k| k[t.cell_of(0)])
    }

    #[test]
    fn never_leaves_out_a_pair_eq7_could_accept() {
        let mut rng = crate::rng::Rng::new(7, 0);
        for k in 0..3000 {
            // Radii from 1 mm to 3 m on both sides, so every path (sets at each level, the
            // list of large cells, large target cells) is taken.
            let r_t = 1e-3 * 3000f32.powf(rng.next_f32());
            let r_v = 1e-3 * 3000f32.powf(rng.next_f32());
            let dir = Vec3::new(
                rng.next_f32() - 0.5,
                rng.next_f32() - 0.5,
                rng.next_f32() - 0.5,
            )
            .normalize_or(Vec3::X);
            let d = 2.0 * r_t.max(r_v) * 0.999 * rng.next_f32();
            let origin = if k % 2 == 0 {
                DVec3::ZERO
            } else {
                DVec3::new(651_234.5, 5_432_109.25, 280.0)
            };
            let pose = DMat4::from_translation(origin);
            let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 20.0 - 10.0;
            // Filler points far away size the cells like a real scan's.
            let target = [p, p + Vec3::splat(15.0), p - Vec3::splat(12.0)];
            let t = PointCells::new(&target, &[r_t, 0.01, 0.01], pose);
            let q = p + dir * d;
            let fill = [
                q,
                q + Vec3::new(0.0, 18.0, 0.0),
                q - Vec3::new(9.0, 0.0, 0.0),
            ];
            let v = view(&fill, &[r_v, 0.005, 0.02], pose);
            assert!(kept(&t, &v), "case {k}: d {d}, r_t {r_t}, r_v {r_v}");
        }
    }

    #[test]
    fn large_target_cells_find_the_view_cells_every_cell_would() {
        let mut rng = crate::rng::Rng::new(5, 0);
        let mut large = 0usize;
        for case in 0..60 {
            // Surfaces of small cells with a scatter of large radii on both sides, so that
            // target cells above the sets meet view cells of larger and smaller radius.
            let pts = |rng: &mut crate::rng::Rng, n: usize, r_big: f32| {
                let mut p = Vec::with_capacity(n);
                let mut r = Vec::with_capacity(n);
                for k in 0..n {
                    p.push(Vec3::new(
                        rng.next_f32() * 8.0 - 4.0,
                        rng.next_f32() * 6.0 - 3.0,
                        rng.next_f32() * 0.2 + (k % 3) as f32,
                    ));
                    let big = rng.next_u64() % 8 == 0;
                    r.push(if big {
                        r_big * (0.2 + rng.next_f32())
                    } else {
                        0.004
                    });
                }
                (p, r)
            };
            let origin = if case % 2 == 0 {
                DVec3::ZERO
            } else {
                DVec3::new(651_234.5, 5_432_109.25, 280.0)
            };
            let pose = DMat4::from_translation(origin);
            // Dense surfaces, or a few points each, where a large cell's answer often rests
            // on one view cell.
            let n = if case % 3 == 0 { 3000 } else { 20 + 10 * case };
            let (tp, tr) = pts(&mut rng, n, 0.05 + 0.1 * (case % 5) as f32);
            let (mut vp, mut vr) = pts(&mut rng, n, 0.05 + 0.08 * (case % 7) as f32);
            if case % 4 == 1 {
                // The same points: every cell meets its twin of equal radius.
                (vp, vr) = (tp.clone(), tr.clone());
            }
            let t = PointCells::new(&tp, &tr, pose);
            let v = view(&vp, &vr, pose);
            let top = v.base + SET_LEVELS;
            large += t
                .levels
                .iter()
                .filter(|l| l.is_some_and(|l| l > top))
                .count();
            assert_eq!(
                v.relevant_with(&t, true),
                v.relevant_with(&t, false),
                "case {case}"
            );
        }
        assert!(large > 1000, "{large} large target cells");
    }

    #[test]
    fn key_filter_holds_every_key_and_rarely_others() {
        // A grown wall of cells, as `grown` builds it, and cells a little off it.
        let wall: Vec<[i64; 3]> = (0..200)
            .flat_map(|x| (0..150).map(move |z| [x, 7, z]))
            .collect();
        let f = grown(&wall);
        for &[x, y, z] in &wall {
            for d in -1..=1 {
                assert!(f.contains(key([x + d, y + d, z - d])), "{x} {y} {z}");
            }
        }
        let off = (0..200)
            .flat_map(|x| (0..150).map(move |z| [x, 7 + 2 + (x + z) % 5, z]))
            .filter(|&k| !f.contains(key(k)))
            .count();
        assert!(
            off >= 30_000 * 98 / 100,
            "{off} of 30000 cells off the wall left out"
        );
        assert!(KeyFilter::default().is_empty() && !KeyFilter::default().contains(key([0; 3])));
        assert!(grown(&[]).is_empty() && !grown(&[]).contains(key([0; 3])));
    }

    #[test]
    fn far_points_are_left_out_and_large_radii_reach_further() {
        let pose = DMat4::IDENTITY;
        let p = Vec3::new(1.0, 2.0, 0.5);
        let target = [p, Vec3::new(20.0, 0.0, 0.0)];
        let t = PointCells::new(&target, &[0.01, 0.01], pose);
        // Nothing of the view within 3 m: left out.
        let q = p + Vec3::new(3.0, 0.0, 0.0);
        let far = [q, Vec3::new(-20.0, 0.0, 0.0)];
        assert!(!kept(&t, &view(&far, &[0.01, 0.01], pose)));
        // A stored point with a 2 m radius reaches it (eq. 7 accepts up to 4 m).
        assert!(kept(&t, &view(&far, &[2.0, 0.01], pose)));
        // So does a target point with a 2 m radius.
        let t2 = PointCells::new(&target, &[2.0, 0.01], pose);
        assert!(kept(&t2, &view(&far, &[0.01, 0.01], pose)));
    }

    #[test]
    fn a_radius_that_is_not_a_number_keeps_everything() {
        let pose = DMat4::IDENTITY;
        let t = PointCells::new(&[Vec3::ZERO, Vec3::X], &[f32::NAN, 0.01], pose);
        let v = view(&[Vec3::new(50.0, 0.0, 0.0)], &[0.01], pose);
        assert!(kept(&t, &v));
        let t = PointCells::new(&[Vec3::ZERO, Vec3::X], &[0.01, 0.01], pose);
        let v = view(&[Vec3::new(50.0, 0.0, 0.0)], &[f32::NAN], pose);
        assert!(v.relevant(&t).is_none());
    }
}
