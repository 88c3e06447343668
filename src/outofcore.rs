//! `mvao merge` and `mvao prepare` with a work directory and a memory budget. Three passes
//! over the inputs, each holding one input file at a time:
//! 1. **catalog**: counts, world bounds, a fingerprint of each scan's local data and the
//!    sample the default radius is taken from; the plan (pairs kept and skipped, memory and
//!    work) follows from it (`--dry-run` stops here);
//! 2. **prepare**: per scan, the G-buffer, SSAO map and border field, written to the work
//!    directory unless a product with the same inputs and parameters is already there;
//! 3. **merge**: per scan, the other scans' maps are loaded on demand through a cache bounded
//!    by the budget (which starts with the views the prepare pass kept, those of the first
//!    scans merged while they fit), added one view at a time in index order (bit-identical to
//!    the in-memory merge), and the results written.
//!
//! Every product is written atomically and recorded last, so a run killed at any moment
//! leaves the work directory consistent; the rerun recomputes only what is missing.

use crate::error::{Error, Result};
use crate::io::dataset::{Dataset, Placer};
use crate::io::results::{self, WriteOptions};
use crate::io::source::Container;
use crate::merge::cull::PointCells;
use crate::merge::{self, Accum, MergeParams, MergeStats, Target};
use crate::pipeline::{
    depth_range, merge_params, prepare_view, robust_diagonal, same_file, world_bounds, Config,
    Observer, Pairs, PreparedView,
};
use crate::products::manifest::{self, FileTime, Stat};
use crate::products::{self, InputRecord, Manifest, MergeMaps};
use crate::report::ScanReport;
use crate::scan::occupancy::Occupancy;
use crate::scan::Scan;
use crate::ssao::SsaoParams;
use glam::{DMat4, DVec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

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
        format!(
            "plan: {} scans, {} points; pairs kept {}, skipped {} (cannot share surface); \
             views ≈ {:.2} GiB in all, largest {:.3} GiB; budget {:.2} GiB; {} point-views to merge",
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

/// Per-scan facts recorded beside the products, so a rerun can plan the merge without
/// loading every view.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Summary {
    points: usize,
    max_radius: f32,
    depth_min: f32,
    depth_max: f32,
    ortho: bool,
    no_sample: u64,
    filled: usize,
    sensor_model: String,
    map_size: [usize; 2],
    native_grid: bool,
    fit_rms_px: Option<f64>,
    reason: String,
    normals: String,
    times: Vec<(String, f64)>,
}

fn summary_path(dir: &Path, key: &str) -> PathBuf {
    dir.join(format!("{key}.summary.json"))
}

/// A scan's summary, when its file is there and readable (a damaged one counts as missing, so
/// that the prepare pass writes it again).
fn read_summary(p: &Path) -> Option<Summary> {
    serde_json::from_slice(&std::fs::read(p).ok()?).ok()
}

/// Estimated bytes of a loaded view with `pixels` pixels and `points` points.
fn view_bytes(pixels: u64, points: u64) -> u64 {
    // position 12, normal 12, depth 4, radius 4, point 4, ssao 4, border 4 per pixel; radii,
    // pixel, depth per point.
    pixels * 44 + points * 12
}

/// How many files of a held prefix (`held`: bytes of each file's scans) the prepare pass can
/// keep. At the start of file `f` it holds the kept scans of files `≥ f` and the views it
/// keeps of files `< f` (`views`, bytes per file); that sum plus `margin` must stay within
/// `budget` at every step.
fn files_to_hold(held: &[u64], views: &[u64], margin: u64, budget: u64) -> usize {
    let fits = |k: usize| {
        let (mut rest, mut kept) = (held[..k].iter().sum::<u64>(), 0u64);
        for (f, v) in views.iter().enumerate() {
            if rest + kept + margin > budget {
                return false;
            }
            rest -= held.get(f).filter(|_| f < k).copied().unwrap_or(0);
            kept += v;
        }
        kept + margin <= budget
    };
    (0..=held.len().min(views.len()))
        .rev()
        .find(|&k| fits(k))
        .unwrap_or(0)
}

/// Which scans' views (`views`: bytes of each, `need`: those the merge uses) the prepare pass
/// keeps for the merge: the needed ones of the first scans, in the order the merge visits
/// them, while their sum stays within `budget` less `margin` (all of them when they fit). The
/// merge's cache then starts with the maps it asks for first instead of reading them back.
fn views_to_keep(views: &[u64], need: &[bool], margin: u64, budget: u64) -> Vec<bool> {
    let mut room = budget.saturating_sub(margin);
    let mut open = true;
    views
        .iter()
        .zip(need)
        .map(|(&v, &wanted)| {
            let kept = open && wanted && v <= room;
            if kept {
                room -= v;
            } else if wanted {
                // A prefix: a later, smaller view would be asked for after the one left out.
                open = false;
            }
            kept
        })
        .collect()
}

/// Heap bytes of a parsed scan.
fn scan_bytes(s: &Scan) -> u64 {
    let per_point =
        12 + 4 + if s.normals.is_some() { 12 } else { 0 } + if s.grid.is_some() { 8 } else { 0 };
    (s.points.capacity() * per_point) as u64
}

/// Peak resident memory of this process so far (bytes), where the system tells.
pub fn peak_rss() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Resident memory of this process now (bytes), where the system tells.
pub fn current_rss() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Lets the allocator keep the memory a run frees for its next allocations.
///
/// A view's maps are tens of megabytes, allocated and freed once per scan. Handed back to the
/// system, each new allocation arrives as fresh pages the kernel must fault in and zero: on a
/// 24-scan site, a merge-only rerun made 0.70–0.75 M page faults and spent 5.9–10.3 s in the
/// kernel; keeping freed memory, 0.40 M and 4.1–6.8 s. Resident memory then includes what the
/// allocator keeps, which the map cache counts as held outside it: an over-estimate, never an
/// under-estimate. The same holds for the few huge-page buffers [`crate::pagebuf`] keeps.
/// One arena for all threads lets a buffer freed by one thread (a product writer) be reused by
/// another: on that site, 0.65 M page faults instead of 0.74 M.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt sets three of glibc's allocator parameters (plain integers, under the main
    // arena's lock); an allocation running on another thread meanwhile follows the old value
    // or the new one, both valid.
    unsafe {
        libc::mallopt(libc::M_MMAP_MAX, 0);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
        libc::mallopt(libc::M_ARENA_MAX, 1);
    }
    crate::pagebuf::keep_freed();
}

