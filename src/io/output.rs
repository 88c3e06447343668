//! Writing PLY results: the input PLY with the AO added as `float` vertex properties for
//! scripts, CloudCompare and MeshLab ([`ao_properties`]) and grey (or modulated) colours.
//! Every file is written atomically. The preview pictures are written by the preview module.

use super::ply::{PlyFile, PropertyKind, ScalarType};
use crate::error::{Error, Result};
use rayon::prelude::*;
use serde::Serialize;
use std::path::Path;

/// What happens to an input's own colours.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ColorMode {
    /// Input colour × AO grey.
    #[default]
    Modulate,
    /// AO grey replaces the colour.
    Replace,
    /// Colours unchanged (AO only as the `ao` scalar).
    Keep,
}

/// The grey level of an AO value: `255·ao^(1/γ)`, rounded.
#[inline]
pub fn grey(ao: f32, gamma: f32) -> u8 {
    let g = if gamma > 0.0 && gamma != 1.0 {
        ao.clamp(0.0, 1.0).powf(1.0 / gamma)
    } else {
        ao.clamp(0.0, 1.0)
    };
    round_u8(g * 255.0)
}

/// `x.round().clamp(0, 255) as u8` (halves away from zero, NaN → 0) without the libm call
/// `round` is on baseline x86-64 (see [`crate::io::ply::round`]): once per output point.
#[inline]
pub fn round_u8(x: f32) -> u8 {
    crate::io::ply::round(f64::from(x)).clamp(0.0, 255.0) as u8
}

/// How a PLY's vertex `red`/`green`/`blue` are stored, as the stored value of one 8-bit
/// step: 1/255 for float colours on a 0–1 scale (all three float, no value above 1), 257 for
/// 16-bit colours (some value above 255: 65535 is 255), else 1 (8-bit values, whatever the
/// type). `None` unless all three are scalar properties.
pub fn colour_step(ply: &PlyFile) -> Option<f64> {
    let float = ["red", "green", "blue"].iter().all(|c| {
        matches!(
            ply.property_kind("vertex", c),
            Some(PropertyKind::Scalar(ScalarType::F32 | ScalarType::F64))
        )
    });
    // One flag byte per vertex, not three f64 columns: the files can be large.
    let flags = ply.map_scalars("vertex", ["red", "green", "blue"], |c| {
        u8::from(c.iter().any(|&v| v > 1.0)) | u8::from(c.iter().any(|&v| v > 255.0)) << 1
    })?;
    let all = flags.par_iter().copied().reduce(|| 0, |a, b| a | b);
    Some(if float && all & 1 == 0 {
        1.0 / 255.0
    } else if all & 2 != 0 {
        257.0
    } else {
        1.0
    })
}

/// The float vertex properties holding non-finite values, with how many: the output writes
/// them as 0, since no NaN may reach an output. `x`, `y`, `z` are left out: rows with
/// non-finite coordinates are not written at all.
pub fn nonfinite_properties(ply: &PlyFile) -> Vec<(String, usize)> {
    let Some(ei) = ply.element("vertex") else {
        return Vec::new();
    };
    let names: Vec<&str> = ply.header.elements[ei]
        .props
        .iter()
        .filter(|p| {
            matches!(
                p.kind,
                PropertyKind::Scalar(ScalarType::F32 | ScalarType::F64)
            ) && !["x", "y", "z"].contains(&p.name.as_str())
        })
        .map(|p| p.name.as_str())
        .collect();
    if names.is_empty() {
        return Vec::new();
    }
    let counts = ply
        .count_scalars("vertex", &names, |v| !v.is_finite())
        .unwrap_or_default();
    names
        .iter()
        .zip(counts)
        .filter(|(_, n)| *n > 0)
        .map(|(p, n)| (p.to_string(), n))
        .collect()
}

/// A float column a result written back into its own LAS or E57 layout carries beside `ao`
/// (one finite value per record).
#[derive(Clone, Copy)]
pub struct ExtraFloat<'a> {
    /// The column's name.
    pub name: &'a str,
    /// What the column holds, for the format's description field (at most 32 bytes in LAS).
    pub description: &'a str,
    /// The declared (minimum, maximum).
    pub range: (f64, f64),
    /// One value per record.
    pub values: &'a [f32],
}

