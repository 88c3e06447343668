//! Reading: the buffered source with its bulk and parallel reads, and the binary bodies.

use super::ascii::read_ascii;
use super::header::parse_header;
use super::*;
use rayon::prelude::*;
use std::fs::File;
use std::io::{BufRead, BufReader, ErrorKind, Read};

impl PlyFile {
    /// Reads a PLY file (ascii, binary little or big endian). Errors name `path` and say what is
    /// wrong: not a PLY, bad header line, unknown type, truncated body (with element and row),
    /// unparsable ascii value, an ascii row with too few or too many values (with its line).
    /// Data after the last element is ignored ([`PlyFile::from_path_warn`] reports it).
    ///
    /// There is no reader over a stream: large bodies are read by several threads at once,
    /// each at its own offset in the file.
    pub fn from_path(path: &Path) -> Result<PlyFile> {
        Self::from_path_warn(path).map(|(ply, _)| ply)
    }

    /// [`PlyFile::from_path`], with what the user should know about the file: data after the
    /// last element (some writers pad their files, so it is not an error).
    pub fn from_path_warn(path: &Path) -> Result<(PlyFile, Vec<String>)> {
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        let len = file
            .metadata()
            .ok()
            .filter(|m| m.is_file())
            .map(|m| m.len());
        // Small files get a small buffer; big ones a large one so the body streams in big reads.
        let cap = len.map_or(READ_BUF, |l| {
            usize::try_from(l.saturating_add(1))
                .unwrap_or(READ_BUF)
                .clamp(8 << 10, READ_BUF)
        });
        let mut src = Source {
            r: BufReader::with_capacity(cap, file),
            pos: 0,
            line: 1,
            len,
            path,
        };
        let header = parse_header(&mut src)?;
        let mut data = Vec::with_capacity(header.elements.len());
        for def in &header.elements {
            data.push(read_element(&mut src, header.encoding, def)?);
        }
        let mut warnings = Vec::new();
        if let Some(w) = trailing_data(&mut src, header.encoding)? {
            warnings.push(w);
        }
        Ok((PlyFile { header, data }, warnings))
    }
}

/// Capacity of the read buffer for big files.
pub(super) const READ_BUF: usize = 4 << 20;

/// Longest header line accepted (a binary file without newlines must not be slurped).
pub(super) const MAX_HEADER_LINE: u64 = 64 << 10;

/// Largest header accepted.
pub(super) const MAX_HEADER_BYTES: u64 = 16 << 20;

/// Longest ascii token accepted.
pub(super) const MAX_TOKEN: usize = 4096;

/// Reserved bulk reads at least this long are read by several threads.
pub(super) const PARALLEL_READ_MIN: usize = 8 << 20;

/// Bulk reads grow their buffer by at most this much before data is seen.
pub(super) const BULK_CHUNK: usize = 64 << 20;

/// Reservation cap when the file length is unknown (not a regular file).
pub(super) const UNKNOWN_LEN_CAP: usize = 64 << 20;

/// The open file being read, with the number of bytes consumed so far.
pub(super) struct Source<'p> {
    pub(super) r: BufReader<File>,
    /// Bytes consumed from the start of the file.
    pub(super) pos: u64,
    /// Line of the next byte (1-based); kept up to date by header and ascii reading only.
    pub(super) line: u64,
    /// File length, when the file is a regular file.
    pub(super) len: Option<u64>,
    /// For error messages.
    pub(super) path: &'p Path,
}

