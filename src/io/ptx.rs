//! Leica PTX: ASCII, one gridded scan per block, several blocks per file.
//!
//! A block is a header of ten lines — number of columns, number of rows, the scanner's
//! registered position, its registered x, y and z axes (three numbers each), and a 4×4
//! registration matrix in row-vector convention (`p' = p·M`; the last row is the
//! translation) — followed by `columns × rows` point lines `x y z intensity [r g b]`,
//! column-major (all rows of column 0 first). A point `0 0 0` is a cell without a return.
//!
//! Points are in the scanner's own frame; the matrix takes them to the registered frame and is
//! what Cyclone and CloudCompare apply, so it is the pose here. The header's position and
//! axes describe the scanner in the registration's frame, which differs from the matrix when a
//! user coordinate system was set at export; [`PtxScan::header_mismatch`] says by how much,
//! and the header never overrides the matrix. A matrix that is not rigid is returned as it is
//! (the caller checks poses).
//!
//! Parsing reads the whole file, finds each block's point lines by counting line ends, and
//! parses them in parallel with an exact fast path for plain decimals.

use super::atomic::write_atomic;
use super::e57::result_colours;
use super::output::ColorMode;
use super::raw::{PointTable, RawGrid, RawScan};
use crate::error::{Error, Result};
use glam::{DMat4, DVec3};
use rayon::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A PTX file as read.
#[derive(Debug, Clone)]
pub struct PtxInput {
    /// The file read.
    pub path: PathBuf,
    /// One scan per block, in file order.
    pub scans: Vec<PtxScan>,
}

/// One PTX block.
#[derive(Debug, Clone)]
pub struct PtxScan {
    /// `<stem>` for a one-block file, else `<stem>_<k>` (k from 0).
    pub name: String,
    /// Number of columns (first header line).
    pub cols: u32,
    /// Number of rows (second header line).
    pub rows: u32,
    /// The header's registered scanner position.
    pub scanner_position: DVec3,
    /// The header's registered scanner x, y and z axes.
    pub scanner_axes: [DVec3; 3],
    /// The registration matrix as a column-vector transform: scanner frame → registered frame.
    pub pose: DMat4,
    /// Largest absolute difference between the header's position and axes and the matrix's
    /// translation and rotation rows (0 when they agree).
    pub header_mismatch: f64,
    /// Coordinates per cell, column-major; non-finite for a cell without a return.
    pub xyz: Vec<[f64; 3]>,
    /// Intensity per cell as stored (usually 0–1).
    pub intensity: Vec<f32>,
    /// Colour per cell, when the block's lines have seven values (`0 0 0` = no colour).
    pub rgb: Option<Vec<[u8; 3]>>,
    /// Line number (from 1) of the block's first header line.
    pub header_line: usize,
}

impl PtxScan {
    /// Number of records (`cols × rows`).
    pub fn len(&self) -> usize {
        self.xyz.len()
    }

    /// True when the block has no record.
    pub fn is_empty(&self) -> bool {
        self.xyz.is_empty()
    }

    /// The block's grid: record `k` is row `k % rows` of column `k / rows`.
    pub fn grid(&self) -> RawGrid {
        let rows = self.rows.max(1) as usize;
        let n = self.len();
        RawGrid {
            rows: self.rows,
            cols: self.cols,
            row: (0..n).into_par_iter().map(|k| (k % rows) as u32).collect(),
            col: (0..n).into_par_iter().map(|k| (k / rows) as u32).collect(),
        }
    }
}

impl PtxInput {
    /// The blocks as the pipeline takes them: scanner-frame coordinates (every cell, a
    /// no-return cell non-finite), the full grid, `pose` = the registration matrix, the
    /// scanner at the frame's origin.
    pub fn raw_scans(&self) -> Vec<RawScan> {
        self.scans
            .iter()
            .map(|s| RawScan {
                name: s.name.clone(),
                xyz: s.xyz.clone(),
                normals: None,
                grid: Some(s.grid()),
                pose: Some(s.pose),
                scanner: Some(DVec3::ZERO),
                sensor_hint: None,
                warnings: Vec::new(),
            })
            .collect()
    }

