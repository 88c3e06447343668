//! The preview picture of a scan: its AO map as the sensor saw it, turned so that world up
//! is at the top, cropped to the data, cleaned of lone outliers and contrast-stretched. Only
//! the picture changes: the `ao` values and colours of the outputs are not touched.
//!
//! - **Upright**: the map is turned by the one of its eight right-angle rotations and mirror
//!   images that best puts the given up axis at the top and the sensor's right (its viewing
//!   direction × up) at the right. Only the sensor's rays decide, not the points, so a flat
//!   floor seen from above turns as well as a wall. A scan rolled by an angle between two
//!   right angles comes out turned by the nearer one.
//! - **Speckle**: a merged value comes from other views' maps at the point's projection; on
//!   sparse scans a point sometimes lands on a pixel of another surface, and its value stands
//!   alone among its neighbours' (the single-view maps, blurred, show none of it). Each pixel
//!   takes the median of itself and its filled 8 neighbours, and an empty pixel with at least
//!   5 filled neighbours (a gap between sparse points) takes theirs.
//! - **Tone** ([`Tone::Stretch`]): the 1st–99th percentile of the picture's values spans black
//!   to white, then the gamma applies; a scan whose AO stays between 0.85 and 1 (a convex
//!   object) shows its shading instead of a white picture. [`Tone::Linear`] is grey = AO.

use crate::error::{Error, Result};
use crate::gbuffer::{GBuffer, EMPTY};
use crate::io::atomic::write_atomic;
use crate::io::output::grey;
use crate::projection::Projection;
use glam::{DMat3, DMat4, DVec3};
use rayon::prelude::*;
use serde::Serialize;
use std::path::Path;

/// Largest preview side; bigger maps are box-downsampled by an integer factor.
const MAX_PREVIEW: usize = 8192;

/// Share of the values left below black and above white by [`Tone::Stretch`], each side.
const STRETCH_TAIL: f64 = 0.01;

/// A stretch narrower than this (in AO) would only show noise: the picture stays linear.
const MIN_STRETCH: f32 = 0.02;

/// The world axis that points up in previews.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
pub enum Up {
    /// +x.
    #[value(name = "x")]
    #[serde(rename = "x")]
    X,
    /// +y (the Stanford scans, most meshes).
    #[value(name = "y")]
    #[serde(rename = "y")]
    Y,
    /// +z (surveying, laser scanners).
    #[default]
    #[value(name = "z")]
    #[serde(rename = "z")]
    Z,
    /// -x.
    #[value(name = "-x")]
    #[serde(rename = "-x")]
    NegX,
    /// -y.
    #[value(name = "-y")]
    #[serde(rename = "-y")]
    NegY,
    /// -z.
    #[value(name = "-z")]
    #[serde(rename = "-z")]
    NegZ,
}

impl Up {
    /// The axis as a world unit vector.
    pub fn vector(self) -> DVec3 {
        match self {
            Up::X => DVec3::X,
            Up::Y => DVec3::Y,
            Up::Z => DVec3::Z,
            Up::NegX => DVec3::NEG_X,
            Up::NegY => DVec3::NEG_Y,
            Up::NegZ => DVec3::NEG_Z,
        }
    }
}

/// How AO values become grey levels in a preview.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Tone {
    /// The 1st–99th percentile of the picture spans black to white.
    #[default]
    Stretch,
    /// Grey = AO (comparable between scans and runs).
    Linear,
}

/// How previews are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct PreviewStyle {
    /// World up.
    pub up: Up,
    /// Grey levels.
    pub tone: Tone,
}

/// A right-angle rotation or mirror image of a picture: a source pixel `(x, y)` goes to
/// `(a, b)` = `(y, x)` when `swap` else `(x, y)`, then `a` and `b` are counted from the far
/// side when `flip_x` and `flip_y`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Orientation {
    /// Source rows become columns.
    pub swap: bool,
    /// Mirror the columns after the swap.
    pub flip_x: bool,
    /// Mirror the rows after the swap.
    pub flip_y: bool,
}

impl Orientation {
    /// All eight, the identity first.
    fn all() -> impl Iterator<Item = Orientation> {
        (0..8u8).map(|k| Orientation {
            swap: k & 4 != 0,
            flip_x: k & 1 != 0,
            flip_y: k & 2 != 0,
        })
    }

