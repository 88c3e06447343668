//! What every format reader hands over and what every cross-format writer takes: a scan's
//! records in file coordinates (f64), and a flat table of attributes for writing a result in
//! another format than the input's. Same-format outputs do not go through these types: they
//! reuse the parsed file so every original field is kept bit for bit.

use crate::projection::SensorModel;
use glam::{DMat4, DVec3, Vec3};

/// One scan as a format reader hands it over, before it becomes a [`Scan`](crate::scan::Scan).
#[derive(Debug, Clone)]
pub struct RawScan {
    /// Scan name: the file stem for one-scan files, the stored name (or `<stem>_<k>`) for
    /// multi-scan containers. Used in messages and output names.
    pub name: String,
    /// Every record's coordinates in the file's frame (metres, f64). A record without a
    /// valid return (PTX zero point, E57 invalid state) has non-finite coordinates; it is
    /// skipped by the pipeline but its slot is kept so outputs line up with the input.
    pub xyz: Vec<[f64; 3]>,
    /// Unit normals per record, when the file has them.
    pub normals: Option<Vec<Vec3>>,
    /// Native grid: `(rows, cols, row per record, column per record)`.
    pub grid: Option<RawGrid>,
    /// File frame → world, when the file carries a pose (E57 `pose`, PTX registration).
    pub pose: Option<DMat4>,
    /// The scanner position in the file frame, when the file says (PTX header, E57 pose
    /// origin). `None` = unknown: the file frame's origin is assumed unless the data is far
    /// from it.
    pub scanner: Option<DVec3>,
    /// The sensor model the file declares.
    pub sensor_hint: Option<SensorModel>,
    /// What the reader found wrong and worked around (each names the file).
    pub warnings: Vec<String>,
}

/// A native acquisition grid of a [`RawScan`], one cell per record.
#[derive(Debug, Clone, PartialEq)]
pub struct RawGrid {
    /// Number of rows.
    pub rows: u32,
    /// Number of columns.
    pub cols: u32,
    /// Row of each record ([`crate::scan::NO_CELL`] for a record without a cell).
    pub row: Vec<u32>,
    /// Column of each record ([`crate::scan::NO_CELL`] for a record without a cell).
    pub col: Vec<u32>,
}

/// A flat per-point attribute table for writing a result in another format than the input's:
/// world coordinates (f64), optional colour and intensity, the AO and any extra scalars.
#[derive(Debug, Clone, Default)]
pub struct PointTable {
    /// Scan name (E57 writers store it as the scan's name).
    pub name: String,
    /// Coordinates (metres, f64) in `pose`'s source frame.
    pub xyz: Vec<[f64; 3]>,
    /// Frame of `xyz` → world; identity when `xyz` is already in world coordinates.
    pub pose: DMat4,
    /// Colour per point, 8 bits per channel (the AO grey or the modulated input colour).
    pub rgb: Option<Vec<[u8; 3]>>,
    /// Intensity per point in [0, 1], when the input had one.
    pub intensity: Option<Vec<f32>>,
    /// Ambient occlusion per point in [0, 1] (1 = open).
    pub ao: Vec<f32>,
    /// Native grid, when the input had one.
    pub grid: Option<RawGrid>,
    /// Further named scalar fields per point (kept from the input where the format allows).
    pub extra: Vec<(String, Vec<f64>)>,
}

impl PointTable {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.xyz.len()
    }

    /// True when the table has no point.
    pub fn is_empty(&self) -> bool {
        self.xyz.is_empty()
    }

    /// World coordinates of point `k`.
    pub fn world(&self, k: usize) -> DVec3 {
        self.pose.transform_point3(DVec3::from(self.xyz[k]))
    }
}
