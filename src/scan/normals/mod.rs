//! Per-point normals (PCA over the 16 nearest neighbours, oriented towards the sensor) and
//! radii `rad(p) = 2·sqrt(d_k²/k)` with `d_k` the distance to the k-th nearest neighbour
//! (k = 32): from a window of the native grid where the scan has one, else from exact k
//! nearest neighbour queries (a cell grid, [`super::knn`], or a k-d tree). Where the 16 nearest
//! are narrower than the scan's noise, the normal is fitted over more ([`widen`]).

use glam::{DVec3, Vec3, Vec3A, Vec4};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use std::num::NonZeroUsize;

mod crease;
mod widen;

/// Neighbours used for a PCA normal.
pub const K_NORMAL: usize = 16;
/// Neighbours used for the radius.
pub const K_RADIUS: usize = 32;
/// Smallest radius kept (metres): duplicate points have `d_k = 0`, and a zero radius would make
/// the merge's radius ratio 0/0.
pub const MIN_RADIUS: f32 = 1e-7;

/// Radius from the distance to the k-th neighbour: `2·sqrt(d_k²/k)`.
#[inline]
pub fn radius_from_dk(dk: f32, k: usize) -> f32 {
    (2.0 * (dk * dk / k.max(1) as f32).sqrt()).max(MIN_RADIUS)
}

/// Estimates radii, and normals when `need_normals`, for `points`. `toward(p)` is the unit
/// direction from `p` to the sensor, used to orient normals (and as the normal where the
/// neighbourhood is degenerate: duplicates, collinear points, fewer than 3 points).
/// Neighbours come from a cell grid when the cloud allows one, else from a k-d tree: the same
/// neighbours either way, so the same radii (normals may differ where distances tie).
pub fn estimate<F>(points: &[Vec3], need_normals: bool, toward: F) -> (Option<Vec<Vec3>>, Vec<f32>)
where
    F: Fn(Vec3) -> Vec3 + Sync,
{
    let (fits, radii) = estimate_fits(points, need_normals, &toward);
    (fits.map(|f| widen::widen(points, &f, &toward)), radii)
}

/// [`estimate`] before its normals are widened.
fn estimate_fits<F>(points: &[Vec3], need_normals: bool, toward: F) -> (Option<Vec<Fit>>, Vec<f32>)
where
    F: Fn(Vec3) -> Vec3 + Sync,
{
    let k = K_RADIUS.max(K_NORMAL).min(points.len());
    if points.len() >= VOXEL_MIN_POINTS {
        if let Some(g) = super::knn::VoxelGrid::new(points, k) {
            return estimate_with(points, Some(&g), k, need_normals, toward);
        }
    }
    estimate_with(points, None, k, need_normals, toward)
}

/// [`estimate`] through a k-d tree for every query: the reference the cell grid is checked
/// against, and the path of small or crowded clouds.
pub fn estimate_kdtree<F>(
    points: &[Vec3],
    need_normals: bool,
    toward: F,
) -> (Option<Vec<Vec3>>, Vec<f32>)
where
    F: Fn(Vec3) -> Vec3 + Sync,
{
    let k = K_RADIUS.max(K_NORMAL).min(points.len());
    let (fits, radii) = estimate_with(points, None, k, need_normals, &toward);
    (fits.map(|f| widen::widen(points, &f, &toward)), radii)
}

/// The k-d tree of `points` (item `i` is point `i`).
fn kd_tree(points: &[Vec3]) -> ImmutableKdTree<f32, 3> {
    let coords: Vec<[f32; 3]> = points.iter().map(|p| p.to_array()).collect();
    ImmutableKdTree::new_from_slice(&coords)
}

/// Clouds from this size take the cell grid ([`super::knn`]) instead of the k-d tree (below,
/// building either costs little and the tree needs no occupancy guesses).
pub const VOXEL_MIN_POINTS: usize = 4096;

/// The k nearest neighbours of each point from `grid` (the same neighbours as the k-d tree,
/// ties broken by index) or, without a grid or for a query it gives up on (an outlier far from
/// every cell's points), from a k-d tree built on first need; then radii and normals.
fn estimate_with<F>(
    points: &[Vec3],
    grid: Option<&super::knn::VoxelGrid>,
    k: usize,
    need_normals: bool,
    toward: F,
) -> (Option<Vec<Fit>>, Vec<f32>)
where
    F: Fn(Vec3) -> Vec3 + Sync,
{
    if points.is_empty() {
        return (need_normals.then(Vec::new), Vec::new());
    }
    let exact = Exact::new(points, grid, k);
    let (mut radii, mut normals) = outputs(points.len(), need_normals);
    let work = |(ci, (rad, nrm)): (usize, (&mut [f32], &mut [Fit]))| {
        // `(d² bits << 32) | index`, nearest first (the tree's answers in its order).
        let mut nb: Vec<u64> = Vec::with_capacity(1024);
        for (o, r) in rad.iter_mut().enumerate() {
            let (ri, ni) = exact.point(ci * CHUNK + o, &mut nb, need_normals, &toward);
            *r = ri;
            if let Some(x) = nrm.get_mut(o) {
                *x = ni;
            }
        }
    };
    run_chunks(&mut radii, &mut normals, work);
    (need_normals.then_some(normals), radii)
}

/// Exact k nearest neighbours of any point of a cloud: from its cell grid, or where the grid
/// gives up (or there is none), from a k-d tree built on first need.
struct Exact<'a> {
    points: &'a [Vec3],
    grid: Option<&'a super::knn::VoxelGrid>,
    tree: std::sync::OnceLock<ImmutableKdTree<f32, 3>>,
    k: usize,
}

impl<'a> Exact<'a> {
    fn new(points: &'a [Vec3], grid: Option<&'a super::knn::VoxelGrid>, k: usize) -> Self {
        Exact {
            points,
            grid,
            tree: std::sync::OnceLock::new(),
            k,
        }
    }

