//! `mvao sweep`: error against run time over a grid of settings. Reads the dataset and its
//! reference once, then runs the in-memory computation per setting (timed without file I/O),
//! scores single-view SSAO, the merge (average of the views' AO) and, when asked, the union
//! occlusion against the reference, and writes `sweep.csv` and `sweep.svg` (e_A against wall
//! time, Pareto front marked).

use crate::accuracy::evaluate;
use crate::config::ComputeParams;
use crate::error::{Error, Result};
use crate::eval::Metrics;
use crate::io::dataset::{Dataset, PlaceOptions};
use crate::io::reference::{check_reference_matches, load_reference};
use crate::merge::union::Occlusion;
use crate::pipeline::{compute, Computed};
use crate::plot::{self, PlotPoint};
use crate::progress::Silent;
use crate::ssao::Estimator;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Columns of `sweep.csv`, in order. Scripts that add rows (e.g. the pymeshlab comparison)
/// write the same columns. `method` is `ssao` (single view), `mvao` (average of the views'
/// AO, N neighbours) or `union` (union occlusion, whose `samples` are its rays per point).
pub const CSV_COLUMNS: [&str; 20] = [
    "dataset",
    "method",
    "estimator",
    "samples",
    "directions",
    "steps",
    "neighbors",
    "radius",
    "tmax",
    "points",
    "wall_s",
    "e_a",
    "e_lt5",
    "rmse",
    "pearson_r",
    "bias",
    "shaded_n",
    "shaded_e_a",
    "skill",
    "shaded_skill",
];

/// One setting of the grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Setting {
    /// Estimator.
    pub estimator: Estimator,
    /// Samples per pixel (paper).
    pub samples: u32,
    /// Directions (horizon).
    pub directions: u32,
    /// Steps per direction (horizon).
    pub steps: u32,
    /// Merge neighbourhoods N to run with this SSAO.
    pub neighbors: Vec<u32>,
}

/// The default grid: paper with 8–64 samples, horizon from 4×4 to 16×16, each with N = 1, 3, 5.
pub fn default_grid() -> Vec<Setting> {
    let n = vec![1, 3, 5];
    let mut g: Vec<Setting> = [8, 16, 32, 64]
        .iter()
        .map(|&s| Setting {
            estimator: Estimator::Paper,
            samples: s,
            directions: 8,
            steps: 8,
            neighbors: n.clone(),
        })
        .collect();
    g.extend(
        [(4, 4), (8, 8), (16, 8), (16, 16)]
            .iter()
            .map(|&(d, k)| Setting {
                estimator: Estimator::Horizon,
                samples: 32,
                directions: d,
                steps: k,
                neighbors: n.clone(),
            }),
    );
    g
}

/// Everything `mvao sweep` needs.
#[derive(Debug, Clone)]
pub struct SweepConfig {
    /// Name written in the `dataset` column.
    pub dataset: String,
    /// Input scans.
    pub scans: Vec<PathBuf>,
    /// Placement.
    pub place: PlaceOptions,
    /// Reference directory (`mvao reference` on the same scans and t_max).
    pub reference: PathBuf,
    /// Output directory (`sweep.csv`, `sweep.svg`).
    pub out_dir: PathBuf,
    /// Base parameters (radius, t_max, seed, projection…); the grid overrides the rest.
    pub base: ComputeParams,
    /// The grid.
    pub grid: Vec<Setting>,
    /// Rays per point of the union occlusion run with every horizon setting (none: no union
    /// rows).
    pub union_rays: Vec<u32>,
    /// Overwrite existing outputs.
    pub force: bool,
}

/// One row of the CSV.
#[derive(Debug, Clone)]
pub struct Row {
    /// "ssao" (single view), "mvao" (average) or "union".
    pub method: String,
    /// The setting.
    pub setting: Setting,
    /// N (0 for single view).
    pub neighbors: u32,
    /// Radius and t_max used.
    pub radius: f32,
    /// t_max used.
    pub tmax: f32,
    /// Points.
    pub points: usize,
    /// Wall time of the computation (s).
    pub wall_s: f64,
    /// Metrics.
    pub metrics: Metrics,
}

