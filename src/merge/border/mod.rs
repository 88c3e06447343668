//! Depth-discontinuity distance field for the multi-view merge. This module owns the border
//! term's inputs: the relative Laplacian of a scan's depth map, the edge mask (Laplacian above
//! its 0.95 quantile) and, for every pixel, the Euclidean pixel distance `d_b` to the nearest
//! edge, computed exactly by two separable passes ([`distance_field`]). Depth maps are
//! row-major `width × height` `f32`; empty pixels are non-finite (normally `f32::INFINITY`).
//! With `wrap_x` the map is a 360° panorama whose left and right columns are neighbours.

use rayon::prelude::*;
use std::borrow::Cow;

/// Quantile of the Laplacian above which pixels are edges in [`border_distance`].
pub const EDGE_QUANTILE: f32 = 0.95;

/// Laplacian values at or below this are never edges (a flat map has no edges).
pub const EDGE_MIN_LAPLACIAN: f32 = 1e-6;

/// Rows per rayon task in the per-pixel passes.
const ROWS_PER_TASK: usize = 4;

/// Relative Laplacian of a depth map.
///
/// For a valid pixel `x` (finite depth): `L = |Σ_nb (D(nb) − D(x))| / D(x)` over the 4
/// neighbours, with `D(x) ≤ 0` replaced by `1e-6` in the denominator. A neighbour that is empty
/// or outside the image counts as background at `D_far = 2 × (largest finite depth of the map)`,
/// so coverage borders are discontinuities. With `wrap_x` the left and right columns are
/// neighbours. Empty pixels get `L = 0`; the result is never NaN (it is clamped to `f32::MAX`).
/// A `depth` slice of the wrong length is truncated or padded with empty pixels; the result has
/// `width × height` values.
pub fn laplacian(depth: &[f32], width: usize, height: usize, wrap_x: bool) -> Vec<f32> {
    let n = width.saturating_mul(height);
    if n == 0 {
        return Vec::new();
    }
    let depth = fit(depth, n, f32::INFINITY);
    let max = depth
        .par_iter()
        .copied()
        .filter(|d| d.is_finite())
        .reduce(|| f32::NEG_INFINITY, f32::max);
    if max == f32::NEG_INFINITY {
        return vec![0.0; n];
    }
    let far = 2.0 * f64::from(max);
    let depth = &depth[..];
    let mut out = crate::par::filled(n, 0.0f32);
    out.par_chunks_mut(width)
        .enumerate()
        .with_min_len(ROWS_PER_TASK)
        .for_each(|(y, row)| {
            let sample = |x: usize, y: usize| {
                let v = depth[y * width + x];
                if v.is_finite() {
                    f64::from(v)
                } else {
                    far
                }
            };
            for (x, l) in row.iter_mut().enumerate() {
                let d = depth[y * width + x];
                if !d.is_finite() {
                    continue;
                }
                let left = if x > 0 {
                    sample(x - 1, y)
                } else if wrap_x {
                    sample(width - 1, y)
                } else {
                    far
                };
                let right = if x + 1 < width {
                    sample(x + 1, y)
                } else if wrap_x {
                    sample(0, y)
                } else {
                    far
                };
                let up = if y > 0 { sample(x, y - 1) } else { far };
                let down = if y + 1 < height {
                    sample(x, y + 1)
                } else {
                    far
                };
                let d = f64::from(d);
                let sum = (left - d) + (right - d) + (up - d) + (down - d);
                let denom = if d > 0.0 { d } else { 1e-6 };
                *l = (sum.abs() / denom).min(f64::from(f32::MAX)) as f32;
            }
        });
    out
}

/// Edge mask from a Laplacian map.
///
/// The threshold `τ` is the `quantile` (clamped to `[0, 1]`) of `lap` over the valid pixels
/// (finite `depth`) by nearest rank: the `⌈quantile · n⌉`-th smallest of the `n` values (at
/// least the first). Edges are valid pixels with `L ≥ τ` and `L > `[`EDGE_MIN_LAPLACIAN`], so a
/// perfectly flat map has no edges, and neither has an empty map. The result has `depth.len()`
/// values; missing Laplacian values count as 0.
pub fn edge_mask(lap: &[f32], depth: &[f32], quantile: f32) -> Vec<bool> {
    let lap = fit(lap, depth.len(), 0.0);
    let valid = lap
        .par_iter()
        .zip(depth)
        .filter(|(_, d)| d.is_finite())
        .count();
    if valid == 0 {
        return vec![false; depth.len()];
    }
    let q = if quantile.is_nan() {
        1.0
    } else {
        f64::from(quantile).clamp(0.0, 1.0)
    };
    let rank = ((q * valid as f64).ceil() as usize).clamp(1, valid);
    let tau = nth_valid(&lap, depth, rank - 1);
    lap.par_iter()
        .zip(depth)
        .map(|(&l, d)| d.is_finite() && l >= tau && l > EDGE_MIN_LAPLACIAN)
        .collect()
}

