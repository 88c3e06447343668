//! LAS and LAZ (compressed LAS) in and out.
//!
//! A file is read into its raw point records (decompressed when LAZ) and everything around
//! them: header fields, VLRs, every EVLR, and the extra-bytes descriptions. A result written
//! with [`write_las`] copies each record byte for byte (coordinates stay the same scaled
//! integers under the same scale and offset), adds or recolours RGB, and stores the AO as an
//! `ao` extra-bytes dimension (float, described in the LAS 1.4 extra-bytes VLR) so CloudCompare,
//! PDAL and laspy show it as a scalar field.
//!
//! Output version: the input's when it can hold the output point format and the EVLRs,
//! otherwise 1.4. A format without colour becomes its colour sibling (0→2, 1→3, 4→5, 6→7,
//! 9→10), so LAS 1.0/1.1 inputs of format 0/1 and LAS 1.2 inputs of format 4 come out as
//! LAS 1.4. The extra-bytes VLR is kept in every version, as PDAL, LAStools and laspy read it.
//!
//! Not carried over: COPC index records (the output is re-chunked, so they would lie) and the
//! LASzip VLR of a compressed input (a new one describes the output). External waveform data
//! (`.wdp`) is referenced, not copied.

use crate::io::atomic::write_atomic_file;
use crate::io::output::{grey, ColorMode};
use crate::io::raw::{PointTable, RawScan};
mod laz_check;

use crate::error::{Error, Result};
use ::las::point::Format;
use ::las::{Builder, Header, PointDataBuilder, Transform, Vector, Version, Vlr, Writer};
use glam::Vec3;
use rayon::prelude::*;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// User id of the extra-bytes VLR (and of the waveform records).
const LASF_SPEC: &str = "LASF_Spec";
/// Record id of the extra-bytes VLR.
const EXTRA_BYTES_RECORD: u16 = 4;
/// Size of one extra-bytes descriptor.
const DESCRIPTOR_LEN: usize = 192;
/// Name of the AO dimension.
const AO_NAME: &str = "ao";
/// Description of the AO dimension (at most 32 bytes).
const AO_DESCRIPTION: &str = "ambient occlusion, 1 = open";
/// Message for compressed data in a build without LAZ.
#[cfg(not(feature = "laz"))]
const NO_LAZ: &str = "LAZ support not compiled in (build with --features laz)";
/// Record length of the standard part of each point format, 0 to 10.
const STD_LEN: [usize; 11] = [20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67];
/// Points per batch when decoding LAZ and when writing.
const BATCH: usize = 1 << 16;
/// Global-encoding bits of waveform data: 1 internal, 2 external.
const WAVEFORM_BITS: u16 = 0b110;
/// Size of an EVLR header.
const EVLR_HEADER_LEN: u64 = 60;
/// Size of a VLR header.
const VLR_HEADER_LEN: u64 = 54;

/// One dimension of the extra bytes, as the extra-bytes VLR describes it.
#[derive(Debug, Clone, PartialEq)]
pub struct ExtraDim {
    /// Name (at most 32 bytes in the file).
    pub name: String,
    /// LAS data type: 0 undocumented bytes, 1–10 u8, i8, u16, i16, u32, i32, u64, i64, f32,
    /// f64; 11–30 the deprecated 2- and 3-element arrays.
    pub data_type: u8,
    /// Byte offset of the value inside a point record.
    pub offset: usize,
    /// Size in bytes.
    pub size: usize,
    /// Scale applied to the stored value, when the descriptor sets one.
    pub scale: Option<f64>,
    /// Offset added after the scale, when the descriptor sets one.
    pub value_offset: Option<f64>,
}

impl ExtraDim {
    /// The value of this dimension in `record` (scale and offset applied), for the scalar
    /// types 1–10; `None` for undocumented bytes and arrays.
    pub fn value(&self, record: &[u8]) -> Option<f64> {
        let b = record.get(self.offset..self.offset + self.size)?;
        let raw = match self.data_type {
            1 => b[0] as f64,
            2 => b[0] as i8 as f64,
            3 => u16::from_le_bytes([b[0], b[1]]) as f64,
            4 => i16::from_le_bytes([b[0], b[1]]) as f64,
            5 => u32::from_le_bytes(b.try_into().ok()?) as f64,
            6 => i32::from_le_bytes(b.try_into().ok()?) as f64,
            7 => u64::from_le_bytes(b.try_into().ok()?) as f64,
            8 => i64::from_le_bytes(b.try_into().ok()?) as f64,
            9 => f32::from_le_bytes(b.try_into().ok()?) as f64,
            10 => f64::from_le_bytes(b.try_into().ok()?),
            _ => return None,
        };
        Some(raw * self.scale.unwrap_or(1.0) + self.value_offset.unwrap_or(0.0))
    }
}