    /// Where source pixel `(x, y)` of a `w × h` picture goes, and the turned picture's size.
    #[inline]
    pub fn apply(&self, x: usize, y: usize, w: usize, h: usize) -> (usize, usize, usize, usize) {
        let (a, b, ow, oh) = if self.swap {
            (y, x, h, w)
        } else {
            (x, y, w, h)
        };
        let a = if self.flip_x { ow - 1 - a } else { a };
        let b = if self.flip_y { oh - 1 - b } else { b };
        (a, b, ow, oh)
    }

    /// A source-image gradient `(along x, along y)` seen along the turned picture's x and y.
    fn turn(&self, g: [f64; 2]) -> [f64; 2] {
        let [gx, gy] = if self.swap { [g[1], g[0]] } else { g };
        [
            if self.flip_x { -gx } else { gx },
            if self.flip_y { -gy } else { gy },
        ]
    }
}

/// The orientation that puts `up` (world) at the top of the map of `proj` and the sensor's
/// right at the right, from the rays of the filled pixels (`filled(i)` for pixel `i`) on a
/// lattice of about 128 × 128; `pose` is the scan's local → world transform. The identity
/// when the rays say nothing (a sensor looking straight along `up`, an empty map).
pub fn orientation(
    proj: &Projection,
    pose: DMat4,
    up: DVec3,
    filled: impl Fn(usize) -> bool,
) -> Orientation {
    let (w, h) = (proj.width, proj.height);
    let rot = DMat3::from_mat4(pose);
    let step = (w.max(h) / 128).max(1);
    let world = |x: f32, y: f32| {
        proj.ray(x, y).map(|(o, d)| {
            let (o, d) = (o.as_dvec3(), d.as_dvec3());
            (rot * (o + d), rot * d)
        })
    };
    // How up-ness and right-ness change per pixel along the map's x and y.
    let (mut g_up, mut g_right) = ([0.0f64; 2], [0.0f64; 2]);
    for y in (0..h).step_by(step) {
        for x in (0..w).step_by(step) {
            if !filled(y * w + x) {
                continue;
            }
            let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
            let (Some((p, d)), Some((px, _)), Some((py, _))) =
                (world(fx, fy), world(fx + 1.0, fy), world(fx, fy + 1.0))
            else {
                continue;
            };
            let right = d.cross(up);
            for (k, dp) in [px - p, py - p].into_iter().enumerate() {
                if dp.is_finite() {
                    g_up[k] += up.dot(dp);
                    g_right[k] += right.dot(dp);
                }
            }
        }
    }
    let score = |o: &Orientation| {
        let (u, r) = (o.turn(g_up), o.turn(g_right));
        // Up falls with the row; right grows with the column.
        r[0] - u[1]
    };
    let mut best = Orientation::default();
    let mut best_score = score(&best);
    for o in Orientation::all() {
        let s = score(&o);
        // A clear margin: near-ties keep the map as the sensor stored it.
        if s > best_score + 1e-9 * best_score.abs().max(1e-30) {
            best = o;
            best_score = s;
        }
    }
    best
}

/// A picture of values, NaN where empty.
#[derive(Debug, Clone, PartialEq)]
pub struct Picture {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Row-major values.
    pub values: Vec<f32>,
}

impl Picture {
    /// Pixel `i` of a G-buffer takes `ao` of its point (NaN when empty).
    pub fn of_gbuffer(g: &GBuffer, ao: &[f32]) -> Picture {
        Picture {
            width: g.width,
            height: g.height,
            values: g
                .point
                .par_iter()
                .map(|&p| {
                    if p == EMPTY {
                        f32::NAN
                    } else {
                        ao.get(p as usize).copied().unwrap_or(f32::NAN)
                    }
                })
                .collect(),
        }
    }

    /// The smallest box holding every filled pixel, with a margin of 1 % of the larger side
    /// (at least 2 pixels); an empty picture stays as it is.
    pub fn cropped(self) -> Picture {
        let (w, h) = (self.width, self.height);
        let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
        for (i, v) in self.values.iter().enumerate() {
            if !v.is_nan() {
                let (x, y) = (i % w, i / w);
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
            }
        }
        if x0 == usize::MAX {
            return self;
        }
        let m = (w.max(h) / 100).max(2);
        let (x0, y0) = (x0.saturating_sub(m), y0.saturating_sub(m));
        let (x1, y1) = ((x1 + m).min(w - 1), (y1 + m).min(h - 1));
        let (cw, ch) = (x1 - x0 + 1, y1 - y0 + 1);
        let mut values = Vec::with_capacity(cw * ch);
        for y in y0..=y1 {
            values.extend_from_slice(&self.values[y * w + x0..=y * w + x1]);
        }
        Picture {
            width: cw,
            height: ch,
            values,
        }
    }

