//! Per-scan products on disk, so the merge runs out of core and reruns reuse what is unchanged
//! (specification, "Out-of-core").
//!
//! A work directory holds, for each product key (one scan's prepared view):
//!
//! | file | content |
//! |---|---|
//! | `<key>.<hash>.maps.exr` | the per-pixel maps, one multi-channel EXR ([`exr_io`]) |
//! | `<key>.<hash>.points.bin` | radius, pixel, depth (and native-grid pixel) per point ([`points`]) |
//! | `<key>.manifest.json` | inputs, parameters, version, product hashes, sensor ([`manifest`]) |
//! | `manifest.json` | a snapshot of all entries, for people ([`Manifest::save`]) |
//!
//! `<hash>` is the first 16 hex digits of the file's xxh3-128, so a rerun writes new products
//! beside the old ones instead of over them. The order of a save is: products (each by
//! temporary file and rename), then the entry (the same way), then removal of the key's older
//! products. A kill at any moment leaves either the old entry with its old products or the new
//! entry with its new ones; leftover temporary files are ignored and removed by the next
//! [`Manifest::load`], unreferenced products by the key's next [`Manifest::record`].
//!
//! Loading checks sizes and xxh3-128 hashes of every product and of the entry itself: a
//! truncated, altered or foreign file is an [`Error`], never a wrong value.
//!
//! Usage: `if !m.is_fresh(key, &inputs, &params) { let rec = InputRecord::capture(..)?; /*
//! read, prepare_view */; let files = save_view(dir, key, &view)?; m.record(key, &[rec],
//! &params, &files)?; }`, later `load_view(dir, key)` or [`load_maps_for_merge`].

pub mod exr_io;
pub mod manifest;
pub mod points;

pub use exr_io::MapCompression;
pub use manifest::{Check, Entry, InputRecord, Manifest, ProductFile, ProductFiles, ViewMeta};

use crate::error::{Error, Result};
use crate::gbuffer::GBuffer;
use crate::io::atomic::write_atomic_with;
use crate::merge::cull::ViewCells;
use crate::merge::{MergeParams, View, ViewMaps};
use crate::projection::{Projection, Warp};
use crate::sensor::SensorSetup;
use crate::ssao::AoMap;
use crate::view::PreparedView;
use glam::DMat4;
use manifest::{hex128, read_entry, FORMAT, MVAO_VERSION};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};
use xxhash_rust::xxh3::xxh3_128;

/// Suffix of the maps product.
const MAPS_SUFFIX: &str = "maps.exr";
/// Suffix of the points product.
const POINTS_SUFFIX: &str = "points.bin";

/// How [`save_view_with`] writes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SaveOptions {
    /// Compression of the EXR maps.
    pub compression: MapCompression,
}

/// Checks that `key` can name files: 1–200 characters of `A–Z a–z 0–9 . _ -`, not starting
/// with a dot (hidden names are temporary files).
pub fn check_key(key: &str) -> Result<()> {
    let ok = !key.is_empty()
        && key.len() <= 200
        && !key.starts_with('.')
        && key
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'));
    if ok {
        Ok(())
    } else {
        Err(Error::Param(format!(
            "product key '{key}': use 1 to 200 of A-Z a-z 0-9 . _ - and do not start with '.'"
        )))
    }
}

/// A valid key made from any name (a scan's file stem): other characters become `_`, a
/// leading dot `_`. Distinct names may map to one key; the caller keeps keys distinct.
pub fn key_from_name(name: &str) -> String {
    let mut k: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .take(200)
        .collect();
    if k.is_empty() || k.starts_with('.') {
        k.replace_range(0..k.len().min(1), "_");
        if k.is_empty() {
            k.push('_');
        }
    }
    k
}

/// Writes `view`'s products for `key` into `dir` (created if needed) and returns what to
/// [`Manifest::record`]. Nothing is visible to [`load_view`] until that record.
pub fn save_view(dir: &Path, key: &str, view: &PreparedView) -> Result<ProductFiles> {
    save_view_with(dir, key, view, &SaveOptions::default())
}

