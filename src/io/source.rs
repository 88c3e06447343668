//! Input files of every supported format as scans, and results written back in the input's
//! format (or another one). A file may hold one scan (PLY, LAS/LAZ) or several (E57, PTX);
//! each reader hands over [`RawScan`]s, which become [`Scan`]s here, with the scanner put at the
//! local origin.

use super::ply::PlyFile;
use super::raw::{RawGrid, RawScan};
use crate::error::{Error, Result};
use crate::scan::{Grid, Scan, NO_CELL};
use glam::{DMat4, DVec3, Vec3};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// A scan file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// Stanford PLY (ascii, binary little or big endian).
    Ply,
    /// ASPRS LAS 1.0–1.4.
    Las,
    /// LAZ (compressed LAS).
    Laz,
    /// ASTM E57.
    E57,
    /// Leica PTX (ascii, gridded). Read only.
    Ptx,
}

impl Format {
    /// The format of `path`, by extension (case-insensitive).
    pub fn of_path(path: &Path) -> Result<Format> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        match ext.as_str() {
            "ply" => Ok(Format::Ply),
            "las" => Ok(Format::Las),
            "laz" => Ok(Format::Laz),
            "e57" => Ok(Format::E57),
            "ptx" => Ok(Format::Ptx),
            _ => Err(Error::format(
                path,
                "unknown scan format (expected .ply, .las, .laz, .e57 or .ptx)",
            )),
        }
    }

    /// The file extension written for this format.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Ply => "ply",
            Format::Las => "las",
            Format::Laz => "laz",
            Format::E57 => "e57",
            Format::Ptx => "ptx",
        }
    }

    /// True when the format stores world (georeferenced) coordinates rather than scanner-local
    /// ones: a pose given for such a scan is the scanner's pose, not a transform of the points.
    pub fn world_coordinates(self) -> bool {
        matches!(self, Format::Las | Format::Laz)
    }

    /// True when one file of this format may hold several scans.
    pub fn multi_scan(self) -> bool {
        matches!(self, Format::E57 | Format::Ptx)
    }

    /// The output format for results of an input in this format when none is chosen: the
    /// same, except PTX (not written), whose results go to PLY with the grid kept.
    pub fn default_output(self) -> Format {
        match self {
            Format::Ptx => Format::Ply,
            f => f,
        }
    }
}

impl std::fmt::Display for Format {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.extension())
    }
}

/// The parsed content of an input file, kept so results can be written back with every
/// original field.
#[derive(Debug)]
pub enum Container {
    /// A PLY file.
    Ply(Box<PlyFile>),
    /// An E57 file.
    E57(Box<super::e57::E57Input>),
    /// A PTX file.
    Ptx(Box<super::ptx::PtxInput>),
    /// A LAS or LAZ file.
    Las(Box<super::las::LasInput>),
}

impl Container {
    /// Names of the per-point attributes of scan `k` of the file.
    pub fn attributes(&self, k: usize) -> Vec<String> {
        match self {
            Container::Las(l) => {
                let mut v: Vec<String> = [
                    "x",
                    "y",
                    "z",
                    "intensity",
                    "return_number",
                    "number_of_returns",
                    "classification",
                    "scan_angle",
                    "user_data",
                    "point_source_id",
                ]
                .map(String::from)
                .to_vec();
                if l.has_color() {
                    v.extend(["red", "green", "blue"].map(String::from));
                }
                v.extend(l.extra_dims().iter().map(|d| d.name.clone()));
                v
            }
            Container::E57(e) => e
                .scans
                .get(k)
                .map(|s| {
                    s.descriptor
                        .prototype
                        .iter()
                        .map(|r| super::e57::record_label(&r.name))
                        .collect()
                })
                .unwrap_or_default(),
            Container::Ptx(p) => p
                .scans
                .get(k)
                .map(|s| {
                    let mut v: Vec<String> =
                        ["x", "y", "z", "intensity"].map(String::from).to_vec();
                    if s.rgb.is_some() {
                        v.extend(["red", "green", "blue"].map(String::from));
                    }
                    v
                })
                .unwrap_or_default(),
            Container::Ply(p) => p
                .element("vertex")
                .map(|e| {
                    p.header.elements[e]
                        .props
                        .iter()
                        .map(|p| p.name.clone())
                        .collect()
                })
                .unwrap_or_default(),
        }
    }
}

