//! Synthetic depth streams with exact ground truth: a pinhole camera moving through an
//! analytic scene or a triangle mesh, with a structured-light-like noise model (depth-dependent Gaussian noise,
//! millimetre quantisation, holes at depth edges and a few random dropouts), and per pixel
//! the reference obscurance `A` at the pixel's noise-free point.

use super::frames::{write_depth_png, DepthFrame, Intrinsics};
use crate::error::{Error, Result};
use crate::falloff::Falloff;
use crate::rng::SplitMix64;
use crate::scan::Scan;
use crate::synth::reference::{analytic_obscurance, mesh_obscurance};
use crate::synth::Scene;
use crate::synth::{MeshScene, Truth};
use glam::{DMat3, DMat4, DVec3};
use rayon::prelude::*;
use std::io::Write as _;
use std::path::Path;

/// How a synthetic stream is made.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamSynthOptions {
    /// Frames.
    pub frames: usize,
    /// Frame width (pixels).
    pub width: usize,
    /// Frame height (pixels).
    pub height: usize,
    /// Horizontal field of view (radians).
    pub fov: f64,
    /// Scale of the depth-dependent noise (1 = a structured-light camera, 0 = none).
    pub noise: f64,
    /// Seed of the noise.
    pub seed: u64,
    /// Rays per pixel of the ground truth (0 = no ground truth).
    pub truth_rays: u32,
    /// t_max and falloff of the ground truth.
    pub truth_tmax: f32,
    /// Falloff of the ground truth.
    pub truth_falloff: Falloff,
}

impl Default for StreamSynthOptions {
    fn default() -> Self {
        StreamSynthOptions {
            frames: 200,
            width: 640,
            height: 480,
            fov: 60f64.to_radians(),
            noise: 1.0,
            seed: 0,
            truth_rays: 64,
            truth_tmax: 0.4,
            truth_falloff: Falloff::Smoothstep,
        }
    }
}

/// A synthetic stream in memory.
#[derive(Debug, Clone, Default)]
pub struct SynthStream {
    /// Camera intrinsics.
    pub intrinsics: Intrinsics,
    /// Noisy depth frames.
    pub frames: Vec<DepthFrame>,
    /// Camera-to-world pose per frame.
    pub poses: Vec<DMat4>,
    /// Per frame and pixel the ground truth `A` (NaN where the pixel saw nothing).
    pub truth: Vec<Vec<f32>>,
}

/// What a stream is made of: an analytic scene or a triangle mesh.
#[derive(Debug, Clone, Copy)]
pub enum StreamScene<'a> {
    /// An analytic scene.
    Analytic(&'a Scene),
    /// A mesh (`mvao synth --scene` with a built-in mesh or a PLY/OBJ file).
    Mesh(&'a MeshScene),
}

impl<'a> From<&'a Scene> for StreamScene<'a> {
    fn from(s: &'a Scene) -> Self {
        StreamScene::Analytic(s)
    }
}

impl<'a> From<&'a MeshScene> for StreamScene<'a> {
    fn from(m: &'a MeshScene) -> Self {
        StreamScene::Mesh(m)
    }
}

impl StreamScene<'_> {
    /// Distance, front normal and primitive of the nearest surface along a unit ray.
    fn hit(&self, origin: DVec3, dir: DVec3) -> Option<(f64, DVec3, u32)> {
        match self {
            StreamScene::Analytic(s) => s
                .intersect(origin, dir)
                .map(|h| (h.t, h.normal, h.prim as u32)),
            StreamScene::Mesh(m) => m
                .intersect_skip(origin, dir, 0.0, f64::INFINITY, u32::MAX)
                .map(|h| (h.t, h.normal, h.prim as u32)),
        }
    }
}

/// A camera orbiting `target` once over `frames` frames, through `start` (the orbit's radius
/// and height above the target are `start`'s), always looking at the target: a handheld
/// camera walked round an object or a room's middle.
pub fn orbit_trajectory(target: DVec3, start: DVec3, frames: usize) -> Vec<DMat4> {
    let off = start - target;
    let scale = off.length().max(1e-6);
    // A start straight above the target still orbits, at a tenth of its height.
    let radius = off.truncate().length().max(0.1 * scale);
    let a0 = off.y.atan2(off.x);
    (0..frames)
        .map(|i| {
            let a = a0 + std::f64::consts::TAU * i as f64 / frames.max(1) as f64;
            let pos = target + DVec3::new(radius * a.cos(), radius * a.sin(), off.z);
            look_pose(pos, target - pos)
        })
        .collect()
}

