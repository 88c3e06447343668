//! Exact k nearest neighbours from a uniform grid of cubic cells, for scans without a native
//! grid: one sort of the points by cell, then per query the cells around the point until they
//! hold k points, whose k-th distance bounds the true one, and the cells that meet the ball of
//! that radius. No tree, no allocation per query.
//!
//! The answer is the k-d tree's: the same squared distances (f32, `dx² + dy² + dz²` in that
//! order, as `kiddo`'s `SquaredEuclidean`), the k smallest, ties broken by point index. A query
//! that would reach more than [`MAX_SHELL`] cells out for its first k points, or 4 × that for
//! the ball (an outlier far from the rest), says so and the caller asks a tree; a cloud whose
//! points crowd into few cells (duplicates, a dense cluster in a large empty box) gets no grid.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Shells visited around a query's cell before it gives up (the caller then asks a tree).
pub const MAX_SHELL: i64 = 4;
/// Mean points per occupied cell aimed at (on the suite station of `cargo bench --bench normals
/// -- kdtree`, 12 made the grid refuse the cloud, leaving it to the tree).
const TARGET_OCCUPANCY: f64 = 6.0;
/// Largest number of points one cell may hold (beyond it the grid is not built).
const MAX_IN_CELL: usize = 4096;
/// Largest number of cells along an axis.
const MAX_DIM: f64 = (1u64 << 20) as f64;

/// Where each cell's points are in the sorted order: per column of cells along the run axis
/// (the box's longest), its occupied cells in order, each with where its points start.
#[derive(Debug)]
struct Table {
    /// Index into `cz` of each column's first occupied cell (and one past the last column).
    col_first: Vec<u32>,
    /// Run-axis index of each occupied cell, column by column.
    cz: Vec<u32>,
    /// Start of each occupied cell's points (and one past the last point).
    cstart: Vec<u32>,
}

/// The points of a cloud sorted by cell, with where each cell starts.
#[derive(Debug)]
pub struct VoxelGrid {
    geo: Geometry,
    side: f64,
    /// Allowance on a query's distance to an unvisited cell for the rounding of cell indices.
    margin: f64,
    xs: Vec<f32>,
    ys: Vec<f32>,
    zs: Vec<f32>,
    /// Index of each sorted point in the input.
    idx: Vec<u32>,
    table: Table,
}

impl VoxelGrid {
    /// The grid of `points` for queries of `k` neighbours; `None` when cells would not help
    /// (fewer than `k` points, not finite, more than 2³² points, or too crowded).
    pub fn new(points: &[Vec3], k: usize) -> Option<VoxelGrid> {
        let n = points.len();
        if n < k.max(1) || n >= u32::MAX as usize || !points.iter().all(|p| p.is_finite()) {
            return None;
        }
        let (lo, hi) = points
            .par_iter()
            .map(|p| (p.as_dvec3(), p.as_dvec3()))
            .reduce(
                || (DVec3::INFINITY, DVec3::NEG_INFINITY),
                |a, b| (a.0.min(b.0), a.1.max(b.1)),
            );
        // Grid axes from the shortest extent to the longest: cells are runs along the last.
        let mut ax = [0usize, 1, 2];
        let ext = hi - lo;
        ax.sort_by(|&a, &b| ext[a].total_cmp(&ext[b]));
        let perm = |v: DVec3| DVec3::new(v[ax[0]], v[ax[1]], v[ax[2]]);
        let (lo, extent) = (perm(lo), perm(ext));
        let size = extent.max_element();
        if !(size > 0.0 && size.is_finite()) {
            return None;
        }
        // A start as if the points covered the box's largest face, then the side that gives
        // the aimed occupancy on a surface (points per cell ∝ side²).
        let mut e = extent.to_array();
        e.sort_by(f64::total_cmp);
        let face = (e[2] * e[1].max(e[2] * 1e-3)).max(f64::MIN_POSITIVE);
        let mut side = (face * TARGET_OCCUPANCY / n as f64)
            .sqrt()
            .max(size / MAX_DIM);
        let mut keys: Vec<(u64, u32)> = Vec::new();
        for round in 0..4 {
            let g = Geometry::new(ax, lo, extent, side);
            keys = (0..n as u32)
                .into_par_iter()
                .map(|i| (g.linear(g.cell(points[i as usize])), i))
                .collect();
            keys.par_sort_unstable();
            let occupied = 1 + keys.windows(2).filter(|w| w[0].0 != w[1].0).count();
            let mean = n as f64 / occupied as f64;
            let f = (TARGET_OCCUPANCY / mean).sqrt();
            if round == 3 || (0.8..=1.25).contains(&f) {
                break;
            }
            side = (side * f.clamp(0.25, 4.0)).max(size / MAX_DIM);
        }
        // The loop ends before changing the side: the keys are those of this geometry.
        let g = Geometry::new(ax, lo, extent, side);
        if g.dims[0] * g.dims[1] > 4 * n as i64 + (1 << 16) {
            return None;
        }
        let mut run = 1usize;
        for w in keys.windows(2) {
            run = if w[0].0 == w[1].0 { run + 1 } else { 1 };
            if run > MAX_IN_CELL {
                return None;
            }
        }
        let idx: Vec<u32> = keys.par_iter().map(|k| k.1).collect();
        let coord = |f: fn(&Vec3) -> f32| -> Vec<f32> {
            idx.par_iter().map(|&i| f(&points[i as usize])).collect()
        };
        let (xs, ys, zs) = (coord(|p| p.x), coord(|p| p.y), coord(|p| p.z));
        let (cols, dz) = ((g.dims[0] * g.dims[1]) as usize, g.dims[2] as u64);
        let mut col_first = vec![0u32; cols + 1];
        let (mut cz, mut cstart) = (Vec::new(), Vec::new());
        for (i, w) in keys.iter().enumerate() {
            if i == 0 || keys[i - 1].0 != w.0 {
                col_first[(w.0 / dz) as usize + 1] += 1;
                cz.push((w.0 % dz) as u32);
                cstart.push(i as u32);
            }
        }
        cstart.push(n as u32);
        for c in 0..cols {
            col_first[c + 1] += col_first[c];
        }
        let table = Table {
            col_first,
            cz,
            cstart,
        };
        Some(VoxelGrid {
            geo: g,
            side,
            margin: 1e-9 * (lo.abs().max_element() + size + side),
            xs,
            ys,
            zs,
            idx,
            table,
        })
    }