/// One input file: its format, its parsed content and its scans (identity alignment, poses
/// from the file itself).
#[derive(Debug)]
pub struct InputFile {
    /// The file.
    pub path: PathBuf,
    /// Its format.
    pub format: Format,
    /// The parsed content.
    pub container: Container,
    /// Its scans, in file order.
    pub scans: Vec<Scan>,
    /// Per scan: file coordinates → scan-local coordinates before any alignment (the offset
    /// subtracted and the scanner moved to the origin). The pipeline composes it with poses.
    pub file_to_local: Vec<DVec3>,
    /// What the reader found worth telling the user (data ignored), each naming the file.
    pub warnings: Vec<String>,
}

/// Reads any supported scan file.
pub fn read_input(path: &Path) -> Result<InputFile> {
    let format = Format::of_path(path)?;
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string());
    match format {
        Format::Ply => {
            let (ply, warnings) = PlyFile::from_path_warn(path)?;
            let raw = super::ply::scan::raw_from_ply(&ply, path, &stem)?;
            let (scan, off) = scan_from_raw(raw, path)?;
            Ok(InputFile {
                path: path.to_path_buf(),
                format,
                container: Container::Ply(Box::new(ply)),
                scans: vec![scan],
                file_to_local: vec![off],
                warnings,
            })
        }
        Format::Las | Format::Laz => {
            let l = super::las::LasInput::from_path(path)?;
            let (scan, off) = scan_from_raw(l.raw_scan(&stem), path)?;
            Ok(InputFile {
                path: path.to_path_buf(),
                format,
                container: Container::Las(Box::new(l)),
                scans: vec![scan],
                file_to_local: vec![off],
                warnings: Vec::new(),
            })
        }
        Format::E57 => {
            let e = super::e57::E57Input::from_path(path)?;
            let (scans, offs) = scans_of(e.raw_scans(), path)?;
            Ok(InputFile {
                path: path.to_path_buf(),
                format,
                container: Container::E57(Box::new(e)),
                scans,
                file_to_local: offs,
                warnings: Vec::new(),
            })
        }
        Format::Ptx => {
            let p = super::ptx::PtxInput::from_path(path)?;
            let (scans, offs) = scans_of(p.raw_scans(), path)?;
            Ok(InputFile {
                path: path.to_path_buf(),
                format,
                container: Container::Ptx(Box::new(p)),
                scans,
                file_to_local: offs,
                warnings: Vec::new(),
            })
        }
    }
}

/// The scans of a multi-scan container; every pose the file gives must be rigid.
fn scans_of(raws: Vec<RawScan>, path: &Path) -> Result<(Vec<Scan>, Vec<DVec3>)> {
    let mut scans = Vec::with_capacity(raws.len());
    let mut offs = Vec::with_capacity(raws.len());
    for mut r in raws {
        if let Some(m) = r.pose {
            r.pose = Some(
                super::align::check_rigid(m, path, &r.name)
                    .map_err(|e| Error::format(path, format!("scan {}: {e}", r.name)))?,
            );
        }
        let (s, o) = scan_from_raw(r, path)?;
        scans.push(s);
        offs.push(o);
    }
    Ok((scans, offs))
}

/// Local coordinates beyond this (metres) are refused: nothing scanned is that large, and
/// single-precision squares of such distances overflow.
pub const MAX_LOCAL: f32 = 1e12;

/// A scan whose points all lie within this distance (metres) of its local origin is refused:
/// single-precision squares of its distances underflow.
pub const MIN_LOCAL: f32 = 1e-9;

/// Coordinates beyond this (metres) lose millimetres in f32, so the scan is re-centred.
pub const RECENTRE_ABOVE: f64 = 1e5;

