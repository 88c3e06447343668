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
mod tests {
    use super::*;

    /// SplitMix64: small deterministic PRNG for the tests.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        fn unit(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    fn random_seeds(rng: &mut Rng, n: usize, density: f64) -> Vec<bool> {
        (0..n).map(|_| rng.unit() < density).collect()
    }

    fn mismatches(a: &[f32], b: &[f32]) -> usize {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .filter(|(x, y)| !(x == y || (*x - *y).abs() <= 1e-4))
            .count()
    }

    const SIZES: [(usize, usize); 8] = [
        (1, 1),
        (1, 50),
        (50, 1),
        (2, 2),
        (37, 23),
        (23, 37),
        (64, 64),
        (200, 100),
    ];
    const DENSITIES: [f64; 4] = [0.001, 0.01, 0.1, 0.5];

    #[test]
    fn jump_flood_equals_brute_force_on_random_images() {
        let mut rng = Rng(12345);
        let mut cases = 0;
        for &(w, h) in &SIZES {
            for &density in &DENSITIES {
                for wrap in [false, true] {
                    let reps = if w * h >= 4096 { 4 } else { 12 };
                    for _ in 0..reps {
                        let seeds = random_seeds(&mut rng, w * h, density);
                        let jfa = jump_flood(&seeds, w, h, wrap);
                        let exact = brute_force_distance(&seeds, w, h, wrap);
                        let bad = mismatches(&jfa, &exact);
                        assert_eq!(bad, 0, "{w}x{h} density {density} wrap {wrap}");
                        cases += 1;
                    }
                }
            }
        }
        assert!(cases > 300);
    }

    #[test]
    fn jump_flood_single_seeds_and_wrap() {
        // A single seed anywhere: the JFA's hardest case for long distances.
        for (w, h) in [(13, 7), (64, 3), (5, 40), (100, 100)] {
            for wrap in [false, true] {
                for i in [0, w * h / 2 + 1, w * h - 1, w - 1, (h - 1) * w] {
                    let mut seeds = vec![false; w * h];
                    seeds[i] = true;
                    let jfa = jump_flood(&seeds, w, h, wrap);
                    let exact = brute_force_distance(&seeds, w, h, wrap);
                    assert_eq!(mismatches(&jfa, &exact), 0, "{w}x{h} seed {i} wrap {wrap}");
                }
            }
        }
        // Wrapping distance goes across the seam.
        let mut seeds = vec![false; 10];
        seeds[0] = true;
        let d = jump_flood(&seeds, 10, 1, true);
        assert_eq!(d, vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 4.0, 3.0, 2.0, 1.0]);
        let d = jump_flood(&seeds, 10, 1, false);
        assert_eq!(d[9], 9.0);
        let mut seeds = vec![false; 12];
        seeds[0] = true; // (0, 0) in a 4 × 3 image
        let d = jump_flood(&seeds, 4, 3, false);
        assert_eq!(d[11], 13f32.sqrt()); // (3, 2)
    }

    #[test]
    fn jump_flood_degenerate_inputs() {
        assert!(jump_flood(&[], 0, 5, false).is_empty());
        assert!(jump_flood(&[], 5, 0, true).is_empty());
        assert!(brute_force_distance(&[], 0, 0, false).is_empty());
        let d = jump_flood(&[false; 6], 3, 2, false);
        assert!(d.iter().all(|v| *v == f32::INFINITY));
        assert_eq!(jump_flood(&[true], 1, 1, true), vec![0.0]);
        assert_eq!(jump_flood(&[false], 1, 1, false), vec![f32::INFINITY]);
        // Too short a mask is padded with non-seeds.
        assert_eq!(jump_flood(&[true], 3, 1, false), vec![0.0, 1.0, 2.0]);
    }

    #[test]
    fn step_schedule() {
        assert_eq!(jfa_steps(1, 1, false, &[]), vec![1]);
        assert_eq!(
            jfa_steps(37, 23, true, &[2, 1]),
            vec![1, 32, 16, 8, 4, 2, 1, 2, 1]
        );
        assert_eq!(jfa_steps(64, 64, false, &[]), vec![32, 16, 8, 4, 2, 1]);
        assert_eq!(jfa_steps(65, 3, false, &[]), vec![64, 32, 16, 8, 4, 2, 1]);
    }

    const INF: f32 = f32::INFINITY;

    #[test]
    fn laplacian_hand_computed_3x3() {
        #[rustfmt::skip]
        let d = [
            1.0, 2.0, 3.0,
            4.0, 5.0, 6.0,
            7.0, 8.0, 9.0,
        ];
        // D_far = 18. Centre: (2-5)+(4-5)+(6-5)+(8-5) = 0.
        // (0,0): (2-1)+(4-1)+2·(18-1) = 38, / 1.  (1,0): (1-2)+(3-2)+(5-2)+(18-2) = 19, / 2.
        // (2,2): (6-9)+(8-9)+2·(18-9) = 14, / 9.
        let l = laplacian(&d, 3, 3, false);
        assert_eq!(l[4], 0.0);
        assert_eq!(l[0], 38.0);
        assert_eq!(l[1], 9.5);
        assert!((l[8] - 14.0 / 9.0).abs() < 1e-6);
        // Wrap: (0,0)'s left neighbour is (2,0) = 3: 1 + 3 + 2 + 17 = 23.
        // (2,0)'s right neighbour is (0,0) = 1: (2-3)+(1-3)+(6-3)+(18-3) = 15, / 3 = 5.
        let l = laplacian(&d, 3, 3, true);
        assert_eq!(l[0], 23.0);
        assert_eq!(l[2], 5.0);
        assert_eq!(l[4], 0.0);
        // (1,1) is unchanged by wrap; (0,1): (6-4)+(5-4)+(1-4)+(7-4) = 3, / 4.
        assert_eq!(l[3], 0.75);
    }

    #[test]
    fn laplacian_empty_neighbour() {
        #[rustfmt::skip]
        let d = [
            1.0, 2.0, 3.0,
            4.0, 5.0, INF,
            7.0, 8.0, 9.0,
        ];
        let l = laplacian(&d, 3, 3, false);
        // D_far = 18 still. Centre: (2-5)+(4-5)+(18-5)+(8-5) = 12, / 5.
        assert_eq!(l[4], 2.4);
        assert_eq!(l[5], 0.0);
        // (2,0): (2-3)+2·(18-3) (right, up outside) + (18-3) (down empty) = 44, / 3.
        assert!((l[2] - 44.0 / 3.0).abs() < 1e-6);
    }

    #[test]
    fn laplacian_4x4_wrap_and_guards() {
        // A constant ring around the panorama: with wrap the rows have no side borders.
        let mut d = vec![2.0f32; 16];
        let l = laplacian(&d, 4, 4, true);
        // Rows 1 and 2 are flat; rows 0 and 3 see the background (D_far = 4) above/below.
        assert_eq!(&l[4..12], &[0.0; 8]);
        assert_eq!(&l[0..4], &[1.0; 4]); // (4-2)/2
        let l = laplacian(&d, 4, 4, false);
        assert_eq!(l[5], 0.0);
        assert_eq!(l[4], 1.0);
        assert_eq!(l[0], 2.0);
        // Zero depth uses 1e-6 as denominator; no NaN anywhere.
        d[5] = 0.0;
        d[6] = f32::NAN;
        d[10] = f32::NEG_INFINITY;
        let l = laplacian(&d, 4, 4, false);
        assert!(l.iter().all(|v| !v.is_nan()));
        assert_eq!(l[6], 0.0);
        assert_eq!(l[10], 0.0);
        // (1,1) = 0: neighbours 2 (left, up, below) and 4 (empty right): 10 / 1e-6.
        assert!((l[5] / 1e7 - 1.0).abs() < 1e-6);
        // All empty → all zero.
        assert_eq!(laplacian(&[INF; 4], 2, 2, true), vec![0.0; 4]);
        assert!(laplacian(&[], 0, 3, false).is_empty());
    }

    #[test]
    fn nth_valid_equals_a_sort() {
        let mut rng = crate::ssao::rng::Rng::new(11, 0);
        let mut next = || rng.next_u64();
        for n in [1usize, 2, 5, 300, 70_000, 200_003] {
            for round in 0..3 {
                let lap: Vec<f32> = (0..n)
                    .map(|_| match (next() % 16, round) {
                        (0, _) => -0.0,
                        (1, _) => 0.0,
                        (2, _) => f32::INFINITY,
                        (3, 2) => -1.5,
                        // Few distinct values on round 1: ties.
                        (_, 1) => (next() % 5) as f32 * 0.25,
                        _ => f32::from_bits(next() as u32 & 0x7f7f_ffff),
                    })
                    .collect();
                let depth: Vec<f32> = (0..n).map(|i| if i % 7 == 3 { INF } else { 1.0 }).collect();
                let mut valid: Vec<f32> = lap
                    .iter()
                    .zip(&depth)
                    .filter(|(_, d)| d.is_finite())
                    .map(|(l, _)| *l)
                    .collect();
                valid.sort_by(f32::total_cmp);
                for k in [0, valid.len() / 2, valid.len() * 95 / 100, valid.len() - 1] {
                    let got = nth_valid(&lap, &depth, k);
                    assert_eq!(
                        got.to_bits(),
                        valid[k].to_bits(),
                        "n {n} round {round} k {k}"
                    );
                }
            }
        }
    }

    #[test]
    fn edge_mask_quantile_nearest_rank() {
        // Values 1..=100 in a shuffled order, plus empty pixels with huge Laplacian (ignored).
        let mut lap: Vec<f32> = (1..=100).map(|v| ((v * 37) % 100 + 1) as f32).collect();
        let mut depth = vec![1.0f32; 100];
        lap.push(1e9);
        depth.push(INF);
        let m = edge_mask(&lap, &depth, 0.95);
        // Nearest rank: τ = 95th smallest = 95, so 95..=100 are edges.
        assert_eq!(m.iter().filter(|e| **e).count(), 6);
        for (l, e) in lap.iter().zip(&m).take(100) {
            assert_eq!(*e, *l >= 95.0);
        }
        assert!(!m[100]);
        let m = edge_mask(&lap, &depth, 0.951);
        assert_eq!(m.iter().filter(|e| **e).count(), 5);
        assert_eq!(
            edge_mask(&lap, &depth, 1.0).iter().filter(|e| **e).count(),
            1
        );
        assert_eq!(
            edge_mask(&lap, &depth, 0.0).iter().filter(|e| **e).count(),
            100
        );
    }

    #[test]
    fn flat_and_empty_maps_have_no_edges() {
        let lap = vec![0.0f32; 50];
        let depth = vec![3.0f32; 50];
        assert!(edge_mask(&lap, &depth, 0.95).iter().all(|e| !e));
        assert!(edge_mask(&[5.0; 4], &[INF; 4], 0.95).iter().all(|e| !e));
        assert!(edge_mask(&[], &[], 0.95).is_empty());
        // An all-empty map has no edges, hence infinite distances.
        let d = border_distance(&[INF; 12], 4, 3, true);
        assert!(d.iter().all(|v| *v == INF));
    }

    #[test]
    fn depth_step_gives_edges_along_the_step() {
        // 64 × 64, depth 1 for x < 32 and 100 for x ≥ 32, D_far = 200.
        // L: x=31 interior 99, x=32 interior 0.99, left column 199, right column 1,
        // top/bottom rows ≥ 199 on the left half, 1 on the right half except x=32 (0.01),
        // corners 398 / 2, interior 0. 188 values ≥ 99, then 2 corners at 2: the 205 largest
        // values (nearest rank 3892 of 4096) end inside the 1s, so τ = 1.
        let (w, h) = (64usize, 64usize);
        let depth: Vec<f32> = (0..w * h)
            .map(|i| if i % w < 32 { 1.0 } else { 100.0 })
            .collect();
        let lap = laplacian(&depth, w, h, false);
        assert!((lap[10 * w + 31] - 99.0).abs() < 1e-4);
        assert!((lap[10 * w + 32] - 0.99).abs() < 1e-6);
        let edges = edge_mask(&lap, &depth, 0.95);
        for y in 0..h {
            for x in 0..w {
                let want = x == 0 || x == 31 || x == 63 || ((y == 0 || y == 63) && x != 32);
                assert_eq!(edges[y * w + x], want, "({x}, {y})");
            }
        }
        let dist = border_distance(&depth, w, h, false);
        for y in 0..h {
            for x in 0..w {
                let want = if x == 32 && (y == 0 || y == 63) {
                    1.0 // the gap in the top/bottom edge rows is next to column 31
                } else {
                    x.min(x.abs_diff(31)).min(63 - x).min(y).min(63 - y) as f32
                };
                assert_eq!(dist[y * w + x], want, "({x}, {y})");
            }
        }
    }

    /// Error rates of JFA variants against brute force (run with `--release -- --ignored
    /// --nocapture`): the fixed suite of the exactness test plus 512 × 256, then a stress suite
    /// of random sizes up to 160 × 160 with sparse seeds (the hard case).
    #[test]
    #[ignore]
    fn jfa_variant_error_rates() {
        type Schedule = fn(usize, usize) -> Vec<usize>;
        const VARIANTS: [(&str, Schedule); 7] = [
            ("JFA", |w, h| jfa_steps(w, h, false, &[])),
            ("1+JFA", |w, h| jfa_steps(w, h, true, &[])),
            ("JFA+1", |w, h| jfa_steps(w, h, false, &[1])),
            ("JFA+2", |w, h| jfa_steps(w, h, false, &[2, 1])),
            ("1+JFA+2", |w, h| jfa_steps(w, h, true, &[2, 1])),
            ("1+JFA+3", |w, h| jfa_steps(w, h, true, &[4, 2, 1])),
            ("1+JFA+JFA", |w, h| {
                let mut s = jfa_steps(w, h, true, &[]);
                s.extend(jfa_steps(w, h, false, &[]));
                s
            }),
        ];
        // Per variant: wrong pixels, wrong images, largest error.
        type Stats = [(usize, usize, f32); VARIANTS.len()];
        fn run(stats: &mut Stats, seeds: &[bool], w: usize, h: usize, wrap: bool) {
            let exact = brute_force_distance(seeds, w, h, wrap);
            for (st, (_, schedule)) in stats.iter_mut().zip(VARIANTS) {
                let jfa = flood_with_steps(seeds, w, h, wrap, &schedule(w, h));
                let bad = mismatches(&jfa, &exact);
                st.0 += bad;
                st.1 += usize::from(bad > 0);
                for (a, b) in jfa.iter().zip(&exact) {
                    if a.is_finite() && b.is_finite() {
                        st.2 = st.2.max(a - b);
                    }
                }
            }
        }
        fn report(title: &str, stats: &Stats, pixels: usize, images: usize) {
            println!("{title}: {images} images, {pixels} pixels");
            for ((name, _), (bad, bad_img, max)) in VARIANTS.iter().zip(stats) {
                println!(
                    "  {name:12} {bad:6} wrong pixels ({:.1e}), {bad_img:4} images, \
                     max error {max:.3} px",
                    *bad as f64 / pixels as f64
                );
            }
        }

        let mut rng = Rng(777);
        let mut stats: Stats = [(0, 0, 0.0); VARIANTS.len()];
        let (mut pixels, mut images) = (0, 0);
        let mut sizes = SIZES.to_vec();
        sizes.push((512, 256));
        for &(w, h) in &sizes {
            for &density in &[0.0002, 0.001, 0.01, 0.1, 0.5] {
                let n = (w * h) as f64;
                if n * n * density > 5e8 {
                    continue; // brute force too slow
                }
                for wrap in [false, true] {
                    let reps = if w * h > 20_000 { 3 } else { 20 };
                    for _ in 0..reps {
                        let seeds = random_seeds(&mut rng, w * h, density);
                        run(&mut stats, &seeds, w, h, wrap);
                        pixels += w * h;
                        images += 1;
                    }
                }
            }
        }
        report("fixed suite", &stats, pixels, images);

        let mut stats: Stats = [(0, 0, 0.0); VARIANTS.len()];
        let (mut pixels, mut images) = (0, 0);
        for i in 0..20_000 {
            let w = 1 + (rng.next() % 160) as usize;
            let h = 1 + (rng.next() % 160) as usize;
            let density = [0.0005, 0.001, 0.002, 0.004, 0.01, 0.05][i % 6];
            let seeds = random_seeds(&mut rng, w * h, density);
            run(&mut stats, &seeds, w, h, i % 2 == 0);
            pixels += w * h;
            images += 1;
        }
        report("stress suite", &stats, pixels, images);
    }

    /// Timing of `border_distance` on a 4096 × 2048 panorama (run with `--ignored --nocapture`).
    #[test]
    #[ignore]
    fn border_distance_timing_4k() {
        let (w, h) = (4096usize, 2048usize);
        let mut depth = vec![INF; w * h];
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
                if v < 0.15 {
                    continue; // sky
                }
                let mut d = 8.0 + 3.0 * (u * std::f32::consts::TAU).sin() + 4.0 * v;
                if (0.2..0.3).contains(&u) && v > 0.5 {
                    d = 3.0; // a box
                }
                if ((u - 0.7).powi(2) + (v - 0.6).powi(2)) < 0.01 {
                    d = 2.0; // a pillar
                }
                depth[y * w + x] = d;
            }
        }
        // Minimum of a few runs: the machine may be shared.
        fn best<T>(mut f: impl FnMut() -> T) -> (T, std::time::Duration) {
            let mut out = None;
            let mut best = std::time::Duration::MAX;
            for _ in 0..5 {
                let t = std::time::Instant::now();
                let v = f();
                best = best.min(t.elapsed());
                out = Some(v);
            }
            (out.unwrap(), best)
        }
        let (lap, t_lap) = best(|| laplacian(&depth, w, h, true));
        let (edges, t_mask) = best(|| edge_mask(&lap, &depth, EDGE_QUANTILE));
        let (dist, t_jfa) = best(|| jump_flood(&edges, w, h, true));
        let (total, t_total) = best(|| border_distance(&depth, w, h, true));
        assert_eq!(dist, total);
        println!(
            "{w}x{h} on {} threads (best of 5): laplacian {t_lap:?}, edge_mask {t_mask:?} \
             ({} edges), jump_flood {t_jfa:?}; border_distance {t_total:?}",
            rayon::current_num_threads(),
            edges.iter().filter(|e| **e).count()
        );
    }
}
