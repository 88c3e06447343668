//! The work directory as a view store: each prepared view's products (EXR maps, per-point
//! file), its summary and, last, its manifest entry, so a run killed at any moment leaves the
//! directory consistent and a rerun recomputes only what is missing or stale. The merge reads
//! the maps back through a cache bounded by the memory budget.

use super::{view_bytes, StoreStats, Summary, ViewStore};
use crate::error::{Error, Result};
use crate::merge::MergeParams;
use crate::products::manifest::{Entry, InputRecord};
use crate::products::points::Points;
use crate::products::{self, Manifest, MergeMaps};
use crate::view::PreparedView;
use glam::DMat4;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::thread::JoinHandle;

/// How a run uses its work directory.
#[derive(Debug, Clone)]
pub struct WorkDirSetup {
    /// The directory (created if needed).
    pub dir: PathBuf,
    /// Each scan's name.
    pub names: Vec<String>,
    /// Each scan's product key.
    pub keys: Vec<String>,
    /// Each scan's input file.
    pub inputs: Vec<PathBuf>,
    /// Each scan's parameters as recorded in its manifest entry.
    pub params: Vec<serde_json::Value>,
    /// Each scan's map size as the catalog estimated it (pixels).
    pub map_pixels: Vec<u64>,
    /// The memory budget in bytes.
    pub budget: u64,
    /// Write a view's products on another thread while the next view is computed.
    pub overlap: bool,
    /// Views the prepare stage keeps in memory for the merge, by scan.
    pub keep: Vec<bool>,
    /// Bytes the kept views may take at most.
    pub keep_room: u64,
}

/// What saving a view gives: its manifest entry (committed on disk), and the view.
type Saved = (Result<Entry>, PreparedView);

/// A view's products, summary and manifest entry being written (on another thread when the
/// prepare stage overlaps writing with computing), and the view.
enum Saving {
    Running(JoinHandle<Saved>),
    Done(Box<Saved>),
}

/// The work directory of a run.
pub struct WorkDirStore {
    setup: WorkDirSetup,
    manifest: Manifest,
    /// The view whose commit is not known to be complete yet (scan index).
    pending: Option<(usize, Saving)>,
    kept_bytes: u64,
    sums: HashMap<usize, Summary>,
    cache: MapCache,
    /// The next scan's per-point products, read while this one merges.
    ahead: Option<(usize, JoinHandle<Result<Points>>)>,
}

/// Resident memory in use (bytes): the process's, less the freed mappings the allocator keeps
/// for the next buffers (after the freed memory it does not keep is handed back).
fn in_use() -> u64 {
    crate::sys::return_freed_memory();
    let rss = crate::sys::current_rss().unwrap_or(0);
    rss.saturating_sub(crate::bigalloc::kept_bytes())
}

/// The file of a scan's summary.
fn summary_path(dir: &Path, key: &str) -> PathBuf {
    dir.join(format!("{key}.summary.json"))
}

/// A scan's summary, when its file is there and readable (a damaged one counts as missing, so
/// that the prepare stage writes it again).
fn read_summary(p: &Path) -> Option<Summary> {
    serde_json::from_slice(&std::fs::read(p).ok()?).ok()
}

/// Writes a view's products, then its summary and, last, its manifest entry (the commit
/// point), in that order. Run off the main thread when the prepare stage overlaps writing with
/// computing: the syncs of the summary and the entry would leave a core idle.
fn save_and_record(
    work_dir: &Path,
    key: &str,
    rec: &InputRecord,
    params: &serde_json::Value,
    sum: &Summary,
    v: &PreparedView,
) -> Result<Entry> {
    let files = products::save_view(work_dir, key, v)?;
    let json = serde_json::to_vec(sum)
        .map_err(|e| Error::Param(format!("cannot encode a summary: {e}")))?;
    crate::io::atomic::write_atomic(&summary_path(work_dir, key), |w| {
        std::io::Write::write_all(w, &json)
    })?;
    products::manifest::write_record(work_dir, key, std::slice::from_ref(rec), params, &files)
}