    /// The radius of point `i` and, when `need_normal`, its PCA fit (else zero), from its
    /// exact k nearest neighbours. `nb` is scratch.
    fn point<F>(&self, i: usize, nb: &mut Vec<u64>, need_normal: bool, toward: &F) -> (f32, Fit)
    where
        F: Fn(Vec3) -> Vec3,
    {
        let (points, k) = (self.points, self.k);
        let p = points[i];
        if !self.grid.is_some_and(|g| g.nearest(p, k, nb)) {
            let t = self.tree.get_or_init(|| kd_tree(points));
            let kq = NonZeroUsize::new(k).unwrap_or(NonZeroUsize::MIN);
            nb.clear();
            nb.extend(
                t.nearest_n::<SquaredEuclidean>(&p.to_array(), kq)
                    .iter()
                    .map(|x| (u64::from(x.distance.to_bits()) << 32) | x.item),
            );
        }
        // The last is the k-th neighbour (self included, as the paper's "smallest sphere
        // containing the k nearest points").
        let dk = nb
            .last()
            .map_or(0.0, |&x| f32::from_bits((x >> 32) as u32).max(0.0).sqrt());
        let normal = if need_normal {
            let m = nb.len().min(K_NORMAL);
            crease::fit(p, &gather(points, &nb[..m])[..m], toward(p))
        } else {
            Fit::default()
        };
        (radius_from_dk(dk, k), normal)
    }
}

/// A PCA normal and the variances of its neighbourhood along the normal, along its narrower
/// and along its wider tangent direction (the eigenvalues of the covariance, ascending, m²):
/// what [`widen`] needs to tell a plane from noise and [`crease`] a bend.
pub(crate) type Fit = (Vec3, [f32; 3]);

/// The points named by the first [`K_NORMAL`] of `keys` (`(bits << 32) | index`).
fn gather(points: &[Vec3], keys: &[u64]) -> [Vec3; K_NORMAL] {
    let mut nb = [Vec3::ZERO; K_NORMAL];
    for (q, &x) in nb.iter_mut().zip(keys) {
        *q = points[(x & 0xffff_ffff) as usize];
    }
    nb
}

/// Zeroed radii and (when wanted, else empty) normal fits for `n` points.
fn outputs(n: usize, need_normals: bool) -> (Vec<f32>, Vec<Fit>) {
    let normals = if need_normals {
        crate::par::filled(n, Fit::default())
    } else {
        Vec::new()
    };
    (crate::par::filled(n, 0.0f32), normals)
}

/// Points per parallel work item.
const CHUNK: usize = 4096;

/// Runs `work(chunk index, (radii chunk, normals chunk))` over `CHUNK`-sized chunks in
/// parallel; `normals` is empty when normals are not wanted (its chunks are then empty).
fn run_chunks<W>(radii: &mut [f32], normals: &mut [Fit], work: W)
where
    W: Fn((usize, (&mut [f32], &mut [Fit]))) + Sync + Send,
{
    if normals.is_empty() {
        radii
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(ci, rad)| work((ci, (rad, &mut []))));
    } else {
        radii
            .par_chunks_mut(CHUNK)
            .zip(normals.par_chunks_mut(CHUNK))
            .enumerate()
            .for_each(work);
    }
}

/// Grid half-window tried first, and the largest one, for neighbours from a native grid.
const GRID_R0: i64 = 4;
const GRID_RMAX: i64 = 6;
/// The same for a grid over the sensor's image ([`estimate_pixels`]), whose cells are smaller
/// than the points' spacing by the caller's scale (1.25): windows as wide in spacings.
const IMAGE_R0: i64 = 5;
const IMAGE_RMAX: i64 = 7;

/// Like [`estimate`], but the k nearest neighbours come from a window of the scan's native
/// grid (the cells around the point, nearest in 3-D first) instead of a k-d tree: one pass
/// with no tree and no per-point allocation. On gridded scans the grid holds each point's
/// surface neighbours; `tests/neighbours.rs` pins the agreement with the k-d tree on the
/// bundled scans (median radius within 5 %, normals within 5°).
pub fn estimate_grid<F>(
    points: &[Vec3],
    grid: &crate::scan::Grid,
    need_normals: bool,
    toward: F,
) -> (Option<Vec<Vec3>>, Vec<f32>)
where
    F: Fn(Vec3) -> Vec3 + Sync,
{
    let (fits, radii) = estimate_window(points, grid, need_normals, &toward, false);
    (fits.map(|f| widen::widen(points, &f, &toward)), radii)
}

/// Like [`estimate_grid`], for a grid that is not the scanner's own but each point's cell in
/// a grid over its fitted sensor's image, with cells a little smaller than the points' spacing
/// (so a window holds a point's surface neighbours as a native grid's does). A point whose
/// largest window holds fewer than k points (at silhouettes, beside open sky, or in a cell
/// another point took) gets its exact k nearest neighbours instead. `None` when more than
/// [`MAX_PIXEL_SHARING`] of the points share a cell: the scan sampled its image unevenly, and
/// a window would see a thinned cloud.
pub fn estimate_pixels<F>(
    points: &[Vec3],
    grid: &crate::scan::Grid,
    need_normals: bool,
    toward: F,
) -> Option<(Option<Vec<Vec3>>, Vec<f32>)>
where
    F: Fn(Vec3) -> Vec3 + Sync,
{
    let cells = grid.rows as usize * grid.cols as usize;
    if grid.row.len() != points.len()
        || shared_cells(grid, cells) > MAX_PIXEL_SHARING * points.len() as f64
    {
        return None;
    }
    let (mut normals, mut radii) = estimate_window(points, grid, need_normals, &toward, true);
    let missing: Vec<usize> = radii
        .par_iter()
        .enumerate()
        .filter_map(|(i, r)| r.is_nan().then_some(i))
        .collect();
    let widened = |fits: Option<Vec<Fit>>| fits.map(|f| widen::widen(points, &f, &toward));
    if missing.is_empty() {
        return Some((widened(normals), radii));
    }
    let k = K_RADIUS.max(K_NORMAL).min(points.len());
    let cell_grid = (points.len() >= VOXEL_MIN_POINTS)
        .then(|| super::knn::VoxelGrid::new(points, k))
        .flatten();
    let exact = Exact::new(points, cell_grid.as_ref(), k);
    let fixed: Vec<(f32, Fit)> = missing
        .par_iter()
        .map_init(
            || Vec::with_capacity(1024),
            |nb, &i| exact.point(i, nb, need_normals, &toward),
        )
        .collect();
    for (&i, (r, n)) in missing.iter().zip(fixed) {
        radii[i] = r;
        if let Some(v) = normals.as_mut() {
            v[i] = n;
        }
    }
    Some((widened(normals), radii))
}

