//! Orders the stages: read scans and poses → per scan sensor model, normals and radii,
//! G-buffer, SSAO and border field → merge every scan against all views → write results and
//! the report. Owns progress bars and timings; has no math of its own.

use crate::error::{Error, Result};
use crate::gbuffer::{self, GBuffer, EMPTY};
use crate::io::dataset::PlaceOptions;
use crate::io::output::ColorMode;
use crate::io::source::Format;
use crate::merge::cull::{PointCells, ViewCells};
use crate::merge::{self, MergeParams, MergeStats, View, ViewMaps};
use crate::projection::Projection;
use crate::report::{Parameters, Report, Totals};
use crate::scan::occupancy::{diagonal, Occupancy, Reach};
use crate::scan::{normals, Scan};
use crate::sensor::{self, ProjectionChoice, SensorSetup};
use crate::ssao::{self, AoMap, Estimator, SsaoParams};
use glam::{DVec3, Vec3};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Everything `mvao merge` needs, validated (see the CLI for meanings and units).
#[derive(Debug, Clone)]
pub struct Config {
    /// Input scans.
    pub scans: Vec<PathBuf>,
    /// How the scans are placed (alignment file, `--pose`, `--allow-scale`).
    pub place: PlaceOptions,
    /// Output format; `None` follows each input.
    pub format: Option<Format>,
    /// Output directory.
    pub out_dir: PathBuf,
    /// The computation's parameters.
    pub compute: ComputeParams,
    /// Gamma of grey colours and previews.
    pub gamma: f32,
    /// What happens to input colours.
    pub color: ColorMode,
    /// No progress bars.
    pub quiet: bool,
    /// Write a PNG preview per scan.
    pub preview: bool,
    /// How previews are drawn (up axis, tone).
    pub preview_style: crate::preview::PreviewStyle,
    /// Overwrite existing outputs.
    pub force: bool,
    /// Reference directory to score the result against.
    pub reference: Option<PathBuf>,
    /// Work directory for per-scan products; `None` = `OUTDIR/work`.
    pub work_dir: Option<PathBuf>,
    /// Memory budget in bytes; `None` = half the machine's memory.
    pub max_memory: Option<u64>,
    /// Only these scans (by name): prepare them, or merge them against their partners.
    pub only: Vec<String>,
    /// Print the plan and stop.
    pub dry_run: bool,
    /// Stop after preparing the products (`mvao prepare`).
    pub prepare_only: bool,
}

/// Parameters of the in-memory computation (no files).
#[derive(Debug, Clone)]
pub struct ComputeParams {
    /// SSAO radius; `None` = scene diagonal / 50.
    pub radius: Option<f32>,
    /// t_max; `None` = 2·radius.
    pub tmax: Option<f32>,
    /// Samples per pixel (paper estimator).
    pub samples: u32,
    /// Directions per pixel (horizon estimator).
    pub directions: u32,
    /// Steps per direction (horizon estimator).
    pub steps: u32,
    /// Merge neighbourhood N.
    pub neighbors: u32,
    /// d_min override.
    pub dmin: Option<f32>,
    /// d_max override.
    pub dmax: Option<f32>,
    /// t_p.
    pub border_px: f32,
    /// Seed.
    pub seed: u64,
    /// Sensor model choice.
    pub projection: ProjectionChoice,
    /// Estimator.
    pub estimator: Estimator,
    /// Blur SSAO maps.
    pub blur: bool,
    /// Skip the merge (MVAO = own SSAO).
    pub ssao_only: bool,
}

impl Default for ComputeParams {
    fn default() -> Self {
        ComputeParams {
            radius: None,
            tmax: None,
            samples: 32,
            directions: 8,
            steps: 8,
            neighbors: 1,
            dmin: None,
            dmax: None,
            border_px: 64.0,
            seed: 0,
            projection: ProjectionChoice::Auto,
            estimator: Estimator::Horizon,
            blur: true,
            ssao_only: false,
        }
    }
}

