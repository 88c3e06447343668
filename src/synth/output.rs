//! Writing synthetic scans: binary PLY files with points, normals and grid cells, and header
//! comments describing the station that produced them.

use super::scanner::Station;
use crate::error::{Error, Result};
use crate::io::ply::{PlyFile, ScalarType};
use crate::projection::SensorModel;
use crate::scan::Scan;
use std::path::Path;

/// `comment` lines describing a station for a scan's PLY header: sensor model and map size,
/// world position and yaw, and the model's parameters (angles in degrees).
pub fn describe_station(station: &Station) -> Vec<String> {
    let p = station.position;
    let mut out = vec![
        format!(
            "sensor {} {}x{}",
            station.model, station.width, station.height
        ),
        format!(
            "station position {:.6} {:.6} {:.6} yaw_deg {:.6}",
            p.x,
            p.y,
            p.z,
            station.yaw.to_degrees()
        ),
    ];
    out.push(match station.model {
        SensorModel::Equirect => format!(
            "equirect elevation_deg {:.6} {:.6}",
            station.elevation[0].to_degrees(),
            station.elevation[1].to_degrees()
        ),
        SensorModel::Perspective => format!(
            "perspective hfov_deg {:.6} pitch_deg {:.6}",
            station.fov.to_degrees(),
            station.pitch.to_degrees()
        ),
        SensorModel::Ortho => format!(
            "ortho half_extent_m {:.6} {:.6} looking down local -z",
            station.half_extent.x, station.half_extent.y
        ),
    });
    out.push(format!("max_range_m {}", station.max_range));
    out
}

/// Writes `scan` as a binary PLY: `float x y z`, `float nx ny nz` (if the scan has normals),
/// `int row col` (if it has a grid), with `comments` in the header.
pub fn write_scan_ply(scan: &Scan, path: &Path, comments: &[String]) -> Result<()> {
    let n = scan.len();
    let mut cols: Vec<(&str, ScalarType, Vec<f64>)> = Vec::with_capacity(8);
    for (k, name) in ["x", "y", "z"].into_iter().enumerate() {
        cols.push((
            name,
            ScalarType::F32,
            scan.points.iter().map(|p| p[k] as f64).collect(),
        ));
    }
    if let Some(normals) = &scan.normals {
        if normals.len() != n {
            return Err(Error::scan(
                &scan.name,
                "normals and points differ in count",
            ));
        }
        for (k, name) in ["nx", "ny", "nz"].into_iter().enumerate() {
            cols.push((
                name,
                ScalarType::F32,
                normals.iter().map(|v| v[k] as f64).collect(),
            ));
        }
    }
    if let Some(g) = &scan.grid {
        if g.row.len() != n || g.col.len() != n {
            return Err(Error::scan(&scan.name, "grid and points differ in count"));
        }
        cols.push((
            "row",
            ScalarType::I32,
            g.row.iter().map(|&r| r as f64).collect(),
        ));
        cols.push((
            "col",
            ScalarType::I32,
            g.col.iter().map(|&c| c as f64).collect(),
        ));
    }
    let refs: Vec<(&str, ScalarType, &[f64])> = cols
        .iter()
        .map(|(n, t, v)| (*n, *t, v.as_slice()))
        .collect();
    PlyFile::from_vertex_columns(&refs, comments)?.write_path(path)
}
