//! A scan: points in its sensor's local frame (f32), a local → world pose (f64), optional
//! normals and native grid. Normals and radii are estimated here when the input has none.
//! No files, no images.

pub mod normals;
pub mod occupancy;

use glam::{DMat4, Vec3};
use std::path::PathBuf;

/// A scan's native acquisition grid: the (row, column) of every valid point, so the grid
/// itself can serve as the range map instead of resampling.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// Number of rows of the grid.
    pub rows: u32,
    /// Number of columns of the grid.
    pub cols: u32,
    /// Row of each valid point (same order as [`Scan::points`]).
    pub row: Vec<u32>,
    /// Column of each valid point.
    pub col: Vec<u32>,
}

/// One range scan in its sensor's local frame.
#[derive(Debug, Clone)]
pub struct Scan {
    /// Name used in messages and output file names (the input's file stem).
    pub name: String,
    /// The file it was read from, if any.
    pub path: Option<PathBuf>,
    /// Valid points (finite coordinates), scan-local, metres.
    pub points: Vec<Vec3>,
    /// For each valid point, its vertex index in the input file.
    pub source_index: Vec<u32>,
    /// Number of vertices in the input, including skipped ones.
    pub vertex_count: usize,
    /// Unit normals of the valid points, if the input had them (or once estimated).
    pub normals: Option<Vec<Vec3>>,
    /// Native grid, if the input has one.
    pub grid: Option<Grid>,
    /// Local → world transform.
    pub pose: DMat4,
    /// Vertices skipped for non-finite coordinates.
    pub skipped_nonfinite: usize,
    /// The sensor model the input declares (a PLY `comment sensor <model>` line, the virtual
    /// scanner); `--projection auto` fits only this model to the grid. Geometry alone cannot
    /// tell an orthographic view of a plane from a perspective one.
    pub sensor_hint: Option<crate::projection::SensorModel>,
}

impl Scan {
    /// A scan of `points` with identity pose and no normals or grid, every point valid.
    pub fn from_points(name: impl Into<String>, points: Vec<Vec3>) -> Scan {
        let n = points.len();
        Scan {
            name: name.into(),
            path: None,
            points,
            source_index: (0..n as u32).collect(),
            vertex_count: n,
            normals: None,
            grid: None,
            pose: DMat4::IDENTITY,
            skipped_nonfinite: 0,
            sensor_hint: None,
        }
    }

    /// Number of valid points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when the scan has no valid point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}