/// Total memory of the machine (bytes), where the system tells.
pub fn total_memory() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = s.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// The default budget: half the machine's memory (4 GiB where it cannot be read).
pub fn default_budget() -> u64 {
    total_memory().map_or(4 << 30, |m| m / 2)
}

/// A fingerprint of what a scan's products depend on: local points, normals and grid.
/// Blocks of values are hashed in parallel and the digest hashes their digests in order.
fn data_hash(s: &Scan) -> String {
    const BLOCK: usize = 1 << 16;
    fn blocks<T: Sync + bytemuck::Pod>(
        v: &[T],
        bytes: impl Fn(&T, &mut Vec<u8>) + Sync,
    ) -> Vec<u128> {
        v.par_chunks(BLOCK)
            .map(|c| {
                // The little-endian bytes of the values are their memory on such a machine.
                if cfg!(target_endian = "little") {
                    return xxhash_rust::xxh3::xxh3_128(bytemuck::cast_slice(c));
                }
                let mut buf = Vec::with_capacity(std::mem::size_of_val(c));
                for x in c {
                    bytes(x, &mut buf);
                }
                xxhash_rust::xxh3::xxh3_128(&buf)
            })
            .collect()
    }
    let vec3 = |p: &glam::Vec3, b: &mut Vec<u8>| {
        for v in p.to_array() {
            b.extend_from_slice(&v.to_le_bytes());
        }
    };
    let u32le = |v: &u32, b: &mut Vec<u8>| b.extend_from_slice(&v.to_le_bytes());
    let mut parts = vec![(&b"p"[..], blocks(&s.points, vec3))];
    if let Some(n) = &s.normals {
        parts.push((b"n", blocks(n, vec3)));
    }
    if let Some(g) = &s.grid {
        parts.push((b"g", vec![u128::from(g.rows), u128::from(g.cols)]));
        parts.push((b"r", blocks(&g.row, u32le)));
        parts.push((b"c", blocks(&g.col, u32le)));
    }
    digest(parts)
}

/// The hash of tagged lists of block hashes: each tag, the list's length and its hashes, in
/// order.
fn digest(parts: Vec<(&[u8], Vec<u128>)>) -> String {
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    for (tag, d) in parts {
        h.update(tag);
        h.update(&(d.len() as u64).to_le_bytes());
        for x in d {
            h.update(&x.to_le_bytes());
        }
    }
    format!("{:032x}", h.digest128())
}

/// What saving a view gives: its manifest entry (committed on disk), and the view.
type Saved = (Result<products::manifest::Entry>, PreparedView);

/// A view's products, summary and manifest entry being written (on another thread when
/// prepare overlaps writing with computing), and the view.
enum Saving<'s> {
    Running(std::thread::ScopedJoinHandle<'s, Saved>),
    Done(Box<Saved>),
}

/// A prepared view whose commit is not known to be complete yet.
struct Pending<'s> {
    /// The scan's index in the catalog.
    index: usize,
    saving: Saving<'s>,
}

/// Writes a view's products, then its summary and, last, its manifest entry (the commit
/// point), in that order. Run off the main thread when prepare overlaps writing with computing:
/// the summary's and the entry's syncs took about 0.1 s a scan, with a core idle.
fn save_and_record(
    work_dir: &Path,
    key: &str,
    rec: &InputRecord,
    params: &serde_json::Value,
    sum: &Summary,
    v: &PreparedView,
) -> Result<products::manifest::Entry> {
    let files = products::save_view(work_dir, key, v)?;
    let json = serde_json::to_vec(sum)
        .map_err(|e| Error::Param(format!("cannot encode a summary: {e}")))?;
    crate::io::atomic::write_atomic(&summary_path(work_dir, key), |w| {
        std::io::Write::write_all(w, &json)
    })?;
    products::manifest::write_record(work_dir, key, std::slice::from_ref(rec), params, &files)
}

/// Waits for a view's commit and takes note of its entry. Returns the view.
fn commit(p: Pending<'_>, manifest: &mut Manifest) -> Result<PreparedView> {
    let (entry, view) = match p.saving {
        Saving::Running(h) => h.join().map_err(|_| {
            Error::Param("writing a view's products failed (internal error)".into())
        })?,
        Saving::Done(r) => *r,
    };
    manifest.insert(entry?);
    Ok(view)
}

/// Waits for a writer thread and passes on its result (its warnings).
fn join_writer(h: std::thread::ScopedJoinHandle<'_, Result<Vec<String>>>) -> Result<Vec<String>> {
    h.join()
        .map_err(|_| Error::Param("writing the outputs failed (internal error)".into()))?
}

/// What merging a scan allocates per point once its inputs are loaded: the weighted sums
/// (8 bytes), its cells and their index (about 8), its own SSAO and flags (5), the merged value
/// and the copy handed to the writer (8), and the cells' sort while they are built (16).
const MERGE_BYTES_PER_POINT: u64 = 48;

/// What reading the next scan's per-point products ahead holds per point at most: the file
/// (16 bytes) and its decoded arrays (16).
const AHEAD_BYTES_PER_POINT: u64 = 32;

/// A cache of other scans' maps, bounded in bytes. The merge's order of loads is known in
/// advance, so the map evicted is the one needed again the latest (Belady's rule): with a
/// cyclic order, least-recently-used would miss every time once the maps do not all fit.
struct MapCache {
    budget: u64,
    /// Memory the process holds outside the cache (measured once per scan).
    outside: u64,
    /// Memory the scan being merged will allocate after that measurement (its sums, cells
    /// and results), kept free.
    reserve: u64,
    used: u64,
    maps: HashMap<usize, (Arc<MergeMaps>, u64)>,
    /// Views this run prepared, kept for the merge (not placed yet).
    fresh: HashMap<usize, (MergeMaps, u64)>,
    /// Every load the merge will ask for, in order, and how far it has got.
    future: Vec<usize>,
    pos: usize,
    loads: u64,
    bytes_read: u64,
}

