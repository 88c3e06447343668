//! Reading LAS and LAZ: header, VLRs and EVLRs checked against the file's size, then the
//! point records as they are stored.

use super::*;

/// The name errors give to LAS read from a stream rather than a file.
const STREAM: &str = "(LAS stream)";

impl LasInput {
    /// Reads a LAS (1.0–1.4) or LAZ file, keeping every point record exactly.
    ///
    /// A file that is not LAS, is truncated, or whose header, VLRs, EVLRs or extra-bytes
    /// description contradict its size gives [`Error::Format`] naming the file.
    pub fn from_path(path: &Path) -> Result<LasInput> {
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        read_from(BufReader::new(file), file_len, path)
    }

    /// Reads LAS or LAZ from memory or any seekable stream, as [`LasInput::from_path`] reads a
    /// file; errors name the input `(LAS stream)`. The LAZ decoder takes the stream over, hence
    /// the `Send + Sync + 'static` bound.
    pub fn new<R: Read + Seek + Send + Sync + 'static>(mut reader: R) -> Result<LasInput> {
        let path = Path::new(STREAM);
        let file_len = reader
            .seek(SeekFrom::End(0))
            .map_err(|e| Error::io(path, e))?;
        seek(&mut reader, 0, path)?;
        read_from(reader, file_len, path)
    }
}

/// What the fixed header says, checked against itself and the file's length.
struct Head {
    raw: ::las::raw::Header,
    format: Format,
    format_id: u8,
    compressed: bool,
    std_len: usize,
    record_len: usize,
    header_size: u64,
    offset_to_points: u64,
    count: u64,
}

/// [`LasInput::from_path`] over `rd`, a stream of `file_len` bytes positioned at its start.
fn read_from<R: Read + Seek + Send + Sync + 'static>(
    mut rd: R,
    file_len: u64,
    path: &Path,
) -> Result<LasInput> {
    let bad = |msg: String| Error::format(path, msg);
    let head = read_head(&mut rd, file_len, path)?;
    let (offset_to_points, count, record_len) =
        (head.offset_to_points, head.count, head.record_len);
    let (mut vlrs, vlr_padding) = read_vlrs(&mut rd, &head, path)?;

    let data_len = count.checked_mul(record_len as u64);
    if !head.compressed {
        let fits = data_len.is_some_and(|l| l <= file_len - offset_to_points);
        if !fits {
            return Err(bad(format!(
                "header says {count} points of {record_len} bytes but the file holds {} after \
                 byte {offset_to_points}",
                (file_len - offset_to_points) / record_len as u64
            )));
        }
    }
    let (mut evlrs, waveform_evlr) = read_evlrs(&mut rd, &head, data_len, file_len, path)?;

    let extra_len = record_len - head.std_len;
    let eb_vlr = vlrs.iter().chain(&evlrs).find(|v| is_extra_bytes_vlr(v));
    let extra = match eb_vlr {
        Some(v) => parse_extra_dims(&v.data, head.std_len, extra_len)
            .map_err(|m| bad(format!("extra-bytes VLR: {m}")))?,
        None => Vec::new(),
    };

    let laszip = vlrs.iter().find(|v| is_laszip_vlr(v));
    let records = match (head.compressed, laszip) {
        (true, None) => {
            return Err(bad(
                "compressed point format but no LASzip VLR describes it".into(),
            ))
        }
        (true, Some(v)) => {
            laz_check::check_layers(&mut rd, path, file_len, offset_to_points, count, &v.data)?;
            read_laz_points(rd, path, file_len, offset_to_points, count, record_len)?
        }
        (false, _) => read_las_points(&mut rd, path, offset_to_points, count, record_len)?,
    };

    let Head {
        raw,
        mut format,
        format_id,
        compressed,
        ..
    } = head;
    let global_encoding = raw.global_encoding;
    let mut builder = Builder::new(raw).map_err(|e| bad(format!("unusable LAS header: {e}")))?;
    vlrs.retain(|v| !is_laszip_vlr(v) && !is_copc(v));
    let waveform_vlr = waveform_evlr.and_then(|i| evlrs.get(i).cloned());
    evlrs.retain(|v| !is_copc(v));
    let waveform_evlr = waveform_vlr.and_then(|w| evlrs.iter().position(|v| *v == w));
    builder.vlrs = vlrs;
    builder.evlrs = evlrs;
    builder.vlr_padding = vlr_padding;
    builder.point_padding = Vec::new();
    format.is_compressed = false;
    builder.point_format = format;
    Ok(LasInput {
        path: path.to_path_buf(),
        builder,
        global_encoding,
        waveform_evlr,
        format,
        format_id,
        compressed,
        record_len,
        records,
        extra,
    })
}