    /// The `k` nearest points of `points` (the cloud the grid was built from) to `p`, as
    /// `(d² bits << 32) | index` in increasing order, into `out`. `false` when the query gave up
    /// (an outlier, see the module's notes; `out` then holds nothing useful).
    pub fn nearest(&self, p: Vec3, k: usize, out: &mut Vec<u64>) -> bool {
        out.clear();
        let k = k.min(self.idx.len());
        if k == 0 {
            return true;
        }
        let g = &self.geo;
        let c = g.cell(p);
        let pd = g.perm(p.as_dvec3());
        // Shells until they hold k points: the k-th of them bounds the true k-th distance.
        let mut r = 1;
        self.shell(c, r, p, out);
        while out.len() < k {
            r += 1;
            if r > MAX_SHELL {
                return false;
            }
            self.shell(c, r, p, out);
        }
        out.select_nth_unstable(k - 1);
        let kth_key = out[k - 1];
        let kth = f64::from(f32::from_bits((kth_key >> 32) as u32));
        // Every point whose f32 distance is within the k-th's lies within `reach` (with
        // allowances for the f32 rounding of squared distances and of cell indices).
        let reach = (kth * (1.0 + 1e-5)).sqrt() + self.margin;
        // The cells beyond the visited cube that meet the ball of radius `reach`.
        let span = |a: usize| {
            let lo = ((pd[a] - reach - g.lo[a]) * g.inv_side).floor() as i64;
            let hi = ((pd[a] + reach - g.lo[a]) * g.inv_side).floor() as i64;
            (lo.max(0), hi.min(g.dims[a] - 1))
        };
        let (sx, sy, sz) = (span(0), span(1), span(2));
        let inside = |a: usize, v: (i64, i64)| c[a] - r <= v.0 && v.1 <= c[a] + r;
        if inside(0, sx) && inside(1, sy) && inside(2, sz) {
            out.truncate(k);
            out.sort_unstable();
            return true;
        }
        if [sx, sy, sz]
            .iter()
            .zip(c)
            .any(|(s, ca)| (s.1 - ca).max(ca - s.0) > 4 * MAX_SHELL)
        {
            return false;
        }
        let gap = |a: usize, i: i64| {
            let (l, h) = (
                g.lo[a] + i as f64 * self.side,
                g.lo[a] + (i + 1) as f64 * self.side,
            );
            (l - pd[a]).max(pd[a] - h).max(0.0)
        };
        let r2 = reach * reach;
        for ix in sx.0..=sx.1 {
            let gx = gap(0, ix);
            for iy in sy.0..=sy.1 {
                let gy = gap(1, iy);
                let left = r2 - gx * gx - gy * gy;
                if left < 0.0 {
                    continue;
                }
                let rz = left.sqrt();
                let z0 = (((pd.z - rz - g.lo.z) * g.inv_side).floor() as i64).max(sz.0);
                let z1 = (((pd.z + rz - g.lo.z) * g.inv_side).floor() as i64).min(sz.1);
                if z0 > z1 {
                    continue;
                }
                let visited = (ix - c[0]).abs() <= r && (iy - c[1]).abs() <= r;
                if !visited {
                    self.run(ix, iy, z0, z1, p, out);
                    continue;
                }
                // Leave out the column's cells inside the cube, already visited.
                if z0 < c[2] - r {
                    self.run(ix, iy, z0, (c[2] - r - 1).min(z1), p, out);
                }
                if z1 > c[2] + r {
                    self.run(ix, iy, (c[2] + r + 1).max(z0), z1, p, out);
                }
            }
        }
        // The first k-th bounds the final one: only keys up to it can be among the k.
        let bound = kth_key;
        out.retain(|&x| x <= bound);
        out.select_nth_unstable(k - 1);
        out.truncate(k);
        out.sort_unstable();
        true
    }

