//! The default SSAO radius: a formula of the scene's size and its point spacing, so that it
//! holds from a figurine to a building. Computes nothing per pixel and reads no file.
//!
//! `r_s = sqrt(s · D)`, clamped to `[D/100, D/10]`, where `D` is the robust scene diagonal
//! (1st–99th percentile box along the points' principal axes) and `s` the point spacing (the
//! median over the scans, weighted by their point counts, of each scan's median spacing
//! `d_8 · sqrt(π/8)`, `d_8` = distance to the 8th nearest neighbour: the side of the square
//! each point covers on the surface).
//!
//! Why the geometric mean: the radius must span many point spacings, or the estimator sees
//! only noise and the surface's own tilt, and be a small part of the scene, or everything
//! shades alike. The geometric mean sits halfway between the two scales on a log axis, and it
//! scales with the scene: a copy scaled by `k` gets `k·r_s` and the same AO. A room of
//! `D` = 10 m scanned at 5 mm gets 0.22 m (the paper's rooms used 0.2 m); the Stanford bunny
//! (`D` = 0.24 m, spacing about 0.7 mm) gets about 13 mm, where `D/50` gave 4.9 mm and
//! almost no shading. The clamp keeps a very dense or very sparse scan from an extreme value.

use crate::rng::splitmix64;
use crate::scan::Scan;
use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use std::num::NonZeroUsize;

/// Neighbours per spacing estimate (the point itself not counted).
const K: usize = 8;

/// Points per scan the spacing is measured on; a larger scan is subsampled and the result
/// corrected for the sampling density.
const SAMPLE: usize = 16_384;

/// The smallest and largest default radius, as a fraction of the scene diagonal.
const MIN_FRACTION: f64 = 1.0 / 100.0;
/// See [`MIN_FRACTION`].
const MAX_FRACTION: f64 = 1.0 / 10.0;

/// The two lengths the default radius comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneScale {
    /// Robust scene diagonal `D` (metres).
    pub diagonal: f64,
    /// Point spacing `s` (metres); 0 when unknown (then `D/50`, the former default).
    pub spacing: f64,
}

impl SceneScale {
    /// The default radius `clamp(sqrt(s·D), D/100, D/10)` (`D/50` without a spacing), with a
    /// note on how it was derived. `None` when the result is not a positive finite `f32`.
    pub fn default_radius(&self) -> Option<(f32, String)> {
        let (d, s) = (self.diagonal, self.spacing);
        if !(d > 0.0 && d.is_finite()) {
            return None;
        }
        let (r, note) = if s > 0.0 && s.is_finite() {
            let g = (s * d).sqrt();
            let r = g.clamp(d * MIN_FRACTION, d * MAX_FRACTION);
            let how = if r == g {
                String::new()
            } else if r > g {
                " (raised to D/100)".into()
            } else {
                " (lowered to D/10)".into()
            };
            (
                r,
                format!(
                    "radius = sqrt(spacing {s:.5} m × scene diagonal {d:.4} m) = {r:.4} m{how}; "
                ),
            )
        } else {
            let r = d / 50.0;
            (
                r,
                format!("radius = scene diagonal {d:.4} m / 50 = {r:.4} m; "),
            )
        };
        let r32 = r as f32;
        (r32 > 0.0 && r32.is_finite()).then_some((r32, note))
    }
}

/// The point spacing of one scan's local points (metres): the median of `d_8·sqrt(π/8)` over
/// a sample of at most [`SAMPLE`] points, measured within the sample and scaled by the square
/// root of the sampled share (density on a surface goes with the number of points). The
/// sample is picked by a hash of the point's coordinates, not every n-th point, so the rows
/// of a gridded scan do not alias with it and the order of the points changes nothing. 0 for
/// fewer than `K + 1` points.
pub fn scan_spacing(points: &[Vec3]) -> f64 {
    let n = points.len();
    if n <= K {
        return 0.0;
    }
    let sample: Vec<[f32; 3]> = if n <= SAMPLE {
        points.iter().map(|p| p.to_array()).collect()
    } else {
        let keep = (SAMPLE as f64 / n as f64 * u64::MAX as f64) as u64;
        points
            .iter()
            .filter(|p| splitmix64(key(**p)) < keep)
            .map(|p| p.to_array())
            .collect()
    };
    let m = sample.len();
    if m <= K {
        return 0.0;
    }
    let tree = ImmutableKdTree::<f32, 3>::new_from_slice(&sample);
    let kq = NonZeroUsize::new(K + 1).unwrap_or(NonZeroUsize::MIN);
    let mut dk: Vec<f64> = sample
        .par_iter()
        .filter_map(|p| {
            let nb = tree.nearest_n::<SquaredEuclidean>(p, kq);
            let d = f64::from(nb.last()?.distance).sqrt();
            d.is_finite().then_some(d)
        })
        .collect();
    if dk.is_empty() {
        return 0.0;
    }
    let mid = dk.len() / 2;
    let (_, med, _) = dk.select_nth_unstable_by(mid, f64::total_cmp);
    *med * (std::f64::consts::PI / K as f64).sqrt() * (m as f64 / n as f64).sqrt()
}

