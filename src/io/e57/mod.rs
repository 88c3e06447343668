//! E57 (ASTM E2807) scans in, results out, through the `e57` crate.
//!
//! **Reading** ([`read_e57`]) keeps every `data3D` point cloud as stored: coordinates stay in
//! the scan's own frame (Cartesian as stored, spherical converted to Cartesian in f64), the
//! `pose` becomes [`RawScan::pose`], `rowIndex`/`columnIndex` become the native grid, and a
//! record whose invalid state is set (or whose coordinates are not finite) becomes a
//! non-finite record in its slot. Every stored attribute is kept as decoded (integers stay
//! integers) so [`write_e57`] can write it back unchanged.
//!
//! **Writing a result** ([`write_e57`]): one file with every scan of the input, in the same
//! order, each with its original name, pose (the stored quaternion and translation, not a
//! recomputation), sensor metadata, grid indices, intensity, spherical coordinates, return
//! indices, time stamps and extension attributes, and
//! - Cartesian coordinates as f64 (`cartesianX/Y/Z`, whatever the input stored);
//! - invalid records written back in their place, flagged with `cartesianInvalidState`
//!   (1 = direction only, 2 = invalid) and their stored direction or zero coordinates;
//! - colour = AO grey (or the input colour modulated or kept, [`ColorMode`]) as 8-bit
//!   `colorRed/Green/Blue`;
//! - the AO itself as the extension attribute `mvao:ao` (single float, 0–1, 1 = open), with
//!   the namespace `mvao` declared as [`MVAO_NAMESPACE_URI`]; an `mvao:ao` of the input is
//!   replaced.
//!
//! Not carried over, because the crate cannot write them: `images2D` (photos),
//! `pointGroupingSchemes`, the file's creation date. Extension attributes whose namespace is
//! not declared in the input file cannot be written either and are dropped. Scans get new
//! GUIDs (derived from the old ones, so reruns give identical files) and list the input scan's
//! GUID in `originalGuids`.

use crate::error::{Error, Result};
use crate::io::align::check_rigid;
use crate::io::atomic::write_atomic_seekable;
use crate::io::output::{grey, ColorMode};
use crate::io::raw::{PointTable, RawGrid, RawScan};
use ::e57::{
    ColorLimits, E57Reader, E57Writer, Extension, IndexBounds, IntensityLimits, PointCloud,
    Quaternion, Record, RecordDataType, RecordName, RecordValue, Transform, Translation,
};
use glam::{DMat3, DMat4, DQuat, DVec3, Vec3};
use rayon::prelude::*;
use std::borrow::Cow;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

/// Namespace prefix of the attributes mvao adds to E57 point records.
pub const MVAO_NAMESPACE: &str = "mvao";
/// URI declared for [`MVAO_NAMESPACE`] in written files.
pub const MVAO_NAMESPACE_URI: &str = "urn:mvao:e57:1";
/// Attribute name of the ambient occlusion (`mvao:ao`).
pub const AO_ATTRIBUTE: &str = "ao";

/// Grid indices at or above this are not taken as a grid (same bound as PLY `row`/`col`).
const MAX_GRID_INDEX: i64 = 10_000_000;
/// A stored rotation quaternion may deviate this much from unit length (printed decimals);
/// it is normalised. More is an error: the pose would scale the scan.
const QUATERNION_TOLERANCE: f64 = 1e-4;

/// An E57 file as read: file-level metadata and every point cloud.
#[derive(Debug, Clone)]
pub struct E57Input {
    /// The file read.
    pub path: PathBuf,
    /// The file's GUID.
    pub guid: String,
    /// The file's coordinate metadata (a CRS, often empty).
    pub coordinate_metadata: Option<String>,
    /// Extension namespaces the file declares.
    pub extensions: Vec<Extension>,
    /// Every `data3D` point cloud, in file order.
    pub scans: Vec<E57Scan>,
}

/// One `data3D` point cloud.
#[derive(Debug, Clone)]
pub struct E57Scan {
    /// Unique name within the file, safe in a file name: the stored name (characters not
    /// allowed in file names replaced by `_`), else `<stem>` (one scan) or `<stem>_<k>`.
    pub name: String,
    /// The stored descriptor: name, GUID, pose, prototype, limits, bounds, sensor metadata.
    pub descriptor: PointCloud,
    /// Scan frame → file frame (the stored pose; identity when the scan has none).
    pub pose: DMat4,
    /// Whether the scan stores a `pose` element (an identity pose counts as given).
    pub has_pose: bool,
    /// Coordinates per record in the scan's frame (metres); non-finite for an invalid record.
    pub xyz: Vec<[f64; 3]>,
    /// Native grid from `rowIndex`/`columnIndex`, when both are stored and plausible.
    pub grid: Option<RawGrid>,
    /// Unit normals from the `normalX/Y/Z` extension attributes, when stored.
    pub normals: Option<Vec<Vec3>>,
    /// Intensity per record normalised to [0, 1] by the stored limits (0 where flagged invalid).
    pub intensity: Option<Vec<f32>>,
    /// Colour per record normalised to 8 bits by the stored limits (black where flagged
    /// invalid, see [`E57Scan::colour_valid`]).
    pub rgb: Option<Vec<[u8; 3]>>,
    /// Records without a valid coordinate.
    pub invalid: usize,
    /// The decoded values of every prototype record, in prototype order.
    columns: Vec<Column>,
}

/// What [`write_e57_scans`] writes for one scan (test files, the virtual scanner).
#[derive(Debug, Clone, Default)]
pub struct E57ScanOut {
    /// Stored name.
    pub name: String,
    /// Scan frame → file frame; `None` writes no `pose` element.
    pub pose: Option<DMat4>,
    /// Coordinates in the scan's frame; a non-finite record is written flagged invalid.
    pub xyz: Vec<[f64; 3]>,
    /// Grid indices, written as `rowIndex`/`columnIndex`.
    pub grid: Option<RawGrid>,
    /// Intensity per record in [0, 1].
    pub intensity: Option<Vec<f32>>,
    /// Colour per record.
    pub rgb: Option<Vec<[u8; 3]>>,
    /// Store spherical (range, azimuth, elevation; f64) instead of Cartesian coordinates.
    pub spherical: bool,
}

/// Decoded values of one prototype record. Integers keep their stored value (a scaled
/// integer its unscaled one) in the smallest type that holds the declared range.
#[derive(Debug, Clone)]
enum Column {
    F32(Vec<f32>),
    F64(Vec<f64>),
    U8(Vec<u8>),
    U16(Vec<u16>),
    I32(Vec<i32>),
    I64(Vec<i64>),
}

impl Column {
    fn for_type(dt: &RecordDataType, cap: usize) -> Column {
        match *dt {
            RecordDataType::Single { .. } => Column::F32(Vec::with_capacity(cap)),
            RecordDataType::Double { .. } => Column::F64(Vec::with_capacity(cap)),
            RecordDataType::Integer { min, max }
            | RecordDataType::ScaledInteger { min, max, .. } => {
                if min >= 0 && max <= u8::MAX as i64 {
                    Column::U8(Vec::with_capacity(cap))
                } else if min >= 0 && max <= u16::MAX as i64 {
                    Column::U16(Vec::with_capacity(cap))
                } else if min >= i32::MIN as i64 && max <= i32::MAX as i64 {
                    Column::I32(Vec::with_capacity(cap))
                } else {
                    Column::I64(Vec::with_capacity(cap))
                }
            }
        }
    }

