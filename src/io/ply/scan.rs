//! A PLY file as a [`Scan`]: coordinates, optional normals, and the native grid when the file
//! has one — a Stanford `range_grid` element (`num_cols`/`num_rows` in `obj_info`) or
//! per-vertex `row`/`col` indices. Vertices with non-finite coordinates are skipped and counted.
//! A grid's bad references are dropped with a warning; a grid mostly bad, or whose declared
//! size does not match, is ignored with a warning.

use super::PlyFile;
use crate::error::{Error, Result};
use crate::io::raw::{RawGrid, RawScan};
use crate::io::source::{GRID_IGNORED, MAX_GRID_DEFECTS};
use crate::projection::SensorModel;
use crate::scan::{Scan, NO_CELL};
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
    let ply = PlyFile::from_path(path)?;
    let scan = scan_from_ply(&ply, path)?;
    Ok((scan, ply))
}

/// Builds a [`Scan`] from a parsed PLY file.
pub fn scan_from_ply(ply: &PlyFile, path: &Path) -> Result<Scan> {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string());
    Ok(crate::io::source::scan_from_raw(raw_from_ply(ply, path, &stem)?, path)?.0)
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
    let normals = ply.map_scalars("vertex", ["nx", "ny", "nz"], |[x, y, z]| {
        Vec3::new(x as f32, y as f32, z as f32)
    });
    let (grid, warnings) = grid_cells(ply, &xyz, path);
    Ok(RawScan {
        name: name.to_string(),
        xyz,
        normals,
        grid,
        pose: None,
        scanner: None,
        sensor_hint: sensor_hint(ply),
        warnings,
    })
}

pub use crate::io::source::RECENTRE_ABOVE;

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

/// The native grid of the file, every vertex's cell ([`NO_CELL`] where it has none), and
/// what was wrong with it as warnings naming `path`. A grid with a few bad references keeps
/// its other cells; one whose size is inconsistent or whose references are mostly bad is
/// dropped with a warning.
fn grid_cells(ply: &PlyFile, xyz: &[[f64; 3]], path: &Path) -> (Option<RawGrid>, Vec<String>) {
    let n = xyz.len();
    if let Some(lists) = ply.list_indices("range_grid", "vertex_indices") {
        return range_grid(ply, n, &lists, path);
    }
    let mut warnings = Vec::new();
    if ply.element("range_grid").is_some() {
        warnings.push(format!(
            "{}: the range_grid element has no readable vertex_indices list; {GRID_IGNORED}",
            path.display()
        ));
    }
    for (rn, cn) in ROW_COL_NAMES {
        let ok = |v: f64| (0.0..1e7).contains(&v) && f64::from(v as u32) == v;
        // A whole number below 10⁷ is never NO_CELL, which marks a value that is not.
        let Some(rc) = ply.map_scalars("vertex", [rn, cn], |[r, c]| {
            if ok(r) && ok(c) {
                (r as u32, c as u32)
            } else {
                (NO_CELL, NO_CELL)
            }
        }) else {
            continue;
        };
        if rc.is_empty() {
            return (None, warnings);
        }
        // Vertices without coordinates are skipped anyway: their indices do not matter.
        let bad = rc
            .par_iter()
            .zip(xyz)
            .filter(|&(&(r, _), p)| r == NO_CELL && p.iter().all(|v| v.is_finite()))
            .count();
        if bad > 0 {
            warnings.push(format!(
                "{}: {bad} vertices have {rn}/{cn} values that are not grid indices (negative, \
                 fractional or beyond 10^7)",
                path.display()
            ));
        }
        let (row, col): (Vec<u32>, Vec<u32>) = rc.into_par_iter().unzip();
        let size = |v: &[u32]| {
            v.par_iter()
                .filter(|&&x| x != NO_CELL)
                .max()
                .map_or(0, |m| m + 1)
        };
        let (rows, cols) = (size(&row), size(&col));
        return (
            Some(RawGrid {
                rows,
                cols,
                row,
                col,
            }),
            warnings,
        );
    }
    (None, warnings)
}

/// A Stanford `range_grid` element (`lists`): entry `row·num_cols + col` lists the vertices
/// stored there. References to no vertex of the file, and repeats of a vertex already placed
/// in another cell, are dropped; beyond [`MAX_GRID_DEFECTS`] of them the grid is.
fn range_grid(
    ply: &PlyFile,
    n: usize,
    lists: &[Vec<u32>],
    path: &Path,
) -> (Option<RawGrid>, Vec<String>) {
    let info = |key: &str| -> Option<u32> {
        ply.header.obj_info.iter().find_map(|l| {
            let mut it = l.split_whitespace();
            (it.next()? == key).then(|| it.next()?.parse().ok())?
        })
    };
    let ignored = |why: String| {
        (
            None,
            vec![format!("{}: {why}; {GRID_IGNORED}", path.display())],
        )
    };
    let (Some(cols), Some(rows)) = (info("num_cols"), info("num_rows")) else {
        return ignored(format!(
            "the range_grid element has {} entries but obj_info gives no usable num_cols and \
             num_rows",
            lists.len()
        ));
    };
    if u64::from(cols) * u64::from(rows) != lists.len() as u64 {
        return ignored(format!(
            "obj_info declares num_cols {cols} × num_rows {rows} = {} cells but the range_grid \
             element has {} entries",
            u64::from(cols) * u64::from(rows),
            lists.len()
        ));
    }
    let mut row = vec![NO_CELL; n];
    let mut col = vec![NO_CELL; n];
    let (mut refs, mut outside, mut repeated) = (0usize, 0usize, 0usize);
    for (e, l) in lists.iter().enumerate() {
        // e < rows·cols, so both fit and neither is NO_CELL.
        let (r, c) = ((e / cols as usize) as u32, (e % cols as usize) as u32);
        for &v in l {
            refs += 1;
            let v = v as usize;
            if v >= n {
                outside += 1;
            } else if row[v] == NO_CELL {
                (row[v], col[v]) = (r, c);
            } else if (row[v], col[v]) != (r, c) {
                repeated += 1;
            }
        }
    }
    let bad = outside + repeated;
    let mut warnings = Vec::new();
    if bad > 0 {
        let mut what = Vec::new();
        if outside > 0 {
            what.push(format!(
                "{outside} with an index that is no vertex of the file (negative, fractional \
                 or not below {n})"
            ));
        }
        if repeated > 0 {
            what.push(format!(
                "{repeated} repeating a vertex already listed in another cell"
            ));
        }
        let what = what.join(", ");
        if bad as f64 > MAX_GRID_DEFECTS * refs as f64 {
            return ignored(format!(
                "{bad} of the {refs} range_grid references are invalid (more than {} %): {what}",
                MAX_GRID_DEFECTS * 100.0
            ));
        }
        warnings.push(format!(
            "{}: {bad} of the {refs} range_grid references dropped: {what}; the other cells \
             of the {cols} × {rows} grid are kept",
            path.display()
        ));
    }
    (
        Some(RawGrid {
            rows,
            cols,
            row,
            col,
        }),
        warnings,
    )
}