    /// Adds the points of the cells at Chebyshev distance `r` from cell `c` (all cells of the
    /// 3×3×3 block when `r` = 1) to `out`.
    fn shell(&self, c: [i64; 3], r: i64, p: Vec3, out: &mut Vec<u64>) {
        let [dx, dy, dz] = self.geo.dims;
        let (x0, x1) = ((c[0] - r).max(0), (c[0] + r).min(dx - 1));
        let (y0, y1) = ((c[1] - r).max(0), (c[1] + r).min(dy - 1));
        let (z0, z1) = ((c[2] - r).max(0), (c[2] + r).min(dz - 1));
        for ix in x0..=x1 {
            for iy in y0..=y1 {
                let edge = r == 1 || (ix - c[0]).abs() == r || (iy - c[1]).abs() == r;
                if edge {
                    self.run(ix, iy, z0, z1, p, out);
                } else {
                    if c[2] - r >= 0 {
                        self.run(ix, iy, c[2] - r, c[2] - r, p, out);
                    }
                    if c[2] + r < dz {
                        self.run(ix, iy, c[2] + r, c[2] + r, p, out);
                    }
                }
            }
        }
    }

    /// Adds the points of cells `(ix, iy, z0..=z1)`: one run of the sorted order.
    #[inline]
    fn run(&self, ix: i64, iy: i64, z0: i64, z1: i64, p: Vec3, out: &mut Vec<u64>) {
        let t = &self.table;
        let col = (ix * self.geo.dims[1] + iy) as usize;
        let (a, b) = (t.col_first[col] as usize, t.col_first[col + 1] as usize);
        let zs = &t.cz[a..b];
        let first = a + zs.partition_point(|&z| i64::from(z) < z0);
        let last = a + zs.partition_point(|&z| i64::from(z) <= z1);
        if first < last {
            self.push(t.cstart[first] as usize, t.cstart[last] as usize, p, out);
        }
    }

    #[inline]
    fn push(&self, s: usize, e: usize, p: Vec3, out: &mut Vec<u64>) {
        let (xs, ys, zs, idx) = (
            &self.xs[s..e],
            &self.ys[s..e],
            &self.zs[s..e],
            &self.idx[s..e],
        );
        out.extend(
            xs.iter()
                .zip(ys)
                .zip(zs)
                .zip(idx)
                .map(|(((&x, &y), &z), &i)| {
                    let (a, b, c) = (p.x - x, p.y - y, p.z - z);
                    let d2 = a * a + b * b + c * c;
                    (u64::from(d2.to_bits()) << 32) | u64::from(i)
                }),
        );
    }
}

/// Cell indexing shared by the build and the queries, in grid axis order.
#[derive(Debug)]
struct Geometry {
    /// Point coordinate of each grid axis (the last, along which cells are runs, the longest).
    ax: [usize; 3],
    /// Lower corner, in grid axis order.
    lo: DVec3,
    inv_side: f64,
    dims: [i64; 3],
}

impl Geometry {
    fn new(ax: [usize; 3], lo: DVec3, extent: DVec3, side: f64) -> Geometry {
        let inv_side = 1.0 / side;
        let dim = |e: f64| ((e * inv_side).floor() as i64 + 1).clamp(1, MAX_DIM as i64 + 1);
        Geometry {
            ax,
            lo,
            inv_side,
            dims: [dim(extent.x), dim(extent.y), dim(extent.z)],
        }
    }

    /// `v` (point axes) in grid axis order.
    #[inline]
    fn perm(&self, v: DVec3) -> DVec3 {
        DVec3::new(v[self.ax[0]], v[self.ax[1]], v[self.ax[2]])
    }

