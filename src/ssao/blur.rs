//! The paper's 5×5 Gaussian smoothing of an AO map, over valid pixels only (weights
//! renormalised where neighbours are empty), wrapping in x on full-circle maps.

use crate::gbuffer::GBuffer;
use rayon::prelude::*;

/// Binomial approximation of a Gaussian with σ = 1 pixel.
const W5: [f32; 5] = [1.0, 4.0, 6.0, 4.0, 1.0];

/// Blurs `ao` (one value per pixel of `g`) with a 5×5 Gaussian restricted to valid pixels.
///
/// Every valid pixel gets `Σ w·a / Σ w` over its valid taps, summed tap by tap (rows, then
/// columns, as [`reference`] does). The taps are taken from rows padded by two pixels on each
/// side, where an empty or outside pixel holds value 0 and weight 0: adding `w·0 = +0` leaves a
/// sum unchanged (a sum that starts at `+0` never becomes `−0`), so the result is the
/// reference's bit for bit while each tap is one multiply-add across a whole row.
pub fn gaussian5(ao: &[f32], g: &GBuffer, wrap_x: bool) -> Vec<f32> {
    let (w, h) = (g.width, g.height);
    let mut out = ao.to_vec();
    let n = w.saturating_mul(h);
    if w == 0 || ao.len() != n || g.point.len() != n {
        return out;
    }
    const BAND: usize = 16;
    let pw = w + 4;
    out.par_chunks_mut(w * BAND)
        .enumerate()
        .for_each(|(band, rows)| {
            let y0 = band * BAND;
            let nr = rows.len() / w;
            // Padded value and weight rows y0 − 2 .. y0 + nr + 2 (those inside the map).
            let lo = y0.saturating_sub(2);
            let hi = (y0 + nr + 2).min(h);
            let mut val = vec![0.0f32; (hi - lo) * pw];
            let mut wgt = vec![0.0f32; (hi - lo) * pw];
            for yy in lo..hi {
                let (v, m) = (
                    &mut val[(yy - lo) * pw..][..pw],
                    &mut wgt[(yy - lo) * pw..][..pw],
                );
                for k in 0..pw {
                    let x = k as i64 - 2;
                    let x = if (0..w as i64).contains(&x) {
                        x as usize
                    } else if wrap_x {
                        x.rem_euclid(w as i64) as usize
                    } else {
                        continue;
                    };
                    let i = yy * w + x;
                    if g.is_valid(i) {
                        v[k] = ao[i];
                        m[k] = 1.0;
                    }
                }
            }
            let mut s = vec![0.0f32; w];
            let mut ws = vec![0.0f32; w];
            for r in 0..nr {
                let y = y0 + r;
                s.fill(0.0);
                ws.fill(0.0);
                for (dy, wy) in (0..5).zip(W5) {
                    let Some(yy) = (y + dy).checked_sub(2).filter(|&yy| yy < h) else {
                        continue;
                    };
                    let (v, m) = (&val[(yy - lo) * pw..][..pw], &wgt[(yy - lo) * pw..][..pw]);
                    for (dx, wx) in W5.into_iter().enumerate() {
                        let wt = wy * wx;
                        for ((s, ws), (&v, &m)) in s
                            .iter_mut()
                            .zip(ws.iter_mut())
                            .zip(v[dx..].iter().zip(&m[dx..]))
                        {
                            *s += wt * v;
                            *ws += wt * m;
                        }
                    }
                }
                let row = &mut rows[r * w..][..w];
                for (x, (o, (&s, &ws))) in row.iter_mut().zip(s.iter().zip(&ws)).enumerate() {
                    if g.is_valid(y * w + x) && ws > 0.0 {
                        *o = s / ws;
                    }
                }
            }
        });
    out
}

