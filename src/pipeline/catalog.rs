//! The catalog stage: every input read once, small files side by side, for what the plan needs —
//! counts, world bounds, occupied cells, a fingerprint of each scan's local data and the
//! sample the default radius is taken from. Also where the later stages get the scans again:
//! [`Inputs`], over the input files or over scans in memory.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::io::dataset::{PlacedFile, Placer};
use crate::io::source::Container;
use crate::products;
use crate::products::manifest::{self, FileTime, InputRecord, Stat};
use crate::progress::Observer;
use crate::report::CatalogScan;
use crate::scan::occupancy::Occupancy;
use crate::scan::Scan;
use crate::site::world_bounds;
use rayon::prelude::*;
use std::borrow::Cow;
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

/// What the catalog stage learns of the inputs.
pub struct Catalog {
    /// Per scan, file by file.
    pub scans: Vec<CatalogScan>,
    /// A subsample of every scan (the points the default radius is measured on).
    pub samples: Vec<Scan>,
    /// Per scan: (point spacing, points), for the default radius; empty when a radius is given.
    pub spacings: Vec<(f64, usize)>,
    /// Occupied cells of every scan, for the pair test.
    pub occupancy: Vec<Occupancy>,
    /// Size of the largest input file in bytes.
    pub max_file_bytes: u64,
    /// Warnings about the inputs.
    pub warnings: Vec<String>,
    /// Wall time of the stage (seconds).
    pub secs: f64,
    /// Bytes read.
    pub bytes_read: u64,
}

/// A file's scans as a stage gets them again after the catalog.
pub struct Opened<'a> {
    /// The scans, in the file's order.
    pub scans: Cow<'a, [Scan]>,
    /// The file's fingerprint, taken before it was read (input files only).
    pub record: Option<InputRecord>,
    /// True when the scans were read again since the catalog (their data must be checked
    /// against it: the file may have changed).
    pub read_again: bool,
    /// The rest of the placed file, which writing its outputs needs (input files only).
    pub placed: Option<PlacedFile>,
}

/// Where the stages after the catalog get the scans.
pub trait Inputs {
    /// Number of input files.
    fn files(&self) -> usize;
    /// File `fi` as an error message names it.
    fn name(&self, fi: usize) -> String;
    /// Size of file `fi` in bytes (0 in memory).
    fn bytes(&self, fi: usize) -> u64;
    /// The scans of file `fi` for the prepare stage, fingerprinted.
    fn for_prepare(&mut self, fi: usize) -> Result<Opened<'_>>;
    /// The scans of file `fi` for the merge stage, with what writing its outputs needs.
    fn for_merge(&self, fi: usize) -> Result<Opened<'_>>;
}

/// Scans already in memory, each its own "file"; nothing to fingerprint or write.
pub struct InMemory<'a>(pub &'a [Scan]);

impl Inputs for InMemory<'_> {
    fn files(&self) -> usize {
        self.0.len()
    }
    fn name(&self, fi: usize) -> String {
        self.0[fi].name.clone()
    }
    fn bytes(&self, _fi: usize) -> u64 {
        0
    }
    fn for_prepare(&mut self, fi: usize) -> Result<Opened<'_>> {
        self.for_merge(fi)
    }
    fn for_merge(&self, fi: usize) -> Result<Opened<'_>> {
        Ok(Opened {
            scans: Cow::Borrowed(std::slice::from_ref(&self.0[fi])),
            record: None,
            read_again: false,
            placed: None,
        })
    }
}

/// The input files, read one at a time; the scans of the first files kept from the catalog
/// while they fit in the budget, so the prepare stage need not read them again.
pub struct Files<'a> {
    /// Resolves each file's poses.
    pub placer: &'a Placer,
    /// The paths, in command-line order.
    pub paths: &'a [PathBuf],
    /// Scans kept from the catalog, by file: the file's identity before it was read, the
    /// scans and their bytes.
    pub held: HashMap<usize, (Stat, Vec<Scan>, u64)>,
}

impl Inputs for Files<'_> {
    fn files(&self) -> usize {
        self.placer.len()
    }
    fn name(&self, fi: usize) -> String {
        self.paths[fi].display().to_string()
    }
    fn bytes(&self, fi: usize) -> u64 {
        std::fs::metadata(&self.paths[fi]).map_or(0, |m| m.len())
    }
    fn for_prepare(&mut self, fi: usize) -> Result<Opened<'_>> {
        let kept = self.held.remove(&fi);
        // Fingerprint the input before reading it, so a change during the run is caught.
        let rec = InputRecord::capture(&self.paths[fi])?;
        // Scans kept from the catalog were read after their file had the identity the record
        // now finds; others are read again and compared with what the catalog read.
        let (scans, read_again) = match kept {
            Some((st, ..)) if st != rec.stat() => return Err(changed(&self.name(fi))),
            Some((_, scans, _)) => (scans, false),
            None => (self.placer.open(fi)?.scans, true),
        };
        Ok(Opened {
            scans: Cow::Owned(scans),
            record: Some(rec),
            read_again,
            placed: None,
        })
    }
    fn for_merge(&self, fi: usize) -> Result<Opened<'_>> {
        let mut pf = self.placer.open(fi)?;
        let scans = std::mem::take(&mut pf.scans);
        Ok(Opened {
            scans: Cow::Owned(scans),
            record: None,
            read_again: false,
            placed: Some(pf),
        })
    }
}