/// Largest share of a scan's points that may share their cell with another for
/// [`estimate_pixels`].
pub const MAX_PIXEL_SHARING: f64 = 0.02;

/// How many of the grid's points lie in a cell an earlier point already holds.
fn shared_cells(grid: &crate::scan::Grid, cells: usize) -> f64 {
    let mut seen = vec![0u64; cells.div_ceil(64)];
    let mut shared = 0usize;
    for (&r, &c) in grid.row.iter().zip(&grid.col) {
        if r < grid.rows && c < grid.cols {
            let cell = r as usize * grid.cols as usize + c as usize;
            let (w, b) = (cell / 64, 1u64 << (cell % 64));
            shared += usize::from(seen[w] & b != 0);
            seen[w] |= b;
        }
    }
    shared as f64
}

/// [`estimate_grid`]'s window search. With `image` (a grid over the sensor's image, not the
/// scanner's own), windows are wider, points are visited cell by cell, and a point whose
/// largest window holds fewer than k points gets a NaN radius (and no normal) for the caller
/// to fill.
fn estimate_window<F>(
    points: &[Vec3],
    grid: &crate::scan::Grid,
    need_normals: bool,
    toward: F,
    image: bool,
) -> (Option<Vec<Fit>>, Vec<f32>)
where
    F: Fn(Vec3) -> Vec3 + Sync,
{
    let n = points.len();
    let (rows, cols) = (grid.rows as i64, grid.cols as i64);
    let cells = (rows * cols) as usize;
    if n == 0 || cells == 0 || grid.row.len() != n {
        return estimate_fits(points, need_normals, toward);
    }
    let (at, xyz) = cell_arrays(points, grid);
    let (gx, rest) = xyz.split_at(cells);
    let (gy, gz) = rest.split_at(cells);
    // Points not stored in grid order (the pixels of a map built from loose points) are
    // visited cell by cell, so that consecutive windows share cache lines; results go to
    // their points afterwards.
    let order: Option<Vec<u32>> = image.then(|| cell_order(&at, n));
    let k = K_RADIUS.min(n);
    let (mut radii, mut normals) = outputs(n, need_normals);
    let work = |(ci, (rad, nrm)): (usize, (&mut [f32], &mut [Fit]))| {
        // Candidates as squared-distance bits (non-negative floats order like their bits, so
        // selection compares integers; empty cells are NaN, whose bits order after every
        // distance); with normals, packed over the point index `(bits << 32) | index` so
        // that ties break the same way every time.
        let mut keys = [0u32; WINDOW];
        let mut idx = [0u32; WINDOW];
        let mut cand = [0u64; WINDOW];
        let mut copy = [0u32; WINDOW];
        let mut scratch32: Scratch<u32> = [[0; SCRATCH]; 2];
        let mut scratch: Scratch<u64> = [[0; SCRATCH]; 2];
        let mut band = Band::default();
        let mut guess = 0.0f32;
        for (o, r) in rad.iter_mut().enumerate() {
            let i = order
                .as_ref()
                .map_or(ci * CHUNK + o, |v| v[ci * CHUNK + o] as usize);
            let p = Vec3A::from(points[i]);
            let (r0, c0) = (grid.row[i] as i64, grid.col[i] as i64);
            // `m` keys, one per cell of the window, `found` of them real points.
            let (mut m, mut found);
            let (r0w, rmax) = if image {
                (IMAGE_R0, IMAGE_RMAX)
            } else {
                (GRID_R0, GRID_RMAX)
            };
            let mut half = r0w;
            // Neighbouring points have nearly the same d_k: the pass gathers the keys within
            // ±10 % (of d_k²) of the previous one while it computes them.
            let (lo, hi) = if guess > 0.0 {
                (guess * 0.9, guess * 1.1)
            } else {
                (f32::INFINITY, f32::NEG_INFINITY)
            };
            loop {
                (m, found) = (0, 0);
                band.clear(lo, hi);
                let (ca, cb) = (
                    (c0 - half).max(0) as usize,
                    (c0 + half).min(cols - 1) as usize,
                );
                for rr in (r0 - half).max(0)..=(r0 + half).min(rows - 1) {
                    let run = (rr * cols) as usize + ca..=(rr * cols) as usize + cb;
                    let (xs, ys, zs) = (&gx[run.clone()], &gy[run.clone()], &gz[run.clone()]);
                    found += distances(xs, ys, zs, p, &mut keys[m..m + xs.len()], &mut band);
                    if need_normals {
                        idx[m..m + xs.len()].copy_from_slice(&at[run]);
                    }
                    m += xs.len();
                }
                if found >= k || half >= rmax {
                    break;
                }
                half += 2;
            }
            if image && found < k {
                *r = f32::NAN;
                continue;
            }
            let kk = k.min(found).max(1);
            // The k-th smallest key (d_k² as bits).
            let mut kth = 0;
            let dk = if found == 0 {
                0.0
            } else {
                let near = if guess <= 0.0 { None } else { band.kth(kk - 1) };
                kth = near.unwrap_or_else(|| {
                    // With normals the keys stay beside their indices: select in a copy.
                    let v = if need_normals {
                        copy[..m].copy_from_slice(&keys[..m]);
                        &mut copy[..m]
                    } else {
                        &mut keys[..m]
                    };
                    select(v, kk - 1, &mut scratch32);
                    v[kk - 1]
                });
                guess = f32::from_bits(kth);
                guess.sqrt()
            };
            *r = radius_from_dk(dk, k);
            if !nrm.is_empty() {
                // The K_NORMAL nearest, ties broken by index: the smallest packed keys. They
                // are within d_k (K_NORMAL ≤ k), so only the keys up to the k-th are packed
                // (about k of a window's 81; written either way, counted when kept).
                let kn = K_NORMAL.min(found);
                let mut nc = 0;
                for (&key, &j) in keys[..m].iter().zip(&idx[..m]) {
                    // The clamp never bites (at most WINDOW keys); it spares a bounds check
                    // and, unlike a modulo, adds one cycle to the chain through `nc`.
                    cand[nc.min(WINDOW - 1)] = (u64::from(key) << 32) | u64::from(j);
                    nc += usize::from(key <= kth);
                }
                if kn > 0 && kn < nc {
                    select(&mut cand[..nc], kn - 1, &mut scratch);
                }
                let nb = gather(points, &cand[..kn]);
                nrm[o] = crease::fit(points[i], &nb[..kn], toward(points[i]));
            }
        }
    };
    run_chunks(&mut radii, &mut normals, work);
    if let Some(order) = &order {
        radii = to_points(&radii, order);
        if need_normals {
            normals = to_points(&normals, order);
        }
    }
    (need_normals.then_some(normals), radii)
}

