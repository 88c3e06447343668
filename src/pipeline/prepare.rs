//! The prepare stage: each scan's view (sensor model, normals and radii, G-buffer, SSAO and
//! border field) computed where the store has none current, and stored with its summary.

use super::catalog::{changed, data_hash, Inputs};
use super::occlusion::prepare_view;
use crate::error::{Error, Result};
use crate::products::manifest::InputRecord;
use crate::progress::Observer;
use crate::report::CatalogScan;
use crate::scan::Scan;
use crate::sensor::ProjectionChoice;
use crate::ssao::SsaoParams;
use crate::store::{Summary, ViewStore};
use crate::view::{depth_range, PreparedView};
use rayon::prelude::*;
use std::borrow::Cow;
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

/// Scans of at most this many points are prepared side by side, several at once: on a small
/// scan the per-view stages cannot keep every core busy (the sensor fit and the stage set-up
/// are serial), while a scan above it fills the cores on its own.
pub const SMALL_SCAN_POINTS: usize = 1 << 18;

/// Points of small scans gathered before they are prepared together: bounds the views held
/// in memory beyond what the serial order holds.
pub const BATCH_POINTS: usize = 1 << 20;

/// An input file read whose small scans wait to be prepared.
struct Pending {
    name: String,
    record: Option<InputRecord>,
    scans: Vec<Scan>,
    /// The catalog entries of its scans to prepare.
    stale: Vec<usize>,
}

/// Small scans read but not yet prepared, in input order.
#[derive(Default)]
struct Batch {
    files: Vec<Pending>,
    points: usize,
}

/// Prepares the views of the scans marked in `need` that `store` does not hold current, one
/// input file at a time; small scans of consecutive files together (see [`SMALL_SCAN_POINTS`]).
/// Views are stored in input order whatever order they are computed in.
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
    let mut batch = Batch::default();
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
        // A failure leaves the store as one scan at a time would: every earlier view put.
        let opened = match inputs.for_prepare(fi) {
            Ok(o) => o,
            Err(e) => {
                flush(&mut batch, cat, store, choice, sp, obs)?;
                return Err(e);
            }
        };
        out.bytes_read += opened.record.as_ref().map_or(0, |r| r.size);
        let fresh = |&i: &usize| data_hash(&opened.scans[cat[i].index]) == cat[i].data_hash;
        if opened.read_again && !stale.iter().all(fresh) {
            flush(&mut batch, cat, store, choice, sp, obs)?;
            return Err(changed(&name));
        }
        let small = stale
            .iter()
            .all(|&i| opened.scans[cat[i].index].len() <= SMALL_SCAN_POINTS);
        match opened.scans {
            Cow::Owned(scans) if small => {
                batch.points += stale
                    .iter()
                    .map(|&i| scans[cat[i].index].len())
                    .sum::<usize>();
                batch.files.push(Pending {
                    name,
                    record: opened.record,
                    scans,
                    stale,
                });
                if batch.points >= BATCH_POINTS {
                    out.made += flush(&mut batch, cat, store, choice, sp, obs)?;
                }
            }
            scans => {
                out.made += flush(&mut batch, cat, store, choice, sp, obs)?;
                for &i in &stale {
                    let s = &scans[cat[i].index];
                    let v = prepare_view(s, choice, sp)?;
                    let sum = summarize(s, &v, &name)?;
                    store.put(i, opened.record.as_ref(), sum, v)?;
                    out.made += 1;
                    obs.advance(s.len() as u64);
                }
            }
        }
    }
    out.made += flush(&mut batch, cat, store, choice, sp, obs)?;
    store.finish_prepare()?;
    out.secs = t0.elapsed().as_secs_f64();
    obs.done("prepare", out.secs);
    Ok(out)
}