    /// Block `k` with its AO (one finite value per cell) as a table for writing in another
    /// format: coordinates with the block's pose, colours by `color` (a `0 0 0` colour counts
    /// as none), intensity clamped to [0, 1], the grid.
    pub fn point_table(
        &self,
        k: usize,
        ao: &[f32],
        gamma: f32,
        color: ColorMode,
    ) -> Result<PointTable> {
        let s = self
            .scans
            .get(k)
            .ok_or_else(|| Error::Param(format!("{}: no block {k}", self.path.display())))?;
        if ao.len() != s.len() || ao.iter().any(|a| !a.is_finite()) {
            return Err(Error::Param(format!(
                "{}: scan {}: {} AO values for {} cells, or a non-finite one (internal error)",
                self.path.display(),
                s.name,
                ao.len(),
                s.len()
            )));
        }
        let valid: Option<Vec<bool>> = s
            .rgb
            .as_ref()
            .map(|c| c.par_iter().map(|p| *p != [0; 3]).collect());
        let rgb = result_colours(s.rgb.as_deref(), valid.as_deref(), ao, gamma, color);
        Ok(PointTable {
            name: s.name.clone(),
            xyz: s.xyz.clone(),
            pose: s.pose,
            rgb: Some(rgb),
            intensity: Some(s.intensity.par_iter().map(|v| v.clamp(0.0, 1.0)).collect()),
            ao: ao.to_vec(),
            grid: Some(s.grid()),
            extra: Vec::new(),
        })
    }
}

/// The name errors and scans take when PTX is read from a stream rather than a file.
const STREAM: &str = "(PTX stream)";

impl PtxInput {
    /// Reads a PTX file (see the module documentation).
    ///
    /// Errors name the file, the block (from 1) and the line: a header line that is not what it
    /// should be, a point line with a bad number or a wrong number of values, a block with
    /// another number of points than `columns × rows` says, a truncated file.
    pub fn from_path(path: &Path) -> Result<PtxInput> {
        let data = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::from_bytes(&data, path)
    }

    /// Reads PTX from any stream, as [`PtxInput::from_path`] reads a file; errors name the
    /// input `(PTX stream)`. The blocks are parsed in parallel from memory, so the stream is
    /// read whole first.
    pub fn new<R: std::io::Read>(mut reader: R) -> Result<PtxInput> {
        let path = Path::new(STREAM);
        let mut data = Vec::new();
        reader
            .read_to_end(&mut data)
            .map_err(|e| Error::io(path, e))?;
        Self::from_bytes(&data, path)
    }

    /// Parses PTX bytes already in memory; `path` names them in messages and scan names.
    pub fn from_bytes(data: &[u8], path: &Path) -> Result<PtxInput> {
        parse_ptx(data, path)
    }
}

fn parse_ptx(data: &[u8], path: &Path) -> Result<PtxInput> {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scan".into());
    // A UTF-8 byte order mark some Windows tools write is not part of the first line.
    let bom = if data.starts_with(b"\xEF\xBB\xBF") {
        3
    } else {
        0
    };
    let mut cur = Cursor {
        data,
        pos: bom,
        line: 1,
    };
    let mut scans: Vec<PtxScan> = Vec::new();
    loop {
        cur.skip_blank_lines();
        if cur.at_end() {
            break;
        }
        let prev = scans.last().map(|s| (s.cols, s.rows));
        let b = scans.len() + 1;
        scans.push(parse_block(&mut cur, b, prev, path)?);
    }
    if scans.is_empty() {
        return Err(Error::format(path, "empty file: no PTX block"));
    }
    let many = scans.len() > 1;
    for (k, s) in scans.iter_mut().enumerate() {
        s.name = if many {
            format!("{stem}_{k}")
        } else {
            stem.clone()
        };
    }
    Ok(PtxInput {
        path: path.to_path_buf(),
        scans,
    })
}

