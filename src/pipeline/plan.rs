//! The plan stage: the run's parameters (the default radius from the scene's extent, t_max,
//! d_min and d_max from the prepared views), which pairs of scans may share surface, and how
//! much memory the views take against the budget.

use crate::config::ComputeParams;
use crate::error::{Error, Result};
use crate::merge::MergeParams;
use crate::radius::SceneScale;
use crate::report::{CatalogScan, Plan};
use crate::scan::occupancy::Occupancy;
use crate::scan::Scan;
use crate::site::Pairs;
use crate::ssao::SsaoParams;
use crate::store::view_bytes;
use glam::DVec3;

/// Robust scene diagonal: 1st–99th percentile box of a sample of points along the sample's
/// principal axes, so that a rigid motion of all poses leaves it unchanged, and the scans are
/// sampled in name order so that the order of the inputs changes nothing.
pub fn robust_diagonal(scans: &[Scan]) -> f64 {
    let mut order: Vec<&Scan> = scans.iter().collect();
    order.sort_by(|a, b| a.name.cmp(&b.name));
    let mut pts: Vec<DVec3> = Vec::new();
    for s in order {
        let step = s.len().div_ceil(20_000).max(1);
        pts.extend(
            s.points
                .iter()
                .step_by(step)
                .map(|p| s.pose.transform_point3(p.as_dvec3())),
        );
    }
    if pts.is_empty() {
        return 0.0;
    }
    let n = pts.len() as f64;
    let mean = pts.iter().fold(DVec3::ZERO, |a, &p| a + p) / n;
    let mut cov = [[0.0f64; 3]; 3];
    for p in &pts {
        let d = (*p - mean).to_array();
        for (r, row) in cov.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v += d[r] * d[c] / n;
            }
        }
    }
    let (_, axes) = crate::scan::normals::sym_eigen3(cov);
    let mut ext = DVec3::ZERO;
    let mut v: Vec<f64> = Vec::with_capacity(pts.len());
    for (k, axis) in axes.iter().enumerate() {
        v.clear();
        v.extend(pts.iter().map(|p| (*p - mean).dot(*axis)));
        v.sort_by(f64::total_cmp);
        let lo = v[(v.len() as f64 * 0.01) as usize];
        let hi = v[((v.len() as f64 * 0.99) as usize).min(v.len() - 1)];
        ext[k] = hi - lo;
    }
    if ext.is_finite() {
        ext.length()
    } else {
        0.0
    }
}

/// The SSAO parameters of a run, with a note on how the defaults were derived: radius from
/// the scene's size and point spacing (`crate::radius`; `scale` is only called when no
/// radius is given), t_max = 2 × radius.
pub fn ssao_params(
    prm: &ComputeParams,
    scale: impl FnOnce() -> SceneScale,
) -> Result<(SsaoParams, String)> {
    let mut note = String::new();
    let radius = match prm.radius {
        Some(r) => r,
        None => {
            let sc = scale();
            let Some((r, how)) = sc.default_radius() else {
                return Err(Error::Param(format!(
                    "no default SSAO radius: the scans' robust diagonal is {} m (every point at \
                     one place, or coordinates beyond single precision); give --radius in metres",
                    sc.diagonal
                )));
            };
            note += &how;
            r
        }
    };
    let tmax = match prm.tmax {
        Some(t) => t,
        None => {
            note += "tmax = 2 × radius; ";
            2.0 * radius
        }
    };
    if !(radius > 0.0 && radius.is_finite()) {
        return Err(Error::Param(format!(
            "the SSAO radius must be a positive number of metres (got {radius}); give --radius"
        )));
    }
    let sp = SsaoParams {
        estimator: prm.estimator,
        radius,
        tmax,
        falloff: prm.falloff,
        samples: prm.samples,
        directions: prm.directions,
        steps: prm.steps,
        seed: prm.seed,
        blur: prm.blur,
        sampling: prm.sampling,
    };
    Ok((sp, note))
}

