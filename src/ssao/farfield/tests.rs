//! Tests of the far-field sweeps against the map's own ray-traced plain ambient occlusion.
use super::*;
use crate::projection::Model;
use crate::ssao::horizon::tests::{
    box_hit, camera, cast, cosine_dirs, equirect, heightfield, mean_abs_error, params, waves,
    waves_reference_with,
};
use crate::ssao::rng::Rng;
use crate::ssao::Falloff;
use glam::{Mat3, Vec3};

const INF: f32 = f32::INFINITY;

/// Obscurance of `p` (normal `n`) with falloff `rho` through the map read as a height field:
/// a ray is blocked where it passes behind a valid pixel's facet (its point and normal) as a
/// sensor at the origin sees it, and leaves through empty pixels, off the map or at `tmax`.
fn map_reference(g: &GBuffer, proj: &Projection, p: Vec3, n: Vec3, seed: u64, rho: Rho) -> f32 {
    let (tmax, falloff) = rho;
    let dirs = cosine_dirs(n, 16, seed);
    let scale = p.length().max(1.0);
    let behind = |q: Vec3| -> Option<bool> {
        let pr = proj.project(q)?;
        let c = proj.pixel_index(pr.x, pr.y)?;
        if !g.is_valid(c) {
            return Some(false);
        }
        // Each pixel is the facet of its point and normal (sensor at the origin).
        let (pc, nc) = (g.position[c], g.normal[c]);
        let den = nc.dot(q);
        let t = nc.dot(pc) / den;
        Some(den.abs() > 1e-9 && t > 0.0 && t < 1.0 - 1e-4)
    };
    let sum: f32 = dirs
        .iter()
        .map(|&w| {
            let mut t = 2e-3 * scale;
            while t < 200.0 * scale && t < tmax {
                match behind(p + w * t) {
                    None => return 1.0,
                    Some(true) => return falloff.rho(t, tmax),
                    Some(false) => {}
                }
                t += (0.004 * t).max(1e-3 * scale);
            }
            1.0
        })
        .sum();
    sum / dirs.len() as f32
}

/// `t_max` and the falloff.
type Rho = (f32, Falloff);

/// Plain ambient occlusion.
const PLAIN: Rho = (INF, Falloff::None);

/// `count` random valid pixels of `g` and their reference.
fn picks(g: &GBuffer, proj: &Projection, count: usize, rho: Rho) -> Vec<(usize, f32)> {
    let mut rng = Rng::new(5, 0);
    let n = g.width * g.height;
    let mut out = Vec::new();
    while out.len() < count {
        let i = (rng.next_u64() % n as u64) as usize;
        if g.is_valid(i) {
            out.push((
                i,
                map_reference(g, proj, g.position[i], g.normal[i], i as u64, rho),
            ));
        }
    }
    out
}

fn span(refs: &[(usize, f32)]) -> f32 {
    let (lo, hi) = refs
        .iter()
        .fold((1.0f32, 0.0f32), |(a, b), r| (a.min(r.1), b.max(r.1)));
    hi - lo
}

/// A 20 × 20 m court with 8 m walls, no roof, and a 2 × 2 m pillar off its centre, seen from
/// 1.5 m above its floor.
pub(crate) fn court(o: Vec3, d: Vec3) -> Option<(f32, Vec3)> {
    let (lo, hi) = (Vec3::new(-10.0, -10.0, -1.5), Vec3::new(10.0, 10.0, 6.5));
    let walls = box_hit(o, d, lo, hi).filter(|b| b.1 != Vec3::NEG_Z);
    let pillar = solid_box_hit(o, d, Vec3::new(3.0, -1.0, -1.5), Vec3::new(5.0, 1.0, 3.0));
    match (walls, pillar) {
        (Some(a), Some(b)) => Some(if a.0 < b.0 { a } else { b }),
        (a, b) => a.or(b),
    }
}

/// Entry into the solid box `[lo, hi]` from outside: ray parameter and outward normal.
fn solid_box_hit(o: Vec3, d: Vec3, lo: Vec3, hi: Vec3) -> Option<(f32, Vec3)> {
    let (mut t0, mut t1, mut n) = (0.0f32, f32::INFINITY, Vec3::ZERO);
    for axis in 0..3 {
        if d[axis] == 0.0 {
            if o[axis] < lo[axis] || o[axis] > hi[axis] {
                return None;
            }
            continue;
        }
        let (a, b) = (
            (lo[axis] - o[axis]) / d[axis],
            (hi[axis] - o[axis]) / d[axis],
        );
        let (near, far) = if a < b { (a, b) } else { (b, a) };
        if near > t0 {
            t0 = near;
            n = Vec3::ZERO;
            n[axis] = -d[axis].signum();
        }
        t1 = t1.min(far);
    }
    (t0 < t1 && t0 > 0.0).then_some((t0, n))
}