/// The vertex property CloudCompare loads as a scalar field without asking: its PLY reader
/// takes a vertex property whose name contains `scal` as a scalar field and names it after
/// the `scalar_` prefix, so this one appears as `ao`. A plain `ao` is left out of its list.
pub const CLOUDCOMPARE_AO: &str = "scalar_ao";

/// The vertex property MeshLab shows as per-vertex quality (its colour-by-quality filters and
/// histogram read it); other float properties are not loaded at all.
pub const MESHLAB_AO: &str = "quality";

/// The header comment a PLY result lists its AO properties in, so that a run on a result
/// knows which of them it may replace.
const AO_COMMENT: &str = "mvao ao properties:";

/// The header comment that lists a result's AO properties.
pub fn ao_comment(names: &[&str]) -> String {
    format!("{AO_COMMENT} {}", names.join(" "))
}

/// The vertex properties a result's AO is written to, with a note for each one left out.
/// `ao` (for scripts) and [`CLOUDCOMPARE_AO`]: a float one is an earlier result and is
/// replaced; any other type is the input's own data and stays, with the result beside it
/// under the first free `NAME_1`, `NAME_2`…. [`MESHLAB_AO`]: added when absent, replaced when
/// an earlier result's header comment lists it; otherwise an input's own `quality` (a
/// scanner's confidence, say) stays and the AO is not written there.
pub fn ao_properties(ply: &PlyFile, path: &Path) -> (Vec<String>, Vec<String>) {
    let kind = |p: &str| ply.property_kind("vertex", p);
    let float = |p: &str| {
        matches!(
            kind(p),
            Some(PropertyKind::Scalar(ScalarType::F32 | ScalarType::F64))
        )
    };
    let free = |base: &str| {
        if kind(base).is_none() || float(base) {
            base.to_string()
        } else {
            (1..)
                .map(|k| format!("{base}_{k}"))
                .find(|n| kind(n).is_none())
                .unwrap_or_default()
        }
    };
    let mut names = vec![free("ao"), free(CLOUDCOMPARE_AO)];
    let mut notes = Vec::new();
    let earlier = ply.header.comments.iter().any(|c| {
        c.strip_prefix(AO_COMMENT)
            .is_some_and(|l| l.split_whitespace().any(|n| n == MESHLAB_AO))
    });
    if kind(MESHLAB_AO).is_none() || earlier {
        names.push(MESHLAB_AO.to_string());
    } else {
        notes.push(format!(
            "{}: the input's own vertex `{MESHLAB_AO}` is kept, so MeshLab shows it, not the \
             AO (the AO is in `{}` and `{}`)",
            path.display(),
            names[0],
            names[1]
        ));
    }
    (names, notes)
}

