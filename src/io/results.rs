//! Where results go and in which format. An output follows its input's format unless
//! `--format` says otherwise. Within a format family (PLY → PLY, LAS ↔ LAZ, E57 → E57) the
//! parsed input is written back with every original field and the AO added; across formats
//! the result is a [`PointTable`] in world coordinates with colour, intensity, AO and grid.

use super::dataset::Dataset;
use super::output::{
    ao_comment, colour_step, grey, write_result_ply, ColorMode, ExtraFloat, CLOUDCOMPARE_AO,
    MESHLAB_AO,
};
use super::ply::{round, PlyFile, PropertyKind, ScalarType};
use super::raw::{PointTable, RawGrid};
use super::source::{Container, Format};
use crate::error::{Error, Result};
use glam::{DMat4, DVec3, Vec3};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// One output file and the scans it holds.
#[derive(Debug, Clone)]
pub struct OutputUnit {
    /// The file to write.
    pub path: PathBuf,
    /// Its format.
    pub format: Format,
    /// Index of the input file in [`Dataset::files`].
    pub file: usize,
    /// Indices into [`Dataset::scans`] written to it, in order.
    pub scans: Vec<usize>,
    /// True when the input's parsed content is written back (same format family).
    pub same_family: bool,
}

/// How results are written.
#[derive(Debug, Clone, Copy)]
pub struct WriteOptions {
    /// Gamma of grey colours.
    pub gamma: f32,
    /// What happens to input colours.
    pub color: ColorMode,
}

/// True when a result in `out` can be written from the parsed input of format `input`.
fn same_family(input: Format, out: Format) -> bool {
    matches!(
        (input, out),
        (Format::Ply, Format::Ply)
            | (Format::Las | Format::Laz, Format::Las | Format::Laz)
            | (Format::E57, Format::E57)
    )
}

/// The outputs of a dataset: one file per input file, except that a multi-scan input written
/// to a one-scan format gives one file per scan (named after the scan). Errors when two
/// outputs would share a name.
pub fn plan(ds: &Dataset, format: Option<Format>, out_dir: &Path) -> Result<Vec<OutputUnit>> {
    let files: Vec<(PathBuf, Format, Vec<String>)> = ds
        .files
        .iter()
        .enumerate()
        .map(|(fi, f)| {
            let names = (0..ds.scans.len())
                .filter(|&i| ds.origin[i].0 == fi)
                .map(|i| ds.scans[i].name.clone())
                .collect();
            (f.path.clone(), f.format, names)
        })
        .collect();
    plan_files(&files, format, out_dir)
}

/// [`plan`] from each input file's path, format and scan names (in order; scans are
/// numbered across files in that order).
pub fn plan_files(
    files: &[(PathBuf, Format, Vec<String>)],
    format: Option<Format>,
    out_dir: &Path,
) -> Result<Vec<OutputUnit>> {
    if format == Some(Format::Ptx) {
        return Err(Error::Param(
            "PTX is read, not written: choose --format ply, las, laz or e57".into(),
        ));
    }
    let mut units: Vec<OutputUnit> = Vec::new();
    let mut next = 0usize;
    for (fi, (path, fmt, names)) in files.iter().enumerate() {
        let out = format.unwrap_or(fmt.default_output());
        let scans: Vec<usize> = (next..next + names.len()).collect();
        next += names.len();
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let fam = same_family(*fmt, out);
        if fam || out == Format::E57 || scans.len() == 1 {
            units.push(OutputUnit {
                path: out_dir.join(format!("{stem}.mvao.{}", out.extension())),
                format: out,
                file: fi,
                scans,
                same_family: fam,
            });
        } else {
            for (k, i) in scans.into_iter().enumerate() {
                units.push(OutputUnit {
                    path: out_dir.join(format!("{}.mvao.{}", names[k], out.extension())),
                    format: out,
                    file: fi,
                    scans: vec![i],
                    same_family: false,
                });
            }
        }
    }
    for (i, u) in units.iter().enumerate() {
        if let Some(v) = units[..i].iter().find(|v| v.path == u.path) {
            return Err(Error::Param(format!(
                "{} and {} would both write {}; rename one or run them separately",
                files[v.file].0.display(),
                files[u.file].0.display(),
                u.path.display()
            )));
        }
    }
    Ok(units)
}

/// The names of the bent normal's columns.
pub const BENT_COLUMNS: [&str; 3] = ["bnx", "bny", "bnz"];