/// [`save_view`] with options.
pub fn save_view_with(
    dir: &Path,
    key: &str,
    view: &PreparedView,
    opt: &SaveOptions,
) -> Result<ProductFiles> {
    check_key(key)?;
    check_view(key, view)?;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let meta = ViewMeta {
        projection: view.sensor.projection.clone(),
        fit_rms_px: view.sensor.fit_rms_px,
        reason: view.sensor.reason.clone(),
        normals_note: view.normals_note.clone(),
        times: view
            .times
            .iter()
            .map(|(n, s)| (n.to_string(), *s))
            .collect(),
        points: view.radii.len() as u64,
        native_grid: view.sensor.grid_pixels.is_some(),
    };
    check_meta_roundtrip(key, &meta)?;
    let g = &view.gbuf;
    let maps = {
        exr_io::encode_maps(
            g,
            &view.ssao.ao,
            &view.ssao.no_sample,
            &view.border,
            opt.compression,
        )
    }
    .map_err(|m| Error::scan(key, m))?;
    let maps = write_product(dir, key, MAPS_SUFFIX, &maps)?;
    let pts = points::encode(
        &view.radii,
        &view.pixel,
        &view.depth,
        view.sensor.grid_pixels.as_deref(),
    );
    let pts = write_product(dir, key, POINTS_SUFFIX, &pts)?;
    Ok(ProductFiles {
        maps,
        points: pts,
        view: meta,
    })
}

/// Every per-view array has the size its map or point count says.
fn check_view(key: &str, v: &PreparedView) -> Result<()> {
    let g = &v.gbuf;
    let p = &v.sensor.projection;
    let n = g.width.saturating_mul(g.height);
    let np = v.radii.len();
    let bad = |what: &str, got: usize, want: usize| {
        Err(Error::scan(
            key,
            format!("cannot store the view: {what} has {got} entries, {want} expected"),
        ))
    };
    if (p.width, p.height) != (g.width, g.height) {
        return Err(Error::scan(
            key,
            format!(
                "cannot store the view: projection {}x{} but G-buffer {}x{}",
                p.width, p.height, g.width, g.height
            ),
        ));
    }
    let maps: [(&str, usize); 8] = [
        ("G-buffer point", g.point.len()),
        ("G-buffer depth", g.depth.len()),
        ("G-buffer position", g.position.len()),
        ("G-buffer normal", g.normal.len()),
        ("G-buffer radius", g.radius.len()),
        ("SSAO map", v.ssao.ao.len()),
        ("SSAO no-sample map", v.ssao.no_sample.len()),
        ("border map", v.border.len()),
    ];
    for (what, len) in maps {
        if len != n {
            return bad(what, len, n);
        }
    }
    let pts = [
        ("pixel", v.pixel.len()),
        ("depth", v.depth.len()),
        (
            "grid pixels",
            v.sensor.grid_pixels.as_ref().map_or(np, Vec::len),
        ),
    ];
    for (what, len) in pts {
        if len != np {
            return bad(what, len, np);
        }
    }
    Ok(())
}

/// The metadata must come back from JSON bit for bit (a NaN or infinity would not).
fn check_meta_roundtrip(key: &str, meta: &ViewMeta) -> Result<()> {
    let back: Option<ViewMeta> = serde_json::to_string(meta)
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok());
    let same = back.as_ref().is_some_and(|b| {
        b == meta
            && b.fit_rms_px.map(f64::to_bits) == meta.fit_rms_px.map(f64::to_bits)
            && b.times
                .iter()
                .zip(&meta.times)
                .all(|(x, y)| x.1.to_bits() == y.1.to_bits())
    });
    if same {
        Ok(())
    } else {
        Err(Error::scan(
            key,
            "cannot store the view: its projection or timings hold a non-finite number",
        ))
    }
}

/// Writes one content-named product atomically.
fn write_product(dir: &Path, key: &str, suffix: &str, bytes: &[u8]) -> Result<ProductFile> {
    let h = xxh3_128(bytes);
    let name = format!("{key}.{:016x}.{suffix}", (h >> 64) as u64);
    let path = dir.join(&name);
    { write_atomic_with(&path, false, |w| w.write_all(bytes)) }?;
    Ok(ProductFile {
        name,
        size: bytes.len() as u64,
        xxh3_128: hex128(h),
    })
}

