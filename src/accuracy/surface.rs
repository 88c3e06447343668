//! The reference of real scans against a known true surface (`mvao reference --surface`): a
//! reconstruction or a model of the site, in the scans' world frame.
//!
//! A scan's points carry range noise, registration residual and estimated normals; the
//! surface does not. Each point is therefore moved to the nearest point of the surface within
//! a tolerance and takes that face's normal (turned to the side of the point's own estimated
//! normal), and its rays are cast from there against the surface alone, as `mvao synth` casts
//! its ground truth. A point farther than the tolerance (an outlier, or a part of the site the
//! surface does not cover) has no place on it: its rays leave from where it is, and it is
//! written with `on_surface` 0 so that scoring leaves it out.

use super::RefConfig;
use crate::error::{Error, Result};
use crate::reference::{Convergence, RefParams};
use crate::scan::Scan;
use crate::synth::reference::{mesh_obscurance_counted, mesh_point, MeshRays};
use crate::synth::{Mesh, MeshScene, Truth};
use glam::{DMat3, Vec3};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

/// Default tolerance, in point radii `rad(p)`: how far a point may lie from the surface and
/// still be scored.
pub const TOLERANCE_RADII: f32 = 4.0;

/// The true surface of `mvao reference --surface`.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceSpec {
    /// A triangle mesh (PLY or OBJ) in the scans' world frame.
    pub path: PathBuf,
    /// Largest distance (metres) from a point to the surface for it to be scored; `None`:
    /// [`TOLERANCE_RADII`] × the point's `rad(p)`.
    pub tolerance: Option<f32>,
}

/// One scan's reference against the surface.
pub(super) struct SurfaceReference {
    /// `A` per point.
    pub a: Vec<f32>,
    /// `|A_R − A_4R|` on a sample; timing of the main run.
    pub convergence: Convergence,
}

/// Reads the surface of `spec` and builds its hierarchy.
pub(super) fn load(spec: &SurfaceSpec) -> Result<MeshScene> {
    if let Some(t) = spec.tolerance {
        if !(t > 0.0 && t.is_finite()) {
            return Err(Error::Param(format!(
                "--surface-tolerance must be a positive number of metres, got {t}"
            )));
        }
    }
    Ok(MeshScene::new(&Mesh::read(&spec.path)?))
}

/// Where each point of `s` lies on the surface: its truth (position, face normal, face) and
/// whether it was within the tolerance. `normals` and `radii` are the scan's own (local).
pub(super) fn place(
    scene: &MeshScene,
    s: &Scan,
    normals: &[Vec3],
    radii: &[f32],
    tolerance: Option<f32>,
) -> (Vec<Truth>, Vec<bool>) {
    let rot = DMat3::from_mat4(s.pose);
    s.points
        .par_iter()
        .zip(normals)
        .zip(radii)
        .map(|((p, n), &r)| {
            let w = s.pose.transform_point3(p.as_dvec3());
            let own = (rot * n.as_dvec3()).normalize_or_zero();
            let tol = tolerance.unwrap_or(TOLERANCE_RADII * r.max(0.0)) as f64;
            match scene.nearest(w, tol) {
                Some((q, face)) => {
                    let f = scene.normal(face as usize);
                    let n = if f.dot(own) < 0.0 { -f } else { f };
                    let t = Truth {
                        p: q,
                        n,
                        prim: face,
                    };
                    (t, true)
                }
                // Off the surface: cast from the point with its own normal, skipping no face.
                None => {
                    let t = Truth {
                        p: w,
                        n: own,
                        prim: u32::MAX,
                    };
                    (t, false)
                }
            }
        })
        .unzip()
}

/// The reference at the placed points `truth` of one scan against the surface `scene`, with
/// `cfg`'s rays and falloff, and its convergence on `cfg.sample` points.
pub(super) fn reference(
    scene: &MeshScene,
    truth: &[Truth],
    cfg: &RefConfig,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<SurfaceReference> {
    let prm: &RefParams = &cfg.params;
    prm.check()?;
    let set = MeshRays::new(prm.rays, (prm.tmax, prm.falloff), prm.seed);
    let start = Instant::now();
    let a = mesh_obscurance_counted(scene, truth, &set, progress);
    let seconds = start.elapsed().as_secs_f64();
    let rays_cast = truth.len() as u64 * set.rays() as u64;
    let convergence = converge(scene, truth, &a, &set, cfg.sample, (rays_cast, seconds));
    Ok(SurfaceReference { a, convergence })
}

/// `|A_R − A_4R|` on `sample` points spread evenly over `truth` (each with its own index as
/// seed, so `A_R` is the main run's `a`); `main` is the main run's rays and seconds.
fn converge(
    scene: &MeshScene,
    truth: &[Truth],
    a: &[f32],
    set: &MeshRays,
    sample: usize,
    (rays_cast, seconds): (u64, f64),
) -> Convergence {
    let n = truth.len();
    let m = sample.min(n);
    let four = set.with_rays(set.rays().saturating_mul(4));
    let az = crate::reference::sampling::Azimuths::new(four.rays());
    let diffs: Vec<f32> = (0..m)
        .into_par_iter()
        .map(|k| {
            let i = (k as u128 * n as u128 / m as u128) as usize;
            (mesh_point(scene, &truth[i], i as u64, &four, &az) - a[i]).abs()
        })
        .collect();
    let mean = if m > 0 {
        (diffs.iter().map(|&d| d as f64).sum::<f64>() / m as f64) as f32
    } else {
        0.0
    };
    Convergence {
        sample: m,
        rays: set.rays(),
        mean_abs_diff_4r: mean,
        max_abs_diff_4r: diffs.iter().copied().fold(0.0, f32::max),
        rays_cast,
        seconds,
        rays_per_second: if seconds > 0.0 {
            rays_cast as f64 / seconds
        } else {
            0.0
        },
    }
}

/// Refuses a surface on which not one of the `total` points lies: most often a surface in
/// another frame than the scans' world frame, which would otherwise be scored as empty.
pub(super) fn check_any_on(path: &std::path::Path, on: usize, total: usize) -> Result<()> {
    if total > 0 && on == 0 {
        return Err(Error::format(
            path,
            format!(
                "none of the {total} points lies within the tolerance of this surface; is it \
                 in the scans' world frame (the frame the alignment places them in)?"
            ),
        ));
    }
    Ok(())
}