impl MapCache {
    /// Measures what the process holds beside the cache.
    fn measure(&mut self) {
        self.outside = current_rss().map_or(0, |r| r.saturating_sub(self.used));
    }

    /// Position of the next request for `k` after the current one (`usize::MAX`: never).
    fn next_use(&self, k: usize) -> usize {
        self.future[self.pos.min(self.future.len())..]
            .iter()
            .position(|&x| x == k)
            .map_or(usize::MAX, |p| self.pos + p)
    }

    /// Evicts maps, those needed latest first, until `need` more bytes fit in the budget.
    fn make_room(&mut self, need: u64) {
        let room = self
            .budget
            .saturating_sub(self.outside)
            .saturating_sub(self.reserve);
        while self.used + need > room {
            let keys = self.maps.keys().chain(self.fresh.keys()).copied();
            let Some(k) = keys.max_by_key(|&k| self.next_use(k)) else {
                break;
            };
            let b = match self.maps.remove(&k) {
                Some((_, b)) => b,
                None => self.fresh.remove(&k).map_or(0, |(_, b)| b),
            };
            self.used -= b;
        }
    }

    /// Scan `j`'s maps (loaded unless held), with its cells placed at `pose`.
    fn get(
        &mut self,
        j: usize,
        dir: &Path,
        key: &str,
        pixels: u64,
        pose: DMat4,
        prm: &MergeParams,
    ) -> Result<Arc<MergeMaps>> {
        // Skip ahead to this request in the planned order.
        if let Some(p) = self.future[self.pos.min(self.future.len())..]
            .iter()
            .position(|&x| x == j)
        {
            self.pos += p + 1;
        }
        if !self.maps.contains_key(&j) {
            let mut m = match self.fresh.remove(&j) {
                Some((m, b)) => {
                    self.used -= b;
                    m
                }
                None => {
                    // Decoding holds the file's bytes, the decoder's channels and the maps
                    // built from them at one moment.
                    let bytes = view_bytes(pixels, 0);
                    self.make_room(3 * bytes);
                    self.loads += 1;
                    self.bytes_read += bytes;
                    products::load_maps_for_merge(dir, key)?
                }
            };
            m.place(pose, prm);
            let held = m.heap_bytes();
            self.used += held;
            self.maps.insert(j, (Arc::new(m), held));
        }
        self.maps
            .get(&j)
            .map(|e| e.0.clone())
            .ok_or_else(|| Error::Param("map cache lost an entry (internal error)".into()))
    }
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
fn check_outputs(cfg: &Config, cat: &[CatalogScan]) -> Result<Vec<PathBuf>> {
    let files: Vec<(PathBuf, crate::io::source::Format, Vec<String>)> = cfg
        .scans
        .iter()
        .enumerate()
        .map(|(fi, p)| {
            let f = crate::io::source::Format::of_path(p)?;
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

/// Outcome of [`run`].
pub struct Outcome {
    /// The plan.
    pub plan: Plan,
    /// Per-scan reports (merged scans only).
    pub scans: Vec<ScanReport>,
    /// SSAO and merge parameters used.
    pub ssao: SsaoParams,
    /// Merge parameters used.
    pub merge: MergeParams,
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
    /// Views the prepare pass handed to the merge.
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

/// Runs the passes `cfg` asks for. `keep_values` keeps each merged scan's AO in memory.
pub fn run(cfg: &Config, obs: &dyn Observer, keep_values: bool) -> Result<Outcome> {
    let mut warnings = Vec::new();
    let mut times: Vec<(String, f64)> = Vec::new();
    let mut bytes_read: Vec<(String, u64)> = Vec::new();
    let placer = Placer::new(&cfg.scans, &cfg.place)?;
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
    let work_dir = cfg
        .work_dir
        .clone()
        .unwrap_or_else(|| cfg.out_dir.join("work"));
    let budget = cfg.max_memory.unwrap_or_else(default_budget);
    let input_bytes: u64 = cfg
        .scans
        .iter()
        .map(|p| std::fs::metadata(p).map(|m| m.len()).unwrap_or(0))
        .sum();

    // Pass 1: catalog.
    let t0 = Instant::now();
    obs.stage("catalog", cfg.scans.len() as u64);
    let mut cat: Vec<CatalogScan> = Vec::new();
    let mut samples: Vec<Scan> = Vec::new();
    // Per scan: (point spacing, points), for the default radius.
    let mut spacings: Vec<(f64, usize)> = Vec::new();
    let mut occ: Vec<Occupancy> = Vec::new();
    let mut max_file_bytes = 0u64;
    // Scans of the first files are kept for the prepare pass, which then need not read them
    // again, while they fit in the budget beside what the pass needs; each with the identity
    // of its file before it was read.
    let mut held: HashMap<usize, (Stat, Vec<Scan>, u64)> = HashMap::new();
    let mut holding = !cfg.dry_run;
    for fi in 0..placer.len() {
        // A file modified within the clock's resolution could change again unseen: read anew.
        let before = holding
            .then(|| manifest::stat(&cfg.scans[fi]).ok())
            .flatten()
            .filter(|st| !st.is_racy(FileTime::now()));
        let mut pf = placer.open(fi)?;
        warnings.append(&mut pf.warnings);
        if let Container::Ply(ply) = &pf.file.container {
            let bad = crate::io::output::nonfinite_properties(ply);
            if !bad.is_empty() {
                let list: Vec<String> = bad.iter().map(|(p, n)| format!("{p} ({n})")).collect();
                warnings.push(format!(
                    "{}: non-finite values in vertex properties {}; written as 0 in the output",
                    cfg.scans[fi].display(),
                    list.join(", ")
                ));
            }
        }
        max_file_bytes =
            max_file_bytes.max(std::fs::metadata(&cfg.scans[fi]).map_or(0, |m| m.len()));
        for (k, s) in pf.scans.iter().enumerate() {
            if s.is_empty() {
                return Err(Error::scan(
                    cfg.scans[fi].display().to_string(),
                    format!("scan {} has no point with finite coordinates", s.name),
                ));
            }
            crate::io::source::check_usable(s, &cfg.scans[fi])?;
            let (lo, hi) = world_bounds(s);
            occ.push(Occupancy::of(s, (hi - lo).length()));
            // The same subsample `robust_diagonal` would take, so the default radius equals
            // the in-memory computation's.
            let step = s.len().div_ceil(20_000).max(1);
            let mut sample = Scan::from_points(
                s.name.clone(),
                s.points.iter().step_by(step).copied().collect(),
            );
            sample.pose = s.pose;
            samples.push(sample);
            if cfg.compute.radius.is_none() {
                spacings.push((crate::radius::scan_spacing(&s.points), s.len()));
            }
            cat.push(CatalogScan {
                name: s.name.clone(),
                file: fi,
                index: k,
                points: s.len(),
                bounds: [lo.to_array(), hi.to_array()],
                // A grid far sparser than its points is resampled at about a pixel a point.
                map_pixels: s
                    .grid
                    .as_ref()
                    .filter(|_| !crate::sensor::grid_too_sparse(s))
                    .map_or(s.len() as u64, |g| g.rows as u64 * g.cols as u64),
                data_hash: data_hash(s),
                key: products::key_from_name(&s.name),
                pose: s.pose,
            });
        }
        let wanted = cfg.only.is_empty() || pf.scans.iter().any(|s| cfg.only.contains(&s.name));
        holding &= before.is_some() && wanted;
        if let Some(st) = before.filter(|_| holding) {
            let bytes: u64 = pf.scans.iter().map(scan_bytes).sum();
            let largest = cat
                .iter()
                .map(|c| view_bytes(c.map_pixels, c.points as u64))
                .max();
            let floor = max_file_bytes * 5 + 3 * largest.unwrap_or(0) + (16 << 20);
            let held_bytes: u64 = held.values().map(|h| h.2).sum();
            holding = held_bytes + bytes + 2 * floor <= budget;
            if holding {
                held.insert(fi, (st, pf.scans, bytes));
            }
        }
        obs.advance(1);
    }
    obs.done("catalog", t0.elapsed().as_secs_f64());
    times.push(("catalog".into(), t0.elapsed().as_secs_f64()));
    bytes_read.push(("catalog".into(), input_bytes));
    placer.check_pose_targets(cat.iter().map(|c| c.name.as_str()))?;
    for o in &cfg.only {
        if !cat.iter().any(|c| &c.name == o) {
            return Err(Error::Param(format!("--only {o}: no scan of that name")));
        }
    }
    for (i, c) in cat.iter().enumerate() {
        if let Some(j) = cat[..i].iter().position(|d| d.key == c.key) {
            let (a, b) = (&cfg.scans[cat[j].file], &cfg.scans[c.file]);
            let same = std::fs::canonicalize(a)
                .ok()
                .is_some_and(|x| std::fs::canonicalize(b).ok() == Some(x));
            return Err(Error::Param(if same && cat[j].index == c.index {
                format!("{} is given twice", b.display())
            } else {
                format!(
                    "scans '{}' ({}) and '{}' ({}) would share the work-directory key '{}': \
                     rename one",
                    cat[j].name,
                    a.display(),
                    c.name,
                    b.display(),
                    c.key
                )
            }));
        }
    }

    let mut refs = None;
    let mut planned_outputs = Vec::new();
    if !cfg.dry_run && !cfg.prepare_only {
        planned_outputs = check_outputs(cfg, &cat)?;
        // A reference that does not match is refused before any work is done.
        if let Some(d) = &cfg.reference {
            let named: Vec<(String, usize)> = cat
                .iter()
                .filter(|c| cfg.only.is_empty() || cfg.only.contains(&c.name))
                .map(|c| (c.name.clone(), c.points))
                .collect();
            refs = Some(crate::accuracy::load_reference_named(d, &named)?);
        }
    }

    // Parameters (as `pipeline::compute` derives them).
    let prm = &cfg.compute;
    let (sp, note) = crate::pipeline::ssao_params(prm, || crate::radius::SceneScale {
        diagonal: robust_diagonal(&samples),
        spacing: crate::radius::combined_spacing(&spacings),
    })?;
    drop(samples);
    // The report is written last and marks a complete set: a rerun over an earlier one drops
    // the old report first, so a run that stops half way does not leave new outputs beside
    // old ones under a report that vouches for them.
    let old_report = cfg.out_dir.join("report.json");
    if !cfg.dry_run && !cfg.prepare_only && cfg.only.is_empty() && old_report.exists() {
        std::fs::remove_file(&old_report).map_err(|e| Error::io(&old_report, e))?;
    }
    if !cfg.dry_run {
        // Temporary files of an earlier run that was killed (their writer is gone).
        crate::products::clean_stale_temps(&cfg.out_dir, &mut warnings);
    }
    let tmax = sp.tmax;

    // The plan. Pair skipping uses the SSAO reach here; eq. 7's reach (radii) is added once
    // the radii are known.
    let n = cat.len();
    let b: Vec<(DVec3, DVec3)> = cat
        .iter()
        .map(|c| (DVec3::from(c.bounds[0]), DVec3::from(c.bounds[1])))
        .collect();
    // Before the radii are known only the SSAO reach counts.
    let plan_pairs = Pairs::new(b.clone(), &occ, tmax, 0.0);
    let pair_meets = |i: usize, j: usize, max_rad: f64| plan_pairs.meets(i, j, max_rad);
    let mut kept = 0usize;
    let mut point_views = 0u64;
    for (i, c) in cat.iter().enumerate() {
        let mut partners = 0usize;
        for j in 0..n {
            if i == j || pair_meets(i, j, 0.0) {
                if i != j {
                    partners += 1;
                }
                point_views += c.points as u64;
            }
        }
        kept += partners;
        // A scan that meets no other is most often misplaced (a wrong or missing pose); its
        // points keep their own view's AO, and its extent inflates the default radius.
        if partners == 0 && n > 1 {
            let centre =
                |c: &CatalogScan| (DVec3::from(c.bounds[0]) + DVec3::from(c.bounds[1])) * 0.5;
            let gap = (0..n)
                .filter(|&j| j != i)
                .map(|j| centre(c).distance(centre(&cat[j])))
                .fold(f64::INFINITY, f64::min);
            warnings.push(format!(
                "{}: scan {} shares no surface with any other scan (the nearest one's centre is \
                 {gap:.1} m away); check its pose or alignment. Its points get their own \
                 view's AO only{}",
                cfg.scans[c.file].display(),
                c.name,
                if prm.radius.is_none() {
                    ", and its place counts in the default radius"
                } else {
                    ""
                }
            ));
        }
    }
    let vb: Vec<u64> = cat
        .iter()
        .map(|c| view_bytes(c.map_pixels, c.points as u64))
        .collect();
    let plan = Plan {
        scans: cat.clone(),
        pairs_kept: kept,
        pairs_skipped: n * n.saturating_sub(1) - kept,
        largest_view_bytes: vb.iter().copied().max().unwrap_or(0),
        all_views_bytes: vb.iter().sum(),
        budget_bytes: budget,
        point_views,
    };
    // One input file's data and one view must fit beside the cache.
    // Measured on PLY scans: the parsed file, its scan, the own view, one partner's maps
    // while they are decoded, and the process itself.
    let floor = max_file_bytes * 5 + 3 * plan.largest_view_bytes + (16 << 20);
    // Freed memory the allocator keeps adds to the peak between two measurements of the map
    // cache: it is kept only when every view fits with that much to spare.
    let roomy = !cfg.dry_run && plan.all_views_bytes + 2 * floor <= budget;
    if roomy {
        keep_freed_memory();
    }
    if floor > budget {
        warnings.push(format!(
            "--max-memory {:.2} GiB is below what one input file and its view need (≈ {:.2} GiB); \
             the run goes on with no map cached beyond the one in use",
            budget as f64 / (1u64 << 30) as f64,
            floor as f64 / (1u64 << 30) as f64
        ));
    }
    let mut out = Outcome {
        plan,
        scans: Vec::new(),
        ssao: sp,
        merge: MergeParams {
            neighbors: prm.neighbors,
            dmin: 0.0,
            dmax: 0.0,
            border_px: prm.border_px,
        },
        defaults_note: note,
        times,
        bytes_read,
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

    // Pass 2: prepare what is missing or stale.
    std::fs::create_dir_all(&work_dir).map_err(|e| Error::io(&work_dir, e))?;
    let mut manifest = Manifest::load(&work_dir);
    out.warnings.append(&mut manifest.warnings);
    let selected = |c: &CatalogScan| cfg.only.is_empty() || cfg.only.contains(&c.name);
    let params = |c: &CatalogScan| {
        serde_json::json!({
            "ssao": sp,
            "projection": prm.projection,
            "data": c.data_hash,
        })
    };
    let t0 = Instant::now();
    obs.stage("prepare", cat.iter().map(|c| c.points as u64).sum());
    let mut prep_bytes = 0u64;
    // With --only, merge needs the products of the selected scans and of their partners;
    // `mvao prepare --only` makes just the selected ones.
    let need: Vec<bool> = (0..n)
        .map(|i| {
            selected(&cat[i])
                || (!cfg.prepare_only && (0..n).any(|j| selected(&cat[j]) && pair_meets(i, j, 0.0)))
        })
        .collect();
    // A view's products are written while the next view is computed, when two views and an
    // input file fit in the budget; the manifest entry, the commit point, still follows its
    // products and summary.
    let overlap = 4 * out.plan.largest_view_bytes + 5 * max_file_bytes + (64 << 20) <= budget;
    // The merge takes the views kept here instead of reading back their products (the same
    // values): all of them when they fit, else those it visits first.
    let keep = if cfg.prepare_only {
        vec![false; n]
    } else {
        views_to_keep(&vb, &need, 2 * floor, budget)
    };
    let keep_room = budget.saturating_sub(2 * floor);
    // The pass frees a file's held scans once it has taken them while the views it keeps pile
    // up: keep the held files (a prefix) for which the sum stays in the budget at every step.
    let file_views: Vec<u64> = (0..placer.len())
        .map(|fi| {
            let kept = |i: &usize| keep[*i] && cat[*i].file == fi;
            (0..n).filter(kept).map(|i| vb[i]).sum()
        })
        .collect();
    let held_of: Vec<u64> = (0..held.len()).map(|fi| held[&fi].2).collect();
    let hold = files_to_hold(&held_of, &file_views, 2 * floor, budget);
    held.retain(|&fi, _| fi < hold);
    let mut fresh: HashMap<usize, (MergeMaps, u64)> = HashMap::new();
    let mut fresh_bytes = 0u64;
    let mut hand_over = |i: usize, v: PreparedView| {
        if keep[i] {
            let m = MergeMaps::from_view(v);
            let b = m.heap_bytes();
            // The plan counted estimated sizes: a view larger than estimated is not kept
            // beyond the room the plan gave the views.
            if fresh_bytes + b <= keep_room {
                fresh_bytes += b;
                fresh.insert(i, (m, b));
            }
        }
    };
    std::thread::scope(|sc| -> Result<()> {
        let mut pending: Option<Pending<'_>> = None;
        for fi in 0..placer.len() {
            let kept = held.remove(&fi);
            let stale: Vec<usize> = (0..n)
                .filter(|&i| cat[i].file == fi && need[i])
                .filter(|&i| {
                    !(manifest.is_fresh(&cat[i].key, &[&cfg.scans[fi]], &params(&cat[i]))
                        && read_summary(&summary_path(&work_dir, &cat[i].key)).is_some())
                })
                .collect();
            out.prepared.1 += (0..n)
                .filter(|&i| cat[i].file == fi && need[i] && !stale.contains(&i))
                .count();
            if stale.is_empty() {
                obs.advance(
                    cat.iter()
                        .filter(|c| c.file == fi)
                        .map(|c| c.points as u64)
                        .sum(),
                );
                continue;
            }
            // Fingerprint the input before reading it, so a change during the run is caught.
            let rec = InputRecord::capture(&cfg.scans[fi])?;
            let changed = || {
                Error::Param(format!(
                    "{}: changed while mvao was running; run again",
                    cfg.scans[fi].display()
                ))
            };
            // Scans kept from the catalog were read after their file had the identity the
            // record now finds; others are read again and compared with what the catalog read.
            let (scans, read_again) = match kept {
                Some((st, ..)) if st != rec.stat() => return Err(changed()),
                Some((_, scans, _)) => (scans, false),
                None => (placer.open(fi)?.scans, true),
            };
            prep_bytes += rec.size;
            for &i in &stale {
                let s = &scans[cat[i].index];
                if read_again && data_hash(s) != cat[i].data_hash {
                    return Err(changed());
                }
                let v = prepare_view(s, prm.projection, &sp)?;
                let (dmin, dmax) = depth_range(&v.depth);
                let max_radius = v.radii.iter().copied().fold(0.0, f32::max);
                if !(dmin.is_finite() && dmax.is_finite() && max_radius.is_finite()) {
                    return Err(Error::scan(
                        cfg.scans[fi].display().to_string(),
                        format!(
                            "scan {}: depths or point radii are not finite (depth {dmin}..{dmax} \
                             m, largest radius {max_radius} m): coordinates out of usable range",
                            s.name
                        ),
                    ));
                }
                let (_, no_sample) = v.point_ssao();
                let proj = &v.sensor.projection;
                let sum = Summary {
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
                };
                // The previous view is committed before this one's products are written.
                if let Some(p) = pending.take() {
                    hand_over(p.index, commit(p, &mut manifest)?);
                }
                let (key, wd, rec, prm_i) = (
                    cat[i].key.clone(),
                    work_dir.clone(),
                    rec.clone(),
                    params(&cat[i]),
                );
                let save = move || (save_and_record(&wd, &key, &rec, &prm_i, &sum, &v), v);
                let saving = if overlap {
                    Saving::Running(sc.spawn(save))
                } else {
                    Saving::Done(Box::new(save()))
                };
                pending = Some(Pending { index: i, saving });
                out.prepared.0 += 1;
                obs.advance(s.len() as u64);
            }
        }
        if let Some(p) = pending.take() {
            hand_over(p.index, commit(p, &mut manifest)?);
        }
        Ok(())
    })?;
    let _ = manifest.save();
    obs.done("prepare", t0.elapsed().as_secs_f64());
    out.times
        .push(("prepare".into(), t0.elapsed().as_secs_f64()));
    out.bytes_read.push(("prepare".into(), prep_bytes));
    if cfg.prepare_only {
        return Ok(out);
    }

    // Summaries of every scan the merge touches.
    let mut sums: Vec<Option<Summary>> = vec![None; n];
    for i in (0..n).filter(|&i| need[i]) {
        let p = summary_path(&work_dir, &cat[i].key);
        let s: Summary = read_summary(&p).ok_or_else(|| {
            Error::Param(format!(
                "{}: missing or damaged; run `mvao prepare` for scan '{}' again",
                p.display(),
                cat[i].name
            ))
        })?;
        sums[i] = Some(s);
    }
    let ranges: Vec<(f32, f32)> = sums
        .iter()
        .flatten()
        .filter(|s| !s.ortho)
        .map(|s| (s.depth_min, s.depth_max))
        .collect();
    out.merge = merge_params(prm, &ranges, &mut out.defaults_note);
    let mp = out.merge;
    for s in sums.iter().flatten() {
        for (k, t) in &s.times {
            match out.times.iter_mut().find(|(n, _)| n == k) {
                Some(e) => e.1 += t,
                None => out.times.push((k.clone(), *t)),
            }
        }
    }
    let max_rad: Vec<f64> = sums
        .iter()
        .map(|s| s.as_ref().map_or(0.0, |s| s.max_radius as f64))
        .collect();
    let pairs = Pairs::new(b, &occ, tmax, max_rad.iter().copied().fold(0.0, f64::max));
    drop(occ);
    let partner = |i: usize, j: usize| pairs.meets(i, j, max_rad[i].max(max_rad[j]));

    // Pass 3: merge, one input file at a time.
    std::fs::create_dir_all(&cfg.out_dir).map_err(|e| Error::io(&cfg.out_dir, e))?;
    let names: Vec<&str> = planned_outputs
        .iter()
        .filter_map(|p| p.file_name().and_then(|n| n.to_str()))
        .collect();
    crate::io::atomic::write_atomic(&unfinished_marker(cfg), |w| {
        std::io::Write::write_all(w, (names.join("\n") + "\n").as_bytes())
    })?;
    let t0 = Instant::now();
    let total: u64 = (0..n)
        .filter(|&i| selected(&cat[i]))
        .map(|i| cat[i].points as u64)
        .sum();
    obs.stage("merge", total);
    let wopts = WriteOptions {
        gamma: cfg.gamma,
        color: cfg.color,
    };
    let comment = format!(
        "mvao {} {}: ao = {} (1 = open)",
        env!("CARGO_PKG_VERSION"),
        if prm.ssao_only { "ssao-only" } else { "merge" },
        match sp.estimator {
            crate::ssao::Estimator::Paper => "paper estimator",
            crate::ssao::Estimator::Horizon => "horizon estimator",
        }
    );
    let mut merge_read = 0u64;
    let mut write_s = 0.0f64;
    // The cache gets what the budget leaves beside one input file's data and its own view.
    let mut future = Vec::new();
    for fi in 0..placer.len() {
        for i in (0..n).filter(|&i| cat[i].file == fi && selected(&cat[i])) {
            // Its own maps first, then its partners' (in the order the merge visits them).
            future.push(i);
            future.extend((0..n).filter(|&j| j != i && partner(i, j)));
        }
    }
    let pixels_of = |j: usize| {
        sums[j].as_ref().map_or(cat[j].map_pixels, |s| {
            (s.map_size[0] * s.map_size[1]) as u64
        })
    };
    let kept_views = fresh.len() as u64;
    let mut cache = MapCache {
        budget,
        outside: 0,
        reserve: 0,
        used: fresh.values().map(|(_, b)| b).sum(),
        maps: HashMap::new(),
        fresh,
        future,
        pos: 0,
        loads: 0,
        bytes_read: 0,
    };
    // A file's outputs are written while the next file is merged, when the budget holds two
    // input files beside the maps.
    let overlap = 10 * max_file_bytes + 3 * out.plan.largest_view_bytes + (64 << 20) <= budget;
    // The scans in the order they are merged.
    let mut order = Vec::new();
    for fi in 0..placer.len() {
        order.extend((0..n).filter(|&i| cat[i].file == fi && selected(&cat[i])));
    }
    std::thread::scope(|sc| -> Result<()> {
        let mut writing: Option<std::thread::ScopedJoinHandle<'_, Result<Vec<String>>>> = None;
        // The next scan's per-point products, read while this one merges.
        let mut ahead: Option<(
            usize,
            std::thread::ScopedJoinHandle<'_, Result<products::points::Points>>,
        )> = None;
        let mut pos = 0;
        for fi in 0..placer.len() {
            let mine: Vec<usize> = (0..n)
                .filter(|&i| cat[i].file == fi && selected(&cat[i]))
                .collect();
            if mine.is_empty() {
                continue;
            }
            let pf = placer.open(fi)?;
            merge_read += std::fs::metadata(&cfg.scans[fi]).map_or(0, |m| m.len());
            let mut aos: Vec<Vec<f32>> = vec![Vec::new(); pf.scans.len()];
            for &i in &mine {
                let s = &pf.scans[cat[i].index];
                // The own maps come through the cache: they are other scans' partner maps too.
                let own_pts = match ahead.take() {
                    Some((j, h)) if j == i => h.join().map_err(|_| {
                        Error::Param("reading a points product failed (internal error)".into())
                    })??,
                    _ => products::load_points(&work_dir, &cat[i].key)?,
                };
                merge_read += view_bytes(0, s.len() as u64);
                pos += 1;
                let next = order.get(pos).copied();
                if let Some(j) = next {
                    let (wd, key) = (&work_dir, cat[j].key.as_str());
                    ahead = Some((j, sc.spawn(move || products::load_points(wd, key))));
                }
                cache.reserve = MERGE_BYTES_PER_POINT * s.len() as u64
                    + next.map_or(0, |j| AHEAD_BYTES_PER_POINT * cat[j].points as u64);
                cache.measure();
                let own = cache.get(i, &work_dir, &cat[i].key, pixels_of(i), s.pose, &mp)?;
                let (own_ssao, no_sample) =
                    crate::pipeline::point_values(&own_pts.pixel, &own.ao, &own.no_sample);
                let (ao, st) = if prm.ssao_only {
                    (own_ssao.clone(), MergeStats::default())
                } else {
                    let cells = PointCells::new(&s.points, &own_pts.radii, s.pose);
                    let t = Target {
                        index: i,
                        points: &s.points,
                        radii: &own_pts.radii,
                        own_pixel: &own_pts.pixel,
                        pose: s.pose,
                        proj: &own.projection,
                        cells: Some(&cells),
                    };
                    let mut acc = Accum::new(s.len());
                    for j in (0..n).filter(|&j| partner(i, j)) {
                        let pose_j = if j == i { s.pose } else { cat[j].pose };
                        let m = if j == i {
                            own.clone()
                        } else {
                            cache.get(j, &work_dir, &cat[j].key, pixels_of(j), pose_j, &mp)?
                        };
                        let v = m.view(pose_j).ok_or_else(|| {
                            Error::Param("maps used before placing (internal error)".into())
                        })?;
                        merge::accumulate(&mut acc, &t, j, &v, &mp, &|_| {});
                    }
                    acc.finish(&own_ssao)
                };
                obs.advance(s.len() as u64);
                if cfg.preview {
                    crate::preview::write_scan_preview(
                        &cfg.out_dir.join(format!("{}.png", s.name)),
                        &own.gbuf,
                        &own.projection,
                        s.pose,
                        &ao,
                        cfg.gamma,
                        cfg.preview_style,
                    )?;
                }
                let sum = sums[i]
                    .clone()
                    .ok_or_else(|| Error::Param("summary missing (internal error)".into()))?;
                // Fixed chunks combined in order: the sum does not depend on the threads.
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
                out.scans.push(ScanReport {
                    name: s.name.clone(),
                    input: cfg.scans[fi].display().to_string(),
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
                    no_ssao_sample: no_sample,
                    zero_merge_weight: st.zero_weight,
                    point_views: st.point_views,
                    point_views_culled: st.culled,
                    ao_min: mn,
                    ao_mean: (total / s.len().max(1) as f64) as f32,
                    ao_max: mx,
                });
                if keep_values {
                    out.values.push((s.name.clone(), own_ssao, ao.clone()));
                }
                aos[cat[i].index] = ao;
            }
            // Write this file's outputs (whole files only: with --only every scan of a
            // multi-scan file must be selected).
            let ds = Dataset {
                scans: pf.scans,
                origin: (0..aos.len()).map(|k| (0, k)).collect(),
                file_to_world: pf.file_to_world,
                pose_source: pf.pose_source,
                alignment: None,
                warnings: Vec::new(),
                files: vec![pf.file],
            };
            let tw = Instant::now();
            // Writing copies the input's content: room for it before the copy.
            cache.measure();
            cache.make_room(3 * std::fs::metadata(&cfg.scans[fi]).map_or(0, |m| m.len()));
            let units = results::plan(&ds, cfg.format, &cfg.out_dir)?;
            let mut todo = Vec::new();
            for u in units {
                if u.scans.iter().all(|&k| !aos[k].is_empty()) {
                    for &k in &u.scans {
                        if let Some(r) = out.scans.iter_mut().find(|r| r.name == ds.scans[k].name) {
                            r.output = u.path.display().to_string();
                        }
                    }
                    todo.push(u);
                } else if u.scans.iter().any(|&k| !aos[k].is_empty()) {
                    out.warnings.push(format!(
                        "{}: not written, --only selected some but not all of its scans",
                        u.path.display()
                    ));
                }
            }
            // The previous file's outputs are complete before this file's are started.
            if let Some(h) = writing.take() {
                out.warnings.extend(join_writer(h)?);
            }
            let comment = comment.clone();
            let write_all = move || -> Result<Vec<String>> {
                let mut warnings = Vec::new();
                for u in &todo {
                    warnings.extend(results::write(u, &ds, &aos, wopts, &comment)?);
                }
                Ok(warnings)
            };
            if overlap {
                writing = Some(sc.spawn(write_all));
            } else {
                out.warnings.extend(write_all()?);
            }
            write_s += tw.elapsed().as_secs_f64();
        }
        if let Some(h) = writing.take() {
            let tw = Instant::now();
            out.warnings.extend(join_writer(h)?);
            write_s += tw.elapsed().as_secs_f64();
        }
        Ok(())
    })?;
    out.map_loads = cache.loads;
    out.views_kept = kept_views;
    merge_read += cache.bytes_read;
    obs.done("merge", t0.elapsed().as_secs_f64());
    out.times
        .push(("merge".into(), t0.elapsed().as_secs_f64() - write_s));
    out.times.push(("write".into(), write_s));
    out.bytes_read.push(("merge".into(), merge_read));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_hash_is_that_of_the_values_little_endian_bytes() {
        // The hash recorded in work directories: each block of 2^16 values hashed from their
        // little-endian bytes, the block hashes combined by `digest`.
        fn reference(s: &Scan) -> String {
            fn blocks(bytes: &[u8], per: usize) -> Vec<u128> {
                bytes
                    .chunks((1 << 16) * per)
                    .map(xxhash_rust::xxh3::xxh3_128)
                    .collect()
            }
            let le = |v: &mut Vec<u8>, x: f32| v.extend_from_slice(&x.to_le_bytes());
            let vec3 = |ps: &[glam::Vec3]| {
                let mut v = Vec::new();
                for p in ps {
                    for x in p.to_array() {
                        le(&mut v, x);
                    }
                }
                blocks(&v, 12)
            };
            let u32s = |xs: &[u32]| {
                let v: Vec<u8> = xs.iter().flat_map(|x| x.to_le_bytes()).collect();
                blocks(&v, 4)
            };
            let mut parts = vec![(&b"p"[..], vec3(&s.points))];
            if let Some(n) = &s.normals {
                parts.push((b"n", vec3(n)));
            }
            if let Some(g) = &s.grid {
                parts.push((b"g", vec![u128::from(g.rows), u128::from(g.cols)]));
                parts.push((b"r", u32s(&g.row)));
                parts.push((b"c", u32s(&g.col)));
            }
            digest(parts)
        }
        // Sizes around the block boundary.
        for n in [0usize, 1, 65_535, 65_536, 65_537, 200_000] {
            let points: Vec<glam::Vec3> = (0..n)
                .map(|i| glam::Vec3::new(i as f32, -(i as f32) * 0.5, 1e-3 * i as f32))
                .collect();
            let mut s = Scan::from_points("s", points.clone());
            assert_eq!(data_hash(&s), reference(&s), "{n} points");
            s.normals = Some(points.iter().map(|p| p.normalize_or_zero()).collect());
            s.grid = Some(crate::scan::Grid {
                rows: 7,
                cols: n as u32,
                row: (0..n as u32).map(|i| i % 7).collect(),
                col: (0..n as u32).collect(),
            });
            assert_eq!(
                data_hash(&s),
                reference(&s),
                "{n} points with normals and grid"
            );
        }
    }

    #[test]
    fn the_views_of_the_first_scans_are_kept_while_they_fit() {
        let all = [true; 4];
        assert_eq!(views_to_keep(&[50, 50, 50, 50], &all, 10, 210), [true; 4]);
        assert_eq!(
            views_to_keep(&[50, 50, 50, 50], &all, 10, 160),
            [true, true, true, false]
        );
        // A prefix: the small view after one that does not fit is not kept either.
        assert_eq!(
            views_to_keep(&[50, 80, 10, 50], &all, 0, 100),
            [true, false, false, false]
        );
        // Views the merge does not use are skipped, not counted.
        assert_eq!(
            views_to_keep(&[50, 80, 50, 50], &[true, false, true, true], 0, 100),
            [true, false, true, false]
        );
        assert_eq!(views_to_keep(&[50, 50], &all, 200, 100), [false, false]);
        assert_eq!(views_to_keep(&[], &[], 0, 100), Vec::<bool>::new());
    }

    #[test]
    fn held_scans_are_kept_while_they_and_the_views_fit() {
        // Scans of 30 each, views of 50: 3 held files start at 90 and end at 150 kept views.
        assert_eq!(files_to_hold(&[30, 30, 30], &[50, 50, 50], 10, 160), 3);
        // The views alone reach 150: with a margin of 20 nothing fits.
        assert_eq!(files_to_hold(&[30, 30, 30], &[50, 50, 50], 20, 165), 0);
        // Views not kept: only the held scans count, as many as fit at the start.
        assert_eq!(files_to_hold(&[30, 30, 30], &[0, 0, 0], 10, 75), 2);
        // Large scans, small views: the start decides.
        assert_eq!(files_to_hold(&[100, 100, 10], &[5, 5, 5], 0, 150), 1);
        // Views that grow faster than the held scans shrink: the middle decides.
        assert_eq!(files_to_hold(&[10, 10, 10], &[100, 100, 0], 0, 205), 2);
        assert_eq!(files_to_hold(&[], &[5, 5], 0, 150), 0);
    }
}