/// Reads a product and checks its size and hash against the entry.
fn read_product(dir: &Path, f: &ProductFile) -> Result<(PathBuf, Vec<u8>)> {
    let path = dir.join(&f.name);
    let bytes = crate::io::direct::read(&path).map_err(|e| Error::io(&path, e))?;
    if bytes.len() as u64 != f.size {
        return Err(Error::format(
            &path,
            format!(
                "{} bytes, {} recorded (truncated or replaced)",
                bytes.len(),
                f.size
            ),
        ));
    }
    if hex128(xxh3_128(&bytes)) != f.xxh3_128 {
        return Err(Error::format(&path, "checksum mismatch (corrupt)"));
    }
    Ok((path, bytes))
}

/// The entry of `key`, required to be of this mvao and layout.
fn current_entry(dir: &Path, key: &str) -> Result<Entry> {
    check_key(key)?;
    let e = read_entry(dir, key)?;
    let path = manifest::entry_path(dir, key);
    if e.format != FORMAT || e.mvao_version != MVAO_VERSION {
        return Err(Error::format(
            &path,
            format!(
                "made by mvao {} (layout {}); this is mvao {MVAO_VERSION} (layout {FORMAT})",
                e.mvao_version, e.format
            ),
        ));
    }
    check_projection(&e.products.view.projection)
        .map_err(|m| Error::format(&path, format!("invalid projection: {m}")))?;
    Ok(e)
}

/// A deserialized projection is used as is: reject what [`Warp::new`] or the map would not
/// accept, so a bad entry cannot panic later.
fn check_projection(p: &Projection) -> std::result::Result<(), String> {
    if p.width == 0 || p.height == 0 {
        return Err(format!("{}x{} map", p.width, p.height));
    }
    for w in [&p.warp_x, &p.warp_y].into_iter().flatten() {
        if !warp_valid(w) {
            return Err("warp knots are not strictly increasing".into());
        }
    }
    Ok(())
}

fn warp_valid(w: &Warp) -> bool {
    #[derive(serde::Deserialize)]
    struct Knots {
        knots: Vec<f32>,
    }
    serde_json::to_value(w)
        .ok()
        .and_then(|v| serde_json::from_value::<Knots>(v).ok())
        .and_then(|k| Warp::new(k.knots))
        .is_some()
}

/// Loads `key`'s prepared view, bit-identical to what [`save_view`] was given. Errors (the
/// caller recomputes): no entry, another mvao version, a missing, truncated or corrupt product.
pub fn load_view(dir: &Path, key: &str) -> Result<PreparedView> {
    let e = current_entry(dir, key)?;
    let pts = forget_on_damage(dir, key, read_points(dir, &e))?;
    let maps = forget_on_damage(dir, key, read_maps(dir, &e))?;
    let meta = e.products.view;
    Ok(PreparedView {
        sensor: SensorSetup {
            projection: meta.projection,
            grid_pixels: pts.grid_pixels,
            fit_rms_px: meta.fit_rms_px,
            reason: meta.reason,
        },
        gbuf: maps.gbuf,
        ssao: AoMap {
            ao: maps.ao,
            no_sample: maps.no_sample.unwrap_or_default(),
            levels: None,
        },
        border: maps.border,
        radii: pts.radii,
        pixel: pts.pixel,
        depth: pts.depth,
        normals_note: meta.normals_note,
        times: meta.times.iter().map(|(n, s)| (intern(n), *s)).collect(),
    })
}

fn check_map_size(path: &Path, g: &GBuffer, p: &Projection) -> Result<()> {
    if (g.width, g.height) != (p.width, p.height) {
        return Err(Error::format(
            path,
            format!(
                "map is {}x{}, the projection {}x{}",
                g.width, g.height, p.width, p.height
            ),
        ));
    }
    Ok(())
}