    /// Appends a decoded value; `Err` when it does not fit the declared type or range (the
    /// crate's decoder can return values past `max` from corrupt bit streams).
    fn push(&mut self, v: &RecordValue, dt: &RecordDataType) -> std::result::Result<(), String> {
        let int = match (v, dt) {
            (RecordValue::Integer(i), RecordDataType::Integer { min, max })
            | (RecordValue::ScaledInteger(i), RecordDataType::ScaledInteger { min, max, .. }) => {
                if i < min || i > max {
                    return Err(format!("value {i} outside its declared range {min}..{max}"));
                }
                Some(*i)
            }
            _ => None,
        };
        match (self, v, int) {
            (Column::F32(c), RecordValue::Single(x), _) => c.push(*x),
            (Column::F64(c), RecordValue::Double(x), _) => c.push(*x),
            (Column::U8(c), _, Some(i)) => c.push(i as u8),
            (Column::U16(c), _, Some(i)) => c.push(i as u16),
            (Column::I32(c), _, Some(i)) => c.push(i as i32),
            (Column::I64(c), _, Some(i)) => c.push(i),
            _ => return Err("value of another type than declared".into()),
        }
        Ok(())
    }

    fn len(&self) -> usize {
        match self {
            Column::F32(c) => c.len(),
            Column::F64(c) => c.len(),
            Column::U8(c) => c.len(),
            Column::U16(c) => c.len(),
            Column::I32(c) => c.len(),
            Column::I64(c) => c.len(),
        }
    }

    /// The stored value without scaling.
    #[inline]
    fn raw(&self, k: usize) -> f64 {
        match self {
            Column::F32(c) => c[k] as f64,
            Column::F64(c) => c[k],
            Column::U8(c) => c[k] as f64,
            Column::U16(c) => c[k] as f64,
            Column::I32(c) => c[k] as f64,
            Column::I64(c) => c[k] as f64,
        }
    }

    #[inline]
    fn int(&self, k: usize) -> i64 {
        match self {
            Column::F32(c) => c[k] as i64,
            Column::F64(c) => c[k] as i64,
            Column::U8(c) => c[k] as i64,
            Column::U16(c) => c[k] as i64,
            Column::I32(c) => c[k] as i64,
            Column::I64(c) => c[k],
        }
    }

    /// The value in its unit (a scaled integer scaled), as the crate's reader gives it.
    #[inline]
    fn value(&self, k: usize, dt: &RecordDataType) -> f64 {
        match dt {
            RecordDataType::ScaledInteger { scale, offset, .. } => {
                self.int(k) as f64 * scale + offset
            }
            _ => self.raw(k),
        }
    }

    /// The value as the crate's writer takes it for a record of type `dt` (the column was
    /// made for that type).
    #[inline]
    fn record_value(&self, k: usize, dt: &RecordDataType) -> RecordValue {
        match (self, dt) {
            (Column::F32(c), _) => RecordValue::Single(c[k]),
            (Column::F64(c), _) => RecordValue::Double(c[k]),
            (_, RecordDataType::ScaledInteger { .. }) => RecordValue::ScaledInteger(self.int(k)),
            _ => RecordValue::Integer(self.int(k)),
        }
    }

    fn min_max_int(&self) -> Option<(i64, i64)> {
        let n = self.len();
        (n > 0).then(|| {
            (0..n)
                .into_par_iter()
                .map(|k| (self.int(k), self.int(k)))
                .reduce(|| (i64::MAX, i64::MIN), |a, b| (a.0.min(b.0), a.1.max(b.1)))
        })
    }
}

/// Bits per value of a record type, as the format packs it.
fn bit_size(dt: &RecordDataType) -> u64 {
    match *dt {
        RecordDataType::Single { .. } => 32,
        RecordDataType::Double { .. } => 64,
        RecordDataType::Integer { min, max } | RecordDataType::ScaledInteger { min, max, .. } => {
            let range = max as i128 - min as i128;
            if range > 0 {
                range.ilog2() as u64 + 1
            } else {
                0
            }
        }
    }
}

/// The E57 element name of a record (`cartesianX`, `nor:normalX`, …), for messages and
/// cross-format attribute names.
pub fn record_label(name: &RecordName) -> String {
    let s = match name {
        RecordName::CartesianX => "cartesianX",
        RecordName::CartesianY => "cartesianY",
        RecordName::CartesianZ => "cartesianZ",
        RecordName::CartesianInvalidState => "cartesianInvalidState",
        RecordName::SphericalRange => "sphericalRange",
        RecordName::SphericalAzimuth => "sphericalAzimuth",
        RecordName::SphericalElevation => "sphericalElevation",
        RecordName::SphericalInvalidState => "sphericalInvalidState",
        RecordName::Intensity => "intensity",
        RecordName::IsIntensityInvalid => "isIntensityInvalid",
        RecordName::ColorRed => "colorRed",
        RecordName::ColorGreen => "colorGreen",
        RecordName::ColorBlue => "colorBlue",
        RecordName::IsColorInvalid => "isColorInvalid",
        RecordName::RowIndex => "rowIndex",
        RecordName::ColumnIndex => "columnIndex",
        RecordName::ReturnCount => "returnCount",
        RecordName::ReturnIndex => "returnIndex",
        RecordName::TimeStamp => "timeStamp",
        RecordName::IsTimeStampInvalid => "isTimeStampInvalid",
        RecordName::Unknown { namespace, name } if namespace.is_empty() => return name.clone(),
        RecordName::Unknown { namespace, name } => return format!("{namespace}:{name}"),
    };
    s.to_string()
}

/// Reads every point cloud of an E57 file (see the module documentation).
///
/// Errors: the file cannot be opened or is not E57, a scan's data is truncated or corrupt
/// (the message names the scan), a scan has no coordinates, a pose is not a rotation plus
/// translation, or the file holds several scans of which none has a pose.
pub fn read_e57(path: &Path) -> Result<E57Input> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let reader = E57Reader::new(BufReader::new(file))
        .map_err(|e| Error::format(path, format!("not a readable E57 file: {e}")))?;
    let clouds = reader.pointclouds();
    let guid = reader.guid().to_string();
    let coordinate_metadata = reader.coordinate_metadata().map(str::to_string);
    let extensions = reader.extensions();
    drop(reader);
    if clouds.is_empty() {
        return Err(Error::format(path, "E57 file holds no data3D point cloud"));
    }
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scan".into());
    let names = scan_names(&clouds, &stem);
    // One reader per scan, so several scans decode in parallel.
    let results: Vec<Result<E57Scan>> = clouds
        .par_iter()
        .zip(names)
        .map(|(pc, name)| read_cloud(path, file_len, pc, name))
        .collect();
    let scans = results.into_iter().collect::<Result<Vec<_>>>()?;
    if scans.len() > 1 && !scans.iter().any(|s| s.has_pose) {
        return Err(Error::format(
            path,
            format!(
                "{} scans and none has a pose; the scans cannot be placed",
                scans.len()
            ),
        ));
    }
    Ok(E57Input {
        path: path.to_path_buf(),
        guid,
        coordinate_metadata,
        extensions,
        scans,
    })
}

