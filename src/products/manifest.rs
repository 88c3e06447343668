//! What each product was made from, so reruns reuse what is unchanged.
//!
//! **One entry file per product key** (`DIR/<key>.manifest.json`), not one shared file:
//! several processes (a workflow engine running one `mvao prepare` per scan) may record
//! products at the same time, and each writes only its own key's file, by temporary file and
//! rename. The set of entries is built by listing the directory; no lock is needed because no
//! two writers share a file. (One writer per key is assumed: two processes preparing the same
//! key at once may leave that key not fresh, never wrong, since loading checks every hash.)
//! [`Manifest::save`] also writes `DIR/manifest.json`, a snapshot of all entries for people
//! and tools; it is never read back for decisions.
//!
//! An entry holds the inputs (path, size, mtime, inode, xxh3-128 of the content and when it
//! was hashed), the xxh3-128 of the canonical JSON of the parameters, the mvao version, the
//! product files with sizes and hashes, and the view's sensor metadata. The entry carries its
//! own checksum, so a damaged entry is dropped (with a warning) rather than trusted.
//!
//! **Freshness.** [`Check::Quick`] trusts an input whose size, mtime and inode are as recorded
//! and whose mtime was at least [`RACY_MARGIN_S`] older than the moment it was hashed (a file
//! modified within the file system's timestamp granularity of the hash could keep its mtime
//! while its content changed, so such a "racy" input is always hashed again, as git does).
//! Any other input is hashed: a touched but unchanged file stays fresh, a changed one is
//! stale. A tool that rewrites a file keeping its size, mtime and inode defeats the quick
//! check; [`Check::Content`] hashes every input every time.

use crate::error::{Error, Result};
use crate::io::atomic::write_atomic;
use crate::projection::Projection;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::BTreeMap;
use std::io::{ErrorKind, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use xxhash_rust::xxh3::{xxh3_128, Xxh3};

/// Layout version of the products and entries; a different one is never fresh.
pub const FORMAT: u32 = 1;
/// The mvao version and build (a hash of the sources the binary was built from) recorded in,
/// and required of, every entry: products of another build are made again.
pub const MVAO_VERSION: &str = concat!(env!("CARGO_PKG_VERSION"), "+", env!("MVAO_SOURCE_HASH"));
/// Suffix of a key's entry file.
pub const ENTRY_SUFFIX: &str = ".manifest.json";
/// The snapshot of all entries written by [`Manifest::save`].
pub const INDEX_FILE: &str = "manifest.json";
/// An input modified less than this many seconds before it was hashed is re-hashed on every
/// check (mtime granularity is 2 s on some file systems).
pub const RACY_MARGIN_S: i64 = 3;
/// A temporary file untouched for this long whose writer is gone is removed.
pub const STALE_TEMP: Duration = Duration::from_secs(120);
/// Read buffer of the streaming hash.
const HASH_BUF: usize = 4 << 20;

/// A file time as seconds and nanoseconds since the Unix epoch (negative before it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct FileTime {
    /// Whole seconds (floor).
    pub secs: i64,
    /// Nanoseconds within the second, 0..1e9.
    pub nanos: u32,
}

impl FileTime {
    /// Converts a system time.
    pub fn from_system(t: SystemTime) -> FileTime {
        match t.duration_since(UNIX_EPOCH) {
            Ok(d) => FileTime {
                secs: i64::try_from(d.as_secs()).unwrap_or(i64::MAX),
                nanos: d.subsec_nanos(),
            },
            Err(e) => {
                let d = e.duration();
                let secs = -i64::try_from(d.as_secs()).unwrap_or(i64::MAX);
                match d.subsec_nanos() {
                    0 => FileTime { secs, nanos: 0 },
                    n => FileTime {
                        secs: secs - 1,
                        nanos: 1_000_000_000 - n,
                    },
                }
            }
        }
    }

    /// Now.
    pub fn now() -> FileTime {
        FileTime::from_system(SystemTime::now())
    }
}

/// The state of one input file when its product was made.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InputRecord {
    /// The path as the caller gave it.
    pub path: String,
    /// Size in bytes.
    pub size: u64,
    /// Modification time.
    pub mtime: FileTime,
    /// Inode number (Unix), to notice a file replaced by another.
    pub ino: Option<u64>,
    /// xxh3-128 of the content, 32 hex digits.
    pub xxh3_128: String,
    /// When hashing started.
    pub hashed_at: FileTime,
}