impl Source<'_> {
    pub(super) fn err(&self, msg: impl Into<String>) -> Error {
        Error::format(self.path, msg)
    }

    pub(super) fn io_err(&self, e: std::io::Error) -> Error {
        Error::io(self.path, e)
    }

    /// Bytes left after the current position, when the file length is known.
    pub(super) fn remaining(&self) -> Option<u64> {
        self.len.map(|l| l.saturating_sub(self.pos))
    }

    /// How many bytes it is safe to reserve for data still to be read.
    pub(super) fn reserve_cap(&self) -> usize {
        self.remaining().map_or(UNKNOWN_LEN_CAP, |r| {
            usize::try_from(r).unwrap_or(usize::MAX)
        })
    }

    /// One header line (with its line ending) into `line`; 0 at end of file.
    pub(super) fn read_line(&mut self, line: &mut Vec<u8>) -> std::io::Result<usize> {
        line.clear();
        let n = (&mut self.r)
            .take(MAX_HEADER_LINE)
            .read_until(b'\n', line)?;
        self.pos += n as u64;
        if line.last() == Some(&b'\n') {
            self.line += 1;
        }
        Ok(n)
    }

    /// Fills `buf` as far as the file allows; returns the number of bytes read.
    pub(super) fn read_full(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let mut got = 0;
        while let Some(rest) = buf.get_mut(got..).filter(|r| !r.is_empty()) {
            match self.r.read(rest) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        self.pos += got as u64;
        Ok(got)
    }

    /// [`Source::append`] of `n` reserved bytes by several threads at once, each reading its
    /// own stretch of the file at its offset (the file position is set past them after): the
    /// copy out of the page cache and the faults of a fresh buffer no longer hold up one core
    /// while the others wait for the decoding.
    #[cfg(unix)]
    pub(super) fn append_parallel(
        &mut self,
        out: &mut Vec<u8>,
        n: usize,
    ) -> std::io::Result<usize> {
        use std::io::{Seek, SeekFrom};
        use std::mem::MaybeUninit;
        use std::os::unix::fs::FileExt;
        const CHUNK: usize = 4 << 20;
        let start = out.len();
        // What the buffered reader already holds comes first.
        let held = self.r.buffer();
        let head = held.len().min(n);
        out.extend_from_slice(&held[..head]);
        self.r.consume(head);
        let at = self.pos + head as u64;
        let rest = n - head;
        out.spare_capacity_mut()[..rest]
            .par_chunks_mut(CHUNK)
            .for_each(|c| c.fill(MaybeUninit::new(0)));
        // SAFETY: the `rest` bytes past the length were just initialised (and are reserved).
        unsafe { out.set_len(start + head + rest) };
        let file = self.r.get_ref();
        let got: Vec<std::io::Result<usize>> = out[start + head..]
            .par_chunks_mut(CHUNK)
            .enumerate()
            .map(|(k, dst)| {
                let mut done = 0;
                while done < dst.len() {
                    match file.read_at(&mut dst[done..], at + (k * CHUNK + done) as u64) {
                        Ok(0) => break,
                        Ok(m) => done += m,
                        Err(e) if e.kind() == ErrorKind::Interrupted => {}
                        Err(e) => return Err(e),
                    }
                }
                Ok(done)
            })
            .collect();
        // The bytes up to the first short stretch (the end of the file).
        let mut read = 0;
        for (k, g) in got.into_iter().enumerate() {
            let g = match g {
                Ok(g) => g,
                Err(e) => {
                    out.truncate(start);
                    return Err(e);
                }
            };
            read += g;
            if g < CHUNK.min(rest - k * CHUNK) {
                break;
            }
        }
        out.truncate(start + head + read);
        if let Err(e) = self.r.seek(SeekFrom::Start(at + read as u64)) {
            out.truncate(start);
            return Err(e);
        }
        self.pos = at + read as u64;
        Ok(head + read)
    }

    /// Appends up to `n` bytes to `out`, growing it chunk by chunk so that a bogus `n` never
    /// allocates more than the data actually present; returns the number of bytes appended.
    pub(super) fn append(&mut self, out: &mut Vec<u8>, n: usize) -> std::io::Result<usize> {
        let start = out.len();
        if out.capacity() - start >= n {
            #[cfg(unix)]
            if n >= PARALLEL_READ_MIN {
                return self.append_parallel(out, n);
            }
            // Already reserved (the file is known to hold the bytes): read straight into the
            // spare capacity, without zero-filling it first.
            let res = (&mut self.r).take(n as u64).read_to_end(out);
            let got = out.len() - start;
            self.pos += got as u64;
            return match res {
                Ok(_) => Ok(got),
                Err(e) => {
                    out.truncate(start);
                    Err(e)
                }
            };
        }
        let mut done = 0;
        while done < n {
            let chunk = (n - done).min(BULK_CHUNK);
            let start = out.len();
            out.resize(start + chunk, 0);
            let got = match out.get_mut(start..) {
                Some(dst) => self.read_full(dst),
                None => Ok(0),
            };
            let got = match got {
                Ok(g) => g,
                Err(e) => {
                    out.truncate(start);
                    return Err(e);
                }
            };
            out.truncate(start + got);
            done += got;
            if got < chunk {
                break;
            }
        }
        Ok(done)
    }

    /// Next whitespace-separated token into `tok`: `None` at end of file, `Some(false)` if the
    /// token was longer than [`MAX_TOKEN`] (then `tok` holds its start). Line ends skipped on
    /// the way are counted in [`Source::line`].
    pub(super) fn next_token(&mut self, tok: &mut Vec<u8>) -> std::io::Result<Option<bool>> {
        tok.clear();
        // Skip whitespace.
        loop {
            let buf = self.r.fill_buf()?;
            if buf.is_empty() {
                return Ok(None);
            }
            let (skip, found) = match buf.iter().position(|b| !b.is_ascii_whitespace()) {
                Some(i) => (i, true),
                None => (buf.len(), false),
            };
            self.line += buf[..skip].iter().filter(|&&b| b == b'\n').count() as u64;
            self.r.consume(skip);
            self.pos += skip as u64;
            if found {
                break;
            }
        }
        // Collect the token.
        let mut complete = true;
        loop {
            let buf = self.r.fill_buf()?;
            if buf.is_empty() {
                break;
            }
            let (take, end) = match buf.iter().position(|b| b.is_ascii_whitespace()) {
                Some(i) => (i, true),
                None => (buf.len(), false),
            };
            let room = MAX_TOKEN.saturating_sub(tok.len());
            if take > room {
                complete = false;
            }
            tok.extend_from_slice(buf.get(..take.min(room)).unwrap_or(&[]));
            self.r.consume(take);
            self.pos += take as u64;
            if end {
                break;
            }
        }
        Ok(Some(complete))
    }

    /// Consumes the rest of the current line, its line end included, and returns the number of
    /// tokens it held.
    pub(super) fn rest_of_line(&mut self) -> std::io::Result<usize> {
        let mut tokens = 0;
        let mut in_token = false;
        loop {
            let buf = self.r.fill_buf()?;
            if buf.is_empty() {
                return Ok(tokens);
            }
            let mut used = buf.len();
            let mut ended = false;
            for (i, &b) in buf.iter().enumerate() {
                if b == b'\n' {
                    used = i + 1;
                    ended = true;
                    break;
                }
                let space = b.is_ascii_whitespace();
                if !space && !in_token {
                    tokens += 1;
                }
                in_token = !space;
            }
            self.r.consume(used);
            self.pos += used as u64;
            if ended {
                self.line += 1;
                return Ok(tokens);
            }
        }
    }
}

