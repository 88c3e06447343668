//! Normals at creases and edges, fitted to the point's own surface.
//!
//! Within a few cells of a crease (floor to wall, column foot, the edge of a step) the 16
//! nearest neighbours hold both surfaces, and their PCA normal is a blend of the two, tilted
//! towards the other surface by tens of degrees: exactly the points whose obscurance a crease
//! decides. The point lies on its own surface, so the plane is fitted again through it with
//! the neighbours far from that plane down-weighted, until it settles on the surface that
//! holds the point and most of its neighbours.

use super::{pca_fit, smallest_eigen, Fit};
use glam::{DVec3, Vec3};

/// Neighbourhoods whose surface variation `λ₀ / (λ₀ + λ₁ + λ₂)` exceeds this bend: a plane
/// with range noise stays far below it (2 mm of noise over 16 neighbours 3 cm apart: about
/// 0.004), two surfaces meeting at a right angle far above.
const BENT: f32 = 0.01;
/// Re-weighting rounds.
const ROUNDS: usize = 3;

/// The PCA fit of the neighbours `nb` of `p` (oriented to `toward`), its normal fitted again to
/// the surface through `p` where the neighbourhood is bent.
pub(super) fn fit(p: Vec3, nb: &[Vec3], toward: Vec3) -> Fit {
    let fit = pca_fit(nb.iter().copied(), toward);
    let [l0, l1, l2] = fit.1;
    if !(l0 > BENT * (l0 + l1 + l2)) {
        return fit;
    }
    (own_surface(p, nb, fit.0), fit.1)
}

/// `n0` fitted again by weighted PCA: each round weighs a neighbour by its distance `r` from
/// the plane through `p` with the current normal as `1 / (1 + (r/s)⁴)`, `s` twice the median
/// distance (neighbours on the point's surface near 1, those across the crease near 0).
fn own_surface(p: Vec3, nb: &[Vec3], n0: Vec3) -> Vec3 {
    const MAX: usize = 32;
    let m = nb.len().min(MAX);
    if m < 4 {
        return n0;
    }
    let o = p.as_dvec3();
    let mut d = [DVec3::ZERO; MAX];
    for (d, q) in d.iter_mut().zip(&nb[..m]) {
        *d = q.as_dvec3() - o;
    }
    let d = &d[..m];
    let mut n = n0.as_dvec3();
    let (mut r, mut sorted) = ([0.0f64; MAX], [0.0f64; MAX]);
    for _ in 0..ROUNDS {
        for (r, d) in r.iter_mut().zip(d) {
            *r = n.dot(*d).abs();
        }
        sorted[..m].copy_from_slice(&r[..m]);
        let s = 2.0 * *sorted[..m].select_nth_unstable_by(m / 2, f64::total_cmp).1;
        if !(s > 0.0) {
            break;
        }
        let (mut sw, mut c) = (0.0, DVec3::ZERO);
        let mut w = [0.0f64; MAX];
        for ((w, &r), &d) in w.iter_mut().zip(&r[..m]).zip(d) {
            let t = (r / s) * (r / s);
            *w = 1.0 / (1.0 + t * t);
            sw += *w;
            c += *w * d;
        }
        let c = c / sw;
        let mut cov = [0.0f64; 6];
        for (&w, &d) in w[..m].iter().zip(d) {
            let e = d - c;
            cov[0] += w * e.x * e.x;
            cov[1] += w * e.x * e.y;
            cov[2] += w * e.x * e.z;
            cov[3] += w * e.y * e.y;
            cov[4] += w * e.y * e.z;
            cov[5] += w * e.z * e.z;
        }
        let Some((v, _, _)) = smallest_eigen(cov) else {
            break;
        };
        n = if v.dot(n) < 0.0 { -v } else { v };
    }
    let n = n.as_vec3().normalize_or(n0);
    if n.dot(n0) < 0.0 {
        -n
    } else {
        n
    }
}

#[cfg(test)]
mod tests {
    use super::super::{estimate, pca_normal, K_NORMAL};
    use glam::Vec3;

    /// A floor (z = 0, x ≥ 0) meeting a wall (x = 0, z > 0) at a right angle, both sampled on
    /// a 2 cm grid, seen from a sensor above the floor in front of the wall.
    fn crease() -> Vec<Vec3> {
        let mut pts = Vec::new();
        for j in 0..60 {
            let y = j as f32 * 0.02;
            pts.extend((0..40).map(|i| Vec3::new(i as f32 * 0.02, y, 0.0)));
            pts.extend((1..40).map(|i| Vec3::new(0.0, y, i as f32 * 0.02)));
        }
        pts
    }

    fn angle_deg(a: Vec3, b: Vec3) -> f32 {
        a.dot(b).clamp(-1.0, 1.0).acos().to_degrees()
    }

    #[test]
    fn floor_points_beside_a_wall_keep_the_floor_normal() {
        let pts = crease();
        let toward = |p: Vec3| Vec3::new(0.5, 0.6, 1.0) - p;
        let (normals, _) = estimate(&pts, true, toward);
        let normals = normals.unwrap();
        // Floor points one and two cells from the wall, away from the ends of the strip.
        for (i, p) in pts.iter().enumerate() {
            let inside = p.y > 0.2 && p.y < 1.0 && p.z == 0.0 && (p.x - 0.03).abs() < 0.015;
            if !inside {
                continue;
            }
            // Their 16 nearest hold wall points: a plain PCA normal leans towards the wall (by
            // over 10° one cell from it).
            let mut near: Vec<Vec3> = pts.clone();
            near.sort_by(|a, b| a.distance_squared(*p).total_cmp(&b.distance_squared(*p)));
            let blend = pca_normal(near[..K_NORMAL].iter().copied(), toward(*p));
            if p.x < 0.03 {
                assert!(angle_deg(blend, Vec3::Z) > 10.0, "{p} {blend}");
            }
            assert!(angle_deg(normals[i], Vec3::Z) < 2.0, "{p} {}", normals[i]);
        }
    }

    #[test]
    fn a_curved_surface_keeps_its_normals() {
        // A cylinder of radius 0.2 m sampled every 2 cm: bent, but a single surface; the
        // re-weighting must not tilt its normals off the radial direction.
        let pts: Vec<Vec3> = (0..40)
            .flat_map(|j| {
                (0..63).map(move |i| {
                    let a = i as f32 * 0.1;
                    Vec3::new(0.2 * a.cos(), 0.2 * a.sin(), j as f32 * 0.02)
                })
            })
            .collect();
        let (normals, _) = estimate(&pts, true, |p: Vec3| Vec3::new(p.x, p.y, 0.0));
        for (p, n) in pts.iter().zip(normals.unwrap()) {
            if p.z > 0.1 && p.z < 0.68 {
                let radial = Vec3::new(p.x, p.y, 0.0).normalize();
                assert!(angle_deg(n, radial) < 1.0, "{p} {n}");
            }
        }
    }
}