/// One scan after the per-view stages.
#[derive(Debug, Clone)]
pub struct PreparedView {
    /// Sensor model and map.
    pub sensor: SensorSetup,
    /// The G-buffer.
    pub gbuf: GBuffer,
    /// SSAO map (blurred).
    pub ssao: AoMap,
    /// Distance (pixels) to the nearest depth discontinuity.
    pub border: Vec<f32>,
    /// Radius of each point.
    pub radii: Vec<f32>,
    /// Pixel of each point ([`EMPTY`] if outside the map).
    pub pixel: Vec<u32>,
    /// Depth of each point.
    pub depth: Vec<f32>,
    /// Normals: "input", "estimated", "input, N re-estimated".
    pub normals_note: String,
    /// Wall time of each per-view stage (seconds): sensor, normals, gbuffer, ssao, border.
    pub times: Vec<(&'static str, f64)>,
}

impl PreparedView {
    /// Each point's SSAO (its pixel's value; 1 for a point outside the map) and whether it
    /// had no valid sample.
    pub fn point_ssao(&self) -> (Vec<f32>, u64) {
        point_values(&self.pixel, &self.ssao.ao, &self.ssao.no_sample)
    }
}

/// Each point's value in a map (`ao` at its pixel; 1 for a point outside the map) and how
/// many points had no valid sample (outside the map, or `no_sample` at their pixel).
pub fn point_values(pixel: &[u32], ao: &[f32], no_sample: &[bool]) -> (Vec<f32>, u64) {
    let mut none = 0u64;
    let v = pixel
        .iter()
        .map(|&px| {
            if px == EMPTY {
                none += 1;
                1.0
            } else {
                none += u64::from(no_sample[px as usize]);
                ao[px as usize]
            }
        })
        .collect();
    (v, none)
}

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

/// Stage hooks: progress and timing, so the computation can run with or without bars.
pub trait Observer: Sync {
    /// A stage starts with `total` units of work.
    fn stage(&self, _name: &str, _total: u64) {}
    /// `n` more units are done.
    fn advance(&self, _n: u64) {}
    /// A stage ended after `secs` seconds.
    fn done(&self, _name: &str, _secs: f64) {}
}

/// An observer that does nothing (tests, library use).
pub struct Silent;
impl Observer for Silent {}

/// Robust scene diagonal: 1st–99th percentile box of a sample of points along the sample's
/// principal axes. A rigid motion of all poses leaves it unchanged (it was once measured along
/// the first scan's axes, which made the default radius depend on the order of the files), and
/// the scans are sampled in name order so that the order of the inputs changes nothing.
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
/// the scene's size and point spacing ([`crate::radius`]; `scale` is only called when no
/// radius is given), t_max = 2 × radius.
pub fn ssao_params(
    prm: &ComputeParams,
    scale: impl FnOnce() -> crate::radius::SceneScale,
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
        samples: prm.samples,
        directions: prm.directions,
        steps: prm.steps,
        seed: prm.seed,
        blur: prm.blur,
    };
    Ok((sp, note))
}

/// Runs the per-view stages on one scan.
pub fn prepare_view(
    scan: &Scan,
    choice: ProjectionChoice,
    prm: &SsaoParams,
) -> Result<PreparedView> {
    let mut times = Vec::with_capacity(5);
    let mut t = Instant::now();
    let mut lap = |name: &'static str, t: &mut Instant| {
        times.push((name, t.elapsed().as_secs_f64()));
        *t = Instant::now();
    };
    let sensor = sensor::setup(scan, choice)?;
    lap("sensor", &mut t);
    let (normals, radii, note) = scan_normals(scan, &sensor);
    let proj: Projection = sensor.projection.clone();
    lap("normals", &mut t);
    let (pixel, depth) = gbuffer::point_pixels(&scan.points, &proj, sensor.grid_pixels.as_deref());
    let gbuf = gbuffer::rasterize(
        proj.width,
        proj.height,
        &pixel,
        &depth,
        &scan.points,
        &normals,
        &radii,
    );
    lap("gbuffer", &mut t);
    let ssao = ssao::compute(&gbuf, &proj, prm);
    lap("ssao", &mut t);
    let border =
        crate::merge::border::border_distance(&gbuf.depth, gbuf.width, gbuf.height, proj.wrap_x);
    lap("border", &mut t);
    Ok(PreparedView {
        sensor,
        gbuf,
        ssao,
        border,
        radii,
        pixel,
        depth,
        normals_note: note,
        times,
    })
}