/// Reads and checks the fixed header: version, sizes, point format, scales and offsets.
fn read_head(rd: &mut impl Read, file_len: u64, path: &Path) -> Result<Head> {
    let bad = |msg: String| Error::format(path, msg);
    let raw = ::las::raw::Header::read_from(rd).map_err(|e| match e {
        ::las::Error::InvalidFileSignature(s) => bad(format!(
            "not a LAS file (signature {:?} instead of \"LASF\")",
            String::from_utf8_lossy(&s)
        )),
        ::las::Error::Io(ref io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            bad(format!("truncated LAS header (file is {file_len} bytes)"))
        }
        other => bad(format!("unreadable LAS header: {other}")),
    })?;
    let version = raw.version;
    if version.major != 1 || version.minor > 4 {
        return Err(bad(format!(
            "unsupported LAS version {}.{}",
            version.major, version.minor
        )));
    }
    let header_size = raw.header_size as u64;
    let offset_to_points = raw.offset_to_point_data as u64;
    if header_size < version.header_size() as u64 {
        return Err(bad(format!(
            "header size {header_size} is smaller than LAS {}.{} needs ({})",
            version.major,
            version.minor,
            version.header_size()
        )));
    }
    if offset_to_points < header_size || offset_to_points > file_len {
        return Err(bad(format!(
            "offset to point data {offset_to_points} lies outside the file \
             (header {header_size} bytes, file {file_len} bytes)"
        )));
    }
    let format = Format::new(raw.point_data_record_format).map_err(|_| {
        bad(format!(
            "unknown point format {}",
            raw.point_data_record_format
        ))
    })?;
    let format_id = raw.point_data_record_format & 0x3f;
    let Some(&std_len) = STD_LEN.get(format_id as usize) else {
        return Err(bad(format!("unknown point format {format_id}")));
    };
    let compressed = format.is_compressed;
    #[cfg(not(feature = "laz"))]
    if compressed {
        return Err(bad(NO_LAZ.into()));
    }
    let record_len = raw.point_data_record_length as usize;
    if record_len < std_len {
        return Err(bad(format!(
            "point record length {record_len} is shorter than point format {format_id} needs \
             ({std_len})"
        )));
    }
    check_transforms(&raw, path)?;
    let legacy = raw.number_of_point_records as u64;
    let count = match raw.large_file {
        Some(l) if legacy == 0 => l.number_of_point_records,
        _ => legacy,
    };
    Ok(Head {
        raw,
        format,
        format_id,
        compressed,
        std_len,
        record_len,
        header_size,
        offset_to_points,
        count,
    })
}

/// Scales must be finite and non-zero, offsets finite.
fn check_transforms(raw: &::las::raw::Header, path: &Path) -> Result<()> {
    for (axis, scale, offset) in [
        ("x", raw.x_scale_factor, raw.x_offset),
        ("y", raw.y_scale_factor, raw.y_offset),
        ("z", raw.z_scale_factor, raw.z_offset),
    ] {
        if !(scale.is_finite() && scale != 0.0 && offset.is_finite()) {
            return Err(Error::format(
                path,
                format!("{axis} scale {scale} / offset {offset} is not usable"),
            ));
        }
    }
    Ok(())
}