/// A LAS or LAZ file in memory: raw point records and the header, VLRs and EVLRs around them.
pub struct LasInput {
    path: PathBuf,
    /// Header fields, VLRs (without the LASzip and COPC ones), EVLRs and VLR padding, as read.
    builder: Builder,
    /// The input's global-encoding bits (the las crate drops the waveform ones).
    global_encoding: u16,
    /// Index in `builder.evlrs` of the internal waveform data packets.
    waveform_evlr: Option<usize>,
    /// Uncompressed point format, with the extra-byte count.
    format: Format,
    /// Point format number, 0–10.
    format_id: u8,
    compressed: bool,
    record_len: usize,
    records: Vec<u8>,
    extra: Vec<ExtraDim>,
}

impl std::fmt::Debug for LasInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LasInput")
            .field("path", &self.path)
            .field("version", &self.builder.version)
            .field("format", &self.format_id)
            .field("compressed", &self.compressed)
            .field("points", &self.len())
            .field("extra", &self.extra)
            .finish()
    }
}

impl LasInput {
    /// The file this was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Number of point records.
    pub fn len(&self) -> usize {
        self.records.len() / self.record_len
    }

    /// True when the file has no point.
    pub fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    /// LAS version as `(major, minor)`.
    pub fn version(&self) -> (u8, u8) {
        (self.builder.version.major, self.builder.version.minor)
    }

    /// Point data record format, 0–10.
    pub fn point_format(&self) -> u8 {
        self.format_id
    }

    /// True when the file was LAZ.
    pub fn is_compressed(&self) -> bool {
        self.compressed
    }

    /// True when the point format has RGB.
    pub fn has_color(&self) -> bool {
        self.format.has_color
    }

    /// The extra-bytes dimensions the file describes.
    pub fn extra_dims(&self) -> &[ExtraDim] {
        &self.extra
    }

    /// The VLRs kept for output (the LASzip and COPC ones are dropped on reading).
    pub fn vlrs(&self) -> &[Vlr] {
        &self.builder.vlrs
    }

    /// Every EVLR, including a LAS 1.3 waveform data packet record.
    pub fn evlrs(&self) -> &[Vlr] {
        &self.builder.evlrs
    }

    /// Bytes per point record.
    pub fn record_len(&self) -> usize {
        self.record_len
    }

    /// The uncompressed point records, `record_len()` bytes each, as in the file.
    pub fn records(&self) -> &[u8] {
        &self.records
    }

    /// Scale and offset of X, Y, Z: world = offset + scale · stored integer.
    pub fn scale_offset(&self) -> ([f64; 3], [f64; 3]) {
        let t = &self.builder.transforms;
        (
            [t.x.scale, t.y.scale, t.z.scale],
            [t.x.offset, t.y.offset, t.z.offset],
        )
    }

    /// The points as a [`RawScan`]: world coordinates (f64), normals when the file has
    /// `nx/ny/nz`, `normal_x/…` or `NormalX/…` extra dimensions; no pose, scanner position or
    /// grid, as LAS records none.
    pub fn raw_scan(&self, name: &str) -> RawScan {
        let t = self.builder.transforms;
        let xyz = self
            .records
            .par_chunks_exact(self.record_len)
            .map(|r| {
                [
                    t.x.direct(i32_at(r, 0)),
                    t.y.direct(i32_at(r, 4)),
                    t.z.direct(i32_at(r, 8)),
                ]
            })
            .collect();
        RawScan {
            name: name.to_string(),
            xyz,
            normals: self.normals(),
            grid: None,
            pose: None,
            scanner: None,
            sensor_hint: None,
            warnings: Vec::new(),
        }
    }

    /// Normals from extra dimensions, when all three components are there.
    fn normals(&self) -> Option<Vec<Vec3>> {
        const NAMES: [[&str; 3]; 3] = [
            ["nx", "ny", "nz"],
            ["normal_x", "normal_y", "normal_z"],
            ["normalx", "normaly", "normalz"],
        ];
        let find = |n: &str| {
            self.extra
                .iter()
                .find(|d| d.name.eq_ignore_ascii_case(n) && (1..=10).contains(&d.data_type))
        };
        let dims = NAMES
            .iter()
            .find_map(|names| Some([find(names[0])?, find(names[1])?, find(names[2])?]))?;
        Some(
            self.records
                .par_chunks_exact(self.record_len)
                .map(|r| {
                    let c = |d: &ExtraDim| d.value(r).unwrap_or(f64::NAN) as f32;
                    // An unusable normal becomes zero and is re-estimated downstream.
                    Vec3::new(c(dims[0]), c(dims[1]), c(dims[2]))
                        .try_normalize()
                        .unwrap_or(Vec3::ZERO)
                })
                .collect(),
        )
    }

    /// Point source id of every record; `None` when all are 0 (the field is unused).
    pub fn point_source_ids(&self) -> Option<Vec<u16>> {
        let at = if self.format.is_extended { 20 } else { 18 };
        let ids: Vec<u16> = self
            .records
            .par_chunks_exact(self.record_len)
            .map(|r| u16::from_le_bytes([r[at], r[at + 1]]))
            .collect();
        ids.iter().any(|&i| i != 0).then_some(ids)
    }

