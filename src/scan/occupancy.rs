//! Which cells of a world grid a scan's points occupy, to tell pairs of scans that cannot share
//! surface from those that may. Bounding boxes alone keep too much: two rooms joined by a
//! doorway have boxes that meet wherever either scan looked through it.
//!
//! Cells are cubes of side `2^level` metres in world coordinates (f64, so georeferenced scans
//! work), indexed by `floor(w / 2^level)`. Two points closer than the cell side lie in the same
//! or in neighbouring cells, so "no cell of one scan touches a cell of the other" proves that no
//! two points are that close, and the test never drops a pair that could meet.

use super::Scan;
use crate::projection::floor_f64;
use glam::{DMat4, DVec3};
use rayon::prelude::*;

/// Cells along the diagonal of a scan's box at its own level: fine enough to separate rooms,
/// coarse enough to stay a few thousand cells on a surface.
const CELLS_PER_DIAGONAL: f64 = 128.0;

/// The occupied cells of one scan.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Occupancy {
    /// Cell side `2^level` metres.
    pub level: i32,
    /// Occupied cells, sorted, each once.
    pub cells: Vec<[i64; 3]>,
}

impl Occupancy {
    /// The cells `s`'s points occupy in world coordinates; `diag` is the diagonal of its world
    /// box (sets the level).
    pub fn of(s: &Scan, diag: f64) -> Occupancy {
        let level = if diag > 0.0 && diag.is_finite() {
            (diag / CELLS_PER_DIAGONAL)
                .log2()
                .floor()
                .clamp(-40.0, 40.0) as i32
        } else {
            0
        };
        let cells = world_cells(&s.points, s.pose, level);
        Occupancy { level, cells }
    }

    /// The cells at the coarser `level` (≥ `self.level`; a finer one returns a copy).
    fn at(&self, level: i32) -> Vec<[i64; 3]> {
        let shift = (level - self.level).clamp(0, 62) as u32;
        let mut out: Vec<[i64; 3]> = self
            .cells
            .iter()
            .map(|c| [c[0] >> shift, c[1] >> shift, c[2] >> shift])
            .collect();
        out.dedup();
        out.sort_unstable();
        out.dedup();
        out
    }
}

/// The world cell of a local point placed by `pose`, for cells of side `1/inv` metres.
#[inline]
pub fn world_cell(p: glam::Vec3, pose: &glam::DMat4, inv: f64) -> [i64; 3] {
    let w = pose.transform_point3(p.as_dvec3()) * inv;
    [floor_f64(w.x), floor_f64(w.y), floor_f64(w.z)]
}

/// The distinct world cells of `points` placed by `pose` at `level`, sorted.
pub fn world_cells(points: &[glam::Vec3], pose: DMat4, level: i32) -> Vec<[i64; 3]> {
    let inv = (-level as f64).exp2();
    packed_cells_and_runs(points, &pose, inv, false)
        .unwrap_or_else(|| cells_and_runs(points, &pose, inv, false))
        .0
}

/// Points per chunk of [`world_cells_and_runs`]' runs.
pub const RUN_CHUNK: usize = 4096;

/// One chunk's runs of consecutive points in one cell: (offset of the run's first point in
/// the chunk, index of the cell in the sorted cells).
pub type Runs = Vec<(u32, u32)>;

/// [`world_cells`], and for each chunk of [`RUN_CHUNK`] points its runs of consecutive points
/// in one cell. Neighbouring points mostly share a cell, so the runs are few and say every
/// point's cell without placing it again.
pub fn world_cells_and_runs(
    points: &[glam::Vec3],
    pose: DMat4,
    level: i32,
) -> (Vec<[i64; 3]>, Vec<Runs>) {
    let inv = (-level as f64).exp2();
    packed_cells_and_runs(points, &pose, inv, true)
        .unwrap_or_else(|| cells_and_runs(points, &pose, inv, true))
}

/// Bits per axis of a packed cell key.
const KEY_BITS: u32 = 21;