/// An equirect station at the origin, its sensor frame turned by `rot`.
fn station(w: usize, h: usize, rot: Mat3) -> Projection {
    let mut proj = equirect(w, h);
    if let Model::Equirect { rot: r, .. } = &mut proj.model {
        *r = rot;
    }
    proj
}

#[test]
fn waves_converge_to_the_ray_traced_height_field_at_the_default_budget() {
    let w = 160usize;
    let (g, proj) = heightfield(w, w, 1.0, waves);
    let refs: Vec<(usize, f32)> = (0..12)
        .flat_map(|yy| (0..12).map(move |xx| (20 + 10 * yy) * w + 20 + 10 * xx))
        .map(|i| {
            let a = waves_reference_with(g.position[i], g.normal[i], INF, Falloff::None, w as f32);
            (i, a)
        })
        .collect();
    let e = mean_abs_error(&ssao(&g, &proj, &params(8, 8, INF)), &refs);
    eprintln!(
        "waves at t_max = ∞, span {:.3}: mean |a − A| {e:.4}",
        span(&refs)
    );
    assert!(span(&refs) > 0.3);
    assert!(e < 0.01, "{e}");
}

#[test]
fn equirect_court_converges_at_the_default_budget() {
    let proj = station(256, 128, Mat3::IDENTITY);
    let g = cast(&proj, court);
    let refs = picks(&g, &proj, 200, PLAIN);
    let m = ssao(&g, &proj, &params(8, 8, INF));
    let e = mean_abs_error(&m, &refs);
    eprintln!(
        "court at t_max = ∞, span {:.3}: mean |a − A| {e:.4}",
        span(&refs)
    );
    assert!(span(&refs) > 0.3);
    assert!(e < 0.01, "{e}");
}

#[test]
fn pinhole_court_with_sky_converges_at_the_default_budget() {
    // Looking towards the pillar and a corner, 10° up: sky above the walls.
    let proj = camera(192, 144, -10f32.to_radians());
    let g = cast(&proj, |o, d| court(o, Mat3::from_rotation_z(0.6) * d));
    let g = rotated_points(g, Mat3::from_rotation_z(0.6));
    let refs = picks(&g, &proj, 200, PLAIN);
    let e = mean_abs_error(&ssao(&g, &proj, &params(8, 8, INF)), &refs);
    eprintln!(
        "pinhole court at t_max = ∞, span {:.3}: mean |a − A| {e:.4}",
        span(&refs)
    );
    assert!(span(&refs) > 0.3);
    assert!(e < 0.01, "{e}");
}

/// The block walk over `k` families, on any map (the sweeps walk only circles).
fn walk_all(g: &GBuffer, proj: &Projection, k: usize, only: Option<&[bool]>) -> (AoMap, Vec<f32>) {
    let fams: Vec<Family> = (0..k).map(|f| Family::new(g, proj, f, k)).collect();
    let pts: Vec<Vec3A> = g.position.iter().map(|&p| Vec3A::from(p)).collect();
    walk(g, proj, &fams, &pts, only)
}

/// `g` with its normals turned back by `rot` (the scene was cast turned by `rot`).
fn rotated_points(mut g: GBuffer, rot: Mat3) -> GBuffer {
    let inv = rot.transpose();
    for n in g.normal.iter_mut() {
        *n = inv * *n;
    }
    g
}

#[test]
fn seam_and_pole_on_geometry_change_little() {
    let (w, h) = (256usize, 128usize);
    let base = station(w, h, Mat3::IDENTITY);
    let gb = cast(&base, court);
    let ab = ssao(&gb, &base, &params(8, 8, INF));
    // The seam on the pillar, then a pole on a wall.
    for rot in [Mat3::from_rotation_z(2.9), Mat3::from_rotation_y(FRAC_PI_2)] {
        let proj = station(w, h, rot);
        let g = cast(&proj, court);
        let a = ssao(&g, &proj, &params(8, 8, INF));
        let (mut sum, mut n) = (0.0f32, 0usize);
        for c in (0..w * h).step_by(7).filter(|&c| gb.is_valid(c)) {
            let Some(q) = proj.project(gb.position[c]) else {
                continue;
            };
            let Some(d) = proj.pixel_index(q.x, q.y).filter(|&d| g.is_valid(d)) else {
                continue;
            };
            if g.normal[d].dot(gb.normal[c]) > 0.99 && g.position[d].distance(gb.position[c]) < 0.2
            {
                sum += (a.ao[d] - ab.ao[c]).abs();
                n += 1;
            }
        }
        let e = sum / n.max(1) as f32;
        eprintln!("turned station: {n} points, mean |Δa| {e:.4}");
        assert!(n > 1000 && e < 0.005, "{n} {e}");
    }
}

