//! What a depth stream is made of on disk: 16-bit PNG depth frames, pinhole intrinsics
//! (`fx fy cx cy` or an Open3D camera JSON) and a trajectory (Open3D/Redwood `.log` or TUM).
//! Every error names the file it is about.

use crate::error::{Error, Result};
use glam::{DMat4, DQuat, DVec3, DVec4};
use std::io::BufReader;
use std::path::{Path, PathBuf};

/// Pinhole intrinsics in pixels, OpenCV convention (pixel centres at integers, x right,
/// y down, the camera looking along +z).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Intrinsics {
    /// Focal length along x.
    pub fx: f64,
    /// Focal length along y.
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
}

impl Intrinsics {
    /// The same camera seen at `1/factor` of the resolution (pixel centres kept aligned).
    pub fn scaled_down(&self, factor: usize) -> Intrinsics {
        let f = factor.max(1) as f64;
        Intrinsics {
            fx: self.fx / f,
            fy: self.fy / f,
            cx: (self.cx + 0.5) / f - 0.5,
            cy: (self.cy + 0.5) / f - 0.5,
        }
    }
}

/// One depth frame: z-depth in metres per pixel, row-major, 0 where nothing was measured.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DepthFrame {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// z-depth (metres); 0 = no measurement.
    pub depth: Vec<f32>,
}

/// Parses `fx fy cx cy` (spaces or commas), or reads an Open3D camera JSON
/// (`intrinsic_matrix`, 9 values, column-major) when `s` names a file ending in `.json`, or
/// `fx fy cx cy` from any other file `s` names (the `intrinsics.txt` of `mvao synth --frames`).
pub fn parse_intrinsics(s: &str) -> Result<Intrinsics> {
    if s.to_ascii_lowercase().ends_with(".json") {
        return read_open3d_json(Path::new(s));
    }
    let path = Path::new(s);
    if path.is_file() {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        return parse_intrinsics_values(text.trim()).map_err(|e| match e {
            Error::Param(m) => Error::format(path, m.replace("--intrinsics", "intrinsics")),
            e => e,
        });
    }
    parse_intrinsics_values(s)
}

/// `fx fy cx cy` (spaces or commas).
fn parse_intrinsics_values(s: &str) -> Result<Intrinsics> {
    let v: Vec<f64> = s
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|t| !t.is_empty())
        .map(str::parse::<f64>)
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| Error::Param(format!("--intrinsics must be 'fx fy cx cy', got '{s}'")))?;
    match v[..] {
        [fx, fy, cx, cy] => check_intrinsics(Intrinsics { fx, fy, cx, cy })
            .map_err(|m| Error::Param(format!("--intrinsics: {m}"))),
        _ => Err(Error::Param(format!(
            "--intrinsics must be 'fx fy cx cy' or an Open3D camera JSON, got '{s}'"
        ))),
    }
}

fn check_intrinsics(k: Intrinsics) -> std::result::Result<Intrinsics, String> {
    let ok = |v: f64| v.is_finite();
    if !(k.fx > 0.0 && k.fy > 0.0 && ok(k.fx) && ok(k.fy) && ok(k.cx) && ok(k.cy)) {
        return Err(format!(
            "focal lengths must be positive and all values finite, got {} {} {} {}",
            k.fx, k.fy, k.cx, k.cy
        ));
    }
    Ok(k)
}

fn read_open3d_json(path: &Path) -> Result<Intrinsics> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| Error::format(path, format!("not JSON: {e}")))?;
    let m: Vec<f64> = v
        .get("intrinsic_matrix")
        .and_then(|m| m.as_array())
        .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
        .unwrap_or_default();
    if m.len() != 9 {
        return Err(Error::format(
            path,
            "no 'intrinsic_matrix' of 9 numbers (an Open3D camera JSON)",
        ));
    }
    // Column-major 3 × 3: fx at 0, fy at 4, cx at 6, cy at 7.
    check_intrinsics(Intrinsics {
        fx: m[0],
        fy: m[4],
        cx: m[6],
        cy: m[7],
    })
    .map_err(|msg| Error::format(path, msg))
}

