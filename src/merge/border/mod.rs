//! Depth-discontinuity distance field for the multi-view merge. This module owns the border
//! term's inputs: the relative Laplacian of a scan's depth map, the edge mask (Laplacian above
//! its 0.95 quantile) and, for every pixel, the Euclidean pixel distance `d_b` to the nearest
//! edge, computed by jump flooding (Rong & Tan 2006) with extra passes that make it exact in
//! practice. Depth maps are row-major `width × height` `f32`; empty pixels are non-finite
//! (normally `f32::INFINITY`). With `wrap_x` the map is a 360° panorama whose left and right
//! columns are neighbours.

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

/// Euclidean distance in pixels from every pixel to the nearest seed, by jump flooding.
///
/// The distance between pixels `(x, y)` and `(sx, sy)` is `√(dx² + dy²)` with `dy = |y − sy|` and
/// `dx = |x − sx|`, or `min(dx, width − dx)` with `wrap_x`. Schedule "1+JFA+3": one pass with
/// step 1, the standard passes with steps `k, k/2, …, 1` (`k` the smallest power of two
/// `≥ max(width, height)/2`), then three more with steps 4, 2 and 1 (16 passes for 4096 × 2048).
/// Each pass looks at the 3×3 neighbourhood at the step and keeps the nearest seed, in parallel
/// over rows, ping-ponging two buffers of packed seed coordinates. The result equals
/// [`brute_force_distance`] at every pixel of the test suite; on a stress run of random sparse
/// images (see the ignored test `jfa_variant_error_rates`) about 2·10⁻⁸ of the pixels came out
/// slightly too far (by less than 1 px), the known residual of jump flooding. No seeds → every pixel is `f32::INFINITY`; an empty image gives an empty
/// vector. A `seeds` slice of the wrong length is truncated or padded with non-seeds.
pub fn jump_flood(seeds: &[bool], width: usize, height: usize, wrap_x: bool) -> Vec<f32> {
    flood_with_steps(
        seeds,
        width,
        height,
        wrap_x,
        &jfa_steps(width, height, true, &[4, 2, 1]),
    )
}

