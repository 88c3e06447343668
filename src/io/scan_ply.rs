//! A PLY file as a [`Scan`]: coordinates, optional normals, and the native grid when the file
//! has one — a Stanford `range_grid` element (`num_cols`/`num_rows` in `obj_info`) or
//! per-vertex `row`/`col` indices. Vertices with non-finite coordinates are skipped and counted.

use super::ply::PlyFile;
use super::raw::{RawGrid, RawScan};
use crate::error::{Error, Result};
use crate::projection::SensorModel;
use crate::scan::{Grid, Scan};
use glam::Vec3;
use rayon::prelude::*;
use std::path::Path;

/// Names accepted for per-vertex grid indices, as (row, column) pairs.
const ROW_COL_NAMES: [(&str, &str); 3] = [
    ("row", "col"),
    ("row_index", "column_index"),
    ("rowIndex", "columnIndex"),
];

/// Reads `path` as a scan (identity pose) and returns it with the parsed file, which the
/// writer reuses so every input property is kept.
pub fn read_scan(path: &Path) -> Result<(Scan, PlyFile)> {
    let ply = PlyFile::read_path(path)?;
    let scan = scan_from_ply(&ply, path)?;
    Ok((scan, ply))
}

/// Builds a [`Scan`] from a parsed PLY file.
pub fn scan_from_ply(ply: &PlyFile, path: &Path) -> Result<Scan> {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string());
    Ok(super::source::scan_from_raw(raw_from_ply(ply, path, &stem)?, path)?.0)
}

/// What a PLY file holds of a scan: coordinates, normals when all three components are
/// present, the native grid (Stanford `range_grid` or per-vertex row/column indices) and the
/// declared sensor model.
pub fn raw_from_ply(ply: &PlyFile, path: &Path, name: &str) -> Result<RawScan> {
    for c in ["x", "y", "z"] {
        if !ply.has_property("vertex", c) {
            return Err(Error::format(
                path,
                format!("vertex element has no '{c}' coordinate"),
            ));
        }
    }
    let xyz = ply
        .vertex_xyz()
        .ok_or_else(|| Error::format(path, "cannot read x/y/z of the vertex element"))?;
    let n = xyz.len();
    let normals = ply.map_scalars("vertex", ["nx", "ny", "nz"], |[x, y, z]| {
        Vec3::new(x as f32, y as f32, z as f32)
    });
    // Vertices missing from the grid are marked with u32::MAX, which lies outside any grid.
    let grid = grid_cells(ply, n).map(|g| RawGrid {
        rows: g.rows,
        cols: g.cols,
        row: g.row,
        col: g.col,
    });
    Ok(RawScan {
        name: name.to_string(),
        xyz,
        normals,
        grid,
        pose: None,
        scanner: None,
        sensor_hint: sensor_hint(ply),
    })
}

pub use super::source::RECENTRE_ABOVE;

/// A `comment sensor <equirect|perspective|ortho> …` line declares the sensor model.
fn sensor_hint(ply: &PlyFile) -> Option<SensorModel> {
    ply.header.comments.iter().find_map(|c| {
        let mut it = c.split_whitespace();
        if it.next()? != "sensor" {
            return None;
        }
        match it.next()? {
            "equirect" | "equirectangular" | "spherical" => Some(SensorModel::Equirect),
            "perspective" | "pinhole" => Some(SensorModel::Perspective),
            "ortho" | "orthographic" => Some(SensorModel::Ortho),
            _ => None,
        }
    })
}

/// The grid cell of every vertex (`u32::MAX` where a vertex has none), if the file has a
/// consistent grid.
fn grid_cells(ply: &PlyFile, n: usize) -> Option<Grid> {
    if let Some(g) = range_grid(ply, n) {
        return Some(g);
    }
    for (rn, cn) in ROW_COL_NAMES {
        let ok = |v: f64| (0.0..1e7).contains(&v) && f64::from(v as u32) == v;
        // A whole number below 10⁷ is never u32::MAX, which marks a value that is not.
        let Some(rc) = ply.map_scalars("vertex", [rn, cn], |[r, c]| {
            if ok(r) && ok(c) {
                (r as u32, c as u32)
            } else {
                (u32::MAX, u32::MAX)
            }
        }) else {
            continue;
        };
        if rc.is_empty() || rc.par_iter().any(|&(r, _)| r == u32::MAX) {
            return None;
        }
        let (row, col): (Vec<u32>, Vec<u32>) = rc.into_par_iter().unzip();
        let rows = row.par_iter().max().map_or(0, |m| m + 1);
        let cols = col.par_iter().max().map_or(0, |m| m + 1);
        return Some(Grid {
            rows,
            cols,
            row,
            col,
        });
    }
    None
}

/// A Stanford `range_grid` element: entry `row·num_cols + col` lists the vertex stored there.
fn range_grid(ply: &PlyFile, n: usize) -> Option<Grid> {
    let lists = ply.list_column("range_grid", "vertex_indices")?;
    let info = |key: &str| -> Option<u32> {
        ply.header.obj_info.iter().find_map(|l| {
            let mut it = l.split_whitespace();
            (it.next()? == key).then(|| it.next()?.parse().ok())?
        })
    };
    let (cols, rows) = (info("num_cols")?, info("num_rows")?);
    if cols as usize * rows as usize != lists.len() {
        return None;
    }
    let mut row = vec![u32::MAX; n];
    let mut col = vec![u32::MAX; n];
    for (e, l) in lists.iter().enumerate() {
        for &v in l {
            let v = v as usize;
            if v >= n {
                return None;
            }
            row[v] = (e / cols as usize) as u32;
            col[v] = (e % cols as usize) as u32;
        }
    }
    Some(Grid {
        rows,
        cols,
        row,
        col,
    })
}
