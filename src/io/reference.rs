//! Reference files: `<scan>.ref.ply` per scan, the scan's valid points in input order with
//! world `x y z`, the normal, `radius` and `ao` = the reference obscurance (written by
//! `mvao reference`, read by `merge --reference` and `mvao eval`). A reference cast at a true
//! surface also has `on_surface`: 0 marks a point too far from the surface to be scored, and
//! readers of the reference see no value there (NaN, which every metric skips).

use crate::error::{Error, Result};
use crate::falloff::{show_tmax, tmax_from_json, Falloff};
use crate::io::ply::{PlyFile, ScalarType};
use crate::scan::Scan;
use glam::Vec3;
use std::path::{Path, PathBuf};

/// The reference file of scan `name` in `dir`.
pub fn reference_path(dir: &Path, name: &str) -> PathBuf {
    dir.join(format!("{name}.ref.ply"))
}

/// The optional per-point columns of a reference file.
#[derive(Debug, Clone, Copy, Default)]
pub struct RefExtras<'a> {
    /// `self_hits`: the rays per point that met the point's own surface.
    pub self_hits: Option<&'a [u32]>,
    /// `on_surface`: whether the point lies on the true surface (scored) or not.
    pub on_surface: Option<&'a [bool]>,
}

/// Writes one scan's reference: world x y z, normal, radius, `ao` = A and the `extras` given.
pub fn write_reference_ply(
    path: &Path,
    s: &Scan,
    normals: &[Vec3],
    radii: &[f32],
    a: &[f32],
    extras: RefExtras,
) -> Result<()> {
    let self_hits = extras.self_hits;
    let world: Vec<[f64; 3]> = s
        .points
        .iter()
        .map(|p| s.pose.transform_point3(p.as_dvec3()).to_array())
        .collect();
    let col = |k: usize| world.iter().map(|p| p[k]).collect::<Vec<f64>>();
    let ncol = |k: usize| normals.iter().map(|n| n[k] as f64).collect::<Vec<f64>>();
    let (x, y, z) = (col(0), col(1), col(2));
    let (nx, ny, nz) = (ncol(0), ncol(1), ncol(2));
    let r: Vec<f64> = radii.iter().map(|&v| v as f64).collect();
    let ao: Vec<f64> = a
        .iter()
        .map(|&v| {
            if v.is_finite() {
                v.clamp(0.0, 1.0) as f64
            } else {
                1.0
            }
        })
        .collect();
    let hits: Vec<f64> = self_hits
        .map(|h| h.iter().map(|&v| v as f64).collect())
        .unwrap_or_default();
    let mut cols: Vec<(&str, ScalarType, &[f64])> = vec![
        ("x", ScalarType::F64, &x),
        ("y", ScalarType::F64, &y),
        ("z", ScalarType::F64, &z),
        ("nx", ScalarType::F32, &nx),
        ("ny", ScalarType::F32, &ny),
        ("nz", ScalarType::F32, &nz),
        ("radius", ScalarType::F32, &r),
        ("ao", ScalarType::F32, &ao),
    ];
    if self_hits.is_some() {
        cols.push(("self_hits", ScalarType::U32, &hits));
    }
    let on: Vec<f64> = extras
        .on_surface
        .map(|o| o.iter().map(|&b| f64::from(u8::from(b))).collect())
        .unwrap_or_default();
    if extras.on_surface.is_some() {
        cols.push(("on_surface", ScalarType::U8, &on));
    }
    let ply = PlyFile::from_vertex_columns(
        &cols,
        &[format!(
            "mvao {} reference obscurance of scan {}",
            env!("CARGO_PKG_VERSION"),
            s.name
        )],
    )?;
    ply.write_path(path)
}

/// Reads the `ao` column of a PLY file (a result or a reference).
pub fn read_ao(path: &Path) -> Result<Vec<f32>> {
    let ply = PlyFile::from_path(path)?;
    let v = ply
        .scalar_column("vertex", "ao")
        .ok_or_else(|| Error::format(path, "has no per-vertex 'ao' property"))?;
    Ok(v.iter().map(|&x| x as f32).collect())
}

