//! The stages of a run, in order: `catalog` (every input read once) → `plan` (parameters,
//! pairs, memory) → `prepare` (per scan: sensor model, normals, G-buffer, border) →
//! `occlusion` (its AO map, stored with it) → `merge` (each scan against the views that may
//! share its surface) → `write` (outputs
//! and the report). They run over a `ViewStore`: the work directory with its budgeted
//! cache for `mvao merge` and `mvao prepare` ([`run`]), memory for library use and the
//! tests ([`compute`]). The stages have no math of their own.

pub(crate) mod catalog;
pub(crate) mod merge;
pub(crate) mod occlusion;
pub(crate) mod plan;
pub(crate) mod prepare;
pub(crate) mod write;

/// Kept for `mvao info`, which still names it here; it lives in `crate::site`.
pub use crate::site::world_bounds;

use crate::config::{ComputeParams, Config};
use crate::error::{Error, Result};
use crate::io::dataset::Placer;
use crate::merge::union::{Occlusion, UnionParams};
use crate::merge::{MergeParams, MergeStats};
use crate::products::MergeMaps;
use crate::progress::Observer;
use crate::radius::SceneScale;
use crate::report::{Parameters, Plan, Report, ScanReport, Totals};
use crate::scan::Scan;
use crate::site::Pairs;
use crate::ssao::SsaoParams;
use crate::store::{MemoryStore, Summary, ViewStore, WorkDirSetup, WorkDirStore};
use crate::view::PreparedView;
use catalog::{Catalog, Inputs as _, Opened};
use glam::DVec3;
use merge::{FileValues, MergeJob, Merged, Sink};
use plan::{robust_diagonal, ssao_params};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Result of the in-memory computation for one scan.
#[derive(Debug, Clone)]
pub struct ScanResult {
    /// The per-view products.
    pub view: PreparedView,
    /// Single-view SSAO per point.
    pub ssao: Vec<f32>,
    /// Final AO per point (MVAO, or SSAO with `ssao_only`).
    pub ao: Vec<f32>,
    /// Points with no valid SSAO sample.
    pub no_sample: u64,
    /// Merge counters.
    pub merge: MergeStats,
    /// Bent normal per point (scan-local frame), with `bent_normals`.
    pub bent: Option<Vec<glam::Vec3>>,
}

/// The output of [`compute`].
#[derive(Debug, Clone)]
pub struct Computed {
    /// Per scan, input order.
    pub scans: Vec<ScanResult>,
    /// SSAO parameters used.
    pub ssao: SsaoParams,
    /// Merge parameters used.
    pub merge: MergeParams,
    /// How the defaults were derived.
    pub defaults_note: String,
    /// Wall time of the merge stage (seconds).
    pub merge_s: f64,
}

/// The whole computation on in-memory scans (poses set): the same stages as [`run`] over a
/// `MemoryStore`, without writing.
pub fn compute(scans: &[Scan], prm: &ComputeParams, obs: &dyn Observer) -> Result<Computed> {
    let cat = catalog::from_scans(scans)?;
    let (sp, mut note) = ssao_params(prm, || SceneScale {
        diagonal: robust_diagonal(&cat.samples),
        spacing: crate::radius::spacing_of(scans),
    })?;
    let n = scans.len();
    let need = vec![true; n];
    let mut store = MemoryStore::new(n);
    let mut inputs = catalog::InMemory(scans);
    prepare::run(
        &cat.scans,
        &need,
        &mut inputs,
        &mut store,
        prm.projection,
        &sp,
        obs,
    )?;
    let mplan = merge_plan(&mut store, &need, prm, &cat, &sp, &mut note)?;
    let partner = |i: usize, j: usize| mplan.meets(i, j);
    let job = MergeJob {
        cat: &cat.scans,
        selected: &need,
        partner: &partner,
        mp: mplan.mp,
        ssao_only: prm.ssao_only,
        union: union_params(prm, &sp, &mplan.mp),
        occlusion: prm.occlusion,
        bent: prm.bent_normals,
    };
    let mut sink = Collect(vec![None; n]);
    let (_, merge_s) = merge::run(&job, &inputs, &mut store, &mut sink, obs)?;
    let scans = store
        .into_views()
        .into_iter()
        .zip(sink.0)
        .map(|(v, m)| match (v, m) {
            (Some(view), Some(m)) => Ok(ScanResult {
                view,
                ssao: m.ssao,
                ao: m.ao,
                no_sample: m.no_sample,
                merge: m.stats,
                bent: m.bent,
            }),
            _ => Err(Error::Param(
                "a scan was not merged (internal error)".into(),
            )),
        })
        .collect::<Result<_>>()?;
    Ok(Computed {
        scans,
        ssao: sp,
        merge: mplan.mp,
        defaults_note: note,
        merge_s,
    })
}