/// Reading position in the file: byte offset and the number (from 1) of the line there.
struct Cursor<'a> {
    data: &'a [u8],
    pos: usize,
    line: usize,
}

impl<'a> Cursor<'a> {
    fn at_end(&self) -> bool {
        self.pos >= self.data.len()
    }

    /// The next line without its terminator, with its number; `None` at the end.
    fn next_line(&mut self) -> Option<(&'a [u8], usize)> {
        if self.at_end() {
            return None;
        }
        let rest = &self.data[self.pos..];
        let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos += (len + 1).min(rest.len());
        let no = self.line;
        self.line += 1;
        Some((&rest[..len], no))
    }

    fn skip_blank_lines(&mut self) {
        loop {
            let (pos, line) = (self.pos, self.line);
            match self.next_line() {
                Some((l, _)) if is_blank(l) => {}
                _ => {
                    self.pos = pos;
                    self.line = line;
                    return;
                }
            }
        }
    }
}

#[inline]
fn is_space(b: u8) -> bool {
    b == b' ' || b == b'\t' || b == b'\r'
}

fn is_blank(l: &[u8]) -> bool {
    l.iter().all(|&b| is_space(b))
}

/// Whitespace-separated tokens of a line.
fn tokens(l: &[u8]) -> impl Iterator<Item = &[u8]> {
    l.split(|&b| is_space(b)).filter(|t| !t.is_empty())
}

/// A token for messages (shortened).
fn shown(t: &[u8]) -> String {
    let s = String::from_utf8_lossy(t);
    if s.chars().count() > 40 {
        format!("{}…", s.chars().take(40).collect::<String>())
    } else {
        s.into_owned()
    }
}

/// A header line of exactly `K` numbers.
fn header_numbers<const K: usize>(l: &[u8]) -> std::result::Result<[f64; K], String> {
    let mut out = [0.0; K];
    let mut n = 0;
    for t in tokens(l) {
        if n == K {
            return Err(format!("expected {K} numbers, found more: '{}'", shown(l)));
        }
        out[n] = parse_f64(t).ok_or_else(|| format!("'{}' is not a finite number", shown(t)))?;
        n += 1;
    }
    if n < K {
        return Err(format!("expected {K} numbers, found {n}: '{}'", shown(l)));
    }
    Ok(out)
}

/// A header line holding one non-negative integer.
fn header_count(l: &[u8]) -> Option<u32> {
    let mut it = tokens(l);
    let t = it.next()?;
    if it.next().is_some() || !t.iter().all(u8::is_ascii_digit) {
        return None;
    }
    std::str::from_utf8(t).ok()?.parse().ok()
}

/// Why a point line was refused.
enum LineError {
    /// Not 4 or 7 values, or another count than the block's first line.
    Count(usize),
    /// A token that is not a finite number (byte range in the line).
    Number(usize, usize),
    /// A colour outside 0–255.
    Colour(f64),
}

/// The ten header lines of a block.
struct BlockHeader {
    cols: u32,
    rows: u32,
    /// Line number of the first header line.
    header_line: usize,
    /// Scanner position and x, y, z axes.
    three: [DVec3; 4],
    pose: DMat4,
    header_mismatch: f64,
}

