//! Checks for the scan formats other than PLY (PTX, LAS/LAZ, E57) and for the per-scan pose
//! files (`.aln` alignments go through [`super::check_align`]; sidecar and `--pose` matrices
//! through [`check_matrix`]).
//!
//! Each check writes the bytes to a scratch file and reads it through the same public entry
//! point `mvao` uses, `read_input`, so the code around the format crates (header checks, extra
//! dimensions, grids, poses, re-centring) is what gets exercised. Whatever reads must hand over
//! scans the rest of the pipeline can trust; whatever fails must fail as a format error naming
//! the file.

use super::{assert_rigid, Scratch};
use glam::{DMat3, DVec4};
use mvao::io::align::{read_matrix_file, split_scale};
use mvao::io::e57::E57Input;
use mvao::io::las::LasInput;
use mvao::io::output::ColorMode;
use mvao::io::ptx::{write_ptx, PtxInput};
use mvao::io::source::{read_input, InputFile};
use mvao::testing::scan::NO_CELL;
use mvao::Error;
use std::path::Path;

/// Bytes of an E57 page that are data; the last four of each 1024-byte page are its checksum.
pub const E57_PAGE_DATA: usize = 1020;

/// An error from reading a scan file: a format error (or, for a file that cannot be decoded
/// at all, an I/O error of kind `InvalidData`) whose message names the file.
fn assert_names_file(e: &Error, path: &Path) {
    match e {
        Error::Format { .. } => {}
        Error::Io { err, .. } => {
            assert_eq!(err.kind(), std::io::ErrorKind::InvalidData, "{e}")
        }
        other => panic!("unexpected error kind: {other:?}"),
    }
    assert!(e.to_string().contains(&path.display().to_string()), "{e}");
}

/// What every reader's output must satisfy once it became scans.
fn check_input(f: &InputFile) {
    assert!(!f.scans.is_empty() || f.file_to_local.is_empty());
    assert_eq!(f.scans.len(), f.file_to_local.len());
    for (s, off) in f.scans.iter().zip(&f.file_to_local) {
        let n = s.points.len();
        assert!(off.is_finite(), "scan {}: offset {off:?}", s.name);
        assert!(s.points.iter().all(|p| p.is_finite()), "scan {}", s.name);
        assert_eq!(s.source_index.len(), n);
        assert_eq!(s.skipped_nonfinite + n, s.vertex_count, "scan {}", s.name);
        assert!(s.source_index.windows(2).all(|w| w[0] < w[1]));
        assert!(s
            .source_index
            .iter()
            .all(|&i| (i as usize) < s.vertex_count));
        if let Some(ns) = &s.normals {
            assert_eq!(ns.len(), n);
            for v in ns {
                let l = v.length();
                assert!(
                    *v == glam::Vec3::ZERO || (l - 1.0).abs() < 1e-3,
                    "normal {v:?}"
                );
            }
        }
        if let Some(g) = &s.grid {
            assert_eq!(g.row.len(), n);
            assert_eq!(g.col.len(), n);
            for (&r, &c) in g.row.iter().zip(&g.col) {
                assert!(r == NO_CELL || r < g.rows, "row {r} of {}", g.rows);
                assert!(c == NO_CELL || c < g.cols, "col {c} of {}", g.cols);
            }
        }
        assert!(s.pose.is_finite(), "scan {}: pose {:?}", s.name, s.pose);
        assert!(s.pose.row(3) == DVec4::W, "scan {}: {:?}", s.name, s.pose);
    }
}

/// Reads `path` with `read_input`; `Some` when it parsed (after [`check_input`]).
fn read_checked(path: &Path) -> Option<InputFile> {
    match read_input(path) {
        Ok(f) => {
            check_input(&f);
            Some(f)
        }
        Err(e) => {
            assert_names_file(&e, path);
            None
        }
    }
}

