//! Reading LAS and LAZ: header, VLRs and EVLRs checked against the file's size, then the
//! point records as they are stored.

use super::*;

/// Reads a LAS (1.0–1.4) or LAZ file, keeping every point record exactly.
///
/// A file that is not LAS, is truncated, or whose header, VLRs, EVLRs or extra-bytes
/// description contradict its size gives [`Error::Format`] naming the file.
pub fn read_las(path: &Path) -> Result<LasInput> {
    let bad = |msg: String| Error::format(path, msg);
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut rd = BufReader::new(file);
    let raw = ::las::raw::Header::read_from(&mut rd).map_err(|e| match e {
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
    let mut format = Format::new(raw.point_data_record_format).map_err(|_| {
        bad(format!(
            "unknown point format {}",
            raw.point_data_record_format
        ))
    })?;
    let format_id = raw.point_data_record_format & 0x3f;
    if format_id as usize >= STD_LEN.len() {
        return Err(bad(format!("unknown point format {format_id}")));
    }
    let compressed = format.is_compressed;
    #[cfg(not(feature = "laz"))]
    if compressed {
        return Err(bad(NO_LAZ.into()));
    }
    let std_len = STD_LEN[format_id as usize];
    let record_len = raw.point_data_record_length as usize;
    if record_len < std_len {
        return Err(bad(format!(
            "point record length {record_len} is shorter than point format {format_id} needs \
             ({std_len})"
        )));
    }
    let transforms = Vector {
        x: Transform {
            scale: raw.x_scale_factor,
            offset: raw.x_offset,
        },
        y: Transform {
            scale: raw.y_scale_factor,
            offset: raw.y_offset,
        },
        z: Transform {
            scale: raw.z_scale_factor,
            offset: raw.z_offset,
        },
    };
    for (axis, t) in [
        ("x", transforms.x),
        ("y", transforms.y),
        ("z", transforms.z),
    ] {
        if !(t.scale.is_finite() && t.scale != 0.0 && t.offset.is_finite()) {
            return Err(bad(format!(
                "{axis} scale {} / offset {} is not usable",
                t.scale, t.offset
            )));
        }
    }
    let legacy = raw.number_of_point_records as u64;
    let count = match raw.large_file {
        Some(l) if legacy == 0 => l.number_of_point_records,
        _ => legacy,
    };
    let global_encoding = raw.global_encoding;
    let waveform_start = raw.start_of_waveform_data_packet_record;
    let evlr_info = raw.evlr;
    let n_vlrs = raw.number_of_variable_length_records;

    // VLRs lie between the header and the point data.
    let mut vlrs = Vec::new();
    let mut pos = header_size;
    seek(&mut rd, pos, path)?;
    for k in 0..n_vlrs {
        let vlr = read_vlr(&mut rd, false, pos, offset_to_points).map_err(|m| {
            bad(format!(
                "VLR {} of {n_vlrs} (at byte {pos}) {m}; the point data starts at byte \
                 {offset_to_points}",
                k + 1
            ))
        })?;
        pos += VLR_HEADER_LEN + vlr.data.len() as u64;
        vlrs.push(vlr);
    }
    let mut vlr_padding = vec![0u8; (offset_to_points - pos) as usize];
    rd.read_exact(&mut vlr_padding)
        .map_err(|e| Error::io(path, e))?;

    let data_len = count.checked_mul(record_len as u64);
    if !compressed {
        let fits = data_len.is_some_and(|l| l <= file_len - offset_to_points);
        if !fits {
            return Err(bad(format!(
                "header says {count} points of {record_len} bytes but the file holds {} after \
                 byte {offset_to_points}",
                (file_len - offset_to_points) / record_len as u64
            )));
        }
    }

    // EVLRs (LAS 1.4), and the waveform packets of LAS 1.3, follow the point data.
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
        if !compressed && pos < points_end {
            return Err(bad(format!(
                "header says {count} points, whose data would end at byte {points_end}, past \
                 the first EVLR at byte {pos}"
            )));
        }
        seek(&mut rd, pos, path)?;
        for k in 0..e.number_of_evlrs {
            let vlr = read_vlr(&mut rd, true, pos, file_len).map_err(|m| {
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
    if let (Some(start), true) = (waveform_start, global_encoding & 2 != 0) {
        waveform_evlr = evlr_pos.iter().position(|&p| p == start);
        if waveform_evlr.is_none() && evlr_info.is_none() {
            if start > file_len {
                return Err(bad(format!(
                    "the waveform data packet record would start at byte {start}, past the end \
                     of the file ({file_len} bytes)"
                )));
            }
            seek(&mut rd, start, path)?;
            let vlr = read_vlr(&mut rd, true, start, file_len)
                .map_err(|m| bad(format!("waveform data packet record (at byte {start}) {m}")))?;
            waveform_evlr = Some(evlrs.len());
            evlrs.push(vlr);
        }
    }
    drop(rd);

    let extra_len = record_len - std_len;
    let eb_vlr = vlrs.iter().chain(&evlrs).find(|v| is_extra_bytes_vlr(v));
    let extra = match eb_vlr {
        Some(v) => parse_extra_dims(&v.data, std_len, extra_len)
            .map_err(|m| bad(format!("extra-bytes VLR: {m}")))?,
        None => Vec::new(),
    };

    let laszip = vlrs.iter().position(is_laszip_vlr);
    if compressed && laszip.is_none() {
        return Err(bad(
            "compressed point format but no LASzip VLR describes it".into(),
        ));
    }
    let records = if compressed {
        if let Some(v) = laszip.map(|i| &vlrs[i]) {
            laz_check::check_layers(path, file_len, offset_to_points, count, &v.data)?;
        }
        read_laz_points(path, file_len, offset_to_points, count, record_len)?
    } else {
        read_las_points(path, offset_to_points, count, record_len)?
    };

    let mut builder = Builder::new(raw).map_err(|e| bad(format!("unusable LAS header: {e}")))?;
    vlrs.retain(|v| !is_laszip_vlr(v) && !is_copc(v));
    let waveform_vlr = waveform_evlr.map(|i| evlrs[i].clone());
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

/// Reads the `ao` extra dimension of a LAS/LAZ file, located by its extra-bytes description.
pub fn read_ao(path: &Path) -> Result<Vec<f32>> {
    let input = read_las(path)?;
    input
        .ao()
        .ok_or_else(|| Error::format(path, "no numeric 'ao' extra-bytes dimension"))
}

pub(super) fn seek(rd: &mut BufReader<File>, pos: u64, path: &Path) -> Result<()> {
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
        (
            u64::from_le_bytes(head[20..28].try_into().expect("8 bytes")),
            &head[28..60],
        )
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
        let f = |o: usize| f64::from_le_bytes(d[o..o + 8].try_into().expect("8 bytes"));
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

pub(super) fn read_las_points(
    path: &Path,
    offset: u64,
    count: u64,
    record_len: usize,
) -> Result<Vec<u8>> {
    // The caller checked that count · record_len bytes follow `offset`.
    let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
    file.seek(SeekFrom::Start(offset))
        .map_err(|e| Error::io(path, e))?;
    let mut records = vec![0u8; count as usize * record_len];
    file.read_exact(&mut records)
        .map_err(|e| Error::io(path, e))?;
    Ok(records)
}

#[cfg(not(feature = "laz"))]
pub(super) fn read_laz_points(
    path: &Path,
    _file_len: u64,
    _offset: u64,
    _count: u64,
    _record_len: usize,
) -> Result<Vec<u8>> {
    Err(Error::format(path, NO_LAZ))
}

#[cfg(feature = "laz")]
pub(super) fn read_laz_points(
    path: &Path,
    file_len: u64,
    offset: u64,
    count: u64,
    record_len: usize,
) -> Result<Vec<u8>> {
    check_chunk_table(path, file_len, offset)?;
    let decode = || -> Result<Vec<u8>> {
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        let mut reader = ::las::Reader::new(BufReader::new(file))
            .map_err(|e| Error::format(path, format!("unreadable LAZ: {e}")))?;
        let mut batch = PointDataBuilder::new().for_header(reader.header()).build();
        // Grow with what was really decoded: the header's count is not trusted for memory.
        let mut records = Vec::with_capacity(
            (count.saturating_mul(record_len as u64)).min(file_len.saturating_mul(8)) as usize,
        );
        let mut done = 0u64;
        while done < count {
            let n = reader.fill_points(BATCH as u64, &mut batch).map_err(|e| {
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
pub(super) fn check_chunk_table(path: &Path, file_len: u64, offset: u64) -> Result<()> {
    let mut f = File::open(path).map_err(|e| Error::io(path, e))?;
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