/// The union occlusion's parameters: rays reach `t_max`, or twice the largest depth of the
/// views at `t_max = ∞`; the thickness defaults to a tenth of the SSAO radius.
///
/// Samples per ray: 24 to a finite `t_max`; twice that at `t_max = ∞`, where the reach is the
/// whole site and 24 quadratically spaced samples step over thin occluders a few metres
/// from the point (`docs/accuracy.md`, "Samples per ray at ∞").
fn union_params(prm: &ComputeParams, sp: &SsaoParams, mp: &MergeParams) -> UnionParams {
    let reach = if sp.tmax.is_finite() {
        sp.tmax
    } else if mp.dmax > 0.0 && mp.dmax.is_finite() {
        2.0 * mp.dmax
    } else {
        100.0 * sp.radius
    };
    // `auto` unites only at `t_max = ∞`, where 8 rays took the error of averaging on stations
    // under open sky down to 0.3–0.7 of it (`docs/accuracy.md`).
    let default_rays = if prm.occlusion == Occlusion::Auto && mp.largest_all_round {
        crate::merge::union::AUTO_RAYS
    } else {
        crate::merge::union::UNION_RAYS
    };
    UnionParams {
        rays: prm.rays.unwrap_or(default_rays).max(2),
        steps: if sp.tmax.is_finite() { 24 } else { 48 },
        tmax: sp.tmax,
        falloff: sp.falloff,
        reach,
        thickness: prm.thickness.unwrap_or(0.1 * sp.radius),
        seed: sp.seed,
        filter: prm.union_filter,
        views: prm.union_views,
    }
}

/// The merge's sink of [`compute`]: every scan's values, kept.
struct Collect(Vec<Option<Merged>>);

impl Sink for Collect {
    fn scan(&mut self, _s: &Scan, m: &Merged, _own: &MergeMaps, _sum: &Summary) -> Result<()> {
        self.0[m.index] = Some(m.clone());
        Ok(())
    }
    fn file(
        &mut self,
        _fi: usize,
        _opened: Opened<'_>,
        _values: FileValues,
        _store: &mut dyn ViewStore,
    ) -> Result<()> {
        Ok(())
    }
}

/// What the merge needs once the views are prepared: its parameters and the pair test with
/// the scans' radii.
struct MergePlan {
    mp: MergeParams,
    pairs: Pairs,
    max_rad: Vec<f64>,
    /// Per-view stage times summed over the scans.
    times: Vec<(String, f64)>,
}

impl MergePlan {
    /// Whether scan `i`'s points may correspond to scan `j`'s.
    fn meets(&self, i: usize, j: usize) -> bool {
        self.pairs.meets(i, j, self.max_rad[i].max(self.max_rad[j]))
    }
}

/// The merge plan from the summaries of the scans marked in `need` (d_min and d_max from
/// their depths, eq. 7's reach from their radii), adding to the note how defaults were set.
fn merge_plan(
    store: &mut dyn ViewStore,
    need: &[bool],
    prm: &ComputeParams,
    cat: &Catalog,
    sp: &SsaoParams,
    note: &mut String,
) -> Result<MergePlan> {
    let tmax = sp.tmax;
    let mut sums: Vec<Option<Summary>> = vec![None; need.len()];
    for i in (0..need.len()).filter(|&i| need[i]) {
        sums[i] = Some(store.summary(i)?);
    }
    let ranges: Vec<(f32, f32)> = sums
        .iter()
        .flatten()
        .filter(|s| !s.ortho)
        .map(|s| (s.depth_min, s.depth_max))
        .collect();
    let mp = plan::merge_params(prm, &ranges, sp, note);
    let mut times: Vec<(String, f64)> = Vec::new();
    for s in sums.iter().flatten() {
        for (k, t) in &s.times {
            match times.iter_mut().find(|(n, _)| n == k) {
                Some(e) => e.1 += t,
                None => times.push((k.clone(), *t)),
            }
        }
    }
    let max_rad: Vec<f64> = sums
        .iter()
        .map(|s| s.as_ref().map_or(0.0, |s| s.max_radius as f64))
        .collect();
    let bounds: Vec<(DVec3, DVec3)> = cat
        .scans
        .iter()
        .map(|c| (DVec3::from(c.bounds[0]), DVec3::from(c.bounds[1])))
        .collect();
    let pairs = Pairs::new(
        bounds,
        &cat.occupancy,
        tmax,
        max_rad.iter().copied().fold(0.0, f64::max),
    );
    Ok(MergePlan {
        mp,
        pairs,
        max_rad,
        times,
    })
}

