//! Edge-aware smoothing of the union's per-point values over the scan's own map.
//!
//! A handful of rays per point leaves Monte Carlo grain that averaging the views' filtered
//! SSAO does not have. Neighbouring points of one surface see nearly the same hemisphere, so
//! their rays are pooled: a point's value becomes the weighted mean over the points whose
//! pixels lie within `radius` pixels of its own, weighted by a Gaussian in pixels and one in
//! metres, and kept only where the neighbour lies on the point's own surface: within
//! `2 (rad(p) + rad(q))` of its tangent plane with a normal within 30°. A wall meeting a
//! floor, a step, or a surface behind a silhouette never mixes.
//!
//! Occlusion changes across a surface on the scale of the distance to its occluders (steeply
//! beside a wall, hardly on an open floor), so the metric σ is half the distance at which the
//! point's nearest ray hit, and at most `t_max / 10`: a point beside a crease pools only with
//! points about as near to it, one in the open with its whole window.
//!
//! Each pixel pools the points that fall on its stored surface (a point hidden behind it does
//! not), so the weights are the pixels' and a pixel holding several points counts them all.

use super::{UnionParams, UnionTarget};
use crate::gbuffer::EMPTY;
use glam::{Vec3, Vec4};
use rayon::prelude::*;

/// Cosine of the largest angle between the normals of two points pooled together.
const COS_SAME: f32 = 0.866;
/// Largest metric σ of the weights as a fraction of a finite `t_max`.
const SIGMA_TMAX: f32 = 0.1;
/// Metric σ of the weights as a fraction of the distance to the point's nearest hit.
const SIGMA_HIT: f32 = 0.5;

/// The union's values of the points of one pixel's surface, summed.
#[derive(Clone, Copy, Default)]
struct Pool {
    ao: f32,
    bent: Vec3,
    count: u32,
}

/// The pixel and normal of point `i` of `t` when the union shaded it (the points it left at
/// their own SSAO have neither).
pub(super) fn shaded(t: &UnionTarget<'_>, i: usize) -> Option<(usize, Vec3)> {
    let px = *t.own_pixel.get(i)?;
    let rest = (px != EMPTY)
        .then(|| t.own.rest.get(px as usize))
        .flatten()?;
    let n = Vec3::new(rest[0], rest[1], rest[2]).normalize_or_zero();
    (n != Vec3::ZERO).then_some((px as usize, n))
}

/// Whether a point at `p` (normal `n`, radius `rad`) and the stored point `near` (radius in
/// `w`) lie on one surface as far as the tangent plane at `p` tells.
#[inline]
fn on_plane(p: Vec3, n: Vec3, rad: f32, near: Vec4) -> bool {
    near.w != f32::NEG_INFINITY && (near.truncate() - p).dot(n).abs() <= 2.0 * (rad + near.w)
}

