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
    falloff: (f32, Falloff),
    seed: u64,
) -> Vec<f32> {
    mesh_obscurance_counted(scene, truth, &MeshRays::new(rays, falloff, seed), &|_| {})
}

/// The ray set of [`mesh_obscurance`]: rays per point, falloff, seed.
#[derive(Debug, Clone, Copy)]
pub struct MeshRays {
    rays: u32,
    tmax: f32,
    falloff: Falloff,
    seed: u64,
}

impl MeshRays {
    /// `rays` per point (at least one), `falloff` to `tmax` (∞ allowed), directions of `seed`.
    pub fn new(rays: u32, (tmax, falloff): (f32, Falloff), seed: u64) -> MeshRays {
        MeshRays {
            rays: rays.max(1),
            tmax,
            falloff,
            seed,
        }
    }

    /// The same set with `rays` per point.
    pub fn with_rays(self, rays: u32) -> MeshRays {
        MeshRays {
            rays: rays.max(1),
            ..self
        }
    }

    /// Rays per point.
    pub fn rays(&self) -> u32 {
        self.rays
    }
}

/// [`mesh_obscurance`] with a progress callback (points done, in chunks).
pub fn mesh_obscurance_counted(
    scene: &MeshScene,
    truth: &[Truth],
    set: &MeshRays,
    progress: &(dyn Fn(u64) + Sync),
) -> Vec<f32> {
    const CHUNK: usize = 1024;
    let az = Azimuths::new(set.rays);
    let mut out = vec![1.0f32; truth.len()];
    out.par_chunks_mut(CHUNK)
        .zip(truth.par_chunks(CHUNK))
        .enumerate()
        .for_each(|(c, (a, t))| {
            for (k, (a, t)) in a.iter_mut().zip(t).enumerate() {
                *a = mesh_point(scene, t, (c * CHUNK + k) as u64, set, &az);
            }
            progress(t.len() as u64);
        });
    out
}

/// `A` of one [`Truth`], the `index`-th point of its set (which seeds its directions), with
/// the azimuths `az` of `set.rays`.
pub(crate) fn mesh_point(
    scene: &MeshScene,
    t: &Truth,
    index: u64,
    set: &MeshRays,
    az: &Azimuths,
) -> f32 {
    if t.n == DVec3::ZERO {
        return 1.0;
    }
    let reach = if set.tmax.is_finite() {
        set.tmax as f64
    } else {
        f64::INFINITY
    };
    let o = t.p + t.n * (1e-9 * scene.extent());
    let pat = Pattern::new(set.seed, index, t.n.as_vec3(), az);
    let mut sum = 0.0f64;
    for j in 0..set.rays {
        let d = pat.dir(j).as_dvec3().normalize_or_zero();
        let v = match scene.intersect_skip(o, d, 0.0, reach, t.prim) {
            Some(h) => set.falloff.rho(h.t as f32, set.tmax),
            None => 1.0,
        };
        sum += v as f64;
    }
    (sum / set.rays as f64).clamp(0.0, 1.0) as f32
}