/// The merge parameters of a run from the depth ranges of its views with a sensor position
/// (`d_min`/`d_max` defaults) and its SSAO parameters, noting how they were derived.
pub fn merge_params(
    prm: &ComputeParams,
    ranges: &[(f32, f32)],
    sp: &SsaoParams,
    note: &mut String,
) -> MergeParams {
    let (mut dmin, dmax) = ranges.iter().fold((f32::INFINITY, 0.0f32), |(lo, hi), r| {
        (lo.min(r.0), hi.max(r.1))
    });
    if !dmin.is_finite() {
        dmin = 0.0;
    }
    if ranges.is_empty() {
        *note += "dmin/dmax unused: every view is orthographic (w_d = 1)";
    } else if prm.dmin.is_none() || prm.dmax.is_none() {
        *note += "dmin/dmax = smallest/largest depth over all scans with a sensor position";
    }
    MergeParams {
        neighbors: prm.neighbors,
        dmin: prm.dmin.unwrap_or(dmin),
        dmax: prm.dmax.unwrap_or(dmax),
        border_px: prm.border_px,
        spacing: prm.spacing_weight * sp.tmax,
        largest_all_round: crate::ssao::uses_far_field(sp),
    }
}

/// What one input file's data and one view need beside the cache: the parsed file, its scan,
/// the own view, one partner's maps while they are decoded, and the process itself.
pub fn floor(max_file_bytes: u64, largest_view_bytes: u64) -> u64 {
    max_file_bytes * 5 + 3 * largest_view_bytes + (16 << 20)
}

/// The plan and what it was made from.
pub struct Planned {
    /// The plan (printed by `--dry-run`, kept in the report).
    pub plan: Plan,
    /// The pair test before the radii are known (only the SSAO reach counts).
    pub pairs: Pairs,
    /// Estimated bytes of every view.
    pub view_bytes: Vec<u64>,
    /// Scans that share surface with no other (most often misplaced), with the distance to
    /// the nearest scan's centre.
    pub lonely: Vec<(usize, f64)>,
}

/// The plan of scans `cat` with occupancies `occ` at SSAO reach `tmax` under `budget`.
pub fn plan(cat: &[CatalogScan], occ: &[Occupancy], tmax: f32, budget: u64) -> Planned {
    let n = cat.len();
    let bounds: Vec<(DVec3, DVec3)> = cat
        .iter()
        .map(|c| (DVec3::from(c.bounds[0]), DVec3::from(c.bounds[1])))
        .collect();
    // Before the radii are known only the SSAO reach counts; eq. 7's reach is added once they
    // are.
    let centres: Vec<DVec3> = bounds.iter().map(|b| (b.0 + b.1) * 0.5).collect();
    let pairs = Pairs::new(bounds, occ, tmax, 0.0);
    let mut kept = 0usize;
    let mut point_views = 0u64;
    let mut lonely = Vec::new();
    for (i, c) in cat.iter().enumerate() {
        let mut partners = 0usize;
        for j in 0..n {
            if i == j || pairs.meets(i, j, 0.0) {
                if i != j {
                    partners += 1;
                }
                point_views += c.points as u64;
            }
        }
        kept += partners;
        if partners == 0 && n > 1 {
            let gap = (0..n)
                .filter(|&j| j != i)
                .map(|j| centres[i].distance(centres[j]))
                .fold(f64::INFINITY, f64::min);
            lonely.push((i, gap));
        }
    }
    let vb: Vec<u64> = cat
        .iter()
        .map(|c| view_bytes(c.map_pixels, c.points as u64))
        .collect();
    let plan = Plan {
        scans: cat.to_vec(),
        pairs_kept: kept,
        pairs_skipped: n * n.saturating_sub(1) - kept,
        largest_view_bytes: vb.iter().copied().max().unwrap_or(0),
        all_views_bytes: vb.iter().sum(),
        occlusion_bytes: 0,
        budget_bytes: budget,
        point_views,
    };
    Planned {
        plan,
        pairs,
        view_bytes: vb,
        lonely,
    }
}

/// How many files of a held prefix (`held`: bytes of each file's scans) the prepare pass can
/// keep. At the start of file `f` it holds the kept scans of files `≥ f` and the views it
/// keeps of files `< f` (`views`, bytes per file); that sum plus `margin` must stay within
/// `budget` at every step.
pub fn files_to_hold(held: &[u64], views: &[u64], margin: u64, budget: u64) -> usize {
    let fits = |k: usize| {
        let (mut rest, mut kept) = (held[..k].iter().sum::<u64>(), 0u64);
        for (f, v) in views.iter().enumerate() {
            if rest + kept + margin > budget {
                return false;
            }
            rest -= held.get(f).filter(|_| f < k).copied().unwrap_or(0);
            kept += v;
        }
        kept + margin <= budget
    };
    (0..=held.len().min(views.len()))
        .rev()
        .find(|&k| fits(k))
        .unwrap_or(0)
}