/// Reads a reference file's values: its `ao`, NaN where `on_surface` is 0 (not scored).
pub fn read_reference_ao(path: &Path) -> Result<Vec<f32>> {
    let ply = PlyFile::from_path(path)?;
    let v = ply
        .scalar_column("vertex", "ao")
        .ok_or_else(|| Error::format(path, "has no per-vertex 'ao' property"))?;
    let on = ply.scalar_column("vertex", "on_surface");
    Ok(v.iter()
        .enumerate()
        .map(|(i, &x)| match on.as_ref().and_then(|o| o.get(i)) {
            Some(&0.0) => f32::NAN,
            _ => x as f32,
        })
        .collect())
}

/// The references of `scans` from `dir`, checked against their point counts.
pub fn load_reference(dir: &Path, scans: &[Scan]) -> Result<Vec<Vec<f32>>> {
    let named: Vec<(String, usize)> = scans.iter().map(|s| (s.name.clone(), s.len())).collect();
    load_reference_named(dir, &named)
}

/// The references of the scans named with their point counts.
pub fn load_reference_named(dir: &Path, scans: &[(String, usize)]) -> Result<Vec<Vec<f32>>> {
    scans
        .iter()
        .map(|(name, len)| {
            let p = reference_path(dir, name);
            if !p.is_file() {
                return Err(Error::Param(format!(
                    "{}: no reference for scan '{name}' (run `mvao reference` on the same scans)",
                    p.display(),
                )));
            }
            let a = read_reference_ao(&p)?;
            if a.len() != *len {
                return Err(Error::format(
                    &p,
                    format!(
                        "holds {} points but scan '{name}' has {len}: not the reference of this scan",
                        a.len(),
                    ),
                ));
            }
            Ok(a)
        })
        .collect()
}

/// The t_max and falloff recorded under `keys` (`params` of a `reference.json`,
/// `parameters.ssao` of a run's `report.json`) in `file`; `None` when the file or the entry
/// is absent.
fn recorded_falloff(file: &Path, keys: &[&str]) -> Result<Option<(f32, Falloff)>> {
    if !file.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(file).map_err(|e| Error::io(file, e))?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| Error::format(file, format!("is not valid JSON: {e}")))?;
    let key = keys.join(".");
    let Some(entry) = keys
        .iter()
        .try_fold(&v, |v, k| v.get(k))
        .filter(|e| e.is_object())
    else {
        return Ok(None);
    };
    let tmax = entry
        .get("tmax")
        .and_then(tmax_from_json)
        .ok_or_else(|| Error::format(file, format!("has no readable {key}.tmax")))?;
    let falloff = match entry.get("falloff") {
        None => Falloff::Smoothstep,
        Some(f) => f
            .as_str()
            .and_then(|s| Falloff::parse(s).ok())
            .ok_or_else(|| Error::format(file, format!("has an unknown {key}.falloff {f}")))?,
    };
    Ok(Some((tmax, falloff)))
}

/// Refuses to score a run at `tmax` with `falloff` against the reference in `dir` when its
/// `reference.json` records other ones: the two would measure different quantities. A
/// directory without `reference.json` (files gathered by hand) is taken on trust.
pub fn check_reference_matches(dir: &Path, tmax: f32, falloff: Falloff) -> Result<()> {
    let file = dir.join("reference.json");
    let Some((rt, rf)) = recorded_falloff(&file, &["params"])? else {
        return Ok(());
    };
    let same_t = rt == tmax || (rt - tmax).abs() <= 1e-6 * rt.abs().max(tmax.abs());
    // At t_max = ∞ every falloff but the exponential is plain ambient occlusion.
    let same_f = rf == falloff || (rf.blocks_fully(rt) && falloff.blocks_fully(tmax));
    if same_t && same_f {
        return Ok(());
    }
    Err(Error::Param(format!(
        "{}: the reference was computed at t_max {} with falloff {rf}, the result at t_max {} \
         with falloff {falloff}; score against a reference of the same t_max and falloff",
        file.display(),
        show_tmax(rt),
        show_tmax(tmax),
    )))
}

/// The t_max and falloff of the run whose results are in `dir`, from its `report.json` (or
/// the `pymeshlab.json` of `scripts/compare_pymeshlab.py`), if there is one.
pub fn run_falloff(dir: &Path) -> Result<Option<(f32, Falloff)>> {
    for name in ["report.json", "pymeshlab.json"] {
        if let Some(found) = recorded_falloff(&dir.join(name), &["parameters", "ssao"])? {
            return Ok(Some(found));
        }
    }
    Ok(None)
}
