//! The write stage: the outputs of each input file (in its format or the one asked for), the
//! previews and the per-scan reports, written by temporary file and rename; the checks that
//! refuse to start a run whose outputs would overwrite an input or an earlier result; and the
//! report.

use super::catalog::Opened;
use super::merge::{FileValues, Merged, Sink};
use crate::config::Config;
use crate::error::{Error, Result};
use crate::io::dataset::Dataset;
use crate::io::results::{self, WriteOptions};
use crate::io::source::Format;
use crate::products::MergeMaps;
use crate::report::{CatalogScan, Report, ScanReport};
use crate::scan::Scan;
use crate::store::{Summary, ViewStore};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::thread::JoinHandle;
use std::time::Instant;

/// True when two paths name the same existing file.
pub fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// Before reading anything: one-scan outputs named after their inputs must not clobber an
/// input (the full check, [`check_outputs`], follows once the scans are known).
pub fn check_inputs_safe(cfg: &Config) -> Result<()> {
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
    Ok(())
}

/// The file listing the outputs of a run whose report is not written yet (one per job, like
/// the report): a run killed while writing its outputs leaves it, and the rerun may replace
/// those outputs without `--force`.
pub fn unfinished_marker(cfg: &Config) -> PathBuf {
    cfg.out_dir
        .join(format!(".mvao-unfinished{}", job_suffix(cfg)))
}

/// What tells one job's files from another's in a shared output directory: `.NAME` for a
/// `--only NAME` job (jobs merging one scan each run side by side), nothing for a whole run.
pub fn job_suffix(cfg: &Config) -> String {
    cfg.only.first().map_or(String::new(), |n| format!(".{n}"))
}

/// Refuses to start when an output would overwrite an input, or exists without `--force`
/// (unless an unfinished run of the same job wrote it). Returns the outputs.
pub fn check_outputs(cfg: &Config, cat: &[CatalogScan]) -> Result<Vec<PathBuf>> {
    let files: Vec<(PathBuf, Format, Vec<String>)> = cfg
        .scans
        .iter()
        .enumerate()
        .map(|(fi, p)| {
            let f = Format::of_path(p)?;
            let names = cat
                .iter()
                .filter(|c| c.file == fi)
                .map(|c| c.name.clone())
                .collect();
            Ok((p.clone(), f, names))
        })
        .collect::<Result<_>>()?;
    for (i, c) in cat.iter().enumerate() {
        if let Some(j) = cat[..i].iter().position(|d| d.name == c.name) {
            return Err(Error::Param(format!(
                "two scans are named '{}' ({} and {}); rename one or run them separately",
                c.name,
                cfg.scans[cat[j].file].display(),
                cfg.scans[c.file].display()
            )));
        }
    }
    let selected = |n: &str| cfg.only.is_empty() || cfg.only.iter().any(|o| o == n);
    let units = results::plan_files(&files, cfg.format, &cfg.out_dir)?;
    let mut outputs: Vec<PathBuf> = units
        .iter()
        .filter(|u| u.scans.iter().any(|&i| selected(&cat[i].name)))
        .map(|u| u.path.clone())
        .collect();
    if cfg.preview {
        outputs.extend(
            cat.iter()
                .filter(|c| selected(&c.name))
                .map(|c| cfg.out_dir.join(format!("{}.png", c.name))),
        );
    }
    if cfg.only.is_empty() {
        outputs.push(cfg.out_dir.join("report.json"));
    }
    let pending: Vec<String> = std::fs::read_to_string(unfinished_marker(cfg))
        .map(|t| t.lines().map(str::to_string).collect())
        .unwrap_or_default();
    let ours = |o: &Path| {
        o.file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| pending.iter().any(|p| p == n))
    };
    for o in &outputs {
        if cfg.scans.iter().any(|s| same_file(s, o)) {
            return Err(Error::Param(format!(
                "{}: output would overwrite an input",
                o.display()
            )));
        }
        if o.exists() && !cfg.force && !ours(o) {
            return Err(Error::Param(format!(
                "{}: exists; use --force to overwrite or choose another -o",
                o.display()
            )));
        }
    }
    Ok(outputs)
}