/// Unique, file-name-safe scan names.
fn scan_names(clouds: &[PointCloud], stem: &str) -> Vec<String> {
    let mut used = std::collections::HashSet::new();
    clouds
        .iter()
        .enumerate()
        .map(|(k, pc)| {
            let stored = pc.name.as_deref().map(file_safe).unwrap_or_default();
            let base = if !stored.is_empty() {
                stored
            } else if clouds.len() == 1 {
                stem.to_string()
            } else {
                format!("{stem}_{k}")
            };
            let mut name = base.clone();
            let mut j = 1;
            while !used.insert(name.clone()) {
                name = format!("{base}_{j}");
                j += 1;
            }
            name
        })
        .collect()
}

/// `s` trimmed, with characters that are not allowed in file names replaced by `_`.
fn file_safe(s: &str) -> String {
    let t: String = s
        .trim()
        .chars()
        .map(|c| {
            if c.is_control() || "/\\:*?\"<>|".contains(c) {
                '_'
            } else {
                c
            }
        })
        .collect();
    if t.chars().all(|c| c == '.') {
        String::new()
    } else {
        t
    }
}

/// The stored pose as a matrix: unit quaternion and translation, checked.
fn pose_matrix(t: &Transform) -> std::result::Result<DMat4, String> {
    let q = DQuat::from_xyzw(t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w);
    let len = q.length();
    if !len.is_finite() || (len - 1.0).abs() > QUATERNION_TOLERANCE {
        return Err(format!(
            "pose rotation quaternion (w {}, x {}, y {}, z {}) has length {len}, not 1",
            t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z
        ));
    }
    let tr = DVec3::new(t.translation.x, t.translation.y, t.translation.z);
    if !tr.is_finite() {
        return Err("pose translation is not finite".into());
    }
    Ok(DMat4::from_rotation_translation(q / len, tr))
}

/// Index of the prototype record called `name`.
fn find(proto: &[Record], name: &RecordName) -> Option<usize> {
    proto.iter().position(|r| &r.name == name)
}

/// Index of the extension record whose attribute name is `name`, in any namespace.
fn find_unknown(proto: &[Record], attr: &str) -> Option<usize> {
    proto
        .iter()
        .position(|r| matches!(&r.name, RecordName::Unknown { name, .. } if name == attr))
}

/// The value range a record's values are normalised by: the stored limits, else the
/// declared type range. `None` when neither bounds the values.
fn value_range(
    lo: Option<&RecordValue>,
    hi: Option<&RecordValue>,
    dt: &RecordDataType,
) -> Option<(f64, f64)> {
    let lim = |v: &RecordValue| match (v, dt) {
        (RecordValue::ScaledInteger(i), RecordDataType::ScaledInteger { scale, offset, .. }) => {
            *i as f64 * scale + offset
        }
        (RecordValue::ScaledInteger(i), _) | (RecordValue::Integer(i), _) => *i as f64,
        (RecordValue::Single(x), _) => *x as f64,
        (RecordValue::Double(x), _) => *x,
    };
    let ordered = |a: f64, b: f64| (a.is_finite() && b.is_finite() && b > a).then_some((a, b));
    if let (Some(a), Some(b)) = (lo, hi) {
        if let Some(r) = ordered(lim(a), lim(b)) {
            return Some(r);
        }
    }
    match *dt {
        RecordDataType::Single {
            min: Some(a),
            max: Some(b),
        } => ordered(a as f64, b as f64),
        RecordDataType::Double {
            min: Some(a),
            max: Some(b),
        } => ordered(a, b),
        RecordDataType::Integer { min, max } => ordered(min as f64, max as f64),
        RecordDataType::ScaledInteger {
            min,
            max,
            scale,
            offset,
        } => {
            let (a, b) = (min as f64 * scale + offset, max as f64 * scale + offset);
            ordered(a.min(b), a.max(b))
        }
        _ => None,
    }
}

/// Values of column `c` (record type `dt`) mapped to [0, 1] by `range`; without a range,
/// values already in [0, 1] are kept and others scaled by their own minimum and maximum.
fn normalised(c: &Column, dt: &RecordDataType, range: Option<(f64, f64)>) -> Vec<f32> {
    let n = c.len();
    let (lo, hi) = range.unwrap_or_else(|| {
        let (a, b) = (0..n)
            .into_par_iter()
            .map(|k| c.value(k, dt))
            .filter(|v| v.is_finite())
            .fold(
                || (f64::INFINITY, f64::NEG_INFINITY),
                |m, v| (m.0.min(v), m.1.max(v)),
            )
            .reduce(
                || (f64::INFINITY, f64::NEG_INFINITY),
                |a, b| (a.0.min(b.0), a.1.max(b.1)),
            );
        if a >= 0.0 && b <= 1.0 || !(b > a) {
            (0.0, 1.0)
        } else {
            (a, b)
        }
    });
    let inv = 1.0 / (hi - lo);
    (0..n)
        .into_par_iter()
        .map(|k| {
            let v = (c.value(k, dt) - lo) * inv;
            if v.is_finite() {
                v.clamp(0.0, 1.0) as f32
            } else {
                0.0
            }
        })
        .collect()
}

