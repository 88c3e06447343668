//! A PLY file as a [`Scan`]: coordinates, optional normals, and the native grid when the file
//! has one — a Stanford `range_grid` element (`num_cols`/`num_rows` in `obj_info`) or
//! per-vertex `row`/`col` indices. Vertices with non-finite coordinates are skipped and counted.

use super::ply::PlyFile;
use crate::error::{Error, Result};
use crate::projection::SensorModel;
use crate::scan::{Grid, Scan};
use glam::{DMat4, DVec3, Vec3};
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
    let vertex_count = xyz.len();
    let normals_in = if ["nx", "ny", "nz"]
        .iter()
        .all(|n| ply.has_property("vertex", n))
    {
        let cols: Vec<Vec<f64>> = ["nx", "ny", "nz"]
            .iter()
            .filter_map(|n| ply.scalar_column("vertex", n))
            .collect();
        (cols.len() == 3).then_some(cols)
    } else {
        None
    };
    let grid_cells = grid_cells(ply, vertex_count);

    let mut points = Vec::with_capacity(vertex_count);
    let mut source_index = Vec::with_capacity(vertex_count);
    let mut normals = normals_in
        .as_ref()
        .map(|_| Vec::with_capacity(vertex_count));
    let mut cells = grid_cells.as_ref().map(|_| {
        (
            Vec::with_capacity(vertex_count),
            Vec::with_capacity(vertex_count),
        )
    });
    let offset = recentre_offset(&xyz);
    let mut skipped = 0usize;
    for (i, p) in xyz.iter().enumerate() {
        let v = Vec3::new(
            (p[0] - offset.x) as f32,
            (p[1] - offset.y) as f32,
            (p[2] - offset.z) as f32,
        );
        if !v.is_finite() {
            skipped += 1;
            continue;
        }
        points.push(v);
        source_index.push(i as u32);
        if let (Some(out), Some(cols)) = (normals.as_mut(), normals_in.as_ref()) {
            let n = Vec3::new(cols[0][i] as f32, cols[1][i] as f32, cols[2][i] as f32);
            // An unusable normal becomes zero and is re-estimated downstream.
            out.push(n.try_normalize().unwrap_or(Vec3::ZERO));
        }
        if let (Some((r, c)), Some(g)) = (cells.as_mut(), grid_cells.as_ref()) {
            r.push(g.row[i]);
            c.push(g.col[i]);
        }
    }
    let grid = match (grid_cells, cells) {
        (Some(g), Some((row, col))) => {
            // A vertex missing from the grid leaves the grid unusable as a whole.
            if row.contains(&u32::MAX) {
                None
            } else {
                Some(Grid {
                    rows: g.rows,
                    cols: g.cols,
                    row,
                    col,
                })
            }
        }
        _ => None,
    };
    Ok(Scan {
        name: path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| path.display().to_string()),
        path: Some(path.to_path_buf()),
        points,
        source_index,
        vertex_count,
        normals,
        grid,
        pose: DMat4::from_translation(offset),
        skipped_nonfinite: skipped,
        sensor_hint: sensor_hint(ply),
    })
}

/// Coordinates beyond this (metres) lose millimetres in f32, so the scan is re-centred.
pub const RECENTRE_ABOVE: f64 = 1e5;

/// The offset subtracted from a scan's coordinates before they become f32: zero for ordinary
/// scanner-local data; for georeferenced coordinates (beyond [`RECENTRE_ABOVE`]) the centre of
/// the bounding box, kept in f64 in the pose. The scanner is then assumed at that centre.
fn recentre_offset(xyz: &[[f64; 3]]) -> DVec3 {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for p in xyz {
        let v = DVec3::from_array(*p);
        if v.is_finite() {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    if !lo.is_finite() || lo.abs().max(hi.abs()).max_element() <= RECENTRE_ABOVE {
        return DVec3::ZERO;
    }
    ((lo + hi) * 0.5).round()
}

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
        let (Some(r), Some(c)) = (
            ply.scalar_column("vertex", rn),
            ply.scalar_column("vertex", cn),
        ) else {
            continue;
        };
        let ok = |v: &f64| v.is_finite() && *v >= 0.0 && *v < 1e7 && v.fract() == 0.0;
        if !r.iter().all(ok) || !c.iter().all(ok) || r.is_empty() {
            return None;
        }
        let row: Vec<u32> = r.iter().map(|&v| v as u32).collect();
        let col: Vec<u32> = c.iter().map(|&v| v as u32).collect();
        let rows = row.iter().max().map_or(0, |m| m + 1);
        let cols = col.iter().max().map_or(0, |m| m + 1);
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
