//! E57 (ASTM E2807) scans in, results out, through the `e57` crate.
//!
//! **Reading** ([`E57Input::from_path`]) keeps every `data3D` point cloud as stored: coordinates stay in
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

mod read;
mod write;

use read::{find, Column};
use write::{check_ao, is_mvao_ao};
pub use write::{result_colours, write_e57, write_e57_scans, write_table_e57};

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
}

#[cfg(test)]
mod tests;