/// Reads block `b`'s header; `prev` is the previous block's size, to recognise a block that
/// holds more points than it declares.
fn parse_header(
    cur: &mut Cursor,
    b: usize,
    prev: Option<(u32, u32)>,
    path: &Path,
) -> Result<BlockHeader> {
    let err =
        |line: usize, msg: String| Error::format(path, format!("block {b}, line {line}: {msg}"));
    let truncated = |what: &str| {
        Error::format(
            path,
            format!("block {b}: the file ends in the header, before the {what} (truncated)"),
        )
    };
    let (l, header_line) = cur
        .next_line()
        .ok_or_else(|| truncated("number of columns"))?;
    let cols = match header_count(l) {
        Some(c) => c,
        None => {
            let n = tokens(l).count();
            if let (Some((pc, pr)), true) = (prev, n == 4 || n == 7) {
                return Err(Error::format(
                    path,
                    format!(
                        "block {} declares {pc} × {pr} = {} points, found more: line {header_line} \
                         holds a point where block {b}'s number of columns should be",
                        b - 1,
                        pc as u64 * pr as u64
                    ),
                ));
            }
            return Err(err(
                header_line,
                format!("expected the number of columns, found '{}'", shown(l)),
            ));
        }
    };
    let (l, no) = cur.next_line().ok_or_else(|| truncated("number of rows"))?;
    let rows = header_count(l).ok_or_else(|| {
        err(
            no,
            format!("expected the number of rows, found '{}'", shown(l)),
        )
    })?;
    let mut three = [DVec3::ZERO; 4];
    for (i, what) in [
        "scanner position",
        "scanner x axis",
        "scanner y axis",
        "scanner z axis",
    ]
    .iter()
    .enumerate()
    {
        let (l, no) = cur.next_line().ok_or_else(|| truncated(what))?;
        three[i] =
            DVec3::from_array(header_numbers::<3>(l).map_err(|m| err(no, format!("{what}: {m}")))?);
    }
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        let what = format!("registration matrix row {}", i + 1);
        let (l, no) = cur.next_line().ok_or_else(|| truncated(&what))?;
        *row = header_numbers::<4>(l).map_err(|e| err(no, format!("{what}: {e}")))?;
    }
    // Row i of the row-vector matrix is column i of the column-vector one.
    let pose = DMat4::from_cols_array_2d(&m);
    let header_mismatch = [
        (three[0] - pose.w_axis.truncate()).abs().max_element(),
        (three[1] - pose.x_axis.truncate()).abs().max_element(),
        (three[2] - pose.y_axis.truncate()).abs().max_element(),
        (three[3] - pose.z_axis.truncate()).abs().max_element(),
    ]
    .into_iter()
    .fold(0.0, f64::max);
    Ok(BlockHeader {
        cols,
        rows,
        header_line,
        three,
        pose,
        header_mismatch,
    })
}