/// Writes `ply` with per-vertex AO (one value per vertex, all finite; under the names of
/// [`ao_properties`]) and colours to `path`. Non-finite values of the input's float
/// properties are written as 0 ([`nonfinite_properties`]). Returns what the user should know
/// about the output. `extra` are further float vertex columns (name and one value per
/// vertex), which replace the input's columns of the same name.
pub fn write_result_ply(
    ply: &PlyFile,
    ao: &[f32],
    extra: &[(&str, Vec<f64>)],
    gamma: f32,
    color: ColorMode,
    comment: &str,
    path: &Path,
) -> Result<Vec<String>> {
    if ao.iter().any(|a| !a.is_finite()) {
        return Err(Error::Param(format!(
            "{}: refusing to write a non-finite ao value (internal error)",
            path.display()
        )));
    }
    let cleaned: PlyFile;
    let bad = nonfinite_properties(ply);
    let ply = if bad.is_empty() {
        ply
    } else {
        let mut c = ply.clone();
        for (name, _) in &bad {
            let v: Vec<f64> = c
                .scalar_column("vertex", name)
                .unwrap_or_default()
                .into_iter()
                .map(|x| if x.is_finite() { x } else { 0.0 })
                .collect();
            // The property exists: it keeps its type (the one given is ignored).
            c.set_scalar_column("vertex", name, ScalarType::F32, &v)?;
        }
        cleaned = c;
        &cleaned
    };
    let aof: Vec<f64> = ao.iter().map(|&a| a as f64).collect();
    let kind = |p: &str| ply.property_kind("vertex", p);
    let (names, notes) = ao_properties(ply, path);
    let channels = ["red", "green", "blue"];
    let present = channels.iter().filter(|c| kind(c).is_some()).count();
    let has_rgb = present == 3;
    // Greys on the colours' own scale (0–1 floats, 8 or 16 bits): existing columns keep
    // their type.
    let scale = if has_rgb {
        colour_step(ply).unwrap_or(1.0)
    } else {
        1.0
    };
    let greys: Vec<f64> = ao.iter().map(|&a| grey(a, gamma) as f64 * scale).collect();
    let mut modulated: Vec<Vec<f64>> = Vec::new();
    if has_rgb && color == ColorMode::Modulate {
        for c in channels {
            let orig = ply.scalar_column("vertex", c).unwrap_or_default();
            modulated.push(
                orig.iter()
                    .zip(&greys)
                    .map(|(o, g)| o * g / (255.0 * scale))
                    .collect(),
            );
        }
    }
    let mut cols: Vec<(&str, ScalarType, &[f64])> = names
        .iter()
        .map(|n| (n.as_str(), ScalarType::F32, aof.as_slice()))
        .collect();
    for (k, c) in channels.into_iter().enumerate() {
        match (has_rgb, color) {
            (true, ColorMode::Keep) => {}
            (true, ColorMode::Modulate) => cols.push((c, ScalarType::U8, &modulated[k])),
            // Only some channels: they are the input's data, not a colour to replace.
            (false, _) if present > 0 => {}
            _ => cols.push((c, ScalarType::U8, &greys)),
        }
    }
    for (name, v) in extra {
        cols.push((name, ScalarType::F32, v));
    }
    let listed: Vec<&str> = names.iter().map(String::as_str).collect();
    let comments = [comment.to_string(), ao_comment(&listed)];
    ply.write_path_with_columns(path, "vertex", &cols, &comments)?;
    Ok(notes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grey_levels() {
        assert_eq!(grey(1.0, 1.0), 255);
        assert_eq!(grey(0.0, 1.0), 0);
        assert_eq!(grey(0.5, 1.0), 128);
        // gamma 2: 0.25^(1/2) = 0.5
        assert_eq!(grey(0.25, 2.0), 128);
        assert_eq!(grey(f32::NAN.max(0.0), 1.0), 0);
    }

    #[test]
    fn colour_modes() {
        let dir = tempfile::tempdir().unwrap();
        let xs = [0.0, 1.0];
        let red = [200.0, 100.0];
        let ply = PlyFile::from_vertex_columns(
            &[
                ("x", ScalarType::F32, &xs),
                ("y", ScalarType::F32, &xs),
                ("z", ScalarType::F32, &xs),
                ("red", ScalarType::U8, &red),
                ("green", ScalarType::U8, &red),
                ("blue", ScalarType::U8, &red),
            ],
            &[],
        )
        .unwrap();
        let ao = [0.5f32, 1.0];
        let get = |mode: ColorMode| {
            let p = dir.path().join(format!("{mode:?}.ply"));
            write_result_ply(&ply, &ao, &[], 1.0, mode, "test", &p).unwrap();
            let o = PlyFile::from_path(&p).unwrap();
            for name in ["ao", CLOUDCOMPARE_AO, MESHLAB_AO] {
                assert_eq!(o.scalar_column("vertex", name).unwrap(), vec![0.5, 1.0]);
            }
            o.scalar_column("vertex", "red").unwrap()
        };
        // modulate: 200·128/255 = 100.4 → 100; 100·255/255 = 100
        assert_eq!(get(ColorMode::Modulate), vec![100.0, 100.0]);
        assert_eq!(get(ColorMode::Replace), vec![128.0, 255.0]);
        assert_eq!(get(ColorMode::Keep), vec![200.0, 100.0]);
        // Without input colours, grey is added.
        let bare = PlyFile::from_vertex_columns(
            &[
                ("x", ScalarType::F32, &xs),
                ("y", ScalarType::F32, &xs),
                ("z", ScalarType::F32, &xs),
            ],
            &[],
        )
        .unwrap();
        let p = dir.path().join("bare.ply");
        write_result_ply(&bare, &ao, &[], 2.0, ColorMode::Keep, "test", &p).unwrap();
        let o = PlyFile::from_path(&p).unwrap();
        // gamma 2: 0.5^(1/2) = 0.7071 → 180
        assert_eq!(
            o.scalar_column("vertex", "green").unwrap(),
            vec![180.0, 255.0]
        );
        // Non-finite AO is refused, and nothing is written.
        let q = dir.path().join("nan.ply");
        assert!(
            write_result_ply(&ply, &[f32::NAN, 1.0], &[], 1.0, ColorMode::Keep, "t", &q).is_err()
        );
        assert!(!q.exists());
    }

    /// An `ao` the input holds as integers is its own data: kept, with the result as `ao_1`.
    /// A float `ao` (an earlier result) is replaced. Float colours on a 0–1 scale get greys on
    /// that scale; a lone `red` is data, not a colour, and stays.
    #[test]
    fn existing_ao_float_colours_and_partial_colours() {
        let dir = tempfile::tempdir().unwrap();
        let xs = [0.0, 1.0];
        let cols = |extra: &[(&'static str, ScalarType, &'static [f64])]| {
            let mut c: Vec<(&str, ScalarType, &[f64])> = vec![
                ("x", ScalarType::F32, &xs),
                ("y", ScalarType::F32, &xs),
                ("z", ScalarType::F32, &xs),
            ];
            c.extend_from_slice(extra);
            PlyFile::from_vertex_columns(&c, &[]).unwrap()
        };
        let ao = [0.5f32, 1.0];
        let run = |ply: &PlyFile, mode: ColorMode, name: &str| {
            let p = dir.path().join(name);
            write_result_ply(ply, &ao, &[], 1.0, mode, "test", &p).unwrap();
            PlyFile::from_path(&p).unwrap()
        };
        let o = run(
            &cols(&[("ao", ScalarType::U8, &[3.0, 7.0])]),
            ColorMode::Modulate,
            "u8.ply",
        );
        assert_eq!(o.scalar_column("vertex", "ao").unwrap(), vec![3.0, 7.0]);
        assert_eq!(o.scalar_column("vertex", "ao_1").unwrap(), vec![0.5, 1.0]);
        assert_eq!(
            o.scalar_column("vertex", "scalar_ao").unwrap(),
            vec![0.5, 1.0]
        );
        let o = run(
            &cols(&[("ao", ScalarType::F64, &[0.1, 0.2])]),
            ColorMode::Modulate,
            "f.ply",
        );
        assert_eq!(o.scalar_column("vertex", "ao").unwrap(), vec![0.5, 1.0]);
        assert!(!o.has_property("vertex", "ao_1"));
        let unit: &[(&str, ScalarType, &[f64])] = &[
            ("red", ScalarType::F32, &[0.8, 0.4]),
            ("green", ScalarType::F32, &[0.8, 0.4]),
            ("blue", ScalarType::F32, &[0.8, 0.4]),
        ];
        let o = run(&cols(unit), ColorMode::Replace, "unit_replace.ply");
        let r = o.scalar_column("vertex", "red").unwrap();
        assert!((r[0] - 128.0 / 255.0).abs() < 1e-6 && r[1] == 1.0, "{r:?}");
        let o = run(&cols(unit), ColorMode::Modulate, "unit_mod.ply");
        let r = o.scalar_column("vertex", "red").unwrap();
        assert!((r[0] - 0.8 * 128.0 / 255.0).abs() < 1e-6 && (r[1] - 0.4).abs() < 1e-6);
        // 16-bit colours get 16-bit greys; modulating keeps their scale.
        let wide: &[(&str, ScalarType, &[f64])] = &[
            ("red", ScalarType::U16, &[60000.0, 300.0]),
            ("green", ScalarType::U16, &[0.0, 0.0]),
            ("blue", ScalarType::U16, &[0.0, 0.0]),
        ];
        let o = run(&cols(wide), ColorMode::Replace, "wide_replace.ply");
        assert_eq!(
            o.scalar_column("vertex", "green").unwrap(),
            vec![128.0 * 257.0, 65535.0]
        );
        let o = run(&cols(wide), ColorMode::Modulate, "wide_mod.ply");
        let r = o.scalar_column("vertex", "red").unwrap();
        assert_eq!(r, vec![(60000.0f64 * 128.0 / 255.0).round(), 300.0]);
        let o = run(
            &cols(&[("red", ScalarType::U8, &[9.0, 9.0])]),
            ColorMode::Replace,
            "red.ply",
        );
        assert_eq!(o.scalar_column("vertex", "red").unwrap(), vec![9.0, 9.0]);
        assert!(!o.has_property("vertex", "green"));
    }

    /// The AO goes to `ao`, `scalar_ao` and `quality`. An input's own `quality` stays (with a
    /// note); an earlier result's three are replaced, not duplicated.
    #[test]
    fn ao_for_cloudcompare_and_meshlab() {
        let dir = tempfile::tempdir().unwrap();
        let xs = [0.0, 1.0];
        let ao = [0.25f32, 0.75];
        let own = PlyFile::from_vertex_columns(
            &[
                ("x", ScalarType::F32, &xs),
                ("y", ScalarType::F32, &xs),
                ("z", ScalarType::F32, &xs),
                ("quality", ScalarType::F32, &[7.0, 9.0]),
            ],
            &[],
        )
        .unwrap();
        let p = dir.path().join("own.ply");
        let notes = write_result_ply(&own, &ao, &[], 1.0, ColorMode::Keep, "t", &p).unwrap();
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(notes[0].contains("own.ply") && notes[0].contains("quality"));
        let o = PlyFile::from_path(&p).unwrap();
        assert_eq!(
            o.scalar_column("vertex", "quality").unwrap(),
            vec![7.0, 9.0]
        );
        assert_eq!(
            o.scalar_column("vertex", "scalar_ao").unwrap(),
            vec![0.25, 0.75]
        );
        // Its output run again: the input's quality still stays.
        let q = dir.path().join("again.ply");
        let notes = write_result_ply(&o, &[0.5, 0.5], &[], 1.0, ColorMode::Keep, "t", &q).unwrap();
        assert_eq!(notes.len(), 1);
        let o2 = PlyFile::from_path(&q).unwrap();
        assert_eq!(
            o2.scalar_column("vertex", "quality").unwrap(),
            vec![7.0, 9.0]
        );
        assert_eq!(o2.scalar_column("vertex", "ao").unwrap(), vec![0.5, 0.5]);
        // A result without an own quality, run again: all three replaced in place.
        let bare = PlyFile::from_vertex_columns(
            &[
                ("x", ScalarType::F32, &xs),
                ("y", ScalarType::F32, &xs),
                ("z", ScalarType::F32, &xs),
            ],
            &[],
        )
        .unwrap();
        let r1 = dir.path().join("r1.ply");
        assert!(
            write_result_ply(&bare, &ao, &[], 1.0, ColorMode::Keep, "t", &r1)
                .unwrap()
                .is_empty()
        );
        let first = PlyFile::from_path(&r1).unwrap();
        let r2 = dir.path().join("r2.ply");
        assert!(
            write_result_ply(&first, &[1.0, 0.0], &[], 1.0, ColorMode::Keep, "t", &r2)
                .unwrap()
                .is_empty()
        );
        let second = PlyFile::from_path(&r2).unwrap();
        let ei = second.element("vertex").unwrap();
        let names: Vec<&str> = second.header.elements[ei]
            .props
            .iter()
            .map(|p| p.name.as_str())
            .collect();
        assert_eq!(
            names,
            [
                "x",
                "y",
                "z",
                "ao",
                "scalar_ao",
                "quality",
                "red",
                "green",
                "blue"
            ]
        );
        for name in ["ao", "scalar_ao", "quality"] {
            assert_eq!(
                second.scalar_column("vertex", name).unwrap(),
                vec![1.0, 0.0]
            );
        }
    }
}