/// The bent normals of scan `i`'s valid points as the columns [`BENT_COLUMNS`], turned from
/// the scan's local frame into the frame that `to_world` leaves (identity: world) and
/// normalised; a point whose every ray was blocked keeps a zero vector.
fn bent_columns(ds: &Dataset, i: usize, bent: &[Vec3], to_world: DMat4) -> [Vec<f64>; 3] {
    let m = to_world.inverse() * ds.scans[i].pose;
    let turned: Vec<DVec3> = bent
        .iter()
        .map(|b| m.transform_vector3(b.as_dvec3()).normalize_or_zero())
        .collect();
    [0, 1, 2].map(|k| turned.iter().map(|v| v[k]).collect())
}

/// Writes one output. `ao[i]` holds scan `i`'s AO per valid point (the order of
/// [`Scan::points`](crate::scan::Scan::points)); every value must be finite. `bent[i]`,
/// when given, its bent normals in its local frame: written in the file's frame to a PLY
/// written back, in world coordinates to a table. Returns what the user should know about the
/// output (points the LAS grid merges).
pub fn write(
    unit: &OutputUnit,
    ds: &Dataset,
    ao: &[Vec<f32>],
    bent: &[Option<Vec<Vec3>>],
    opts: WriteOptions,
    comment: &str,
) -> Result<Vec<String>> {
    for &i in &unit.scans {
        if ao[i].iter().any(|a| !a.is_finite()) {
            return Err(Error::Param(format!(
                "{}: refusing to write a non-finite ao value (internal error)",
                unit.path.display()
            )));
        }
    }
    let file = &ds.files[unit.file];
    if unit.same_family {
        let written = match &file.container {
            Container::Ply(ply) => {
                let i = unit.scans[0];
                let s = &ds.scans[i];
                let mut per_vertex = vec![1.0f32; s.vertex_count];
                for (k, &vi) in s.source_index.iter().enumerate() {
                    per_vertex[vi as usize] = ao[i][k];
                }
                let kept: PlyFile;
                let ply: &PlyFile = if s.skipped_nonfinite > 0 || ply.faces_out_of_range() > 0 {
                    let mut keep = vec![false; s.vertex_count];
                    for &vi in &s.source_index {
                        keep[vi as usize] = true;
                    }
                    per_vertex = s
                        .source_index
                        .iter()
                        .map(|&vi| per_vertex[vi as usize])
                        .collect();
                    kept = ply.as_ref().clone().retain_vertices(&keep)?;
                    &kept
                } else {
                    ply.as_ref()
                };
                let mut extra = Vec::new();
                if let Some(b) = bent.get(i).and_then(Option::as_ref) {
                    let cols = bent_columns(ds, i, b, ds.file_to_world[i]);
                    for (name, v) in BENT_COLUMNS.into_iter().zip(cols) {
                        // The rows written are the kept vertices (as `per_vertex`) or all of
                        // them, where those without a valid point keep 0 (their AO keeps 1).
                        let full = if s.skipped_nonfinite > 0 {
                            v
                        } else {
                            per_record(ds, i, &v, 0.0)
                        };
                        extra.push((name, full));
                    }
                }
                return write_result_ply(
                    ply,
                    &per_vertex,
                    &extra,
                    opts.gamma,
                    opts.color,
                    comment,
                    &unit.path,
                );
            }
            Container::E57(e) => {
                let records: Vec<Vec<f32>> = unit
                    .scans
                    .iter()
                    .map(|&i| per_record(ds, i, &ao[i], 1.0))
                    .collect();
                let bent_records: Vec<Option<[Vec<f32>; 3]>> = unit
                    .scans
                    .iter()
                    .map(|&i| bent_per_record(ds, i, bent))
                    .collect();
                let extra: Vec<Vec<ExtraFloat>> = bent_records.iter().map(bent_floats).collect();
                super::e57::write_e57(e, &records, &extra, opts.gamma, opts.color, &unit.path)
            }
            Container::Ptx(_) => Err(Error::Param(format!(
                "{}: PTX is read, not written",
                unit.path.display()
            ))),
            Container::Las(l) => {
                let i = unit.scans[0];
                let bent_records = bent_per_record(ds, i, bent);
                super::las::write_las(
                    l,
                    &per_record(ds, i, &ao[i], 1.0),
                    &bent_floats(&bent_records),
                    opts.gamma,
                    opts.color,
                    &unit.path,
                    unit.format == Format::Laz,
                )
            }
        };
        written.map(|()| Vec::new())
    } else {
        let tables: Vec<PointTable> = unit
            .scans
            .iter()
            .map(|&i| {
                let mut t = table_of(ds, i, &ao[i], opts)?;
                if let Some(b) = bent.get(i).and_then(Option::as_ref) {
                    t.extra.retain(|(n, _)| !BENT_COLUMNS.contains(&n.as_str()));
                    let cols = bent_columns(ds, i, b, DMat4::IDENTITY);
                    t.extra
                        .extend(BENT_COLUMNS.into_iter().map(String::from).zip(cols));
                }
                Ok(t)
            })
            .collect::<Result<_>>()?;
        match unit.format {
            Format::Ply => write_table_ply(&tables[0], comment, &unit.path),
            Format::E57 => super::e57::write_table_e57(&tables, &unit.path).map(|()| Vec::new()),
            Format::Las | Format::Laz => {
                super::las::write_table_las(&tables[0], &unit.path, unit.format == Format::Laz)
            }
            Format::Ptx => Err(Error::Param(format!(
                "{}: PTX is read, not written",
                unit.path.display()
            ))),
        }
    }
}