/// Parses one block starting at the cursor; `prev` is the previous block's (cols, rows).
fn parse_block(
    cur: &mut Cursor,
    b: usize,
    prev: Option<(u32, u32)>,
    path: &Path,
) -> Result<PtxScan> {
    let err =
        |line: usize, msg: String| Error::format(path, format!("block {b}, line {line}: {msg}"));
    let BlockHeader {
        cols,
        rows,
        header_line,
        three,
        pose,
        header_mismatch,
    } = parse_header(cur, b, prev, path)?;

    let n = cols as u64 * rows as u64;
    let declared = format!("block {b} declares {cols} × {rows} = {n} points");
    let start = cur.pos;
    let first_line = cur.line;
    let pieces = line_pieces(cur.data, start, n);
    let end = pieces.last().map_or(start, |p| p.1);
    let found = pieces.iter().map(|p| p.2).sum::<u64>() as usize;
    let region = &cur.data[start..end];

    // The block's field count comes from its first point line.
    let fields = match region.split(|&c| c == b'\n').next() {
        Some(l) if found > 0 => {
            let k = tokens(l).count();
            if k == 4 || k == 7 {
                k
            } else {
                4
            }
        }
        _ => 4,
    };
    let mut xyz = vec![[0.0f64; 3]; found];
    let mut intensity = vec![0.0f32; found];
    let mut rgbf = if fields == 7 {
        vec![[0.0f32; 3]; found]
    } else {
        Vec::new()
    };
    if let Some((m, e)) = parse_pieces(
        cur.data,
        &pieces,
        fields,
        &mut xyz,
        &mut intensity,
        &mut rgbf,
    ) {
        let line_no = first_line + m;
        let line = region.split(|&c| c == b'\n').nth(m).unwrap_or_default();
        let rest_blank = region
            .split(|&c| c == b'\n')
            .skip(m)
            .chain(cur.data[end..].split(|&c| c == b'\n'))
            .all(is_blank);
        // A last line cut short by the end of the file is truncation, not a bad line.
        let cut_short = m + 1 == found && end == cur.data.len() && cur.data.last() != Some(&b'\n');
        if rest_blank || cut_short {
            return Err(Error::format(
                path,
                format!("{declared}, found {m}; the file ends early (truncated)"),
            ));
        }
        // A point count short of the header's: the next block's header starts here.
        let next = if m + 1 < found {
            region.split(|&c| c == b'\n').nth(m + 1)
        } else {
            cur.data[end..].split(|&c| c == b'\n').next()
        };
        if header_count(line).is_some() && next.and_then(header_count).is_some() {
            return Err(Error::format(path, format!("{declared}, found {m}")));
        }
        let msg = match e {
            LineError::Count(k) => format!(
                "expected {fields} values (x y z intensity{}), found {k}: '{}'",
                if fields == 7 { " r g b" } else { " [r g b]" },
                shown(line)
            ),
            LineError::Number(s, t) => {
                format!("'{}' is not a finite number", shown(&line[s..t]))
            }
            LineError::Colour(v) => format!("colour value {v} outside 0–255"),
        };
        return Err(err(line_no, msg));
    }
    if (found as u64) < n {
        return Err(Error::format(
            path,
            format!("{declared}, found {found}; the file ends early (truncated)"),
        ));
    }
    cur.pos = end;
    cur.line = first_line + found;

    let rgb = (fields == 7).then(|| {
        // Colours written as 0–1 floats are scaled; integers 0–255 are taken as they are.
        let fractional = rgbf.par_iter().any(|c| c.iter().any(|v| v.fract() != 0.0));
        let unit = fractional && rgbf.par_iter().all(|c| c.iter().all(|&v| v <= 1.0));
        let s = if unit { 255.0 } else { 1.0 };
        rgbf.par_iter()
            .map(|c| c.map(|v| (v * s).round().clamp(0.0, 255.0) as u8))
            .collect()
    });
    Ok(PtxScan {
        name: String::new(),
        cols,
        rows,
        scanner_position: three[0],
        scanner_axes: [three[1], three[2], three[3]],
        pose,
        header_mismatch,
        xyz,
        intensity,
        rgb,
        header_line,
    })
}

/// The next `n` lines from `start` as pieces of about a megabyte `(first byte, end byte,
/// lines)`, fewer lines in all at the end of the file (an unterminated, non-blank last line
/// counts). Pieces are counted in parallel a batch at a time, so counting stops near the
/// block's end, and the same pieces are then parsed in parallel.
fn line_pieces(data: &[u8], start: usize, n: u64) -> Vec<(usize, usize, u64)> {
    const PIECE: usize = 1 << 20;
    let batch = 4 * rayon::current_num_threads().max(1);
    let mut out = Vec::new();
    let (mut pos, mut found) = (start, 0u64);
    while found < n && pos < data.len() {
        let mut cuts = Vec::with_capacity(batch);
        let mut p = pos;
        while cuts.len() < batch && p < data.len() {
            let want = (p + PIECE).min(data.len());
            let cut = data[want..]
                .iter()
                .position(|&b| b == b'\n')
                .map_or(data.len(), |i| want + i + 1);
            cuts.push((p, cut));
            p = cut;
        }
        let counts: Vec<u64> = cuts
            .par_iter()
            .map(|&(a, b)| lines_in(&data[a..b]) as u64)
            .collect();
        for (&(a, b), &c) in cuts.iter().zip(&counts) {
            if found + c < n {
                out.push((a, b, c));
                found += c;
                pos = b;
                continue;
            }
            // The block ends inside this piece, after its `need`-th line.
            let need = n - found;
            let mut seen = 0u64;
            let mut e = b;
            for (i, &ch) in data[a..b].iter().enumerate() {
                if ch == b'\n' {
                    seen += 1;
                    if seen == need {
                        e = a + i + 1;
                        break;
                    }
                }
            }
            out.push((a, e, need));
            return out;
        }
    }
    out
}