impl InputRecord {
    /// Stats and hashes `path`. Call it before reading the input for the computation, so the
    /// record describes content no newer than what was used (a later change is then seen as
    /// stale). A file that changes while it is hashed is an error.
    pub fn capture(path: &Path) -> Result<InputRecord> {
        let before = stat(path)?;
        let hashed_at = FileTime::now();
        let (size, hash) = hash_file(path)?;
        let after = stat(path)?;
        if before != after || size != before.size {
            return Err(Error::format(
                path,
                "changed while it was being hashed; run again once it is complete",
            ));
        }
        Ok(InputRecord {
            path: path_string(path),
            size,
            mtime: before.mtime,
            ino: before.ino,
            xxh3_128: hash,
            hashed_at,
        })
    }

    /// The size, modification time and inode the record holds.
    pub fn stat(&self) -> Stat {
        Stat {
            size: self.size,
            mtime: self.mtime,
            ino: self.ino,
        }
    }
}

/// One product file of a key.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ProductFile {
    /// File name inside the work directory.
    pub name: String,
    /// Size in bytes.
    pub size: u64,
    /// xxh3-128 of the content, 32 hex digits.
    pub xxh3_128: String,
}

/// The non-pixel part of a prepared view, kept in its entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewMeta {
    /// The projection (model, map size, warps).
    pub projection: Projection,
    /// RMS of the grid fit, when the native grid is the map.
    pub fit_rms_px: Option<f64>,
    /// Why this sensor model was chosen.
    pub reason: String,
    /// Where the normals came from.
    pub normals_note: String,
    /// Wall time of each per-view stage (seconds).
    pub times: Vec<(String, f64)>,
    /// Number of points.
    pub points: u64,
    /// True when the native grid is the map (the points file holds the grid pixels).
    pub native_grid: bool,
}

/// What [`save_view`](super::save_view) wrote: pass it to [`Manifest::record`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProductFiles {
    /// The per-pixel maps (EXR).
    pub maps: ProductFile,
    /// The per-point arrays (raw).
    pub points: ProductFile,
    /// Sensor and notes.
    pub view: ViewMeta,
}

impl ProductFiles {
    /// The product files.
    pub fn files(&self) -> [&ProductFile; 2] {
        [&self.maps, &self.points]
    }
}

/// One key's record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Entry {
    /// Layout version ([`FORMAT`]).
    pub format: u32,
    /// The product key.
    pub key: String,
    /// The mvao version that made the products.
    pub mvao_version: String,
    /// When the entry was recorded.
    pub recorded: FileTime,
    /// xxh3-128 of the parameters' canonical JSON.
    pub params_hash: String,
    /// The parameters, for people reading the entry.
    pub params: Value,
    /// The inputs, in the caller's order.
    pub inputs: Vec<InputRecord>,
    /// The products.
    pub products: ProductFiles,
}

/// The entry file: the entry and the xxh3-128 of its compact JSON.
#[derive(Deserialize)]
struct EntryFile {
    entry: Entry,
    checksum: String,
}

#[derive(Serialize)]
struct EntryFileRef<'a> {
    entry: &'a Entry,
    checksum: String,
}

/// How thoroughly [`Manifest::why_stale`] looks at the inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Check {
    /// Size, mtime and inode; the content only when those changed or the record is racy.
    #[default]
    Quick,
    /// Always hash every input.
    Content,
}

/// The entries of a work directory.
#[derive(Debug, Clone, Default)]
pub struct Manifest {
    dir: PathBuf,
    entries: BTreeMap<String, Entry>,
    /// Entry files that were ignored (unreadable, corrupt) and why; their products are
    /// recomputed.
    pub warnings: Vec<String>,
    /// Stale temporary files removed while loading.
    pub cleaned: Vec<PathBuf>,
}