/// Smooths `ao` (and `bent`, renormalised) of `t`'s points over `prm.filter` pixels of its own
/// map; 0 returns them unchanged. `nearest` is each point's nearest hit. Points the union did
/// not shade keep their value.
pub(super) fn smooth(
    t: &UnionTarget<'_>,
    ao: Vec<f32>,
    bent: Option<Vec<Vec3>>,
    nearest: &[f32],
    prm: &UnionParams,
) -> (Vec<f32>, Option<Vec<Vec3>>) {
    let (proj, radius) = (t.own_proj, prm.filter);
    let cells = t.own.near.len();
    if radius == 0 || cells == 0 || proj.width * proj.height != cells {
        return (ao, bent);
    }
    let rad = |i: usize| t.radii.get(i).copied().unwrap_or(0.0).max(0.0);
    let n_pts = ao.len().min(t.points.len());
    // Each point's pixel and normal where it lies on its pixel's stored surface: the points
    // that pool, and that are smoothed.
    let member: Vec<Option<(usize, Vec3)>> = (0..n_pts)
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| shaded(t, i).filter(|&(px, n)| on_plane(t.points[i], n, rad(i), t.own.near[px])))
        .collect();
    let mut pools = vec![Pool::default(); cells];
    for (i, m) in member.iter().enumerate() {
        if let Some((px, _)) = *m {
            let pool = &mut pools[px];
            pool.ao += ao[i];
            pool.bent += bent.as_ref().map_or(Vec3::ZERO, |b| b[i]);
            pool.count += 1;
        }
    }
    let r = radius as i64;
    let sigma_px = (radius as f32 / 2.0).max(0.5);
    let gauss: Vec<f32> = (0..=r)
        .map(|d| (-((d * d) as f32) / (2.0 * sigma_px * sigma_px)).exp())
        .collect();
    let sigma_max = SIGMA_TMAX * prm.tmax;
    let w = proj.width as i64;
    let pooled: Vec<Option<(f32, Vec3)>> = (0..ao.len())
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| {
            let (px, n) = (*member.get(i)?)?;
            let (p, rad_p) = (t.points[i], rad(i));
            let (x0, y0) = ((px as i64) % w, (px as i64) / w);
            let sigma = (SIGMA_HIT * nearest.get(i).copied().unwrap_or(f32::INFINITY))
                .min(sigma_max)
                .max(1e-6);
            let inv_2s2 = if sigma.is_finite() {
                1.0 / (2.0 * sigma * sigma)
            } else {
                0.0
            };
            let (mut sw, mut sa, mut sb) = (0.0f32, 0.0f32, Vec3::ZERO);
            for dy in -r..=r {
                for dx in -r..=r {
                    let Some(q) = proj.pixel_at(x0 + dx, y0 + dy) else {
                        continue;
                    };
                    let pool = pools[q];
                    if pool.count == 0 {
                        continue;
                    }
                    let rest = &t.own.rest[q];
                    let nq = Vec3::new(rest[0], rest[1], rest[2]);
                    let near = t.own.near[q];
                    if nq.dot(n) < COS_SAME * nq.length() || !on_plane(p, n, rad_p, near) {
                        continue;
                    }
                    let d2 = (near.truncate() - p).length_squared();
                    let wgt = gauss[dx.unsigned_abs() as usize]
                        * gauss[dy.unsigned_abs() as usize]
                        * (-d2 * inv_2s2).exp();
                    sw += wgt * pool.count as f32;
                    sa += wgt * pool.ao;
                    sb += wgt * pool.bent;
                }
            }
            // The point's own pixel always qualifies (it passed the same test), so `sw > 0`
            // unless the weights underflowed.
            (sw > 0.0).then(|| ((sa / sw).clamp(0.0, 1.0), sb.normalize_or_zero()))
        })
        .collect();
    let ao = ao
        .iter()
        .zip(&pooled)
        .map(|(&a, f)| f.map_or(a, |f| f.0))
        .collect();
    let bent = bent.map(|b| {
        b.iter()
            .zip(&pooled)
            .map(|(&v, f)| f.map_or(v, |f| f.1))
            .collect()
    });
    (ao, bent)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gbuffer::rasterize;
    use crate::merge::{MergeParams, ViewMaps};
    use crate::projection::{Model, Projection};
    use crate::rng::Rng;
    use glam::DMat4;

    const W: usize = 24;
    const H: usize = 16;
    /// Pixel size (metres) of the orthographic patch.
    const PX: f32 = 0.01;

    /// Per-point values of a patch seen from above (one point per pixel, 1 cm apart): the left
    /// half a floor at z = 0 with values `0.6 ± 0.1`; on the right, either a step 5 cm up
    /// (`step`) or the same plane with normals tilted 45°, with values `0.9 ± 0.1`. Returns
    /// the raw and the smoothed values.
    fn patch(step: bool, radius: u32, nearest: f32) -> (Vec<f32>, Vec<f32>) {
        let proj = Projection::new(
            Model::Ortho {
                a: Vec3::new(1.0 / PX, 0.0, 0.0),
                a0: 0.0,
                b: Vec3::new(0.0, 1.0 / PX, 0.0),
                b0: 0.0,
                toward: Vec3::Z,
                depth0: 2.0,
            },
            W,
            H,
            false,
        );
        let right = |i: usize| i % W >= W / 2;
        let pts: Vec<Vec3> = (0..W * H)
            .map(|i| {
                let z = if step && right(i) { 0.05 } else { 0.0 };
                Vec3::new((i % W) as f32 + 0.5, (i / W) as f32 + 0.5, 0.0) * PX + Vec3::Z * z
            })
            .collect();
        let tilted = Vec3::new(1.0, 0.0, 1.0).normalize();
        let normals: Vec<Vec3> = (0..W * H)
            .map(|i| if !step && right(i) { tilted } else { Vec3::Z })
            .collect();
        let px: Vec<u32> = (0..(W * H) as u32).collect();
        let depth: Vec<f32> = pts.iter().map(|p| 2.0 - p.z).collect();
        let rad = vec![PX; W * H];
        let g = rasterize(W, H, &px, &depth, &pts, &normals, &rad);
        let prm = MergeParams::single_pixel(64.0);
        let maps = ViewMaps::new(&proj, &g, &vec![1.0; W * H], &vec![1e3; W * H], &prm);
        let mut rng = Rng::new(7, 0);
        let raw: Vec<f32> = (0..W * H)
            .map(|i| {
                let mean = if right(i) { 0.9 } else { 0.6 };
                mean + 0.2 * (rng.next_f32() - 0.5)
            })
            .collect();
        let t = UnionTarget {
            index: 0,
            points: &pts,
            radii: &rad,
            own_pixel: &px,
            own: &maps,
            own_proj: &proj,
            pose: DMat4::IDENTITY,
            fallback: &raw,
        };
        let prm = UnionParams {
            rays: 8,
            steps: 24,
            tmax: f32::INFINITY,
            falloff: crate::falloff::Falloff::None,
            reach: 1.0,
            thickness: 0.01,
            seed: 0,
            filter: radius,
            views: 0,
        };
        let (out, _) = smooth(&t, raw.clone(), None, &vec![nearest; W * H], &prm);
        (raw, out)
    }

    /// Mean and standard deviation of the values of the left (floor) or right half.
    fn stats(v: &[f32], right: bool) -> (f32, f32) {
        let sel: Vec<f32> = (0..v.len())
            .filter(|&i| (i % W >= W / 2) == right)
            .map(|i| v[i])
            .collect();
        let m = sel.iter().sum::<f32>() / sel.len() as f32;
        let var = sel.iter().map(|x| (x - m) * (x - m)).sum::<f32>() / sel.len() as f32;
        (m, var.sqrt())
    }

    #[test]
    fn smooths_within_a_surface_and_keeps_the_halves_apart() {
        for step in [true, false] {
            let (raw, out) = patch(step, 3, f32::INFINITY);
            for right in [false, true] {
                let (m0, s0) = stats(&raw, right);
                let (m1, s1) = stats(&out, right);
                assert!(s1 < 0.4 * s0, "step {step}: spread {s0} -> {s1}");
                assert!((m1 - m0).abs() < 0.01, "step {step}: mean {m0} -> {m1}");
            }
            // Beside the edge no value is pulled towards the other half's (0.3 apart; the raw
            // noise is ±0.1).
            for y in 0..H {
                let (l, r) = (y * W + W / 2 - 1, y * W + W / 2);
                assert!(out[l] < 0.7 && out[r] > 0.8, "{} {}", out[l], out[r]);
            }
        }
    }

    #[test]
    fn radius_zero_leaves_values_alone() {
        let (raw, out) = patch(true, 0, f32::INFINITY);
        assert_eq!(raw, out);
    }

    #[test]
    fn near_occluders_narrow_the_pool() {
        // Rays hitting one pixel away: σ is half a pixel, the point keeps most of its own
        // value; in the open the whole window pools.
        let (raw, near) = patch(false, 3, PX);
        let (_, open) = patch(false, 3, f32::INFINITY);
        let (_, s0) = stats(&raw, false);
        let (_, s_near) = stats(&near, false);
        let (_, s_open) = stats(&open, false);
        assert!(
            s_near > 0.6 * s0 && s_open < 0.4 * s0,
            "{s0} {s_near} {s_open}"
        );
    }
}
