use super::*;
use crate::ssao::horizon::tests::{
    camera, cast, equirect, floor_and_wall, heightfield, params, plane, room,
};
use crate::ssao::Sampling;

/// A sphere of radius `r` centred under the middle of a `w × w` orthographic map of pixel
/// `step`, seen from outside (`sign = 1`, a cap) or from inside (`sign = −1`, a bowl).
fn sphere(w: usize, step: f32, r: f32, sign: f32) -> GBuffer {
    let c = 0.5 * w as f32 * step;
    heightfield(w, w, step, |x, y| {
        let (dx, dy) = (x - c, y - c);
        let z = (r * r - dx * dx - dy * dy).max(0.0).sqrt();
        let p = Vec3::new(dx, dy, sign * z);
        let n = if sign > 0.0 { p / r } else { -p / r };
        (sign * z, n)
    })
    .0
}

/// Pixels within `frac × r` of the sphere's axis, away from the map's border.
fn inner(w: usize, step: f32, r: f32, frac: f32) -> Vec<usize> {
    let c = 0.5 * w as f32 * step;
    (0..w * w)
        .filter(|&i| {
            let x = ((i % w) as f32 + 0.5) * step - c;
            let y = ((i / w) as f32 + 0.5) * step - c;
            (x * x + y * y).sqrt() < frac * r
        })
        .collect()
}

#[test]
fn curvature_reads_one_over_r_on_a_sphere() {
    for (r, step) in [(1.0f32, 0.01f32), (0.05, 0.001), (20.0, 0.1)] {
        let w = (2.4 * r / step) as usize;
        for sign in [1.0f32, -1.0] {
            let g = sphere(w, step, r, sign);
            let k = curvature(&g);
            let ids = inner(w, step, r, 0.7);
            assert!(ids.len() > 100);
            for &i in &ids {
                let rel = k[i] * r * sign;
                assert!(
                    (rel - 1.0).abs() < 0.05,
                    "R {r}, sign {sign}: pixel {i} reads κ·R = {}",
                    k[i] * r
                );
            }
        }
    }
}

#[test]
fn curvature_and_discontinuity_read_zero_on_a_plane() {
    let n = Vec3::new(0.3, -0.2, 1.0).normalize();
    let (g, _) = heightfield(64, 48, 0.02, |x, y| (-(n.x * x + n.y * y) / n.z + 0.5, n));
    let k = curvature(&g);
    let d = discontinuity(&g);
    for y in 1..47 {
        for x in 1..63 {
            let i = y * 64 + x;
            assert!(k[i].abs() < 1e-3, "κ {} at {i}", k[i]);
            assert!(d[i] < 1e-3, "discontinuity {} at {i}", d[i]);
        }
    }
    // The border of the data counts as an edge.
    assert_eq!(d[0], 1.0);
}

#[test]
fn discontinuity_marks_a_step() {
    let (g, _) = heightfield(32, 32, 0.01, |x, _| {
        (if x < 0.16 { 0.0 } else { 0.05 }, Vec3::Z)
    });
    let d = discontinuity(&g);
    // Columns 15 and 16 face each other across the 5 cm step; column 8 is flat.
    assert!(d[10 * 32 + 15] > 0.9 && d[10 * 32 + 16] > 0.9);
    assert!(d[10 * 32 + 8] < 1e-6);
    let lv = plan(&g, 0.4);
    for y in 0..32 {
        assert_eq!(lv[y * 32 + 15], 0);
        assert_eq!(lv[y * 32 + 16], 0);
    }
}

fn adaptive(tmax: f32) -> SsaoParams {
    SsaoParams {
        sampling: Sampling::Adaptive,
        ..params(8, 8, tmax)
    }
}

#[test]
fn open_plane_reads_one_and_runs_coarse() {
    let proj = camera(160, 120, 0.5);
    let g = cast(&proj, |o, d| {
        plane(o, d, Vec3::Z, -1.5).map(|t| (t, Vec3::Z))
    });
    // Pixels here are 3 cm or more: a t_max of 2 m lets 4×4 blocks span them.
    let m = ssao(&g, &proj, &adaptive(2.0));
    // As the uniform march reads it: 1 up to rounding.
    for (i, &a) in m.ao.iter().enumerate() {
        assert!((a - 1.0).abs() < 1e-6, "pixel {i}: {a}");
    }
    let lv = m.levels.unwrap();
    let s = lv.shares();
    assert_eq!(lv.pixels.iter().sum::<u64>() as usize, g.filled());
    assert!(s[2] > 0.5, "{}", lv.to_text());
}