/// The key of `v` in [`f32::total_cmp`]'s order, as an unsigned integer.
#[inline]
fn order_key(v: f32) -> u32 {
    let b = v.to_bits();
    // Negative values: all bits flipped; others: the sign bit set.
    b ^ ((((b as i32) >> 31) as u32) | 0x8000_0000)
}

/// The `k`-th smallest (0-based, in [`f32::total_cmp`]'s order) of the `lap` values whose
/// `depth` is finite; `k` must be below their count. Exact, in two parallel passes instead of
/// a serial selection over a million values: a histogram of the keys' top 16 bits finds the
/// bucket holding the `k`-th, whose few values are then selected.
fn nth_valid(lap: &[f32], depth: &[f32], k: usize) -> f32 {
    const BUCKETS: usize = 1 << 16;
    let top = |v: f32| (order_key(v) >> 16) as usize;
    let hist = lap
        .par_chunks(1 << 16)
        .zip(depth.par_chunks(1 << 16))
        .fold(
            || vec![0usize; BUCKETS],
            |mut h, (l, d)| {
                for (&l, d) in l.iter().zip(d) {
                    if d.is_finite() {
                        h[top(l)] += 1;
                    }
                }
                h
            },
        )
        .reduce(
            || vec![0usize; BUCKETS],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    *x += y;
                }
                a
            },
        );
    let (mut below, mut bucket) = (0usize, BUCKETS - 1);
    for (b, &c) in hist.iter().enumerate() {
        if below + c > k {
            bucket = b;
            break;
        }
        below += c;
    }
    let mut vals: Vec<f32> = lap
        .par_iter()
        .zip(depth)
        .filter(|(&l, d)| d.is_finite() && top(l) == bucket)
        .map(|(&l, _)| l)
        .collect();
    let r = (k - below).min(vals.len().saturating_sub(1));
    match vals.get(r) {
        Some(_) => *vals.select_nth_unstable_by(r, f32::total_cmp).1,
        None => f32::NAN,
    }
}

/// Euclidean distance in pixels from every pixel to the nearest seed, exact.
///
/// The distance between pixels `(x, y)` and `(sx, sy)` is `√(dx² + dy²)` with `dy = |y − sy|` and
/// `dx = |x − sx|`, or `min(dx, width − dx)` with `wrap_x`. Two separable passes (Felzenszwalb &
/// Huttenlocher 2012): each column's distance to its nearest seed, then per row the lower
/// envelope of the parabolas `(x − x')² + g(x')²`, over a row extended by half its width on both
/// sides when it wraps. The squared distances are exact integers, so the result equals
/// [`brute_force_distance`] bit for bit. No seeds → every pixel is `f32::INFINITY`; an empty
/// image gives an empty vector. A `seeds` slice of the wrong length is truncated or padded with
/// non-seeds.
pub fn distance_field(seeds: &[bool], width: usize, height: usize, wrap_x: bool) -> Vec<f32> {
    let n = width.saturating_mul(height);
    if n == 0 {
        return Vec::new();
    }
    let seeds = fit(seeds, n, false);
    let cols = column_distances(&seeds, width, height);
    let pad = if wrap_x { width / 2 } else { 0 };
    let mut out = crate::par::filled(n, f32::INFINITY);
    out.par_chunks_mut(width)
        .zip(cols.par_chunks(width))
        .with_min_len(ROWS_PER_TASK)
        .for_each_init(Envelope::default, |env, (row, g)| {
            env.build(g, pad);
            env.read(row);
        });
    out
}

/// "No seed in this column" in [`column_distances`].
const NO_SEED: u32 = u32::MAX;

/// Per pixel, the distance to the nearest seed of its column ([`NO_SEED`] where the column
/// has none): one sweep down and one up, each row at once.
fn column_distances(seeds: &[bool], width: usize, height: usize) -> Vec<u32> {
    let mut g = crate::par::filled(width * height, NO_SEED);
    for y in 0..height {
        let (done, rest) = g.split_at_mut(y * width);
        let row = &mut rest[..width];
        let s = &seeds[y * width..(y + 1) * width];
        match done
            .get(done.len().saturating_sub(width)..)
            .filter(|_| y > 0)
        {
            Some(above) => {
                for ((v, &a), &s) in row.iter_mut().zip(above).zip(s) {
                    *v = if s { 0 } else { a.saturating_add(1) };
                }
            }
            None => {
                for (v, &s) in row.iter_mut().zip(s) {
                    *v = if s { 0 } else { NO_SEED };
                }
            }
        }
    }
    for y in (0..height.saturating_sub(1)).rev() {
        let (head, below) = g.split_at_mut((y + 1) * width);
        let row = &mut head[y * width..];
        for (v, &b) in row.iter_mut().zip(&below[..width]) {
            *v = (*v).min(b.saturating_add(1));
        }
    }
    g
}