/// Decodes one point cloud and derives coordinates, grid, normals, intensity and colour.
fn read_cloud(path: &Path, file_len: u64, pc: &PointCloud, name: String) -> Result<E57Scan> {
    let fail = |msg: String| Error::format(path, format!("scan {name}: {msg}"));
    let proto = &pc.prototype;
    let bits: u64 = proto.iter().map(|r| bit_size(&r.data_type)).sum();
    if bits == 0 {
        // The crate would generate constant records without end.
        return Err(fail(
            "every attribute is constant (0 bits per record); not a point cloud".into(),
        ));
    }
    let (has_pose, pose) = match &pc.transform {
        Some(t) => (true, pose_matrix(t).map_err(&fail)?),
        None => (false, DMat4::IDENTITY),
    };
    let ix = |n: RecordName| find(proto, &n);
    let cart = (
        ix(RecordName::CartesianX),
        ix(RecordName::CartesianY),
        ix(RecordName::CartesianZ),
    );
    let sph = (
        ix(RecordName::SphericalRange),
        ix(RecordName::SphericalAzimuth),
        ix(RecordName::SphericalElevation),
    );
    let cart = match cart {
        (Some(a), Some(b), Some(c)) => Some([a, b, c]),
        _ => None,
    };
    let sph = match sph {
        (Some(a), Some(b), Some(c)) => Some([a, b, c]),
        _ => None,
    };
    if cart.is_none() && sph.is_none() {
        return Err(fail(
            "has neither Cartesian (cartesianX/Y/Z) nor spherical coordinates".into(),
        ));
    }
    // A scaled integer with a zero or non-finite scale holds no value (the standard asks for
    // a non-zero scale).
    for &k in cart.iter().chain(sph.iter()).flatten() {
        if let RecordDataType::ScaledInteger { scale, offset, .. } = proto[k].data_type {
            if !(scale != 0.0 && scale.is_finite() && offset.is_finite()) {
                return Err(fail(format!(
                    "{} is a scaled integer with scale {scale} and offset {offset}",
                    record_label(&proto[k].name)
                )));
            }
        }
    }

    // Decode. The capacity is bounded by what the file can hold, not by the stored count.
    let cap = pc.records.min(file_len.saturating_mul(8) / bits + 1) as usize;
    let mut cols: Vec<Column> = proto
        .iter()
        .map(|r| Column::for_type(&r.data_type, cap))
        .collect();
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let mut reader = E57Reader::new(BufReader::new(file))
        .map_err(|e| Error::format(path, format!("not a readable E57 file: {e}")))?;
    let iter = reader
        .pointcloud_raw(pc)
        .map_err(|e| fail(format!("cannot start reading points: {e}")))?;
    for (k, values) in iter.enumerate() {
        let values = values.map_err(|e| {
            fail(format!(
                "record {k} of {}: {e} (truncated or corrupt)",
                pc.records
            ))
        })?;
        if values.len() != cols.len() {
            return Err(fail(format!(
                "record {k} has {} values, the prototype {}",
                values.len(),
                cols.len()
            )));
        }
        for ((c, r), v) in cols.iter_mut().zip(proto).zip(&values) {
            c.push(v, &r.data_type)
                .map_err(|m| fail(format!("record {k}: {}: {m}", record_label(&r.name))))?;
        }
    }
    let n = cols.first().map_or(0, Column::len);
    if n as u64 != pc.records {
        return Err(fail(format!(
            "{} records declared, {n} decoded (truncated or corrupt)",
            pc.records
        )));
    }

    let dt = |i: usize| &proto[i].data_type;
    let state = |i: Option<usize>, k: usize| i.map_or(0, |i| cols[i].value(k, dt(i)) as i64);
    let cart_state = ix(RecordName::CartesianInvalidState);
    let sph_state = ix(RecordName::SphericalInvalidState);
    let xyz: Vec<[f64; 3]> = (0..n)
        .into_par_iter()
        .map(|k| {
            if let Some(c) = cart {
                if state(cart_state, k) == 0 {
                    let p = c.map(|i| cols[i].value(k, dt(i)));
                    if p.iter().all(|v| v.is_finite()) {
                        return p;
                    }
                }
            }
            if let Some([r, a, e]) = sph {
                if state(sph_state, k) == 0 {
                    let (r, a, e) = (
                        cols[r].value(k, dt(r)),
                        cols[a].value(k, dt(a)),
                        cols[e].value(k, dt(e)),
                    );
                    let (se, ce) = e.sin_cos();
                    let (sa, ca) = a.sin_cos();
                    let p = [r * ce * ca, r * ce * sa, r * se];
                    if p.iter().all(|v| v.is_finite()) {
                        return p;
                    }
                }
            }
            [f64::NAN; 3]
        })
        .collect();
    let invalid = xyz.par_iter().filter(|p| !p[0].is_finite()).count();

    let grid = match (ix(RecordName::RowIndex), ix(RecordName::ColumnIndex)) {
        (Some(ri), Some(ci)) if n > 0 => {
            let (r0, r1) = cols[ri].min_max_int().unwrap_or((0, 0));
            let (c0, c1) = cols[ci].min_max_int().unwrap_or((0, 0));
            if r0 < 0 || c0 < 0 || r1 >= MAX_GRID_INDEX || c1 >= MAX_GRID_INDEX {
                None
            } else {
                // The stored bounds may declare a larger grid than the records reach.
                let bound = |b: Option<i64>, data: i64| match b {
                    Some(b) if (0..MAX_GRID_INDEX).contains(&b) => b.max(data),
                    _ => data,
                };
                let ib = pc.index_bounds.as_ref();
                let rows = bound(ib.and_then(|b| b.row_max), r1) + 1;
                let ncols = bound(ib.and_then(|b| b.column_max), c1) + 1;
                Some(RawGrid {
                    rows: rows as u32,
                    cols: ncols as u32,
                    row: (0..n)
                        .into_par_iter()
                        .map(|k| cols[ri].int(k) as u32)
                        .collect(),
                    col: (0..n)
                        .into_par_iter()
                        .map(|k| cols[ci].int(k) as u32)
                        .collect(),
                })
            }
        }
        _ => None,
    };

    let normals = match (
        find_unknown(proto, "normalX"),
        find_unknown(proto, "normalY"),
        find_unknown(proto, "normalZ"),
    ) {
        (Some(a), Some(b), Some(c)) => Some(
            (0..n)
                .into_par_iter()
                .map(|k| {
                    let v = Vec3::new(
                        cols[a].value(k, dt(a)) as f32,
                        cols[b].value(k, dt(b)) as f32,
                        cols[c].value(k, dt(c)) as f32,
                    );
                    // An unusable normal becomes zero and is re-estimated downstream.
                    v.try_normalize().unwrap_or(Vec3::ZERO)
                })
                .collect(),
        ),
        _ => None,
    };

    let intensity = ix(RecordName::Intensity).map(|i| {
        let lim = pc.intensity_limits.as_ref();
        let range = value_range(
            lim.and_then(|l| l.intensity_min.as_ref()),
            lim.and_then(|l| l.intensity_max.as_ref()),
            dt(i),
        );
        let mut v = normalised(&cols[i], dt(i), range);
        if let Some(f) = ix(RecordName::IsIntensityInvalid) {
            v.par_iter_mut()
                .enumerate()
                .for_each(|(k, x)| *x = if cols[f].int(k) != 0 { 0.0 } else { *x });
        }
        v
    });

    let rgb = match (
        ix(RecordName::ColorRed),
        ix(RecordName::ColorGreen),
        ix(RecordName::ColorBlue),
    ) {
        (Some(r), Some(g), Some(b)) => {
            let lim = pc.color_limits.as_ref();
            let ch = |i: usize, lo: Option<&RecordValue>, hi: Option<&RecordValue>| {
                normalised(&cols[i], dt(i), value_range(lo, hi, dt(i)))
            };
            let rr = ch(
                r,
                lim.and_then(|l| l.red_min.as_ref()),
                lim.and_then(|l| l.red_max.as_ref()),
            );
            let gg = ch(
                g,
                lim.and_then(|l| l.green_min.as_ref()),
                lim.and_then(|l| l.green_max.as_ref()),
            );
            let bb = ch(
                b,
                lim.and_then(|l| l.blue_min.as_ref()),
                lim.and_then(|l| l.blue_max.as_ref()),
            );
            let bad = ix(RecordName::IsColorInvalid);
            let to8 = |v: f32| (v * 255.0).round() as u8;
            Some(
                (0..n)
                    .into_par_iter()
                    .map(|k| {
                        if bad.is_some_and(|f| cols[f].int(k) != 0) {
                            [0; 3]
                        } else {
                            [to8(rr[k]), to8(gg[k]), to8(bb[k])]
                        }
                    })
                    .collect(),
            )
        }
        _ => None,
    };

    Ok(E57Scan {
        name,
        descriptor: pc.clone(),
        pose,
        has_pose,
        xyz,
        grid,
        normals,
        intensity,
        rgb,
        invalid,
        columns: cols,
    })
}