#[test]
fn coarse_blocks_follow_the_footprint_against_tmax() {
    let proj = camera(160, 120, 0.5);
    let g = cast(&proj, |o, d| {
        plane(o, d, Vec3::Z, -1.5).map(|t| (t, Vec3::Z))
    });
    let share = |tmax: f32| {
        let l = ssao(&g, &proj, &adaptive(tmax)).levels.unwrap();
        l.shares()[0]
    };
    // A t_max shorter than a few pixels' footprint leaves every pixel at full rate.
    assert!(share(1e-3) > 0.999);
    assert!(share(0.05) > share(0.4));
    // No finite t_max, no scale: full rate.
    assert_eq!(
        plan(&g, f32::INFINITY).iter().filter(|&&l| l > 0).count(),
        0
    );
}

#[test]
fn floor_and_wall_stay_close_to_uniform_and_keep_the_crease_at_full_rate() {
    let proj = camera(200, 150, 0.3);
    let g = floor_and_wall(&proj);
    let uni = crate::ssao::horizon::ssao(&g, &proj, &params(8, 8, 1.0));
    let ada = ssao(&g, &proj, &adaptive(1.0));
    let again = ssao(&g, &proj, &adaptive(1.0));
    assert_eq!(ada.ao, again.ao, "deterministic for a seed");
    let lv = plan(&g, 1.0);
    let k = curvature(&g);
    let (mut err, mut n) = (0.0f64, 0usize);
    for c in 0..g.width * g.height {
        if !g.is_valid(c) {
            continue;
        }
        // Pixels whose neighbours lie on the other surface are on the crease.
        if discontinuity(&g)[c] > 0.5 || k[c].abs() > 1.0 {
            assert_eq!(lv[c], 0, "crease pixel {c} must run at full rate");
        }
        err += (ada.ao[c] - uni.ao[c]).abs() as f64;
        n += 1;
    }
    let mean = err / n as f64;
    let l = ada.levels.unwrap();
    eprintln!("mean |adaptive − uniform| {mean:.4}; {}", l.to_text());
    assert!(mean < 0.02, "{mean}");
    assert!(l.shares()[0] < 0.5, "{}", l.to_text());
}

#[test]
fn room_on_an_equirect_map_stays_close_to_uniform() {
    let proj = equirect(256, 128);
    let g = room(&proj);
    let uni = crate::ssao::horizon::ssao(&g, &proj, &params(8, 8, 0.4));
    let ada = ssao(&g, &proj, &adaptive(0.4));
    let n = g.filled() as f64;
    let mean: f64 = (0..g.width * g.height)
        .filter(|&c| g.is_valid(c))
        .map(|c| (ada.ao[c] - uni.ao[c]).abs() as f64)
        .sum::<f64>()
        / n;
    let l = ada.levels.unwrap();
    eprintln!("room: mean |adaptive − uniform| {mean:.4}; {}", l.to_text());
    assert!(mean < 0.02, "{mean}");
    assert_eq!(ada.no_sample, uni.no_sample);
}

#[test]
fn far_field_open_plane_reads_one_and_runs_coarse() {
    let proj = camera(160, 120, 0.5);
    let g = cast(&proj, |o, d| {
        plane(o, d, Vec3::Z, -1.5).map(|t| (t, Vec3::Z))
    });
    let m = far_field(&g, &proj, &adaptive(f32::INFINITY));
    for (i, &a) in m.ao.iter().enumerate() {
        assert!((a - 1.0).abs() < 1e-6, "pixel {i}: {a}");
    }
    let lv = m.levels.unwrap();
    assert_eq!(lv.pixels.iter().sum::<u64>() as usize, g.filled());
    // The plane is open everywhere: its blocks take the coarsest level where they fit.
    assert!(lv.shares()[4] > 0.5, "{}", lv.to_text());
}

#[test]
fn far_field_stays_close_to_full_rate_under_open_sky() {
    use crate::ssao::farfield::{self, tests::court};
    let inf = adaptive(f32::INFINITY);
    let pinhole = camera(200, 150, 0.3);
    let station = equirect(256, 128);
    for (name, proj, g) in [
        ("floor and wall", &pinhole, floor_and_wall(&pinhole)),
        ("court", &station, cast(&station, court)),
    ] {
        let full = farfield::ssao(&g, proj, &inf);
        let ada = far_field(&g, proj, &inf);
        let n = g.filled() as f64;
        let mean = (0..g.width * g.height)
            .filter(|&c| g.is_valid(c))
            .map(|c| (ada.ao[c] - full.ao[c]).abs() as f64)
            .sum::<f64>()
            / n;
        let l = ada.levels.unwrap();
        eprintln!(
            "{name} at t_max = ∞: mean |adaptive − full| {mean:.5}; {}",
            l.to_text()
        );
        assert!(mean < 0.003, "{name}: {mean}");
        assert!(l.shares()[0] < 0.6, "{name}: {}", l.to_text());
        assert_eq!(ada.no_sample, full.no_sample);
    }
}