impl Manifest {
    /// Reads every entry of `dir` and removes temporary files left by interrupted writers.
    /// A missing directory gives an empty manifest; a damaged entry is left out with a
    /// warning (products are reproducible).
    pub fn load(dir: &Path) -> Manifest {
        let mut m = Manifest {
            dir: dir.to_path_buf(),
            ..Default::default()
        };
        let (entries, warnings) = scan_entries(dir);
        m.entries = entries;
        m.warnings = warnings;
        m.cleaned = super::clean_stale_temps(dir, &mut m.warnings);
        m
    }

    /// The work directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The entry of `key`.
    pub fn entry(&self, key: &str) -> Option<&Entry> {
        self.entries.get(key)
    }

    /// All keys with an entry, sorted.
    pub fn keys(&self) -> impl Iterator<Item = &str> {
        self.entries.keys().map(String::as_str)
    }

    /// True when `key`'s products were made by this mvao from these inputs (same paths in the
    /// same order, same content) with these parameters, and are still on disk
    /// ([`Check::Quick`]). Products are checked by size here and by hash when loaded, so a
    /// product damaged in place is found by the load, whose error means "recompute".
    pub fn is_fresh<P: AsRef<Path>>(&self, key: &str, inputs: &[P], params: &Value) -> bool {
        self.why_stale(key, inputs, params, Check::Quick).is_none()
    }

    /// `None` when `key` is fresh, else why it is not (one line).
    pub fn why_stale<P: AsRef<Path>>(
        &self,
        key: &str,
        inputs: &[P],
        params: &Value,
        check: Check,
    ) -> Option<String> {
        let Some(e) = self.entries.get(key) else {
            return Some(format!("{key}: no product recorded"));
        };
        if e.format != FORMAT {
            return Some(format!(
                "{key}: product layout {} (this mvao writes {FORMAT})",
                e.format
            ));
        }
        if e.mvao_version != MVAO_VERSION {
            return Some(format!(
                "{key}: made by mvao {} (this is {MVAO_VERSION})",
                e.mvao_version
            ));
        }
        if e.params_hash != params_hash(params) {
            return Some(format!("{key}: parameters changed"));
        }
        if e.inputs.len() != inputs.len()
            || e.inputs
                .iter()
                .zip(inputs)
                .any(|(r, p)| r.path != path_string(p.as_ref()))
        {
            return Some(format!("{key}: a different list of inputs"));
        }
        for f in e.products.files() {
            let p = self.dir.join(&f.name);
            match std::fs::metadata(&p) {
                Ok(m) if m.is_file() && m.len() == f.size => {}
                Ok(_) => return Some(format!("{}: changed on disk", p.display())),
                Err(_) => return Some(format!("{}: missing", p.display())),
            }
        }
        for (r, p) in e.inputs.iter().zip(inputs) {
            let p = p.as_ref();
            let Ok(now) = stat(p) else {
                return Some(format!("{}: cannot be read", p.display()));
            };
            if now.size != r.size {
                return Some(format!("{}: size changed", p.display()));
            }
            let racy = r.mtime.secs.saturating_add(RACY_MARGIN_S) >= r.hashed_at.secs;
            let same_stat = now.mtime == r.mtime && now.ino == r.ino;
            if check == Check::Quick && same_stat && !racy {
                continue;
            }
            match hash_file(p) {
                Ok((size, h)) if size == r.size && h == r.xxh3_128 => {}
                Ok(_) => return Some(format!("{}: content changed", p.display())),
                Err(_) => return Some(format!("{}: cannot be read", p.display())),
            }
        }
        None
    }

    /// Records `key`'s products (written by [`save_view`](super::save_view)) as made from
    /// `inputs` with `params`. This is the commit point: the entry file is written last,
    /// atomically, after the products it names are on disk; afterwards the key's older product
    /// files are removed.
    pub fn record(
        &mut self,
        key: &str,
        inputs: &[InputRecord],
        params: &Value,
        files: &ProductFiles,
    ) -> Result<()> {
        let entry = write_record(&self.dir, key, inputs, params, files)?;
        self.insert(entry);
        Ok(())
    }

    /// Takes note of an entry [`write_record`] committed to this manifest's directory.
    pub fn insert(&mut self, entry: Entry) {
        self.entries.insert(entry.key.clone(), entry);
    }