/// What the stages of a run over the input files give.
pub struct Outcome {
    /// The plan.
    pub plan: Plan,
    /// Per-scan reports (merged scans only).
    pub scans: Vec<ScanReport>,
    /// SSAO parameters used.
    pub ssao: SsaoParams,
    /// Merge parameters used.
    pub merge: MergeParams,
    /// Union occlusion parameters used (the union or bent normals ran).
    pub union: Option<UnionParams>,
    /// How the defaults were derived.
    pub defaults_note: String,
    /// Per-stage seconds.
    pub times: Vec<(String, f64)>,
    /// Bytes read per stage (inputs and products).
    pub bytes_read: Vec<(String, u64)>,
    /// Products recomputed / reused.
    pub prepared: (usize, usize),
    /// Maps loaded by the merge (cache misses).
    pub map_loads: u64,
    /// Views the prepare stage handed to the merge.
    pub views_kept: u64,
    /// Per merged scan: (name, single-view SSAO, AO), kept only when asked (for `--reference`).
    pub values: Vec<(String, Vec<f32>, Vec<f32>)>,
    /// Warnings.
    pub warnings: Vec<String>,
    /// The alignment file used, if any.
    pub alignment: Option<PathBuf>,
    /// The reference values of the merged scans (`--reference`), checked before the work.
    pub refs: Option<Vec<Vec<f32>>>,
}

/// `mvao merge`: reads, computes, writes. Returns the report (also written as `report.json`);
/// progress, warnings and the summary lines go to `obs`. With `cfg.dry_run` nothing is computed
/// and the report holds the plan.
pub fn run(cfg: &Config, obs: &dyn Observer) -> Result<Report> {
    let t_all = Instant::now();
    let mut report = Report {
        version: env!("CARGO_PKG_VERSION").to_string(),
        ..Default::default()
    };
    let warn = |report: &mut Report, msg: String| {
        obs.warn(&msg);
        report.warnings.push(msg);
    };
    if cfg.scans.is_empty() {
        return Err(Error::Param("no scan given".into()));
    }
    write::check_inputs_safe(cfg)?;
    let oc = run_files(cfg, obs, cfg.reference.is_some())?;
    for w in &oc.warnings {
        warn(&mut report, w.clone());
    }
    for (k, t) in &oc.times {
        report.add_time(k, *t);
    }
    report.bytes_read = oc.bytes_read.iter().cloned().collect();
    report.alignment = oc.alignment.as_ref().map(|a| a.display().to_string());
    report.products = [oc.prepared.0, oc.prepared.1];
    report.map_loads = oc.map_loads;
    report.views_kept = oc.views_kept;
    if cfg.dry_run {
        report.plan = Some(oc.plan);
        return Ok(report);
    }
    if !cfg.prepare_only {
        obs.info(&format!(
            "radius {:.4} m, tmax {}, falloff {}, dmin {:.3} m, dmax {:.3} m ({})",
            oc.ssao.radius,
            if oc.ssao.tmax.is_finite() {
                format!("{:.4} m", oc.ssao.tmax)
            } else {
                "inf".into()
            },
            oc.ssao.falloff,
            oc.merge.dmin,
            oc.merge.dmax,
            if oc.defaults_note.is_empty() {
                "as given"
            } else {
                oc.defaults_note.as_str()
            }
        ));
    }
    if let (Some(d), Some(refs)) = (&cfg.reference, &oc.refs) {
        let names: Vec<String> = oc.values.iter().map(|v| v.0.clone()).collect();
        let ssao: Vec<Vec<f32>> = oc.values.iter().map(|v| v.1.clone()).collect();
        let aos: Vec<Vec<f32>> = oc.values.iter().map(|v| v.2.clone()).collect();
        let acc = crate::accuracy::evaluate(d, &names, Some(&ssao), &aos, refs);
        if let Some(s) = &acc.ssao {
            obs.info(&format!("single-view SSAO vs reference: {}", s.one_line()));
        }
        obs.info(&format!(
            "{} vs reference: {}",
            if cfg.compute.ssao_only {
                "result"
            } else {
                "MVAO"
            },
            acc.result.one_line()
        ));
        report.accuracy = Some(acc);
    }
    report.parameters = Parameters {
        ssao: Some(oc.ssao),
        merge: Some(oc.merge),
        defaults_note: oc.defaults_note.clone(),
        gamma: cfg.gamma,
        color: format!("{:?}", cfg.color).to_lowercase(),
        projection: format!("{:?}", cfg.compute.projection).to_lowercase(),
        ssao_only: cfg.compute.ssao_only,
        occlusion: cfg.compute.occlusion,
        union: oc.union,
    };
    report.scans = oc.scans;
    report.plan = Some(oc.plan);
    report.peak_rss_bytes = crate::sys::peak_rss();
    report.totals = Totals {
        points: report.scans.iter().map(|s| s.points as u64).sum(),
        no_ssao_sample: report.scans.iter().map(|s| s.no_ssao_sample).sum(),
        zero_merge_weight: report.scans.iter().map(|s| s.zero_merge_weight).sum(),
        wall_s: t_all.elapsed().as_secs_f64(),
        ssao_levels: report
            .scans
            .iter()
            .fold(None, |acc, s| match (acc, &s.ssao_levels) {
                (acc, None) => acc,
                (None, Some(l)) => Some(*l),
                (Some(mut a), Some(l)) => {
                    a.add(l);
                    Some(a)
                }
            }),
    };
    if cfg.prepare_only {
        return Ok(report);
    }
    write::write_report(cfg, &report)?;
    Ok(report)
}

