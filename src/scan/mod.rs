//! A scan: points in its sensor's local frame (f32), a local → world pose (f64), optional
//! normals and native grid. Normals and radii are estimated here when the input has none.
//! No files, no images.

pub mod knn;
pub mod normals;
pub mod occupancy;

use glam::{DMat4, Vec3};
use rayon::prelude::*;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

/// Row and column of a point the native grid does not place (its reference in the file was
/// invalid): such a point is placed by the sensor model fitted to the grid.
pub const NO_CELL: u32 = u32::MAX;

/// A scan's native acquisition grid: the (row, column) of every valid point, so the grid
/// itself can serve as the range map instead of resampling.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// Number of rows of the grid.
    pub rows: u32,
    /// Number of columns of the grid.
    pub cols: u32,
    /// Row of each valid point (same order as [`Scan::points`]), [`NO_CELL`] for a point
    /// without a cell.
    pub row: Vec<u32>,
    /// Column of each valid point, [`NO_CELL`] for a point without a cell.
    pub col: Vec<u32>,
}

impl Grid {
    /// True when point `i` has a cell inside the grid.
    #[inline]
    pub fn has_cell(&self, i: usize) -> bool {
        self.row[i] < self.rows && self.col[i] < self.cols
    }

    /// Number of points without a cell inside the grid.
    pub fn uncelled(&self) -> usize {
        self.row
            .par_iter()
            .zip(self.col.par_iter())
            .filter(|&(&r, &c)| r >= self.rows || c >= self.cols)
            .count()
    }

    /// Number of distinct cells holding at least one point (never more than the points).
    pub fn occupied_cells(&self) -> usize {
        let cells = u64::from(self.rows) * u64::from(self.cols);
        let keys = || {
            self.row
                .par_iter()
                .zip(self.col.par_iter())
                .filter(|&(&r, &c)| r < self.rows && c < self.cols)
                .map(|(&r, &c)| u64::from(r) * u64::from(self.cols) + u64::from(c))
        };
        // A bitmap of the cells when it is no larger than a key per point (or small anyway);
        // a sparse grid of huge declared size sorts the keys instead.
        if cells <= (64 * self.row.len() as u64).max(1 << 27) {
            let words: Vec<AtomicU64> = (0..cells.div_ceil(64))
                .into_par_iter()
                .map(|_| AtomicU64::new(0))
                .collect();
            keys().for_each(|k| {
                words[(k / 64) as usize].fetch_or(1 << (k % 64), Ordering::Relaxed);
            });
            words
                .par_iter()
                .map(|w| w.load(Ordering::Relaxed).count_ones() as usize)
                .sum()
        } else {
            let mut v: Vec<u64> = keys().collect();
            v.par_sort_unstable();
            v.dedup();
            v.len()
        }
    }
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
    /// What reading the input found wrong and worked around (each names the file), passed
    /// on to the user when the scan is placed.
    pub warnings: Vec<String>,
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
            warnings: Vec::new(),
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