/// The result of scan `i` as a table in world coordinates (valid points only), from the
/// file's own f64 coordinates and the exact f64 placement.
pub fn table_of(ds: &Dataset, i: usize, ao: &[f32], opts: WriteOptions) -> Result<PointTable> {
    let s = &ds.scans[i];
    let (fi, k) = ds.origin[i];
    let file = &ds.files[fi];
    let rec_ao = per_record(ds, i, ao, 1.0);
    let per_record_table = |xyz: Vec<[f64; 3]>, attrs: Attributes| {
        let (rgb, intensity, extra) = attrs;
        PointTable {
            name: s.name.clone(),
            xyz,
            pose: glam::DMat4::IDENTITY,
            rgb: Some(colours(rgb.as_deref(), &rec_ao, opts)),
            intensity,
            ao: rec_ao.clone(),
            grid: None,
            extra,
        }
    };
    let t = match &file.container {
        Container::E57(e) => e.point_table(k, &rec_ao, opts.gamma, opts.color)?,
        Container::Ptx(p) => p.point_table(k, &rec_ao, opts.gamma, opts.color)?,
        Container::Ply(ply) => {
            let xyz = ply.vertex_xyz().ok_or_else(|| {
                Error::format(&file.path, "cannot read x/y/z of the vertex element")
            })?;
            per_record_table(xyz, ply_attributes(ply))
        }
        Container::Las(l) => per_record_table(
            l.raw_scan(&s.name).xyz,
            (l.rgb8(), Some(l.intensities()), l.extra_columns()),
        ),
    };
    let mut t = valid_rows(t, &s.source_index, ds.file_to_world[i]);
    if t.grid.is_none() {
        // Other formats store a cell for every point: a grid with points outside it stays
        // behind.
        t.grid = s
            .grid
            .as_ref()
            .filter(|g| g.uncelled() == 0)
            .map(|g| RawGrid {
                rows: g.rows,
                cols: g.cols,
                row: g.row.clone(),
                col: g.col.clone(),
            });
    }
    Ok(t)
}

/// AO per record of scan `i` (1 for records without a valid point).
fn per_record<T: Copy>(ds: &Dataset, i: usize, values: &[T], fill: T) -> Vec<T> {
    let s = &ds.scans[i];
    let mut v = vec![fill; s.vertex_count];
    for (k, &r) in s.source_index.iter().enumerate() {
        v[r as usize] = values[k];
    }
    v
}

/// Scan `i`'s bent normals (when it has them) per record of its file, in the frame of the
/// file's coordinates; a record without a valid point gets a zero vector.
fn bent_per_record(ds: &Dataset, i: usize, bent: &[Option<Vec<Vec3>>]) -> Option<[Vec<f32>; 3]> {
    let b = bent.get(i).and_then(Option::as_ref)?;
    let cols = bent_columns(ds, i, b, ds.file_to_world[i]);
    Some(cols.map(|c| {
        let c: Vec<f32> = c.iter().map(|&x| x as f32).collect();
        per_record(ds, i, &c, 0.0)
    }))
}