/// [`world_cells_and_runs`] with each cell packed into a `u64` relative to the lowest cell of
/// the points' box, which sorts and searches faster than `[i64; 3]` (one integer compare) and
/// in the same order (each axis is non-negative and fixed width, the first most significant). `None`
/// when the box spans too many cells along an axis for the key (or a point falls outside it:
/// every key is checked, so rounding at the box's corners cannot mislead it). The runs are
/// left empty unless `with_runs`.
fn packed_cells_and_runs(
    points: &[glam::Vec3],
    pose: &DMat4,
    inv: f64,
    with_runs: bool,
) -> Option<(Vec<[i64; 3]>, Vec<Runs>)> {
    let (lo, hi) = points
        .par_iter()
        .fold(
            || (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        )
        .reduce(
            || (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY),
            |a, b| (a.0.min(b.0), a.1.max(b.1)),
        );
    if !(lo.is_finite() && hi.is_finite()) {
        return None;
    }
    // The cells of the box's corners bound those of the points up to rounding; one cell of
    // margin on each side, and the check below for the rest.
    let (mut cmin, mut cmax) = ([i64::MAX; 3], [i64::MIN; 3]);
    for k in 0..8 {
        let c = glam::Vec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        );
        let w = world_cell(c, pose, inv);
        for a in 0..3 {
            (cmin[a], cmax[a]) = (cmin[a].min(w[a]), cmax[a].max(w[a]));
        }
    }
    let mut origin = [0i64; 3];
    for a in 0..3 {
        origin[a] = cmin[a].checked_sub(1)?;
        let span = cmax[a].checked_add(1)?.checked_sub(origin[a])?;
        if span >= 1 << KEY_BITS {
            return None;
        }
    }
    let mask = (1u64 << KEY_BITS) - 1;
    let pack = |c: [i64; 3]| -> Option<u64> {
        let mut key = 0u64;
        for a in 0..3 {
            let r = c[a].wrapping_sub(origin[a]) as u64;
            if r > mask {
                return None;
            }
            key = key << KEY_BITS | r;
        }
        Some(key)
    };
    let (keys, runs) = sorted_keys_and_runs(points, |p| pack(world_cell(p, pose, inv)), with_runs)?;
    let cells = keys
        .par_iter()
        .map(|&k| {
            let axis = |a: u32| origin[a as usize] + ((k >> (KEY_BITS * (2 - a))) & mask) as i64;
            [axis(0), axis(1), axis(2)]
        })
        .collect();
    Some((cells, runs))
}

/// [`world_cells_and_runs`] on the cells themselves, for boxes too large for a packed key.
fn cells_and_runs(
    points: &[glam::Vec3],
    pose: &DMat4,
    inv: f64,
    with_runs: bool,
) -> (Vec<[i64; 3]>, Vec<Runs>) {
    sorted_keys_and_runs(points, |p| Some(world_cell(p, pose, inv)), with_runs).unwrap_or_default()
}

/// The distinct keys `key` gives the points, sorted, and each chunk's runs of consecutive
/// points with one key (with the key's index; left empty unless `with_runs`). `None` as soon
/// as `key` gives `None` for a point.
fn sorted_keys_and_runs<K: Ord + Copy + Send + Sync>(
    points: &[glam::Vec3],
    key: impl Fn(glam::Vec3) -> Option<K> + Sync,
    with_runs: bool,
) -> Option<(Vec<K>, Vec<Runs>)> {
    let keyed: Vec<Option<Vec<(u32, K)>>> = points
        .par_chunks(RUN_CHUNK)
        .map(|c| {
            let mut out: Vec<(u32, K)> = Vec::new();
            for (o, p) in c.iter().enumerate() {
                let k = key(*p)?;
                if out.last().map(|r| r.1) != Some(k) {
                    out.push((o as u32, k));
                }
            }
            Some(out)
        })
        .collect();
    let keyed: Vec<Vec<(u32, K)>> = keyed.into_iter().collect::<Option<_>>()?;
    // Dropping repeats within a chunk keeps the sort small.
    let mut keys: Vec<K> = keyed
        .par_iter()
        .flat_map_iter(|r| {
            let mut k: Vec<K> = r.iter().map(|r| r.1).collect();
            k.sort_unstable();
            k.dedup();
            k
        })
        .collect();
    keys.par_sort_unstable();
    keys.dedup();
    let runs = if with_runs {
        keyed
            .par_iter()
            .map(|r| {
                r.iter()
                    .map(|&(o, k)| (o, keys.binary_search(&k).unwrap_or(0) as u32))
                    .collect()
            })
            .collect()
    } else {
        Vec::new()
    };
    Some((keys, runs))
}

/// Pair tests of a set of scans for one reach: whether some point of scan `i` may lie within
/// `reach` metres of some point of scan `j`.
#[derive(Debug, Clone)]
pub struct Reach {
    /// An unbounded reach: every pair may meet.
    unbounded: bool,
    /// Each scan's cells at the common level.
    cells: Vec<Vec<[i64; 3]>>,
    /// The same grown by one cell in every direction.
    grown: Vec<Vec<[i64; 3]>>,
}

