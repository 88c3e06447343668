//! The JSON report written beside the results: parameters after defaults, what was chosen per
//! scan and why, per-stage wall times and the counts a user needs to trust the result.
//! Computes nothing it reports.

use crate::merge::MergeParams;
use crate::ssao::SsaoParams;
use serde::Serialize;
use std::collections::BTreeMap;

/// The whole report (`report.json`).
#[derive(Debug, Clone, Serialize, Default)]
pub struct Report {
    /// mvao version that wrote it.
    pub version: String,
    /// Parameters after defaults.
    pub parameters: Parameters,
    /// The alignment file used, if any.
    pub alignment: Option<String>,
    /// One entry per input scan, in input order.
    pub scans: Vec<ScanReport>,
    /// Wall time per stage (seconds), summed over scans.
    pub timings_s: BTreeMap<String, f64>,
    /// Totals over all scans.
    pub totals: Totals,
    /// Warnings printed during the run.
    pub warnings: Vec<String>,
    /// The plan: pairs kept and skipped, memory and work.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub plan: Option<crate::outofcore::Plan>,
    /// Peak resident memory of the process (bytes).
    pub peak_rss_bytes: Option<u64>,
    /// Bytes read per stage (inputs and products).
    pub bytes_read: BTreeMap<String, u64>,
    /// Per-scan products recomputed and reused from the work directory.
    pub products: [usize; 2],
    /// Maps of other scans loaded by the merge (cache misses).
    pub map_loads: u64,
    /// Views the prepare pass handed to the merge instead of the merge reading them back.
    pub views_kept: u64,
    /// Error against a reference (`--reference`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accuracy: Option<crate::accuracy::Accuracy>,
}

/// Run parameters after defaults were filled in.
#[derive(Debug, Clone, Serialize, Default)]
pub struct Parameters {
    /// SSAO parameters.
    pub ssao: Option<SsaoParams>,
    /// Merge parameters.
    pub merge: Option<MergeParams>,
    /// How the radius and t_max defaults were derived (when not given).
    pub defaults_note: String,
    /// Gamma of the grey colours and previews.
    pub gamma: f32,
    /// Colour mode.
    pub color: String,
    /// `--projection` as given.
    pub projection: String,
    /// True when the single-view SSAO was written instead of the merge.
    pub ssao_only: bool,
}

/// What happened to one scan.
#[derive(Debug, Clone, Serialize, Default)]
pub struct ScanReport {
    /// Scan name (file stem).
    pub name: String,
    /// Input path as given.
    pub input: String,
    /// Output PLY path.
    pub output: String,
    /// Vertices in the input.
    pub vertices: usize,
    /// Vertices with finite coordinates (the ones processed and written).
    pub points: usize,
    /// Vertices skipped for non-finite coordinates (not written).
    pub skipped_nonfinite: usize,
    /// Chosen sensor model.
    pub sensor_model: String,
    /// Map size in pixels (width, height).
    pub map_size: [usize; 2],
    /// Pixels of the map holding a point.
    pub map_filled: usize,
    /// True when the native grid is the map.
    pub native_grid: bool,
    /// RMS (pixels) of the projection fitted to the native grid.
    pub grid_fit_rms_px: Option<f64>,
    /// Why this sensor model and map.
    pub sensor_reason: String,
    /// "input", "estimated" or "input, N re-estimated".
    pub normals: String,
    /// Points whose SSAO had no valid sample (left at 1).
    pub no_ssao_sample: u64,
    /// Points whose merge weights summed to zero (kept their own SSAO).
    pub zero_merge_weight: u64,
    /// (point, view) pairs evaluated by the merge.
    pub point_views: u64,
    /// (point, view) pairs left out before projecting: no stored point of the view was near
    /// enough for eq. 7 (the merged value is the same as if they had been evaluated).
    pub point_views_culled: u64,
    /// Smallest, mean and largest AO written.
    pub ao_min: f32,
    /// Mean AO written.
    pub ao_mean: f32,
    /// Largest AO written.
    pub ao_max: f32,
}

/// Totals over the run.
#[derive(Debug, Clone, Serialize, Default)]
pub struct Totals {
    /// Points processed.
    pub points: u64,
    /// Points with no valid SSAO sample.
    pub no_ssao_sample: u64,
    /// Points with zero merge weight.
    pub zero_merge_weight: u64,
    /// Wall time of the whole run (seconds).
    pub wall_s: f64,
}

impl Report {
    /// Adds `secs` to stage `stage`.
    pub fn add_time(&mut self, stage: &str, secs: f64) {
        *self.timings_s.entry(stage.to_string()).or_insert(0.0) += secs;
    }
}