/// Reads the body of one element into little-endian rows.
pub(super) fn read_element(
    src: &mut Source,
    enc: Encoding,
    def: &ElementDef,
) -> Result<ElementData> {
    if def.props.is_empty() {
        // Rows without properties hold no bytes in any encoding.
        return Ok(ElementData::default());
    }
    match (enc, fixed_stride(&def.props)) {
        (Encoding::Ascii, _) => read_ascii(src, def),
        (_, Some(stride)) => read_binary_fixed(src, enc == Encoding::BinaryBe, def, stride),
        (_, None) => read_binary_rows(src, enc == Encoding::BinaryBe, def),
    }
}

pub(super) fn truncated(src: &Source, def: &ElementDef, row: usize) -> Error {
    src.err(format!(
        "truncated: element '{}' has {} rows but data ends in row {row}",
        def.name, def.count
    ))
}

/// A fixed-stride binary element: one bulk read, then (big endian) an in-place byte swap.
pub(super) fn read_binary_fixed(
    src: &mut Source,
    big_endian: bool,
    def: &ElementDef,
    stride: usize,
) -> Result<ElementData> {
    let total = def.count.checked_mul(stride).ok_or_else(|| {
        src.err(format!(
            "element '{}' declares {} rows of {stride} bytes, more than can be addressed",
            def.name, def.count
        ))
    })?;
    // Fail before allocating when the file is known to be too short.
    if let Some(rem) = src.remaining() {
        if (total as u64) > rem {
            let rows = usize::try_from(rem / stride as u64).unwrap_or(usize::MAX);
            return Err(truncated(src, def, rows));
        }
    }
    let mut bytes = Vec::with_capacity(total.min(src.reserve_cap()));
    let got = src.append(&mut bytes, total).map_err(|e| src.io_err(e))?;
    if got < total {
        return Err(truncated(src, def, got / stride));
    }
    if big_endian {
        let mut fields = Vec::with_capacity(def.props.len());
        let mut off = 0;
        for p in &def.props {
            if let PropertyKind::Scalar(t) = p.kind {
                if t.size() > 1 {
                    fields.push(off..off + t.size());
                }
                off += t.size();
            }
        }
        if !fields.is_empty() {
            for row in bytes.chunks_exact_mut(stride) {
                for f in &fields {
                    if let Some(x) = row.get_mut(f.clone()) {
                        x.reverse();
                    }
                }
            }
        }
    }
    Ok(ElementData {
        bytes,
        row_offsets: None,
    })
}