/// Writes the report of a complete run (`report.json`, one per job), then removes the
/// unfinished marker: the run's outputs are protected again.
pub fn write_report(cfg: &Config, report: &Report) -> Result<()> {
    let json = serde_json::to_vec_pretty(report)
        .map_err(|e| Error::Param(format!("cannot encode the report: {e}")))?;
    // Jobs merging one scan each (`--only`) run side by side: one report per job.
    let rp = cfg.out_dir.join(format!("report{}.json", job_suffix(cfg)));
    crate::io::atomic::write_atomic(&rp, |w| std::io::Write::write_all(w, &json))?;
    let marker = unfinished_marker(cfg);
    match std::fs::remove_file(&marker) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(Error::io(&marker, e)),
        _ => Ok(()),
    }
}

/// Lists the outputs about to be written in the unfinished marker (see [`unfinished_marker`]).
pub fn mark_unfinished(cfg: &Config, outputs: &[PathBuf]) -> Result<()> {
    std::fs::create_dir_all(&cfg.out_dir).map_err(|e| Error::io(&cfg.out_dir, e))?;
    let names: Vec<&str> = outputs
        .iter()
        .filter_map(|p| p.file_name().and_then(|n| n.to_str()))
        .collect();
    crate::io::atomic::write_atomic(&unfinished_marker(cfg), |w| {
        std::io::Write::write_all(w, (names.join("\n") + "\n").as_bytes())
    })
}

/// Smallest, largest and mean of `ao`, summed in fixed chunks combined in order, so the mean
/// does not depend on the threads.
fn ao_range(ao: &[f32]) -> (f32, f32, f32) {
    let (mn, mx, total) = ao
        .par_chunks(1 << 16)
        .map(|c| {
            c.iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY, 0.0f64), |a, &v| {
                    (a.0.min(v), a.1.max(v), a.2 + v as f64)
                })
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY, 0.0f64), |a, b| {
            (a.0.min(b.0), a.1.max(b.1), a.2 + b.2)
        });
    (mn, mx, (total / ao.len().max(1) as f64) as f32)
}

/// The merge's sink for `mvao merge`: previews and reports per scan, the outputs per input
/// file (on another thread while the next file is merged, when the budget allows).
pub struct Writer<'a> {
    cfg: &'a Config,
    cat: &'a [CatalogScan],
    comment: String,
    /// Write a file's outputs on another thread.
    overlap: bool,
    writing: Option<JoinHandle<Result<Vec<String>>>>,
    keep_values: bool,
    /// Per merged scan.
    pub reports: Vec<ScanReport>,
    /// Per merged scan (name, single-view SSAO, AO), when asked to keep them.
    pub values: Vec<(String, Vec<f32>, Vec<f32>)>,
    /// Warnings of the writers.
    pub warnings: Vec<String>,
    /// Seconds spent writing (not overlapped with merging).
    pub secs: f64,
}

impl<'a> Writer<'a> {
    /// A writer of `cfg`'s outputs; `keep_values` keeps each scan's values for the caller.
    pub fn new(cfg: &'a Config, cat: &'a [CatalogScan], overlap: bool, keep_values: bool) -> Self {
        let comment = format!(
            "mvao {} {}: ao = {} (1 = open)",
            env!("CARGO_PKG_VERSION"),
            if cfg.compute.ssao_only {
                "ssao-only"
            } else {
                "merge"
            },
            match cfg.compute.estimator {
                crate::ssao::Estimator::Paper => "paper estimator",
                crate::ssao::Estimator::Horizon => "horizon estimator",
            }
        );
        Writer {
            cfg,
            cat,
            comment,
            overlap,
            writing: None,
            keep_values,
            reports: Vec::new(),
            values: Vec::new(),
            warnings: Vec::new(),
            secs: 0.0,
        }
    }

    /// Waits for the writer thread and takes its warnings.
    fn join(&mut self) -> Result<()> {
        if let Some(h) = self.writing.take() {
            let w = h.join().map_err(|_| {
                Error::Param("writing the outputs failed (internal error)".into())
            })??;
            self.warnings.extend(w);
        }
        Ok(())
    }
}