/// Reads a 16-bit greyscale PNG depth frame: value / `scale` metres, 0 = no measurement.
pub fn read_depth_png(path: &Path, scale: f64) -> Result<DepthFrame> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let bad = |m: String| Error::format(path, m);
    let dec = png::Decoder::new(BufReader::new(file));
    let mut reader = dec
        .read_info()
        .map_err(|e| bad(format!("not a readable PNG: {e}")))?;
    let info = reader.info();
    let (w, h) = (info.width as usize, info.height as usize);
    if info.bit_depth != png::BitDepth::Sixteen || info.color_type != png::ColorType::Grayscale {
        return Err(bad(format!(
            "a depth frame must be a 16-bit greyscale PNG, this one is {:?} {}-bit",
            info.color_type, info.bit_depth as u8
        )));
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| bad("image too large".into()))?;
    let mut buf = vec![0u8; size];
    reader
        .next_frame(&mut buf)
        .map_err(|e| bad(format!("cannot decode: {e}")))?;
    if buf.len() < w * h * 2 {
        return Err(bad("truncated image data".into()));
    }
    let inv = if scale > 0.0 { 1.0 / scale } else { 0.0 };
    let depth = buf
        .chunks_exact(2)
        .take(w * h)
        .map(|b| (u16::from_be_bytes([b[0], b[1]]) as f64 * inv) as f32)
        .collect();
    Ok(DepthFrame {
        width: w,
        height: h,
        depth,
    })
}

/// Writes `depth` (metres) as a 16-bit greyscale PNG at `scale` units per metre (rounded,
/// clamped to 65535; 0 and non-finite values stay 0).
pub fn write_depth_png(path: &Path, frame: &DepthFrame, scale: f64) -> Result<()> {
    let mut buf = Vec::with_capacity(frame.depth.len() * 2);
    for &d in &frame.depth {
        let v = if d.is_finite() && d > 0.0 {
            (d as f64 * scale).round().clamp(0.0, 65535.0) as u16
        } else {
            0
        };
        buf.extend_from_slice(&v.to_be_bytes());
    }
    crate::io::atomic::write_atomic(path, |out| {
        let mut enc = png::Encoder::new(out, frame.width as u32, frame.height as u32);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let mut wr = enc.write_header().map_err(std::io::Error::other)?;
        wr.write_image_data(&buf).map_err(std::io::Error::other)?;
        wr.finish().map_err(std::io::Error::other)?;
        Ok(())
    })
}

/// The depth frames named by `inputs`: files as given, folders by their `*.png` files in
/// name order.
pub fn list_frames(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in inputs {
        if p.is_dir() {
            let mut v: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(|e| Error::io(p, e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|q| q.extension().is_some_and(|x| x.eq_ignore_ascii_case("png")))
                .collect();
            v.sort();
            if v.is_empty() {
                return Err(Error::format(p, "no .png depth frame in this folder"));
            }
            out.extend(v);
        } else {
            out.push(p.clone());
        }
    }
    Ok(out)
}

/// A camera trajectory: camera-to-world poses, with timestamps for TUM files.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    /// Camera-to-world pose per entry (f64).
    pub poses: Vec<DMat4>,
    /// Timestamp per entry (TUM), empty for `.log`.
    pub stamps: Vec<f64>,
}

/// Reads a trajectory: TUM (`timestamp tx ty tz qx qy qz qw` per line, `#` comments) when
/// every data line has 8 numbers, else Open3D/Redwood `.log` (a line `i j k` then 4 rows of
/// the 4 × 4 camera-to-world matrix).
pub fn read_trajectory(path: &Path) -> Result<Trajectory> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let lines: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
        .collect();
    if lines.is_empty() {
        return Err(Error::format(path, "no pose in this trajectory"));
    }
    let tum = lines.iter().all(|(_, l)| l.split_whitespace().count() == 8);
    if tum {
        read_tum(path, &lines)
    } else {
        read_log(path, &lines)
    }
}

fn numbers(path: &Path, no: usize, line: &str, want: usize) -> Result<Vec<f64>> {
    let v: Vec<f64> = line
        .split_whitespace()
        .map(str::parse::<f64>)
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| Error::format(path, format!("line {no}: not numbers: '{line}'")))?;
    if v.len() != want || v.iter().any(|x| !x.is_finite()) {
        return Err(Error::format(
            path,
            format!("line {no}: expected {want} finite numbers, got '{line}'"),
        ));
    }
    Ok(v)
}