    /// Scan angle of every record in degrees (the legacy rank, or the 0.006° steps of formats
    /// 6–10); `None` when all are 0 (the field is unused).
    pub fn scan_angles(&self) -> Option<Vec<f32>> {
        let extended = self.format.is_extended;
        let angles: Vec<f32> = self
            .records
            .par_chunks_exact(self.record_len)
            .map(|r| {
                if extended {
                    i16::from_le_bytes([r[18], r[19]]) as f32 * 0.006
                } else {
                    r[16] as i8 as f32
                }
            })
            .collect();
        angles.iter().any(|&a| a != 0.0).then_some(angles)
    }

    /// Intensity of every record scaled to [0, 1] (the 16-bit value / 65535), for a
    /// [`PointTable`] when writing another format.
    pub fn intensities(&self) -> Vec<f32> {
        self.records
            .par_chunks_exact(self.record_len)
            .map(|r| u16::from_le_bytes([r[12], r[13]]) as f32 / 65535.0)
            .collect()
    }

    /// RGB of every record in 8 bits, when the format has colour. Files whose values all fit
    /// in 0–255 stored 8-bit colour in the 16-bit fields (a common habit) and are taken as
    /// they are; otherwise the high byte is kept.
    pub fn rgb8(&self) -> Option<Vec<[u8; 3]>> {
        let at = rgb_offset(self.format_id)?;
        let rgb16: Vec<[u16; 3]> = self
            .records
            .par_chunks_exact(self.record_len)
            .map(|r| [0, 1, 2].map(|c| u16::from_le_bytes([r[at + 2 * c], r[at + 2 * c + 1]])))
            .collect();
        let wide = rgb16.par_iter().any(|c| c.iter().any(|&v| v > 255));
        let shift = if wide { 8 } else { 0 };
        Some(
            rgb16
                .iter()
                .map(|c| c.map(|v| (v >> shift) as u8))
                .collect(),
        )
    }

    /// Every scalar extra dimension (types 1–10, scale and offset applied) as a named column,
    /// `ao` excluded, for [`PointTable::extra`] when writing another format.
    pub fn extra_columns(&self) -> Vec<(String, Vec<f64>)> {
        self.extra
            .iter()
            .filter(|d| (1..=10).contains(&d.data_type) && d.name != AO_NAME)
            .map(|d| {
                let values = self
                    .records
                    .par_chunks_exact(self.record_len)
                    .map(|r| d.value(r).unwrap_or(f64::NAN))
                    .collect();
                (d.name.clone(), values)
            })
            .collect()
    }

    /// The `ao` values of every record, when the file has an `ao` extra dimension.
    pub fn ao(&self) -> Option<Vec<f32>> {
        let dim = self.extra.iter().find(|d| d.name == AO_NAME)?;
        if !(1..=10).contains(&dim.data_type) {
            return None;
        }
        Some(
            self.records
                .par_chunks_exact(self.record_len)
                .map(|r| dim.value(r).unwrap_or(f64::NAN) as f32)
                .collect(),
        )
    }
}

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

fn seek(rd: &mut BufReader<File>, pos: u64, path: &Path) -> Result<()> {
    rd.seek(SeekFrom::Start(pos))
        .map(|_| ())
        .map_err(|e| Error::io(path, e))
}

#[inline]
fn i32_at(r: &[u8], at: usize) -> i32 {
    i32::from_le_bytes([r[at], r[at + 1], r[at + 2], r[at + 3]])
}