impl Reach {
    /// Builds the tests for `reach` metres over `occ` (one per scan).
    pub fn new(occ: &[Occupancy], reach: f64) -> Reach {
        if !(reach < f64::INFINITY) {
            return Reach {
                unbounded: true,
                cells: Vec::new(),
                grown: Vec::new(),
            };
        }
        let need = if reach > 0.0 {
            reach.log2().ceil().clamp(-40.0, 60.0) as i32
        } else {
            i32::MIN
        };
        let level = occ.iter().map(|o| o.level).fold(need, i32::max);
        let cells: Vec<Vec<[i64; 3]>> = occ.par_iter().map(|o| o.at(level)).collect();
        let grown = cells
            .par_iter()
            .map(|c| {
                let mut g = Vec::with_capacity(c.len() * 27);
                for k in c {
                    for dx in -1..=1 {
                        for dy in -1..=1 {
                            for dz in -1..=1 {
                                g.push([k[0] + dx, k[1] + dy, k[2] + dz]);
                            }
                        }
                    }
                }
                g.sort_unstable();
                g.dedup();
                g
            })
            .collect();
        Reach {
            unbounded: false,
            cells,
            grown,
        }
    }

    /// Whether scans `i` and `j` may come within the reach of each other (true for `i == j`).
    pub fn meets(&self, i: usize, j: usize) -> bool {
        if i == j || self.unbounded {
            return true;
        }
        let (Some(a), Some(b)) = (self.grown.get(i), self.cells.get(j)) else {
            return true;
        };
        sorted_intersect(a, b)
    }
}

/// Whether two sorted slices share a value.
fn sorted_intersect(a: &[[i64; 3]], b: &[[i64; 3]]) -> bool {
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        match a[i].cmp(&b[j]) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => return true,
        }
    }
    false
}

