//! The JSON report written beside the results: parameters after defaults, what was chosen per
//! scan and why, per-stage wall times and the counts a user needs to trust the result.
//! Computes nothing it reports.

use crate::eval::Metrics;
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
    pub plan: Option<Plan>,
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
    pub accuracy: Option<Accuracy>,
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
    /// How the merge combined the views.
    pub occlusion: crate::merge::union::Occlusion,
    /// The union occlusion's parameters, when its rays may run (`--occlusion union`, `auto` at
    /// `t_max = ∞`, bent normals).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub union: Option<crate::merge::union::UnionParams>,
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
    /// Points given the largest value of the all-round stations that matched them instead of
    /// the weighted average (plain ambient occlusion; `docs/design.md`).
    pub merged_by_largest: u64,
    /// Points shaded by the union occlusion (`--occlusion union`, or `auto` on an all-round
    /// station at `t_max = ∞`) rather than by combining the views' values.
    pub union_points: u64,
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
    /// Valid pixels of the SSAO map evaluated at each level (full rate, one per 2×2, one per
    /// 4×4) under `--sampling adaptive`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ssao_levels: Option<crate::ssao::multires::Levels>,
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
    /// Valid SSAO pixels at each level over all scans (`--sampling adaptive`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ssao_levels: Option<crate::ssao::multires::Levels>,
}

impl Report {
    /// Adds `secs` to stage `stage`.
    pub fn add_time(&mut self, stage: &str, secs: f64) {
        *self.timings_s.entry(stage.to_string()).or_insert(0.0) += secs;
    }
}

/// What the catalog pass learns of one scan.
#[derive(Debug, Clone, Serialize)]
pub struct CatalogScan {
    /// Scan name.
    pub name: String,
    /// Index of its file.
    pub file: usize,
    /// Index within its file.
    pub index: usize,
    /// Valid points.
    pub points: usize,
    /// World bounds.
    pub bounds: [[f64; 3]; 2],
    /// Pixels of the map it will get (native grid, else about one per point).
    pub map_pixels: u64,
    /// xxh3 of its local points, normals and grid (what its products depend on).
    pub data_hash: String,
    /// Work-directory key.
    pub key: String,
    /// Local → world pose.
    pub pose: glam::DMat4,
}

/// The plan of a run, printed by `--dry-run` and kept in the report.
#[derive(Debug, Clone, Serialize)]
pub struct Plan {
    /// Per scan.
    pub scans: Vec<CatalogScan>,
    /// Pairs (i, j), i ≠ j, whose bounds meet (grown by the reach of SSAO and of eq. 7).
    pub pairs_kept: usize,
    /// Pairs that cannot share surface and are skipped.
    pub pairs_skipped: usize,
    /// Largest single view in bytes (estimated).
    pub largest_view_bytes: u64,
    /// All views together in bytes (estimated): what an in-memory run would hold.
    pub all_views_bytes: u64,
    /// What the occlusion stage holds beside the largest view while it computes its map
    /// (estimated): the far-field sweeps' line families at `t_max = ∞`, else nothing.
    pub occlusion_bytes: u64,
    /// The memory budget in bytes.
    pub budget_bytes: u64,
    /// Point-views the merge will visit (points × kept views, including their own).
    pub point_views: u64,
}

impl Plan {
    /// A human-readable summary.
    pub fn to_text(&self) -> String {
        let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
        let pts: usize = self.scans.iter().map(|s| s.points).sum();
        let sweeps = if self.occlusion_bytes > 0 {
            format!(", far-field sweeps {:.3} GiB", gib(self.occlusion_bytes))
        } else {
            String::new()
        };
        format!(
            "plan: {} scans, {} points; pairs kept {}, skipped {} (cannot share surface); \
             views ≈ {:.2} GiB in all, largest {:.3} GiB{sweeps}; budget {:.2} GiB; {} \
             point-views to merge",
            self.scans.len(),
            pts,
            self.pairs_kept,
            self.pairs_skipped,
            gib(self.all_views_bytes),
            gib(self.largest_view_bytes),
            gib(self.budget_bytes),
            self.point_views
        )
    }
}

/// Metrics of one scan.
#[derive(Debug, Clone, Serialize)]
pub struct ScanAccuracy {
    /// Scan name.
    pub name: String,
    /// Single-view SSAO against the reference (absent for `mvao eval`).
    pub ssao: Option<Metrics>,
    /// The result against the reference.
    pub result: Metrics,
}

/// Accuracy of a run against a reference.
#[derive(Debug, Clone, Serialize)]
pub struct Accuracy {
    /// The reference directory.
    pub reference: String,
    /// Per scan.
    pub scans: Vec<ScanAccuracy>,
    /// All single-view SSAO values together.
    pub ssao: Option<Metrics>,
    /// All result values together.
    pub result: Metrics,
}