/// The point each cell of `grid` holds (`u32::MAX` where none; the last of several) and the
/// positions in grid order (NaN where empty), one array per coordinate (four cells per
/// instruction) in one allocation, so that a window row is one contiguous run instead of two
/// dependent gathers per cell.
fn cell_arrays(points: &[Vec3], grid: &crate::scan::Grid) -> (Vec<u32>, Vec<f32>) {
    let cells = grid.rows as usize * grid.cols as usize;
    let mut at = crate::par::filled(cells, u32::MAX);
    // One allocation for the three coordinate arrays (the allocator keeps freed memory when
    // every view fits: fewer, larger blocks fragment its heap less).
    let mut xyz = crate::par::filled(3 * cells, f32::NAN);
    let (gx, rest) = xyz.split_at_mut(cells);
    let (gy, gz) = rest.split_at_mut(cells);
    for (i, p) in points.iter().enumerate() {
        let c = grid.row[i] as usize * grid.cols as usize + grid.col[i] as usize;
        if c < cells {
            at[c] = i as u32;
            (gx[c], gy[c], gz[c]) = (p.x, p.y, p.z);
        }
    }
    (at, xyz)
}

/// The points of `at` (the point each cell holds, `u32::MAX` where none) cell by cell, then
/// the ones no cell holds.
fn cell_order(at: &[u32], n: usize) -> Vec<u32> {
    let mut order = Vec::with_capacity(n);
    let mut placed = vec![false; n];
    for &i in at.iter().filter(|&&i| i != u32::MAX) {
        order.push(i);
        placed[i as usize] = true;
    }
    order.extend((0..n as u32).filter(|&i| !placed[i as usize]));
    order
}

/// `v` (one value per entry of `order`) moved to the points `order` names.
fn to_points<T: Copy + Default>(v: &[T], order: &[u32]) -> Vec<T> {
    let mut out = vec![T::default(); v.len()];
    for (&x, &i) in v.iter().zip(order) {
        out[i as usize] = x;
    }
    out
}

/// The squared distances from `p` of the cells at `(xs, ys, zs)` as float bits into `out`,
/// four cells per SIMD instruction, with the arithmetic of `Vec3::distance_squared` (the
/// same bits as one cell at a time), and the ones within `band`'s bracket into `band`.
/// Returns how many are not NaN (the cells holding a point: points are finite, empty cells
/// NaN).
#[inline(always)]
fn distances(
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    p: Vec3A,
    out: &mut [u32],
    band: &mut Band,
) -> usize {
    let n = xs.len().min(ys.len()).min(zs.len()).min(out.len());
    let (px, py, pz) = (Vec4::splat(p.x), Vec4::splat(p.y), Vec4::splat(p.z));
    let (lo, hi) = (Vec4::splat(band.lo), Vec4::splat(band.hi));
    let (mut i, mut found) = (0, 0);
    while i + 4 <= n {
        let dx = Vec4::from_slice(&xs[i..i + 4]) - px;
        let dy = Vec4::from_slice(&ys[i..i + 4]) - py;
        let dz = Vec4::from_slice(&zs[i..i + 4]) - pz;
        let d2 = dx * dx + dy * dy + dz * dz;
        let bits = d2.to_array().map(f32::to_bits);
        out[i..i + 4].copy_from_slice(&bits);
        found += d2.cmpeq(d2).bitmask().count_ones() as usize;
        // NaN compares false both ways: empty cells are neither below nor within.
        band.below += d2.cmplt(lo).bitmask().count_ones() as usize;
        let within = (d2.cmpge(lo) & d2.cmple(hi)).bitmask();
        if within != 0 {
            for (l, &b) in bits.iter().enumerate() {
                band.push(b, within >> l & 1 != 0);
            }
        }
        i += 4;
    }
    for j in i..n {
        let (dx, dy, dz) = (xs[j] - p.x, ys[j] - p.y, zs[j] - p.z);
        let d2 = dx * dx + dy * dy + dz * dz;
        out[j] = d2.to_bits();
        found += usize::from(!d2.is_nan());
        band.below += usize::from(d2 < band.lo);
        band.push(d2.to_bits(), d2 >= band.lo && d2 <= band.hi);
    }
    found
}

/// The distances (as float bits) within a bracket `[lo, hi]`, and how many fell below it,
/// gathered while a window's distances are computed.
struct Band {
    lo: f32,
    hi: f32,
    below: usize,
    len: usize,
    values: [u32; SCRATCH],
}

impl Default for Band {
    fn default() -> Self {
        Band {
            lo: f32::INFINITY,
            hi: f32::NEG_INFINITY,
            below: 0,
            len: 0,
            values: [0; SCRATCH],
        }
    }
}

impl Band {
    /// Empties the band and sets its bracket.
    fn clear(&mut self, lo: f32, hi: f32) {
        (self.lo, self.hi, self.below, self.len) = (lo, hi, 0, 0);
    }

    /// Adds `v` when `keep` (written either way: no branch on a coin toss).
    #[inline(always)]
    fn push(&mut self, v: u32, keep: bool) {
        // The modulo never wraps (at most SCRATCH values); it spares a bounds check.
        self.values[self.len % SCRATCH] = v;
        self.len += usize::from(keep);
    }