impl E57Input {
    /// The scans as the pipeline takes them: scan-frame coordinates, `pose` = the stored pose
    /// (identity when absent), `scanner` = the scan frame's origin when the scan has a pose
    /// (an E57 scan's frame is the scanner's), unknown (`None`) when it has none, since such
    /// files often hold registered or georeferenced points.
    pub fn raw_scans(&self) -> Vec<RawScan> {
        self.scans
            .iter()
            .map(|s| RawScan {
                name: s.name.clone(),
                xyz: s.xyz.clone(),
                normals: s.normals.clone(),
                grid: s.grid.clone(),
                pose: Some(s.pose),
                scanner: s.has_pose.then_some(DVec3::ZERO),
                sensor_hint: None,
                warnings: Vec::new(),
            })
            .collect()
    }

    /// Scan `k` with its AO as a table for writing in another format: coordinates in the scan
    /// frame with the scan's pose, colours by `color` ([`result_colours`]), intensity, grid,
    /// and every other stored scalar attribute as an extra field named by
    /// [`record_label`].
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
            .ok_or_else(|| Error::Param(format!("{}: no scan {k}", self.path.display())))?;
        check_ao(&self.path, &s.name, ao, s.len())?;
        let valid: Option<Vec<bool>> = s
            .rgb
            .as_ref()
            .map(|_| (0..s.len()).map(|k| s.colour_valid(k)).collect());
        let rgb = result_colours(s.rgb.as_deref(), valid.as_deref(), ao, gamma, color);
        let proto = &s.descriptor.prototype;
        let skip = |n: &RecordName| {
            matches!(
                n,
                RecordName::CartesianX
                    | RecordName::CartesianY
                    | RecordName::CartesianZ
                    | RecordName::CartesianInvalidState
                    | RecordName::Intensity
                    | RecordName::ColorRed
                    | RecordName::ColorGreen
                    | RecordName::ColorBlue
                    | RecordName::RowIndex
                    | RecordName::ColumnIndex
            ) || is_mvao_ao(n)
        };
        let extra = proto
            .iter()
            .zip(&s.columns)
            .filter(|(r, _)| !skip(&r.name))
            .map(|(r, c)| {
                let v = (0..c.len())
                    .into_par_iter()
                    .map(|k| c.value(k, &r.data_type))
                    .collect();
                (record_label(&r.name), v)
            })
            .collect();
        Ok(PointTable {
            name: s.name.clone(),
            xyz: s.xyz.clone(),
            pose: s.pose,
            rgb: Some(rgb),
            intensity: s.intensity.clone(),
            ao: ao.to_vec(),
            grid: s.grid.clone(),
            extra,
        })
    }
}

impl E57Scan {
    /// Number of records (valid and invalid).
    pub fn len(&self) -> usize {
        self.xyz.len()
    }

    /// True when the scan has no record.
    pub fn is_empty(&self) -> bool {
        self.xyz.is_empty()
    }

    /// The values of the stored attribute `name` in its unit (scaled integers scaled), e.g.
    /// `RecordName::Unknown { namespace: "mvao".into(), name: "ao".into() }`.
    pub fn values(&self, name: &RecordName) -> Option<Vec<f64>> {
        let i = find(&self.descriptor.prototype, name)?;
        let (c, dt) = (&self.columns[i], &self.descriptor.prototype[i].data_type);
        Some(
            (0..c.len())
                .into_par_iter()
                .map(|k| c.value(k, dt))
                .collect(),
        )
    }

    /// Whether record `k` has a usable colour (stored and not flagged `isColorInvalid`).
    pub fn colour_valid(&self, k: usize) -> bool {
        let proto = &self.descriptor.prototype;
        self.rgb.is_some()
            && find(proto, &RecordName::IsColorInvalid).is_none_or(|f| self.columns[f].int(k) == 0)
    }

    /// The Cartesian coordinates and `cartesianInvalidState` written for record `k`: valid
    /// records their coordinates, a direction-only record its stored direction, others zero.
    fn output_xyz(&self, k: usize) -> ([f64; 3], u8) {
        let p = self.xyz[k];
        if p.iter().all(|v| v.is_finite()) {
            return (p, 0);
        }
        let proto = &self.descriptor.prototype;
        let col = |n: RecordName| find(proto, &n);
        let val = |i: usize| self.columns[i].value(k, &proto[i].data_type);
        let st = |i: Option<usize>| i.map_or(0, |i| val(i) as i64);
        if let (Some(x), Some(y), Some(z)) = (
            col(RecordName::CartesianX),
            col(RecordName::CartesianY),
            col(RecordName::CartesianZ),
        ) {
            let q = [val(x), val(y), val(z)];
            if st(col(RecordName::CartesianInvalidState)) == 1 && q.iter().all(|v| v.is_finite()) {
                return (q, 1);
            }
            return ([0.0; 3], 2);
        }
        if let (Some(a), Some(e)) = (
            col(RecordName::SphericalAzimuth),
            col(RecordName::SphericalElevation),
        ) {
            if st(col(RecordName::SphericalInvalidState)) == 1 {
                let (se, ce) = val(e).sin_cos();
                let (sa, ca) = val(a).sin_cos();
                let d = [ce * ca, ce * sa, se];
                if d.iter().all(|v| v.is_finite()) {
                    return (d, 1);
                }
            }
        }
        ([0.0; 3], 2)
    }