/// Lines in a piece: its line ends, and a non-blank unterminated tail (the end of the file).
fn lines_in(b: &[u8]) -> usize {
    // A plain count vectorises.
    let nl = b.iter().filter(|&&c| c == b'\n').count();
    let tail = b
        .iter()
        .rposition(|&c| c == b'\n')
        .map_or(b, |i| &b[i + 1..]);
    nl + usize::from(!is_blank(tail))
}

/// Parses the point lines of `pieces` into the outputs (one slot per line) in parallel.
/// Returns the first refused line (index from the block's first point line) and why.
fn parse_pieces(
    data: &[u8],
    pieces: &[(usize, usize, u64)],
    fields: usize,
    xyz: &mut [[f64; 3]],
    intensity: &mut [f32],
    rgb: &mut [[f32; 3]],
) -> Option<(usize, LineError)> {
    let mut jobs = Vec::with_capacity(pieces.len());
    let (mut xs, mut is, mut cs) = (xyz, intensity, rgb);
    let mut first = 0usize;
    for &(a, b, c) in pieces {
        let c = (c as usize).min(xs.len());
        let (x, rest) = xs.split_at_mut(c);
        xs = rest;
        let (i, rest) = is.split_at_mut(c);
        is = rest;
        let col = if fields == 7 {
            let (x, rest) = cs.split_at_mut(c);
            cs = rest;
            x
        } else {
            &mut []
        };
        jobs.push((first, &data[a..b], x, i, col));
        first += c;
    }
    jobs.into_par_iter()
        .filter_map(|(first, bytes, xs, is, cs)| {
            parse_piece(bytes, fields, xs, is, cs).map(|(m, e)| (first + m, e))
        })
        .min_by_key(|(m, _)| *m)
}

fn parse_piece(
    bytes: &[u8],
    fields: usize,
    xyz: &mut [[f64; 3]],
    intensity: &mut [f32],
    rgb: &mut [[f32; 3]],
) -> Option<(usize, LineError)> {
    let mut vals = [0.0f64; 7];
    for (k, line) in bytes.split(|&c| c == b'\n').take(xyz.len()).enumerate() {
        match parse_point(line, &mut vals) {
            Ok(c) if c == fields => {}
            Ok(c) => return Some((k, LineError::Count(c))),
            Err(e) => return Some((k, e)),
        }
        let p = [vals[0], vals[1], vals[2]];
        xyz[k] = if p == [0.0; 3] { [f64::NAN; 3] } else { p };
        intensity[k] = vals[3] as f32;
        if fields == 7 {
            for (o, &v) in rgb[k].iter_mut().zip(&vals[4..7]) {
                if !(0.0..=255.0).contains(&v) {
                    return Some((k, LineError::Colour(v)));
                }
                *o = v as f32;
            }
        }
    }
    None
}

/// Parses up to seven numbers of a point line; returns how many there were.
#[inline]
fn parse_point(line: &[u8], out: &mut [f64; 7]) -> std::result::Result<usize, LineError> {
    let (mut i, len, mut n) = (0usize, line.len(), 0usize);
    loop {
        while i < len && is_space(line[i]) {
            i += 1;
        }
        if i >= len {
            return Ok(n);
        }
        let s = i;
        while i < len && !is_space(line[i]) {
            i += 1;
        }
        if n == 7 {
            return Err(LineError::Count(8 + tokens(&line[i..]).count()));
        }
        out[n] = parse_f64(&line[s..i]).ok_or(LineError::Number(s, i))?;
        n += 1;
    }
}