fn read_tum(path: &Path, lines: &[(usize, &str)]) -> Result<Trajectory> {
    let mut t = Trajectory::default();
    for &(no, l) in lines {
        let v = numbers(path, no, l, 8)?;
        let q = DQuat::from_xyzw(v[4], v[5], v[6], v[7]);
        let len = q.length();
        if !(len > 1e-6) {
            return Err(Error::format(path, format!("line {no}: zero quaternion")));
        }
        let pose = DMat4::from_rotation_translation(q / len, DVec3::new(v[1], v[2], v[3]));
        t.poses.push(pose);
        t.stamps.push(v[0]);
    }
    Ok(t)
}

fn read_log(path: &Path, lines: &[(usize, &str)]) -> Result<Trajectory> {
    if lines.len() % 5 != 0 {
        return Err(Error::format(
            path,
            format!(
                "a .log trajectory has 5 lines per pose (an index line and 4 matrix rows); \
                 {} data lines is not a multiple of 5",
                lines.len()
            ),
        ));
    }
    let mut t = Trajectory::default();
    for block in lines.chunks(5) {
        let (no, head) = block[0];
        let n = head.split_whitespace().count();
        if n != 3 {
            return Err(Error::format(
                path,
                format!("line {no}: expected the index line 'i j k', got '{head}'"),
            ));
        }
        let mut rows = [DVec4::ZERO; 4];
        for (r, &(no, l)) in rows.iter_mut().zip(&block[1..]) {
            let v = numbers(path, no, l, 4)?;
            *r = DVec4::new(v[0], v[1], v[2], v[3]);
        }
        let m = DMat4::from_cols(rows[0], rows[1], rows[2], rows[3]).transpose();
        let rigid = (m.row(3) - DVec4::W).abs().max_element() < 1e-6
            && (m.determinant() - 1.0).abs() < 1e-3;
        if !rigid {
            return Err(Error::format(
                path,
                format!("line {no}: the pose ending here is not a rigid transform"),
            ));
        }
        t.poses.push(m);
    }
    Ok(t)
}

/// The pose of each of `frames` from trajectory `traj` read from `path`. A TUM trajectory is
/// matched by time when every frame's file name is a timestamp with a pose within `max_dt`
/// seconds (the nearest one), since a camera's poses and depth frames rarely come at the
/// same instants even when their counts agree; otherwise, and for `.log` files, by order,
/// which needs as many poses as frames. Errors name the trajectory.
pub fn match_poses(
    frames: &[PathBuf],
    traj: &Trajectory,
    path: &Path,
    max_dt: f64,
) -> Result<Vec<DMat4>> {
    let by_time = match_by_time(frames, traj, max_dt);
    match by_time {
        Ok(poses) => return Ok(poses),
        Err(_) if traj.poses.len() == frames.len() => return Ok(traj.poses.clone()),
        Err(_) => {}
    }
    let why = match by_time {
        Err(Unmatched::NotTum) => "a .log trajectory is matched by order".to_string(),
        Err(Unmatched::NoStamp(f)) => {
            format!("and frame {} has no timestamp as its name", f.display())
        }
        Err(Unmatched::TooFar(f, dt)) => format!(
            "and frame {}'s nearest pose is {dt:.3} s away (--max-dt {max_dt})",
            f.display()
        ),
        Ok(_) => unreachable!("matched frames returned above"),
    };
    Err(Error::format(
        path,
        format!(
            "{} poses for {} depth frames, {why}",
            traj.poses.len(),
            frames.len()
        ),
    ))
}

/// Why frames could not be matched to a trajectory by time.
enum Unmatched<'a> {
    NotTum,
    NoStamp(&'a Path),
    TooFar(&'a Path, f64),
}

/// Each frame's pose by the nearest timestamp to the number its file name holds.
fn match_by_time<'a>(
    frames: &'a [PathBuf],
    traj: &Trajectory,
    max_dt: f64,
) -> std::result::Result<Vec<DMat4>, Unmatched<'a>> {
    if traj.stamps.is_empty() {
        return Err(Unmatched::NotTum);
    }
    frames
        .iter()
        .map(|f| {
            let stamp = f
                .file_stem()
                .and_then(|s| s.to_str())
                .and_then(|s| s.parse::<f64>().ok())
                .filter(|s| s.is_finite())
                .ok_or(Unmatched::NoStamp(f))?;
            let (k, dt) = traj
                .stamps
                .iter()
                .enumerate()
                .map(|(k, s)| (k, (s - stamp).abs()))
                .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
            if !(dt <= max_dt) {
                return Err(Unmatched::TooFar(f, dt));
            }
            Ok(traj.poses[k])
        })
        .collect()
}