/// Exact distance to the nearest seed (same metric as [`jump_flood`]) by comparing every pixel
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
/// [`laplacian`] → [`edge_mask`] at [`EDGE_QUANTILE`] → [`jump_flood`]. Empty pixels get a
/// distance too; a map without edges gives `f32::INFINITY` everywhere.
pub fn border_distance(depth: &[f32], width: usize, height: usize, wrap_x: bool) -> Vec<f32> {
    let n = width.saturating_mul(height);
    let depth = fit(depth, n, f32::INFINITY);
    let lap = laplacian(&depth, width, height, wrap_x);
    let edges = edge_mask(&lap, &depth, EDGE_QUANTILE);
    jump_flood(&edges, width, height, wrap_x)
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

/// The step sequence: optionally a leading step-1 pass, the halving steps from the smallest
/// power of two `≥ ⌈max(width, height)/2⌉` down to 1, then `post`.
fn jfa_steps(width: usize, height: usize, pre: bool, post: &[usize]) -> Vec<usize> {
    let half = width.max(height).div_ceil(2).max(1);
    let mut k = half
        .checked_next_power_of_two()
        .unwrap_or(1 << (usize::BITS - 1));
    let mut steps = Vec::new();
    if pre {
        steps.push(1);
    }
    while k >= 1 {
        steps.push(k);
        k /= 2;
    }
    steps.extend_from_slice(post);
    steps
}

/// A pixel's nearest-seed coordinates packed into one word; `NONE` means "no seed yet".
trait Cell: Copy + Eq + Send + Sync {
    /// Squared distance type.
    type D: Copy + Ord + Send;
    const NONE: Self;
    const FAR: Self::D;
    fn pack(x: usize, y: usize) -> Self;
    fn unpack(self) -> (usize, usize);
    /// Squared distance from pixel `(x, y)` to this seed, `FAR` for `NONE`.
    fn dist2(self, x: usize, y: usize, width: usize, wrap_x: bool) -> Self::D;
    /// [`relax`]: pixels `x0, x0 + 1, …` of row `y` against the candidates `cand`.
    #[inline(always)]
    fn relax_run(
        best: &mut [Self],
        best_d: &mut [Self::D],
        cand: &[Self],
        x0: usize,
        y: usize,
        width: usize,
        wrap_x: bool,
    ) {
        relax(best, best_d, cand, x0, y, width, wrap_x);
    }
}

/// 16 + 16 bits, for images up to 32767 × 32767, so that `NONE` is never a real pixel and
/// squared distances (at most 2 · 32767² < 2³¹) fit signed 32-bit arithmetic, which vectorises
/// with the baseline x86-64 instructions (signed compares; `dx² + dy²` as one multiply-add of
/// the packed 16-bit halves).
impl Cell for u32 {
    type D = i32;
    const NONE: Self = u32::MAX;
    const FAR: i32 = i32::MAX;
    #[inline(always)]
    fn pack(x: usize, y: usize) -> Self {
        ((x as u32) << 16) | y as u32
    }
    #[inline(always)]
    fn unpack(self) -> (usize, usize) {
        ((self >> 16) as usize, (self & 0xFFFF) as usize)
    }
    #[inline(always)]
    fn dist2(self, x: usize, y: usize, width: usize, wrap_x: bool) -> i32 {
        // Real coordinates are below 2^15, so nothing here can overflow; `NONE` gives
        // garbage that is replaced below.
        let sx = (self >> 16) as i32;
        let sy = (self & 0xFFFF) as i32;
        let mut dx = (x as i32).wrapping_sub(sx).wrapping_abs();
        if wrap_x {
            dx = dx.min((width as i32).wrapping_sub(dx));
        }
        let dy = (y as i32).wrapping_sub(sy);
        let d = dx.wrapping_mul(dx).wrapping_add(dy.wrapping_mul(dy));
        if self == Self::NONE {
            i32::MAX
        } else {
            d
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn relax_run(
        best: &mut [u32],
        best_d: &mut [i32],
        cand: &[u32],
        x0: usize,
        y: usize,
        width: usize,
        wrap_x: bool,
    ) {
        let n = best.len().min(best_d.len()).min(cand.len());
        let done = relax_sse2(
            &mut best[..n],
            &mut best_d[..n],
            &cand[..n],
            x0,
            y,
            width,
            wrap_x,
        );
        relax(
            &mut best[done..n],
            &mut best_d[done..n],
            &cand[done..n],
            x0 + done,
            y,
            width,
            wrap_x,
        );
    }
}

/// [`relax`] on four `u32` cells at a time with SSE2 (part of every x86-64 CPU): the pixel's
/// and the seed's packed coordinates are subtracted as 16-bit lanes, giving `(dy, dx)` in each
/// 32-bit lane, and `pmaddwd` squares and sums them exactly (`|dx|, |dy| ≤ 32767`). Same
/// distances, ties and results as the scalar loop. Returns how many leading pixels it relaxed
/// (a multiple of 4); the caller finishes the rest.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn relax_sse2(
    best: &mut [u32],
    best_d: &mut [i32],
    cand: &[u32],
    x0: usize,
    y: usize,
    width: usize,
    wrap_x: bool,
) -> usize {
    use std::arch::x86_64::*;
    let chunks = best.len().min(best_d.len()).min(cand.len()) / 4;
    if chunks == 0 {
        return 0;
    }
    // SAFETY: SSE2 is in the x86-64 baseline; every load and store is of four elements at
    // offset 4k with k < chunks, inside all three slices (unaligned accesses).
    unsafe {
        let mut pix = _mm_add_epi32(
            _mm_set1_epi32(<u32 as Cell>::pack(x0, y) as i32),
            _mm_setr_epi32(0, 1 << 16, 2 << 16, 3 << 16),
        );
        let step = _mm_set1_epi32(4 << 16);
        let none = _mm_set1_epi32(-1);
        let far = _mm_set1_epi32(i32::MAX);
        let zero = _mm_setzero_si128();
        // The width in the x half of each lane, and a mask selecting that half.
        let wv = _mm_set1_epi32((width as i32) << 16);
        let x_half = _mm_set1_epi32(0xFFFF_0000u32 as i32);
        let select = |m: __m128i, a: __m128i, b: __m128i| {
            _mm_or_si128(_mm_and_si128(m, a), _mm_andnot_si128(m, b))
        };
        for k in 0..chunks {
            let c = _mm_loadu_si128(cand.as_ptr().add(4 * k).cast());
            let d = _mm_sub_epi16(pix, c);
            let mut a = _mm_max_epi16(d, _mm_sub_epi16(zero, d));
            if wrap_x {
                let short = _mm_min_epi16(a, _mm_sub_epi16(wv, a));
                a = select(x_half, short, a);
            }
            let d2 = select(_mm_cmpeq_epi32(c, none), far, _mm_madd_epi16(a, a));
            let bd_ptr = best_d.as_mut_ptr().add(4 * k).cast::<__m128i>();
            let b_ptr = best.as_mut_ptr().add(4 * k).cast::<__m128i>();
            let old = _mm_loadu_si128(bd_ptr);
            let nearer = _mm_cmpgt_epi32(old, d2);
            _mm_storeu_si128(b_ptr, select(nearer, c, _mm_loadu_si128(b_ptr)));
            _mm_storeu_si128(bd_ptr, select(nearer, d2, old));
            pix = _mm_add_epi32(pix, step);
        }
    }
    4 * chunks
}

/// 32 + 32 bits, for larger images.
impl Cell for u64 {
    type D = u64;
    const NONE: Self = u64::MAX;
    const FAR: u64 = u64::MAX;
    #[inline(always)]
    fn pack(x: usize, y: usize) -> Self {
        ((x as u64) << 32) | y as u64
    }
    #[inline(always)]
    fn unpack(self) -> (usize, usize) {
        ((self >> 32) as usize, (self & 0xFFFF_FFFF) as usize)
    }
    #[inline(always)]
    fn dist2(self, x: usize, y: usize, width: usize, wrap_x: bool) -> u64 {
        if self == Self::NONE {
            return u64::MAX;
        }
        let (sx, sy) = self.unpack();
        dist2(x, y, sx, sy, width, wrap_x)
    }
}

/// Jump flooding with an explicit step sequence (see [`jump_flood`]).
fn flood_with_steps(
    seeds: &[bool],
    width: usize,
    height: usize,
    wrap_x: bool,
    steps: &[usize],
) -> Vec<f32> {
    let n = width.saturating_mul(height);
    if n == 0 {
        return Vec::new();
    }
    let seeds = fit(seeds, n, false);
    if !seeds.iter().any(|&s| s) {
        return vec![f32::INFINITY; n];
    }
    if width < 0x8000 && height < 0x8000 {
        flood::<u32>(&seeds, width, height, wrap_x, steps)
    } else if (width as u64) < u64::from(u32::MAX) && (height as u64) < u64::from(u32::MAX) {
        flood::<u64>(&seeds, width, height, wrap_x, steps)
    } else {
        brute_force_distance(&seeds, width, height, wrap_x)
    }
}

/// Jump flooding with seed coordinates packed in `C`; `seeds` has `width × height` values.
fn flood<C: Cell>(
    seeds: &[bool],
    width: usize,
    height: usize,
    wrap_x: bool,
    steps: &[usize],
) -> Vec<f32> {
    let mut a: Vec<C> = crate::par::filled(width * height, C::NONE);
    a.par_chunks_mut(width)
        .zip(seeds.par_chunks(width))
        .enumerate()
        .for_each(|(y, (row, s))| {
            for (x, (c, &s)) in row.iter_mut().zip(s).enumerate() {
                if s {
                    *c = C::pack(x, y);
                }
            }
        });
    let mut b: Vec<C> = crate::par::filled(width * height, C::NONE);
    for &k in steps {
        jfa_pass(&a, &mut b, width, height, k, wrap_x);
        std::mem::swap(&mut a, &mut b);
    }
    let mut out = crate::par::filled(width * height, f32::INFINITY);
    out.par_chunks_mut(width)
        .zip(a.par_chunks(width))
        .enumerate()
        .for_each(|(y, (o, cells))| {
            for (x, (o, &c)) in o.iter_mut().zip(cells).enumerate() {
                if c != C::NONE {
                    let (sx, sy) = c.unpack();
                    *o = to_distance(dist2(x, y, sx, sy, width, wrap_x));
                }
            }
        });
    out
}

/// One jump-flooding pass with step `k`: every pixel keeps the nearest of the seeds recorded
/// at itself and at its 8 neighbours `k` pixels away. Each output row is relaxed against the
/// (up to) three source rows, each shifted by `−k`, `0` and `+k` in contiguous runs, so the
/// inner loops have no bounds checks or wrap branches.
fn jfa_pass<C: Cell>(
    src: &[C],
    dst: &mut [C],
    width: usize,
    height: usize,
    k: usize,
    wrap_x: bool,
) {
    // (first output column, first source column, run length) for the shifted reads.
    let mut runs: Vec<(usize, usize, usize)> = vec![(0, 0, width)];
    if wrap_x {
        let kx = k % width;
        if kx != 0 {
            runs.push((kx, 0, width - kx)); // reads x − k
            runs.push((0, width - kx, kx));
            runs.push((0, kx, width - kx)); // reads x + k
            runs.push((width - kx, 0, kx));
        }
    } else if k < width {
        runs.push((k, 0, width - k));
        runs.push((0, k, width - k));
    }
    let runs = &runs[..];
    dst.par_chunks_mut(width)
        .enumerate()
        .with_min_len(ROWS_PER_TASK)
        .for_each_init(
            || vec![C::FAR; width],
            |best_d, (y, row)| {
                row.fill(C::NONE);
                best_d.fill(C::FAR);
                let rows = [
                    y.checked_sub(k),
                    Some(y),
                    y.checked_add(k).filter(|&v| v < height),
                ];
                for ny in rows.into_iter().flatten() {
                    let srow = &src[ny * width..(ny + 1) * width];
                    for &(x0, s0, len) in runs {
                        C::relax_run(
                            &mut row[x0..x0 + len],
                            &mut best_d[x0..x0 + len],
                            &srow[s0..s0 + len],
                            x0,
                            y,
                            width,
                            wrap_x,
                        );
                    }
                }
            },
        );
}

/// Relaxes pixels `x0, x0 + 1, …` of row `y` against the candidate seeds `cand`.
#[inline(always)]
fn relax<C: Cell>(
    best: &mut [C],
    best_d: &mut [C::D],
    cand: &[C],
    x0: usize,
    y: usize,
    width: usize,
    wrap_x: bool,
) {
    for (i, ((b, bd), &c)) in best.iter_mut().zip(best_d.iter_mut()).zip(cand).enumerate() {
        // Branch-free selects and unconditional stores so the loop vectorises.
        let d = c.dist2(x0 + i, y, width, wrap_x);
        let old = *bd;
        *b = if d < old { c } else { *b };
        *bd = old.min(d);
    }
}

#[cfg(test)]
mod tests;