impl Row {
    /// The row of `method` for `setting` from a computation `c` over `points` points.
    fn of(
        method: &str,
        setting: Setting,
        neighbors: u32,
        c: &Computed,
        (points, wall_s): (usize, f64),
        metrics: Metrics,
    ) -> Row {
        Row {
            method: method.into(),
            setting,
            neighbors,
            radius: c.ssao.radius,
            tmax: c.ssao.tmax,
            points,
            wall_s,
            metrics,
        }
    }
}

fn estimator_name(e: Estimator) -> &'static str {
    match e {
        Estimator::Paper => "paper",
        Estimator::Horizon => "horizon",
    }
}

/// Runs the sweep; returns the rows (also written as CSV and SVG).
pub fn run(cfg: &SweepConfig, progress: &dyn Fn(&str)) -> Result<Vec<Row>> {
    let csv = cfg.out_dir.join("sweep.csv");
    let svg = cfg.out_dir.join("sweep.svg");
    for o in [&csv, &svg] {
        if o.exists() && !cfg.force {
            return Err(Error::Param(format!(
                "{}: exists; use --force to overwrite or choose another -o",
                o.display()
            )));
        }
    }
    let ds = Dataset::open(&cfg.scans, &cfg.place, &|| {})?;
    let refs = load_reference(&cfg.reference, &ds.scans)?;
    let names: Vec<String> = ds.scans.iter().map(|s| s.name.clone()).collect();
    let points: usize = ds.scans.iter().map(|s| s.len()).sum();
    let mut rows = Vec::new();
    for st in &cfg.grid {
        for (k, &n) in st.neighbors.iter().enumerate() {
            let prm = ComputeParams {
                estimator: st.estimator,
                samples: st.samples,
                directions: st.directions,
                steps: st.steps,
                neighbors: n,
                ssao_only: false,
                ..cfg.base.clone()
            };
            let t0 = Instant::now();
            let c = compute(&ds.scans, &prm, &Silent)?;
            if rows.is_empty() {
                check_reference_matches(&cfg.reference, c.ssao.tmax, c.ssao.falloff)?;
            }
            let wall = t0.elapsed().as_secs_f64();
            let ssao: Vec<Vec<f32>> = c.scans.iter().map(|r| r.ssao.clone()).collect();
            let ao: Vec<Vec<f32>> = c.scans.iter().map(|r| r.ao.clone()).collect();
            let acc = evaluate(&cfg.reference, &names, Some(&ssao), &ao, &refs);
            if k == 0 {
                let single = acc.ssao.unwrap_or_default();
                let time = (points, wall - c.merge_s);
                rows.push(Row::of("ssao", st.clone(), 0, &c, time, single));
            }
            let row = Row::of("mvao", st.clone(), n, &c, (points, wall), acc.result);
            progress(&format!(
                "{} {} N={n}: {:.2} s, {}",
                estimator_name(st.estimator),
                budget(st),
                wall,
                row.metrics.one_line()
            ));
            rows.push(row);
        }
        if st.estimator == Estimator::Horizon {
            for &rays in &cfg.union_rays {
                let prm = ComputeParams {
                    directions: st.directions,
                    steps: st.steps,
                    occlusion: Occlusion::Union,
                    rays: Some(rays),
                    ssao_only: false,
                    ..cfg.base.clone()
                };
                let t0 = Instant::now();
                let c = compute(&ds.scans, &prm, &Silent)?;
                let wall = t0.elapsed().as_secs_f64();
                let ao: Vec<Vec<f32>> = c.scans.iter().map(|r| r.ao.clone()).collect();
                let acc = evaluate(&cfg.reference, &names, None, &ao, &refs);
                let setting = Setting {
                    samples: rays,
                    ..st.clone()
                };
                let row = Row::of("union", setting, 0, &c, (points, wall), acc.result);
                progress(&format!(
                    "union {} {rays} rays: {wall:.2} s, {}",
                    budget(st),
                    row.metrics.one_line()
                ));
                rows.push(row);
            }
        }
    }
    std::fs::create_dir_all(&cfg.out_dir).map_err(|e| Error::io(&cfg.out_dir, e))?;
    let mut text = CSV_COLUMNS.join(",") + "\n";
    for r in &rows {
        text += &csv_row(&cfg.dataset, r);
    }
    crate::io::atomic::write_atomic(&csv, |w| std::io::Write::write_all(w, text.as_bytes()))?;
    plot_csv(
        &csv,
        &svg,
        &format!("{}: e_A against wall time", cfg.dataset),
    )?;
    Ok(rows)
}