/// The blur as first written, one pixel and one tap at a time: the tests' reference.
#[cfg(test)]
fn reference(ao: &[f32], g: &GBuffer, wrap_x: bool) -> Vec<f32> {
    let (w, h) = (g.width as i64, g.height as i64);
    let mut out = ao.to_vec();
    if w == 0 {
        return out;
    }
    out.par_chunks_mut(g.width)
        .enumerate()
        .for_each(|(y, row)| {
            let y = y as i64;
            for x in 0..w {
                let c = (y * w + x) as usize;
                if !g.is_valid(c) {
                    continue;
                }
                let (mut s, mut ws) = (0.0f32, 0.0f32);
                for (dy, wy) in (-2..=2).zip(W5) {
                    let yy = y + dy;
                    if yy < 0 || yy >= h {
                        continue;
                    }
                    for (dx, wx) in (-2..=2).zip(W5) {
                        let mut xx = x + dx;
                        if xx < 0 || xx >= w {
                            if !wrap_x {
                                continue;
                            }
                            while xx < 0 {
                                xx += w;
                            }
                            while xx >= w {
                                xx -= w;
                            }
                        }
                        let i = (yy * w + xx) as usize;
                        if g.is_valid(i) {
                            s += wy * wx * ao[i];
                            ws += wy * wx;
                        }
                    }
                }
                if ws > 0.0 {
                    row[x as usize] = s / ws;
                }
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gbuffer::EMPTY;

    fn gb(w: usize, h: usize, mut valid: impl FnMut(usize) -> bool) -> GBuffer {
        GBuffer {
            width: w,
            height: h,
            point: (0..w * h)
                .map(|i| if valid(i) { i as u32 } else { EMPTY })
                .collect(),
            ..Default::default()
        }
    }

    #[test]
    fn constant_stays_constant_and_empty_is_ignored() {
        let g = gb(7, 5, |i| i % 3 != 0);
        let ao: Vec<f32> = (0..35)
            .map(|i| if i % 3 == 0 { 0.0 } else { 0.6 })
            .collect();
        let b = gaussian5(&ao, &g, false);
        for (i, v) in b.iter().enumerate() {
            if i % 3 != 0 {
                assert!((v - 0.6).abs() < 1e-6);
            } else {
                assert_eq!(*v, 0.0);
            }
        }
    }

    #[test]
    fn impulse_spreads_with_binomial_weights() {
        let g = gb(5, 5, |_| true);
        let mut ao = vec![0.0f32; 25];
        ao[12] = 256.0;
        let b = gaussian5(&ao, &g, false);
        assert!((b[12] - 36.0).abs() < 1e-4); // 256·6·6/256
                                              // corner pixel (0,0): sees the impulse at (+2,+2) with weight 1·1 over its 3×3 valid
                                              // window sum (6+4+1)² = 121 → 256/121
        assert!((b[0] - 256.0 / 121.0).abs() < 1e-4);
    }

    /// Wrapping by adding the width equals the modulo on every width, down to maps narrower
    /// than the kernel (where a tap wraps twice or lands on its own pixel).
    #[test]
    fn wrap_equals_the_modulo_on_narrow_maps() {
        for w in 1..8usize {
            let h = 4usize;
            let g = gb(w, h, |i| i % 5 != 3);
            let ao: Vec<f32> = (0..w * h).map(|i| (i * 7 % 11) as f32 / 10.0).collect();
            let b = gaussian5(&ao, &g, true);
            for c in (0..w * h).filter(|&c| g.is_valid(c)) {
                let (x, y) = ((c % w) as i64, (c / w) as i64);
                let (mut s, mut ws) = (0.0f32, 0.0f32);
                for (dy, wy) in (-2..=2).zip(W5) {
                    for (dx, wx) in (-2..=2).zip(W5) {
                        let yy = y + dy;
                        let i = (yy * w as i64 + (x + dx).rem_euclid(w as i64)) as usize;
                        if (0..h as i64).contains(&yy) && g.is_valid(i) {
                            s += wy * wx * ao[i];
                            ws += wy * wx;
                        }
                    }
                }
                assert_eq!(b[c], s / ws, "width {w}, pixel {c}");
            }
        }
    }

    /// The row-wise blur equals the reference bit for bit: any size, both edge rules, empty
    /// pixels holding NaN, ∞ or garbage, valid pixels holding 0, −0, subnormals and ∞.
    #[test]
    fn equals_the_reference_bit_for_bit() {
        let mut rng = crate::rng::Rng::new(7, 0);
        let mut next = || rng.next_u64();
        let special = [
            0.0,
            -0.0,
            f32::MIN_POSITIVE / 4.0,
            f32::INFINITY,
            f32::NAN,
            1e30,
        ];
        for (w, h) in [
            (1, 1),
            (1, 7),
            (2, 3),
            (3, 40),
            (4, 4),
            (5, 17),
            (37, 33),
            (64, 35),
        ] {
            for wrap in [false, true] {
                for density in [2u64, 5, 9] {
                    let g = gb(w, h, |_| next() % 10 < density);
                    let ao: Vec<f32> = (0..w * h)
                        .map(|i| {
                            let r = next();
                            if !g.is_valid(i) || r % 17 == 0 {
                                special[(r >> 8) as usize % special.len()]
                            } else {
                                (r >> 11) as f32 / (1u64 << 53) as f32
                            }
                        })
                        .collect();
                    let (a, b) = (gaussian5(&ao, &g, wrap), reference(&ao, &g, wrap));
                    for (i, (x, y)) in a.iter().zip(&b).enumerate() {
                        assert_eq!(x.to_bits(), y.to_bits(), "{w}x{h} wrap {wrap} pixel {i}");
                    }
                }
            }
        }
    }

    #[test]
    fn wraps_in_x() {
        let g = gb(6, 1, |_| true);
        let ao = vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let b = gaussian5(&ao, &g, true);
        // pixel 5 sees pixel 0 at dx=+1 (weight 4 of 16)
        assert!((b[5] - 4.0 / 16.0).abs() < 1e-6);
        let nb = gaussian5(&ao, &g, false);
        assert_eq!(nb[5], 0.0);
    }
}