    /// The `k`-th smallest of all the values seen (0-based) when it lies in the bracket.
    fn kth(&mut self, k: usize) -> Option<u32> {
        if self.below > k || self.below + self.len <= k {
            return None;
        }
        Some(nth_of_few(&mut self.values[..self.len], k - self.below))
    }
}

/// The `r`-th smallest of `v` (0-based, `r < v.len()`), for a bracket's handful of values
/// (5 to 20 on a scanner's grid): the largest value with at most `r` values below it,
/// counted without a branch. Insertion sort, std's choice for short slices, mispredicted
/// about as often as it compared.
fn nth_of_few(v: &mut [u32], r: usize) -> u32 {
    if v.len() > 32 {
        v.select_nth_unstable(r);
        return v[r];
    }
    let mut best = 0;
    for &x in v.iter() {
        let below: usize = v.iter().map(|&y| usize::from(y < x)).sum();
        best = if below <= r { best.max(x) } else { best };
    }
    best
}

// The normals' neighbours are found among the radius's.
const _: () = assert!(K_NORMAL <= K_RADIUS);

/// Room for the values [`select`] partitions: a whole `IMAGE_RMAX` window.
const SCRATCH: usize = 256;

/// Cells of the largest window.
const WINDOW: usize = ((2 * IMAGE_RMAX + 1) * (2 * IMAGE_RMAX + 1)) as usize;

const _: () = assert!(GRID_RMAX <= IMAGE_RMAX);

const _: () = assert!(WINDOW <= SCRATCH);

/// Two partition buffers for [`select`], kept across calls.
type Scratch<T> = [[T; SCRATCH]; 2];

/// Reorders `v` so that `v[k]` is the value a sort would put there, with no larger value
/// before it and no smaller after it (quickselect).
///
/// Pivots are medians of three values at pseudo-random places: a grid window lists its
/// cells row by row, so the first, middle and last cells are the two farthest corners and the
/// centre, and the usual choice of those three gives a pivot near the largest value. Each
/// value is copied to both buffers and only the count of its side advances: which side a
/// distance falls on is unpredictable, and a mispredicted branch per value cost more than the
/// copies (about 100 mispredictions per point for the two selections of a 9×9 window).
fn select<T: Copy + Ord>(v: &mut [T], k: usize, scratch: &mut Scratch<T>) {
    let (mut lo, mut hi) = (0usize, v.len());
    if k >= hi {
        return;
    }
    if hi > SCRATCH {
        v.select_nth_unstable(k);
        return;
    }
    let [below, above] = scratch;
    let mut state = 0x2545_F491_4F6C_DD1Du64 ^ v.len() as u64;
    let mut pick = |lo: usize, len: usize| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        lo + (((state >> 32) * len as u64) >> 32) as usize
    };
    while hi - lo > 2 {
        let len = hi - lo;
        let (a, b, c) = (v[pick(lo, len)], v[pick(lo, len)], v[pick(lo, len)]);
        let pivot = a.max(b).min(a.min(b).max(c));
        let (mut nb, mut na) = (0usize, 0usize);
        for &x in &v[lo..hi] {
            // The modulo never wraps (at most SCRATCH values); it spares a bounds check.
            below[nb % SCRATCH] = x;
            above[na % SCRATCH] = x;
            nb += usize::from(x < pivot);
            na += usize::from(x > pivot);
        }
        // v[lo..mid] < pivot = v[mid..top] < v[top..hi]: the pivot is there, so each round
        // leaves at least one value out.
        let (mid, top) = (lo + nb, hi - na);
        v[lo..mid].copy_from_slice(&below[..nb]);
        v[mid..top].fill(pivot);
        v[top..hi].copy_from_slice(&above[..na]);
        if k < mid {
            hi = mid;
        } else if k < top {
            return;
        } else {
            lo = top;
        }
    }
    if hi - lo == 2 && v[lo] > v[lo + 1] {
        v.swap(lo, lo + 1);
    }
}

/// The PCA normal of a neighbourhood (eigenvector of the smallest covariance eigenvalue),
/// oriented so that `n·toward ≥ 0`. Degenerate neighbourhoods (fewer than 3 points,
/// duplicates, collinear points) return `toward`.
pub fn pca_normal(nb: impl Iterator<Item = Vec3>, toward: Vec3) -> Vec3 {
    pca_fit(nb, toward).0
}

/// [`pca_normal`] with the neighbourhood's variances along its three axes, the normal first
/// (zeros when degenerate).
#[inline(never)]
pub(crate) fn pca_fit(mut nb: impl Iterator<Item = Vec3>, toward: Vec3) -> Fit {
    let fallback = (toward.normalize_or(Vec3::Z), [0.0; 3]);
    let Some(first) = nb.next() else {
        return fallback;
    };
    // One pass of sums over offsets from the first neighbour: they are no larger than the
    // neighbourhood, so the cancellation in `Σd dᵀ − (Σd)(Σd)ᵀ/n` is f64 rounding of its
    // size, far below the spread any scanner leaves across a surface.
    let o = first.as_dvec3();
    let (mut s, mut cnt) = (DVec3::ZERO, 1usize);
    let [mut xx, mut xy, mut xz, mut yy, mut yz, mut zz] = [0.0f64; 6];
    for q in nb {
        let d = q.as_dvec3() - o;
        s += d;
        (xx, xy, xz) = (xx + d.x * d.x, xy + d.x * d.y, xz + d.x * d.z);
        (yy, yz, zz) = (yy + d.y * d.y, yz + d.y * d.z, zz + d.z * d.z);
        cnt += 1;
    }
    if cnt < 3 {
        return fallback;
    }
    let c = s / cnt as f64;
    let cov = [
        xx - s.x * c.x,
        xy - s.x * c.y,
        xz - s.x * c.z,
        yy - s.y * c.y,
        yz - s.y * c.z,
        zz - s.z * c.z,
    ];
    let Some((n, l0, l1)) = smallest_eigen(cov) else {
        return fallback;
    };
    let n = n.as_vec3().normalize_or(fallback.0);
    let tr = cov[0] + cov[3] + cov[5];
    let spread = [l0, l1, (tr - l0 - l1).max(l1)].map(|l| (l / cnt as f64) as f32);
    if n.dot(toward) < 0.0 {
        (-n, spread)
    } else {
        (n, spread)
    }
}

