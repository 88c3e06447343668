//! Upright previews (issue 34): scans of the synthetic room taken by sensors rolled and
//! pitched in every sensor model come out with the highest points at the top of the PNG and,
//! for cameras and linear sweeps, the sensor's right on the right (not a mirror image).

use glam::{DMat3, DMat4, DVec3, Mat2, Mat3, Vec2};
use mvao::synth::Scene;
use mvao::testing::gbuffer::{GBuffer, EMPTY};
use mvao::testing::preview::{write_scan_preview, PreviewStyle, Tone, Up};
use mvao::testing::projection::{Model, Projection};
use std::path::Path;

const W: usize = 160;
const H: usize = 120;

/// A sensor in the room: its projection in the scan's local frame, the pose and the world
/// direction that is "right" for an upright viewer behind it (None for a panorama).
struct Sensor {
    proj: Projection,
    pose: DMat4,
    right: Option<DVec3>,
}

/// The scan's local frame: the world turned by 30° about z, moved to a point in the room.
fn pose() -> DMat4 {
    DMat4::from_translation(DVec3::new(-1.0, -0.5, 1.5)) * DMat4::from_rotation_z(0.5)
}

/// The camera axes (right, down, forward) in the local frame: looking along local +x, then
/// rolled about the view axis by `roll` and pitched up by `pitch` (degrees).
fn axes(roll: f64, pitch: f64) -> [DVec3; 3] {
    let (r0, d0, f0) = (DVec3::NEG_Y, DVec3::NEG_Z, DVec3::X);
    let t = DMat3::from_axis_angle(r0, pitch.to_radians())
        * DMat3::from_axis_angle(f0, roll.to_radians());
    [t * r0, t * d0, t * f0]
}

fn world_right() -> DVec3 {
    // Local +x seen from above: right is local -y, in the world turned with the pose.
    DMat3::from_mat4(pose()) * DVec3::NEG_Y
}

fn perspective(roll: f64, pitch: f64) -> Sensor {
    let [r, d, f] = axes(roll, pitch).map(|v| v.as_vec3());
    let focal = W as f32 / 2.0 / 35f32.to_radians().tan();
    let model = Model::Perspective {
        rot: Mat3::from_cols(r, d, f).transpose(),
        a: Mat2::from_diagonal(Vec2::splat(focal)),
        c: Vec2::new(W as f32 / 2.0, H as f32 / 2.0),
    };
    Sensor {
        proj: Projection::new(model, W, H, false),
        pose: pose(),
        right: Some(world_right()),
    }
}

fn ortho(roll: f64, pitch: f64) -> Sensor {
    let [r, d, f] = axes(roll, pitch).map(|v| v.as_vec3());
    // 2 m across, the sensor plane through the local origin.
    let ppm = W as f32 / 2.0;
    let model = Model::Ortho {
        a: r * ppm,
        a0: W as f32 / 2.0,
        b: d * ppm,
        b0: H as f32 / 2.0,
        toward: -f,
        depth0: 0.0,
    };
    Sensor {
        proj: Projection::new(model, W, H, false),
        pose: pose(),
        right: Some(world_right()),
    }
}

/// A full panorama whose pole is tilted by `tilt` degrees about local x and which is hung
/// upside down when `inverted`.
fn equirect(tilt: f64, inverted: bool) -> Sensor {
    let flip = if inverted {
        DMat3::from_rotation_x(std::f64::consts::PI)
    } else {
        DMat3::IDENTITY
    };
    let t = DMat3::from_rotation_x(tilt.to_radians()) * flip;
    let (w, h) = (2 * W, W);
    let model = Model::Equirect {
        rot: t.transpose().as_mat3(),
        az_ref: 0.0,
        sx: -(w as f32) / std::f32::consts::TAU,
        ox: w as f32 / 2.0,
        sy: -(h as f32) / std::f32::consts::PI,
        oy: h as f32 / 2.0,
    };
    Sensor {
        proj: Projection::new(model, w, h, true),
        pose: pose(),
        right: None,
    }
}