/// Powers of ten that are exact in f64.
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// A finite decimal number. Plain decimals with at most 15 significant digits take an exact
/// fast path (an exact integer times or over an exact power of ten rounds once, correctly);
/// everything else goes through the standard library's parser.
#[inline]
fn parse_f64(t: &[u8]) -> Option<f64> {
    let (mut i, len) = (0usize, t.len());
    let neg = match t.first() {
        Some(b'-') => {
            i = 1;
            true
        }
        Some(b'+') => {
            i = 1;
            false
        }
        _ => false,
    };
    let mut mant: u64 = 0;
    let mut digits = 0u32;
    let mut exp: i32 = 0;
    let mut any = false;
    while i < len && t[i].is_ascii_digit() {
        if mant != 0 || t[i] != b'0' {
            digits += 1;
        }
        mant = mant.wrapping_mul(10).wrapping_add((t[i] - b'0') as u64);
        any = true;
        i += 1;
    }
    if i < len && t[i] == b'.' {
        i += 1;
        while i < len && t[i].is_ascii_digit() {
            if mant != 0 || t[i] != b'0' {
                digits += 1;
            }
            mant = mant.wrapping_mul(10).wrapping_add((t[i] - b'0') as u64);
            exp -= 1;
            any = true;
            i += 1;
        }
    }
    if i < len && (t[i] == b'e' || t[i] == b'E') && any {
        i += 1;
        let eneg = match t.get(i) {
            Some(b'-') => {
                i += 1;
                true
            }
            Some(b'+') => {
                i += 1;
                false
            }
            _ => false,
        };
        let mut e: i32 = 0;
        let mut edigits = false;
        while i < len && t[i].is_ascii_digit() {
            e = e.saturating_mul(10).saturating_add((t[i] - b'0') as i32);
            edigits = true;
            i += 1;
        }
        if !edigits {
            return None;
        }
        exp = exp.saturating_add(if eneg { -e } else { e });
    }
    if !any || i != len {
        return slow_f64(t);
    }
    if digits > 15 || !(-22..=22).contains(&exp) {
        return slow_f64(t);
    }
    let m = mant as f64;
    let v = if exp >= 0 {
        m * POW10[exp as usize]
    } else {
        m / POW10[(-exp) as usize]
    };
    let v = if neg { -v } else { v };
    v.is_finite().then_some(v)
}

#[cold]
fn slow_f64(t: &[u8]) -> Option<f64> {
    let v: f64 = std::str::from_utf8(t).ok()?.parse().ok()?;
    v.is_finite().then_some(v)
}

