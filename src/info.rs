//! `mvao info`: what `merge` would see in each scan — format, points, attributes, pose and
//! where it came from, grid, the sensor model it would fit, world bounds, and which other
//! scans it overlaps. Reads and fits, computes no AO.

use crate::error::{Error, Result};
use crate::io::dataset::{Dataset, PlaceOptions};
use crate::sensor::{self, ProjectionChoice};
use glam::DVec3;
use serde::Serialize;
use std::path::PathBuf;

/// One scan's description.
#[derive(Debug, Clone, Serialize)]
pub struct ScanInfo {
    /// Scan name.
    pub name: String,
    /// Input file.
    pub file: String,
    /// Format of the file.
    pub format: String,
    /// Records in the file (including invalid ones).
    pub records: usize,
    /// Points with finite coordinates.
    pub points: usize,
    /// Per-point attributes the file stores.
    pub attributes: Vec<String>,
    /// Local → world pose, row-major.
    pub pose: [[f64; 4]; 4],
    /// Where the pose came from.
    pub pose_source: String,
    /// `[rows, cols]` of the native grid, if any.
    pub grid: Option<[u32; 2]>,
    /// Filled share of the native grid.
    pub grid_filled: Option<f64>,
    /// Scanner position in world coordinates.
    pub scanner: [f64; 3],
    /// Sensor model `merge` would use.
    pub sensor_model: String,
    /// Map size `[width, height]`.
    pub map_size: [usize; 2],
    /// Why that model.
    pub sensor_reason: String,
    /// World bounding box `[min, max]`.
    pub bounds: [[f64; 3]; 2],
    /// Names of the scans whose bounds meet this one's.
    pub overlaps: Vec<String>,
}

/// The description of a dataset.
#[derive(Debug, Clone, Serialize)]
pub struct Info {
    /// Alignment file used.
    pub alignment: Option<String>,
    /// Warnings from reading and placing.
    pub warnings: Vec<String>,
    /// Per scan.
    pub scans: Vec<ScanInfo>,
    /// Files that could not be read and scans no sensor model fits, each with what is wrong
    /// (naming the file or scan).
    pub problems: Vec<String>,
}

/// Describes the scans of `paths`. It never refuses to describe a file for a placement
/// problem (an alignment that does not name it, a broken alignment or sidecar): that is a
/// warning and the scan is described as it is. A file that cannot be read, or a scan no sensor
/// model fits, is listed in [`Info::problems`] and the others are still described.
pub fn describe(paths: &[PathBuf], place: &PlaceOptions, choice: ProjectionChoice) -> Result<Info> {
    let (ds, unreadable) = Dataset::describe(paths, place)?;
    let mut problems: Vec<String> = unreadable.iter().map(ToString::to_string).collect();
    let mut scans = Vec::with_capacity(ds.scans.len());
    let bounds: Vec<(DVec3, DVec3)> = ds.scans.iter().map(crate::pipeline::world_bounds).collect();
    for (i, s) in ds.scans.iter().enumerate() {
        let (fi, k) = ds.origin[i];
        let f = &ds.files[fi];
        let setup = match sensor::setup(s, choice) {
            Ok(setup) => setup,
            Err(e) => {
                problems.push(e.to_string());
                continue;
            }
        };
        let p = &setup.projection;
        let b = bounds[i];
        // Boxes meeting within 1 ‰ of their size (rounding) count as overlapping.
        let overlaps = (0..ds.scans.len())
            .filter(|&j| j != i)
            .filter(|&j| {
                let m = 1e-3 * ((b.1 - b.0).length() + (bounds[j].1 - bounds[j].0).length());
                (b.0 - m).cmple(bounds[j].1).all() && (bounds[j].0 - m).cmple(b.1).all()
            })
            .map(|j| ds.scans[j].name.clone())
            .collect();
        let m = s.pose;
        scans.push(ScanInfo {
            name: s.name.clone(),
            file: f.path.display().to_string(),
            format: f.format.to_string(),
            records: s.vertex_count,
            points: s.len(),
            attributes: f.container.attributes(k),
            pose: [0, 1, 2, 3].map(|r| m.row(r).to_array()),
            pose_source: ds.pose_source[i].clone(),
            grid: s.grid.as_ref().map(|g| [g.rows, g.cols]),
            // Distinct cells: points sharing a cell fill it once.
            grid_filled: s.grid.as_ref().map(|g| {
                let cells = g.rows as f64 * g.cols as f64;
                if cells > 0.0 {
                    g.occupied_cells() as f64 / cells
                } else {
                    0.0
                }
            }),
            scanner: m.w_axis.truncate().to_array(),
            sensor_model: p.sensor_model().to_string(),
            map_size: [p.width, p.height],
            sensor_reason: setup.reason.clone(),
            bounds: [b.0.to_array(), b.1.to_array()],
            overlaps,
        });
    }
    Ok(Info {
        alignment: ds.alignment.map(|a| a.display().to_string()),
        warnings: ds.warnings,
        scans,
        problems,
    })
}

impl Info {
    /// The exit status of `mvao info`: an error when something could not be described (the
    /// problem itself when there is one), after everything else was.
    pub fn status(&self) -> Result<()> {
        match self.problems.as_slice() {
            [] => Ok(()),
            [one] => Err(Error::Param(one.clone())),
            [first, rest @ ..] => Err(Error::Param(format!(
                "{first} (and {} more problems, listed above)",
                rest.len()
            ))),
        }
    }
}