/// The output and work directories are directories where they exist.
fn check_dirs(cfg: &Config) -> Result<()> {
    for (d, flag) in [
        (Some(&cfg.out_dir), "-o"),
        (cfg.work_dir.as_ref(), "--work"),
    ] {
        if let Some(d) = d.filter(|d| d.exists() && !d.is_dir()) {
            return Err(Error::Param(format!(
                "{flag} {}: exists and is not a directory",
                d.display()
            )));
        }
    }
    Ok(())
}

/// The stages `cfg` asks for over the input files and the work directory. `keep_values`
/// keeps each merged scan's values in memory.
pub fn run_files(cfg: &Config, obs: &dyn Observer, keep_values: bool) -> Result<Outcome> {
    let placer = Placer::new(&cfg.scans, &cfg.place)?;
    check_dirs(cfg)?;
    let budget = cfg.max_memory.unwrap_or_else(crate::sys::default_budget);
    let (mut cat, mut files) = catalog::from_files(cfg, &placer, budget, obs)?;
    let (refs, planned_outputs) = check_before_work(cfg, &cat)?;
    let prm = &cfg.compute;
    let (sp, note) = ssao_params(prm, || SceneScale {
        diagonal: robust_diagonal(&cat.samples),
        spacing: crate::radius::combined_spacing(&cat.spacings),
    })?;
    if let Some(d) = cfg.reference.as_ref().filter(|_| refs.is_some()) {
        crate::io::reference::check_reference_matches(d, sp.tmax, sp.falloff)?;
    }
    cat.samples = Vec::new();
    // The report is written last and marks a complete set: a rerun over an earlier one drops
    // the old report first, so a run that stops half way does not leave new outputs beside
    // old ones under a report that vouches for them.
    let old_report = cfg.out_dir.join("report.json");
    if !cfg.dry_run && !cfg.prepare_only && cfg.only.is_empty() && old_report.exists() {
        std::fs::remove_file(&old_report).map_err(|e| Error::io(&old_report, e))?;
    }
    let mut warnings = std::mem::take(&mut cat.warnings);
    if !cfg.dry_run {
        // Temporary files of an earlier run that was killed (their writer is gone).
        crate::products::clean_stale_temps(&cfg.out_dir, &mut warnings);
    }
    let mut planned = plan::plan(&cat.scans, &cat.occupancy, sp.tmax, budget);
    let largest_map = cat.scans.iter().map(|c| c.map_pixels).max().unwrap_or(0);
    planned.plan.occlusion_bytes = crate::ssao::working_bytes(largest_map, &sp);
    warnings.extend(lonely_warnings(cfg, &cat, &planned.lonely));
    let floor = plan::floor(cat.max_file_bytes, planned.plan.largest_view_bytes)
        + planned.plan.occlusion_bytes;
    // Freed memory the allocator keeps adds to the peak between two measurements of the map
    // cache: it is kept only when every view fits with that much to spare.
    if !cfg.dry_run && planned.plan.all_views_bytes + 2 * floor <= budget {
        crate::sys::keep_freed_memory();
    }
    warnings.extend(below_floor(budget, floor, planned.plan.occlusion_bytes));
    let base_floor = plan::floor(cat.max_file_bytes, planned.plan.largest_view_bytes);
    let (occlusion, warned) = occlusion_within(prm, &sp, &planned, base_floor, budget);
    warnings.extend(warned);
    let mut out = Outcome {
        plan: planned.plan.clone(),
        scans: Vec::new(),
        ssao: sp,
        merge: MergeParams {
            neighbors: prm.neighbors,
            dmin: 0.0,
            dmax: 0.0,
            border_px: prm.border_px,
            spacing: 0.0,
            largest_all_round: false,
        },
        union: None,
        defaults_note: note,
        times: vec![("catalog".into(), cat.secs)],
        bytes_read: vec![("catalog".into(), cat.bytes_read)],
        prepared: (0, 0),
        map_loads: 0,
        views_kept: 0,
        values: Vec::new(),
        warnings,
        refs,
        alignment: placer.alignment().map(Path::to_path_buf),
    };
    if cfg.dry_run {
        return Ok(out);
    }
    let n = cat.scans.len();
    let selected: Vec<bool> = cat
        .scans
        .iter()
        .map(|c| cfg.only.is_empty() || cfg.only.contains(&c.name))
        .collect();
    // With --only, merge needs the products of the selected scans and of their partners;
    // `mvao prepare --only` makes just the selected ones.
    let need: Vec<bool> = (0..n)
        .map(|i| {
            selected[i]
                || (!cfg.prepare_only
                    && (0..n).any(|j| selected[j] && planned.pairs.meets(i, j, 0.0)))
        })
        .collect();
    let mut store = open_store(cfg, &cat, &mut files, &planned, &need, &sp, budget, floor)?;
    out.warnings.append(&mut store.1);
    let mut store = store.0;
    let prep = prepare::run(
        &cat.scans,
        &need,
        &mut files,
        &mut store,
        prm.projection,
        &sp,
        obs,
    )?;
    out.prepared = (prep.made, prep.reused);
    out.times.push(("prepare".into(), prep.secs));
    out.bytes_read.push(("prepare".into(), prep.bytes_read));
    if cfg.prepare_only {
        return Ok(out);
    }
    let mut note = std::mem::take(&mut out.defaults_note);
    let mplan = merge_plan(&mut store, &need, prm, &cat, &sp, &mut note)?;
    // The pair test holds what the merge needs of the occupied cells.
    cat.occupancy = Vec::new();
    out.defaults_note = note;
    out.merge = mplan.mp;
    for (k, t) in &mplan.times {
        match out.times.iter_mut().find(|(n, _)| n == k) {
            Some(e) => e.1 += t,
            None => out.times.push((k.clone(), *t)),
        }
    }
    write::mark_unfinished(cfg, &planned_outputs)?;
    // A file's outputs are written while the next file is merged, when the budget holds two
    // input files beside the maps.
    let overlap = 10 * cat.max_file_bytes + 3 * out.plan.largest_view_bytes + (64 << 20) <= budget;
    let mut writer = write::Writer::new(cfg, &cat.scans, overlap, keep_values);
    let partner = |i: usize, j: usize| mplan.meets(i, j);
    let job = MergeJob {
        cat: &cat.scans,
        selected: &selected,
        partner: &partner,
        mp: mplan.mp,
        ssao_only: prm.ssao_only,
        union: union_params(prm, &sp, &mplan.mp),
        occlusion,
        bent: prm.bent_normals,
    };
    let rays =
        (!prm.ssao_only && occlusion.unites(mplan.mp.largest_all_round, true)) || prm.bent_normals;
    out.union = rays.then_some(job.union);
    let (read, secs) = merge::run(&job, &files, &mut store, &mut writer, obs)?;
    let stats = store.stats();
    out.map_loads = stats.map_loads;
    out.views_kept = stats.views_kept;
    out.times.push(("merge".into(), secs - writer.secs));
    out.times.push(("write".into(), writer.secs));
    out.bytes_read
        .push(("merge".into(), read + stats.bytes_read));
    out.scans = std::mem::take(&mut writer.reports);
    out.values = std::mem::take(&mut writer.values);
    out.warnings.append(&mut writer.warnings);
    Ok(out)
}