/// The error of an input that changed while the run read it.
pub fn changed(file: &str) -> Error {
    Error::Param(format!("{file}: changed while mvao was running; run again"))
}

/// One scan's catalog entry.
fn entry(s: &Scan, file: usize, index: usize, with_hash: bool) -> CatalogScan {
    let (lo, hi) = world_bounds(s);
    CatalogScan {
        name: s.name.clone(),
        file,
        index,
        points: s.len(),
        bounds: [lo.to_array(), hi.to_array()],
        // A grid far sparser than its points is resampled at about a pixel a point.
        map_pixels: s
            .grid
            .as_ref()
            .filter(|_| !crate::sensor::grid_too_sparse(s))
            .map_or(s.len() as u64, |g| g.rows as u64 * g.cols as u64),
        data_hash: if with_hash {
            data_hash(s)
        } else {
            String::new()
        },
        key: products::key_from_name(&s.name),
        pose: s.pose,
    }
}

/// The subsample [`super::plan::robust_diagonal`] takes of a scan, so the default radius of a
/// run that reads its files one at a time equals that of scans in memory.
fn sample(s: &Scan) -> Scan {
    let step = s.len().div_ceil(20_000).max(1);
    let mut sample = Scan::from_points(
        s.name.clone(),
        s.points.iter().step_by(step).copied().collect(),
    );
    sample.pose = s.pose;
    sample
}

/// The catalog of scans in memory (each its own file).
pub fn from_scans(scans: &[Scan]) -> Result<Catalog> {
    if scans.is_empty() {
        return Err(Error::Param("no scan given".into()));
    }
    if let Some(s) = scans.iter().find(|s| s.is_empty()) {
        return Err(Error::scan(&s.name, "has no valid point"));
    }
    let cat: Vec<CatalogScan> = scans
        .iter()
        .enumerate()
        .map(|(i, s)| entry(s, i, 0, false))
        .collect();
    let occupancy = scans
        .iter()
        .zip(&cat)
        .map(|(s, c)| Occupancy::of(s, bounds_diagonal(c)))
        .collect();
    Ok(Catalog {
        scans: cat,
        samples: scans.iter().map(sample).collect(),
        spacings: Vec::new(),
        occupancy,
        max_file_bytes: 0,
        warnings: Vec::new(),
        secs: 0.0,
        bytes_read: 0,
    })
}

/// Length of a catalog entry's world box diagonal.
fn bounds_diagonal(c: &CatalogScan) -> f64 {
    (glam::DVec3::from(c.bounds[1]) - glam::DVec3::from(c.bounds[0])).length()
}

/// Warns of non-finite values in a PLY file's other vertex properties (written as 0).
fn nonfinite_warning(pf: &PlacedFile, path: &std::path::Path) -> Option<String> {
    let Container::Ply(ply) = &pf.file.container else {
        return None;
    };
    let bad = crate::io::output::nonfinite_properties(ply);
    if bad.is_empty() {
        return None;
    }
    let list: Vec<String> = bad.iter().map(|(p, n)| format!("{p} ({n})")).collect();
    Some(format!(
        "{}: non-finite values in vertex properties {}; written as 0 in the output",
        path.display(),
        list.join(", ")
    ))
}