/// Prepares the scans of `batch` in parallel and stores their views in input order (the first
/// failure in that order is the error, as one at a time); returns how many were made.
fn flush(
    batch: &mut Batch,
    cat: &[CatalogScan],
    store: &mut dyn ViewStore,
    choice: ProjectionChoice,
    sp: &SsaoParams,
    obs: &dyn Observer,
) -> Result<usize> {
    let files = std::mem::take(&mut batch.files);
    batch.points = 0;
    let jobs: Vec<(usize, usize)> = files
        .iter()
        .enumerate()
        .flat_map(|(f, p)| p.stale.iter().map(move |&i| (f, i)))
        .collect();
    let views: Vec<Result<(Summary, PreparedView)>> = jobs
        .par_iter()
        .map(|&(f, i)| {
            let s = &files[f].scans[cat[i].index];
            let v = prepare_view(s, choice, sp)?;
            Ok((summarize(s, &v, &files[f].name)?, v))
        })
        .collect();
    for (&(f, i), made) in jobs.iter().zip(views) {
        let (sum, v) = made?;
        store.put(i, files[f].record.as_ref(), sum, v)?;
        obs.advance(files[f].scans[cat[i].index].len() as u64);
    }
    Ok(jobs.len())
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

    /// A cheap horizon march for the tests' small views.
    fn small_ssao() -> SsaoParams {
        SsaoParams {
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
        }
    }

    #[test]
    fn a_stored_view_comes_back_as_it_was_put() {
        let station = Station::equirect(glam::DVec3::new(0.0, 0.0, 1.5), 0.0, 120, 60);
        let mut scan = scan_scene(&Scene::room(), &station, 0.0, 1, "s");
        scan.pose = station.pose();
        let sp = small_ssao();
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
        };
        let m = store.maps(0, scan.pose, &prm).unwrap();
        assert_eq!(m.ao, v.ssao.ao);
        assert!(m.view(scan.pose).is_some(), "maps come placed");
        // Asked again: the same placed maps, not a second copy.
        assert!(Arc::ptr_eq(&m, &store.maps(0, scan.pose, &prm).unwrap()));
        let views = store.into_views();
        assert!(views[0].is_some() && views[1].is_none());
    }

    /// Scans handed over owned, as input files are: the path that prepares small scans
    /// together.
    struct Owned(Vec<Scan>);

    impl crate::pipeline::catalog::Inputs for Owned {
        fn files(&self) -> usize {
            self.0.len()
        }
        fn name(&self, fi: usize) -> String {
            self.0[fi].name.clone()
        }
        fn bytes(&self, _fi: usize) -> u64 {
            0
        }
        fn for_prepare(&mut self, fi: usize) -> Result<crate::pipeline::catalog::Opened<'_>> {
            Ok(crate::pipeline::catalog::Opened {
                scans: Cow::Owned(vec![self.0[fi].clone()]),
                record: None,
                read_again: false,
                placed: None,
            })
        }
        fn for_merge(&self, _fi: usize) -> Result<crate::pipeline::catalog::Opened<'_>> {
            unreachable!("the prepare stage only")
        }
    }

    #[test]
    fn small_scans_prepared_together_store_the_views_one_at_a_time_would() {
        let scans: Vec<Scan> = (0..5)
            .map(|k| {
                let p = glam::DVec3::new(0.3 * k as f64 - 0.6, 0.2, 1.4);
                let station = Station::equirect(p, 0.5 * k as f64, 96 + 8 * k, 48 + 4 * k);
                let mut s = scan_scene(&Scene::room(), &station, 0.0, 1, &format!("s{k}"));
                s.pose = station.pose();
                s
            })
            .collect();
        assert!(scans.iter().all(|s| s.len() <= SMALL_SCAN_POINTS));
        let sp = small_ssao();
        let choice = crate::sensor::ProjectionChoice::Auto;
        let cat = crate::pipeline::catalog::from_scans(&scans).unwrap();
        let mut store = MemoryStore::new(scans.len());
        let done = run(
            &cat.scans,
            &[true, false, true, true, true],
            &mut Owned(scans.clone()),
            &mut store,
            choice,
            &sp,
            &crate::progress::Silent,
        )
        .unwrap();
        assert_eq!((done.made, done.reused), (4, 0));
        let prm = MergeParams {
            neighbors: 1,
            dmin: 0.0,
            dmax: 10.0,
            border_px: 64.0,
        };
        for (i, s) in scans.iter().enumerate() {
            if i == 1 {
                assert!(!store.is_current(1), "a scan not asked for is not prepared");
                continue;
            }
            let v = prepare_view(s, choice, &sp).unwrap();
            let m = store.maps(i, s.pose, &prm).unwrap();
            assert_eq!(m.ao, v.ssao.ao, "scan {i}");
            let p = store.points(i, None).unwrap();
            assert_eq!((p.radii, p.pixel), (v.radii.clone(), v.pixel.clone()));
            assert_eq!(store.summary(i).unwrap().points, s.len());
        }
    }
}