    /// Forgets `key`: removes its entry (first, so no half state is ever fresh) and products.
    pub fn remove(&mut self, key: &str) -> Result<()> {
        super::check_key(key)?;
        let path = entry_path(&self.dir, key);
        match std::fs::remove_file(&path) {
            Ok(()) => {}
            Err(e) if e.kind() == ErrorKind::NotFound => {}
            Err(e) => return Err(Error::io(&path, e)),
        }
        super::remove_old_products(&self.dir, key, &[]);
        self.entries.remove(key);
        Ok(())
    }

    /// Writes `DIR/manifest.json`, a snapshot of every entry on disk now (listed afresh, so
    /// other processes' entries are included). Informational: never read for decisions.
    pub fn save(&self) -> Result<()> {
        #[derive(Serialize)]
        struct Index<'a> {
            format: u32,
            mvao_version: &'a str,
            note: &'a str,
            entries: BTreeMap<String, Entry>,
        }
        let (entries, _) = scan_entries(&self.dir);
        let index = Index {
            format: FORMAT,
            mvao_version: MVAO_VERSION,
            note: "snapshot of the <key>.manifest.json files; those are authoritative",
            entries,
        };
        let path = self.dir.join(INDEX_FILE);
        let json = serde_json::to_vec_pretty(&index)
            .map_err(|e| Error::format(&path, format!("cannot encode the index: {e}")))?;
        write_atomic(&path, |w| w.write_all(&json))
    }
}

/// `DIR/<key>.manifest.json`.
pub fn entry_path(dir: &Path, key: &str) -> PathBuf {
    dir.join(format!("{key}{ENTRY_SUFFIX}"))
}

/// Writes `entry` with its checksum to `DIR/<key>.manifest.json`, atomically. The low-level
/// step of [`Manifest::record`] (which also checks the products and cleans old ones).
pub fn write_entry(dir: &Path, entry: &Entry) -> Result<()> {
    super::check_key(&entry.key)?;
    let path = entry_path(dir, &entry.key);
    let checksum = entry_checksum(entry).map_err(|m| Error::format(&path, m))?;
    let file = EntryFileRef { entry, checksum };
    let json = serde_json::to_vec_pretty(&file)
        .map_err(|e| Error::format(&path, format!("cannot encode the entry: {e}")))?;
    write_atomic(&path, |w| w.write_all(&json))
}

/// The file work of [`Manifest::record`] in work directory `dir`, for a thread that does not
/// hold the manifest: checks the products' sizes, writes the entry (the commit point), removes
/// the key's older products, and returns the entry for [`Manifest::insert`].
pub fn write_record(
    dir: &Path,
    key: &str,
    inputs: &[InputRecord],
    params: &Value,
    files: &ProductFiles,
) -> Result<Entry> {
    super::check_key(key)?;
    for f in files.files() {
        let p = dir.join(&f.name);
        let m = std::fs::metadata(&p).map_err(|e| Error::io(&p, e))?;
        if m.len() != f.size {
            return Err(Error::format(
                &p,
                format!("{} bytes on disk, {} expected", m.len(), f.size),
            ));
        }
    }
    let entry = Entry {
        format: FORMAT,
        key: key.to_string(),
        mvao_version: MVAO_VERSION.to_string(),
        recorded: FileTime::now(),
        params_hash: params_hash(params),
        params: params.clone(),
        inputs: inputs.to_vec(),
        products: files.clone(),
    };
    write_entry(dir, &entry)?;
    let keep = [files.maps.name.as_str(), files.points.name.as_str()];
    super::remove_old_products(dir, key, &keep);
    Ok(entry)
}

/// Reads and verifies one entry file.
pub fn read_entry(dir: &Path, key: &str) -> Result<Entry> {
    let path = entry_path(dir, key);
    let bytes = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
    parse_entry(&bytes, key).map_err(|m| Error::format(&path, m))
}

fn parse_entry(bytes: &[u8], key: &str) -> std::result::Result<Entry, String> {
    let file: EntryFile =
        serde_json::from_slice(bytes).map_err(|e| format!("corrupt entry: {e}"))?;
    if entry_checksum(&file.entry)? != file.checksum {
        return Err("corrupt entry: checksum mismatch".into());
    }
    if file.entry.key != key {
        return Err(format!(
            "entry is for key '{}', not '{key}'",
            file.entry.key
        ));
    }
    Ok(file.entry)
}

