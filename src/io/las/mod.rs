//! LAS and LAZ (compressed LAS) in and out.
//!
//! A file is read into its raw point records (decompressed when LAZ) and everything around
//! them: header fields, VLRs, every EVLR, and the extra-bytes descriptions. A result written
//! with [`write_las`] copies each record byte for byte (coordinates stay the same scaled
//! integers under the same scale and offset), adds or recolours RGB, and stores the AO as an
//! `ao` extra-bytes dimension (float, described in the LAS 1.4 extra-bytes VLR; bent normals as
//! `bnx bny bnz` beside it) so CloudCompare, PDAL and laspy show it as a scalar field.
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
mod read;
mod table;
mod write;

pub use read::read_ao;
pub use table::{grid_exponent, write_table_las};
use write::rgb_offset;
pub use write::write_las;

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
/// At most this many bytes of LAZ records are decoded at once.
#[cfg(feature = "laz")]
const BATCH_BYTES: usize = 4 << 20;
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

#[inline]
fn i32_at(r: &[u8], at: usize) -> i32 {
    i32::from_le_bytes([r[at], r[at + 1], r[at + 2], r[at + 3]])
}

#[cfg(test)]
mod tests;