#[test]
fn deterministic_and_finite() {
    let proj = station(128, 64, Mat3::IDENTITY);
    let g = cast(&proj, court);
    let a = ssao(&g, &proj, &params(8, 8, INF));
    let b = ssao(&g, &proj, &params(8, 8, INF));
    assert_eq!(a.ao, b.ao);
    assert!(a
        .ao
        .iter()
        .all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
}

#[test]
fn one_pass_sweep_of_straight_lines_matches_the_walk() {
    let proj = camera(192, 144, -10f32.to_radians());
    let g = cast(&proj, |o, d| court(o, Mat3::from_rotation_z(0.6) * d));
    let g = rotated_points(g, Mat3::from_rotation_z(0.6));
    let one = ssao(&g, &proj, &params(8, 8, INF));
    let (each, _) = walk_all(&g, &proj, 32, None);
    let (mut sum, mut worst, mut n) = (0.0f32, 0.0f32, 0usize);
    for c in (0..g.width * g.height).filter(|&c| g.is_valid(c)) {
        assert_eq!(one.no_sample[c], each.no_sample[c]);
        let d = (one.ao[c] - each.ao[c]).abs();
        sum += d;
        worst = worst.max(d);
        n += 1;
    }
    let mean = sum / n as f32;
    eprintln!("one pass against the walk: {n} pixels, mean |Δa| {mean:.5}, largest {worst:.4}");
    assert!(mean < 0.0005 && worst < 0.01, "{mean} {worst}");
}

/// The march's mean error against the map's own rays at 200 points of the courts, under open
/// sky (an equirectangular station) and through a pinhole, with falloff `rho` at 8 × 8; the
/// span of the references is checked on the way.
fn march_error_on_the_courts(rho: Rho) -> [(&'static str, f32); 2] {
    let equirect = station(768, 384, Mat3::IDENTITY);
    let pinhole = camera(576, 432, -10f32.to_radians());
    let turn = Mat3::from_rotation_z(0.6);
    let maps = [
        ("equirectangular", cast(&equirect, court), &equirect),
        (
            "pinhole",
            rotated_points(cast(&pinhole, |o, d| court(o, turn * d)), turn),
            &pinhole,
        ),
    ];
    maps.map(|(name, g, proj)| {
        let refs = picks(&g, proj, 200, rho);
        let mut prm = params(8, 8, rho.0);
        prm.falloff = rho.1;
        let e = mean_abs_error(&crate::ssao::compute(&g, proj, &prm), &refs);
        eprintln!(
            "{name} court at t_max = {} m, span {:.3}: mean |a − A| {e:.4}",
            rho.0,
            span(&refs)
        );
        assert!(span(&refs) > 0.3);
        (name, e)
    })
}

/// At a finite `t_max` spanning tens to a hundred pixels the march (not the sweeps) computes
/// obscurance: with the default falloff it stays within 0.01 of the map's own rays on the
/// courts, under open sky and through a pinhole.
#[test]
fn march_at_four_metres_converges_on_the_courts() {
    for (name, e) in march_error_on_the_courts((4.0, Falloff::Smoothstep)) {
        assert!(e < 0.01, "{name}: {e}");
    }
}

/// At twenty metres the `t_max` disk spans hundreds of pixels: with eight steps a slice strode
/// over the court's pillar and walls (mean error 0.12 on the station), so the march takes one
/// sample per `MAX_STRIDE` pixels of the disk, and stays near the map's own rays.
#[test]
fn march_at_twenty_metres_does_not_stride_over_the_court() {
    let errors = march_error_on_the_courts((20.0, Falloff::Smoothstep));
    for ((name, e), bound) in errors.into_iter().zip([0.06, 0.03]) {
        assert!(e < bound, "{name}: {e}");
    }
}