/// The bent-normal columns as further float columns of a LAS or E57 written back.
fn bent_floats(cols: &Option<[Vec<f32>; 3]>) -> Vec<ExtraFloat<'_>> {
    const DESCRIPTIONS: [&str; 3] = [
        "bent normal x, file frame",
        "bent normal y, file frame",
        "bent normal z, file frame",
    ];
    let Some(cols) = cols else {
        return Vec::new();
    };
    BENT_COLUMNS
        .iter()
        .zip(DESCRIPTIONS)
        .zip(cols)
        .map(|((&name, description), values)| ExtraFloat {
            name,
            description,
            range: (-1.0, 1.0),
            values,
        })
        .collect()
}

/// The rows of a per-record table that hold valid points, in world coordinates (`m`: the
/// table's coordinates → world).
fn valid_rows(t: PointTable, index: &[u32], m: glam::DMat4) -> PointTable {
    let pick = |k: &u32| *k as usize;
    PointTable {
        name: t.name,
        xyz: index
            .iter()
            .map(|k| {
                m.transform_point3(DVec3::from_array(t.xyz[pick(k)]))
                    .to_array()
            })
            .collect(),
        pose: glam::DMat4::IDENTITY,
        rgb: t.rgb.map(|c| index.iter().map(|k| c[pick(k)]).collect()),
        intensity: t
            .intensity
            .map(|c| index.iter().map(|k| c[pick(k)]).collect()),
        ao: index.iter().map(|k| t.ao[pick(k)]).collect(),
        grid: t.grid.map(|g| RawGrid {
            rows: g.rows,
            cols: g.cols,
            row: index.iter().map(|k| g.row[pick(k)]).collect(),
            col: index.iter().map(|k| g.col[pick(k)]).collect(),
        }),
        extra: t
            .extra
            .into_iter()
            .map(|(n, v)| (n, index.iter().map(|k| v[pick(k)]).collect()))
            .collect(),
    }
}

/// Output colours from the input's (if any) and the AO, as [`ColorMode`] says.
pub fn colours(input: Option<&[[u8; 3]]>, ao: &[f32], opts: WriteOptions) -> Vec<[u8; 3]> {
    ao.iter()
        .enumerate()
        .map(|(k, &a)| {
            let g = grey(a, opts.gamma);
            match (input, opts.color) {
                (Some(c), ColorMode::Keep) => c[k],
                (Some(c), ColorMode::Modulate) => {
                    c[k].map(|v| ((v as f32) * (g as f32) / 255.0).round().clamp(0.0, 255.0) as u8)
                }
                _ => [g, g, g],
            }
        })
        .collect()
}

/// Colour, intensity and other scalar properties per record.
type Attributes = (
    Option<Vec<[u8; 3]>>,
    Option<Vec<f32>>,
    Vec<(String, Vec<f64>)>,
);

/// A PLY's vertex colour (8 bits, from the colours' own scale: [`colour_step`]), intensity
/// (in [0, 1]: [`ply_intensity`]) and other scalar properties (per vertex).
fn ply_attributes(ply: &PlyFile) -> Attributes {
    let rgb = colour_step(ply).and_then(|step| {
        // NaN becomes 0 in the cast.
        ply.map_scalars("vertex", ["red", "green", "blue"], |c| {
            c.map(|v| round(v / step).clamp(0.0, 255.0) as u8)
        })
    });
    let intensity = ply_intensity(ply);
    const SKIP: [&str; 14] = [
        "x",
        "y",
        "z",
        "red",
        "green",
        "blue",
        "alpha",
        "intensity",
        "ao",
        "row",
        "col",
        "nx",
        "ny",
        "nz",
    ];
    let mut extra = Vec::new();
    if let Some(ei) = ply.element("vertex") {
        for p in &ply.header.elements[ei].props {
            if SKIP.contains(&p.name.as_str()) {
                continue;
            }
            if let Some(c) = ply.scalar_column("vertex", &p.name) {
                extra.push((p.name.clone(), c));
            }
        }
    }
    (rgb, intensity, extra)
}