/// The diagonal of a world box.
pub fn diagonal(b: &(DVec3, DVec3)) -> f64 {
    (b.1 - b.0).length()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat4, Vec3};

    fn scan_of(points: Vec<Vec3>, pose: DMat4) -> Scan {
        let mut s = Scan::from_points("s", points);
        s.pose = pose;
        s
    }

    fn plane(x0: f32, n: usize, step: f32) -> Vec<Vec3> {
        (0..n * n)
            .map(|k| Vec3::new(x0 + (k % n) as f32 * step, (k / n) as f32 * step, 0.0))
            .collect()
    }

    #[test]
    fn packed_keys_give_the_cells_and_runs_of_the_cells_themselves() {
        let mut rng = crate::rng::Rng::new(7, 0);
        let (mut packed, mut fell_back) = (0, 0);
        for case in 0..40 {
            // Clouds along a line (long runs) or scattered, georeferenced or not, some with
            // a far outlier, at levels from millimetres to kilometres.
            let n = 1 + (rng.next_u64() % 20_000) as usize;
            let scale = [0.01f32, 1.0, 50.0, 3000.0][case % 4];
            let mut pts: Vec<Vec3> = (0..n)
                .map(|k| {
                    if case % 3 == 0 {
                        Vec3::new(k as f32 * 1e-3 * scale, 0.0, 0.5)
                    } else {
                        Vec3::new(
                            (rng.next_f32() - 0.5) * scale,
                            (rng.next_f32() - 0.5) * scale,
                            (rng.next_f32() - 0.5) * scale,
                        )
                    }
                })
                .collect();
            if case % 5 == 4 {
                pts.push(Vec3::new(1e6, -1e6, 1e5));
            }
            let offset = if case % 2 == 0 { 0.0 } else { 4.2e6 };
            let pose = DMat4::from_translation(glam::DVec3::new(offset, -offset / 3.0, 17.0))
                * DMat4::from_rotation_z(0.1 * case as f64)
                * DMat4::from_rotation_x(0.07 * case as f64);
            let level = -12 + (case as i32 % 9) * 3;
            let inv = (-level as f64).exp2();
            let want = cells_and_runs(&pts, &pose, inv, true);
            match packed_cells_and_runs(&pts, &pose, inv, true) {
                Some(got) => {
                    assert_eq!(got, want, "case {case}");
                    packed += 1;
                }
                // Only a box too wide for the key falls back: its points' cells then span
                // at least 2^21/√3 along some axis.
                None => {
                    let span = (0..3)
                        .map(|a| {
                            let v = want.0.iter().map(|c| c[a]);
                            v.clone().max().unwrap_or(0) - v.min().unwrap_or(0)
                        })
                        .max();
                    assert!(span > Some(1 << 20), "case {case} fell back, span {span:?}");
                    fell_back += 1;
                }
            }
            assert_eq!(world_cells_and_runs(&pts, pose, level), want, "case {case}");
            assert_eq!(world_cells(&pts, pose, level), want.0, "case {case}");
        }
        assert!(
            packed > 20 && fell_back > 2,
            "{packed} packed, {fell_back} fell back"
        );
    }

    #[test]
    fn near_scans_meet_and_far_ones_do_not() {
        // Two 1 m squares, the second starting 0.3 m after the first ends.
        let a = scan_of(plane(0.0, 101, 0.01), DMat4::IDENTITY);
        let b = scan_of(plane(1.3, 101, 0.01), DMat4::IDENTITY);
        let occ = [Occupancy::of(&a, 1.5), Occupancy::of(&b, 1.5)];
        // Reach beyond the gap: must meet (never a false "no").
        assert!(Reach::new(&occ, 0.31).meets(0, 1));
        assert!(Reach::new(&occ, 0.31).meets(1, 0));
        // A reach far below the gap at a fine level: apart.
        let fine = [Occupancy::of(&a, 0.5), Occupancy::of(&b, 0.5)];
        assert!(!Reach::new(&fine, 0.05).meets(0, 1));
    }

    #[test]
    fn never_misses_a_close_pair() {
        // Points of b placed within the reach of a's points, at many offsets and levels.
        for k in 0..50 {
            let off = 0.013 * k as f32;
            let reach = 0.02 + 0.01 * (k % 7) as f64;
            let a = scan_of(vec![Vec3::new(off, 0.5 * off, 0.0)], DMat4::IDENTITY);
            let d = (reach * 0.99) as f32;
            let b = scan_of(
                vec![Vec3::new(off + d * 0.6, 0.5 * off - d * 0.8, 0.0)],
                DMat4::IDENTITY,
            );
            let occ = [Occupancy::of(&a, 1.0 + k as f64), Occupancy::of(&b, 0.1)];
            assert!(Reach::new(&occ, reach).meets(0, 1), "{k}");
        }
    }

    #[test]
    fn scans_whose_boxes_overlap_can_still_be_apart() {
        // A long strip along y = 0 with one far point, so its box covers the second scan,
        // a patch 5 m away from every point of the strip.
        let mut strip = plane(0.0, 11, 0.1);
        strip.extend((0..100).map(|k| Vec3::new(0.1 * k as f32, 0.0, 0.0)));
        strip.push(Vec3::new(10.0, 10.0, 0.0));
        let patch: Vec<Vec3> = plane(0.0, 11, 0.1)
            .iter()
            .map(|p| *p + Vec3::new(0.0, 6.0, 0.0))
            .collect();
        let (a, b) = (
            scan_of(strip, DMat4::IDENTITY),
            scan_of(patch, DMat4::IDENTITY),
        );
        let occ = [Occupancy::of(&a, 14.2), Occupancy::of(&b, 1.5)];
        let r = Reach::new(&occ, 0.8);
        assert!(!r.meets(0, 1) && !r.meets(1, 0));
        // Within reach of the far point once the reach covers the gap.
        assert!(Reach::new(&occ, 9.0).meets(0, 1));
    }

    #[test]
    fn an_unbounded_reach_meets_everything() {
        let a = scan_of(plane(0.0, 11, 0.1), DMat4::IDENTITY);
        let b = scan_of(plane(500.0, 11, 0.1), DMat4::IDENTITY);
        let occ = [Occupancy::of(&a, 1.5), Occupancy::of(&b, 1.5)];
        assert!(Reach::new(&occ, f64::INFINITY).meets(0, 1));
        assert!(Reach::new(&occ, f64::NAN).meets(0, 1));
        assert!(!Reach::new(&occ, 1.0).meets(0, 1));
    }

    #[test]
    fn georeferenced_poses_are_exact() {
        let t = DMat4::from_translation(DVec3::new(512_000.0, 5_200_000.0, 300.0));
        let a = scan_of(plane(0.0, 11, 0.1), t);
        let b = scan_of(plane(5.0, 11, 0.1), t);
        let occ = [Occupancy::of(&a, 1.5), Occupancy::of(&b, 1.5)];
        assert!(!Reach::new(&occ, 0.5).meets(0, 1));
        assert!(Reach::new(&occ, 4.5).meets(0, 1));
    }
}
