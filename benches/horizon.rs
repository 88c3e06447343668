//! Horizon estimator on two analytic scenes of `N × N` pixels (default 1024): an orthographic
//! height field of smooth waves (`t_max` 12 px) and a pinhole view of a floor and a wall
//! (`t_max` 0.3), each against the paper estimator with 64 samples:
//! `cargo bench --bench horizon`. Wall time and CPU seconds (user + system of this process; the
//! machine may be shared) averaged over three runs after a warm-up.
//! `MVAO_SPEED_N` sets `N`, `MVAO_SPEED_CASE=ortho` or `=pinhole` runs one scene,
//! `MVAO_SPEED_DIRS` and `MVAO_SPEED_STEPS` set the budget (default 8 × 8).
//! `MVAO_SPEED_CASE=tmax` times the occlusion stage (`ssao::compute`, no blur) on the pinhole
//! scene at `t_max` 0.4 m, 4 m and ∞ (the far-field sweeps), in CPU seconds.

use glam::{Mat2, Mat3, Vec2, Vec3};
use mvao::testing::gbuffer::{rasterize, GBuffer};
use mvao::testing::projection::{Model, Projection};
use mvao::testing::ssao::{self as ssao, horizon, paper, Estimator, Falloff, SsaoParams};
use mvao::testing::sys;
use std::time::Instant;

/// Depth of the plane z = 0 along the orthographic sensor's axis.
const DEPTH0: f32 = 1000.0;

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// An orthographic sensor looking down at z = 0 with square pixels of size `step`.
fn ortho(w: usize, h: usize, step: f32) -> Projection {
    let model = Model::Ortho {
        a: Vec3::new(1.0 / step, 0.0, 0.0),
        a0: 0.0,
        b: Vec3::new(0.0, 1.0 / step, 0.0),
        b0: 0.0,
        toward: Vec3::Z,
        depth0: DEPTH0,
    };
    Projection::new(model, w, h, false)
}

/// A height field `z = f(x, y)` (with its normal) seen from above: one point per pixel
/// centre.
fn heightfield(
    w: usize,
    h: usize,
    step: f32,
    f: impl Fn(f32, f32) -> (f32, Vec3),
) -> (GBuffer, Projection) {
    let (mut pts, mut nrm) = (Vec::new(), Vec::new());
    for i in 0..w * h {
        let x = ((i % w) as f32 + 0.5) * step;
        let y = ((i / w) as f32 + 0.5) * step;
        let (z, n) = f(x, y);
        pts.push(Vec3::new(x, y, z));
        nrm.push(n);
    }
    let px: Vec<u32> = (0..(w * h) as u32).collect();
    let d: Vec<f32> = pts.iter().map(|p| DEPTH0 - p.z).collect();
    let g = rasterize(w, h, &px, &d, &pts, &nrm, &vec![step; w * h]);
    (g, ortho(w, h, step))
}

/// A smooth random-looking height field (pixel size 1) and its gradient.
fn waves(x: f32, y: f32) -> (f32, Vec3) {
    const W: [(f32, f32, f32, f32); 3] = [
        // amplitude, kx, ky, phase
        (7.0, 0.150, 0.045, 0.3),
        (4.5, -0.093, 0.233, 1.7),
        (1.5, 0.341, 0.341, 4.0),
    ];
    let (mut z, mut gx, mut gy) = (0.0f32, 0.0f32, 0.0f32);
    for (a, kx, ky, ph) in W {
        let arg = kx * x + ky * y + ph;
        z += a * arg.sin();
        gx += a * kx * arg.cos();
        gy += a * ky * arg.cos();
    }
    (z, Vec3::new(-gx, -gy, 1.0).normalize())
}

/// A pinhole camera at the origin looking along +y, pitched down by `pitch`, 60° vertical
/// field of view.
fn camera(w: usize, h: usize, pitch: f32) -> Projection {
    let z = Vec3::new(0.0, pitch.cos(), -pitch.sin());
    let x = Vec3::X;
    let y = z.cross(x);
    let f = (h as f32 * 0.5) / 30f32.to_radians().tan();
    let model = Model::Perspective {
        rot: Mat3::from_cols(x, y, z).transpose(),
        a: Mat2::from_diagonal(Vec2::splat(f)),
        c: Vec2::new(w as f32 * 0.5, h as f32 * 0.5),
    };
    Projection::new(model, w, h, false)
}

/// Ray-plane hit `n·x = c` (normal facing the ray's origin side).
fn plane(o: Vec3, d: Vec3, n: Vec3, c: f32) -> Option<f32> {
    let den = n.dot(d);
    let t = (c - n.dot(o)) / den;
    (den < 0.0 && t > 0.0).then_some(t)
}

