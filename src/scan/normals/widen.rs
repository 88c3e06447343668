//! Normals of neighbourhoods narrower than the scan's noise, fitted again over more neighbours.
//!
//! The 16 nearest neighbours define a plane only when they spread across it by more than the
//! range noise lifts them off it. Where a scanner samples more densely than its noise (close to
//! the sensor, around an equirectangular scan's poles) the 16 nearest lie along a few
//! millimetres of one scan line, and the fitted normal points anywhere across that line: on
//! synthetic stations with 2 mm of noise, the floor points within 5 cm of a station's foot had
//! normals a median 70° off.

use super::{kd_tree, pca_fit, Fit};
use glam::Vec3;
use kiddo::SquaredEuclidean;
use rayon::prelude::*;
use std::num::NonZeroUsize;

/// A neighbourhood is a plane when its variance along its narrower tangent direction is at
/// least this multiple of the scan's noise variance (a spread of 4 σ).
const PLANE_OVER_NOISE: f32 = 16.0;
/// Neighbour counts tried in turn for a point whose nearest neighbours span no plane.
const WIDER: [usize; 3] = [64, 128, 256];
/// Largest share of a scan's points fitted again. The noise is measured over all the points'
/// neighbourhoods; when most of them are narrower than it, the measure no longer describes
/// surfaces and the scan keeps its 16-neighbour normals.
const MAX_SHARE: f64 = 0.5;

/// The normals of `fits`, those whose neighbourhood is narrower than the noise fitted again
/// over the smallest of [`WIDER`] nearest neighbours that spans a plane (else the widest).
pub(super) fn widen<F>(points: &[Vec3], fits: &[Fit], toward: &F) -> Vec<Vec3>
where
    F: Fn(Vec3) -> Vec3 + Sync,
{
    let mut normals: Vec<Vec3> = fits.par_iter().map(|f| f.0).collect();
    let noise = noise_variance(fits);
    if !(noise > 0.0) || points.len() <= WIDER[0] {
        return normals;
    }
    let floor = PLANE_OVER_NOISE * noise;
    let narrow: Vec<u32> = fits
        .par_iter()
        .enumerate()
        .filter(|(_, f)| f.1[1] < floor)
        .map(|(i, _)| i as u32)
        .collect();
    if narrow.is_empty() || narrow.len() as f64 > MAX_SHARE * points.len() as f64 {
        return normals;
    }
    let tree = kd_tree(points);
    let refit: Vec<Vec3> = narrow
        .par_iter()
        .map(|&i| {
            let p = points[i as usize];
            let mut n = normals[i as usize];
            for k in WIDER {
                let k = NonZeroUsize::new(k.min(points.len())).unwrap_or(NonZeroUsize::MIN);
                let nb = tree.nearest_n::<SquaredEuclidean>(&p.to_array(), k);
                let (m, spread) = pca_fit(nb.iter().map(|x| points[x.item as usize]), toward(p));
                n = m;
                if spread[1] >= floor {
                    break;
                }
            }
            n
        })
        .collect();
    for (&i, n) in narrow.iter().zip(refit) {
        normals[i as usize] = n;
    }
    normals
}

/// The scan's noise variance along the normal: the median over the points of their
/// neighbourhood's variance along its normal (on smooth surfaces sampled finer than they bend,
/// that is the noise; noise-free scans give about zero, and nothing is fitted again).
fn noise_variance(fits: &[Fit]) -> f32 {
    let step = (fits.len() / 65_536).max(1);
    let mut v: Vec<f32> = fits
        .iter()
        .step_by(step)
        .filter(|f| f.1[1] > 0.0)
        .map(|f| f.1[0])
        .collect();
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f32::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::super::{estimate, estimate_fits};
    use crate::rng::SplitMix64;
    use glam::Vec3;

    /// A noisy floor (2 cm grid, σ 1 mm) with a scan line along it sampled every 0.2 mm, as
    /// a scanner samples the floor at its own foot: the line's 16 nearest neighbours span
    /// 3 mm along it and nothing across.
    fn floor_with_dense_line() -> (Vec<Vec3>, std::ops::Range<usize>) {
        let mut rng = SplitMix64::new(7, 0);
        let mut noise = || (rng.gaussian() * 0.001) as f32;
        let mut pts: Vec<Vec3> = (0..80 * 80)
            .map(|i| Vec3::new((i % 80) as f32 * 0.02, (i / 80) as f32 * 0.02, noise()))
            .collect();
        let start = pts.len();
        pts.extend((0..400).map(|i| Vec3::new(0.4 + i as f32 * 0.0002, 0.81, noise())));
        (pts, start..start + 400)
    }

    fn median_angle_deg(normals: &[Vec3]) -> f32 {
        let mut a: Vec<f32> = normals
            .iter()
            .map(|n| n.dot(Vec3::Z).clamp(-1.0, 1.0).acos().to_degrees())
            .collect();
        a.sort_by(f32::total_cmp);
        a[a.len() / 2]
    }

    #[test]
    fn a_line_denser_than_the_noise_gets_the_floor_normal() {
        let (pts, line) = floor_with_dense_line();
        let toward = |p: Vec3| Vec3::new(0.0, 0.0, 1.5) - p;
        let (fits, _) = estimate_fits(&pts, true, toward);
        let fits = fits.unwrap();
        let before: Vec<Vec3> = fits[line.clone()].iter().map(|f| f.0).collect();
        assert!(
            median_angle_deg(&before) > 30.0,
            "{}",
            median_angle_deg(&before)
        );
        let (normals, _) = estimate(&pts, true, toward);
        let normals = normals.unwrap();
        assert!(median_angle_deg(&normals[line.clone()]) < 5.0);
        // Floor points away from the line keep the normal their 16 nearest give them.
        let changed = (0..line.start)
            .filter(|&i| (pts[i].y - 0.81).abs() > 0.05 && normals[i] != fits[i].0)
            .count();
        assert_eq!(changed, 0);
    }

    #[test]
    fn noise_free_scans_are_left_alone() {
        let pts: Vec<Vec3> = (0..60 * 60)
            .map(|i| Vec3::new((i % 60) as f32 * 0.01, (i / 60) as f32 * 0.01, 0.0))
            .chain((0..200).map(|i| Vec3::new(0.1 + i as f32 * 0.0001, 0.305, 0.0)))
            .collect();
        let toward = |p: Vec3| Vec3::new(0.0, 0.0, 1.0) - p;
        let (fits, _) = estimate_fits(&pts, true, toward);
        let (normals, _) = estimate(&pts, true, toward);
        let fits: Vec<Vec3> = fits.unwrap().iter().map(|f| f.0).collect();
        assert_eq!(normals.unwrap(), fits);
    }
}
