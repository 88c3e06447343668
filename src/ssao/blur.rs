//! The paper's 5×5 Gaussian smoothing of an AO map, over valid pixels only (weights
//! renormalised where neighbours are empty), wrapping in x on full-circle maps.

use crate::gbuffer::GBuffer;
use rayon::prelude::*;

/// Binomial approximation of a Gaussian with σ = 1 pixel.
const W5: [f32; 5] = [1.0, 4.0, 6.0, 4.0, 1.0];

/// Blurs `ao` (one value per pixel of `g`) with a 5×5 Gaussian restricted to valid pixels.
pub fn gaussian5(ao: &[f32], g: &GBuffer, wrap_x: bool) -> Vec<f32> {
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
                            // Taps reach 2 pixels past an edge: a wrap or two, no division.
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

    fn gb(w: usize, h: usize, valid: impl Fn(usize) -> bool) -> GBuffer {
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
