//! Writing results: the input PLY with `float ao` and grey (or modulated) colours added, and a
//! preview picture of the AO map as the scanner saw it. Every file is written atomically.

use super::atomic::write_atomic;
use super::ply::{PlyFile, ScalarType};
use crate::error::{Error, Result};
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
    (g * 255.0).round().clamp(0.0, 255.0) as u8
}

/// Writes `ply` with per-vertex `ao` (one value per vertex, all finite) and colours to `path`.
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
    let aof: Vec<f64> = ao.iter().map(|&a| a as f64).collect();
    let has_rgb = ["red", "green", "blue"]
        .iter()
        .all(|c| ply.has_property("vertex", c));
    let greys: Vec<f64> = ao.iter().map(|&a| grey(a, gamma) as f64).collect();
    let mut modulated: Vec<Vec<f64>> = Vec::new();
    if has_rgb && color == ColorMode::Modulate {
        for c in ["red", "green", "blue"] {
            let orig = ply.scalar_column("vertex", c).unwrap_or_default();
            modulated.push(
                orig.iter()
                    .zip(&greys)
                    .map(|(o, g)| o * g / 255.0)
                    .collect(),
            );
        }
    }
    let mut cols: Vec<(&str, ScalarType, &[f64])> = vec![("ao", ScalarType::F32, &aof)];
    for (k, c) in ["red", "green", "blue"].into_iter().enumerate() {
        match (has_rgb, color) {
            (true, ColorMode::Keep) => {}
            (true, ColorMode::Modulate) => cols.push((c, ScalarType::U8, &modulated[k])),
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