/// An error naming `path` when scan `s`'s local coordinates are out of the range shading can
/// use: beyond [`MAX_LOCAL`], or all within [`MIN_LOCAL`] of the origin.
pub fn check_usable(s: &Scan, path: &Path) -> Result<()> {
    let far = s
        .points
        .par_iter()
        .filter(|v| v.is_finite())
        .map(|v| v.abs().max_element())
        .reduce(|| 0.0, f32::max);
    if far < MIN_LOCAL && !s.points.is_empty() {
        return Err(Error::format(
            path,
            format!(
                "scan {}: every point lies within {MIN_LOCAL:e} m of the scanner (or the scan's \
                 centre): too small to shade in single precision",
                s.name
            ),
        ));
    }
    if far > MAX_LOCAL {
        return Err(Error::format(
            path,
            format!(
                "scan {}: points lie {far:e} m from the scanner (or the scan's centre); beyond \
                 {MAX_LOCAL:e} m the squared distances of single-precision shading overflow",
                s.name
            ),
        ));
    }
    Ok(())
}

/// Builds a [`Scan`] from what a reader handed over. Returns it with the offset subtracted
/// from the file coordinates: the declared scanner position, else zero for ordinary
/// scanner-local data, else (coordinates beyond [`RECENTRE_ABOVE`], scanner unknown) the
/// centre of the bounding box. The file's own pose and the offset go into [`Scan::pose`].
pub fn scan_from_raw(mut raw: RawScan, path: &Path) -> Result<(Scan, DVec3)> {
    let n = raw.xyz.len();
    if u32::try_from(n).is_err() {
        return Err(Error::format(
            path,
            format!(
                "scan {}: {n} points; one scan may hold at most 2^32 − 1",
                raw.name
            ),
        ));
    }
    let offset = match raw.scanner {
        Some(s) if s.is_finite() => s,
        _ => recentre_offset(&raw.xyz),
    };
    let local = |p: &[f64; 3]| {
        Vec3::new(
            (p[0] - offset.x) as f32,
            (p[1] - offset.y) as f32,
            (p[2] - offset.z) as f32,
        )
    };
    // An unusable normal becomes zero and is re-estimated downstream.
    let unit = |v: &Vec3| v.try_normalize().unwrap_or(Vec3::ZERO);
    let all: Vec<Vec3> = raw.xyz.par_iter().map(local).collect();
    let (points, source_index, normals, cells, skipped) = if all.par_iter().all(|v| v.is_finite()) {
        // The usual case: every vertex is a point.
        let points = all;
        let source_index: Vec<u32> = (0..n as u32).into_par_iter().collect();
        let normals = raw
            .normals
            .as_ref()
            .map(|g| g.par_iter().map(unit).collect::<Vec<Vec3>>());
        let cells = raw
            .grid
            .as_mut()
            .map(|g| (std::mem::take(&mut g.row), std::mem::take(&mut g.col)));
        (points, source_index, normals, cells, 0usize)
    } else {
        let mut points = Vec::with_capacity(n);
        let mut source_index = Vec::with_capacity(n);
        let mut normals = raw.normals.as_ref().map(|_| Vec::with_capacity(n));
        let mut cells = raw
            .grid
            .as_ref()
            .map(|_| (Vec::with_capacity(n), Vec::with_capacity(n)));
        let mut skipped = 0usize;
        for (i, &v) in all.iter().enumerate() {
            if !v.is_finite() {
                skipped += 1;
                continue;
            }
            points.push(v);
            source_index.push(i as u32);
            if let (Some(out), Some(given)) = (normals.as_mut(), raw.normals.as_ref()) {
                out.push(unit(&given[i]));
            }
            if let (Some((r, c)), Some(g)) = (cells.as_mut(), raw.grid.as_ref()) {
                r.push(g.row[i]);
                c.push(g.col[i]);
            }
        }
        (points, source_index, normals, cells, skipped)
    };
    let mut warnings = std::mem::take(&mut raw.warnings);
    let grid = match (raw.grid, cells) {
        (Some(RawGrid { rows, cols, .. }), Some((row, col))) => {
            let label = match Format::of_path(path) {
                Ok(f) if f.multi_scan() => format!("{}: scan {}", path.display(), raw.name),
                _ => path.display().to_string(),
            };
            checked_grid(
                Grid {
                    rows,
                    cols,
                    row,
                    col,
                },
                &label,
                &mut warnings,
            )
        }
        _ => None,
    };
    let pose = raw.pose.unwrap_or(DMat4::IDENTITY) * DMat4::from_translation(offset);
    Ok((
        Scan {
            name: raw.name,
            path: Some(path.to_path_buf()),
            points,
            source_index,
            vertex_count: n,
            normals,
            grid,
            pose,
            skipped_nonfinite: skipped,
            sensor_hint: raw.sensor_hint,
            warnings,
        },
        offset,
    ))
}