/// Each point's unit normal (the input's, facing the sensor, or estimated where missing) and
/// radius `rad(p)`, with a note on where the normals came from. Neighbours come from the
/// native grid when the sensor model uses it, else from a k-d tree.
pub fn scan_normals(scan: &Scan, sensor: &SensorSetup) -> (Vec<Vec3>, Vec<f32>, String) {
    let proj: &Projection = &sensor.projection;
    let invalid_normals = scan
        .normals
        .as_ref()
        .map(|n| n.par_iter().filter(|v| *v == &Vec3::ZERO).count());
    let need = invalid_normals.is_none_or(|k| k > 0);
    let toward = |p| proj.toward_sensor(p);
    // A point without a cell has no grid neighbours: then the k-d tree serves every point.
    let grid = scan
        .grid
        .as_ref()
        .filter(|g| sensor.grid_pixels.is_some() && g.uncelled() == 0);
    let (est, radii) = match grid {
        Some(g) => normals::estimate_grid(&scan.points, g, need, toward),
        None => normals::estimate(&scan.points, need, toward),
    };
    let (normals, note) = match (&scan.normals, est) {
        (Some(given), Some(est)) => {
            let n: Vec<Vec3> = given
                .par_iter()
                .zip(&est)
                .zip(&scan.points)
                .map(|((g, e), p)| {
                    if *g == Vec3::ZERO {
                        *e
                    } else {
                        face(*g, proj.toward_sensor(*p))
                    }
                })
                .collect();
            (
                n,
                format!("input, {} re-estimated", invalid_normals.unwrap_or(0)),
            )
        }
        (Some(given), None) => (
            given
                .par_iter()
                .zip(&scan.points)
                .map(|(g, p)| face(*g, proj.toward_sensor(*p)))
                .collect(),
            "input".to_string(),
        ),
        (None, Some(est)) => (
            est,
            if grid.is_some() {
                "estimated (PCA, k = 16, neighbours from the native grid)".to_string()
            } else {
                "estimated (PCA, k = 16)".to_string()
            },
        ),
        (None, None) => (vec![Vec3::Z; scan.len()], "none".into()),
    };
    (normals, radii, note)
}

/// Flips `n` to face the sensor direction `t`.
fn face(n: Vec3, t: Vec3) -> Vec3 {
    if n.dot(t) < 0.0 {
        -n
    } else {
        n
    }
}