/// What the merge reads of another scan's view: projection, G-buffer, SSAO and border maps.
#[derive(Debug, Clone)]
pub struct MergeMaps {
    /// The view's projection.
    pub projection: Projection,
    /// Its G-buffer.
    pub gbuf: GBuffer,
    /// Its per-pixel SSAO.
    pub ao: Vec<f32>,
    /// Where a valid pixel had no SSAO sample.
    pub no_sample: Vec<bool>,
    /// Its per-pixel border distance.
    pub border: Vec<f32>,
    /// Number of points of the scan.
    pub points: u64,
    /// Its cells and packed maps, once placed by its pose ([`MergeMaps::place`]).
    pub placed: Option<(ViewCells, ViewMaps)>,
}

impl MergeMaps {
    /// Computes the view's cells at `pose` and packs its maps for a merge with `prm`; the
    /// G-buffer's position, normal, radius and depth and the border map are then freed (the
    /// packed maps hold what the merge reads of them).
    pub fn place(&mut self, pose: DMat4, prm: &MergeParams) {
        let cells = ViewCells::new(&self.gbuf, pose);
        let maps = ViewMaps::new(&self.projection, &self.gbuf, &self.ao, &self.border, prm);
        let g = &mut self.gbuf;
        (g.position, g.normal, g.radius, g.depth) = Default::default();
        self.border = Vec::new();
        self.placed = Some((cells, maps));
    }

    /// Heap bytes held (maps, cells and packed maps).
    pub fn heap_bytes(&self) -> u64 {
        let g = &self.gbuf;
        let maps = 4 * (g.point.capacity() + g.depth.capacity() + g.radius.capacity())
            + 12 * (g.position.capacity() + g.normal.capacity())
            + 4 * (self.ao.capacity() + self.border.capacity())
            + self.no_sample.capacity();
        maps as u64
            + self
                .placed
                .as_ref()
                .map_or(0, |(c, m)| c.heap_bytes() + m.heap_bytes())
    }

    /// The merge's view of these maps with the scan's local → world pose (`None` until
    /// [`MergeMaps::place`]d).
    pub fn view(&self, pose: DMat4) -> Option<View<'_>> {
        let (cells, maps) = self.placed.as_ref()?;
        Some(View {
            proj: &self.projection,
            maps,
            pose,
            cells: Some(cells),
        })
    }
}

impl MergeMaps {
    /// What the merge reads of a view just prepared (the same values its products hold).
    pub fn from_view(v: PreparedView) -> MergeMaps {
        MergeMaps {
            projection: v.sensor.projection,
            points: v.radii.len() as u64,
            gbuf: v.gbuf,
            ao: v.ssao.ao,
            no_sample: v.ssao.no_sample,
            border: v.border,
            placed: None,
        }
    }
}

/// Loads only what the merge reads of `key`'s view (no per-point file, no no-sample flags):
/// cheaper than [`load_view`] when scan j is only a partner of other scans.
pub fn load_maps_for_merge(dir: &Path, key: &str) -> Result<MergeMaps> {
    let e = current_entry(dir, key)?;
    let maps = forget_on_damage(dir, key, read_maps(dir, &e))?;
    let meta = e.products.view;
    let n = maps.gbuf.width * maps.gbuf.height;
    Ok(MergeMaps {
        projection: meta.projection,
        gbuf: maps.gbuf,
        ao: maps.ao,
        no_sample: maps.no_sample.unwrap_or_else(|| vec![false; n]),
        border: maps.border,
        points: meta.points,
        placed: None,
    })
}

/// Loads `key`'s per-point products (radius, pixel, depth, grid pixel), checked against its
/// entry and against the map size.
pub fn load_points(dir: &Path, key: &str) -> Result<points::Points> {
    let e = current_entry(dir, key)?;
    forget_on_damage(dir, key, read_points(dir, &e))
}

/// Reads and checks the maps of an entry.
fn read_maps(dir: &Path, e: &Entry) -> Result<exr_io::Maps> {
    let (mpath, mbytes) = read_product(dir, &e.products.maps)?;
    let maps = exr_io::decode_maps(&mbytes, &mpath, Some(e.products.view.points), true)?;
    drop(mbytes);
    check_map_size(&mpath, &maps.gbuf, &e.products.view.projection)?;
    Ok(maps)
}