/// The camera path through the room of [`Scene::room`]: a loop around its middle at eye
/// height, looking outwards and a little down, so walls, corners, the column, the table and
/// the ball are each seen from many frames.
pub fn room_trajectory(frames: usize) -> Vec<DMat4> {
    (0..frames)
        .map(|i| {
            let th = std::f64::consts::TAU * i as f64 / frames.max(1) as f64;
            let pos = DVec3::new(1.0 * th.cos(), 0.8 * th.sin(), 1.5 + 0.1 * (3.0 * th).sin());
            let yaw = th + 0.7;
            let pitch: f64 = -0.35;
            let fwd = DVec3::new(
                yaw.cos() * pitch.cos(),
                yaw.sin() * pitch.cos(),
                pitch.sin(),
            );
            look_pose(pos, fwd)
        })
        .collect()
}

/// Camera-to-world pose of a camera at `pos` looking along `fwd` with world z up (OpenCV
/// camera axes: x right, y down, z forward).
pub fn look_pose(pos: DVec3, fwd: DVec3) -> DMat4 {
    let f = fwd.normalize();
    let r = f.cross(DVec3::Z).normalize();
    let d = f.cross(r);
    DMat4::from_cols(r.extend(0.0), d.extend(0.0), f.extend(0.0), pos.extend(1.0))
}

/// Standard deviation (metres) of a structured-light camera's depth noise at depth `z`.
pub fn noise_sigma(z: f64) -> f64 {
    0.0012 + 0.0019 * (z - 0.4) * (z - 0.4)
}

/// A synthetic stream of `scene` along `poses`.
pub fn synth_stream<'a>(
    scene: impl Into<StreamScene<'a>>,
    poses: &[DMat4],
    o: &StreamSynthOptions,
) -> SynthStream {
    let scene = scene.into();
    let (w, h) = (o.width, o.height);
    let fx = w as f64 / (2.0 * (o.fov / 2.0).tan());
    let k = Intrinsics {
        fx,
        fy: fx,
        cx: (w as f64 - 1.0) / 2.0,
        cy: (h as f64 - 1.0) / 2.0,
    };
    let mut s = SynthStream {
        intrinsics: k,
        ..Default::default()
    };
    for (fi, pose) in poses.iter().enumerate() {
        let (frame, truth) = synth_frame(&scene, *pose, &k, (w, h), o, fi as u64);
        s.frames.push(frame);
        s.poses.push(*pose);
        s.truth.push(truth);
    }
    s
}

/// One frame: noisy z-depth and the ground truth per pixel.
fn synth_frame(
    scene: &StreamScene,
    pose: DMat4,
    k: &Intrinsics,
    (w, h): (usize, usize),
    o: &StreamSynthOptions,
    index: u64,
) -> (DepthFrame, Vec<f32>) {
    let rot = DMat3::from_mat4(pose);
    let origin = pose.w_axis.truncate();
    // Exact z-depth, world point, normal (towards the camera) and primitive per pixel.
    let exact: Vec<Option<Exact>> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            let ray = DVec3::new((x - k.cx) / k.fx, (y - k.cy) / k.fy, 1.0);
            let len = ray.length();
            let d = rot * (ray / len);
            let (t, mut n, prim) = scene.hit(origin, d)?;
            if n.dot(d) > 0.0 {
                n = -n;
            }
            Some((t / len, origin + d * t, n, prim))
        })
        .collect();
    let seed = o.seed ^ index.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    let depth: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let Some((z, ..)) = exact[i] else {
                return 0.0;
            };
            let mut rng = SplitMix64::new(seed, i as u64);
            // Structured light loses the pixels next to a depth edge (the projector's
            // pattern is occluded there) and a few at random.
            let (x, y) = (i % w, i / w);
            let edge = [(0i64, -1i64), (0, 1), (-1, 0), (1, 0)]
                .iter()
                .any(|&(dx, dy)| {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                        return false;
                    }
                    exact[ny as usize * w + nx as usize]
                        .is_none_or(|(q, ..)| (q - z).abs() > 0.04 * z)
                });
            let u = rng.next_f64();
            if (edge && u < 0.6) || u < 0.01 * o.noise.min(1.0) {
                return 0.0;
            }
            let noisy = z + o.noise * noise_sigma(z) * rng.gaussian();
            ((noisy * 1000.0).round() / 1000.0).max(0.0) as f32
        })
        .collect();
    let truth = truth_of(scene, &exact, o);
    (
        DepthFrame {
            width: w,
            height: h,
            depth,
        },
        truth,
    )
}