    #[inline]
    fn cell(&self, p: Vec3) -> [i64; 3] {
        let q = (self.perm(p.as_dvec3()) - self.lo) * self.inv_side;
        let c = |v: f64, d: i64| (v.floor() as i64).clamp(0, d - 1);
        [
            c(q.x, self.dims[0]),
            c(q.y, self.dims[1]),
            c(q.z, self.dims[2]),
        ]
    }

    #[inline]
    fn linear(&self, c: [i64; 3]) -> u64 {
        ((c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2]) as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// The k smallest `(d² bits, index)` keys by brute force.
    fn brute(points: &[Vec3], p: Vec3, k: usize) -> Vec<u64> {
        let mut v: Vec<u64> = points
            .iter()
            .enumerate()
            .map(|(i, q)| {
                let (a, b, c) = (p.x - q.x, p.y - q.y, p.z - q.z);
                (u64::from((a * a + b * b + c * c).to_bits()) << 32) | i as u64
            })
            .collect();
        v.sort_unstable();
        v.truncate(k);
        v
    }

    fn check(points: &[Vec3], k: usize) -> usize {
        let g = VoxelGrid::new(points, k).expect("grid built");
        let mut out = Vec::new();
        let mut gave_up = 0;
        for (i, &p) in points.iter().enumerate().step_by(7) {
            if g.nearest(p, k, &mut out) {
                assert_eq!(out, brute(points, p, k), "point {i}");
            } else {
                gave_up += 1;
            }
        }
        gave_up
    }

    #[test]
    fn matches_brute_force_on_surfaces_volumes_and_lattices() {
        let mut rng = Rng::new(3, 0);
        let mut u = || rng.next_f32();
        // A tilted plane, a box's surface, a volume, far from the origin.
        let plane: Vec<Vec3> = (0..6000)
            .map(|_| {
                let (a, b) = (u() * 4.0, u() * 3.0);
                Vec3::new(a, b, 0.3 * a - 0.2 * b)
            })
            .collect();
        assert_eq!(check(&plane, 32), 0);
        let mut rng = Rng::new(4, 0);
        let mut u = || rng.next_f32();
        let shell: Vec<Vec3> = (0..6000)
            .map(|_| {
                let (a, b) = (u(), u());
                match (u() * 6.0) as u32 {
                    0 => Vec3::new(0.0, a, b),
                    1 => Vec3::new(1.0, a, b),
                    2 => Vec3::new(a, 0.0, b),
                    3 => Vec3::new(a, 1.0, b),
                    4 => Vec3::new(a, b, 0.0),
                    _ => Vec3::new(a, b, 1.0),
                }
            })
            .collect();
        assert_eq!(check(&shell, 32), 0);
        let mut rng = Rng::new(5, 0);
        let mut u = || rng.next_f32();
        let volume: Vec<Vec3> = (0..5000)
            .map(|_| Vec3::new(1e4 + u() * 2.0, -3e3 + u(), 50.0 + u() * 0.5))
            .collect();
        assert_eq!(check(&volume, 16), 0);
        // A lattice: many equal distances, ties broken by index.
        let lattice: Vec<Vec3> = (0..4096)
            .map(|i| Vec3::new((i % 64) as f32 * 0.01, (i / 64) as f32 * 0.01, 0.0))
            .collect();
        assert_eq!(check(&lattice, 32), 0);
    }

    #[test]
    fn outliers_give_up_and_crowds_get_no_grid() {
        let mut rng = Rng::new(6, 0);
        let mut pts: Vec<Vec3> = (0..5000)
            .map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), 0.0))
            .collect();
        pts.push(Vec3::new(1000.0, 1000.0, 5.0));
        let g = VoxelGrid::new(&pts, 32).expect("grid");
        let mut out = Vec::new();
        let last = *pts.last().unwrap();
        // Either exact or a refusal, never a wrong answer.
        if g.nearest(last, 32, &mut out) {
            assert_eq!(out, brute(&pts, last, 32));
        }
        assert!(check(&pts, 32) <= 1);
        // All points on one spot: no grid (one cell would hold them all).
        let same = vec![Vec3::new(1.0, 2.0, 3.0); 10_000];
        assert!(VoxelGrid::new(&same, 32).is_none());
        // Fewer points than k, or not finite: no grid.
        assert!(VoxelGrid::new(&pts[..10], 32).is_none());
        let mut bad = pts.clone();
        bad[3].x = f32::NAN;
        assert!(VoxelGrid::new(&bad, 32).is_none());
    }
}