/// A binary element with list properties, row by row.
pub(super) fn read_binary_rows(
    src: &mut Source,
    big_endian: bool,
    def: &ElementDef,
) -> Result<ElementData> {
    // Smallest possible row: every scalar plus every list count.
    let min_row: usize = def
        .props
        .iter()
        .map(|p| match p.kind {
            PropertyKind::Scalar(t) => t.size(),
            PropertyKind::List { count, .. } => count.size(),
        })
        .sum::<usize>()
        .max(1);
    let max_rows = src.reserve_cap() / min_row;
    let mut offs = Vec::with_capacity(def.count.min(max_rows).saturating_add(1));
    let mut bytes = Vec::with_capacity(def.count.min(max_rows).saturating_mul(min_row));
    offs.push(0);
    let mut tmp = [0u8; 8];
    for row in 0..def.count {
        for p in &def.props {
            match p.kind {
                PropertyKind::Scalar(t) => {
                    let v = read_scalar(src, t, big_endian, &mut tmp, def, row)?;
                    bytes.extend_from_slice(v);
                }
                PropertyKind::List { count, item } => {
                    let c = read_scalar(src, count, big_endian, &mut tmp, def, row)?;
                    let n = count.read_f64(c, 0).unwrap_or(0.0);
                    if n < 0.0 {
                        return Err(src.err(format!(
                            "element '{}' row {row}: list count {n} is negative",
                            def.name
                        )));
                    }
                    bytes.extend_from_slice(c);
                    let n = n as usize;
                    let need = n.checked_mul(item.size());
                    let short = match (need, src.remaining()) {
                        (None, _) => true,
                        (Some(need), Some(rem)) => need as u64 > rem,
                        (Some(_), None) => false,
                    };
                    if short {
                        return Err(src.err(format!(
                            "truncated: element '{}' has {} rows but data ends in row {row} \
                             (list '{}' of {n} items goes past the end of the file)",
                            def.name, def.count, p.name
                        )));
                    }
                    let need = need.unwrap_or(0);
                    let start = bytes.len();
                    let got = src.append(&mut bytes, need).map_err(|e| src.io_err(e))?;
                    if got < need {
                        return Err(truncated(src, def, row));
                    }
                    if big_endian && item.size() > 1 {
                        if let Some(items) = bytes.get_mut(start..) {
                            for it in items.chunks_exact_mut(item.size()) {
                                it.reverse();
                            }
                        }
                    }
                }
            }
        }
        offs.push(bytes.len());
    }
    Ok(ElementData {
        bytes,
        row_offsets: Some(offs),
    })
}

/// One binary scalar as little-endian bytes (a slice of `tmp`).
pub(super) fn read_scalar<'t>(
    src: &mut Source,
    t: ScalarType,
    big_endian: bool,
    tmp: &'t mut [u8; 8],
    def: &ElementDef,
    row: usize,
) -> Result<&'t [u8]> {
    let size = t.size();
    let buf = tmp.get_mut(..size).unwrap_or(&mut []);
    let got = src.read_full(buf).map_err(|e| src.io_err(e))?;
    if got < size {
        return Err(truncated(src, def, row));
    }
    if big_endian {
        buf.reverse();
    }
    Ok(buf)
}

/// A warning for data after the last element: any byte of a binary file, anything but
/// whitespace in an ascii one.
pub(super) fn trailing_data(src: &mut Source, enc: Encoding) -> Result<Option<String>> {
    let what = src.path.display().to_string();
    let path = src.path;
    if enc == Encoding::Ascii {
        loop {
            let buf = src.r.fill_buf().map_err(|e| Error::io(path, e))?;
            let n = buf.len();
            if n == 0 {
                return Ok(None);
            }
            let nl = |b: &[u8]| b.iter().filter(|&&c| c == b'\n').count() as u64;
            if let Some(i) = buf.iter().position(|b| !b.is_ascii_whitespace()) {
                let line = src.line + nl(&buf[..i]);
                return Ok(Some(format!(
                    "{what}: line {line}: data after the last element ignored"
                )));
            }
            src.line += nl(buf);
            src.r.consume(n);
            src.pos += n as u64;
        }
    }
    let extra = match src.remaining() {
        Some(r) => r,
        None => std::io::copy(&mut src.r, &mut std::io::sink()).map_err(|e| src.io_err(e))?,
    };
    Ok((extra > 0).then(|| format!("{what}: {extra} bytes after the last element ignored")))
}