/// A pixel's exact z-depth, world point, normal turned to the camera and primitive.
type Exact = (f64, DVec3, DVec3, u32);

/// The reference obscurance at each pixel's noise-free point (NaN where none).
fn truth_of(scene: &StreamScene, exact: &[Option<Exact>], o: &StreamSynthOptions) -> Vec<f32> {
    if o.truth_rays == 0 {
        return vec![f32::NAN; exact.len()];
    }
    let seen: Vec<(usize, Exact)> = exact
        .iter()
        .enumerate()
        .filter_map(|(i, e)| e.map(|e| (i, e)))
        .collect();
    let falloff = (o.truth_tmax, o.truth_falloff);
    let a = match scene {
        StreamScene::Analytic(sc) => {
            let pts = seen.iter().map(|(_, e)| e.1.as_vec3()).collect();
            let mut scan = Scan::from_points("frame", pts);
            scan.normals = Some(seen.iter().map(|(_, e)| e.2.as_vec3()).collect());
            analytic_obscurance(sc, &scan, o.truth_rays, falloff, o.seed)
        }
        StreamScene::Mesh(m) => {
            let truth: Vec<Truth> = seen
                .iter()
                .map(|(_, e)| Truth {
                    p: e.1,
                    n: e.2,
                    prim: e.3,
                })
                .collect();
            mesh_obscurance(m, &truth, o.truth_rays, falloff, o.seed)
        }
    };
    let mut out = vec![f32::NAN; exact.len()];
    for ((i, _), v) in seen.iter().zip(a) {
        out[*i] = v;
    }
    out
}

/// Writes a synthetic stream: `depth/NNNNN.png` (millimetres), `truth/NNNNN.png` (16-bit,
/// `1 + A·65534`, 0 = no point), `trajectory.log` (Open3D/Redwood) and `intrinsics.txt`
/// (`fx fy cx cy`).
pub fn write_stream(s: &SynthStream, dir: &Path) -> Result<()> {
    for sub in ["depth", "truth"] {
        let p = dir.join(sub);
        std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
    }
    for (i, (f, t)) in s.frames.iter().zip(&s.truth).enumerate() {
        write_depth_png(&dir.join(format!("depth/{i:05}.png")), f, 1000.0)?;
        let tf = DepthFrame {
            width: f.width,
            height: f.height,
            depth: t
                .iter()
                .map(|&a| {
                    if a.is_finite() {
                        1.0 + a.clamp(0.0, 1.0) * 65534.0
                    } else {
                        0.0
                    }
                })
                .collect(),
        };
        write_depth_png(&dir.join(format!("truth/{i:05}.png")), &tf, 1.0)?;
    }
    let mut log = String::new();
    for (i, p) in s.poses.iter().enumerate() {
        log += &format!("{i} {i} {}\n", i + 1);
        for r in 0..4 {
            let row = p.row(r);
            log += &format!("{:.9} {:.9} {:.9} {:.9}\n", row.x, row.y, row.z, row.w);
        }
    }
    let k = &s.intrinsics;
    for (name, text) in [
        ("trajectory.log", log),
        (
            "intrinsics.txt",
            format!("{} {} {} {}\n", k.fx, k.fy, k.cx, k.cy),
        ),
    ] {
        let p = dir.join(name);
        crate::io::atomic::write_atomic(&p, |w| w.write_all(text.as_bytes()))?;
    }
    Ok(())
}