/// The catalog of the input files of `cfg`, each read once. The scans of the first files are
/// kept for the prepare stage while they fit in `budget` beside what the stages need, each
/// with the identity of its file before it was read.
pub fn from_files<'a>(
    cfg: &'a Config,
    placer: &'a Placer,
    budget: u64,
    obs: &dyn Observer,
) -> Result<(Catalog, Files<'a>)> {
    let t0 = Instant::now();
    obs.stage("catalog", cfg.scans.len() as u64);
    let mut cat: Vec<CatalogScan> = Vec::new();
    let mut samples = Vec::new();
    let mut spacings = Vec::new();
    let mut occupancy = Vec::new();
    let mut warnings = Vec::new();
    let mut max_file_bytes = 0u64;
    let mut held: HashMap<usize, (Stat, Vec<Scan>, u64)> = HashMap::new();
    let mut holding = !cfg.dry_run;
    let mut start = 0;
    while start < placer.len() {
        let held_bytes: u64 = held.values().map(|h| h.2).sum();
        let end = window_end(&cfg.scans, start, budget.saturating_sub(held_bytes));
        let window = read_window(placer, &cfg.scans, start..end, holding);
        for (fi, (before, pf)) in (start..end).zip(window) {
            let path = &cfg.scans[fi];
            let mut pf = pf?;
            warnings.append(&mut pf.warnings);
            warnings.extend(nonfinite_warning(&pf, path));
            max_file_bytes = max_file_bytes.max(std::fs::metadata(path).map_or(0, |m| m.len()));
            for (k, s) in pf.scans.iter().enumerate() {
                if s.is_empty() {
                    return Err(Error::scan(
                        path.display().to_string(),
                        format!(
                            "scan {} has no point to shade (no record with finite coordinates; \
                             a grid's no-return cells are not points)",
                            s.name
                        ),
                    ));
                }
                crate::io::source::check_usable(s, path)?;
                let c = entry(s, fi, k, true);
                occupancy.push(Occupancy::of(s, bounds_diagonal(&c)));
                samples.push(sample(s));
                if cfg.compute.radius.is_none() {
                    spacings.push((crate::radius::scan_spacing(&s.points), s.len()));
                }
                cat.push(c);
            }
            let wanted = cfg.only.is_empty() || pf.scans.iter().any(|s| cfg.only.contains(&s.name));
            holding &= before.is_some() && wanted;
            if let Some(st) = before.filter(|_| holding) {
                let bytes: u64 = pf.scans.iter().map(scan_bytes).sum();
                let largest = cat
                    .iter()
                    .map(|c| crate::store::view_bytes(c.map_pixels, c.points as u64))
                    .max();
                let floor = super::plan::floor(max_file_bytes, largest.unwrap_or(0));
                let held_bytes: u64 = held.values().map(|h| h.2).sum();
                holding = held_bytes + bytes + 2 * floor <= budget;
                if holding {
                    held.insert(fi, (st, pf.scans, bytes));
                }
            }
            obs.advance(1);
        }
        start = end;
    }
    obs.done("catalog", t0.elapsed().as_secs_f64());
    let input_bytes = cfg
        .scans
        .iter()
        .map(|p| std::fs::metadata(p).map(|m| m.len()).unwrap_or(0))
        .sum();
    let catalog = Catalog {
        scans: cat,
        samples,
        spacings,
        occupancy,
        max_file_bytes,
        warnings,
        secs: t0.elapsed().as_secs_f64(),
        bytes_read: input_bytes,
    };
    check_names(cfg, placer, &catalog.scans)?;
    let files = Files {
        placer,
        paths: &cfg.scans,
        held,
    };
    Ok((catalog, files))
}

/// Bytes of one file as the catalog holds it while reading: the parsed file and its scans
/// ([`super::plan::floor`] counts five times the file).
const READ_FACTOR: u64 = 5;

/// The end of the window of files read side by side from `start`: one file per thread while
/// twice their parsed bytes fit in `room`, and always at least `start` itself (small files,
/// the common case of many scans, take both cores; one large file is read alone).
fn window_end(paths: &[PathBuf], start: usize, room: u64) -> usize {
    let size = |fi: usize| std::fs::metadata(&paths[fi]).map_or(u64::MAX / 4, |m| m.len());
    let threads = rayon::current_num_threads().max(1);
    let mut end = start + 1;
    let mut bytes = size(start);
    while end < paths.len() && end - start < threads {
        let more = bytes.saturating_add(size(end));
        if more.saturating_mul(2 * READ_FACTOR) > room {
            break;
        }
        bytes = more;
        end += 1;
    }
    end
}

/// Reads the files of `range` side by side, each with its identity taken before it was read
/// when `stat` (`None` for a file modified within the clock's resolution, which could change
/// again unseen: it is read anew later). In input order; each file's own error.
fn read_window(
    placer: &Placer,
    paths: &[PathBuf],
    range: std::ops::Range<usize>,
    stat: bool,
) -> Vec<(Option<Stat>, Result<PlacedFile>)> {
    range
        .into_par_iter()
        .map(|fi| {
            let before = stat
                .then(|| manifest::stat(&paths[fi]).ok())
                .flatten()
                .filter(|st| !st.is_racy(FileTime::now()));
            (before, placer.open(fi))
        })
        .collect()
}

/// Refuses a catalog whose scans cannot all be told apart: a `--pose` or `--only` naming no
/// scan, two scans whose work-directory keys collide, a file given twice.
fn check_names(cfg: &Config, placer: &Placer, cat: &[CatalogScan]) -> Result<()> {
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
    Ok(())
}

/// Heap bytes of a parsed scan.
fn scan_bytes(s: &Scan) -> u64 {
    let per_point =
        12 + 4 + if s.normals.is_some() { 12 } else { 0 } + if s.grid.is_some() { 8 } else { 0 };
    (s.points.capacity() * per_point) as u64
}

/// A fingerprint of what a scan's products depend on: local points, normals and grid.
/// Blocks of values are hashed in parallel and the digest hashes their digests in order.
pub fn data_hash(s: &Scan) -> String {
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
}