/// The checks a run makes before any work: its outputs may be written, and the reference
/// (`--reference`) matches the scans. Returns the reference values and the planned outputs.
#[allow(clippy::type_complexity)]
fn check_before_work(cfg: &Config, cat: &Catalog) -> Result<(Option<Vec<Vec<f32>>>, Vec<PathBuf>)> {
    if cfg.dry_run || cfg.prepare_only {
        return Ok((None, Vec::new()));
    }
    let outputs = write::check_outputs(cfg, &cat.scans)?;
    let Some(d) = &cfg.reference else {
        return Ok((None, outputs));
    };
    let named: Vec<(String, usize)> = cat
        .scans
        .iter()
        .filter(|c| cfg.only.is_empty() || cfg.only.contains(&c.name))
        .map(|c| (c.name.clone(), c.points))
        .collect();
    Ok((
        Some(crate::io::reference::load_reference_named(d, &named)?),
        outputs,
    ))
}

/// A scan that meets no other is most often misplaced (a wrong or missing pose); its points
/// keep their own view's AO, and its extent inflates the default radius.
fn lonely_warnings(cfg: &Config, cat: &Catalog, lonely: &[(usize, f64)]) -> Vec<String> {
    lonely
        .iter()
        .map(|&(i, gap)| {
            let c = &cat.scans[i];
            format!(
                "{}: scan {} shares no surface with any other scan (the nearest one's centre is \
                 {gap:.1} m away); check its pose or alignment. Its points get their own \
                 view's AO only{}",
                cfg.scans[c.file].display(),
                c.name,
                if cfg.compute.radius.is_none() {
                    ", and its place counts in the default radius"
                } else {
                    ""
                }
            )
        })
        .collect()
}