/// The VLRs between the header and the point data, and the bytes after them.
fn read_vlrs<R: Read + Seek>(rd: &mut R, head: &Head, path: &Path) -> Result<(Vec<Vlr>, Vec<u8>)> {
    let offset_to_points = head.offset_to_points;
    let n_vlrs = head.raw.number_of_variable_length_records;
    let mut vlrs = Vec::new();
    let mut pos = head.header_size;
    seek(rd, pos, path)?;
    for k in 0..n_vlrs {
        let vlr = read_vlr(rd, false, pos, offset_to_points).map_err(|m| {
            Error::format(
                path,
                format!(
                    "VLR {} of {n_vlrs} (at byte {pos}) {m}; the point data starts at byte \
                     {offset_to_points}",
                    k + 1
                ),
            )
        })?;
        pos += VLR_HEADER_LEN + vlr.data.len() as u64;
        vlrs.push(vlr);
    }
    let mut vlr_padding = vec![0u8; (offset_to_points - pos) as usize];
    rd.read_exact(&mut vlr_padding)
        .map_err(|e| Error::io(path, e))?;
    Ok((vlrs, vlr_padding))
}

/// The EVLRs (LAS 1.4) and the waveform packets of LAS 1.3, which follow the point data, with
/// the index among them of the waveform packets.
fn read_evlrs<R: Read + Seek>(
    rd: &mut R,
    head: &Head,
    data_len: Option<u64>,
    file_len: u64,
    path: &Path,
) -> Result<(Vec<Vlr>, Option<usize>)> {
    let bad = |msg: String| Error::format(path, msg);
    let (count, offset_to_points) = (head.count, head.offset_to_points);
    let evlr_info = head.raw.evlr;
    let mut evlrs = Vec::new();
    let mut evlr_pos = Vec::new();
    // Where the EVLRs start says nothing when there are none (writers leave 0 or junk).
    if let Some(e) = evlr_info.filter(|e| e.number_of_evlrs > 0) {
        let mut pos = e.start_of_first_evlr;
        let points_end = offset_to_points + data_len.unwrap_or(0);
        if pos > file_len {
            return Err(bad(format!(
                "the first of {} EVLRs would start at byte {pos}, past the end of the file \
                 ({file_len} bytes)",
                e.number_of_evlrs
            )));
        }
        if !head.compressed && pos < points_end {
            return Err(bad(format!(
                "header says {count} points, whose data would end at byte {points_end}, past \
                 the first EVLR at byte {pos}"
            )));
        }
        seek(rd, pos, path)?;
        for k in 0..e.number_of_evlrs {
            let vlr = read_vlr(rd, true, pos, file_len).map_err(|m| {
                bad(format!(
                    "EVLR {} of {} (at byte {pos}) {m}; the file is {file_len} bytes",
                    k + 1,
                    e.number_of_evlrs
                ))
            })?;
            evlr_pos.push(pos);
            pos += EVLR_HEADER_LEN + vlr.data.len() as u64;
            evlrs.push(vlr);
        }
    }
    let mut waveform_evlr = None;
    let waveform_start = head.raw.start_of_waveform_data_packet_record;
    if let (Some(start), true) = (waveform_start, head.raw.global_encoding & 2 != 0) {
        waveform_evlr = evlr_pos.iter().position(|&p| p == start);
        if waveform_evlr.is_none() && evlr_info.is_none() {
            if start > file_len {
                return Err(bad(format!(
                    "the waveform data packet record would start at byte {start}, past the end \
                     of the file ({file_len} bytes)"
                )));
            }
            seek(rd, start, path)?;
            let vlr = read_vlr(rd, true, start, file_len)
                .map_err(|m| bad(format!("waveform data packet record (at byte {start}) {m}")))?;
            waveform_evlr = Some(evlrs.len());
            evlrs.push(vlr);
        }
    }
    Ok((evlrs, waveform_evlr))
}

/// Reads the `ao` extra dimension of a LAS/LAZ file, located by its extra-bytes description.
pub fn read_ao(path: &Path) -> Result<Vec<f32>> {
    let input = LasInput::from_path(path)?;
    input
        .ao()
        .ok_or_else(|| Error::format(path, "no numeric 'ao' extra-bytes dimension"))
}

pub(super) fn seek<R: Seek>(rd: &mut R, pos: u64, path: &Path) -> Result<()> {
    rd.seek(SeekFrom::Start(pos))
        .map(|_| ())
        .map_err(|e| Error::io(path, e))
}

