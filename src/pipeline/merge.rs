//! The merge stage: each selected scan's points against its own view and every partner view
//! that may share surface (eq. 6–12), one input file at a time, the views coming from the
//! store. What becomes of the results is the [`Sink`]'s business.

use super::catalog::{Inputs, Opened};
use crate::error::{Error, Result};
use crate::merge::cull::PointCells;
use crate::merge::union::{union_scan, Occlusion, UnionParams, UnionTarget};
use crate::merge::{self, Accum, MergeParams, MergeStats, Target};
use crate::products::MergeMaps;
use crate::progress::Observer;
use crate::report::CatalogScan;
use crate::scan::Scan;
use crate::store::{view_bytes, Summary, ViewStore};
use crate::view::point_values;
use std::time::Instant;

/// What merging a scan allocates per point once its inputs are loaded: the weighted sums
/// (8 bytes), its cells and their index (about 8), its own SSAO and flags (5), the merged value
/// and the copy handed to the writer (8), and the cells' sort while they are built (16).
const MERGE_BYTES_PER_POINT: u64 = 48;

/// What reading the next scan's per-point products ahead holds per point at most: the file
/// (16 bytes) and its decoded arrays (16).
const AHEAD_BYTES_PER_POINT: u64 = 32;

/// One scan merged.
#[derive(Debug, Clone)]
pub struct Merged {
    /// Its index in the catalog.
    pub index: usize,
    /// Single-view SSAO per point.
    pub ssao: Vec<f32>,
    /// Final AO per point (MVAO, or the SSAO with `ssao_only`).
    pub ao: Vec<f32>,
    /// Points with no valid SSAO sample.
    pub no_sample: u64,
    /// Merge counters.
    pub stats: MergeStats,
    /// Bent normal per point (scan-local frame), when asked for.
    pub bent: Option<Vec<glam::Vec3>>,
}

/// What the merge hands on for one input file, per scan of the file (empty, or `None`, for a
/// scan not selected).
#[derive(Debug, Default)]
pub struct FileValues {
    /// AO per point.
    pub ao: Vec<Vec<f32>>,
    /// Bent normal per point (scan-local frame), when asked for.
    pub bent: Vec<Option<Vec<glam::Vec3>>>,
}

/// Where the merged scans go.
pub trait Sink {
    /// Scan `scan` was merged; `own` are its maps and `sum` its summary.
    fn scan(&mut self, scan: &Scan, m: &Merged, own: &MergeMaps, sum: &Summary) -> Result<()>;
    /// Every selected scan of input file `fi` was merged, with these values.
    fn file(
        &mut self,
        fi: usize,
        opened: Opened<'_>,
        values: FileValues,
        store: &mut dyn ViewStore,
    ) -> Result<()>;
    /// The stage is over.
    fn finish(&mut self) -> Result<()> {
        Ok(())
    }
}

/// What the merge stage works on.
pub struct MergeJob<'a> {
    /// The catalog.
    pub cat: &'a [CatalogScan],
    /// The scans to merge, by index.
    pub selected: &'a [bool],
    /// Whether scan `i`'s points may correspond to scan `j`'s.
    pub partner: &'a dyn Fn(usize, usize) -> bool,
    /// The merge parameters.
    pub mp: MergeParams,
    /// Keep each scan's own SSAO instead of merging.
    pub ssao_only: bool,
    /// Union occlusion parameters; where `occlusion` unites a scan they replace the average.
    pub union: UnionParams,
    /// How the views are combined.
    pub occlusion: Occlusion,
    /// Compute bent normals (by the union's rays, in either mode).
    pub bent: bool,
}