    /// Box-downsampled by the smallest integer factor that fits [`MAX_PREVIEW`] (the mean of
    /// the filled pixels of each box).
    pub fn fitted(self) -> Picture {
        let (width, height) = (self.width, self.height);
        let f = width.max(height).div_ceil(MAX_PREVIEW).max(1);
        if f == 1 {
            return self;
        }
        let (w, h) = (width.div_ceil(f), height.div_ceil(f));
        let mut values = vec![f32::NAN; w * h];
        values.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, out) in row.iter_mut().enumerate() {
                let (mut s, mut n) = (0.0f32, 0u32);
                for yy in y * f..((y + 1) * f).min(height) {
                    for xx in x * f..((x + 1) * f).min(width) {
                        let v = self.values[yy * width + xx];
                        if !v.is_nan() {
                            s += v;
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    *out = s / n as f32;
                }
            }
        });
        Picture {
            width: w,
            height: h,
            values,
        }
    }

    /// Each filled pixel becomes the median of itself and its filled 8 neighbours; an empty
    /// pixel with at least 5 filled neighbours becomes theirs.
    pub fn despeckled(&self) -> Picture {
        let (w, h) = (self.width, self.height);
        let mut values = vec![f32::NAN; w * h];
        values.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let mut win = [0.0f32; 9];
            for (x, out) in row.iter_mut().enumerate() {
                let mut n = 0;
                for yy in y.saturating_sub(1)..=(y + 1).min(h - 1) {
                    for xx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                        let v = self.values[yy * w + xx];
                        if !v.is_nan() {
                            win[n] = v;
                            n += 1;
                        }
                    }
                }
                let own = !self.values[y * w + x].is_nan();
                if own || n >= 5 {
                    let s = &mut win[..n];
                    s.sort_unstable_by(f32::total_cmp);
                    *out = if n % 2 == 1 {
                        s[n / 2]
                    } else {
                        0.5 * (s[n / 2 - 1] + s[n / 2])
                    };
                }
            }
        });
        Picture {
            width: w,
            height: h,
            values,
        }
    }

    /// The values at the `tail` and `1 − tail` quantiles of the filled pixels (a histogram of
    /// 4096 bins over [0, 1]); `None` when no pixel is filled.
    pub fn quantiles(&self, tail: f64) -> Option<(f32, f32)> {
        const BINS: usize = 4096;
        let mut hist = vec![0u64; BINS];
        for v in self.values.iter().filter(|v| !v.is_nan()) {
            hist[((v.clamp(0.0, 1.0) * (BINS - 1) as f32).round()) as usize] += 1;
        }
        let n: u64 = hist.iter().sum();
        if n == 0 {
            return None;
        }
        let at = |q: f64| {
            let target = (q * n as f64).ceil().max(1.0) as u64;
            let mut acc = 0;
            for (b, c) in hist.iter().enumerate() {
                acc += c;
                if acc >= target {
                    return b as f32 / (BINS - 1) as f32;
                }
            }
            1.0
        };
        Some((at(tail), at(1.0 - tail)))
    }

    /// Grey + alpha bytes, turned by `o`: grey from the value by `tone` and `gamma`, alpha 0
    /// where empty. Returns the turned width and height too.
    pub fn grey_alpha(&self, tone: Tone, gamma: f32, o: Orientation) -> (usize, usize, Vec<u8>) {
        let (lo, hi) = match (tone, self.quantiles(STRETCH_TAIL)) {
            (Tone::Stretch, Some((lo, hi))) if hi - lo >= MIN_STRETCH => (lo, hi),
            _ => (0.0, 1.0),
        };
        let (w, h) = (self.width, self.height);
        let (_, _, ow, oh) = o.apply(0, 0, w, h);
        let mut buf = vec![0u8; ow * oh * 2];
        for (i, &v) in self.values.iter().enumerate() {
            if v.is_nan() {
                continue;
            }
            let (a, b, _, _) = o.apply(i % w, i / w, w, h);
            let k = (b * ow + a) * 2;
            buf[k] = grey((v - lo) / (hi - lo), gamma);
            buf[k + 1] = 255;
        }
        (ow, oh, buf)
    }
}