/// Which scans' views (`views`: bytes of each, `need`: those the merge uses) the prepare pass
/// keeps for the merge: the needed ones of the first scans, in the order the merge visits
/// them, while their sum stays within `budget` less `margin` (all of them when they fit). The
/// merge's cache then starts with the maps it asks for first instead of reading them back.
pub fn views_to_keep(views: &[u64], need: &[bool], margin: u64, budget: u64) -> Vec<bool> {
    let mut room = budget.saturating_sub(margin);
    let mut open = true;
    views
        .iter()
        .zip(need)
        .map(|(&v, &wanted)| {
            let kept = open && wanted && v <= room;
            if kept {
                room -= v;
            } else if wanted {
                // A prefix: a later, smaller view would be asked for after the one left out.
                open = false;
            }
            kept
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat4, DQuat, Vec3};

    /// Two slabs of points, each in its own frame, placed side by side in the world.
    fn two_scans() -> Vec<Scan> {
        let slab = |name: &str, pose: DMat4| {
            let pts = (0..40_000)
                .map(|k| {
                    let (i, j) = ((k % 200) as f32, (k / 200) as f32);
                    Vec3::new(
                        i * 0.02,
                        j * 0.01,
                        ((i * 0.3).sin() + (j * 0.2).cos()) * 0.1,
                    )
                })
                .collect();
            let mut s = Scan::from_points(name, pts);
            s.pose = pose;
            s
        };
        let turn = DMat4::from_rotation_translation(
            DQuat::from_rotation_z(0.7),
            DVec3::new(3.0, 1.0, 0.5),
        );
        vec![slab("a", DMat4::IDENTITY), slab("b", turn)]
    }

    #[test]
    fn the_default_diagonal_does_not_depend_on_the_order_or_a_rigid_motion() {
        let scans = two_scans();
        let d = robust_diagonal(&scans);
        assert!(d > 3.0 && d < 8.0, "diagonal {d}");
        let swapped: Vec<Scan> = scans.iter().rev().cloned().collect();
        assert_eq!(robust_diagonal(&swapped).to_bits(), d.to_bits());
        // A georeferenced placement of the whole site: far offset and a turn.
        let site = DMat4::from_rotation_translation(
            DQuat::from_rotation_z(-1.1) * DQuat::from_rotation_x(0.2),
            DVec3::new(512_345.1, 5_412_345.7, 310.0),
        );
        let moved: Vec<Scan> = scans
            .iter()
            .map(|s| {
                let mut m = s.clone();
                m.pose = site * s.pose;
                m
            })
            .collect();
        let dm = robust_diagonal(&moved);
        assert!((dm - d).abs() < 1e-6 * d, "{dm} vs {d}");
    }

    #[test]
    fn the_views_of_the_first_scans_are_kept_while_they_fit() {
        let all = [true; 4];
        assert_eq!(views_to_keep(&[50, 50, 50, 50], &all, 10, 210), [true; 4]);
        assert_eq!(
            views_to_keep(&[50, 50, 50, 50], &all, 10, 160),
            [true, true, true, false]
        );
        // A prefix: the small view after one that does not fit is not kept either.
        assert_eq!(
            views_to_keep(&[50, 80, 10, 50], &all, 0, 100),
            [true, false, false, false]
        );
        // Views the merge does not use are skipped, not counted.
        assert_eq!(
            views_to_keep(&[50, 80, 50, 50], &[true, false, true, true], 0, 100),
            [true, false, true, false]
        );
        assert_eq!(views_to_keep(&[50, 50], &all, 200, 100), [false, false]);
        assert_eq!(views_to_keep(&[], &[], 0, 100), Vec::<bool>::new());
    }

    #[test]
    fn held_scans_are_kept_while_they_and_the_views_fit() {
        // Scans of 30 each, views of 50: 3 held files start at 90 and end at 150 kept views.
        assert_eq!(files_to_hold(&[30, 30, 30], &[50, 50, 50], 10, 160), 3);
        // The views alone reach 150: with a margin of 20 nothing fits.
        assert_eq!(files_to_hold(&[30, 30, 30], &[50, 50, 50], 20, 165), 0);
        // Views not kept: only the held scans count, as many as fit at the start.
        assert_eq!(files_to_hold(&[30, 30, 30], &[0, 0, 0], 10, 75), 2);
        // Large scans, small views: the start decides.
        assert_eq!(files_to_hold(&[100, 100, 10], &[5, 5, 5], 0, 150), 1);
        // Views that grow faster than the held scans shrink: the middle decides.
        assert_eq!(files_to_hold(&[10, 10, 10], &[100, 100, 0], 0, 205), 2);
        assert_eq!(files_to_hold(&[], &[5, 5], 0, 150), 0);
    }
}