/// xxh3-128 of the entry's compact JSON. Floats round-trip exactly (serde_json with
/// `float_roundtrip`), so re-encoding a parsed entry gives the same bytes.
fn entry_checksum(e: &Entry) -> std::result::Result<String, String> {
    let s = serde_json::to_vec(e).map_err(|e| format!("cannot encode the entry: {e}"))?;
    Ok(hex128(xxh3_128(&s)))
}

/// Every valid entry in `dir`, and a warning for each damaged one.
fn scan_entries(dir: &Path) -> (BTreeMap<String, Entry>, Vec<String>) {
    let mut entries = BTreeMap::new();
    let mut warnings = Vec::new();
    let rd = match std::fs::read_dir(dir) {
        Ok(rd) => rd,
        Err(e) if e.kind() == ErrorKind::NotFound => return (entries, warnings),
        Err(e) => {
            warnings.push(format!(
                "{}: {e}; every product is recomputed",
                dir.display()
            ));
            return (entries, warnings);
        }
    };
    for de in rd.flatten() {
        let name = de.file_name();
        let Some(name) = name.to_str() else { continue };
        let Some(key) = name.strip_suffix(ENTRY_SUFFIX) else {
            continue;
        };
        if super::check_key(key).is_err() {
            continue;
        }
        let path = de.path();
        match std::fs::read(&path)
            .map_err(|e| e.to_string())
            .and_then(|b| parse_entry(&b, key))
        {
            Ok(e) => {
                entries.insert(key.to_string(), e);
            }
            Err(m) => warnings.push(format!(
                "{}: {m}; ignored, its products are recomputed",
                path.display()
            )),
        }
    }
    (entries, warnings)
}

/// xxh3-128 (32 hex digits) of the canonical JSON of `params` (object keys sorted at every
/// level, no whitespace), so the same parameters hash the same whatever their key order.
pub fn params_hash(params: &Value) -> String {
    let mut s = String::with_capacity(256);
    canonical(params, &mut s);
    hex128(xxh3_128(s.as_bytes()))
}

fn canonical(v: &Value, out: &mut String) {
    match v {
        Value::Object(m) => {
            let mut keys: Vec<&String> = m.keys().collect();
            keys.sort();
            out.push('{');
            for (i, k) in keys.into_iter().enumerate() {
                if i > 0 {
                    out.push(',');
                }
                out.push_str(&Value::String(k.clone()).to_string());
                out.push(':');
                if let Some(x) = m.get(k) {
                    canonical(x, out);
                }
            }
            out.push('}');
        }
        Value::Array(a) => {
            out.push('[');
            for (i, x) in a.iter().enumerate() {
                if i > 0 {
                    out.push(',');
                }
                canonical(x, out);
            }
            out.push(']');
        }
        other => out.push_str(&other.to_string()),
    }
}

/// 32 lowercase hex digits.
pub fn hex128(h: u128) -> String {
    format!("{h:032x}")
}

/// Size and xxh3-128 (hex) of a file, streamed in large blocks.
pub fn hash_file(path: &Path) -> Result<(u64, String)> {
    let f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut h = Xxh3::new();
    let mut size = 0u64;
    #[cfg(unix)]
    {
        // Two blocks read at once (the copy out of the page cache is most of the time), then
        // hashed in order.
        use std::os::unix::fs::FileExt;
        let read_at = |buf: &mut [u8], at: u64| -> std::io::Result<usize> {
            let mut got = 0;
            while got < buf.len() {
                match f.read_at(&mut buf[got..], at + got as u64) {
                    Ok(0) => break,
                    Ok(k) => got += k,
                    Err(e) if e.kind() == ErrorKind::Interrupted => {}
                    Err(e) => return Err(e),
                }
            }
            Ok(got)
        };
        let (mut a, mut b) = (vec![0u8; HASH_BUF], vec![0u8; HASH_BUF]);
        loop {
            let (ra, rb) = rayon::join(
                || read_at(&mut a, size),
                || read_at(&mut b, size + HASH_BUF as u64),
            );
            let ra = ra.map_err(|e| Error::io(path, e))?;
            h.update(&a[..ra]);
            size += ra as u64;
            if ra < HASH_BUF {
                break;
            }
            let rb = rb.map_err(|e| Error::io(path, e))?;
            h.update(&b[..rb]);
            size += rb as u64;
            if rb < HASH_BUF {
                break;
            }
        }
    }
    #[cfg(not(unix))]
    {
        use std::io::Read;
        let mut f = f;
        let mut buf = vec![0u8; HASH_BUF];
        loop {
            let k = match f.read(&mut buf) {
                Ok(0) => break,
                Ok(k) => k,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(Error::io(path, e)),
            };
            h.update(&buf[..k]);
            size += k as u64;
        }
    }
    Ok((size, hex128(h.digest128())))
}