impl WorkDirStore {
    /// Opens (creating) the work directory of `setup`, with the manifest's warnings.
    pub fn open(setup: WorkDirSetup) -> Result<(WorkDirStore, Vec<String>)> {
        std::fs::create_dir_all(&setup.dir).map_err(|e| Error::io(&setup.dir, e))?;
        let mut manifest = Manifest::load(&setup.dir);
        let warnings = std::mem::take(&mut manifest.warnings);
        let cache = MapCache {
            budget: setup.budget,
            outside: 0,
            reserve: 0,
            step_start: 0,
            used: 0,
            maps: HashMap::new(),
            fresh: HashMap::new(),
            future: Vec::new(),
            pos: 0,
            loads: 0,
            bytes_read: 0,
            kept: 0,
        };
        let store = WorkDirStore {
            setup,
            manifest,
            pending: None,
            kept_bytes: 0,
            sums: HashMap::new(),
            cache,
            ahead: None,
        };
        Ok((store, warnings))
    }

    /// Waits for the pending view's commit, takes note of its entry and keeps the view for the
    /// merge when planned and it fits.
    fn commit(&mut self) -> Result<()> {
        let Some((i, saving)) = self.pending.take() else {
            return Ok(());
        };
        let (entry, view) = match saving {
            Saving::Running(h) => h.join().map_err(|_| {
                Error::Param("writing a view's products failed (internal error)".into())
            })?,
            Saving::Done(r) => *r,
        };
        self.manifest.insert(entry?);
        if self.setup.keep[i] {
            let m = MergeMaps::from_view(view);
            let b = m.heap_bytes();
            // The plan counted estimated sizes: a view larger than estimated is not kept
            // beyond the room the plan gave the views.
            // The estimate leaves out what the process holds beside the views (the catalog,
            // thread stacks, the allocator's own pages), so the view is also kept only when
            // the resident memory measured now, this view included, leaves one more step's
            // room in the budget.
            let held = in_use();
            let step = self.setup.budget.saturating_sub(self.setup.keep_room);
            if self.kept_bytes + b <= self.setup.keep_room && held + step <= self.setup.budget {
                self.kept_bytes += b;
                self.cache.used += b;
                self.cache.kept += 1;
                self.cache.fresh.insert(i, (m, b));
            }
        }
        Ok(())
    }

    /// Map size of scan `j` in pixels: its summary's, else the catalog's estimate.
    fn pixels_of(&self, j: usize) -> u64 {
        self.sums.get(&j).map_or(self.setup.map_pixels[j], |s| {
            (s.map_size[0] * s.map_size[1]) as u64
        })
    }
}

impl ViewStore for WorkDirStore {
    fn is_current(&mut self, i: usize) -> bool {
        let s = &self.setup;
        self.manifest
            .is_fresh(&s.keys[i], &[&s.inputs[i]], &s.params[i])
            && read_summary(&summary_path(&s.dir, &s.keys[i])).is_some()
    }

    fn put(
        &mut self,
        i: usize,
        record: Option<&InputRecord>,
        sum: Summary,
        view: PreparedView,
    ) -> Result<()> {
        let rec = record.cloned().ok_or_else(|| {
            Error::Param("a view without its input's record (internal error)".into())
        })?;
        // The previous view is committed before this one's products are written.
        self.commit()?;
        let s = &self.setup;
        let (key, wd, prm) = (s.keys[i].clone(), s.dir.clone(), s.params[i].clone());
        let save = move || (save_and_record(&wd, &key, &rec, &prm, &sum, &view), view);
        let saving = if s.overlap {
            Saving::Running(std::thread::spawn(save))
        } else {
            Saving::Done(Box::new(save()))
        };
        self.pending = Some((i, saving));
        Ok(())
    }

    fn finish_prepare(&mut self) -> Result<()> {
        self.commit()?;
        let _ = self.manifest.save();
        Ok(())
    }

    fn summary(&mut self, i: usize) -> Result<Summary> {
        if let Some(s) = self.sums.get(&i) {
            return Ok(s.clone());
        }
        let p = summary_path(&self.setup.dir, &self.setup.keys[i]);
        let s = read_summary(&p).ok_or_else(|| {
            Error::Param(format!(
                "{}: missing or damaged; run `mvao prepare` for scan '{}' again",
                p.display(),
                self.setup.names[i]
            ))
        })?;
        self.sums.insert(i, s.clone());
        Ok(s)
    }

