//! Where the prepared views live between the stages: in memory ([`MemoryStore`], for library
//! use and tests) or in the work directory under a memory budget ([`WorkDirStore`], for
//! `mvao merge` and `mvao prepare`). The stages run the same way over either; the store holds
//! no algorithm.

mod memory;
mod work;

pub use memory::MemoryStore;
pub use work::{WorkDirSetup, WorkDirStore};

use crate::error::Result;
use crate::merge::MergeParams;
use crate::products::manifest::InputRecord;
use crate::products::points::Points;
use crate::products::MergeMaps;
use crate::view::PreparedView;
use glam::DMat4;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Per-scan facts recorded beside the products, so a rerun can plan the merge without
/// loading every view.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Summary {
    /// Points of the scan.
    pub points: usize,
    /// Largest point radius.
    pub max_radius: f32,
    /// Smallest finite depth.
    pub depth_min: f32,
    /// Largest finite depth.
    pub depth_max: f32,
    /// True for an orthographic view (no sensor position).
    pub ortho: bool,
    /// Points with no valid SSAO sample.
    pub no_sample: u64,
    /// Pixels of the map holding a point.
    pub filled: usize,
    /// Sensor model chosen.
    pub sensor_model: String,
    /// Map size (width, height).
    pub map_size: [usize; 2],
    /// True when the native grid is the map.
    pub native_grid: bool,
    /// RMS of the model fitted to the native grid (pixels).
    pub fit_rms_px: Option<f64>,
    /// Why this model and map.
    pub reason: String,
    /// Where the normals came from.
    pub normals: String,
    /// Wall time of each per-view stage (seconds).
    pub times: Vec<(String, f64)>,
    /// Valid pixels of the SSAO map evaluated at each level of `--sampling adaptive`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ssao_levels: Option<crate::ssao::multires::Levels>,
}

/// What a store counted.
#[derive(Debug, Clone, Copy, Default)]
pub struct StoreStats {
    /// Maps loaded by the merge (cache misses).
    pub map_loads: u64,
    /// Views the prepare stage handed to the merge instead of the merge reading them back.
    pub views_kept: u64,
    /// Bytes of products the merge read.
    pub bytes_read: u64,
}

/// The prepared views of a run, by scan index in the catalog.
pub trait ViewStore {
    /// Whether scan `i`'s view is stored and current (same inputs and parameters).
    fn is_current(&mut self, i: usize) -> bool;
    /// Stores scan `i`'s view and summary; `record` fingerprints its input file.
    fn put(
        &mut self,
        i: usize,
        record: Option<&InputRecord>,
        sum: Summary,
        view: PreparedView,
    ) -> Result<()>;
    /// Every view put so far is stored for good.
    fn finish_prepare(&mut self) -> Result<()>;
    /// Scan `i`'s summary.
    fn summary(&mut self, i: usize) -> Result<Summary>;
    /// The order in which the merge will ask for maps (a store with a cache evicts by it).
    fn expect(&mut self, _loads: Vec<usize>) {}
    /// Scan `i`'s per-point arrays; `next` is the scan asked for after it (read ahead).
    fn points(&mut self, i: usize, next: Option<usize>) -> Result<Points>;
    /// Memory the scan being merged will allocate besides the maps (kept free).
    fn reserve(&mut self, _bytes: u64) {}
    /// Scan `j`'s maps with its cells placed at `pose`, packed for a merge with `prm`.
    fn maps(&mut self, j: usize, pose: DMat4, prm: &MergeParams) -> Result<Arc<MergeMaps>>;
    /// Frees cached maps until `bytes` more fit in the budget.
    fn make_room(&mut self, _bytes: u64) {}
    /// What the store counted.
    fn stats(&self) -> StoreStats {
        StoreStats::default()
    }
}

/// Estimated bytes of a loaded view with `pixels` pixels and `points` points.
pub fn view_bytes(pixels: u64, points: u64) -> u64 {
    // position 12, normal 12, depth 4, radius 4, point 4, ssao 4, border 4 per pixel; radii,
    // pixel, depth per point.
    pixels * 44 + points * 12
}