/// The G-buffer of the floor z = −3 and the wall y = 4 seen by `proj`, ray cast through every
/// pixel centre.
fn floor_and_wall(proj: &Projection) -> GBuffer {
    let (mut px, mut d, mut pts, mut nrm) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for i in 0..proj.width * proj.height {
        let (x, y) = ((i % proj.width) as f32 + 0.5, (i / proj.width) as f32 + 0.5);
        let Some((o, dir)) = proj.ray(x, y) else {
            continue;
        };
        let f = plane(o, dir, Vec3::Z, -3.0).map(|t| (t, Vec3::Z));
        let wl = plane(o, dir, Vec3::NEG_Y, -4.0).map(|t| (t, Vec3::NEG_Y));
        let hit = match (f, wl) {
            (Some(a), Some(b)) => Some(if a.0 < b.0 { a } else { b }),
            (a, b) => a.or(b),
        };
        if let Some((t, n)) = hit {
            px.push(i as u32);
            d.push(t);
            pts.push(o + dir * t);
            nrm.push(n);
        }
    }
    let r = vec![0.01; pts.len()];
    rasterize(proj.width, proj.height, &px, &d, &pts, &nrm, &r)
}

fn main() {
    let n: usize = env_or("MVAO_SPEED_N", 1024);
    let dirs: u32 = env_or("MVAO_SPEED_DIRS", 8);
    let steps: u32 = env_or("MVAO_SPEED_STEPS", 8);
    let only = std::env::var("MVAO_SPEED_CASE").ok();
    let persp = camera(n, n, 35f32.to_radians());
    let g_persp = floor_and_wall(&persp);
    let (g_waves, ortho) = heightfield(n, n, 1.0, waves);
    let cases = [
        ("ortho waves, t_max 12 px", &g_waves, &ortho, 12.0f32),
        ("pinhole floor+wall, t_max 0.3", &g_persp, &persp, 0.3),
    ];
    if only.as_deref().is_none_or(|o| o == "tmax") {
        stage_by_tmax(&g_persp, &persp, dirs, steps);
    }
    for (name, g, proj, tmax) in cases {
        if only.as_deref().is_some_and(|o| !name.starts_with(o)) {
            continue;
        }
        let prm = SsaoParams {
            estimator: Estimator::Horizon,
            radius: tmax,
            tmax,
            falloff: Falloff::Smoothstep,
            samples: 32,
            directions: dirs,
            steps,
            seed: 1,
            blur: false,
            sampling: Default::default(),
        };
        let _ = horizon::ssao(g, proj, &prm);
        let reps = 3;
        let (t, c) = (Instant::now(), sys::cpu_seconds());
        for _ in 0..reps {
            let _ = horizon::ssao(g, proj, &prm);
        }
        let wall = t.elapsed().as_secs_f64() / reps as f64;
        let cpu = (sys::cpu_seconds() - c) / reps as f64;
        let px = g.filled() as f64 * 1e-6;
        println!(
            "{name}: {:.2} Mpx valid, {dirs}×{steps}: wall {:.3} s ({:.2} Mpx/s on {} threads), \
             CPU {:.3} s ({:.2} Mpx/s per core)",
            px,
            wall,
            px / wall,
            rayon::current_num_threads(),
            cpu,
            px / cpu
        );
        // Baseline on the same machine: the paper estimator with as many samples.
        let pp = SsaoParams { samples: 64, ..prm };
        let c = sys::cpu_seconds();
        let _ = paper::ssao(g, proj, &pp);
        println!(
            "  paper estimator, 64 samples: CPU {:.3} s",
            sys::cpu_seconds() - c
        );
    }
}

/// CPU seconds of the occlusion stage at three `t_max` on one map, best of three.
fn stage_by_tmax(g: &GBuffer, proj: &Projection, dirs: u32, steps: u32) {
    let mut base = None;
    for tmax in [0.4f32, 4.0, f32::INFINITY] {
        let prm = SsaoParams {
            estimator: Estimator::Horizon,
            radius: tmax.min(1.0),
            tmax,
            falloff: Falloff::Smoothstep,
            samples: 32,
            directions: dirs,
            steps,
            seed: 1,
            blur: false,
            sampling: Default::default(),
        };
        let best = (0..3)
            .map(|_| {
                let c = sys::cpu_seconds();
                let _ = ssao::compute(g, proj, &prm);
                sys::cpu_seconds() - c
            })
            .fold(f64::INFINITY, f64::min);
        let b = *base.get_or_insert(best);
        println!(
            "pinhole floor+wall, occlusion stage at t_max {tmax}: CPU {best:.3} s ({:.2} × 0.4 m)",
            best / b
        );
    }
}