/// Merges the selected scans file by file into `sink`. Returns the bytes of inputs and
/// per-point products read (the store counts the maps) and the wall time.
pub fn run(
    job: &MergeJob<'_>,
    inputs: &dyn Inputs,
    store: &mut dyn ViewStore,
    sink: &mut dyn Sink,
    obs: &dyn Observer,
) -> Result<(u64, f64)> {
    let cat = job.cat;
    let n = cat.len();
    let t0 = Instant::now();
    let total: u64 = (0..n)
        .filter(|&i| job.selected[i])
        .map(|i| cat[i].points as u64)
        .sum();
    obs.stage("merge", total);
    // The scans in the order they are merged, and every map the merge will ask for in order:
    // its own first, then its partners' (in the order the merge visits them).
    let mut order = Vec::new();
    for fi in 0..inputs.files() {
        order.extend((0..n).filter(|&i| cat[i].file == fi && job.selected[i]));
    }
    let mut loads = Vec::new();
    for &i in &order {
        loads.push(i);
        loads.extend((0..n).filter(|&j| j != i && (job.partner)(i, j)));
    }
    store.expect(loads);
    let mut read = 0u64;
    let mut pos = 0;
    for fi in 0..inputs.files() {
        let mine: Vec<usize> = order
            .iter()
            .copied()
            .filter(|&i| cat[i].file == fi)
            .collect();
        if mine.is_empty() {
            continue;
        }
        let opened = inputs.for_merge(fi)?;
        read += inputs.bytes(fi);
        let mut values = FileValues {
            ao: vec![Vec::new(); opened.scans.len()],
            bent: vec![None; opened.scans.len()],
        };
        for &i in &mine {
            let s = &opened.scans[cat[i].index];
            pos += 1;
            let next = order.get(pos).copied();
            let pts = store.points(i, next)?;
            read += view_bytes(0, s.len() as u64);
            store.reserve(
                MERGE_BYTES_PER_POINT * s.len() as u64
                    + next.map_or(0, |j| AHEAD_BYTES_PER_POINT * cat[j].points as u64),
            );
            // The own maps come through the store: they are other scans' partner maps too.
            let own = store.maps(i, s.pose, &job.mp)?;
            let (ssao, no_sample) = point_values(&pts.pixel, &own.ao, &own.no_sample);
            let union = !job.ssao_only
                && job
                    .occlusion
                    .unites(job.mp.largest_all_round, own.projection.all_round());
            let (mut ao, stats) = if job.ssao_only {
                (ssao.clone(), MergeStats::default())
            } else if union {
                let united = s.len() as u64;
                (
                    Vec::new(),
                    MergeStats {
                        united,
                        ..Default::default()
                    },
                )
            } else {
                merge_one(job, i, s, &pts.radii, &pts.pixel, &ssao, &own, store)?
            };
            let mut bent = None;
            if union || job.bent {
                let (u, b) = union_one(job, i, s, &pts.radii, &pts.pixel, &ssao, &own, store)?;
                if union {
                    ao = u;
                }
                bent = b;
            }
            obs.advance(s.len() as u64);
            let m = Merged {
                index: i,
                ssao,
                ao,
                no_sample,
                stats,
                bent,
            };
            let sum = store.summary(i)?;
            sink.scan(s, &m, &own, &sum)?;
            values.ao[cat[i].index] = m.ao;
            values.bent[cat[i].index] = m.bent;
        }
        sink.file(fi, opened, values, store)?;
    }
    sink.finish()?;
    let secs = t0.elapsed().as_secs_f64();
    obs.done("merge", secs);
    Ok((read, secs))
}

/// Scan `i`'s points against its own view and each partner's, added one view at a time in
/// index order (so the sums do not depend on which views the store held).
#[allow(clippy::too_many_arguments)]
fn merge_one(
    job: &MergeJob<'_>,
    i: usize,
    s: &Scan,
    radii: &[f32],
    pixel: &[u32],
    own_ssao: &[f32],
    own: &std::sync::Arc<MergeMaps>,
    store: &mut dyn ViewStore,
) -> Result<(Vec<f32>, MergeStats)> {
    let cells = PointCells::new(&s.points, radii, s.pose);
    let t = Target {
        index: i,
        points: &s.points,
        radii,
        own_pixel: pixel,
        pose: s.pose,
        proj: &own.projection,
        cells: Some(&cells),
    };
    let mut acc = Accum::new(s.len());
    for j in (0..job.cat.len()).filter(|&j| (job.partner)(i, j)) {
        let (pose_j, m) = if j == i {
            (s.pose, own.clone())
        } else {
            let pose = job.cat[j].pose;
            (pose, store.maps(j, pose, &job.mp)?)
        };
        let v = m
            .view(pose_j)
            .ok_or_else(|| Error::Param("maps used before placing (internal error)".into()))?;
        merge::accumulate(&mut acc, &t, j, &v, &job.mp, &|_| {});
    }
    Ok(acc.finish(own_ssao))
}

/// Scan `i`'s union occlusion (and bent normals when asked for) against its own view and
/// every partner's, all held at once: the rays cross every view that overlaps a point.
#[allow(clippy::too_many_arguments)]
fn union_one(
    job: &MergeJob<'_>,
    i: usize,
    s: &Scan,
    radii: &[f32],
    pixel: &[u32],
    own_ssao: &[f32],
    own: &std::sync::Arc<MergeMaps>,
    store: &mut dyn ViewStore,
) -> Result<(Vec<f32>, Option<Vec<glam::Vec3>>)> {
    let mut held = Vec::new();
    for j in (0..job.cat.len()).filter(|&j| (job.partner)(i, j)) {
        if j == i {
            held.push((s.pose, own.clone()));
        } else {
            let pose = job.cat[j].pose;
            held.push((pose, store.maps(j, pose, &job.mp)?));
        }
    }
    let internal = || Error::Param("maps used before placing (internal error)".into());
    let views = held
        .iter()
        .map(|(pose, m)| m.view(*pose).ok_or_else(internal))
        .collect::<Result<Vec<_>>>()?;
    let own_view = own.view(s.pose).ok_or_else(internal)?;
    let t = UnionTarget {
        index: i,
        points: &s.points,
        radii,
        own_pixel: pixel,
        own: own_view.maps,
        own_proj: own_view.proj,
        pose: s.pose,
        fallback: own_ssao,
    };
    Ok(union_scan(&t, &views, &job.union, job.bent))
}