/// Target `ptx_parse`: arbitrary bytes as a `.ptx` file. When it parses, every block has
/// `cols × rows` cells, and writing it back (with a constant AO) and reading that gives the
/// same blocks: sizes, registration matrix, and the coordinates of every cell with a return.
pub fn check_ptx(bytes: &[u8]) {
    let scratch = Scratch::new("ptx");
    let path = scratch.file("input.ptx");
    std::fs::write(&path, bytes).expect("write scratch input");
    let via_input = read_checked(&path).is_some();
    let ptx = match PtxInput::from_path(&path) {
        Ok(p) => p,
        Err(e) => {
            assert_names_file(&e, &path);
            return;
        }
    };
    assert!(!ptx.scans.is_empty());
    let mut tables = Vec::with_capacity(ptx.scans.len());
    for (k, s) in ptx.scans.iter().enumerate() {
        assert_eq!(s.len() as u64, s.cols as u64 * s.rows as u64);
        assert_eq!(s.intensity.len(), s.len());
        assert!(s.rgb.as_ref().is_none_or(|c| c.len() == s.len()));
        assert!(s.pose.is_finite());
        let g = s.grid();
        assert_eq!(g.row.len(), s.len());
        assert!(g.row.iter().all(|&r| r < s.rows) && g.col.iter().all(|&c| c < s.cols));
        if s.len() > super::MAX_HARNESS_ROWS {
            return;
        }
        let ao = vec![0.5f32; s.len()];
        tables.push(
            ptx.point_table(k, &ao, 1.0, ColorMode::Keep)
                .expect("point_table of a block as read"),
        );
    }
    if !via_input {
        // The file parses but a pose is not rigid, or a scan is unusable: nothing to write.
        return;
    }
    let out = scratch.file("back.ptx");
    write_ptx(&tables, &out).expect("write_ptx of a file as read");
    let back = PtxInput::from_path(&out).expect("reading a written PTX file");
    assert_eq!(back.scans.len(), ptx.scans.len());
    for (a, b) in ptx.scans.iter().zip(&back.scans) {
        assert_eq!((a.cols, a.rows), (b.cols, b.rows));
        assert!(a.pose == b.pose, "{:?} became {:?}", a.pose, b.pose);
        for (k, (p, q)) in a.xyz.iter().zip(&b.xyz).enumerate() {
            let valid = p.iter().all(|v| v.is_finite());
            assert_eq!(valid, q.iter().all(|v| v.is_finite()), "cell {k}");
            if valid {
                assert!(p == q, "cell {k}: {p:?} became {q:?}");
            }
        }
    }
}

/// Replaces libFuzzer's panic hook, which aborts on every panic, by one that only prints.
/// The LAZ decoder is third-party code that asserts on corrupt arithmetic-coded streams; mvao
/// catches those panics and reports a format error, which is the behaviour under test. A
/// panic that escapes mvao still reaches libFuzzer's own `catch_unwind` and aborts, so it is
/// still found.
pub fn report_caught_panics() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| std::panic::set_hook(Box::new(|info| eprintln!("caught: {info}"))));
}

/// Target `las_parse`: the first byte chooses `.las` or `.laz`, the rest is the file. When it
/// parses, every per-point accessor gives one value per record.
pub fn check_las(data: &[u8]) {
    let (ext, bytes) = match data.split_first() {
        Some((b, rest)) if b & 1 == 1 => ("laz", rest),
        Some((_, rest)) => ("las", rest),
        None => ("las", data),
    };
    let scratch = Scratch::new("las");
    let path = scratch.file(&format!("input.{ext}"));
    std::fs::write(&path, bytes).expect("write scratch input");
    read_checked(&path);
    let las = match LasInput::from_path(&path) {
        Ok(l) => l,
        Err(e) => {
            assert_names_file(&e, &path);
            return;
        }
    };
    let n = las.len();
    assert_eq!(las.records().len(), n * las.record_len());
    assert_eq!(las.intensities().len(), n);
    assert!(las.rgb8().is_none_or(|c| c.len() == n));
    assert!(las.point_source_ids().is_none_or(|c| c.len() == n));
    assert!(las.scan_angles().is_none_or(|c| c.len() == n));
    assert!(las.ao().is_none_or(|c| c.len() == n));
    for (name, col) in las.extra_columns() {
        assert_eq!(col.len(), n, "extra dimension {name}");
    }
    let raw = las.raw_scan("fuzz");
    assert_eq!(raw.xyz.len(), n);
}