/// The unit eigenvector of the smallest eigenvalue `λ0` of the symmetric positive
/// semi-definite matrix `[a00, a01, a02, a11, a12, a22]`, or `None` when the matrix is zero
/// or not finite or its middle eigenvalue is not clearly above zero (`λ1 ≤ 10⁻¹² λ2`:
/// duplicates or collinear points, no plane defined).
///
/// `λ0` is the smallest root of the characteristic polynomial, reached by Newton's method
/// from 0 (below every root the polynomial is concave and increasing, so the iterates rise
/// monotonically to `λ0`); the eigenvector is the longest cross product of two rows of
/// `A − λ0 I`, which are orthogonal to it. A handful of iterations against the dozen
/// square roots and divisions of each sweep of [`sym_eigen3`]'s Jacobi rotations.
pub fn smallest_eigenvector(a: [f64; 6]) -> Option<DVec3> {
    smallest_eigen(a).map(|(v, _, _)| v)
}

/// [`smallest_eigenvector`] with the smallest and middle eigenvalues.
fn smallest_eigen(a: [f64; 6]) -> Option<(DVec3, f64, f64)> {
    let tr = a[0] + a[3] + a[5];
    if !(tr > 0.0 && tr.is_finite()) {
        return None;
    }
    // Scaled to unit trace: the thresholds below are then relative, and no product of three
    // entries can underflow.
    let k = 1.0 / tr;
    let [a00, a01, a02, a11, a12, a22] = a.map(|x| x * k);
    // det(λI − A) = λ³ − λ² + c1·λ − det.
    let c1 = (a00 * a11 - a01 * a01) + (a00 * a22 - a02 * a02) + (a11 * a22 - a12 * a12);
    let det = a00 * (a11 * a22 - a12 * a12) - a01 * (a01 * a22 - a12 * a02)
        + a02 * (a01 * a12 - a11 * a02);
    let mut l = 0.0f64;
    // Quadratic convergence for a plane; a double or triple root converges linearly (by a
    // factor 1/2 or 2/3 a step), within the cap.
    for _ in 0..128 {
        let q = ((l - 1.0) * l + c1) * l - det;
        let dq = (3.0 * l - 2.0) * l + c1;
        if !(dq > 0.0) {
            break;
        }
        let next = l - q / dq;
        if !(next > l) {
            break;
        }
        l = next;
    }
    // λ1 + λ2 and λ1·λ2 from the remaining factor; λ1 from the product (no cancellation).
    let (sum, prod) = (1.0 - l, c1 - l * (1.0 - l));
    let l2 = 0.5 * (sum + (sum * sum - 4.0 * prod).max(0.0).sqrt());
    if !(l2 > 0.0 && prod > 1e-12 * l2 * l2) {
        return None;
    }
    let r0 = DVec3::new(a00 - l, a01, a02);
    let r1 = DVec3::new(a01, a11 - l, a12);
    let r2 = DVec3::new(a02, a12, a22 - l);
    let (c01, c02, c12) = (r0.cross(r1), r0.cross(r2), r1.cross(r2));
    let (n01, n02, n12) = (
        c01.length_squared(),
        c02.length_squared(),
        c12.length_squared(),
    );
    let (v, len2) = if n01 >= n02 && n01 >= n12 {
        (c01, n01)
    } else if n02 >= n12 {
        (c02, n02)
    } else {
        (c12, n12)
    };
    let l1 = prod / l2;
    (len2 > 0.0 && len2.is_finite()).then(|| (v / len2.sqrt(), l * tr, l1 * tr))
}