    /// Everything [`write_e57`] writes for this scan.
    fn result_cloud<'a>(
        &'a self,
        ao: &[f32],
        gamma: f32,
        color: ColorMode,
        extensions: &[Extension],
    ) -> CloudOut<'a> {
        let n = self.len();
        let proto = &self.descriptor.prototype;
        let coords: Vec<([f64; 3], u8)> =
            (0..n).into_par_iter().map(|k| self.output_xyz(k)).collect();
        let any_invalid = coords.iter().any(|c| c.1 != 0);
        let mut records: Vec<(Record, Cow<'a, Column>)> = Vec::with_capacity(proto.len() + 6);
        for (axis, rec) in [
            Record::CARTESIAN_X_F64,
            Record::CARTESIAN_Y_F64,
            Record::CARTESIAN_Z_F64,
        ]
        .into_iter()
        .enumerate()
        {
            let c = coords.par_iter().map(|c| c.0[axis]).collect();
            records.push((rec, Cow::Owned(Column::F64(c))));
        }
        if any_invalid || find(proto, &RecordName::CartesianInvalidState).is_some() {
            let c = coords.par_iter().map(|c| c.1).collect();
            records.push((Record::CARTESIAN_INVALID_STATE, Cow::Owned(Column::U8(c))));
        }
        drop(coords);
        let replace_colour = color != ColorMode::Keep || self.rgb.is_none();
        let declared = |ns: &str| extensions.iter().any(|e| e.namespace == ns);
        for (r, c) in proto.iter().zip(&self.columns) {
            let drop_it = match &r.name {
                RecordName::CartesianX
                | RecordName::CartesianY
                | RecordName::CartesianZ
                | RecordName::CartesianInvalidState => true,
                RecordName::ColorRed
                | RecordName::ColorGreen
                | RecordName::ColorBlue
                | RecordName::IsColorInvalid => replace_colour,
                RecordName::Unknown { namespace, name } => {
                    (namespace == MVAO_NAMESPACE && name == AO_ATTRIBUTE) || !declared(namespace)
                }
                _ => false,
            };
            if !drop_it {
                records.push((r.clone(), Cow::Borrowed(c)));
            }
        }
        if replace_colour {
            let valid: Option<Vec<bool>> = self
                .rgb
                .as_ref()
                .map(|_| (0..n).map(|k| self.colour_valid(k)).collect());
            let rgb = result_colours(self.rgb.as_deref(), valid.as_deref(), ao, gamma, color);
            for (ch, rec) in [
                Record::COLOR_RED_U8,
                Record::COLOR_GREEN_U8,
                Record::COLOR_BLUE_U8,
            ]
            .into_iter()
            .enumerate()
            {
                let c = rgb.par_iter().map(|p| p[ch]).collect();
                records.push((rec, Cow::Owned(Column::U8(c))));
            }
        }
        records.push((ao_record(), Cow::Owned(Column::F32(ao.to_vec()))));

        let d = &self.descriptor;
        let intensity_limits = find(proto, &RecordName::Intensity).and_then(|i| {
            let l = d.intensity_limits.as_ref()?;
            let dt = &proto[i].data_type;
            Some(IntensityLimits {
                intensity_min: l.intensity_min.as_ref().map(|v| unit_limit(v, dt)),
                intensity_max: l.intensity_max.as_ref().map(|v| unit_limit(v, dt)),
            })
        });
        let color_limits = if replace_colour {
            None
        } else {
            d.color_limits.as_ref().and_then(|l| {
                let dt = |n: RecordName| find(proto, &n).map(|i| &proto[i].data_type);
                let (r, g, b) = (
                    dt(RecordName::ColorRed)?,
                    dt(RecordName::ColorGreen)?,
                    dt(RecordName::ColorBlue)?,
                );
                let f = |v: &Option<RecordValue>, dt| v.as_ref().map(|v| unit_limit(v, dt));
                Some(ColorLimits {
                    red_min: f(&l.red_min, r),
                    red_max: f(&l.red_max, r),
                    green_min: f(&l.green_min, g),
                    green_max: f(&l.green_max, g),
                    blue_min: f(&l.blue_min, b),
                    blue_max: f(&l.blue_max, b),
                })
            })
        };
        let mut original_guids = d.original_guids.clone().unwrap_or_default();
        let seed = d.guid.clone().unwrap_or_else(|| self.name.clone());
        if let Some(g) = &d.guid {
            original_guids.push(g.clone());
        }
        CloudOut {
            guid: derived_guid(&format!("mvao result of {seed}")),
            name: d.name.clone(),
            meta: Some(d),
            transform: d.transform.clone(),
            original_guids: (!original_guids.is_empty()).then_some(original_guids),
            intensity_limits,
            color_limits,
            index_bounds: d.index_bounds.clone(),
            records,
            len: n,
        }
    }
}

/// A stored limit in the record's unit, as a double (a scaled-integer limit written back
/// without its scale would change meaning).
fn unit_limit(v: &RecordValue, dt: &RecordDataType) -> RecordValue {
    match (v, dt) {
        (RecordValue::ScaledInteger(i), RecordDataType::ScaledInteger { scale, offset, .. }) => {
            RecordValue::Double(*i as f64 * scale + offset)
        }
        (RecordValue::ScaledInteger(i), _) => RecordValue::Double(*i as f64),
        _ => v.clone(),
    }
}

fn is_mvao_ao(n: &RecordName) -> bool {
    matches!(n, RecordName::Unknown { namespace, name } if namespace == MVAO_NAMESPACE && name == AO_ATTRIBUTE)
}

/// The `mvao:ao` record: single float in [0, 1].
fn ao_record() -> Record {
    Record {
        name: RecordName::Unknown {
            namespace: MVAO_NAMESPACE.into(),
            name: AO_ATTRIBUTE.into(),
        },
        data_type: RecordDataType::UNIT_F32,
    }
}

/// Output colours of a result, as the PLY writer makes them: without input colours (or
/// with [`ColorMode::Replace`]) the grey `ao^(1/γ)`; [`ColorMode::Modulate`] multiplies the
/// input colour by it; [`ColorMode::Keep`] keeps the input colour. Records whose colour is
/// flagged invalid (`valid[k] == false`) get the grey.
pub fn result_colours(
    input: Option<&[[u8; 3]]>,
    valid: Option<&[bool]>,
    ao: &[f32],
    gamma: f32,
    color: ColorMode,
) -> Vec<[u8; 3]> {
    ao.par_iter()
        .enumerate()
        .map(|(k, &a)| {
            let g = grey(a, gamma);
            let own = input
                .and_then(|c| c.get(k))
                .filter(|_| valid.is_none_or(|v| v.get(k).copied().unwrap_or(true)));
            match (own, color) {
                (Some(c), ColorMode::Keep) => *c,
                (Some(c), ColorMode::Modulate) => {
                    c.map(|v| (v as f32 * g as f32 / 255.0).round().clamp(0.0, 255.0) as u8)
                }
                _ => [g; 3],
            }
        })
        .collect()
}

/// Checks that `ao` has one finite value per record of scan `name`.
fn check_ao(path: &Path, name: &str, ao: &[f32], n: usize) -> Result<()> {
    if ao.len() != n {
        return Err(Error::Param(format!(
            "{}: scan {name}: {} AO values for {n} records (internal error)",
            path.display(),
            ao.len()
        )));
    }
    if ao.iter().any(|a| !a.is_finite()) {
        return Err(Error::Param(format!(
            "{}: scan {name}: refusing to write a non-finite ao value (internal error)",
            path.display()
        )));
    }
    Ok(())
}

/// A GUID in the usual `{8-4-4-4-12}` form, derived from `seed` so outputs are reproducible.
fn derived_guid(seed: &str) -> String {
    let h = xxhash_rust::xxh3::xxh3_128(seed.as_bytes());
    let x = format!("{h:032X}");
    format!(
        "{{{}-{}-{}-{}-{}}}",
        &x[0..8],
        &x[8..12],
        &x[12..16],
        &x[16..20],
        &x[20..32]
    )
}