/// The budget of a setting as a short label.
fn budget(s: &Setting) -> String {
    match s.estimator {
        Estimator::Paper => format!("{} samples", s.samples),
        Estimator::Horizon => format!("{}×{}", s.directions, s.steps),
    }
}

fn opt(x: Option<f64>) -> String {
    x.map_or(String::new(), |v| format!("{v:.6}"))
}

/// A CSV field without separators or quotes (names are free text).
pub fn csv_field(s: &str) -> String {
    s.replace([',', '"', '\n', '\r'], " ")
}

fn csv_row(dataset: &str, r: &Row) -> String {
    let dataset = csv_field(dataset);
    let m = &r.metrics;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{dataset},{},{},{},{},{},{},{},{},{},{:.4},{:.6},{:.6},{:.6},{},{:.6},{},{},{},{}",
        r.method,
        estimator_name(r.setting.estimator),
        r.setting.samples,
        r.setting.directions,
        r.setting.steps,
        r.neighbors,
        r.radius,
        r.tmax,
        r.points,
        r.wall_s,
        m.e_a,
        m.e_lt5,
        m.rmse,
        opt(m.pearson_r),
        m.bias,
        m.shaded_n,
        opt(m.shaded_e_a),
        opt(m.skill),
        opt(m.shaded_skill),
    );
    s
}

/// Plots a sweep CSV (with any rows added by scripts) as e_A against wall time.
pub fn plot_csv(csv: &Path, svg: &Path, title: &str) -> Result<()> {
    let text = std::fs::read_to_string(csv).map_err(|e| Error::io(csv, e))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name);
    let (Some(cm), Some(ce), Some(cw), Some(ca)) =
        (col("method"), col("estimator"), col("wall_s"), col("e_a"))
    else {
        return Err(Error::format(
            csv,
            "not a sweep CSV (needs method, estimator, wall_s, e_a columns)",
        ));
    };
    let get = |f: &[&str], c: Option<usize>| c.and_then(|c| f.get(c)).map(|s| s.to_string());
    let mut pts = Vec::new();
    for (ln, line) in lines.enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        let num = |c: usize| -> Result<f64> {
            f.get(c).and_then(|v| v.parse::<f64>().ok()).ok_or_else(|| {
                Error::format(csv, format!("line {}: bad number in column {c}", ln + 2))
            })
        };
        let method = get(&f, Some(cm)).unwrap_or_default();
        let est = get(&f, Some(ce)).unwrap_or_default();
        let label = match est.as_str() {
            "paper" => format!("{}s", get(&f, col("samples")).unwrap_or_default()),
            "horizon" => format!(
                "{}×{}",
                get(&f, col("directions")).unwrap_or_default(),
                get(&f, col("steps")).unwrap_or_default()
            ),
            _ => get(&f, col("directions"))
                .map(|d| format!("{d} dirs"))
                .unwrap_or_default(),
        };
        let n = get(&f, col("neighbors")).unwrap_or_default();
        let (series, label) = match method.as_str() {
            "mvao" => (format!("MVAO {est}"), format!("{label} N={n}")),
            "union" => (
                format!("union {est}"),
                format!(
                    "{label} {} rays",
                    get(&f, col("samples")).unwrap_or_default()
                ),
            ),
            "ssao" => (format!("SSAO {est}"), label),
            m => (m.to_string(), label),
        };
        pts.push(PlotPoint {
            series,
            label,
            seconds: num(cw)?,
            error: num(ca)?,
        });
    }
    plot::write_svg(svg, title, "e_A = mean |a − A|", &pts)
}