/// Writes the preview of one scan: its G-buffer's pixels with the scan's AO per point,
/// upright for `style.up` with the sensor `proj` placed by `pose`, cropped, despeckled and
/// toned (see the module docs).
pub fn write_scan_preview(
    path: &Path,
    gbuf: &GBuffer,
    proj: &Projection,
    pose: DMat4,
    ao: &[f32],
    gamma: f32,
    style: PreviewStyle,
) -> Result<()> {
    if gbuf.width != proj.width || gbuf.height != proj.height {
        return Err(Error::Param(format!(
            "{}: map {}×{} and sensor {}×{} differ (internal error)",
            path.display(),
            gbuf.width,
            gbuf.height,
            proj.width,
            proj.height
        )));
    }
    let o = orientation(proj, pose, style.up.vector(), |i| gbuf.point[i] != EMPTY);
    let pic = Picture::of_gbuffer(gbuf, ao)
        .cropped()
        .fitted()
        .despeckled();
    let (w, h, buf) = pic.grey_alpha(style.tone, gamma, o);
    write_png(path, w, h, &buf)
}

/// Writes grey + alpha bytes as an 8-bit PNG.
pub fn write_png(path: &Path, w: usize, h: usize, buf: &[u8]) -> Result<()> {
    write_atomic(path, |out| {
        let mut enc = png::Encoder::new(out, w as u32, h as u32);
        enc.set_color(png::ColorType::GrayscaleAlpha);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header().map_err(std::io::Error::other)?;
        wr.write_image_data(buf).map_err(std::io::Error::other)?;
        wr.finish().map_err(std::io::Error::other)?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pic(w: usize, h: usize, v: &[f32]) -> Picture {
        Picture {
            width: w,
            height: h,
            values: v.to_vec(),
        }
    }

    /// The eight orientations are the eight distinct permutations of a 3 × 2 picture.
    #[test]
    fn orientations_permute() {
        let mut seen = std::collections::HashSet::new();
        for o in Orientation::all() {
            let mut img = Vec::new();
            for y in 0..2 {
                for x in 0..3 {
                    img.push(o.apply(x, y, 3, 2));
                }
            }
            let (_, _, ow, oh) = img[0];
            assert_eq!(ow * oh, 6);
            let cells: std::collections::HashSet<_> = img.iter().map(|p| (p.0, p.1)).collect();
            assert_eq!(cells.len(), 6);
            assert!(img.iter().all(|p| p.0 < ow && p.1 < oh));
            seen.insert(img);
        }
        assert_eq!(seen.len(), 8);
    }

    /// A lone outlier takes its neighbours' value; a gap among filled pixels is filled; an
    /// empty corner with few neighbours stays empty.
    #[test]
    fn despeckle() {
        let n = f32::NAN;
        #[rustfmt::skip]
        let p = pic(4, 3, &[
            0.5, 0.5, 0.5, n,
            0.5, 0.0, n,   n,
            0.5, 0.5, 0.5, n,
        ]);
        let d = p.despeckled();
        assert_eq!(d.values[5], 0.5);
        assert_eq!(d.values[6], 0.5, "gap between 5 filled neighbours");
        assert!(d.values[3].is_nan() && d.values[7].is_nan() && d.values[11].is_nan());
    }

    /// The crop keeps the filled box and a 2-pixel margin.
    #[test]
    fn crop() {
        let mut v = vec![f32::NAN; 20 * 10];
        v[5 * 20 + 10] = 0.5;
        let c = pic(20, 10, &v).cropped();
        assert_eq!((c.width, c.height), (5, 5));
        assert_eq!(c.values[2 * 5 + 2], 0.5);
    }

    /// The stretch maps the 1st–99th percentile to black–white; a flat picture stays linear.
    #[test]
    fn stretch() {
        let v: Vec<f32> = (0..=100).map(|i| 0.8 + 0.002 * i as f32).collect();
        let p = pic(101, 1, &v);
        let (lo, hi) = p.quantiles(0.01).unwrap();
        assert!(
            (lo - 0.802).abs() < 5e-4 && (hi - 0.998).abs() < 5e-4,
            "{lo} {hi}"
        );
        let (_, _, b) = p.grey_alpha(Tone::Stretch, 1.0, Orientation::default());
        assert_eq!((b[0], b[2 * 100]), (0, 255));
        assert!((127..=128).contains(&b[2 * 50]), "{}", b[100]);
        let (_, _, b) = p.grey_alpha(Tone::Linear, 1.0, Orientation::default());
        assert_eq!((b[0], b[2 * 100]), (204, 255));
        let flat = pic(3, 1, &[0.8, 0.81, f32::NAN]);
        let (_, _, b) = flat.grey_alpha(Tone::Stretch, 1.0, Orientation::default());
        assert_eq!(b, [204, 255, 207, 255, 0, 0]);
    }
}