/// A damaged product (truncated, altered, not what its entry says) is never used again: the
/// key's entry is removed, so the next run recomputes its products instead of failing on them.
fn forget_on_damage<T>(dir: &Path, key: &str, r: Result<T>) -> Result<T> {
    match r {
        Err(Error::Format { path, msg }) => {
            let _ = std::fs::remove_file(manifest::entry_path(dir, key));
            Err(Error::Format {
                path,
                msg: format!(
                    "{msg}; the products of scan key '{key}' are dropped: run again to \
                     recompute them"
                ),
            })
        }
        r => r,
    }
}

/// Reads and checks the per-point products of an entry.
fn read_points(dir: &Path, e: &Entry) -> Result<points::Points> {
    let (ppath, pbytes) = read_product(dir, &e.products.points)?;
    let pts = points::decode(&pbytes, &ppath)?;
    drop(pbytes);
    check_points(&ppath, &pts, &e.products.view)?;
    Ok(pts)
}

/// The per-point products agree with the entry: count, grid, pixels inside the map.
fn check_points(path: &Path, pts: &points::Points, meta: &ViewMeta) -> Result<()> {
    if pts.radii.len() as u64 != meta.points || pts.grid_pixels.is_some() != meta.native_grid {
        return Err(Error::format(
            path,
            format!(
                "{} points{}, the entry says {}{}",
                pts.radii.len(),
                if pts.grid_pixels.is_some() {
                    " with grid"
                } else {
                    ""
                },
                meta.points,
                if meta.native_grid { " with grid" } else { "" }
            ),
        ));
    }
    let n = meta.projection.width * meta.projection.height;
    let oob = |v: &[u32]| {
        v.iter()
            .any(|&p| p != crate::gbuffer::EMPTY && p as usize >= n)
    };
    if oob(&pts.pixel) || pts.grid_pixels.as_deref().is_some_and(oob) {
        return Err(Error::format(path, "a point's pixel lies outside the map"));
    }
    Ok(())
}

/// A stage name as the `&'static str` [`PreparedView::times`] holds: the pipeline's names
/// directly, any other name leaked once and reused.
fn intern(name: &str) -> &'static str {
    const KNOWN: [&str; 5] = ["sensor", "normals", "gbuffer", "ssao", "border"];
    if let Some(k) = KNOWN.iter().find(|k| **k == name) {
        return k;
    }
    static OTHERS: OnceLock<Mutex<Vec<&'static str>>> = OnceLock::new();
    let mut v = match OTHERS.get_or_init(Default::default).lock() {
        Ok(v) => v,
        Err(p) => p.into_inner(),
    };
    if let Some(k) = v.iter().find(|k| **k == name) {
        return k;
    }
    let k: &'static str = Box::leak(name.to_string().into_boxed_str());
    v.push(k);
    k
}

/// True when `name` is a product of `key` (`<key>.<16 hex>.<suffix>`).
fn is_product_of(name: &str, key: &str) -> bool {
    let Some(rest) = name.strip_prefix(key).and_then(|r| r.strip_prefix('.')) else {
        return false;
    };
    let (hash, suffix) = rest.split_at(rest.len().min(16));
    hash.len() == 16
        && hash.bytes().all(|b| b.is_ascii_hexdigit())
        && matches!(
            suffix.strip_prefix('.'),
            Some(MAPS_SUFFIX) | Some(POINTS_SUFFIX)
        )
}

/// Removes `key`'s product files other than `keep` (best effort: a leftover is harmless).
fn remove_old_products(dir: &Path, key: &str, keep: &[&str]) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    for de in rd.flatten() {
        let name = de.file_name();
        let Some(name) = name.to_str() else { continue };
        if is_product_of(name, key) && !keep.contains(&name) {
            let _ = std::fs::remove_file(de.path());
        }
    }
}