/// A PLY's vertex `intensity` in [0, 1], as [`PointTable::intensity`] holds it: `uchar` by
/// 255 and `ushort` by 65535; other integers by 255 or 65535 when their values fit, floats
/// as they are when within [0, 1]; anything else by its own minimum and maximum (as E57
/// intensities without limits). Values outside the range are clamped; NaN becomes 0.
fn ply_intensity(ply: &PlyFile) -> Option<Vec<f32>> {
    let Some(PropertyKind::Scalar(t)) = ply.property_kind("vertex", "intensity") else {
        return None;
    };
    let v = ply.scalar_column("vertex", "intensity")?;
    let (lo, hi) = match t {
        ScalarType::U8 => (0.0, 255.0),
        ScalarType::U16 => (0.0, 65535.0),
        _ => {
            let (mn, mx) = v
                .par_iter()
                .filter(|x| x.is_finite())
                .fold(
                    || (f64::INFINITY, f64::NEG_INFINITY),
                    |m, &x| (m.0.min(x), m.1.max(x)),
                )
                .reduce(
                    || (f64::INFINITY, f64::NEG_INFINITY),
                    |a, b| (a.0.min(b.0), a.1.max(b.1)),
                );
            let int = !matches!(t, ScalarType::F32 | ScalarType::F64);
            if mn >= 0.0 && mx <= 1.0 || !(mx > mn) {
                (0.0, 1.0)
            } else if int && mn >= 0.0 && mx <= 255.0 {
                (0.0, 255.0)
            } else if int && mn >= 0.0 && mx <= 65535.0 {
                (0.0, 65535.0)
            } else {
                (mn, mx)
            }
        }
    };
    let inv = 1.0 / (hi - lo);
    Some(
        v.par_iter()
            .map(|&x| {
                let u = ((x - lo) * inv).clamp(0.0, 1.0);
                if u.is_nan() {
                    0.0
                } else {
                    u as f32
                }
            })
            .collect(),
    )
}