/// The lower envelope of one row's parabolas, with its scratch kept across rows.
#[derive(Default)]
struct Envelope {
    /// Apexes (positions in the extended row, `x − pad`) and their heights `g²`.
    at: Vec<i64>,
    height: Vec<i64>,
    /// `from[k]`: where parabola `k` starts being the lowest.
    from: Vec<f64>,
}

impl Envelope {
    /// The envelope of the parabolas of row `g` (column distances), the row extended by `pad`
    /// pixels on each side with the wrapped-around columns.
    fn build(&mut self, g: &[u32], pad: usize) {
        self.at.clear();
        self.height.clear();
        self.from.clear();
        let w = g.len();
        // Column of extended position `e` is `(e − pad) mod w`, stepped without a division.
        let mut col = (w - pad) % w.max(1);
        for e in 0..w + 2 * pad {
            let gv = g[col];
            col = if col + 1 == w { 0 } else { col + 1 };
            if gv == NO_SEED {
                continue;
            }
            let (q, fq) = (e as i64 - pad as i64, i64::from(gv) * i64::from(gv));
            let mut s = f64::NEG_INFINITY;
            while let (Some(&v), Some(&fv), Some(&z)) =
                (self.at.last(), self.height.last(), self.from.last())
            {
                // Where parabola q starts lying below the last one (apexes strictly ordered).
                s = ((fq + q * q) - (fv + v * v)) as f64 / (2 * (q - v)) as f64;
                if s > z {
                    break;
                }
                self.at.pop();
                self.height.pop();
                self.from.pop();
                s = f64::NEG_INFINITY;
            }
            self.at.push(q);
            self.height.push(fq);
            self.from.push(s);
        }
    }

    /// The distances of row pixels `0..row.len()` from the envelope (`∞` when it is empty).
    fn read(&self, row: &mut [f32]) {
        if self.at.is_empty() {
            return;
        }
        let mut k = 0;
        for (x, o) in row.iter_mut().enumerate() {
            let x = x as i64;
            while k + 1 < self.at.len() && self.from[k + 1] <= x as f64 {
                k += 1;
            }
            let dx = x - self.at[k];
            *o = to_distance((dx * dx + self.height[k]) as u64);
        }
    }
}

/// Exact distance to the nearest seed (same metric as [`distance_field`]) by comparing every pixel
/// with every seed: `O(pixels × seeds)`. A reference for tests and checks, not for production
/// use.
pub fn brute_force_distance(seeds: &[bool], width: usize, height: usize, wrap_x: bool) -> Vec<f32> {
    let n = width.saturating_mul(height);
    if n == 0 {
        return Vec::new();
    }
    let seeds = fit(seeds, n, false);
    let list: Vec<(usize, usize)> = seeds
        .iter()
        .enumerate()
        .filter(|(_, s)| **s)
        .map(|(i, _)| (i % width, i / width))
        .collect();
    let mut out = crate::par::filled(n, f32::INFINITY);
    if list.is_empty() {
        return out;
    }
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let best = list
                .iter()
                .map(|&(sx, sy)| dist2(x, y, sx, sy, width, wrap_x))
                .min()
                .unwrap_or(u64::MAX);
            *o = to_distance(best);
        }
    });
    out
}

/// Distance in pixels from every pixel to the nearest depth discontinuity:
/// [`laplacian`] → [`edge_mask`] at [`EDGE_QUANTILE`] → [`distance_field`]. Empty pixels get a
/// distance too; a map without edges gives `f32::INFINITY` everywhere.
pub fn border_distance(depth: &[f32], width: usize, height: usize, wrap_x: bool) -> Vec<f32> {
    let n = width.saturating_mul(height);
    let depth = fit(depth, n, f32::INFINITY);
    let lap = laplacian(&depth, width, height, wrap_x);
    let edges = edge_mask(&lap, &depth, EDGE_QUANTILE);
    distance_field(&edges, width, height, wrap_x)
}

/// `v` with exactly `n` elements: truncated, or padded with `pad`.
fn fit<T: Copy>(v: &[T], n: usize, pad: T) -> Cow<'_, [T]> {
    if v.len() == n {
        Cow::Borrowed(v)
    } else {
        let mut o = v[..v.len().min(n)].to_vec();
        o.resize(n, pad);
        Cow::Owned(o)
    }
}

/// Squared pixel distance, wrapping in x when asked (`width > 0`).
#[inline(always)]
fn dist2(x: usize, y: usize, sx: usize, sy: usize, width: usize, wrap_x: bool) -> u64 {
    let mut dx = x.abs_diff(sx);
    if wrap_x {
        dx = dx.min(width - dx);
    }
    let dx = dx as u64;
    let dy = y.abs_diff(sy) as u64;
    dx.saturating_mul(dx).saturating_add(dy.saturating_mul(dy))
}

/// `√d2` as `f32`, `∞` for "no seed".
#[inline]
fn to_distance(d2: u64) -> f32 {
    if d2 == u64::MAX {
        f32::INFINITY
    } else {
        (d2 as f64).sqrt() as f32
    }
}

#[cfg(test)]
mod tests;