/// What [`Check::Quick`] compares: size, modification time and inode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stat {
    size: u64,
    mtime: FileTime,
    ino: Option<u64>,
}

impl Stat {
    /// Whether the file was modified less than [`RACY_MARGIN_S`] before `now`: a change made
    /// within the same clock tick would then leave its stat as it is.
    pub fn is_racy(&self, now: FileTime) -> bool {
        self.mtime.secs.saturating_add(RACY_MARGIN_S) >= now.secs
    }
}

/// The size, modification time and inode of the regular file `path`.
pub fn stat(path: &Path) -> Result<Stat> {
    let m = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !m.is_file() {
        return Err(Error::format(path, "not a regular file"));
    }
    let mtime = m.modified().map_err(|e| Error::io(path, e))?;
    #[cfg(unix)]
    let ino = Some(std::os::unix::fs::MetadataExt::ino(&m));
    #[cfg(not(unix))]
    let ino = None;
    Ok(Stat {
        size: m.len(),
        mtime: FileTime::from_system(mtime),
        ino,
    })
}

fn path_string(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floats_round_trip_through_json_exactly() {
        // Entry checksums re-encode parsed entries: every finite float must come back with
        // its bits (serde_json's `float_roundtrip`).
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        for _ in 0..20_000 {
            let d = f64::from_bits(next());
            let f = f32::from_bits(next() as u32);
            if d.is_finite() {
                let back: f64 = serde_json::from_str(&serde_json::to_string(&d).unwrap()).unwrap();
                assert_eq!(back.to_bits(), d.to_bits(), "{d:e}");
            }
            if f.is_finite() {
                let back: f32 = serde_json::from_str(&serde_json::to_string(&f).unwrap()).unwrap();
                assert_eq!(back.to_bits(), f.to_bits(), "{f:e}");
            }
        }
    }

    #[test]
    fn file_hash_is_the_hash_of_the_whole_content() {
        let dir = tempfile::tempdir().unwrap();
        for len in [
            0,
            1,
            HASH_BUF - 1,
            HASH_BUF,
            2 * HASH_BUF,
            2 * HASH_BUF + 7,
            5 * HASH_BUF / 2,
        ] {
            let bytes: Vec<u8> = (0..len).map(|i| (i * 7 + i / 4099) as u8).collect();
            let p = dir.path().join(format!("f{len}"));
            std::fs::write(&p, &bytes).unwrap();
            assert_eq!(
                hash_file(&p).unwrap(),
                (len as u64, hex128(xxh3_128(&bytes))),
                "{len}"
            );
        }
    }

    #[test]
    fn parameter_hash_ignores_key_order_only() {
        let a: Value = serde_json::from_str(r#"{"x": 1, "y": {"b": [1, 2], "a": "s"}}"#).unwrap();
        let b: Value = serde_json::from_str(r#"{"y": {"a": "s", "b": [1, 2]}, "x": 1}"#).unwrap();
        let c: Value = serde_json::from_str(r#"{"y": {"a": "s", "b": [2, 1]}, "x": 1}"#).unwrap();
        assert_eq!(params_hash(&a), params_hash(&b));
        assert_ne!(params_hash(&a), params_hash(&c));
        assert_eq!(params_hash(&a).len(), 32);
    }

    #[test]
    fn file_times_before_the_epoch() {
        let t = UNIX_EPOCH - Duration::new(1, 250_000_000);
        assert_eq!(
            FileTime::from_system(t),
            FileTime {
                secs: -2,
                nanos: 750_000_000
            }
        );
    }
}