/// Reads one (E)VLR at `pos` that must end by `limit`, checking its length before allocating.
fn read_vlr(
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
fn c_string(b: &[u8]) -> String {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    String::from_utf8_lossy(&b[..end]).into_owned()
}

fn is_extra_bytes_vlr(v: &Vlr) -> bool {
    v.user_id == LASF_SPEC && v.record_id == EXTRA_BYTES_RECORD
}

fn is_laszip_vlr(v: &Vlr) -> bool {
    v.user_id == "laszip encoded" && v.record_id == 22204
}

/// COPC info and hierarchy records: they index chunk offsets, which a rewrite changes.
fn is_copc(v: &Vlr) -> bool {
    v.user_id == "copc"
}

/// Size in bytes of an extra-bytes value of `data_type` (`options` sizes type 0).
fn extra_size(data_type: u8, options: u8) -> Option<usize> {
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
fn parse_extra_dims(
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

fn read_las_points(path: &Path, offset: u64, count: u64, record_len: usize) -> Result<Vec<u8>> {
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
fn read_laz_points(
    path: &Path,
    _file_len: u64,
    _offset: u64,
    _count: u64,
    _record_len: usize,
) -> Result<Vec<u8>> {
    Err(Error::format(path, NO_LAZ))
}

#[cfg(feature = "laz")]
fn read_laz_points(
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
fn check_chunk_table(path: &Path, file_len: u64, offset: u64) -> Result<()> {
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

/// What happens to RGB in a record.
#[derive(Clone, Copy)]
enum Paint {
    /// The input had no colour: grey.
    Grey,
    /// The input's colour stays.
    Keep,
    /// Grey replaces the colour.
    Replace,
    /// Colour × grey.
    Modulate,
}

/// Storage type of the `ao` dimension.
#[derive(Clone, Copy, PartialEq)]
enum AoType {
    F32,
    F64,
}

/// Writes `input`'s points with every original field unchanged, plus the AO (one finite value
/// per point) as an `ao` float extra-bytes dimension and RGB by `color` (grey `ao^(1/gamma)`
/// scaled to 16 bits; formats without colour gain it). An existing `ao` dimension is
/// overwritten. The header keeps scale, offset, VLRs, EVLRs and system identifier; the
/// generating software becomes `mvao <version>`. `compress` writes LAZ. Atomic.
pub fn write_las(
    input: &LasInput,
    ao: &[f32],
    gamma: f32,
    color: ColorMode,
    out: &Path,
    compress: bool,
) -> Result<()> {
    check_ao(ao, input.len(), out)?;
    check_compress(compress, out)?;
    let out_id = match input.format_id {
        0 => 2,
        1 => 3,
        4 => 5,
        6 => 7,
        9 => 10,
        id => id,
    };
    let in_std = STD_LEN[input.format_id as usize];
    let out_std = STD_LEN[out_id as usize];
    let in_extra = input.record_len - in_std;
    let paint = match (input.format.has_color, color) {
        (false, _) => Paint::Grey,
        (true, ColorMode::Keep) => Paint::Keep,
        (true, ColorMode::Replace) => Paint::Replace,
        (true, ColorMode::Modulate) => Paint::Modulate,
    };
    // RGB goes where the output format has it; formats without colour get it inserted there.
    let rgb_at = rgb_offset(out_id).expect("output format has colour");
    let (insert_at, insert_len) = if out_id != input.format_id {
        (rgb_at, out_std - in_std)
    } else {
        (input.record_len, 0)
    };
    let mut vlrs = input.builder.vlrs.clone();
    let mut evlrs = input.builder.evlrs.clone();
    let existing = input.extra.iter().find(|d| d.name == AO_NAME);
    let (ao_at, ao_type, out_extra) = match existing {
        Some(d) if d.data_type == 9 && d.scale.is_none() && d.value_offset.is_none() => {
            (d.offset + insert_len, AoType::F32, in_extra)
        }
        Some(d) if d.data_type == 10 && d.scale.is_none() && d.value_offset.is_none() => {
            (d.offset + insert_len, AoType::F64, in_extra)
        }
        Some(d) => {
            return Err(Error::format(
                &input.path,
                format!(
                    "has an extra dimension 'ao' of data type {} (scaled or not a float): \
                     rename it before writing a new 'ao'",
                    d.data_type
                ),
            ))
        }
        None => {
            let documented: usize = input.extra.iter().map(|d| d.size).sum();
            let mut data = Vec::new();
            // Undocumented extra bytes keep their place: describe them so 'ao' lands after.
            let mut gap = in_extra - documented;
            let mut k = 0;
            while gap > 0 {
                let n = gap.min(255);
                data.extend(descriptor(
                    &format!("undocumented_{k}"),
                    0,
                    n as u8,
                    "",
                    None,
                ));
                gap -= n;
                k += 1;
            }
            data.extend(descriptor(AO_NAME, 9, 0, AO_DESCRIPTION, Some((0.0, 1.0))));
            let found = vlrs
                .iter_mut()
                .chain(evlrs.iter_mut())
                .find(|v| is_extra_bytes_vlr(v));
            match found {
                Some(v) => v.data.extend(data),
                None => vlrs.push(extra_bytes_vlr(data)),
            }
            (out_std + in_extra, AoType::F32, in_extra + 4)
        }
    };
    let mut format = Format::new(out_id).expect("format 0-10");
    format.extra_bytes = out_extra as u16;
    format.is_compressed = compress;

    let mut builder = input.builder.clone();
    builder.vlrs = vlrs;
    builder.evlrs = evlrs;
    builder.point_format = format;
    builder.generating_software = software();
    builder.system_identifier = las_ascii(&builder.system_identifier, 32);
    for v in builder.vlrs.iter_mut().chain(builder.evlrs.iter_mut()) {
        v.user_id = las_ascii(&v.user_id, 16);
        v.description = las_ascii(&v.description, 32);
    }
    let v = builder.version;
    // Legacy records hold return numbers up to 7, but before LAS 1.4 the header counts
    // points by return for 1–5 only.
    let high_returns = !input.format.is_extended
        && input
            .records
            .par_chunks_exact(input.record_len.max(1))
            .any(|r| r.len() > 14 && r[14] & 7 > 5);
    let large = v.supports::<::las::feature::LargeFiles>();
    let fits = v.supports_point_format(format)
        && (builder.evlrs.is_empty() || v.supports::<::las::feature::Evlrs>())
        && (input.len() as u64 <= u32::MAX as u64 || large)
        && (!high_returns || large);
    let header = if fits {
        builder.clone().into_header().ok()
    } else {
        None
    };
    let header = match header {
        Some(h) => h,
        None => {
            if v == Version::new(1, 0) && builder.vlr_padding.ends_with(&[0xCC, 0xDD]) {
                // The point-data start signature belongs to LAS 1.0 only.
                let n = builder.vlr_padding.len();
                builder.vlr_padding.truncate(n - 2);
            }
            builder.version = Version::new(1, 4);
            builder
                .into_header()
                .map_err(|e| write_error(out, format!("cannot build the LAS header: {e}")))?
        }
    };
    let waveform = WaveformPatch {
        bits: if format.has_waveform {
            input.global_encoding & WAVEFORM_BITS
        } else {
            0
        },
        evlr: input.waveform_evlr.filter(|_| format.has_waveform),
    };

    let out_len = format.len() as usize;
    let in_len = input.record_len;
    let fill = |dst: &mut [u8], first: usize| {
        let n = dst.len() / out_len;
        let src = &input.records[first * in_len..(first + n) * in_len];
        dst.par_chunks_exact_mut(out_len)
            .zip(src.par_chunks_exact(in_len))
            .zip(&ao[first..first + n])
            .for_each(|((o, i), &a)| {
                o[..insert_at].copy_from_slice(&i[..insert_at]);
                o[insert_at..insert_at + insert_len].fill(0);
                o[insert_at + insert_len..insert_len + in_len].copy_from_slice(&i[insert_at..]);
                let g = grey(a, gamma) as u16;
                for c in 0..3 {
                    let at = rgb_at + 2 * c;
                    let old = u16::from_le_bytes([o[at], o[at + 1]]);
                    let new = match paint {
                        Paint::Keep => old,
                        Paint::Grey | Paint::Replace => g * 257,
                        Paint::Modulate => ((old as u32 * g as u32 + 127) / 255) as u16,
                    };
                    o[at..at + 2].copy_from_slice(&new.to_le_bytes());
                }
                match ao_type {
                    AoType::F32 => o[ao_at..ao_at + 4].copy_from_slice(&a.to_le_bytes()),
                    AoType::F64 => o[ao_at..ao_at + 8].copy_from_slice(&(a as f64).to_le_bytes()),
                }
            });
    };
    write_points(out, header, input.len(), fill, waveform)
}

/// Where the RGB of a point format starts.
fn rgb_offset(id: u8) -> Option<usize> {
    match id {
        2 => Some(20),
        3 | 5 => Some(28),
        7 | 8 | 10 => Some(30),
        _ => None,
    }
}

fn software() -> String {
    format!("mvao {}", env!("CARGO_PKG_VERSION"))
}

/// `s` as the las crate can write it: ASCII, at most `max` bytes.
fn las_ascii(s: &str, max: usize) -> String {
    s.chars()
        .map(|c| if c.is_ascii() { c } else { '?' })
        .take(max)
        .collect()
}

/// One extra-bytes descriptor; `min_max` is stored as doubles, as for float types.
fn descriptor(
    name: &str,
    data_type: u8,
    options: u8,
    description: &str,
    min_max: Option<(f64, f64)>,
) -> [u8; DESCRIPTOR_LEN] {
    let mut d = [0u8; DESCRIPTOR_LEN];
    d[2] = data_type;
    d[3] = options;
    let n = truncate_utf8(name, 32);
    d[4..4 + n.len()].copy_from_slice(n.as_bytes());
    if let Some((lo, hi)) = min_max {
        d[3] |= 0b110;
        d[64..72].copy_from_slice(&lo.to_le_bytes());
        d[88..96].copy_from_slice(&hi.to_le_bytes());
    }
    let s = truncate_utf8(description, 32);
    d[160..160 + s.len()].copy_from_slice(s.as_bytes());
    d
}

fn extra_bytes_vlr(data: Vec<u8>) -> Vlr {
    Vlr {
        user_id: LASF_SPEC.into(),
        record_id: EXTRA_BYTES_RECORD,
        description: "extra bytes".into(),
        data,
    }
}

/// The longest prefix of `s` of at most `max` bytes ending on a character boundary.
fn truncate_utf8(s: &str, max: usize) -> &str {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

fn check_ao(ao: &[f32], n: usize, out: &Path) -> Result<()> {
    if ao.len() != n {
        return Err(Error::Param(format!(
            "{}: {} ao values for {n} points (internal error)",
            out.display(),
            ao.len()
        )));
    }
    if ao.iter().any(|a| !a.is_finite()) {
        return Err(Error::Param(format!(
            "{}: refusing to write a non-finite ao value (internal error)",
            out.display()
        )));
    }
    Ok(())
}

#[cfg(feature = "laz")]
fn check_compress(_compress: bool, _out: &Path) -> Result<()> {
    Ok(())
}

#[cfg(not(feature = "laz"))]
fn check_compress(compress: bool, out: &Path) -> Result<()> {
    if compress {
        Err(Error::Param(format!("{}: {NO_LAZ}", out.display())))
    } else {
        Ok(())
    }
}

fn write_error(out: &Path, msg: String) -> Error {
    Error::io(out, std::io::Error::other(msg))
}

/// The header fields the las crate does not write: waveform bits and packet position.
struct WaveformPatch {
    /// Global-encoding waveform bits to set.
    bits: u16,
    /// Index among the output EVLRs of the internal waveform packets.
    evlr: Option<usize>,
}

/// A file writer that, once poisoned, swallows everything: the las writer closes itself when
/// dropped and panics if that fails, so after an error the drop must succeed silently.
struct Sink {
    inner: BufWriter<File>,
    dead: Arc<AtomicBool>,
}

impl Sink {
    fn check<T>(&self, r: std::io::Result<T>) -> std::io::Result<T> {
        if r.is_err() {
            self.dead.store(true, Ordering::Relaxed);
        }
        r
    }
}

impl Write for Sink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.dead.load(Ordering::Relaxed) {
            return Ok(buf.len());
        }
        let r = self.inner.write(buf);
        self.check(r)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        if self.dead.load(Ordering::Relaxed) {
            return Ok(());
        }
        let r = self.inner.flush();
        self.check(r)
    }
}

impl Seek for Sink {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        if self.dead.load(Ordering::Relaxed) {
            return Ok(0);
        }
        let r = self.inner.seek(pos);
        self.check(r)
    }
}

/// Writes `n` records produced by `fill(batch, first_index)` under `header` to `out`
/// atomically, then completes the header fields the las crate leaves out.
fn write_points<F>(
    out: &Path,
    header: Header,
    n: usize,
    fill: F,
    waveform: WaveformPatch,
) -> Result<()>
where
    F: Fn(&mut [u8], usize),
{
    let werr = |e: ::las::Error| match e {
        ::las::Error::Io(io) => Error::io(out, io),
        other => write_error(out, format!("cannot write LAS: {other}")),
    };
    let evlr_lens: Vec<u64> = header
        .evlrs()
        .iter()
        .map(|v| EVLR_HEADER_LEN + v.data.len() as u64)
        .collect();
    let version = header.version();
    let extended = header.point_format().is_extended;
    write_atomic_file(out, |file| {
        let dead = Arc::new(AtomicBool::new(false));
        let sink = Sink {
            inner: BufWriter::with_capacity(1 << 20, file),
            dead: dead.clone(),
        };
        let mut batch = PointDataBuilder::new()
            .with_format(*header.point_format())
            .with_transforms(*header.transforms())
            .build();
        let mut writer = Writer::new(sink, header).map_err(werr)?;
        // A panic in the encoder becomes an error; the poisoned sink then lets the writer's
        // closing on drop succeed.
        let written = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let mut first = 0;
            while first < n {
                let m = BATCH.min(n - first);
                fill(batch.resize_for(m), first);
                writer.write_points(&batch)?;
                first += m;
            }
            writer.close()
        }));
        let written = written.unwrap_or_else(|_| {
            Err(::las::Error::Io(std::io::Error::other(
                "the LAS/LAZ encoder failed on these points",
            )))
        });
        if let Err(e) = written {
            dead.store(true, Ordering::Relaxed);
            // The writer closes itself on drop and panics if that fails again (as it does
            // for a header it cannot write): it is left undropped instead.
            std::mem::forget(writer);
            return Err(werr(e));
        }
        let sink = writer.into_inner().map_err(werr)?;
        let mut file = sink
            .inner
            .into_inner()
            .map_err(|e| Error::io(out, e.into_error()))?;
        patch_header(&mut file, version, extended, &waveform, &evlr_lens)
            .map_err(|e| Error::io(out, e))?;
        Ok(file)
    })
}

/// Sets what the las crate does not: the waveform bits and packet offset, and zero legacy
/// point counts for formats 6–10 (LAS 1.4 asks for them).
fn patch_header(
    file: &mut File,
    version: Version,
    extended: bool,
    waveform: &WaveformPatch,
    evlr_lens: &[u64],
) -> std::io::Result<()> {
    let mut b2 = [0u8; 2];
    file.seek(SeekFrom::Start(6))?;
    file.read_exact(&mut b2)?;
    let ge = (u16::from_le_bytes(b2) & !WAVEFORM_BITS) | waveform.bits;
    file.seek(SeekFrom::Start(6))?;
    file.write_all(&ge.to_le_bytes())?;
    if version >= Version::new(1, 4) {
        if let Some(i) = waveform.evlr.filter(|_| waveform.bits & 2 != 0) {
            let mut b8 = [0u8; 8];
            file.seek(SeekFrom::Start(235))?;
            file.read_exact(&mut b8)?;
            let start = u64::from_le_bytes(b8) + evlr_lens[..i].iter().sum::<u64>();
            file.seek(SeekFrom::Start(227))?;
            file.write_all(&start.to_le_bytes())?;
        }
        if extended {
            file.seek(SeekFrom::Start(107))?;
            file.write_all(&[0u8; 24])?;
        }
    }
    Ok(())
}

/// Writes a [`PointTable`] (from another input format) as LAS 1.4, or LAZ with `compress`:
/// world coordinates (the table's pose applied) on a grid chosen by [`grid_exponent`] with an
/// offset near the data, RGB when the table has it (format 7, else 6), intensity scaled to 16
/// bits, the `ao` float dimension and each `extra` field as a double dimension (names cut to
/// 32 bytes, made unique). Records with non-finite coordinates (no return) have no place in
/// LAS and are left out. Atomic. Returns warnings: points the grid merges.
pub fn write_table_las(table: &PointTable, out: &Path, compress: bool) -> Result<Vec<String>> {
    let n = table.len();
    check_ao(&table.ao, n, out)?;
    check_compress(compress, out)?;
    let bad_len = |what: &str, len: usize| {
        Error::Param(format!(
            "{}: {len} {what} values for {n} points (internal error)",
            out.display()
        ))
    };
    if let Some(c) = table.rgb.as_ref().filter(|c| c.len() != n) {
        return Err(bad_len("colour", c.len()));
    }
    if let Some(i) = table.intensity.as_ref().filter(|i| i.len() != n) {
        return Err(bad_len("intensity", i.len()));
    }
    if let Some((name, v)) = table.extra.iter().find(|(_, v)| v.len() != n) {
        return Err(bad_len(name, v.len()));
    }
    let world: Vec<[f64; 3]> = (0..n)
        .into_par_iter()
        .map(|k| table.world(k).to_array())
        .collect();
    let keep: Vec<usize> = (0..n)
        .filter(|&k| world[k].iter().all(|c| c.is_finite()))
        .collect();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &k in &keep {
        for a in 0..3 {
            lo[a] = lo[a].min(world[k][a]);
            hi[a] = hi[a].max(world[k][a]);
        }
    }
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    let exp = grid_exponent(extent);
    let axis = |a: usize| {
        if keep.is_empty() {
            return Transform {
                scale: 1e-4,
                offset: 0.0,
            };
        }
        let offset = ((lo[a] + hi[a]) * 0.5).round();
        let half = (hi[a] - offset).max(offset - lo[a]);
        // Coarser where the extent would overflow the 32-bit integers.
        let mut e = exp;
        while half / pow10(e) > 2.0e9 && e < 300 {
            e += 1;
        }
        Transform {
            scale: pow10(e),
            offset,
        }
    };
    let transforms = Vector {
        x: axis(0),
        y: axis(1),
        z: axis(2),
    };
    let grid = [transforms.x, transforms.y, transforms.z];
    let mut warnings = Vec::new();
    let merged = merged_points(&world, &keep, &grid);
    if merged > 0 {
        let step = grid.iter().map(|t| t.scale).fold(0.0, f64::max);
        warnings.push(format!(
            "{}: {merged} of {} points fall on the LAS grid position ({step:e} m steps) of a \
             different point and can no longer be told apart",
            out.display(),
            keep.len()
        ));
    }

    // Extra dimensions: ao, then each extra field as f64 with a unique name.
    let mut names: Vec<String> = vec![AO_NAME.to_string()];
    let mut data = descriptor(AO_NAME, 9, 0, AO_DESCRIPTION, Some((0.0, 1.0))).to_vec();
    let mut nodata = Vec::new();
    for (k, (name, values)) in table.extra.iter().enumerate() {
        let base = if name.is_empty() {
            format!("extra_{k}")
        } else {
            name.clone()
        };
        let mut unique = truncate_utf8(&base, 32).to_string();
        let mut i = 2;
        while names.contains(&unique) {
            let suffix = format!("_{i}");
            unique = format!("{}{suffix}", truncate_utf8(&base, 32 - suffix.len()));
            i += 1;
        }
        // No NaN reaches the file: non-finite values become the declared no-data value.
        let has_nodata = values.iter().any(|v| !v.is_finite());
        let mut d = descriptor(&unique, 10, 0, "", None);
        if has_nodata {
            d[3] |= 1;
            d[40..48].copy_from_slice(&f64::MIN.to_le_bytes());
        }
        data.extend(d);
        nodata.push(has_nodata);
        names.push(unique);
    }
    let id = if table.rgb.is_some() { 7 } else { 6 };
    let mut format = Format::new(id).expect("format 6/7");
    format.extra_bytes = (4 + 8 * table.extra.len()) as u16;
    format.is_compressed = compress;
    let mut builder = Builder::from((1, 4));
    builder.point_format = format;
    builder.transforms = transforms;
    builder.generating_software = software();
    builder.system_identifier = "OTHER".into();
    builder.date = None;
    builder.vlrs.push(extra_bytes_vlr(data));
    let header = builder
        .into_header()
        .map_err(|e| write_error(out, format!("cannot build the LAS header: {e}")))?;
    let out_len = format.len() as usize;
    let std_len = STD_LEN[id as usize];
    let fill = |dst: &mut [u8], first: usize| {
        let m = dst.len() / out_len;
        dst.par_chunks_exact_mut(out_len)
            .zip(&keep[first..first + m])
            .for_each(|(o, &k)| {
                o.fill(0);
                for (a, q) in quantise(world[k], &grid).into_iter().enumerate() {
                    o[4 * a..4 * a + 4].copy_from_slice(&q.to_le_bytes());
                }
                if let Some(i) = &table.intensity {
                    let v = i[k].clamp(0.0, 1.0); // NaN stays NaN and casts to 0
                    o[12..14].copy_from_slice(&((v * 65535.0).round() as u16).to_le_bytes());
                }
                o[14] = 0x11; // return 1 of 1
                if let Some(c) = &table.rgb {
                    for ch in 0..3 {
                        let v = c[k][ch] as u16 * 257;
                        o[30 + 2 * ch..32 + 2 * ch].copy_from_slice(&v.to_le_bytes());
                    }
                }
                o[std_len..std_len + 4].copy_from_slice(&table.ao[k].to_le_bytes());
                for (j, (_, values)) in table.extra.iter().enumerate() {
                    let v = values[k];
                    let v = if v.is_finite() { v } else { f64::MIN };
                    let at = std_len + 4 + 8 * j;
                    o[at..at + 8].copy_from_slice(&v.to_le_bytes());
                }
            });
    };
    let waveform = WaveformPatch {
        bits: 0,
        evlr: None,
    };
    write_points(out, header, keep.len(), fill, waveform)?;
    Ok(warnings)
}

/// The coarsest grid step of table output, 0.1 mm (10^-4 m): scans of scenes a metre or more
/// across are stored at it.
const GRID_EXP_COARSEST: i32 = -4;
/// The finest grid step, 1 nm: an offset on a whole metre leaves every coordinate within
/// ±2 m of it, still inside the 32-bit integers at this step.
const GRID_EXP_FINEST: i32 = -9;
/// Grid steps across the data's largest extent below which the step is made finer.
const GRID_MIN_STEPS: f64 = 1e4;

/// The power of ten of the LAS grid step for data of `extent` (metres, largest over the
/// axes): the point spacing is unknown, so the step is at most 1/10⁴ of the extent (the
/// relative precision of any scanner), 0.1 mm at the most, 1 nm at the least. A 10 cm object
/// gets 10 µm; a room or a city 0.1 mm.
pub fn grid_exponent(extent: f64) -> i32 {
    let mut e = GRID_EXP_COARSEST;
    while e > GRID_EXP_FINEST && extent < GRID_MIN_STEPS * pow10(e) {
        e -= 1;
    }
    e
}

/// `10^e`, correctly rounded (`1e-4` exactly as the literal).
fn pow10(e: i32) -> f64 {
    // 10^k is exact for the exponents used; one division rounds correctly.
    if e < 0 {
        1.0 / 10f64.powi(-e)
    } else {
        10f64.powi(e)
    }
}

/// A world position as the 32-bit integers of `grid` (saturating; the grid is chosen so that
/// every kept point fits).
fn quantise(w: [f64; 3], grid: &[Transform; 3]) -> [i32; 3] {
    [0, 1, 2].map(|a| ((w[a] - grid[a].offset) / grid[a].scale).round() as i32)
}

/// How many of the points `keep` of `world` the grid puts on the position of a different
/// point (distinct points of a group sharing a position count all but one).
fn merged_points(world: &[[f64; 3]], keep: &[usize], grid: &[Transform; 3]) -> usize {
    // A u32 index keeps the sort at 16 bytes a point; no table of one scan comes near 2^32.
    let Ok(mut q) = keep
        .par_iter()
        .map(|&k| u32::try_from(k).map(|i| (quantise(world[k], grid), i)))
        .collect::<std::result::Result<Vec<_>, _>>()
    else {
        return 0;
    };
    q.par_sort_unstable();
    let mut merged = 0;
    for g in q.chunk_by(|a, b| a.0 == b.0).filter(|g| g.len() > 1) {
        let mut pts: Vec<[u64; 3]> = g
            .iter()
            .map(|&(_, i)| world[i as usize].map(|c| (c + 0.0).to_bits()))
            .collect();
        pts.sort_unstable();
        pts.dedup();
        merged += pts.len() - 1;
    }
    merged
}

#[cfg(test)]
mod tests;
