//! Per-ray account of one query point, for diagnosing the reference against a ground truth:
//! every ray's nearest accepted hit found by testing all primitives (no hierarchy), with the
//! primitive that stopped it.

use super::bvh::{Primitive, Ray};
use super::sampling::{Azimuths, Pattern};
use super::{Scene, ORIGIN_OFFSET};
use glam::Vec3;

/// What stopped one ray of [`Scene::explain`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayStop {
    /// Distance along the ray.
    pub t: f32,
    /// A surfel's centre, or a triangle's first vertex.
    pub centre: Vec3,
    /// The primitive's unit normal.
    pub normal: Vec3,
    /// A surfel's radius (0 for a triangle).
    pub radius: f32,
    /// True for a triangle.
    pub triangle: bool,
}

/// One ray of [`Scene::explain`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayAccount {
    /// Unit direction.
    pub dir: Vec3,
    /// The nearest accepted hit within `t_max`, if any.
    pub stop: Option<RayStop>,
    /// Hits the self-hit rules discarded.
    pub discarded: u32,
}

impl Scene {
    /// Each ray of query point `p` (normal `n`, radius `r`, seed index `index`) as
    /// [`Scene::point`] casts it, with what stopped it; every primitive is tested.
    pub fn explain(
        &self,
        p: Vec3,
        n: Vec3,
        r: f32,
        prm: &super::RefParams,
        index: u64,
    ) -> Vec<RayAccount> {
        let n = n.normalize_or_zero();
        if n == Vec3::ZERO || !p.is_finite() {
            return Vec::new();
        }
        let r = if r > 0.0 && r.is_finite() { r } else { 0.0 };
        let eps = (ORIGIN_OFFSET * r).max(16.0 * f32::EPSILON * p.abs().max_element());
        let o = p + n * eps;
        let az = Azimuths::new(prm.rays);
        let pat = Pattern::new(prm.seed, index, n, &az);
        let far = prm.tmax.min(f32::MAX);
        (0..prm.rays)
            .map(|j| {
                let ray = Ray::of_point(o, pat.dir(j), r, n, self.self_height);
                let mut best = far;
                let mut stop = None;
                for s in self.surfels.prims() {
                    if let Some(t) = s.hit(&ray, best) {
                        best = t;
                        stop = Some(RayStop {
                            t,
                            centre: s.c,
                            normal: s.n,
                            radius: s.r,
                            triangle: false,
                        });
                    }
                }
                for tr in self.tris.prims() {
                    if let Some(t) = tr.hit(&ray, best) {
                        best = t;
                        stop = Some(RayStop {
                            t,
                            centre: tr.v0,
                            normal: tr.e1.cross(tr.e2).normalize_or_zero(),
                            radius: 0.0,
                            triangle: true,
                        });
                    }
                }
                RayAccount {
                    dir: ray.d,
                    stop,
                    discarded: ray.discarded.get(),
                }
            })
            .collect()
    }
}