/// Eigen-decomposition of a symmetric 3×3 matrix by cyclic Jacobi rotations: eigenvalues
/// ascending and their unit eigenvectors.
#[inline(never)]
pub fn sym_eigen3(mut a: [[f64; 3]; 3]) -> ([f64; 3], [DVec3; 3]) {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..32 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        let scale = a[0][0].abs() + a[1][1].abs() + a[2][2].abs();
        if off <= 1e-15 * scale || off == 0.0 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for row in a.iter_mut() {
                let (akp, akq) = (row[p], row[q]);
                row[p] = c * akp - s * akq;
                row[q] = s * akp + c * akq;
            }
            let (rp, rq) = (a[p], a[q]);
            for k in 0..3 {
                a[p][k] = c * rp[k] - s * rq[k];
                a[q][k] = s * rp[k] + c * rq[k];
            }
            for row in v.iter_mut() {
                let vp = row[p];
                let vq = row[q];
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]));
    let vals = [a[idx[0]][idx[0]], a[idx[1]][idx[1]], a[idx[2]][idx[2]]];
    let col = |c: usize| DVec3::new(v[0][c], v[1][c], v[2][c]);
    (vals, [col(idx[0]), col(idx[1]), col(idx[2])])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn select_agrees_with_a_sort() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        for n in 1..300usize {
            for rep in 0..4 {
                let mut v: Vec<u64> = (0..n)
                    .map(|_| {
                        state ^= state << 13;
                        state ^= state >> 7;
                        state ^= state << 17;
                        // Few distinct values on some rounds: ties must work.
                        if rep % 2 == 0 {
                            state % 7
                        } else {
                            state
                        }
                    })
                    .collect();
                let mut sorted = v.clone();
                sorted.sort_unstable();
                let k = (state as usize) % n;
                select(&mut v, k, &mut [[0; SCRATCH]; 2]);
                assert_eq!(v[k], sorted[k], "n {n} k {k}");
                assert!(v[..k].iter().all(|&x| x <= v[k]));
                assert!(v[k + 1..].iter().all(|&x| x >= v[k]));
            }
        }
    }

    #[test]
    fn bracketed_selection_agrees_with_a_sort() {
        let mut rng = crate::rng::Rng::new(11, 0);
        let mut next = || rng.next_u64();
        for n in 1..=SCRATCH {
            for rep in 0..8 {
                // Squared distances as a window holds them: ties (few distinct values on some
                // rounds), empty cells (NaN) and a bracket that may miss.
                let d2: Vec<f32> = (0..n)
                    .map(|_| match next() % 8 {
                        0 => f32::NAN,
                        _ if rep % 2 == 0 => (next() % 5) as f32 * 0.25,
                        _ => (next() % 100_000) as f32 * 1e-5,
                    })
                    .collect();
                let mut sorted: Vec<f32> = d2.iter().copied().filter(|x| !x.is_nan()).collect();
                if sorted.is_empty() {
                    continue;
                }
                sorted.sort_unstable_by(f32::total_cmp);
                let k = next() as usize % sorted.len();
                let guess = sorted[next() as usize % sorted.len()].max(1e-6);
                let (lo, hi) = (guess * 0.9, guess * 1.1);
                // Cells at (√d2, 0, 0) from the origin (NaN stays empty); the truth is taken
                // from the keys the pass computed, as the square may round.
                let xs: Vec<f32> = d2.iter().map(|x| x.sqrt()).collect();
                let zero = vec![0.0; n];
                let mut keys = vec![0u32; n];
                let mut band = Band::default();
                band.clear(lo, hi);
                let found = distances(&xs, &zero, &zero, Vec3A::ZERO, &mut keys, &mut band);
                assert_eq!(found, sorted.len());
                let mut truth: Vec<u32> =
                    keys.iter().copied().filter(|&b| b < 0x7f80_0000).collect();
                truth.sort_unstable();
                let fused = band.kth(k);
                let inside = (lo.to_bits()..=hi.to_bits()).contains(&truth[k]);
                assert_eq!(fused, inside.then_some(truth[k]), "n {n} k {k}");
                let mut few = truth.clone();
                few.reverse();
                assert_eq!(nth_of_few(&mut few, k), truth[k], "n {n} k {k}");
            }
        }
    }

    /// The grid path against a brute-force reading of its own rule: the window grows from
    /// `GRID_R0` until it holds k points; the k-th smallest squared distance gives the radius and
    /// the 16 nearest (ties by index) the normal. Empty cells, edges and duplicates included.
    #[test]
    fn grid_windows_match_brute_force() {
        let (rows, cols) = (23u32, 31u32);
        let mut state = 0x1234_5678_9ABC_DEF1u64;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let (mut pts, mut row, mut col) = (Vec::new(), Vec::new(), Vec::new());
        for r in 0..rows {
            for c in 0..cols {
                // A sparse band of rows, so some windows must grow past GRID_R0.
                let keep = if (8..15).contains(&r) { 0.15 } else { 0.8 };
                if rnd() > keep {
                    continue;
                }
                let z = if rnd() < 0.02 { 0.0 } else { 0.05 * rnd() };
                pts.push(Vec3::new(c as f32 * 0.01, r as f32 * 0.012, -2.0 + z));
                row.push(r);
                col.push(c);
            }
        }
        // One exact duplicate of a point's position.
        pts[7] = pts[6];
        let grid = crate::scan::Grid {
            rows,
            cols,
            row: row.clone(),
            col: col.clone(),
        };
        let toward = |p: Vec3| (-p).normalize_or_zero();
        let (none, r_only) = estimate_grid(&pts, &grid, false, toward);
        // Before the noise rule (`widen`), which no window decides.
        let (nrm, r_both) = estimate_window(&pts, &grid, true, toward, false);
        assert!(none.is_none());
        let nrm: Vec<Vec3> = nrm.unwrap().iter().map(|f| f.0).collect();
        let k = K_RADIUS.min(pts.len());
        for i in 0..pts.len() {
            let mut half = GRID_R0;
            let near = loop {
                let mut near: Vec<(u32, u32)> = (0..pts.len())
                    .filter(|&j| {
                        (row[j] as i64 - row[i] as i64).abs() <= half
                            && (col[j] as i64 - col[i] as i64).abs() <= half
                    })
                    .map(|j| (pts[j].distance_squared(pts[i]).to_bits(), j as u32))
                    .collect();
                near.sort_unstable();
                if near.len() >= k || half >= GRID_RMAX {
                    break near;
                }
                half += 2;
            };
            let kk = k.min(near.len()).max(1);
            let want = radius_from_dk(f32::from_bits(near[kk - 1].0).sqrt(), k);
            assert_eq!(r_only[i].to_bits(), want.to_bits(), "radius of point {i}");
            assert_eq!(r_both[i].to_bits(), want.to_bits(), "radius of point {i}");
            let kn = K_NORMAL.min(near.len());
            let nb: Vec<Vec3> = near[..kn].iter().map(|&(_, j)| pts[j as usize]).collect();
            let n = crease::fit(pts[i], &nb, toward(pts[i])).0;
            assert!((nrm[i] - n).length() < 1e-6, "normal of point {i}");
        }
    }

    #[test]
    fn radius_formula_matches_hand_value() {
        // d_k = 0.4, k = 32: 2·sqrt(0.16/32) = 2·0.0707107 = 0.1414214
        assert!((radius_from_dk(0.4, 32) - 0.141_421_36).abs() < 1e-6);
        assert_eq!(radius_from_dk(0.0, 32), MIN_RADIUS);
    }

    #[test]
    fn eigen_of_diagonal_and_rotated() {
        let (vals, vecs) = sym_eigen3([[3.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]]);
        assert_eq!(vals, [1.0, 2.0, 3.0]);
        assert!((vecs[0].y.abs() - 1.0).abs() < 1e-12);
        // [[2,1,0],[1,2,0],[0,0,5]] has eigenvalues 1 (along (1,-1,0)), 3, 5.
        let (vals, vecs) = sym_eigen3([[2.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 5.0]]);
        assert!((vals[0] - 1.0).abs() < 1e-12 && (vals[1] - 3.0).abs() < 1e-12);
        assert!((vecs[0].x + vecs[0].y).abs() < 1e-12);
    }

    /// A symmetric matrix of eigenvalues `l` along the axes of a random rotation.
    fn rotated(l: [f64; 3], rng: &mut crate::rng::Rng) -> ([f64; 6], [DVec3; 3]) {
        let mut g = || 2.0 * rng.next_f32() as f64 - 1.0;
        let r = glam::DMat3::from_quat(glam::DQuat::from_xyzw(g(), g(), g(), g()).normalize());
        let m = r * glam::DMat3::from_diagonal(DVec3::from(l)) * r.transpose();
        let a = [
            m.x_axis.x, m.y_axis.x, m.z_axis.x, m.y_axis.y, m.z_axis.y, m.z_axis.z,
        ];
        (a, [r.x_axis, r.y_axis, r.z_axis])
    }

    /// Newton's root and the cross product give Jacobi's eigenvector of the smallest
    /// eigenvalue, to what the gap to the next one allows, for planes, strips, close and
    /// repeated eigenvalues at any scale and orientation; and both refuse the same
    /// degenerate matrices.
    #[test]
    fn smallest_eigenvector_agrees_with_jacobi() {
        let mut rng = crate::rng::Rng::new(5, 0);
        let spectra = [
            [1e-9, 0.4, 1.0],
            [0.0, 0.3, 1.0],
            [1e-6, 1e-4, 1.0],
            [0.2, 0.2001, 1.0],
            [0.1, 0.5, 0.5],
            [1e-3, 1.0, 1.0],
            [0.3, 0.33, 0.34],
            [0.0, 1e-7, 1.0],
        ];
        for round in 0..300 {
            for l in spectra {
                let scale = 10f64.powi(round % 19 - 12);
                let (a, axes) = rotated(l.map(|x| x * scale), &mut rng);
                let got = smallest_eigenvector(a).expect("a plane is defined");
                let full = [[a[0], a[1], a[2]], [a[1], a[3], a[4]], [a[2], a[4], a[5]]];
                let (_, jacobi) = sym_eigen3(full);
                let tol = 1e-9 * l[2] / (l[1] - l[0]);
                for want in [axes[0], jacobi[0]] {
                    let sin = got.cross(want).length();
                    assert!(
                        sin <= tol,
                        "{l:?}×{scale:e}: {got} against {want} ({sin:e})"
                    );
                }
                assert!((got.length() - 1.0).abs() < 1e-12);
            }
        }
        for l in [
            [0.0, 0.0, 1.0],
            [0.0, 1e-14, 1.0],
            [1e-15, 1e-14, 1.0],
            [0.0; 3],
        ] {
            let (a, _) = rotated(l, &mut rng);
            assert_eq!(smallest_eigenvector(a), None, "{l:?}");
        }
        assert_eq!(
            smallest_eigenvector([f64::NAN, 0.0, 0.0, 1.0, 0.0, 1.0]),
            None
        );
        assert_eq!(
            smallest_eigenvector([f64::INFINITY, 0.0, 0.0, 1.0, 0.0, 1.0]),
            None
        );
    }

    /// The one-pass normal against two passes (mean, then centred sums) and Jacobi, on noisy
    /// patches of planes far from the origin.
    #[test]
    fn pca_normal_agrees_with_two_passes_and_jacobi() {
        let mut rng = crate::rng::Rng::new(9, 0);
        for round in 0..2000 {
            let mut g = || 2.0 * rng.next_f32() - 1.0;
            let n = Vec3::new(g(), g(), g()).normalize_or(Vec3::Z);
            let (u, v) = n.any_orthonormal_pair();
            let o = Vec3::new(g(), g(), g()) * 10f32.powi(round % 4);
            let (spread, noise) = (0.05 * (1.0 + g()), 1e-4 * (1.0 + g()));
            let pts: Vec<Vec3> = (0..K_NORMAL)
                .map(|_| o + (u * g() + v * g()) * spread + n * (g() * noise))
                .collect();
            let toward = (-o).normalize_or(Vec3::Z);
            let got = pca_normal(pts.iter().copied(), toward);
            let mean = pts.iter().map(|p| p.as_dvec3()).sum::<DVec3>() / pts.len() as f64;
            let mut cov = [[0.0f64; 3]; 3];
            for p in &pts {
                let d = (p.as_dvec3() - mean).to_array();
                for (i, row) in cov.iter_mut().enumerate() {
                    for (j, x) in row.iter_mut().enumerate() {
                        *x += d[i] * d[j];
                    }
                }
            }
            let want = sym_eigen3(cov).1[0].as_vec3();
            let want = if want.dot(toward) < 0.0 { -want } else { want };
            assert!(got.dot(toward) >= 0.0);
            assert!(
                got.angle_between(want) < 1e-5,
                "round {round}: {got} against {want}"
            );
        }
    }

    #[test]
    fn plane_normals_face_the_sensor() {
        // A 20×20 grid on z = -1 seen from the origin: normals must be +z.
        let pts: Vec<Vec3> = (0..400)
            .map(|i| Vec3::new((i % 20) as f32 * 0.01, (i / 20) as f32 * 0.01, -1.0))
            .collect();
        let (n, r) = estimate(&pts, true, |p| (-p).normalize());
        let n = n.unwrap();
        assert!(n.iter().all(|v| (v.z - 1.0).abs() < 1e-5), "{:?}", &n[..3]);
        // Interior point: 32 nearest on a 1 cm grid reach d_k = sqrt(0.01²·(3²+1)) ≈ 0.0316
        // (within the ring at distances 3 and sqrt(10) grid steps).
        let r_mid = r[10 * 20 + 10];
        assert!(r_mid > 0.009 && r_mid < 0.013, "{r_mid}");
    }

    #[test]
    fn degenerate_neighbourhoods_fall_back_to_sensor_direction() {
        let dup = vec![Vec3::new(1.0, 0.0, 0.0); 40];
        let (n, r) = estimate(&dup, true, |p| (-p).normalize());
        assert!(n
            .unwrap()
            .iter()
            .all(|v| (*v - Vec3::NEG_X).length() < 1e-6));
        assert!(r.iter().all(|&x| x == MIN_RADIUS));
        let line: Vec<Vec3> = (0..40).map(|i| Vec3::new(i as f32, 0.0, 5.0)).collect();
        let (n, _) = estimate(&line, true, |_| Vec3::Y);
        assert!(n.unwrap().iter().all(|v| *v == Vec3::Y));
        let two = vec![Vec3::ONE, Vec3::ZERO];
        let (n, r) = estimate(&two, true, |_| Vec3::X);
        assert_eq!(n.unwrap(), vec![Vec3::X, Vec3::X]);
        assert!(r.iter().all(|x| x.is_finite() && *x > 0.0));
    }
}