/// The whole computation on in-memory scans (poses set): per-view stages, then the merge.
pub fn compute(scans: &[Scan], prm: &ComputeParams, obs: &dyn Observer) -> Result<Computed> {
    if scans.is_empty() {
        return Err(Error::Param("no scan given".into()));
    }
    if let Some(s) = scans.iter().find(|s| s.is_empty()) {
        return Err(Error::scan(&s.name, "has no valid point"));
    }
    let (sp, mut note) = ssao_params(prm, || crate::radius::SceneScale {
        diagonal: robust_diagonal(scans),
        spacing: crate::radius::spacing_of(scans),
    })?;
    let tmax = sp.tmax;
    let total: u64 = scans.iter().map(|s| s.len() as u64).sum();
    obs.stage("prepare", total);
    let t0 = Instant::now();
    let mut views = Vec::with_capacity(scans.len());
    for s in scans {
        views.push(prepare_view(s, prm.projection, &sp)?);
        obs.advance(s.len() as u64);
    }
    obs.done("prepare", t0.elapsed().as_secs_f64());

    let ranges: Vec<(f32, f32)> = views
        .iter()
        .filter(|v| v.sensor.projection.sensor_model() != crate::projection::SensorModel::Ortho)
        .map(|v| depth_range(&v.depth))
        .collect();
    let mp = merge_params(prm, &ranges, &mut note);

    let bounds: Vec<(DVec3, DVec3)> = scans.iter().map(world_bounds).collect();
    let max_rad: Vec<f64> = views
        .iter()
        .map(|v| v.radii.iter().copied().fold(0.0f32, f32::max) as f64)
        .collect();
    let occ: Vec<Occupancy> = scans
        .iter()
        .zip(&bounds)
        .map(|(s, b)| Occupancy::of(s, diagonal(b)))
        .collect();
    let pairs = Pairs::new(
        bounds,
        &occ,
        tmax,
        max_rad.iter().copied().fold(0.0, f64::max),
    );
    let vcells = if prm.ssao_only {
        Vec::new()
    } else {
        view_cells(&views, scans)
    };
    let vmaps = if prm.ssao_only {
        Vec::new()
    } else {
        view_maps(&views, &mp)
    };
    let mv = merge_views(&views, &vmaps, scans, Some(&vcells));
    obs.stage("merge", if prm.ssao_only { 0 } else { total });
    let t0 = Instant::now();
    let mut results = Vec::with_capacity(scans.len());
    for (i, (s, v)) in scans.iter().zip(&views).enumerate() {
        let (own, no_sample) = v.point_ssao();
        let (ao, st) = if prm.ssao_only {
            (own.clone(), MergeStats::default())
        } else {
            let skip: Vec<bool> = (0..scans.len())
                .map(|j| !pairs.meets(i, j, max_rad[i].max(max_rad[j])))
                .collect();
            let cells = PointCells::new(&s.points, &v.radii, s.pose);
            merge::merge_scan(
                i,
                &s.points,
                &v.radii,
                &own,
                &v.pixel,
                Some(&cells),
                &mv,
                &skip,
                &mp,
                &|n| obs.advance(n),
            )
        };
        results.push((own, ao, no_sample, st));
    }
    let merge_s = t0.elapsed().as_secs_f64();
    obs.done("merge", merge_s);
    let scans_out = views
        .into_iter()
        .zip(results)
        .map(|(view, (ssao, ao, no_sample, merge))| ScanResult {
            view,
            ssao,
            ao,
            no_sample,
            merge,
        })
        .collect();
    Ok(Computed {
        scans: scans_out,
        ssao: sp,
        merge: mp,
        defaults_note: note,
        merge_s,
    })
}

/// What the merge reads of each prepared view (with its scan's pose and, when given, its
/// cells).
pub fn merge_views<'a>(
    views: &'a [PreparedView],
    maps: &'a [ViewMaps],
    scans: &[Scan],
    cells: Option<&'a [ViewCells]>,
) -> Vec<View<'a>> {
    views
        .iter()
        .zip(maps)
        .zip(scans)
        .enumerate()
        .map(|(j, ((v, m), s))| View {
            proj: &v.sensor.projection,
            maps: m,
            pose: s.pose,
            cells: cells.and_then(|c| c.get(j)),
        })
        .collect()
}

/// Each view's maps packed for the merge with parameters `prm`.
pub fn view_maps(views: &[PreparedView], prm: &MergeParams) -> Vec<ViewMaps> {
    views
        .iter()
        .map(|v| ViewMaps::new(&v.sensor.projection, &v.gbuf, &v.ssao.ao, &v.border, prm))
        .collect()
}

/// Each view's cells, for leaving out points a view cannot match.
pub fn view_cells(views: &[PreparedView], scans: &[Scan]) -> Vec<ViewCells> {
    views
        .par_iter()
        .zip(scans)
        .map(|(v, s)| ViewCells::new(&v.gbuf, s.pose))
        .collect()
}

