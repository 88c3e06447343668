//! The reference obscurance of synthetic scans against the exact scene (analytic primitives or
//! a triangle mesh) instead of surfels: the same cosine-weighted ray sets as `mvao reference`,
//! cast at the true geometry, so the reference's own error can be measured.

use super::mesh::MeshScene;
use super::scanner::Truth;
use super::scene::Scene;
use crate::falloff::Falloff;
use crate::reference::sampling::{Azimuths, Pattern};
use crate::scan::Scan;
use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;

/// Ray origins are lifted this far (metres) along the normal: the scan's points lie exactly
/// on the primitives, and a ray must not hit the surface it starts from.
pub const LIFT: f64 = 1e-5;

/// `A(p)` of every point of `scan` (exact normals required; points without one read 1),
/// `rays` cosine-weighted rays per point, falloff `falloff` to `tmax` (∞ allowed), deterministic for
/// `seed` and independent of the thread count.
pub fn analytic_obscurance(
    scene: &Scene,
    scan: &Scan,
    rays: u32,
    (tmax, falloff): (f32, Falloff),
    seed: u64,
) -> Vec<f32> {
    let Some(normals) = scan.normals.as_ref() else {
        return vec![1.0; scan.len()];
    };
    let rot = DMat3::from_mat4(scan.pose);
    let az = Azimuths::new(rays.max(1));
    let reach = if tmax.is_finite() {
        tmax as f64
    } else {
        f64::INFINITY
    };
    scan.points
        .par_iter()
        .zip(normals.par_iter())
        .enumerate()
        .map(|(i, (p, n))| {
            let nw = (rot * n.as_dvec3()).normalize_or_zero();
            if nw == DVec3::ZERO {
                return 1.0;
            }
            let o = scan.pose.transform_point3(p.as_dvec3()) + nw * LIFT;
            let pat = Pattern::new(seed, i as u64, nw.as_vec3(), &az);
            let mut sum = 0.0f64;
            for j in 0..rays.max(1) {
                let d: Vec3 = pat.dir(j);
                let d = d.as_dvec3().normalize_or_zero();
                let v = match scene.intersect_range(o, d, 0.0, reach) {
                    Some(h) => falloff.rho(h.t as f32, tmax),
                    None => 1.0,
                };
                sum += v as f64;
            }
            (sum / rays.max(1) as f64).clamp(0.0, 1.0) as f32
        })
        .collect()
}

/// `A(p)` of every scanned point against the exact mesh: at the point's noise-free position
/// on the mesh with the true face normal ([`Truth`]), `rays` cosine-weighted rays per point
/// (the same direction sets as `mvao reference` for a seed), `falloff` to `tmax` (∞ allowed). The
/// ray leaves from the surface itself (lifted by 10⁻⁹ of the mesh's extent, f64) and never
/// hits the face it starts on; every other face counts. Deterministic and independent of the
/// thread count.
pub fn mesh_obscurance(
    scene: &MeshScene,
    truth: &[Truth],
    rays: u32,
    (tmax, falloff): (f32, Falloff),
    seed: u64,
) -> Vec<f32> {
    let rays = rays.max(1);
    let az = Azimuths::new(rays);
    let reach = if tmax.is_finite() {
        tmax as f64
    } else {
        f64::INFINITY
    };
    let lift = 1e-9 * scene.extent();
    truth
        .par_iter()
        .enumerate()
        .map(|(i, t)| {
            if t.n == DVec3::ZERO {
                return 1.0;
            }
            let o = t.p + t.n * lift;
            let pat = Pattern::new(seed, i as u64, t.n.as_vec3(), &az);
            let mut sum = 0.0f64;
            for j in 0..rays {
                let d = pat.dir(j).as_dvec3().normalize_or_zero();
                let v = match scene.intersect_skip(o, d, 0.0, reach, t.prim) {
                    Some(h) => falloff.rho(h.t as f32, tmax),
                    None => 1.0,
                };
                sum += v as f64;
            }
            (sum / rays as f64).clamp(0.0, 1.0) as f32
        })
        .collect()
}