/// The bytes as E57 pages: every [`E57_PAGE_DATA`] bytes (the last chunk padded with zeros)
/// followed by their CRC-32C, big-endian as the format stores it. Without this, nearly every
/// mutation would only exercise the checksum test.
pub fn e57_with_checksums(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(data.len().div_ceil(E57_PAGE_DATA) * 1024);
    for chunk in data.chunks(E57_PAGE_DATA) {
        let mut page = chunk.to_vec();
        page.resize(E57_PAGE_DATA, 0);
        let crc = crc32c(&page);
        out.extend_from_slice(&page);
        out.extend_from_slice(&crc.to_be_bytes());
    }
    out
}

/// The inverse of [`e57_with_checksums`] for files with 1024-byte pages (to make seeds).
pub fn e57_without_checksums(file: &[u8]) -> Vec<u8> {
    file.chunks(1024)
        .flat_map(|p| &p[..p.len().min(E57_PAGE_DATA)])
        .copied()
        .collect()
}

/// CRC-32C (Castagnoli), bitwise: the harness has no table to share and pages are small.
fn crc32c(data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in data {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0x82F6_3B78
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// Target `e57_parse`: the bytes as the data of an E57 file's pages (checksums added by
/// [`e57_with_checksums`]). When it parses, each scan's columns line up with its records and
/// every pose is rigid.
pub fn check_e57(data: &[u8]) {
    let scratch = Scratch::new("e57");
    let path = scratch.file("input.e57");
    std::fs::write(&path, e57_with_checksums(data)).expect("write scratch input");
    read_checked(&path);
    let e = match E57Input::from_path(&path) {
        Ok(e) => e,
        Err(err) => {
            assert_names_file(&err, &path);
            return;
        }
    };
    assert!(!e.scans.is_empty());
    for s in &e.scans {
        let n = s.len();
        assert!(s.invalid <= n);
        assert!(s.intensity.as_ref().is_none_or(|c| c.len() == n));
        assert!(s.rgb.as_ref().is_none_or(|c| c.len() == n));
        assert!(s.normals.as_ref().is_none_or(|c| c.len() == n));
        if let Some(g) = &s.grid {
            assert_eq!(g.row.len(), n);
            assert_eq!(g.col.len(), n);
        }
        assert_rigid(s.pose, &s.name);
        for r in &s.descriptor.prototype {
            let v = s.values(&r.name).expect("values of a stored attribute");
            assert_eq!(v.len(), n, "{:?}", r.name);
        }
        for k in 0..n.min(64) {
            let _ = s.colour_valid(k);
        }
    }
}

/// Target `pose_matrix`: the first byte says whether scale is allowed, the rest is a sidecar
/// (`scan.txt`) or `--pose` matrix file. A matrix that is accepted is finite with bottom row
/// `(0, 0, 0, 1)`; without `--allow-scale` it is rigid, with it its determinant is positive.
pub fn check_matrix(data: &[u8]) {
    let (allow_scale, bytes) = match data.split_first() {
        Some((b, rest)) => (b & 1 == 1, rest),
        None => (false, data),
    };
    let scratch = Scratch::new("matrix");
    let path = scratch.file("scan.txt");
    std::fs::write(&path, bytes).expect("write scratch input");
    match read_matrix_file(&path, "scan.ply", allow_scale) {
        Ok(m) if allow_scale => {
            assert!(m.is_finite());
            assert!(m.row(3) == DVec4::W, "{m:?}");
            let a = DMat3::from_mat4(m);
            assert!(a.determinant() > 0.0);
            // The pose is applied as a rigid pose plus a stretch of the points: both must be
            // usable and give the pose back.
            let (rigid, stretch) = split_scale(m);
            assert_rigid(rigid, "scan.ply");
            assert!(stretch.is_finite(), "{stretch:?}");
            let back = DMat3::from_mat4(rigid) * stretch;
            let scale = a.to_cols_array().iter().fold(0.0f64, |x, v| x.max(v.abs()));
            let d = (back - a)
                .to_cols_array()
                .iter()
                .fold(0.0f64, |x, v| x.max(v.abs()));
            assert!(d <= 1e-9 * scale, "R·S is off by {d:e} from {a:?}");
        }
        Ok(m) => assert_rigid(m, "scan.ply"),
        Err(e) => {
            match &e {
                Error::Align { .. } => {}
                Error::Io { err, .. } => {
                    assert_eq!(err.kind(), std::io::ErrorKind::InvalidData, "{e}")
                }
                other => panic!("unexpected error kind: {other:?}"),
            }
            assert!(e.to_string().contains(&path.display().to_string()), "{e}");
        }
    }
}