/// World-space bounding box of a scan: of its points moved by the pose (not of its local box
/// moved, which a rotated pose would inflate).
pub fn world_bounds(s: &Scan) -> (DVec3, DVec3) {
    let pose = s.pose;
    let empty = || (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    let (lo, hi) = s
        .points
        .par_iter()
        .fold(empty, |(lo, hi), p| {
            let w = pose.transform_point3(p.as_dvec3());
            (lo.min(w), hi.max(w))
        })
        .reduce(empty, |a, b| (a.0.min(b.0), a.1.max(b.1)));
    if !(lo.is_finite() && hi.is_finite()) {
        return (DVec3::ZERO, DVec3::ZERO);
    }
    (lo, hi)
}

/// True when two scans with world bounds `a` and `b` may see common surface: eq. 7 accepts
/// partners within 2·rad (`max_rad` = the larger radius of both scans, 0 when unknown) and
/// SSAO reaches `t_max`, so boxes that do not meet when grown by the larger of both (and by
/// rounding) share nothing.
pub fn may_share_surface(a: &(DVec3, DVec3), b: &(DVec3, DVec3), tmax: f32, max_rad: f64) -> bool {
    let scale = (a.1 - a.0).length() + (b.1 - b.0).length();
    overlaps(a, b, pair_margin(tmax, max_rad, scale))
}

/// How close two scans' points must come to pair them (see [`may_share_surface`]); `scale`
/// sizes the allowance for rounding.
fn pair_margin(tmax: f32, max_rad: f64, scale: f64) -> f64 {
    (2.0 * tmax as f64).max(2.0 * max_rad) + 1e-6 * scale + 1e-9
}

/// Which pairs of scans may see common surface: their bounds must meet
/// ([`may_share_surface`]) and so must their occupied cells
/// ([`crate::scan::occupancy`]), which separates scans that only look at each other's
/// surfaces through an opening.
#[derive(Debug, Clone)]
pub struct Pairs {
    bounds: Vec<(DVec3, DVec3)>,
    reach: Reach,
    tmax: f32,
}

impl Pairs {
    /// The pair tests of scans with these world bounds and occupancies, for radii up to
    /// `max_rad` (0 when not known yet).
    pub fn new(bounds: Vec<(DVec3, DVec3)>, occ: &[Occupancy], tmax: f32, max_rad: f64) -> Pairs {
        let scale = 2.0 * bounds.iter().map(diagonal).fold(0.0, f64::max);
        let reach = Reach::new(occ, pair_margin(tmax, max_rad, scale));
        Pairs {
            bounds,
            reach,
            tmax,
        }
    }

    /// Whether scan `i`'s points may correspond to scan `j`'s (always for `i == j`), with
    /// `max_rad` the larger radius of both (at most the one given to [`Pairs::new`]).
    pub fn meets(&self, i: usize, j: usize, max_rad: f64) -> bool {
        i == j
            || (may_share_surface(&self.bounds[i], &self.bounds[j], self.tmax, max_rad)
                && self.reach.meets(i, j))
    }
}

/// Smallest and largest finite depth (∞, 0 when there is none).
pub fn depth_range(depth: &[f32]) -> (f32, f32) {
    depth
        .iter()
        .filter(|d| d.is_finite())
        .fold((f32::INFINITY, 0.0f32), |(lo, hi), &d| {
            (lo.min(d), hi.max(d))
        })
}

/// The merge parameters of a run from the depth ranges of its views with a sensor position
/// (`d_min`/`d_max` defaults), noting how they were derived.
pub fn merge_params(prm: &ComputeParams, ranges: &[(f32, f32)], note: &mut String) -> MergeParams {
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
    }
}

/// True when two boxes, grown by `margin`, intersect.
fn overlaps(a: &(DVec3, DVec3), b: &(DVec3, DVec3), margin: f64) -> bool {
    (a.0 - margin).cmple(b.1).all() && (b.0 - margin).cmple(a.1).all()
}

/// Progress bars on stderr (one per stage), silent with `-q` or when stderr is not a terminal.
pub(crate) struct Bars {
    quiet: bool,
    bar: std::sync::Mutex<Option<ProgressBar>>,
}