/// Removes temporary files (`.<name>.tmp-<pid>`, see [`crate::io::atomic::temp_path`]) left in
/// `dir` by interrupted writers: untouched for [`manifest::STALE_TEMP`] and, on Linux, whose
/// process is gone. Returns the removed paths; failures become warnings.
pub fn clean_stale_temps(dir: &Path, warnings: &mut Vec<String>) -> Vec<PathBuf> {
    let mut removed = Vec::new();
    let Ok(rd) = std::fs::read_dir(dir) else {
        return removed;
    };
    let now = std::time::SystemTime::now();
    for de in rd.flatten() {
        let name = de.file_name();
        let Some(name) = name.to_str() else { continue };
        let Some(pid) = temp_pid(name) else { continue };
        if pid == std::process::id() || process_alive(pid) {
            continue;
        }
        let old = de
            .metadata()
            .ok()
            .filter(|m| m.is_file())
            .and_then(|m| m.modified().ok())
            .and_then(|t| now.duration_since(t).ok())
            .is_some_and(|age| age >= manifest::STALE_TEMP);
        if !old {
            continue;
        }
        let p = de.path();
        match std::fs::remove_file(&p) {
            Ok(()) => removed.push(p),
            Err(e) => warnings.push(format!(
                "{}: cannot remove stale temporary file: {e}",
                p.display()
            )),
        }
    }
    removed
}

/// The writer's process id of a temporary file name `.<name>.tmp-<pid>`.
fn temp_pid(name: &str) -> Option<u32> {
    if !name.starts_with('.') {
        return None;
    }
    let (_, pid) = name.rsplit_once(".tmp-")?;
    if pid.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    pid.parse().ok()
}

/// True when a local process `pid` exists (Linux); elsewhere unknown, so false and only the
/// age decides.
fn process_alive(pid: u32) -> bool {
    #[cfg(target_os = "linux")]
    {
        Path::new("/proc").join(pid.to_string()).exists()
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = pid;
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_and_product_names() {
        assert!(check_key("station_000").is_ok());
        assert!(check_key("a.b-c").is_ok());
        for bad in ["", ".hidden", "a/b", "a b", "ä"] {
            assert!(check_key(bad).is_err(), "{bad}");
        }
        assert_eq!(key_from_name("scan 1/ä"), "scan_1__");
        assert_eq!(key_from_name(".x"), "_x");
        assert_eq!(key_from_name(""), "_");
        assert!(check_key(&key_from_name("..")).is_ok());
        let h = "0123456789abcdef";
        assert!(is_product_of(&format!("a.{h}.maps.exr"), "a"));
        assert!(is_product_of(&format!("a.{h}.points.bin"), "a"));
        assert!(!is_product_of(&format!("a.{h}.maps.exr.tmp"), "a"));
        assert!(!is_product_of(&format!("a.b.{h}.maps.exr"), "a"));
        assert!(!is_product_of(&format!("a.{h}.manifest.json"), "a"));
        assert!(!is_product_of("a.manifest.json", "a"));
        assert_eq!(temp_pid(".a.maps.exr.tmp-123"), Some(123));
        assert_eq!(temp_pid("a.tmp-123"), None);
        assert_eq!(temp_pid(".a.tmp-12x"), None);
    }

    #[test]
    fn intern_keeps_names() {
        assert_eq!(intern("ssao"), "ssao");
        let a = intern("some new stage");
        let b = intern("some new stage");
        assert!(std::ptr::eq(a, b));
    }

    #[test]
    fn points_file_rejects_damage() {
        let radii = [0.5f32, 1.0, f32::MIN_POSITIVE];
        let pixel = [0u32, crate::gbuffer::EMPTY, 7];
        let depth = [1.0f32, f32::INFINITY, 2.5];
        let grid = [1u32, 2, 3];
        let b = points::encode(&radii, &pixel, &depth, Some(&grid));
        let p = Path::new("x.points.bin");
        let d = points::decode(&b, p).unwrap();
        assert_eq!(d.radii, radii);
        assert_eq!(d.pixel, pixel);
        assert_eq!(d.depth, depth);
        assert_eq!(d.grid_pixels.as_deref(), Some(&grid[..]));
        for cut in [0, 10, points::HEADER_LEN, b.len() - 1] {
            assert!(points::decode(&b[..cut], p).is_err(), "cut at {cut}");
        }
        let mut flip = b.clone();
        let last = flip.len() - 1;
        flip[last] ^= 1;
        assert!(points::decode(&flip, p).is_err());
        let mut ver = b.clone();
        ver[8] = 9;
        assert!(points::decode(&ver, p).is_err());
        let empty = points::encode(&[], &[], &[], None);
        assert_eq!(
            points::decode(&empty, p).unwrap(),
            points::Points::default()
        );
    }
}