    fn expect(&mut self, loads: Vec<usize>) {
        self.cache.future = loads;
        self.cache.pos = 0;
    }

    fn points(&mut self, i: usize, next: Option<usize>) -> Result<Points> {
        let dir = &self.setup.dir;
        let pts = match self.ahead.take() {
            Some((j, h)) if j == i => h.join().map_err(|_| {
                Error::Param("reading a points product failed (internal error)".into())
            })??,
            _ => products::load_points(dir, &self.setup.keys[i])?,
        };
        if let Some(j) = next {
            let (wd, key) = (dir.clone(), self.setup.keys[j].clone());
            self.ahead = Some((
                j,
                std::thread::spawn(move || products::load_points(&wd, &key)),
            ));
        }
        Ok(pts)
    }

    fn reserve(&mut self, bytes: u64) {
        self.cache.reserve = bytes;
        self.cache.measure();
        self.cache.step_start = self.cache.outside;
    }

    fn maps(&mut self, j: usize, pose: DMat4, prm: &MergeParams) -> Result<Arc<MergeMaps>> {
        let pixels = self.pixels_of(j);
        self.cache
            .get(j, &self.setup.dir, &self.setup.keys[j], pixels, pose, prm)
    }

    fn make_room(&mut self, bytes: u64) {
        self.cache.measure();
        self.cache.make_room(bytes);
    }

    fn stats(&self) -> StoreStats {
        StoreStats {
            map_loads: self.cache.loads,
            views_kept: self.cache.kept,
            bytes_read: self.cache.bytes_read,
        }
    }
}

impl Drop for WorkDirStore {
    /// A run stopped by an error still waits for the products being written, so that no
    /// thread outlives the store.
    fn drop(&mut self) {
        if let Some((_, Saving::Running(h))) = self.pending.take() {
            let _ = h.join();
        }
        if let Some((_, h)) = self.ahead.take() {
            let _ = h.join();
        }
    }
}

/// A cache of other scans' maps, bounded in bytes. The merge's order of loads is known in
/// advance, so the map evicted is the one needed again the latest (Belady's rule): with a
/// cyclic order, least-recently-used would miss every time once the maps do not all fit.
struct MapCache {
    budget: u64,
    /// Memory the process holds outside the cache (measured when a scan's step begins and
    /// before each load).
    outside: u64,
    /// Memory the scan being merged will allocate after that measurement (its sums, cells
    /// and results), kept free.
    reserve: u64,
    /// `outside` when the scan's step began: what the step allocates since then is part of its
    /// reserve, not more of it.
    step_start: u64,
    used: u64,
    maps: HashMap<usize, (Arc<MergeMaps>, u64)>,
    /// Views this run prepared, kept for the merge (not placed yet).
    fresh: HashMap<usize, (MergeMaps, u64)>,
    /// Every load the merge will ask for, in order, and how far it has got.
    future: Vec<usize>,
    pos: usize,
    loads: u64,
    bytes_read: u64,
    /// Views the prepare stage handed over.
    kept: u64,
}

impl MapCache {
    /// Measures what the process holds beside the cache.
    fn measure(&mut self) {
        self.outside = in_use().saturating_sub(self.used);
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
        // What the step has grown by since it began is part of its reserve, not more of it
        // (memory freed meanwhile by others leaves the step's reserve whole).
        let grown = self.outside.saturating_sub(self.step_start);
        let step = self.outside + self.reserve.saturating_sub(grown);
        let room = self.budget.saturating_sub(step);
        // Freed mappings the allocator keeps are resident beside the budget's count: as many
        // are returned as the load would not fit beside.
        crate::bigalloc::trim_kept(room.saturating_sub(self.used + need));
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
                    // What the process holds beside the cache grows within a scan's step (its
                    // sums, the outputs being built): measured again before each load, so that
                    // the growth is counted against the budget.
                    self.measure();
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