/// The warning for a budget below `floor`, what one step needs (`sweeps` of it for the
/// far-field sweeps).
fn below_floor(budget: u64, floor: u64, sweeps: u64) -> Option<String> {
    if floor <= budget {
        return None;
    }
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    let of_which = if sweeps > 0 {
        format!(", of which {:.2} GiB for the far-field sweeps", gib(sweeps))
    } else {
        String::new()
    };
    Some(format!(
        "--max-memory {:.2} GiB is below what one input file and its view need (≈ {:.2} GiB\
         {of_which}); the run goes on with no map cached beyond the one in use",
        gib(budget),
        gib(floor),
    ))
}

/// How the merge combines the views within `budget`. The union holds a scan's own view and
/// every partner's at once (at `t_max = ∞` every view of the site), each with its depths and
/// radii packed for the rays, beside what one step needs
/// (`floor`): where that does not fit, `auto` averages instead, and an explicit `union` runs
/// anyway; both say so.
fn occlusion_within(
    prm: &ComputeParams,
    sp: &SsaoParams,
    planned: &plan::Planned,
    floor: u64,
    budget: u64,
) -> (Occlusion, Option<String>) {
    let asked = prm.occlusion;
    if prm.ssao_only || !asked.unites(crate::ssao::uses_far_field(sp), true) {
        return (asked, None);
    }
    let n = planned.view_bytes.len();
    let held = (0..n)
        .map(|i| {
            (0..n)
                .filter(|&j| j == i || planned.pairs.meets(i, j, 0.0))
                .map(|j| {
                    let packed = crate::merge::union::BYTES_PER_VIEW_PIXEL;
                    planned.view_bytes[j] + packed * planned.plan.scans[j].map_pixels
                })
                .sum::<u64>()
        })
        .max()
        .unwrap_or(0);
    if floor + held <= budget {
        return (asked, None);
    }
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    let what = format!(
        "holds about {:.2} GiB of views at once, beyond --max-memory {:.2} GiB with what one \
         step needs",
        gib(held),
        gib(budget)
    );
    match asked {
        Occlusion::Auto => (
            Occlusion::Average,
            Some(format!(
                "the union that --tmax inf runs on all-round stations {what}: the views are \
                 averaged instead (--occlusion union runs it anyway)"
            )),
        ),
        _ => (
            asked,
            Some(format!(
                "--occlusion union {what}; the run may go beyond it"
            )),
        ),
    }
}