/// Scans the room with `s` (one ray per pixel centre) and writes the preview of a per-point
/// value `value(world point)` (linear tone); returns the PNG's grey values (None where
/// transparent) and its width.
fn preview_of(s: &Sensor, value: impl Fn(DVec3) -> f64, dir: &Path) -> (Vec<Option<u8>>, usize) {
    let scene = Scene::room();
    let (w, h) = (s.proj.width, s.proj.height);
    let mut g = GBuffer {
        width: w,
        height: h,
        point: vec![EMPTY; w * h],
        ..Default::default()
    };
    let mut world = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let Some((o, d)) = s.proj.ray(x as f32 + 0.5, y as f32 + 0.5) else {
                continue;
            };
            let (wo, wd) = (
                s.pose.transform_point3(o.as_dvec3()),
                s.pose.transform_vector3(d.as_dvec3()),
            );
            if let Some(hit) = scene.intersect(wo, wd) {
                g.point[y * w + x] = world.len() as u32;
                world.push(wo + wd * hit.t);
            }
        }
    }
    assert!(world.len() > w * h / 2, "the sensor sees the room");
    let v: Vec<f64> = world.iter().map(|&p| value(p)).collect();
    let (lo, hi) = v
        .iter()
        .fold((f64::MAX, f64::MIN), |a, &x| (a.0.min(x), a.1.max(x)));
    let ao: Vec<f32> = v.iter().map(|x| ((x - lo) / (hi - lo)) as f32).collect();
    let path = dir.join("p.png");
    let style = PreviewStyle {
        up: Up::Z,
        tone: Tone::Linear,
    };
    write_scan_preview(&path, &g, &s.proj, s.pose, &ao, 1.0, style).unwrap();
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    let px = buf[..info.buffer_size()]
        .chunks(2)
        .map(|c| (c[1] > 0).then_some(c[0]))
        .collect();
    (px, info.width as usize)
}

/// Mean grey of the filled pixels in a band of rows (or of columns when `cols`), as a share
/// `[a, b)` of the picture.
fn band(px: &[Option<u8>], w: usize, a: f64, b: f64, cols: bool) -> f64 {
    let h = px.len() / w;
    let (mut s, mut n) = (0.0, 0);
    for (i, p) in px.iter().enumerate() {
        let (x, y) = (i % w, i / w);
        let t = if cols {
            x as f64 / w as f64
        } else {
            y as f64 / h as f64
        };
        if let (Some(v), true) = (p, t >= a && t < b) {
            s += *v as f64;
            n += 1;
        }
    }
    assert!(n > 0, "band {a}–{b} is empty");
    s / n as f64
}

/// Heights brighter at the top third than the bottom third, and (for sensors with a right)
/// the right third further right than the left third.
fn check(s: &Sensor, what: &str) {
    let dir = tempfile::tempdir().unwrap();
    let (px, w) = preview_of(s, |p| p.z, dir.path());
    let (top, bottom) = (
        band(&px, w, 0.0, 0.33, false),
        band(&px, w, 0.67, 1.0, false),
    );
    assert!(
        top > bottom + 20.0,
        "{what}: top {top:.0} vs bottom {bottom:.0}"
    );
    if let Some(r) = s.right {
        let (px, w) = preview_of(s, |p| p.dot(r), dir.path());
        let (left, right) = (band(&px, w, 0.0, 0.33, true), band(&px, w, 0.67, 1.0, true));
        assert!(
            right > left + 20.0,
            "{what}: left {left:.0} vs right {right:.0}"
        );
    }
}

#[test]
fn perspective_rolled_and_pitched() {
    for roll in [0.0, 30.0, 80.0, 100.0, 160.0, 200.0, 260.0, 290.0, -30.0] {
        for pitch in [-30.0, 0.0, 30.0] {
            check(
                &perspective(roll, pitch),
                &format!("perspective roll {roll} pitch {pitch}"),
            );
        }
    }
}

#[test]
fn ortho_rolled_and_pitched() {
    for roll in [0.0, 30.0, 80.0, 100.0, 160.0, 200.0, 260.0, 290.0, -30.0] {
        // A 2 m sweep pitched further sees only floor or ceiling in the room.
        for pitch in [-15.0, 0.0, 15.0] {
            check(
                &ortho(roll, pitch),
                &format!("ortho roll {roll} pitch {pitch}"),
            );
        }
    }
}

/// A panorama turns by whole right angles only: tilted scanners stay upright, one hung upside
/// down is turned back.
#[test]
fn equirect_tilted_and_inverted() {
    for tilt in [-20.0, 0.0, 20.0] {
        for inverted in [false, true] {
            check(
                &equirect(tilt, inverted),
                &format!("equirect tilt {tilt} inverted {inverted}"),
            );
        }
    }
}

/// The sensor's rays decide, not the points: a camera looking down at the floor (nearly
/// every point at one height) still turns its far side up.
#[test]
fn floor_seen_from_above() {
    let s = perspective(120.0, -60.0);
    let dir = tempfile::tempdir().unwrap();
    let o = pose().inverse();
    // Distance from the camera: the far side of the floor is at the top.
    let (px, w) = preview_of(&s, |p| o.transform_point3(p).length(), dir.path());
    let (top, bottom) = (
        band(&px, w, 0.0, 0.33, false),
        band(&px, w, 0.67, 1.0, false),
    );
    assert!(top > bottom + 20.0, "top {top:.0} vs bottom {bottom:.0}");
}