/// Reads one (E)VLR at `pos` that must end by `limit`, checking its length before allocating.
pub(super) fn read_vlr(
    rd: &mut impl Read,
    extended: bool,
    pos: u64,
    limit: u64,
) -> std::result::Result<Vlr, String> {
    let head_len = if extended {
        EVLR_HEADER_LEN
    } else {
        VLR_HEADER_LEN
    };
    if pos.saturating_add(head_len) > limit {
        return Err("runs past its end (header cut)".into());
    }
    let mut head = [0u8; EVLR_HEADER_LEN as usize];
    let head = &mut head[..head_len as usize];
    rd.read_exact(head).map_err(|e| e.to_string())?;
    let record_id = u16::from_le_bytes([head[18], head[19]]);
    let (len, desc) = if extended {
        (u64::from_le_bytes(bytes8(&head[20..28])), &head[28..60])
    } else {
        (
            u16::from_le_bytes([head[20], head[21]]) as u64,
            &head[22..54],
        )
    };
    if pos + head_len + len > limit {
        return Err(format!("claims {len} bytes of data, more than is left"));
    }
    let mut data = vec![0u8; len as usize];
    rd.read_exact(&mut data).map_err(|e| e.to_string())?;
    Ok(Vlr {
        user_id: c_string(&head[2..18]),
        record_id,
        description: c_string(desc),
        data,
    })
}

/// The first 8 bytes of `b` (which has at least 8) as an array.
fn bytes8(b: &[u8]) -> [u8; 8] {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[..8]);
    a
}

/// A NUL-terminated fixed-size string field.
pub(super) fn c_string(b: &[u8]) -> String {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    String::from_utf8_lossy(&b[..end]).into_owned()
}

pub(super) fn is_extra_bytes_vlr(v: &Vlr) -> bool {
    v.user_id == LASF_SPEC && v.record_id == EXTRA_BYTES_RECORD
}

pub(super) fn is_laszip_vlr(v: &Vlr) -> bool {
    v.user_id == "laszip encoded" && v.record_id == 22204
}

/// COPC info and hierarchy records: they index chunk offsets, which a rewrite changes.
pub(super) fn is_copc(v: &Vlr) -> bool {
    v.user_id == "copc"
}

/// Size in bytes of an extra-bytes value of `data_type` (`options` sizes type 0).
pub(super) fn extra_size(data_type: u8, options: u8) -> Option<usize> {
    const BASE: [usize; 10] = [1, 1, 2, 2, 4, 4, 8, 8, 4, 8];
    match data_type {
        0 => Some(options as usize),
        1..=10 => Some(BASE[data_type as usize - 1]),
        11..=20 => Some(2 * BASE[data_type as usize - 11]),
        21..=30 => Some(3 * BASE[data_type as usize - 21]),
        _ => None,
    }
}

/// The dimensions an extra-bytes VLR describes, laid out from `std_len` in that order.
pub(super) fn parse_extra_dims(
    data: &[u8],
    std_len: usize,
    extra_len: usize,
) -> std::result::Result<Vec<ExtraDim>, String> {
    if data.len() % DESCRIPTOR_LEN != 0 {
        return Err(format!(
            "length {} is not a multiple of {DESCRIPTOR_LEN}",
            data.len()
        ));
    }
    let mut at = 0;
    let mut dims = Vec::new();
    for (k, d) in data.chunks_exact(DESCRIPTOR_LEN).enumerate() {
        let (data_type, options) = (d[2], d[3]);
        let size = extra_size(data_type, options)
            .ok_or_else(|| format!("dimension {} has unknown data type {data_type}", k + 1))?;
        let f = |o: usize| f64::from_le_bytes(bytes8(&d[o..o + 8]));
        let scalar = (1..=10).contains(&data_type);
        dims.push(ExtraDim {
            name: c_string(&d[4..36]),
            data_type,
            offset: std_len + at,
            size,
            scale: (scalar && options & 8 != 0).then(|| f(112)),
            value_offset: (scalar && options & 16 != 0).then(|| f(136)),
        });
        at += size;
    }
    if at > extra_len {
        return Err(format!(
            "describes {at} bytes but each record has {extra_len} extra bytes"
        ));
    }
    Ok(dims)
}