/// The work directory set up for the run: which views the prepare stage keeps for the merge
/// and which input files' scans the catalog keeps for the prepare stage, both within the
/// budget. Returns the store and the manifest's warnings.
#[allow(clippy::too_many_arguments)]
fn open_store(
    cfg: &Config,
    cat: &Catalog,
    files: &mut catalog::Files<'_>,
    planned: &plan::Planned,
    need: &[bool],
    sp: &SsaoParams,
    budget: u64,
    floor: u64,
) -> Result<(WorkDirStore, Vec<String>)> {
    let n = cat.scans.len();
    let vb = &planned.view_bytes;
    // The merge takes the views kept here instead of reading back their products (the same
    // values): all of them when they fit, else those it visits first.
    let keep = if cfg.prepare_only {
        vec![false; n]
    } else {
        plan::views_to_keep(vb, need, floor, budget)
    };
    // The stage frees a file's held scans once it has taken them while the views it keeps
    // pile up: keep the held files (a prefix) for which the sum stays in the budget at every
    // step.
    let file_views: Vec<u64> = (0..files.files())
        .map(|fi| {
            let kept = |i: &usize| keep[*i] && cat.scans[*i].file == fi;
            (0..n).filter(kept).map(|i| vb[i]).sum()
        })
        .collect();
    let held_of: Vec<u64> = (0..files.held.len()).map(|fi| files.held[&fi].2).collect();
    let hold = plan::files_to_hold(&held_of, &file_views, floor, budget);
    files.held.retain(|&fi, _| fi < hold);
    let work_dir = cfg
        .work_dir
        .clone()
        .unwrap_or_else(|| cfg.out_dir.join("work"));
    let setup = WorkDirSetup {
        dir: work_dir,
        names: cat.scans.iter().map(|c| c.name.clone()).collect(),
        keys: cat.scans.iter().map(|c| c.key.clone()).collect(),
        inputs: cat
            .scans
            .iter()
            .map(|c| cfg.scans[c.file].clone())
            .collect(),
        params: cat
            .scans
            .iter()
            .map(|c| {
                serde_json::json!({
                    "ssao": sp,
                    "projection": cfg.compute.projection,
                    "data": c.data_hash,
                })
            })
            .collect(),
        map_pixels: cat.scans.iter().map(|c| c.map_pixels).collect(),
        budget,
        // A view's products are written while the next view is computed, when two views and
        // an input file fit in the budget; the manifest entry, the commit point, still follows
        // its products and summary.
        overlap: 4 * planned.plan.largest_view_bytes + 5 * cat.max_file_bytes + (64 << 20)
            <= budget,
        keep,
        keep_room: budget.saturating_sub(floor),
    };
    WorkDirStore::open(setup)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn union_rays_take_twice_the_samples_to_reach_the_whole_site() {
        let sp = |tmax: f32| SsaoParams {
            estimator: crate::ssao::Estimator::Horizon,
            radius: 0.2,
            tmax,
            falloff: Default::default(),
            samples: 8,
            directions: 8,
            steps: 8,
            seed: 1,
            blur: true,
            sampling: Default::default(),
        };
        let mp = MergeParams {
            neighbors: 1,
            dmin: 1.0,
            dmax: 20.0,
            border_px: 64.0,
            spacing: 0.0,
            largest_all_round: false,
        };
        let prm = ComputeParams::default();
        let near = union_params(&prm, &sp(0.4), &mp);
        assert_eq!((near.steps, near.reach), (24, 0.4));
        let far = union_params(&prm, &sp(f32::INFINITY), &mp);
        assert_eq!((far.steps, far.reach), (48, 40.0));
    }
}
