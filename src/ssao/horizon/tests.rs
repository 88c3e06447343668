//! Tests of the horizon estimator, and the one-direction references the SIMD march is
//! checked against.
use super::*;
use crate::gbuffer::rasterize;
use crate::projection::Model;
use crate::ssao::rho;
use crate::ssao::Estimator;
use glam::{Mat2, Mat3, Vec2, Vec3};

const DEPTH0: f32 = 1000.0;

pub(crate) fn params(directions: u32, steps: u32, tmax: f32) -> SsaoParams {
    SsaoParams {
        estimator: Estimator::Horizon,
        radius: tmax,
        tmax,
        falloff: Falloff::Smoothstep,
        samples: 32,
        directions,
        steps,
        seed: 1,
        blur: false,
        sampling: Default::default(),
    }
}

/// An orthographic sensor looking down at z = 0 with square pixels of size `step`.
pub(crate) fn ortho(w: usize, h: usize, step: f32) -> Projection {
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
pub(crate) fn heightfield(
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

/// The G-buffer of an analytic scene ray cast through every pixel centre (`hit` returns
/// the ray parameter and normal of the first hit; rays are unit for point sensors).
pub(crate) fn cast(proj: &Projection, hit: impl Fn(Vec3, Vec3) -> Option<(f32, Vec3)>) -> GBuffer {
    let (mut px, mut d, mut pts, mut nrm) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for i in 0..proj.width * proj.height {
        let (x, y) = ((i % proj.width) as f32 + 0.5, (i / proj.width) as f32 + 0.5);
        let Some((o, dir)) = proj.ray(x, y) else {
            continue;
        };
        if let Some((t, n)) = hit(o, dir) {
            px.push(i as u32);
            d.push(t);
            pts.push(o + dir * t);
            nrm.push(n);
        }
    }
    let r = vec![0.01; pts.len()];
    rasterize(proj.width, proj.height, &px, &d, &pts, &nrm, &r)
}

/// A full-circle equirect sensor at the origin, pole along z.
pub(crate) fn equirect(w: usize, h: usize) -> Projection {
    let model = Model::Equirect {
        rot: Mat3::IDENTITY,
        az_ref: 0.0,
        sx: w as f32 / TAU,
        ox: w as f32 * 0.5,
        sy: -(h as f32) / PI,
        oy: h as f32 * 0.5,
    };
    Projection::new(model, w, h, true)
}

/// Corners of a closed 6 × 5 × 3 m room around a scanner 1.5 m above its floor.
pub(crate) const ROOM: (Vec3, Vec3) = (Vec3::new(-2.5, -2.0, -1.5), Vec3::new(3.5, 3.0, 1.5));

/// The G-buffer of [`ROOM`] seen by `proj`.
pub(crate) fn room(proj: &Projection) -> GBuffer {
    cast(proj, |o, d| box_hit(o, d, ROOM.0, ROOM.1))
}

/// The G-buffer of the floor z = −3 and the wall y = 4 seen by `proj`.
pub(crate) fn floor_and_wall(proj: &Projection) -> GBuffer {
    cast(proj, |o, d| {
        let f = plane(o, d, Vec3::Z, -3.0).map(|t| (t, Vec3::Z));
        let wl = plane(o, d, Vec3::NEG_Y, -4.0).map(|t| (t, Vec3::NEG_Y));
        match (f, wl) {
            (Some(a), Some(b)) => Some(if a.0 < b.0 { a } else { b }),
            (a, b) => a.or(b),
        }
    })
}

/// A pinhole camera at the origin looking along +y, pitched down by `pitch`, 60° vertical
/// field of view.
pub(crate) fn camera(w: usize, h: usize, pitch: f32) -> Projection {
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
pub(crate) fn plane(o: Vec3, d: Vec3, n: Vec3, c: f32) -> Option<f32> {
    let den = n.dot(d);
    let t = (c - n.dot(o)) / den;
    (den < 0.0 && t > 0.0).then_some(t)
}

/// Cosine-weighted, stratified directions around `n` (Malley), `k × k` of them.
pub(crate) fn cosine_dirs(n: Vec3, k: usize, seed: u64) -> Vec<Vec3> {
    let (t1, t2) = n.any_orthonormal_pair();
    let mut rng = Rng::new(seed, 0);
    let mut out = Vec::with_capacity(k * k);
    for i in 0..k {
        for j in 0..k {
            let u1 = (i as f32 + rng.next_f32()) / k as f32;
            let u2 = (j as f32 + rng.next_f32()) / k as f32;
            let r = u1.sqrt();
            let (s, c) = (TAU * u2).sin_cos();
            out.push(t1 * (r * c) + t2 * (r * s) + n * (1.0 - u1).max(0.0).sqrt());
        }
    }
    out
}

#[test]
fn open_planes_read_exactly_one() {
    // A level floor from above, for any budget and falloff.
    let (g, proj) = heightfield(48, 40, 0.01, |_, _| (0.0, Vec3::Z));
    for (k, s) in [(1, 1), (3, 5), (8, 8), (32, 64)] {
        for tmax in [0.02, 0.1, 1e6] {
            let m = ssao(&g, &proj, &params(k, s, tmax));
            assert!(
                m.ao.iter().all(|&a| (a - 1.0).abs() < 1e-6),
                "({k},{s}) t={tmax}"
            );
            // Only a border pixel can have all its half-lines leave the map at once.
            for (i, &f) in m.no_sample.iter().enumerate() {
                let (x, y) = (i % 48, i / 48);
                assert!(!f || x < 3 || y < 3 || x > 44 || y > 36, "{i} flagged");
            }
        }
    }
    // A tilted plane from above: seen obliquely (n ≠ V).
    let n = Vec3::new(-0.6, -0.3, 1.0).normalize();
    let (g, proj) = heightfield(48, 40, 0.01, |x, y| (0.6 * x + 0.3 * y, n));
    for (k, s) in [(1, 1), (5, 7), (32, 64)] {
        let m = ssao(&g, &proj, &params(k, s, 0.1));
        let worst = m.ao.iter().map(|a| (a - 1.0).abs()).fold(0.0, f32::max);
        assert!(worst < 1e-6, "tilted ({k},{s}): {worst}");
    }
    // A floor seen by a pitched pinhole camera, grazing at the top of the image.
    let proj = camera(96, 72, 25f32.to_radians());
    let g = cast(&proj, |o, d| {
        plane(o, d, Vec3::Z, -1.5).map(|t| (t, Vec3::Z))
    });
    let m = ssao(&g, &proj, &params(16, 16, 0.3));
    let worst = m.ao.iter().map(|a| (a - 1.0).abs()).fold(0.0, f32::max);
    assert!(worst < 1e-6, "perspective floor: {worst}");
    assert!(m.no_sample.iter().filter(|&&f| !f).count() > 1000);
    // A floor around a terrestrial scanner (equirectangular, wrapping in azimuth).
    let proj = equirect(256, 128);
    let g = cast(&proj, |o, d| {
        plane(o, d, Vec3::Z, -1.5).map(|t| (t, Vec3::Z))
    });
    let m = ssao(&g, &proj, &params(8, 8, 0.5));
    let worst = m.ao.iter().map(|a| (a - 1.0).abs()).fold(0.0, f32::max);
    assert!(worst < 1e-6, "equirect floor: {worst}");
    assert!(g.filled() > 10_000);
}

/// A floor whose heights carry 2 mm of noise (1 cm pixels, exact normals): the lift reads
/// the noise off the map and the floor reads open, where an unlifted receiver takes its
/// neighbours' noise for occluders; a noise-free floor is not lifted.
#[test]
fn range_noise_is_measured_and_does_not_darken_a_floor() {
    let sigma = 0.002;
    let mut rng = crate::rng::SplitMix64::new(3, 0);
    let z: Vec<f32> = (0..96 * 96)
        .map(|_| (rng.gaussian() * sigma) as f32)
        .collect();
    let (g, proj) = heightfield(96, 96, 0.01, |x, y| {
        let (i, j) = ((x / 0.01) as usize, (y / 0.01) as usize);
        (z[j * 96 + i], Vec3::Z)
    });
    let pts = positions(&g);
    let est = range_noise(&g, &pts) as f64;
    assert!((est / sigma - 1.0).abs() < 0.1, "noise {est}");
    let tmax = 0.2;
    assert!((receiver_lift(&g, &pts, tmax) - 3.0 * est as f32).abs() < 1e-6);
    // A rough surface is not all noise: the lift stops at 5 % of t_max.
    assert!((receiver_lift(&g, &pts, 0.01) - 0.0005).abs() < 1e-7);
    let m = ssao(&g, &proj, &params(8, 8, tmax));
    let mean = m.ao.iter().sum::<f32>() / m.ao.len() as f32;
    assert!(mean > 0.985, "noisy floor reads {mean}");
    let (g, _) = heightfield(96, 96, 0.01, |_, _| (0.0, Vec3::Z));
    assert_eq!(range_noise(&g, &positions(&g)), 0.0);
}

/// A floor z = 0 for x < 48 and a block of height `hgt` for x ≥ 48 (pixel size 1).
fn step_scene(hgt: f32) -> (GBuffer, Projection) {
    heightfield(96, 192, 1.0, |x, _| {
        (if x >= 48.0 { hgt } else { 0.0 }, Vec3::Z)
    })
}

#[test]
fn floor_next_to_a_wall_tends_to_half_and_darkens_towards_it() {
    // Infinitely tall wall, ρ ≈ 0 in range: a floor point half a pixel from the step sees
    // half of its cosine-weighted hemisphere blocked.
    let (g, proj) = step_scene(1000.0);
    let m = ssao(&g, &proj, &params(64, 256, 1e6));
    let a = m.ao[96 * 96 + 47];
    eprintln!("δ = 0.5 from an H = 1000 wall: A = {a:.4}");
    assert!((0.45..=0.55).contains(&a), "next to the wall: {a}");
    // Wall of height H = 10 at distance δ (cosine AO, t_max = ∞ in effect):
    // A = 1/2 + k / (2√(1+k²)), k = δ/H.
    let (g, proj) = step_scene(10.0);
    let m = ssao(&g, &proj, &params(64, 256, 1e6));
    let mut prev = 0.0f32;
    let mut worst = 0.0f32;
    for j in 0..16 {
        let a = m.ao[96 * 96 + 47 - j];
        let k = (j as f32 + 0.5) / 10.0;
        let exact = 0.5 + k / (2.0 * (1.0 + k * k).sqrt());
        worst = worst.max((a - exact).abs());
        assert!(
            a > prev,
            "not increasing away from the wall at δ = {}: {a} ≤ {prev}",
            j
        );
        prev = a;
    }
    eprintln!("H = 10 wall, δ = 0.5…15.5: worst |a − exact| = {worst:.4}");
    assert!(worst < 0.03, "off the analytic wall AO by {worst}");
}

#[test]
fn bottom_of_a_narrow_pit_is_dark() {
    let (g, proj) = heightfield(21, 21, 1.0, |x, y| {
        let pit = (x - 10.5).abs() < 0.1 && (y - 10.5).abs() < 0.1;
        (if pit { 0.0 } else { 50.0 }, Vec3::Z)
    });
    let m = ssao(&g, &proj, &params(16, 16, 1e6));
    let a = m.ao[10 * 21 + 10];
    eprintln!("pit bottom: A = {a:.4}");
    assert!(a < 0.1, "{a}");
    assert!(!m.no_sample[10 * 21 + 10]);
}

/// A smooth random-looking height field (pixel size 1) and its gradient.
pub(crate) fn waves(x: f32, y: f32) -> (f32, Vec3) {
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

/// Ray-traced obscurance of the analytic `waves` field at `p`: stratified cosine rays
/// marched in steps of 0.1 and refined by bisection.
fn waves_reference(p: Vec3, n: Vec3, tmax: f32) -> f32 {
    waves_reference_with(p, n, tmax, Falloff::Smoothstep, f32::INFINITY)
}

/// [`waves_reference`] with any falloff, the field cut at the square `[0, size]²` (what a
/// map of that size holds: rays leaving it miss).
pub(crate) fn waves_reference_with(
    p: Vec3,
    n: Vec3,
    tmax: f32,
    falloff: Falloff,
    size: f32,
) -> f32 {
    let dirs = cosine_dirs(n, 40, 7);
    let dt = 0.1f32;
    let mut sum = 0.0f32;
    for w in &dirs {
        let below = |t: f32| {
            let q = p + *w * t;
            q.z < waves(q.x, q.y).0
        };
        let gone = |t: f32| {
            let q = p + *w * t;
            // Above the highest crest and rising, or off the map: a miss.
            (q.z > 13.5 && w.z >= 0.0) || !(q.x >= 0.0 && q.y >= 0.0 && q.x <= size && q.y <= size)
        };
        let mut d = f32::INFINITY;
        let mut t = dt;
        while t < tmax + dt && !gone(t) {
            if below(t) {
                let (mut lo, mut hi) = (t - dt, t);
                for _ in 0..20 {
                    let mid = 0.5 * (lo + hi);
                    if below(mid) {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                d = hi;
                break;
            }
            t += dt;
        }
        sum += falloff.rho(d, tmax);
    }
    sum / dirs.len() as f32
}

#[test]
fn every_falloff_and_an_infinite_tmax_converge_to_the_ray_traced_height_field() {
    let w = 160usize;
    let (g, proj) = heightfield(w, w, 1.0, waves);
    let picks: Vec<usize> = (0..12)
        .flat_map(|yy| (0..12).map(move |xx| (20 + 10 * yy) * w + 20 + 10 * xx))
        .collect();
    let inf = f32::INFINITY;
    for (tmax, falloff, limit) in [
        (inf, Falloff::Smoothstep, 0.012),
        (inf, Falloff::None, 0.012),
        (inf, Falloff::Exp(20.0), 0.012),
        (16.0, Falloff::Linear, 0.012),
        (16.0, Falloff::None, 0.012),
        (16.0, Falloff::Exp(20.0), 0.012),
    ] {
        let refs: Vec<(usize, f32)> = picks
            .iter()
            .map(|&i| {
                let a = waves_reference_with(g.position[i], g.normal[i], tmax, falloff, w as f32);
                (i, a)
            })
            .collect();
        let (lo, hi) = refs
            .iter()
            .fold((1.0f32, 0.0f32), |(a, b), r| (a.min(r.1), b.max(r.1)));
        let prm = SsaoParams {
            falloff,
            ..params(64, 64, tmax)
        };
        let e = mean_abs_error(&ssao(&g, &proj, &prm), &refs);
        eprintln!("t_max {tmax} {falloff}: A in [{lo:.3}, {hi:.3}], mean |a − A| {e:.4}");
        assert!(
            hi - lo > 0.3,
            "{tmax} {falloff}: A should span 0.3, [{lo}, {hi}]"
        );
        assert!(e < limit, "{tmax} {falloff}: {e}");
    }
}

pub(crate) fn mean_abs_error(m: &AoMap, refs: &[(usize, f32)]) -> f32 {
    refs.iter().map(|&(i, r)| (m.ao[i] - r).abs()).sum::<f32>() / refs.len() as f32
}

#[test]
fn converges_to_the_ray_traced_height_field() {
    let (w, tmax) = (160usize, 16.0f32);
    let (g, proj) = heightfield(w, w, 1.0, waves);
    let refs: Vec<(usize, f32)> = (0..16)
        .flat_map(|yy| (0..16).map(move |xx| (16 + 8 * yy) * w + 16 + 8 * xx))
        .map(|i| (i, waves_reference(g.position[i], g.normal[i], tmax)))
        .collect();
    let mean = refs.iter().map(|r| r.1).sum::<f32>() / refs.len() as f32;
    let min = refs.iter().map(|r| r.1).fold(1.0f32, f32::min);
    assert!(
        min < 0.7,
        "the field should have some occlusion: min A = {min}"
    );
    let err = |k: u32, s: u32| mean_abs_error(&ssao(&g, &proj, &params(k, s, tmax)), &refs);
    let (e4, e8, e16, e32, e64) = (err(4, 4), err(8, 8), err(16, 16), err(32, 32), err(64, 64));
    eprintln!(
        "reference A: mean {mean:.3}, min {min:.3}; mean |a − A| at (4,4) {e4:.4}, (8,8) {e8:.4}, \
         (16,16) {e16:.4}, (32,32) {e32:.4}, (64,64) {e64:.4}"
    );
    assert!(e64 < 0.02, "{e64}");
    assert!(e4 > e32, "{e4} vs {e32}");
}

/// Mean |a − A| over the floor points within `t_max` of the wall of [`floor_and_wall`] seen
/// by a camera pitched 35° down, `A` from rays against the infinite wall.
fn floor_by_wall_error(falloff: Falloff, directions: u32, steps: u32) -> f32 {
    // Camera at the origin pitched 35° down; floor z = −3, wall y = 4 facing the camera.
    let proj = camera(256, 256, 35f32.to_radians());
    let g = floor_and_wall(&proj);
    let tmax = 1.0f32;
    let mut prm = params(directions, steps, tmax);
    prm.falloff = falloff;
    let m = ssao(&g, &proj, &prm);
    let mut n = 0;
    let mut err = 0.0f32;
    for i in 0..g.width * g.height {
        let p = g.position[i];
        let delta = 4.0 - p.y;
        let on_floor = g.is_valid(i) && g.normal[i] == Vec3::Z && p.x.abs() < 0.5;
        if !(on_floor && (0.15..1.0).contains(&delta)) {
            continue;
        }
        let dirs = cosine_dirs(Vec3::Z, 32, i as u64);
        let reference = dirs
            .iter()
            .map(|w| {
                let d = if w.y > 0.0 {
                    delta / w.y
                } else {
                    f32::INFINITY
                };
                falloff.rho(d, tmax)
            })
            .sum::<f32>()
            / dirs.len() as f32;
        err += (m.ao[i] - reference).abs();
        n += 1;
    }
    assert!(n > 100, "{n}");
    err / n as f32
}

#[test]
fn oblique_pinhole_view_of_floor_and_wall_matches_the_reference() {
    let err = floor_by_wall_error(Falloff::Smoothstep, 64, 64);
    eprintln!("oblique floor by a wall: mean |a − A| = {err:.4}");
    assert!(err < 0.03, "{err}");
}

#[test]
fn a_wall_leaving_the_tmax_sphere_blocks_up_to_where_it_leaves() {
    // With ρ = 0 up to t_max the wall blocks fully up to the height where it leaves the
    // sphere, which no sample need lie on.
    // Measured: 0.0067 at 8 × 8 and 0.0019 at 64 × 64; 0.0122 and 0.0025 when the march
    // dropped the samples beyond t_max and stopped at the last one inside.
    for (k, s, bound) in [(8, 8, 0.009), (64, 64, 0.003)] {
        let err = floor_by_wall_error(Falloff::None, k, s);
        eprintln!("floor by a wall, no falloff, {k} × {s}: mean |a − A| = {err:.4}");
        assert!(err < bound, "{k} × {s}: {err}");
    }
}

/// First hit from inside the box `[lo, hi]`: ray parameter and inward normal.
pub(crate) fn box_hit(o: Vec3, d: Vec3, lo: Vec3, hi: Vec3) -> Option<(f32, Vec3)> {
    let mut best: Option<(f32, Vec3)> = None;
    for axis in 0..3 {
        let (dv, ov) = (d[axis], o[axis]);
        let (t, mut n) = if dv > 0.0 {
            ((hi[axis] - ov) / dv, Vec3::ZERO)
        } else if dv < 0.0 {
            ((lo[axis] - ov) / dv, Vec3::ZERO)
        } else {
            continue;
        };
        n[axis] = -dv.signum();
        if t > 0.0 && best.is_none_or(|b| t < b.0) {
            best = Some((t, n));
        }
    }
    best
}

#[test]
fn equirect_courtyard_under_open_sky_converges_at_infinite_tmax() {
    // A scanner 1.5 m above the floor of a 20 × 20 m court with 8 m walls and no roof:
    // plain ambient occlusion reaches the far walls, tens of degrees round the great
    // circles the half-planes image to.
    let (w, h) = (512usize, 256usize);
    let proj = equirect(w, h);
    let (lo, hi) = (Vec3::new(-10.0, -10.0, -1.5), Vec3::new(10.0, 10.0, 6.5));
    let court = |o: Vec3, d: Vec3| box_hit(o, d, lo, hi).filter(|b| b.1 != Vec3::NEG_Z);
    let g = cast(&proj, court);
    let mut rng = Rng::new(5, 0);
    let mut picks = Vec::new();
    while picks.len() < 300 {
        let i = (rng.next_u64() % (w * h) as u64) as usize;
        if g.is_valid(i) {
            let (p, nrm) = (g.position[i], g.normal[i]);
            let dirs = cosine_dirs(nrm, 24, i as u64);
            let open = dirs
                .iter()
                .filter(|&&d| court(p + nrm * 1e-4, d).is_none())
                .count();
            picks.push((i, open as f32 / dirs.len() as f32));
        }
    }
    let (lo_a, hi_a) = picks
        .iter()
        .fold((1.0f32, 0.0f32), |(a, b), r| (a.min(r.1), b.max(r.1)));
    assert!(hi_a - lo_a > 0.3, "A in [{lo_a}, {hi_a}]");
    let inf = f32::INFINITY;
    let errs: Vec<f32> = [(8, 8), (16, 32), (32, 64)]
        .iter()
        .map(|&(k, st)| mean_abs_error(&ssao(&g, &proj, &params(k, st, inf)), &picks))
        .collect();
    eprintln!("open court at t_max = ∞, A in [{lo_a:.3}, {hi_a:.3}]: mean |a − A| {errs:?}");
    // Straight image lines instead of great circles stay near 0.21 at every budget.
    assert!(errs[1] < 0.08 && errs[2] < 0.04, "{errs:?}");
}

#[test]
fn equirect_room_matches_the_reference() {
    // A terrestrial scanner 1.5 m above the floor of a closed 6 × 5 × 3 m room.
    let (w, h) = (1024usize, 512usize);
    let proj = equirect(w, h);
    let (lo, hi) = ROOM;
    let g = room(&proj);
    let tmax = 0.5f32;
    let m = ssao(&g, &proj, &params(32, 32, tmax));
    // Mean |a − A| over 400 random pixels, and over those with A < 0.9, in a band of
    // elevations (the half-line is the tangent of a great circle: fine away from the poles).
    let sample = |el_range: std::ops::Range<f32>, seed: u64| {
        let (mut err, mut n, mut err_dark, mut dark) = (0.0f32, 0, 0.0f32, 0);
        let mut rng = Rng::new(seed, 0);
        while n < 400 {
            let i = (rng.next_u64() % (w * h) as u64) as usize;
            let el = ((h / 2) as f32 - (i / w) as f32 - 0.5) * PI / h as f32;
            if !g.is_valid(i) || !el_range.contains(&el.abs().to_degrees()) {
                continue;
            }
            let (p, nrm) = (g.position[i], g.normal[i]);
            let dirs = cosine_dirs(nrm, 24, i as u64);
            let reference = dirs
                .iter()
                .map(|&d| {
                    let hit = box_hit(p + nrm * 1e-4, d, lo, hi);
                    rho(hit.map_or(f32::INFINITY, |b| b.0), tmax)
                })
                .sum::<f32>()
                / dirs.len() as f32;
            let e = (m.ao[i] - reference).abs();
            if reference < 0.9 {
                err_dark += e;
                dark += 1;
            }
            err += e;
            n += 1;
        }
        (err / n as f32, err_dark / dark.max(1) as f32, dark)
    };
    let (err, err_dark, dark) = sample(0.0..60.0, 3);
    let (err_pole, err_pole_dark, dark_pole) = sample(60.0..90.0, 4);
    eprintln!(
        "equirect room, |el| < 60°: mean |a − A| = {err:.4} ({dark} px with A < 0.9: \
         {err_dark:.4}); |el| ≥ 60°: {err_pole:.4} ({dark_pole} px: {err_pole_dark:.4})"
    );
    assert!(dark > 20, "{dark}");
    assert!(err < 0.02 && err_dark < 0.05, "{err} {err_dark}");
}

#[test]
fn lanes_set_up_and_march_exactly_like_one_half_plane_at_a_time() {
    let (pinhole, scanner) = (camera(96, 96, 35f32.to_radians()), equirect(256, 128));
    // The room again with normals tilted at random, a third of them facing away from the
    // sensor (n·V ≤ 0 takes the other branch of the slice set-up), some exactly ⊥ V.
    let mut tilted = room(&scanner);
    let mut rng = Rng::new(9, 0);
    for (n, p) in tilted.normal.iter_mut().zip(&tilted.position) {
        let r = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
        *n = match rng.next_u64() % 6 {
            0 | 1 => -*n + r * 0.3,
            2 => (-*p).normalize_or_zero().any_orthogonal_vector(),
            _ => *n + r * 0.5,
        };
    }
    let scenes = [
        (heightfield(48, 40, 1.0, waves), 6.0),
        (step_scene(30.0), 20.0),
        ((floor_and_wall(&pinhole), pinhole), 1.0),
        ((room(&scanner), scanner.clone()), 0.5),
        ((tilted, scanner), 0.5),
    ];
    let mut raised = 0;
    for ((g, proj), tmax) in &scenes {
        let pts = positions(g);
        for (d, st, t, falloff) in [
            (1, 8, *tmax, Falloff::Smoothstep),
            (3, 5, *tmax, Falloff::Smoothstep),
            (8, 8, *tmax, Falloff::Smoothstep),
            (7, 30, f32::INFINITY, Falloff::Smoothstep),
            // ρ jumps at t_max: where the profile leaves the sphere is offered too.
            (5, 12, *tmax, Falloff::None),
        ] {
            let mut prm = params(d, st, t);
            prm.falloff = falloff;
            let ctx = Ctx::new(g, &pts, proj, &prm);
            for c in 0..g.width * g.height {
                if !g.is_valid(c) {
                    continue;
                }
                let (x, y) = (c % g.width, c / g.width);
                let one = ctx.pixel_with(
                    x,
                    y,
                    c,
                    &mut Group::default(),
                    Ctx::setup_one,
                    Ctx::march_one,
                );
                let lanes = ctx.pixel_with(
                    x,
                    y,
                    c,
                    &mut Group::default(),
                    Ctx::setup_lanes,
                    Ctx::march_lanes,
                );
                assert_eq!(one.map(f32::to_bits), lanes.map(f32::to_bits), "pixel {c}");
                raised += usize::from(one.is_some_and(|a| a < 1.0));
            }
        }
    }
    assert!(raised > 1000, "{raised}");
}

#[test]
fn deterministic_for_a_seed_and_seeds_differ_a_little() {
    let (g, proj) = heightfield(64, 64, 1.0, waves);
    let a = ssao(&g, &proj, &params(8, 8, 10.0));
    let b = ssao(&g, &proj, &params(8, 8, 10.0));
    assert_eq!(a.ao, b.ao);
    let mut p = params(8, 8, 10.0);
    p.seed = 2;
    let c = ssao(&g, &proj, &p);
    assert_ne!(a.ao, c.ao);
    let diff =
        a.ao.iter()
            .zip(&c.ao)
            .map(|(x, y)| (x - y).abs())
            .sum::<f32>()
            / a.ao.len() as f32;
    eprintln!("seed 1 vs 2: mean |Δa| = {diff:.4}");
    assert!(diff < 0.05, "{diff}");
}

/// `∫_{x0}^{x1} ρ(r(γ)) f(γ) dγ` by a fine midpoint rule (f64).
fn numeric(sl: &Slice, x0: f32, x1: f32, r: impl Fn(f64) -> f64, tmax: f32) -> f64 {
    let n = 20_000;
    let h = (x1 - x0) as f64 / n as f64;
    (0..n)
        .map(|i| {
            let gm = x0 as f64 + (i as f64 + 0.5) * h;
            let f = ((sl.a as f64) * gm.cos() + (sl.b as f64) * gm.sin()).max(0.0) * gm.sin();
            f * rho(r(gm) as f32, tmax) as f64 * h
        })
        .sum()
}

/// Open directions: ρ = 1.
fn open(_: f64) -> f64 {
    f64::INFINITY
}

/// A march fed samples by their in-plane coordinates, with the tests of the march loops.
struct Fed {
    hz: Horizon,
    prev: (f32, f32),
}

impl Fed {
    fn new(sl: Slice) -> Fed {
        Fed {
            hz: Horizon::new(sl, Vec3A::X, Vec3A::Y),
            prev: (f32::NAN, f32::NAN),
        }
    }

    /// A sample at `(x, y)`, above `p`'s tangent plane or not.
    fn add(&mut self, x: f32, y: f32, above: bool, tmax: f32) {
        if above && x > 0.0 && above_horizon(x, y, self.hz.sc.1) {
            let rho = Rho::new(Falloff::Smoothstep, tmax);
            self.hz.raise(x, y, self.prev.0, self.prev.1, &rho);
        }
        self.prev = (x, y);
    }

    fn value(&self) -> f32 {
        self.hz.value()
    }
}

#[test]
fn hand_computed_slices() {
    // Surface facing the sensor: a = 1, b = 0, the tangent plane at γ = π/2.
    let sl = Slice::new(1.0, 0.0).expect("slice");
    assert!((sl.open() - 0.5).abs() < 1e-6);
    // t_max = ∞ (ρ = 0): the horizon set by (1,1) (45°), (2,1.5) hidden (53°), then
    // (2.5,3.5) raises it to γ = atan(2.5/3.5): S/T = sin²γ = 6.25/18.5, i.e.
    // 1 − sin²(elevation).
    let samples = [(1.0, 1.0), (2.0, 1.5), (2.5, 3.5)];
    let mut hz = Fed::new(sl);
    for (x, y) in samples {
        hz.add(x, y, true, f32::INFINITY);
    }
    let want = 6.25 / 18.5;
    assert!(
        (hz.value() / sl.open() - want).abs() < 1e-6,
        "{}",
        hz.value()
    );
    // Finite t_max. [45°, 90°]: the parabola η = τ² from p through (1,1) (no earlier
    // sample), r = cos γ / sin²γ. [γ₃, 45°]: the segment (2,1.5)–(2.5,3.5),
    // r = cross(P, D) / cross(ω, D) with D = (0.5, 2). [0, γ₃]: open.
    let tmax = 4.0;
    let mut hz = Fed::new(sl);
    for (x, y) in samples {
        hz.add(x, y, true, tmax);
    }
    let (g1, g3) = (FRAC_PI_2 / 2.0, 2.5f32.atan2(3.5));
    let parabola = |g: f64| g.cos() / (g.sin() * g.sin());
    assert!((parabola(g1 as f64) - 2f64.sqrt()).abs() < 1e-6);
    let segment = |g: f64| (2.0 * 2.0 - 1.5 * 0.5) / (g.sin() * 2.0 - g.cos() * 0.5);
    assert!((segment(g3 as f64) - 18.5f64.sqrt()).abs() < 1e-5);
    let expect = numeric(&sl, g1, FRAC_PI_2, parabola, tmax)
        + numeric(&sl, g3, g1, segment, tmax)
        + numeric(&sl, 0.0, g3, open, tmax);
    let got = hz.value() as f64;
    assert!((got - expect).abs() < 1e-3 * expect, "{got} vs {expect}");
    // Tilted normal n = 0.8 V + 0.6 u: tangent plane at γ = atan2(0.6, 0.8) + π/2.
    let sl = Slice::new(0.8, 0.6).expect("slice");
    assert!((sl.hi - (0.6f32.atan2(0.8) + FRAC_PI_2)).abs() < 1e-6);
    assert!((sl.open() as f64 - numeric(&sl, 0.0, PI, open, 1.0)).abs() < 1e-5);
    let mut hz = Fed::new(sl);
    // γ = 116.6°, above the tangent plane (126.9°): tangent coordinate τ = 1.1, height
    // η = 0.2 (R = 1), parabola η = κτ².
    hz.add(1.0, -0.5, true, 3.0);
    let gk = 1.0f32.atan2(-0.5);
    let parabola = |g: f64| {
        let (tw, ew) = (0.8 * g.sin() - 0.6 * g.cos(), 0.6 * g.sin() + 0.8 * g.cos());
        ew * 1.1 * 1.1 / (0.2 * tw * tw)
    };
    assert!((parabola(gk as f64) - 1.25f64.sqrt()).abs() < 1e-5);
    let expect = numeric(&sl, gk, sl.hi, parabola, 3.0) + numeric(&sl, 0.0, gk, open, 3.0);
    let got = hz.value() as f64;
    assert!((got - expect).abs() < 1e-4, "{got} vs {expect}");
    // Behind the line of V, below the tangent plane or below the current horizon: ignored.
    let before = hz.value();
    hz.add(-1.0, 1.0, true, 3.0);
    hz.add(1.0, 2.0, false, 3.0);
    hz.add(1.0, -0.6, true, 3.0);
    assert_eq!(hz.value(), before);
}

#[test]
fn fast_atan2_matches_std() {
    let mut worst = 0.0f32;
    for i in 0..2000 {
        for j in 0..50 {
            let ang = -PI + TAU * (i as f32 + 0.5) / 2000.0;
            let r = 1e-3 + j as f32;
            let (y, x) = (r * ang.sin(), r * ang.cos());
            worst = worst.max((fast_atan2(y, x) - y.atan2(x)).abs());
        }
    }
    assert!(worst < 5e-7, "{worst}");
    for (y, x) in [
        (0.0f32, 1.0f32),
        (1.0, 0.0),
        (0.0, -1.0),
        (-1.0, 0.0),
        (1.0, 1.0),
        (0.0, 0.0),
    ] {
        assert!((fast_atan2(y, x) - y.atan2(x)).abs() < 5e-7, "{y} {x}");
    }
}

#[test]
fn sub_pixel_reach_and_bad_normals_are_flagged() {
    let (g, proj) = heightfield(21, 21, 0.01, |_, _| (0.0, Vec3::Z));
    let m = ssao(&g, &proj, &params(8, 8, 0.004));
    assert!(m.no_sample[10 * 21 + 10]);
    assert_eq!(m.ao[10 * 21 + 10], 1.0);
    let (mut g, proj) = heightfield(21, 21, 0.01, |_, _| (0.0, Vec3::Z));
    g.normal[5] = Vec3::ZERO;
    g.normal[6] = Vec3::splat(f32::NAN);
    let m = ssao(&g, &proj, &params(8, 8, 0.05));
    assert!(m.no_sample[5] && m.no_sample[6] && !m.no_sample[7]);
    assert!(m.ao.iter().all(|a| a.is_finite()));
}

#[test]
#[ignore]
fn error_shrinks_with_resolution() {
    // The converged estimate differs from the analytic field's A by the range map's
    // discretization (nearest point per pixel, piecewise-linear profile between samples),
    // which shrinks with the pixel size. Slow-ish: run with --release.
    let tmax = 16.0f32;
    let mut errs = Vec::new();
    for (w, step) in [(160usize, 1.0f32), (320, 0.5), (640, 0.25)] {
        let (g, proj) = heightfield(w, w, step, waves);
        let scale = (1.0 / step) as usize;
        let refs: Vec<(usize, f32)> = (0..16)
            .flat_map(|yy| {
                (0..16).map(move |xx| ((16 + 8 * yy) * scale) * w + (16 + 8 * xx) * scale)
            })
            .map(|i| (i, waves_reference(g.position[i], g.normal[i], tmax)))
            .collect();
        let e = mean_abs_error(&ssao(&g, &proj, &params(64, 128, tmax)), &refs);
        eprintln!("pixel {step}: mean |a − A| = {e:.4}");
        errs.push(e);
    }
    assert!(errs[2] < errs[0], "{errs:?}");
}

impl<'a> Ctx<'a> {
    /// The reference for [`Ctx::setup_lanes`]: one direction at a time.
    fn setup_one(&self, f: &Frame, dirs: &mut Dirs, grp: &mut Group, terms: &mut [Term; LANES]) {
        for (l, term) in terms.iter_mut().enumerate().take(grp.n) {
            let ((s, co), jitter) = dirs.next(self.rot);
            let u = f.e1 * co + f.e2 * s;
            let Some(slice) = Slice::new(f.a, f.na.dot(u)) else {
                continue;
            };
            let open = slice.open();
            *term = Term::Open(open);
            let Some((x, y)) =
                f.d.map(|(d1, d2)| (co * d1.0 + s * d2.0, co * d1.1 + s * d2.1))
            else {
                continue;
            };
            let len = (x * x + y * y).sqrt();
            if !(len > 0.0 && len.is_finite()) {
                continue;
            }
            let (dx, dy) = (x / len, y / len);
            let (idx, idy) = (1.0 / dx, 1.0 / dy);
            let (ox, oy) = f.o;
            let ppr = len * f.arc.map_or(0.0, |a| a.0);
            let reach = if let Some((_, angle)) = f.arc {
                ppr * angle
            } else {
                let reach = (1.0 / (dx * dx * f.irx2 + dy * dy * f.iry2).sqrt())
                    .min(exit(oy, idy, self.hf))
                    .min(self.wf + self.hf);
                if self.wrap {
                    reach
                } else {
                    reach.min(exit(ox, idx, self.wf))
                }
            };
            let t0 = exit(f.fo.0, idx, 1.0).min(exit(f.fo.1, idy, 1.0));
            let span = reach - t0;
            if !(span > 0.0) {
                continue;
            }
            self.start(f, grp, l, slice, u, (dx, dy), (t0, span), ppr, jitter);
            *term = Term::March(open, l);
        }
    }

    /// The reference for [`Ctx::march_lanes`]: each lane's half-plane marched on its own.
    fn march_one(&self, grp: &mut Group, c: usize, pa: Vec3A, na: Vec3A) -> bool {
        let mut any = false;
        for l in 0..grp.n {
            let (mut px, mut py) = (f32::NAN, f32::NAN);
            // The previous sample's offset, when it was inside the t_max sphere.
            let mut inside_before: Option<Vec3A> = None;
            for _ in 0..grp.count[l] {
                let Some(i) = self.next_index(grp, l) else {
                    break;
                };
                let q = self.pts[i];
                if i == c || q.x.is_nan() {
                    continue;
                }
                any = true;
                let v = q - pa;
                let l2 = v.length_squared();
                let before = std::mem::replace(&mut inside_before, (l2 < self.tmax2).then_some(v));
                if !(l2 < self.tmax2) {
                    if let Some(pv) = before.filter(|_| self.clip) {
                        let hz = &mut grp.hz[l];
                        if let Some(xy) =
                            self.offer_exit(hz, (pa, na), (pv, v), (px, py), grp.arc_on)
                        {
                            (px, py) = xy;
                        }
                    }
                    continue;
                }
                // Heights within 10⁻⁵ rad of the tangent plane count as on it (rounding noise
                // of a plane; the sliver they could block weighs ≤ 10⁻¹⁰).
                let height = na.dot(v);
                let height = if height * height > 1e-10 * l2 {
                    height
                } else {
                    0.0
                };
                let hz = &mut grp.hz[l];
                let (x, y) = (v.dot(hz.fx), v.dot(hz.fy));
                if height > 0.0
                    && x > 0.0
                    && above_horizon(x, y, hz.sc.1)
                    && (!grp.arc_on || joins_horizon(pa, v, hz.sc.1))
                {
                    hz.raise(x, y, px, py, &self.rho);
                }
                (px, py) = (x, y);
            }
        }
        any
    }
}

/// Distance from coordinate `o` to the boundary of `[0, size]` along a direction component
/// of reciprocal `inv` (`±∞` for a zero component).
#[inline]
fn exit(o: f32, inv: f32, size: f32) -> f32 {
    if inv > 0.0 {
        (size - o) * inv
    } else if inv < 0.0 {
        -o * inv
    } else {
        f32::INFINITY
    }
}