/// The point records of an uncompressed file (the caller checked that `count · record_len`
/// bytes follow `offset`).
pub(super) fn read_las_points<R: Read + Seek>(
    rd: &mut R,
    path: &Path,
    offset: u64,
    count: u64,
    record_len: usize,
) -> Result<Vec<u8>> {
    seek(rd, offset, path)?;
    let mut records = vec![0u8; count as usize * record_len];
    rd.read_exact(&mut records)
        .map_err(|e| Error::io(path, e))?;
    Ok(records)
}

#[cfg(not(feature = "laz"))]
pub(super) fn read_laz_points<R>(
    _rd: R,
    path: &Path,
    _file_len: u64,
    _offset: u64,
    _count: u64,
    _record_len: usize,
) -> Result<Vec<u8>> {
    Err(Error::format(path, NO_LAZ))
}

/// The point records of a LAZ file, decoded.
#[cfg(feature = "laz")]
pub(super) fn read_laz_points<R: Read + Seek + Send + Sync + 'static>(
    mut rd: R,
    path: &Path,
    file_len: u64,
    offset: u64,
    count: u64,
    record_len: usize,
) -> Result<Vec<u8>> {
    check_chunk_table(&mut rd, file_len, offset, path)?;
    seek(&mut rd, 0, path)?;
    let decode = move || -> Result<Vec<u8>> {
        let mut reader = ::las::Reader::new(rd)
            .map_err(|e| Error::format(path, format!("unreadable LAZ: {e}")))?;
        let mut batch = PointDataBuilder::new().for_header(reader.header()).build();
        // Grow with what was really decoded: the header's count is not trusted for memory.
        let mut records = Vec::with_capacity(
            (count.saturating_mul(record_len as u64)).min(file_len.saturating_mul(8)) as usize,
        );
        let mut done = 0u64;
        while done < count {
            // A batch is bounded in bytes too: the record length comes from the header, and
            // the decoder allocates a whole batch before decoding it.
            let per_batch = (BATCH_BYTES / record_len.max(1)).clamp(1, BATCH);
            let n = reader
                .fill_points(per_batch as u64, &mut batch)
                .map_err(|e| {
                    Error::format(
                        path,
                        format!("corrupt or truncated LAZ data after point {done} of {count}: {e}"),
                    )
                })?;
            if n == 0 {
                break;
            }
            records.extend_from_slice(batch.raw_bytes());
            done += n;
        }
        if done < count {
            return Err(Error::format(
                path,
                format!("header says {count} points but the LAZ data holds {done}"),
            ));
        }
        Ok(records)
    };
    // The LAZ decoder is third-party code fed with file bytes: a corrupt stream must become
    // an error, not abort the run.
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(decode)).unwrap_or_else(|_| {
        Err(Error::format(
            path,
            "corrupt LAZ data (the decompressor failed)",
        ))
    })
}

/// Rejects a chunk table whose entry count could not fit in the file, before the LAZ decoder
/// allocates for it.
#[cfg(feature = "laz")]
pub(super) fn check_chunk_table<R: Read + Seek>(
    f: &mut R,
    file_len: u64,
    offset: u64,
    path: &Path,
) -> Result<()> {
    let mut read_i64_at = |at: u64| -> Option<i64> {
        let mut b = [0u8; 8];
        f.seek(SeekFrom::Start(at)).ok()?;
        f.read_exact(&mut b).ok()?;
        Some(i64::from_le_bytes(b))
    };
    let valid = |t: i64| t > offset as i64 && (t as u64).saturating_add(8) <= file_len;
    let table = match read_i64_at(offset) {
        Some(t) if valid(t) => Some(t),
        // A writer that could not seek back stores the offset in the last 8 bytes.
        _ => read_i64_at(file_len.saturating_sub(8)).filter(|&t| valid(t)),
    };
    if let Some(t) = table {
        if let Some(v) = read_i64_at(t as u64) {
            let chunks = (v as u64) >> 32;
            if chunks > file_len {
                return Err(Error::format(
                    path,
                    format!("corrupt LAZ chunk table ({chunks} chunks in a {file_len}-byte file)"),
                ));
            }
        }
    }
    Ok(())
}