/// The end of a warning about a native grid that is not used.
pub(crate) const GRID_IGNORED: &str =
    "the native grid is ignored and the sensor model fitted to the points";

/// More than this fraction of a native grid's references invalid, of a scan's points without
/// a cell, or of its points in a cell already holding another, and the grid is not trusted.
pub const MAX_GRID_DEFECTS: f64 = 0.05;

/// `grid` (one cell per valid point) when it can serve as the range map, with a warning
/// about what is wrong with it into `warnings` (`label` names the file and scan). A point
/// outside the grid is marked [`NO_CELL`] and placed by the fitted sensor model; points
/// sharing a cell are kept (the range map holds the nearest). Beyond [`MAX_GRID_DEFECTS`]
/// of either, the grid is no scanner grid and is dropped.
fn checked_grid(mut grid: Grid, label: &str, warnings: &mut Vec<String>) -> Option<Grid> {
    let n = grid.row.len();
    let (rows, cols) = (grid.rows, grid.cols);
    grid.row
        .par_iter_mut()
        .zip(grid.col.par_iter_mut())
        .for_each(|(r, c)| {
            if *r >= rows || *c >= cols {
                (*r, *c) = (NO_CELL, NO_CELL);
            }
        });
    let uncelled = grid.uncelled();
    let too_many = |k: usize, of: usize| k as f64 > MAX_GRID_DEFECTS * of as f64;
    let pct = MAX_GRID_DEFECTS * 100.0;
    if too_many(uncelled, n) {
        warnings.push(format!(
            "{label}: {uncelled} of {n} points have no cell in the native {cols} × {rows} grid \
             (more than {pct} %); {GRID_IGNORED}"
        ));
        return None;
    }
    let shared = (n - uncelled) - grid.occupied_cells();
    if too_many(shared, n - uncelled) {
        warnings.push(format!(
            "{label}: {shared} of {n} points fall in a native grid cell already holding another \
             point (more than {pct} %), which a scanner grid does not; {GRID_IGNORED}"
        ));
        return None;
    }
    if uncelled > 0 {
        warnings.push(format!(
            "{label}: {uncelled} of {n} points have no cell in the native {cols} × {rows} grid; \
             they are placed by the sensor model fitted to the grid"
        ));
    }
    if shared > 0 {
        warnings.push(format!(
            "{label}: {shared} of {n} points fall in a native grid cell already holding another \
             point; the range map keeps the nearest point of each cell and the others share \
             its pixel"
        ));
    }
    Some(grid)
}

/// The bounding-box centre of `xyz` (rounded to metres) when it lies beyond
/// [`RECENTRE_ABOVE`], else zero.
fn recentre_offset(xyz: &[[f64; 3]]) -> DVec3 {
    let none = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    // Fixed chunks combined in order: the same box whatever the threads.
    let (lo, hi) = xyz
        .par_chunks(1 << 16)
        .map(|c| {
            c.iter().fold(none, |(lo, hi), p| {
                let v = DVec3::from_array(*p);
                if v.is_finite() {
                    (lo.min(v), hi.max(v))
                } else {
                    (lo, hi)
                }
            })
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold(none, |(lo, hi), (a, b)| (lo.min(a), hi.max(b)));
    if !lo.is_finite() || lo.abs().max(hi.abs()).max_element() <= RECENTRE_ABOVE {
        return DVec3::ZERO;
    }
    // Halved before the sum: coordinates near f64::MAX must not overflow to an infinite centre.
    (lo * 0.5 + hi * 0.5).round()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recentre_offset_stays_finite_near_the_largest_coordinates() {
        let big = f64::MAX * 0.9;
        let off = recentre_offset(&[[big, 1.0, 1.0], [big * 0.99, 2.0e9, 1.0]]);
        assert!(off.is_finite(), "{off:?}");
        assert!(off.x > big * 0.98 && off.x <= big);
        // Ordinary georeferenced coordinates: the rounded centre of the box.
        let off = recentre_offset(&[
            [500_000.5, 4_000_000.0, 10.0],
            [500_101.5, 4_000_050.0, 30.0],
        ]);
        assert_eq!(off, DVec3::new(500_051.0, 4_000_025.0, 20.0));
    }
}