/// The spacing of a set of scans from each one's spacing and point count: the median
/// weighted by the counts (scans with no spacing left out); 0 when none has one.
pub fn combined_spacing(per_scan: &[(f64, usize)]) -> f64 {
    let mut v: Vec<(f64, usize)> = per_scan
        .iter()
        .copied()
        .filter(|(s, n)| *s > 0.0 && s.is_finite() && *n > 0)
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: usize = v.iter().map(|x| x.1).sum();
    let mut acc = 0;
    for (s, n) in &v {
        acc += n;
        if 2 * acc >= total {
            return *s;
        }
    }
    0.0
}

/// The spacing of in-memory scans ([`scan_spacing`] of each, [`combined_spacing`]).
pub fn spacing_of(scans: &[Scan]) -> f64 {
    let per: Vec<(f64, usize)> = scans
        .iter()
        .map(|s| (scan_spacing(&s.points), s.len()))
        .collect();
    combined_spacing(&per)
}

/// The bits of a point's coordinates folded into one word.
fn key(p: Vec3) -> u64 {
    let [x, y, z] = p.to_array().map(|c| u64::from(c.to_bits()));
    x ^ y.rotate_left(21) ^ z.rotate_left(42)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square grid of `side × side` points `step` apart in the plane z = 0.
    fn grid(side: usize, step: f32) -> Vec<Vec3> {
        (0..side * side)
            .map(|i| Vec3::new((i % side) as f32 * step, (i / side) as f32 * step, 0.0))
            .collect()
    }

    /// On a regular grid the 8th neighbour is at √2·step: spacing √2·√(π/8) ≈ 0.886 step,
    /// whether measured on every point or on a hashed sample of a larger grid.
    #[test]
    fn spacing_of_a_grid() {
        let s = scan_spacing(&grid(100, 0.01));
        assert!((s - 0.00886).abs() < 1e-4, "{s}");
        // 250 000 points: a sample of about 16 000, corrected by √(m/n). The sample is
        // random-like, so within 15 % of the grid's own answer, not exact.
        let s = scan_spacing(&grid(500, 0.002));
        assert!((s / 0.001772 - 1.0).abs() < 0.15, "{s}");
        assert_eq!(scan_spacing(&grid(2, 1.0)), 0.0);
    }

    /// The order of the points does not change the spacing.
    #[test]
    fn order_free() {
        let mut g = grid(300, 0.01);
        let a = scan_spacing(&g);
        g.reverse();
        g.swap(10, 20_000);
        assert_eq!(scan_spacing(&g), a);
    }

    /// The weighted median follows the scans with most points; scans without a spacing do
    /// not count.
    #[test]
    fn combined() {
        assert_eq!(combined_spacing(&[(1.0, 10), (2.0, 30), (0.0, 100)]), 2.0);
        assert_eq!(combined_spacing(&[(1.0, 30), (2.0, 10)]), 1.0);
        assert_eq!(combined_spacing(&[]), 0.0);
    }

    /// The formula, its clamps and its scale covariance.
    #[test]
    fn formula() {
        let r = |d: f64, s: f64| {
            SceneScale {
                diagonal: d,
                spacing: s,
            }
            .default_radius()
        };
        let (a, note) = r(10.0, 0.005).unwrap();
        assert!(
            (a - 0.2236).abs() < 1e-4 && note.contains("sqrt"),
            "{a} {note}"
        );
        // Scaled by 150: radius × 150.
        let (b, _) = r(1500.0, 0.75).unwrap();
        assert!((b / a - 150.0).abs() < 1e-3);
        // A very fine spacing: D/100; a very coarse one: D/10.
        assert_eq!(r(10.0, 1e-6).unwrap().0, 0.1);
        assert_eq!(r(10.0, 5.0).unwrap().0, 1.0);
        // No spacing: the diagonal alone.
        assert_eq!(r(10.0, 0.0).unwrap().0, 0.2);
        assert!(r(0.0, 0.0).is_none());
        assert!(r(f64::NAN, 0.01).is_none());
    }
}