/// An E57 name (namespace or attribute) the format accepts.
fn valid_xml_name(s: &str) -> bool {
    !s.is_empty()
        && !s.to_ascii_lowercase().starts_with("xml")
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

/// `name` as an attribute name the format accepts, not yet in `used` (which it joins).
fn attribute_name(name: &str, used: &mut Vec<String>) -> String {
    let mut s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if !valid_xml_name(&s) || s.starts_with(|c: char| c.is_ascii_digit() || c == '-') {
        s = format!("x_{s}");
    }
    let base = s.clone();
    let mut j = 1;
    while used.contains(&s) {
        s = format!("{base}_{j}");
        j += 1;
    }
    used.push(s.clone());
    s
}

/// A rigid pose as an E57 transform (unit quaternion with w ≥ 0, translation).
fn transform_of(pose: DMat4) -> Transform {
    let q = DQuat::from_mat3(&DMat3::from_mat4(pose)).normalize();
    let q = if q.w < 0.0 { -q } else { q };
    let t = pose.w_axis;
    Transform {
        rotation: Quaternion {
            w: q.w,
            x: q.x,
            y: q.y,
            z: q.z,
        },
        translation: Translation {
            x: t.x,
            y: t.y,
            z: t.z,
        },
    }
}

/// One point cloud to write.
struct CloudOut<'a> {
    guid: String,
    name: Option<String>,
    /// Descriptor whose description and sensor metadata are copied.
    meta: Option<&'a PointCloud>,
    transform: Option<Transform>,
    original_guids: Option<Vec<String>>,
    intensity_limits: Option<IntensityLimits>,
    color_limits: Option<ColorLimits>,
    /// Stored index bounds, widened to the data.
    index_bounds: Option<IndexBounds>,
    records: Vec<(Record, Cow<'a, Column>)>,
    len: usize,
}

/// Writes `clouds` as one E57 file, atomically.
fn write_clouds(
    out: &Path,
    file_guid: &str,
    coordinate_metadata: Option<String>,
    extensions: &[Extension],
    clouds: &[CloudOut],
) -> Result<()> {
    let other = |name: &str, e: ::e57::Error| std::io::Error::other(format!("scan {name}: {e}"));
    write_atomic_seekable(out, |file| {
        let mut w = E57Writer::new(file, file_guid).map_err(std::io::Error::other)?;
        for e in extensions {
            w.register_extension(e.clone())
                .map_err(std::io::Error::other)?;
        }
        w.set_coordinate_metadata(coordinate_metadata);
        for c in clouds {
            let label = c.name.clone().unwrap_or_else(|| c.guid.clone());
            let proto: Vec<Record> = c.records.iter().map(|(r, _)| r.clone()).collect();
            let mut pw = w
                .add_pointcloud(&c.guid, proto)
                .map_err(|e| other(&label, e))?;
            pw.set_name(c.name.clone());
            pw.set_transform(c.transform.clone());
            pw.set_original_guids(c.original_guids.clone());
            if let Some(m) = c.meta {
                pw.set_description(m.description.clone());
                pw.set_sensor_vendor(m.sensor_vendor.clone());
                pw.set_sensor_model(m.sensor_model.clone());
                pw.set_sensor_serial(m.sensor_serial.clone());
                pw.set_sensor_hw_version(m.sensor_hw_version.clone());
                pw.set_sensor_sw_version(m.sensor_sw_version.clone());
                pw.set_sensor_fw_version(m.sensor_fw_version.clone());
                pw.set_temperature(m.temperature);
                pw.set_humidity(m.humidity);
                pw.set_atmospheric_pressure(m.atmospheric_pressure);
                pw.set_acquisition_start(m.acquisition_start.clone());
                pw.set_acquisition_end(m.acquisition_end.clone());
            }
            if c.intensity_limits.is_some() {
                pw.set_intensity_limits(c.intensity_limits.clone());
            }
            if c.color_limits.is_some() {
                pw.set_color_limits(c.color_limits.clone());
            }
            for k in 0..c.len {
                // The crate takes one vector per record.
                let values = c
                    .records
                    .iter()
                    .map(|(r, col)| col.record_value(k, &r.data_type))
                    .collect();
                pw.add_point(values).map_err(|e| other(&label, e))?;
            }
            if let Some(b) = &c.index_bounds {
                // After the last point, as the crate requires; never narrower than the data.
                let data = |n: RecordName| {
                    c.records
                        .iter()
                        .find(|(r, _)| r.name == n)
                        .and_then(|(_, col)| col.min_max_int())
                };
                let widen = |lo: Option<i64>, hi: Option<i64>, d: Option<(i64, i64)>| match d {
                    Some((a, b)) => (
                        Some(lo.map_or(a, |l| l.min(a))),
                        Some(hi.map_or(b, |h| h.max(b))),
                    ),
                    None => (lo, hi),
                };
                let (row_min, row_max) = widen(b.row_min, b.row_max, data(RecordName::RowIndex));
                let (column_min, column_max) =
                    widen(b.column_min, b.column_max, data(RecordName::ColumnIndex));
                let (return_min, return_max) =
                    widen(b.return_min, b.return_max, data(RecordName::ReturnIndex));
                pw.set_index_bounds(Some(IndexBounds {
                    row_min,
                    row_max,
                    column_min,
                    column_max,
                    return_min,
                    return_max,
                }));
            }
            pw.finalize().map_err(|e| other(&label, e))?;
        }
        w.finalize().map_err(std::io::Error::other)?;
        Ok(())
    })
}

/// The extensions a result file declares: the input's valid ones and `mvao`.
fn output_extensions(input: &[Extension]) -> Vec<Extension> {
    let mut ext: Vec<Extension> = Vec::with_capacity(input.len() + 1);
    for e in input {
        if e.namespace != MVAO_NAMESPACE
            && valid_xml_name(&e.namespace)
            && !ext.iter().any(|x| x.namespace == e.namespace)
        {
            ext.push(e.clone());
        }
    }
    ext.push(Extension::new(MVAO_NAMESPACE, MVAO_NAMESPACE_URI));
    ext
}

/// Writes the result of `input`: every scan with its AO (`ao[k]` has one value per record of
/// scan `k`, finite), grey colours `ao^(1/gamma)` treated by `color`, to `out`, atomically.
/// See the module documentation for what is kept.
pub fn write_e57(
    input: &E57Input,
    ao: &[Vec<f32>],
    gamma: f32,
    color: ColorMode,
    out: &Path,
) -> Result<()> {
    if ao.len() != input.scans.len() {
        return Err(Error::Param(format!(
            "{}: {} AO arrays for {} scans (internal error)",
            out.display(),
            ao.len(),
            input.scans.len()
        )));
    }
    for (s, a) in input.scans.iter().zip(ao) {
        check_ao(out, &s.name, a, s.len())?;
    }
    let extensions = output_extensions(&input.extensions);
    let clouds: Vec<CloudOut> = input
        .scans
        .iter()
        .zip(ao)
        .map(|(s, a)| s.result_cloud(a, gamma, color, &extensions))
        .collect();
    write_clouds(
        out,
        &derived_guid(&format!("mvao result of {}", input.guid)),
        input.coordinate_metadata.clone(),
        &extensions,
        &clouds,
    )
}

/// Columns of a generated scan: coordinates, intensity, colour, grid.
fn simple_records(
    out: &Path,
    name: &str,
    xyz: &[[f64; 3]],
    spherical: bool,
    intensity: Option<&[f32]>,
    rgb: Option<&[[u8; 3]]>,
    grid: Option<&RawGrid>,
) -> Result<Vec<(Record, Cow<'static, Column>)>> {
    let n = xyz.len();
    let bad = |what: &str, len: usize| {
        Error::Param(format!(
            "{}: scan {name}: {len} {what} for {n} points",
            out.display()
        ))
    };
    let mut rec: Vec<(Record, Cow<'static, Column>)> = Vec::with_capacity(9);
    let valid = |p: &[f64; 3]| p.iter().all(|v| v.is_finite());
    let any_invalid = xyz.par_iter().any(|p| !valid(p));
    if spherical {
        let rae: Vec<[f64; 3]> = xyz
            .par_iter()
            .map(|p| {
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                if valid(p) && r > 0.0 {
                    [r, p[1].atan2(p[0]), (p[2] / r).clamp(-1.0, 1.0).asin()]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        for (i, r) in [
            Record::SPHERICAL_RANGE_F64,
            Record::SPHERICAL_AZIMUTH_F64,
            Record::SPHERICAL_ELEVATION_F64,
        ]
        .into_iter()
        .enumerate()
        {
            let c = rae.iter().map(|v| v[i]).collect();
            rec.push((r, Cow::Owned(Column::F64(c))));
        }
        let zero = |p: &[f64; 3]| p.iter().all(|v| *v == 0.0);
        if any_invalid || xyz.iter().any(zero) {
            let c = xyz
                .iter()
                .map(|p| if valid(p) && !zero(p) { 0 } else { 2 })
                .collect();
            rec.push((Record::SPHERICAL_INVALID_STATE, Cow::Owned(Column::U8(c))));
        }
    } else {
        for (i, r) in [
            Record::CARTESIAN_X_F64,
            Record::CARTESIAN_Y_F64,
            Record::CARTESIAN_Z_F64,
        ]
        .into_iter()
        .enumerate()
        {
            let c = xyz
                .par_iter()
                .map(|p| if valid(p) { p[i] } else { 0.0 })
                .collect();
            rec.push((r, Cow::Owned(Column::F64(c))));
        }
        if any_invalid {
            let c = xyz.iter().map(|p| if valid(p) { 0 } else { 2 }).collect();
            rec.push((Record::CARTESIAN_INVALID_STATE, Cow::Owned(Column::U8(c))));
        }
    }
    if let Some(i) = intensity {
        if i.len() != n {
            return Err(bad("intensities", i.len()));
        }
        let c = i
            .iter()
            .map(|v| {
                if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        rec.push((Record::INTENSITY_UNIT_F32, Cow::Owned(Column::F32(c))));
    }
    if let Some(rgb) = rgb {
        if rgb.len() != n {
            return Err(bad("colours", rgb.len()));
        }
        for (ch, r) in [
            Record::COLOR_RED_U8,
            Record::COLOR_GREEN_U8,
            Record::COLOR_BLUE_U8,
        ]
        .into_iter()
        .enumerate()
        {
            let c = rgb.iter().map(|p| p[ch]).collect();
            rec.push((r, Cow::Owned(Column::U8(c))));
        }
    }
    if let Some(g) = grid {
        if g.row.len() != n || g.col.len() != n {
            return Err(bad("grid cells", g.row.len().min(g.col.len())));
        }
        if g.row.iter().any(|&r| r >= g.rows) || g.col.iter().any(|&c| c >= g.cols) {
            return Err(Error::Param(format!(
                "{}: scan {name}: a grid cell lies outside the {} × {} grid",
                out.display(),
                g.rows,
                g.cols
            )));
        }
        for (name, idx, len) in [
            (RecordName::RowIndex, &g.row, g.rows),
            (RecordName::ColumnIndex, &g.col, g.cols),
        ] {
            let max = len.saturating_sub(1) as i64;
            let dt = RecordDataType::Integer { min: 0, max };
            let col = if max <= u16::MAX as i64 {
                Column::U16(idx.iter().map(|&v| v as u16).collect())
            } else {
                Column::I64(idx.iter().map(|&v| v as i64).collect())
            };
            rec.push((
                Record {
                    name,
                    data_type: dt,
                },
                Cow::Owned(col),
            ));
        }
    }
    Ok(rec)
}

/// Writes `scans` as one E57 file (synthetic stations with known poses and grids; the
/// virtual scanner), atomically. Scans get GUIDs derived from their name and position.
pub fn write_e57_scans(scans: &[E57ScanOut], out: &Path) -> Result<()> {
    let mut clouds = Vec::with_capacity(scans.len());
    for (k, s) in scans.iter().enumerate() {
        let transform = match s.pose {
            Some(p) => Some(transform_of(check_rigid(p, out, &s.name)?)),
            None => None,
        };
        let records = simple_records(
            out,
            &s.name,
            &s.xyz,
            s.spherical,
            s.intensity.as_deref(),
            s.rgb.as_deref(),
            s.grid.as_ref(),
        )?;
        clouds.push(CloudOut {
            guid: derived_guid(&format!("mvao scan {k} {}", s.name)),
            name: Some(s.name.clone()),
            meta: None,
            transform,
            original_guids: None,
            intensity_limits: None,
            color_limits: None,
            index_bounds: None,
            records,
            len: s.xyz.len(),
        });
    }
    let seed: String = scans
        .iter()
        .map(|s| s.name.as_str())
        .collect::<Vec<_>>()
        .join("/");
    write_clouds(
        out,
        &derived_guid(&format!("mvao scans {seed}")),
        None,
        &[Extension::new(MVAO_NAMESPACE, MVAO_NAMESPACE_URI)],
        &clouds,
    )
}

/// Writes `tables` (results of other formats) as one E57 file, one scan per table with its
/// pose (must be rigid), Cartesian f64 coordinates (non-finite ones flagged invalid),
/// intensity, colours (the table's, else the AO grey), grid, `mvao:ao`, and every extra field
/// as an `mvao:` double attribute (name reduced to letters, digits, `_` and `-`; non-finite
/// values written as 0). Atomic.
pub fn write_table_e57(tables: &[PointTable], out: &Path) -> Result<()> {
    let mut clouds = Vec::with_capacity(tables.len());
    for (k, t) in tables.iter().enumerate() {
        check_ao(out, &t.name, &t.ao, t.len())?;
        let pose = check_rigid(t.pose, out, &t.name)?;
        let grey_rgb;
        let rgb = match &t.rgb {
            Some(c) => c.as_slice(),
            None => {
                grey_rgb = result_colours(None, None, &t.ao, 1.0, ColorMode::Replace);
                &grey_rgb
            }
        };
        let mut records = simple_records(
            out,
            &t.name,
            &t.xyz,
            false,
            t.intensity.as_deref(),
            Some(rgb),
            t.grid.as_ref(),
        )?;
        records.push((ao_record(), Cow::Owned(Column::F32(t.ao.clone()))));
        let mut used = vec![AO_ATTRIBUTE.to_string()];
        for (name, v) in &t.extra {
            if v.len() != t.len() {
                return Err(Error::Param(format!(
                    "{}: scan {}: field {name} has {} values for {} points",
                    out.display(),
                    t.name,
                    v.len(),
                    t.len()
                )));
            }
            let c = v
                .iter()
                .map(|x| if x.is_finite() { *x } else { 0.0 })
                .collect();
            records.push((
                Record {
                    name: RecordName::Unknown {
                        namespace: MVAO_NAMESPACE.into(),
                        name: attribute_name(name, &mut used),
                    },
                    data_type: RecordDataType::F64,
                },
                Cow::Owned(Column::F64(c)),
            ));
        }
        clouds.push(CloudOut {
            guid: derived_guid(&format!("mvao table {k} {}", t.name)),
            name: Some(t.name.clone()),
            meta: None,
            transform: Some(transform_of(pose)),
            original_guids: None,
            intensity_limits: None,
            color_limits: None,
            index_bounds: None,
            records,
            len: t.len(),
        });
    }
    let seed: String = tables
        .iter()
        .map(|s| s.name.as_str())
        .collect::<Vec<_>>()
        .join("/");
    write_clouds(
        out,
        &derived_guid(&format!("mvao tables {seed}")),
        None,
        &[Extension::new(MVAO_NAMESPACE, MVAO_NAMESPACE_URI)],
        &clouds,
    )
}

#[cfg(test)]
mod tests;