/// Writes `scans` as a PTX file, atomically: one block per table, which must have a grid
/// (cells without a point are written as `0 0 0 0.5`, no-return). The matrix is the table's
/// pose, the header's position and axes are taken from it; coordinates are written with
/// round-trip precision; intensity is the table's (0.5 without one); colour lines when the
/// table has colours.
pub fn write_ptx(scans: &[PointTable], out: &Path) -> Result<()> {
    let mut cells: Vec<Vec<u32>> = Vec::with_capacity(scans.len());
    for t in scans {
        let bad = |msg: String| Error::Param(format!("{}: scan {}: {msg}", out.display(), t.name));
        let g = t
            .grid
            .as_ref()
            .ok_or_else(|| bad("has no grid; a PTX block needs one".into()))?;
        let n = t.len();
        if g.row.len() != n || g.col.len() != n {
            return Err(bad(format!("grid of {} cells for {n} points", g.row.len())));
        }
        if t.intensity.as_ref().is_some_and(|i| i.len() != n)
            || t.rgb.as_ref().is_some_and(|c| c.len() != n)
        {
            return Err(bad(
                "intensity or colour count differs from the points".into()
            ));
        }
        let size = g.rows as u64 * g.cols as u64;
        if size > u32::MAX as u64 {
            return Err(bad(format!("grid {} × {} is too large", g.rows, g.cols)));
        }
        // Cell (row, col) → record, stored column-major as the file is.
        let mut at = vec![u32::MAX; size as usize];
        for (k, (&r, &c)) in g.row.iter().zip(&g.col).enumerate() {
            if r >= g.rows || c >= g.cols {
                return Err(bad(format!(
                    "cell ({r}, {c}) outside the {} × {} grid",
                    g.rows, g.cols
                )));
            }
            let slot = &mut at[c as usize * g.rows as usize + r as usize];
            if *slot != u32::MAX {
                return Err(bad(format!("two points in cell ({r}, {c})")));
            }
            *slot = k as u32;
        }
        cells.push(at);
    }
    write_atomic(out, |w| {
        for (t, at) in scans.iter().zip(&cells) {
            let g = t.grid.as_ref().map_or((0, 0), |g| (g.rows, g.cols));
            let p = t.pose;
            writeln!(w, "{}\n{}", g.1, g.0)?;
            let v = |a: glam::DVec4| format!("{} {} {}", a.x, a.y, a.z);
            writeln!(w, "{}", v(p.w_axis))?;
            writeln!(w, "{}\n{}\n{}", v(p.x_axis), v(p.y_axis), v(p.z_axis))?;
            for c in [p.x_axis, p.y_axis, p.z_axis, p.w_axis] {
                writeln!(w, "{} {} {} {}", c.x, c.y, c.z, c.w)?;
            }
            for &k in at {
                let k = k as usize;
                let q = t.xyz.get(k).filter(|q| q.iter().all(|v| v.is_finite()));
                match q {
                    Some(q) => {
                        let i = t.intensity.as_ref().map_or(0.5, |i| {
                            if i[k].is_finite() {
                                i[k]
                            } else {
                                0.0
                            }
                        });
                        write!(w, "{} {} {} {}", q[0], q[1], q[2], i)?;
                    }
                    None => write!(w, "0 0 0 0.5")?,
                }
                if let Some(c) = &t.rgb {
                    let c = c.get(k).copied().unwrap_or([0; 3]);
                    write!(w, " {} {} {}", c[0], c[1], c[2])?;
                }
                writeln!(w)?;
            }
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_float_path_is_exact() {
        for s in [
            "0",
            "-0",
            "1",
            "0.5",
            "-12.345678",
            "1e3",
            "2.5E-3",
            "123456.789012345",
            "0.000001",
            "+7.25",
            "1234567890123456789",
            "0.1234567890123456789",
            "1e-30",
            "5e300",
            ".5",
            "5.",
        ] {
            let want: f64 = s.parse().unwrap();
            assert_eq!(parse_f64(s.as_bytes()), Some(want), "{s}");
        }
        for s in [
            "", "-", "abc", "1.2.3", "1e", "nan", "inf", "1e999", "0x10", "1,5",
        ] {
            assert_eq!(parse_f64(s.as_bytes()), None, "{s}");
        }
        // Random decimals agree bit for bit with the standard parser.
        let mut x = 0x9e3779b97f4a7c15u64;
        for _ in 0..20000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let v = (x >> 11) as f64 / (1u64 << 53) as f64 * 2000.0 - 1000.0;
            for s in [format!("{v}"), format!("{v:.6}"), format!("{v:e}")] {
                assert_eq!(parse_f64(s.as_bytes()), s.parse().ok(), "{s}");
            }
        }
    }

    #[test]
    fn line_counting() {
        let ends = |d: &[u8], s: usize, n: u64| {
            let p = line_pieces(d, s, n);
            (
                p.last().map_or(s, |p| p.1),
                p.iter().map(|p| p.2).sum::<u64>(),
            )
        };
        assert_eq!(ends(b"a\nb\nc\n", 0, 2), (4, 2));
        assert_eq!(ends(b"a\nb\nc\n", 2, 2), (6, 2));
        assert_eq!(ends(b"a\nb\nc", 0, 5), (5, 3));
        assert_eq!(ends(b"a\nb\nc", 0, 3), (5, 3));
        assert_eq!(ends(b"a\nb\n  \n", 0, 5), (7, 3));
        assert_eq!(ends(b"a\nb\n  ", 0, 5), (6, 2));
        assert_eq!(ends(b"", 0, 1), (0, 0));
        assert_eq!(lines_in(b"a\nb"), 2);
        // Many pieces: the count stops exactly after the n-th line.
        let big: Vec<u8> = (0..400_000)
            .flat_map(|k| format!("{k}\n").into_bytes())
            .collect();
        let p = line_pieces(&big, 0, 300_000);
        assert!(p.len() > 1);
        assert_eq!(p.iter().map(|p| p.2).sum::<u64>(), 300_000);
        assert!(big[..p.last().unwrap().1].ends_with(b"\n299999\n"));
    }
}
