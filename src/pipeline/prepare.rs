//! The prepare stage: each scan's view (sensor model, normals and radii, G-buffer, SSAO and
//! border field) computed where the store has none current, and stored with its summary.

use super::catalog::{changed, data_hash, Inputs};
use super::occlusion::prepare_view;
use crate::error::{Error, Result};
use crate::progress::Observer;
use crate::report::CatalogScan;
use crate::scan::Scan;
use crate::sensor::ProjectionChoice;
use crate::ssao::SsaoParams;
use crate::store::{Summary, ViewStore};
use crate::view::{depth_range, PreparedView};
use std::time::Instant;

/// What the prepare stage did.
#[derive(Debug, Clone, Copy, Default)]
pub struct Prepared {
    /// Views computed.
    pub made: usize,
    /// Views the store already held.
    pub reused: usize,
    /// Bytes of input read.
    pub bytes_read: u64,
    /// Wall time (seconds).
    pub secs: f64,
}

/// Prepares the views of the scans marked in `need` that `store` does not hold current, one
/// input file at a time.
#[allow(clippy::too_many_arguments)]
pub fn run(
    cat: &[CatalogScan],
    need: &[bool],
    inputs: &mut dyn Inputs,
    store: &mut dyn ViewStore,
    choice: ProjectionChoice,
    sp: &SsaoParams,
    obs: &dyn Observer,
) -> Result<Prepared> {
    let t0 = Instant::now();
    obs.stage("prepare", cat.iter().map(|c| c.points as u64).sum());
    let mut out = Prepared::default();
    let n = cat.len();
    for fi in 0..inputs.files() {
        let mine: Vec<usize> = (0..n).filter(|&i| cat[i].file == fi && need[i]).collect();
        let stale: Vec<usize> = mine
            .iter()
            .copied()
            .filter(|&i| !store.is_current(i))
            .collect();
        out.reused += mine.len() - stale.len();
        if stale.is_empty() {
            obs.advance(
                cat.iter()
                    .filter(|c| c.file == fi)
                    .map(|c| c.points as u64)
                    .sum(),
            );
            continue;
        }
        let name = inputs.name(fi);
        let opened = inputs.for_prepare(fi)?;
        out.bytes_read += opened.record.as_ref().map_or(0, |r| r.size);
        for &i in &stale {
            let s = &opened.scans[cat[i].index];
            if opened.read_again && data_hash(s) != cat[i].data_hash {
                return Err(changed(&name));
            }
            let v = prepare_view(s, choice, sp)?;
            let sum = summarize(s, &v, &name)?;
            store.put(i, opened.record.as_ref(), sum, v)?;
            out.made += 1;
            obs.advance(s.len() as u64);
        }
    }
    store.finish_prepare()?;
    out.secs = t0.elapsed().as_secs_f64();
    obs.done("prepare", out.secs);
    Ok(out)
}

/// The summary of scan `s`'s view `v` (of input `file`); an error when its depths or radii
/// are not finite, which no stage after could use.
pub fn summarize(s: &Scan, v: &PreparedView, file: &str) -> Result<Summary> {
    let (dmin, dmax) = depth_range(&v.depth);
    let max_radius = v.radii.iter().copied().fold(0.0, f32::max);
    if !(dmin.is_finite() && dmax.is_finite() && max_radius.is_finite()) {
        return Err(Error::scan(
            file,
            format!(
                "scan {}: depths or point radii are not finite (depth {dmin}..{dmax} m, largest \
                 radius {max_radius} m): coordinates out of usable range",
                s.name
            ),
        ));
    }
    let (_, no_sample) = v.point_ssao();
    let proj = &v.sensor.projection;
    Ok(Summary {
        points: s.len(),
        max_radius,
        depth_min: dmin,
        depth_max: dmax,
        ortho: proj.sensor_model() == crate::projection::SensorModel::Ortho,
        no_sample,
        filled: v.gbuf.filled(),
        sensor_model: proj.sensor_model().to_string(),
        map_size: [proj.width, proj.height],
        native_grid: v.sensor.grid_pixels.is_some(),
        fit_rms_px: v.sensor.fit_rms_px,
        reason: v.sensor.reason.clone(),
        normals: v.normals_note.clone(),
        times: v.times.iter().map(|(k, t)| (k.to_string(), *t)).collect(),
        ssao_levels: v.ssao.levels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::merge::MergeParams;
    use crate::pipeline::occlusion::prepare_view;
    use crate::ssao::SsaoParams;
    use crate::store::{MemoryStore, ViewStore};
    use crate::synth::{scan_scene, Scene, Station};
    use std::sync::Arc;

    #[test]
    fn a_stored_view_comes_back_as_it_was_put() {
        let station = Station::equirect(glam::DVec3::new(0.0, 0.0, 1.5), 0.0, 120, 60);
        let mut scan = scan_scene(&Scene::room(), &station, 0.0, 1, "s");
        scan.pose = station.pose();
        let sp = SsaoParams {
            estimator: crate::ssao::Estimator::Horizon,
            radius: 0.2,
            tmax: 0.4,
            falloff: Default::default(),
            samples: 8,
            directions: 4,
            steps: 4,
            seed: 1,
            blur: true,
            sampling: Default::default(),
        };
        let v = prepare_view(&scan, crate::sensor::ProjectionChoice::Auto, &sp).unwrap();
        let sum = summarize(&scan, &v, "s").unwrap();
        let mut store = MemoryStore::new(2);
        assert!(!store.is_current(0));
        assert!(
            store.points(0, None).is_err(),
            "a view asked for before it was put"
        );
        store.put(0, None, sum.clone(), v.clone()).unwrap();
        assert!(store.is_current(0) && !store.is_current(1));
        assert_eq!(store.summary(0).unwrap().points, scan.len());
        let p = store.points(0, None).unwrap();
        assert_eq!((p.radii, p.pixel), (v.radii.clone(), v.pixel.clone()));
        let prm = MergeParams {
            neighbors: 1,
            dmin: 0.0,
            dmax: 10.0,
            border_px: 64.0,
            spacing: 0.0,
            largest_all_round: false,
        };
        let m = store.maps(0, scan.pose, &prm).unwrap();
        assert_eq!(m.ao, v.ssao.ao);
        assert!(m.view(scan.pose).is_some(), "maps come placed");
        // Asked again: the same placed maps, not a second copy.
        assert!(Arc::ptr_eq(&m, &store.maps(0, scan.pose, &prm).unwrap()));
        let views = store.into_views();
        assert!(views[0].is_some() && views[1].is_none());
    }
}