impl Observer for Bars {
    fn stage(&self, name: &str, total: u64) {
        if self.quiet {
            return;
        }
        let pb = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
        pb.set_style(
            ProgressStyle::with_template(
                "{prefix:>8} [{bar:40}] {human_pos}/{human_len} points {elapsed_precise} ETA {eta}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        pb.set_prefix(name.to_string());
        if let Ok(mut b) = self.bar.lock() {
            *b = Some(pb);
        }
    }
    fn advance(&self, n: u64) {
        if let Ok(b) = self.bar.lock() {
            if let Some(pb) = b.as_ref() {
                pb.inc(n);
            }
        }
    }
    fn done(&self, _name: &str, _secs: f64) {
        if let Ok(mut b) = self.bar.lock() {
            if let Some(pb) = b.take() {
                pb.finish();
            }
        }
    }
}

/// `mvao merge`: reads, computes, writes. Returns the report (also written as `report.json`).
pub fn run(cfg: &Config) -> Result<Report> {
    let t_all = Instant::now();
    let mut report = Report {
        version: env!("CARGO_PKG_VERSION").to_string(),
        ..Default::default()
    };
    let warn = |report: &mut Report, msg: String| {
        eprintln!("warning: {msg}");
        report.warnings.push(msg);
    };
    if cfg.scans.is_empty() {
        return Err(Error::Param("no scan given".into()));
    }
    // Before reading anything: one-scan outputs named after their inputs must not clobber an
    // input (the full check follows once the scans are known).
    for p in &cfg.scans {
        if let (Ok(f), Some(stem)) = (Format::of_path(p), p.file_stem()) {
            let out = cfg.format.unwrap_or(f.default_output());
            let o = cfg.out_dir.join(format!(
                "{}.mvao.{}",
                stem.to_string_lossy(),
                out.extension()
            ));
            if cfg.scans.iter().any(|s| same_file(s, &o)) {
                return Err(Error::Param(format!(
                    "{}: output would overwrite an input",
                    o.display()
                )));
            }
        }
    }
    let obs = Bars {
        quiet: cfg.quiet,
        bar: std::sync::Mutex::new(None),
    };
    let oc = crate::outofcore::run(cfg, &obs, cfg.reference.is_some())?;
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
        println!("{}", oc.plan.to_text());
        report.plan = Some(oc.plan);
        return Ok(report);
    }
    if !cfg.quiet && !cfg.prepare_only {
        eprintln!(
            "radius {:.4} m, tmax {:.4} m, dmin {:.3} m, dmax {:.3} m ({})",
            oc.ssao.radius,
            oc.ssao.tmax,
            oc.merge.dmin,
            oc.merge.dmax,
            if oc.defaults_note.is_empty() {
                "as given"
            } else {
                oc.defaults_note.as_str()
            }
        );
    }
    if let (Some(d), Some(refs)) = (&cfg.reference, &oc.refs) {
        let names: Vec<String> = oc.values.iter().map(|v| v.0.clone()).collect();
        let ssao: Vec<Vec<f32>> = oc.values.iter().map(|v| v.1.clone()).collect();
        let aos: Vec<Vec<f32>> = oc.values.iter().map(|v| v.2.clone()).collect();
        let acc = crate::accuracy::evaluate(d, &names, Some(&ssao), &aos, refs);
        if !cfg.quiet {
            if let Some(s) = &acc.ssao {
                eprintln!("single-view SSAO vs reference: {}", s.one_line());
            }
            eprintln!(
                "{} vs reference: {}",
                if cfg.compute.ssao_only {
                    "result"
                } else {
                    "MVAO"
                },
                acc.result.one_line()
            );
        }
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
    };
    report.scans = oc.scans;
    report.plan = Some(oc.plan);
    report.peak_rss_bytes = crate::outofcore::peak_rss();
    report.totals = Totals {
        points: report.scans.iter().map(|s| s.points as u64).sum(),
        no_ssao_sample: report.scans.iter().map(|s| s.no_ssao_sample).sum(),
        zero_merge_weight: report.scans.iter().map(|s| s.zero_merge_weight).sum(),
        wall_s: t_all.elapsed().as_secs_f64(),
    };
    if cfg.prepare_only {
        return Ok(report);
    }
    let json = serde_json::to_vec_pretty(&report)
        .map_err(|e| Error::Param(format!("cannot encode the report: {e}")))?;
    // Jobs merging one scan each (`--only`) run side by side: one report per job.
    let rp = cfg
        .out_dir
        .join(format!("report{}.json", crate::outofcore::job_suffix(cfg)));
    crate::io::atomic::write_atomic(&rp, |w| std::io::Write::write_all(w, &json))?;
    // The run is complete: its outputs are protected again.
    let marker = crate::outofcore::unfinished_marker(cfg);
    match std::fs::remove_file(&marker) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(Error::io(&marker, e)),
        _ => {}
    }
    Ok(report)
}

/// True when two paths name the same existing file.
pub(crate) fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
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
}
