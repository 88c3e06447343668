//! Writing results: the input PLY with `float ao` and grey (or modulated) colours added, and a
//! preview picture of the AO map as the scanner saw it. Every file is written atomically.

use super::atomic::write_atomic;
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

/// Writes `ply` with per-vertex `ao` (one value per vertex, all finite) and colours to `path`.
/// Non-finite values of the input's float properties are written as 0
/// ([`nonfinite_properties`]).
pub fn write_result_ply(
    ply: &PlyFile,
    ao: &[f32],
    gamma: f32,
    color: ColorMode,
    comment: &str,
    path: &Path,
) -> Result<()> {
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
    let float = |k: Option<PropertyKind>| {
        matches!(
            k,
            Some(PropertyKind::Scalar(ScalarType::F32 | ScalarType::F64))
        )
    };
    // A float `ao` is a previous result and is replaced; any other `ao` is the input's own
    // data and stays, with the result beside it under the first free name.
    let ao_name = if kind("ao").is_none() || float(kind("ao")) {
        "ao".to_string()
    } else {
        (1..)
            .map(|k| format!("ao_{k}"))
            .find(|n| kind(n).is_none())
            .unwrap_or_default()
    };
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
    let mut cols: Vec<(&str, ScalarType, &[f64])> = vec![(&ao_name, ScalarType::F32, &aof)];
    for (k, c) in channels.into_iter().enumerate() {
        match (has_rgb, color) {
            (true, ColorMode::Keep) => {}
            (true, ColorMode::Modulate) => cols.push((c, ScalarType::U8, &modulated[k])),
            // Only some channels: they are the input's data, not a colour to replace.
            (false, _) if present > 0 => {}
            _ => cols.push((c, ScalarType::U8, &greys)),
        }
    }
    ply.write_path_with_columns(path, "vertex", &cols, &[comment.to_string()])
}

/// Largest preview side; bigger maps are box-downsampled by an integer factor.
const MAX_PREVIEW: usize = 8192;

/// Writes a grey + alpha PNG of a `width × height` map (`None` = empty pixel, transparent).
pub fn write_preview(
    path: &Path,
    width: usize,
    height: usize,
    values: &[Option<f32>],
    gamma: f32,
) -> Result<()> {
    let f = width.max(height).div_ceil(MAX_PREVIEW).max(1);
    let (w, h) = (width.div_ceil(f).max(1), height.div_ceil(f).max(1));
    let mut buf = vec![0u8; w * h * 2];
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut n) = (0.0f32, 0u32);
            for yy in y * f..((y + 1) * f).min(height) {
                for xx in x * f..((x + 1) * f).min(width) {
                    if let Some(v) = values[yy * width + xx] {
                        s += v;
                        n += 1;
                    }
                }
            }
            if n > 0 {
                buf[(y * w + x) * 2] = grey(s / n as f32, gamma);
                buf[(y * w + x) * 2 + 1] = 255;
            }
        }
    }
    write_atomic(path, |out| {
        let mut enc = png::Encoder::new(out, w as u32, h as u32);
        enc.set_color(png::ColorType::GrayscaleAlpha);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header().map_err(std::io::Error::other)?;
        wr.write_image_data(&buf).map_err(std::io::Error::other)?;
        wr.finish().map_err(std::io::Error::other)?;
        Ok(())
    })
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
            write_result_ply(&ply, &ao, 1.0, mode, "test", &p).unwrap();
            let o = PlyFile::read_path(&p).unwrap();
            assert_eq!(o.scalar_column("vertex", "ao").unwrap(), vec![0.5, 1.0]);
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
        write_result_ply(&bare, &ao, 2.0, ColorMode::Keep, "test", &p).unwrap();
        let o = PlyFile::read_path(&p).unwrap();
        // gamma 2: 0.5^(1/2) = 0.7071 → 180
        assert_eq!(
            o.scalar_column("vertex", "green").unwrap(),
            vec![180.0, 255.0]
        );
        // Non-finite AO is refused, and nothing is written.
        let q = dir.path().join("nan.ply");
        assert!(write_result_ply(&ply, &[f32::NAN, 1.0], 1.0, ColorMode::Keep, "t", &q).is_err());
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
            write_result_ply(ply, &ao, 1.0, mode, "test", &p).unwrap();
            PlyFile::read_path(&p).unwrap()
        };
        let o = run(
            &cols(&[("ao", ScalarType::U8, &[3.0, 7.0])]),
            ColorMode::Modulate,
            "u8.ply",
        );
        assert_eq!(o.scalar_column("vertex", "ao").unwrap(), vec![3.0, 7.0]);
        assert_eq!(o.scalar_column("vertex", "ao_1").unwrap(), vec![0.5, 1.0]);
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

    #[test]
    fn preview_is_a_png() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        write_preview(
            &p,
            3,
            2,
            &[Some(1.0), None, Some(0.0), None, None, Some(0.5)],
            1.0,
        )
        .unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
    }
}