/// Writes a table as a binary little-endian PLY: double x y z (world), uchar colour, float
/// intensity and AO (as `ao`, `scalar_ao` and `quality`: [`super::output::ao_properties`]),
/// int row/col when gridded, and the extra fields as doubles. An extra field named
/// `quality` is the input's own and stays (the AO then goes to `ao` and `scalar_ao` only).
/// Returns what the user should know about the output.
pub fn write_table_ply(t: &PointTable, comment: &str, path: &Path) -> Result<Vec<String>> {
    let n = t.len();
    let world: Vec<DVec3> = (0..n).map(|k| t.world(k)).collect();
    let xs: Vec<f64> = world.iter().map(|p| p.x).collect();
    let ys: Vec<f64> = world.iter().map(|p| p.y).collect();
    let zs: Vec<f64> = world.iter().map(|p| p.z).collect();
    let mut cols: Vec<(String, ScalarType, Vec<f64>)> = vec![
        ("x".into(), ScalarType::F64, xs),
        ("y".into(), ScalarType::F64, ys),
        ("z".into(), ScalarType::F64, zs),
    ];
    if let Some(rgb) = &t.rgb {
        for (c, name) in ["red", "green", "blue"].iter().enumerate() {
            cols.push((
                name.to_string(),
                ScalarType::U8,
                rgb.iter().map(|v| v[c] as f64).collect(),
            ));
        }
    }
    if let Some(i) = &t.intensity {
        cols.push((
            "intensity".into(),
            ScalarType::F32,
            i.iter().map(|&v| v as f64).collect(),
        ));
    }
    let ao: Vec<f64> = t.ao.iter().map(|&v| v as f64).collect();
    let mut notes = Vec::new();
    let own_quality = t.extra.iter().any(|(n, _)| n == MESHLAB_AO);
    for name in ["ao", CLOUDCOMPARE_AO, MESHLAB_AO] {
        if name == MESHLAB_AO && own_quality {
            notes.push(format!(
                "{}: the input's own `{MESHLAB_AO}` is kept, so MeshLab shows it, not the AO \
                 (the AO is in `ao` and `{CLOUDCOMPARE_AO}`)",
                path.display()
            ));
            continue;
        }
        cols.push((name.into(), ScalarType::F32, ao.clone()));
    }
    if let Some(g) = &t.grid {
        cols.push((
            "row".into(),
            ScalarType::I32,
            g.row.iter().map(|&v| v as f64).collect(),
        ));
        cols.push((
            "col".into(),
            ScalarType::I32,
            g.col.iter().map(|&v| v as f64).collect(),
        ));
    }
    for (name, v) in &t.extra {
        if !cols.iter().any(|c| &c.0 == name) {
            cols.push((name.clone(), ScalarType::F64, v.clone()));
        }
    }
    let refs: Vec<(&str, ScalarType, &[f64])> = cols
        .iter()
        .map(|(n, t, v)| (n.as_str(), *t, v.as_slice()))
        .collect();
    let listed: Vec<&str> = ["ao", CLOUDCOMPARE_AO, MESHLAB_AO]
        .into_iter()
        .filter(|n| !(own_quality && *n == MESHLAB_AO))
        .collect();
    let comments = [comment.to_string(), ao_comment(&listed)];
    let ply = PlyFile::from_vertex_columns(&refs, &comments)?;
    ply.write_path(path)?;
    Ok(notes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vertices(extra: &[(&str, ScalarType, &[f64])]) -> PlyFile {
        let xs = vec![0.0; extra.first().map_or(0, |c| c.2.len())];
        let mut cols: Vec<(&str, ScalarType, &[f64])> = vec![
            ("x", ScalarType::F32, &xs),
            ("y", ScalarType::F32, &xs),
            ("z", ScalarType::F32, &xs),
        ];
        cols.extend_from_slice(extra);
        PlyFile::from_vertex_columns(&cols, &[]).unwrap()
    }

    fn rgb_of(t: ScalarType, r: &[f64], g: &[f64], b: &[f64]) -> Vec<[u8; 3]> {
        let p = vertices(&[("red", t, r), ("green", t, g), ("blue", t, b)]);
        ply_attributes(&p).0.unwrap()
    }

    /// Colours reach 8 bits from their own scale: floats in [0, 1] by 255, 16-bit values
    /// (any above 255) by 257, 8-bit values as they are; NaN is black.
    #[test]
    fn ply_colours_on_every_scale() {
        let f = ScalarType::F32;
        assert_eq!(
            rgb_of(f, &[0.8, 1.0, f64::NAN], &[0.2, 0.0, 0.5], &[0.1, 0.5, 1.0]),
            [[204, 51, 26], [255, 0, 128], [0, 128, 255]]
        );
        // Float colours beyond 1 are on the 0–255 scale.
        assert_eq!(
            rgb_of(f, &[200.4, 1.0], &[2.0, 0.0], &[0.5, 255.0]),
            [[200, 2, 1], [1, 0, 255]]
        );
        let u = ScalarType::U16;
        assert_eq!(
            rgb_of(u, &[65535.0, 50000.0], &[0.0, 257.0], &[32768.0, 128.0]),
            [[255, 0, 128], [195, 1, 0]]
        );
        // 8-bit values in a 16-bit type stay as they are; so do uchar colours.
        assert_eq!(rgb_of(u, &[200.0], &[50.0], &[10.0]), [[200, 50, 10]]);
        let i = ScalarType::I32;
        assert_eq!(rgb_of(i, &[65535.0], &[-5.0], &[70000.0]), [[255, 0, 255]]);
        let c = ScalarType::U8;
        assert_eq!(
            rgb_of(c, &[200.0, 1.0], &[50.0, 0.0], &[10.0, 1.0]),
            [[200, 50, 10], [1, 0, 1]]
        );
        // Only some channels: no colour.
        let p = vertices(&[("red", c, &[1.0]), ("green", c, &[1.0])]);
        assert!(ply_attributes(&p).0.is_none());
    }

    /// Intensities reach [0, 1] from their own scale, NaN as 0.
    #[test]
    fn ply_intensity_on_every_scale() {
        let of =
            |t: ScalarType, v: &[f64]| ply_attributes(&vertices(&[("intensity", t, v)])).1.unwrap();
        assert_eq!(of(ScalarType::U8, &[0.0, 51.0, 255.0]), [0.0, 0.2, 1.0]);
        assert_eq!(
            of(ScalarType::U16, &[0.0, 13107.0, 65535.0]),
            [0.0, 0.2, 1.0]
        );
        assert_eq!(of(ScalarType::U16, &[0.0, 255.0]), [0.0, 255.0 / 65535.0]);
        assert_eq!(of(ScalarType::I32, &[0.0, 51.0, 255.0]), [0.0, 0.2, 1.0]);
        assert_eq!(of(ScalarType::I32, &[0.0, 65535.0]), [0.0, 1.0]);
        assert_eq!(
            of(ScalarType::F32, &[0.25, f64::NAN, 1.0]),
            [0.25, 0.0, 1.0]
        );
        // A float range of its own (a reflectance in dB, say) spans [0, 1].
        assert_eq!(of(ScalarType::F32, &[-20.0, -10.0, 0.0]), [0.0, 0.5, 1.0]);
    }
}