impl Sink for Writer<'_> {
    fn scan(&mut self, s: &Scan, m: &Merged, own: &MergeMaps, sum: &Summary) -> Result<()> {
        let ao = &m.ao;
        if self.cfg.preview {
            crate::preview::write_scan_preview(
                &self.cfg.out_dir.join(format!("{}.png", s.name)),
                &own.gbuf,
                &own.projection,
                s.pose,
                ao,
                self.cfg.gamma,
                self.cfg.preview_style,
            )?;
        }
        let (mn, mx, mean) = ao_range(ao);
        self.reports.push(ScanReport {
            name: s.name.clone(),
            input: self.cfg.scans[self.cat[m.index].file].display().to_string(),
            output: String::new(),
            vertices: s.vertex_count,
            points: s.len(),
            skipped_nonfinite: s.skipped_nonfinite,
            sensor_model: sum.sensor_model.clone(),
            map_size: sum.map_size,
            map_filled: sum.filled,
            native_grid: sum.native_grid,
            grid_fit_rms_px: sum.fit_rms_px,
            sensor_reason: sum.reason.clone(),
            normals: sum.normals.clone(),
            no_ssao_sample: m.no_sample,
            zero_merge_weight: m.stats.zero_weight,
            merged_by_largest: m.stats.largest,
            union_points: m.stats.united,
            point_views: m.stats.point_views,
            point_views_culled: m.stats.culled,
            ao_min: mn,
            ao_mean: mean,
            ao_max: mx,
            ssao_levels: sum.ssao_levels,
        });
        if self.keep_values {
            self.values
                .push((s.name.clone(), m.ssao.clone(), m.ao.clone()));
        }
        Ok(())
    }

    fn file(
        &mut self,
        fi: usize,
        opened: Opened<'_>,
        values: FileValues,
        store: &mut dyn ViewStore,
    ) -> Result<()> {
        let FileValues { ao: aos, bent } = values;
        let pf = opened.placed.ok_or_else(|| {
            Error::Param("an input file without its placement (internal error)".into())
        })?;
        // Whole files only: with --only every scan of a multi-scan file must be selected.
        let ds = Dataset {
            scans: opened.scans.into_owned(),
            origin: (0..aos.len()).map(|k| (0, k)).collect(),
            file_to_world: pf.file_to_world,
            pose_source: pf.pose_source,
            alignment: None,
            warnings: Vec::new(),
            files: vec![pf.file],
        };
        let tw = Instant::now();
        // Writing copies the input's content: room for it before the copy.
        let path = &self.cfg.scans[fi];
        store.make_room(3 * std::fs::metadata(path).map_or(0, |m| m.len()));
        let units = results::plan(&ds, self.cfg.format, &self.cfg.out_dir)?;
        let mut todo = Vec::new();
        for u in units {
            if u.scans.iter().all(|&k| !aos[k].is_empty()) {
                for &k in &u.scans {
                    if let Some(r) = self.reports.iter_mut().find(|r| r.name == ds.scans[k].name) {
                        r.output = u.path.display().to_string();
                    }
                }
                todo.push(u);
            } else if u.scans.iter().any(|&k| !aos[k].is_empty()) {
                self.warnings.push(format!(
                    "{}: not written, --only selected some but not all of its scans",
                    u.path.display()
                ));
            }
        }
        // The previous file's outputs are complete before this file's are started.
        self.join()?;
        let comment = self.comment.clone();
        let wopts = WriteOptions {
            gamma: self.cfg.gamma,
            color: self.cfg.color,
        };
        let write_all = move || -> Result<Vec<String>> {
            let mut warnings = Vec::new();
            for u in &todo {
                warnings.extend(results::write(u, &ds, &aos, &bent, wopts, &comment)?);
            }
            Ok(warnings)
        };
        if self.overlap {
            self.writing = Some(std::thread::spawn(write_all));
        } else {
            let w = write_all()?;
            self.warnings.extend(w);
        }
        self.secs += tw.elapsed().as_secs_f64();
        Ok(())
    }

    fn finish(&mut self) -> Result<()> {
        let tw = Instant::now();
        self.join()?;
        self.secs += tw.elapsed().as_secs_f64();
        Ok(())
    }
}

impl Drop for Writer<'_> {
    /// A run stopped by an error still waits for the outputs being written.
    fn drop(&mut self) {
        if let Some(h) = self.writing.take() {
            let _ = h.join();
        }
    }
}
