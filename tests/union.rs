//! Union occlusion against analytic ground truth: synthetic stations of small scenes, the
//! truth ray-cast against the exact primitives.

use glam::DVec3;
use mvao::config::ComputeParams;
use mvao::pipeline::{compute, ScanResult};
use mvao::progress::Silent;
use mvao::synth::{scan_with_truth, Prim, Scene, Station, Truth};
use mvao::Occlusion;

/// Runs the stations of `scene` through the in-memory pipeline.
fn run(
    scene: &Scene,
    stations: &[Station],
    radius: f32,
    tmax: f32,
    occlusion: Occlusion,
    bent: bool,
) -> (Vec<ScanResult>, Vec<Vec<Truth>>) {
    let (scans, truth): (Vec<_>, Vec<_>) = stations
        .iter()
        .enumerate()
        .map(|(k, s)| scan_with_truth(scene, s, 0.0, 1, &format!("s{k}")))
        .unzip();
    let prm = ComputeParams {
        radius: Some(radius),
        tmax: Some(tmax),
        occlusion,
        rays: Some(64),
        bent_normals: bent,
        ..ComputeParams::default()
    };
    let c = compute(&scans, &prm, &Silent).expect("compute");
    (c.scans, truth)
}

/// Ray-cast obscurance (smoothstep ρ) of the exact surface point `t` against `scene`.
fn truth_ao(scene: &Scene, t: &Truth, tmax: f64) -> f64 {
    let n = t.n;
    let a = if n.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let t1 = n.cross(a).normalize();
    let t2 = n.cross(t1);
    let (k1, k2) = (32, 32);
    let mut sum = 0.0;
    for i in 0..k1 {
        for j in 0..k2 {
            let u1 = (i as f64 + 0.5) / k1 as f64;
            let phi = std::f64::consts::TAU * (j as f64 + 0.5) / k2 as f64;
            let r = u1.sqrt();
            let d = t1 * (r * phi.cos()) + t2 * (r * phi.sin()) + n * (1.0 - u1).sqrt();
            let hit = scene.intersect_range(t.p + n * 1e-6, d, 1e-9, tmax);
            sum += match hit {
                Some(h) => {
                    let x = (h.t / tmax).clamp(0.0, 1.0);
                    x * x * (3.0 - 2.0 * x)
                }
                None => 1.0,
            };
        }
    }
    sum / (k1 * k2) as f64
}

/// Mean of (estimate − truth) and of the estimate over the points of scan 0 picked by `pick`.
fn score(
    scene: &Scene,
    truth: &[Truth],
    est: &[f32],
    tmax: f64,
    pick: impl Fn(&Truth) -> bool,
) -> (f64, f64, usize) {
    let idx: Vec<usize> = (0..truth.len()).filter(|&i| pick(&truth[i])).collect();
    assert!(idx.len() >= 10, "too few points picked: {}", idx.len());
    let (mut bias, mut mean) = (0.0, 0.0);
    for &i in &idx {
        bias += est[i] as f64 - truth_ao(scene, &truth[i], tmax);
        mean += est[i] as f64;
    }
    let k = idx.len() as f64;
    (bias / k, mean / k, idx.len())
}

fn quad(center: DVec3, u: DVec3, v: DVec3, facing: DVec3) -> Prim {
    Prim::quad_facing(center, u, v, facing)
}

fn floor(size: f64) -> Prim {
    quad(DVec3::ZERO, DVec3::X * size, DVec3::Y * size, DVec3::Z)
}

fn cam(pos: [f64; 3], at: [f64; 3], fov_deg: f64, w: usize) -> Station {
    Station::perspective(
        DVec3::from(pos),
        DVec3::from(at),
        fov_deg.to_radians(),
        w,
        w * 3 / 4,
    )
}

#[test]
fn open_plane_seen_by_three_views_is_open() {
    let scene = Scene {
        prims: vec![floor(20.0)],
    };
    let st = [
        cam([-1.0, -1.0, 1.5], [0.0, 0.0, 0.0], 60.0, 96),
        cam([1.5, 0.0, 1.2], [0.0, 0.0, 0.0], 60.0, 96),
        cam([0.0, 1.5, 2.0], [0.0, 0.0, 0.0], 60.0, 96),
    ];
    let (r, truth) = run(&scene, &st, 0.25, 0.5, Occlusion::Union, true);
    for (k, (s, tr)) in r.iter().zip(&truth).enumerate() {
        let near: Vec<usize> = (0..tr.len())
            .filter(|&i| tr[i].p.x.abs() < 0.4 && tr[i].p.y.abs() < 0.4)
            .collect();
        assert!(!near.is_empty());
        let mean = near.iter().map(|&i| s.ao[i] as f64).sum::<f64>() / near.len() as f64;
        let least = near.iter().map(|&i| s.ao[i]).fold(1.0f32, f32::min);
        assert!(mean >= 0.99 && least >= 0.97, "mean {mean}, least {least}");
        let bent = s.bent.as_ref().expect("bent normals");
        for &i in &near {
            let n = tr[i].n;
            let bw = (st[k].pose() * bent[i].as_dvec3().extend(0.0)).truncate();
            let ang = bw.normalize().dot(n).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(ang < 0.5, "bent normal {ang}° off an open plane");
        }
    }
}

#[test]
fn occluder_seen_only_by_the_other_scan() {
    // A box on the floor right of x = 0.05; A looks down at the floor left of it (the box
    // outside its frame), B sees both from the side.
    let scene = Scene {
        prims: vec![
            floor(20.0),
            Prim::Box {
                min: DVec3::new(0.05, -0.6, 0.0),
                max: DVec3::new(0.65, 0.6, 0.6),
            },
        ],
    };
    let st = [
        cam([-0.45, 0.0, 1.0], [-0.45, 0.0, 0.0], 50.0, 128),
        cam([-1.6, -1.2, 1.4], [0.0, 0.0, 0.2], 60.0, 160),
    ];
    let tmax = 0.6;
    let (u, truth) = run(&scene, &st, 0.3, tmax as f32, Occlusion::Union, false);
    let pick = |t: &Truth| t.n.z > 0.9 && t.p.x > -0.3 && t.p.x < 0.0 && t.p.y.abs() < 0.3;
    let (b_single, m_single, _) = score(&scene, &truth[0], &u[0].ssao, tmax, pick);
    let (bias, mean, k) = score(&scene, &truth[0], &u[0].ao, tmax, pick);
    eprintln!(
        "single {m_single:.3} (bias {b_single:+.3}); union {mean:.3} (bias {bias:+.3}), {k} pts"
    );
    assert!(bias.abs() <= 0.02, "union bias {bias}");
}

#[test]
fn crease_wall_outside_the_frame() {
    let scene = Scene {
        prims: vec![
            floor(20.0),
            quad(
                DVec3::new(0.0, 0.0, 5.0),
                DVec3::Y * 20.0,
                DVec3::Z * 10.0,
                -DVec3::X,
            ),
        ],
    };
    let st = [
        cam([-0.34, 0.0, 1.0], [-0.34, 0.0, 0.0], 50.0, 128),
        cam([-2.0, -1.0, 1.2], [0.0, 0.0, 0.3], 60.0, 160),
    ];
    let tmax = 0.6;
    let (u, truth) = run(&scene, &st, 0.3, tmax as f32, Occlusion::Union, false);
    let pick = |t: &Truth| t.n.z > 0.9 && t.p.x > -0.15 && t.p.y.abs() < 0.3;
    let (_, m_single, _) = score(&scene, &truth[0], &u[0].ssao, tmax, pick);
    let (bias, mean, k) = score(&scene, &truth[0], &u[0].ao, tmax, pick);
    eprintln!("single {m_single:.3}; union {mean:.3} (bias {bias:+.3}), {k} pts");
    assert!(m_single >= 0.9, "A alone {m_single}");
    assert!(bias.abs() <= 0.03, "union bias {bias}");
}

#[test]
fn thin_panel_in_front_of_a_wall() {
    // Wall y = 0 facing +y; a panel 2 cm thick, 0.5 m in front of it. A faces the wall, B
    // looks along it from the side and sees the gap behind the panel.
    let scene = Scene {
        prims: vec![
            quad(DVec3::ZERO, DVec3::X * 20.0, DVec3::Z * 20.0, DVec3::Y),
            Prim::Box {
                min: DVec3::new(-0.4, 0.5, -0.4),
                max: DVec3::new(0.4, 0.52, 0.4),
            },
        ],
    };
    let st = [
        cam([0.0, 3.0, 0.0], [0.0, 0.0, 0.0], 50.0, 160),
        cam([3.0, 1.2, 0.0], [0.0, 0.25, 0.0], 50.0, 160),
    ];
    let tmax = 2.0;
    let (u, truth) = run(&scene, &st, 1.0, tmax as f32, Occlusion::Union, false);
    // A's wall points just outside the panel's outline as A sees it (the panel's shadow
    // from A reaches |x| = 0.4 · 3 / 2.48 on the wall).
    let edge = 0.4 * 3.0 / 2.48;
    let pick = |t: &Truth| {
        t.n.y > 0.9 && t.p.y.abs() < 1e-3 && {
            let m = t.p.x.abs().max(t.p.z.abs());
            m > edge + 0.02 && m < edge + 0.12
        }
    };
    let (b_single, m_single, _) = score(&scene, &truth[0], &u[0].ssao, tmax, pick);
    let (bias, mean, k) = score(&scene, &truth[0], &u[0].ao, tmax, pick);
    eprintln!(
        "single {m_single:.3} (bias {b_single:+.3}); union {mean:.3} (bias {bias:+.3}), {k} pts"
    );
    assert!(b_single <= -0.1, "A alone bias {b_single}");
    assert!(bias.abs() <= 0.03, "union bias {bias}");
}

#[test]
fn bent_normal_beside_a_wall_tilts_away() {
    let scene = Scene {
        prims: vec![
            floor(200.0),
            quad(
                DVec3::new(0.0, 0.0, 50.0),
                DVec3::Y * 200.0,
                DVec3::Z * 100.0,
                -DVec3::X,
            ),
        ],
    };
    let st = [cam([-1.0, 0.0, 0.8], [-0.02, 0.0, 0.0], 30.0, 192)];
    let tmax = 2.0;
    let (r, truth) = run(&scene, &st, 1.0, tmax as f32, Occlusion::Union, true);
    let bent = r[0].bent.as_ref().expect("bent normals");
    let pose = st[0].pose();
    let mut tilt = Vec::new();
    for (i, t) in truth[0].iter().enumerate() {
        if t.n.z > 0.9 && t.p.x > -0.02 && t.p.x < -0.005 && t.p.y.abs() < 0.1 {
            let b = (pose * bent[i].as_dvec3().extend(0.0))
                .truncate()
                .normalize();
            assert!(b.x < 0.0, "tilts towards the wall: {b}");
            tilt.push(b.z.clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    assert!(tilt.len() >= 5, "{} points", tilt.len());
    let mean = tilt.iter().sum::<f64>() / tilt.len() as f64;
    let want = (2.0 / std::f64::consts::PI).atan().to_degrees();
    assert!((mean - want).abs() <= 2.0, "tilt {mean}° want {want}°");
}

#[test]
fn coarse_view_takes_a_pixel_behind_its_surface_as_solid() {
    // A 0.6 m cube on the floor seen by one coarse camera (about 4 cm pixels at the cube)
    // from its front and above; the floor points beside the cube. Rays into the cube through
    // the side faces the camera sees edge-on are behind the front face, not through it, and
    // with a thickness far below a pixel (1 mm) only the pixel's floor infers them solid.
    let scene = Scene {
        prims: vec![
            floor(20.0),
            Prim::Box {
                min: DVec3::new(-0.3, -0.3, 0.0),
                max: DVec3::new(0.3, 0.3, 0.6),
            },
        ],
    };
    let st = [cam([-2.2, 0.0, 1.6], [0.0, 0.0, 0.2], 60.0, 64)];
    let tmax = 0.4;
    let (scans, truth): (Vec<_>, Vec<_>) = st
        .iter()
        .map(|s| scan_with_truth(&scene, s, 0.0, 1, "s0"))
        .unzip();
    let prm = ComputeParams {
        radius: Some(0.2),
        tmax: Some(tmax as f32),
        occlusion: Occlusion::Union,
        rays: Some(64),
        thickness: Some(0.001),
        ..ComputeParams::default()
    };
    let u = compute(&scans, &prm, &Silent).expect("compute").scans;
    let pick = |t: &Truth| {
        t.n.z > 0.9 && t.p.z < 1e-3 && t.p.x > -0.45 && t.p.x < -0.3 && t.p.y.abs() < 0.28
    };
    let (b_single, _, _) = score(&scene, &truth[0], &u[0].ssao, tmax, pick);
    let (bias, mean, k) = score(&scene, &truth[0], &u[0].ao, tmax, pick);
    eprintln!("single bias {b_single:+.3}; union {mean:.3} (bias {bias:+.3}), {k} pts");
    assert!(bias.abs() <= 0.1, "union bias {bias}");
}

#[test]
fn floor_seen_at_grazing_incidence_stops_the_rays() {
    // The underside of a slab 0.6 m above the floor, seen from below by A (whose frame holds
    // no floor); B, 15 cm above the floor 3 m away, sees the floor under the slab at about
    // 3° of incidence, where its stored depth steps by ~20 cm from one pixel row to the next.
    // The rays from the slab down to the floor cross it only in B's map.
    let scene = Scene {
        prims: vec![
            floor(20.0),
            quad(
                DVec3::new(0.0, 0.0, 0.6),
                DVec3::X * 1.2,
                DVec3::Y * 1.2,
                -DVec3::Z,
            ),
        ],
    };
    let st = [
        cam([-0.8, 0.0, 0.1], [0.0, 0.0, 0.6], 50.0, 128),
        cam([-3.0, 0.0, 0.15], [0.0, 0.0, 0.2], 50.0, 192),
    ];
    let tmax = 1.0;
    let (u, truth) = run(&scene, &st, 0.5, tmax as f32, Occlusion::Union, false);
    let pick = |t: &Truth| t.n.z < -0.9 && t.p.x.abs() < 0.3 && t.p.y.abs() < 0.3;
    let (b_single, m_single, _) = score(&scene, &truth[0], &u[0].ssao, tmax, pick);
    let (bias, mean, k) = score(&scene, &truth[0], &u[0].ao, tmax, pick);
    eprintln!(
        "single {m_single:.3} (bias {b_single:+.3}); union {mean:.3} (bias {bias:+.3}), {k} pts"
    );
    assert!(bias.abs() <= 0.03, "union bias {bias}");
}

#[test]
fn far_face_of_a_panel_thinner_than_a_pixel_stays_open() {
    // A 2 cm panel standing free; B sees its front face from 3 m with 5 cm pixels, so its
    // solid behind that face reaches past the back face; A sees the back face, which nothing
    // overlooks within t_max.
    let scene = Scene {
        prims: vec![Prim::Box {
            min: DVec3::new(-0.5, -0.01, 0.0),
            max: DVec3::new(0.5, 0.01, 1.0),
        }],
    };
    let st = [
        cam([0.0, 1.0, 0.5], [0.0, 0.0, 0.5], 60.0, 96),
        cam([0.0, -3.0, 0.5], [0.0, 0.0, 0.5], 60.0, 64),
    ];
    let tmax = 0.4;
    let (u, truth) = run(&scene, &st, 0.2, tmax as f32, Occlusion::Union, false);
    let pick = |t: &Truth| t.n.y > 0.9 && t.p.x.abs() < 0.3 && (t.p.z - 0.5).abs() < 0.3;
    let (bias, mean, k) = score(&scene, &truth[0], &u[0].ao, tmax, pick);
    eprintln!("union {mean:.3} (bias {bias:+.3}), {k} pts");
    assert!(bias.abs() <= 0.02, "union bias {bias}");
}

#[test]
fn gentle_ridge_beside_floor_points_is_not_their_own_surface() {
    // A ridge 3 cm high whose faces slope at 50° (normals within the same-surface cone of the
    // floor's) along the floor; floor points 0.5–5 cm from its foot, about 7 mm pixels. Stored
    // points of the ridge higher than the same-surface band above the floor's tangent plane
    // are occluders, not the floor as another view sampled it. With a band of
    // 2 (rad(p) + rad) the whole ridge was ignored: union 1.000, bias +0.067 (now +0.022;
    // single view +0.013).
    let (h, slope) = (0.03f64, 50f64.to_radians());
    let w = h / slope.tan();
    let face = |s: f64| {
        quad(
            DVec3::new(s * w / 2.0, 0.0, h / 2.0),
            DVec3::new(-s * w, 0.0, h),
            DVec3::Y * 2.0,
            DVec3::new(s * h, 0.0, w),
        )
    };
    let scene = Scene {
        prims: vec![floor(20.0), face(-1.0), face(1.0)],
    };
    let st = [
        cam([-0.3, -0.1, 0.9], [-0.1, 0.0, 0.0], 50.0, 128),
        cam([0.4, 0.2, 0.8], [-0.05, 0.0, 0.0], 55.0, 128),
    ];
    let tmax = 0.3;
    let (u, truth) = run(&scene, &st, 0.15, tmax as f32, Occlusion::Union, false);
    let pick = |t: &Truth| {
        t.n.z > 0.99 && t.p.z < 1e-3 && t.p.x > -w - 0.05 && t.p.x < -w - 0.005 && t.p.y.abs() < 0.2
    };
    let (b_single, m_single, _) = score(&scene, &truth[0], &u[0].ssao, tmax, pick);
    let (bias, mean, k) = score(&scene, &truth[0], &u[0].ao, tmax, pick);
    eprintln!(
        "single {m_single:.3} (bias {b_single:+.3}); union {mean:.3} (bias {bias:+.3}), {k} pts"
    );
    assert!(bias.abs() <= 0.03, "union bias {bias}");
}

#[test]
fn a_closed_room_reads_closed_at_infinity() {
    // The analytic room (walls, floor, ceiling, a niche) from three stations: at t_max = ∞
    // every direction is blocked, truth 0 everywhere. Rays that cross a surface where no view
    // catches the crossing (at a crease, neighbouring pixels lie on different surfaces) end
    // behind the walls in every view, and count as blocked.
    let stations: Vec<Station> = [(1.0, 0.8), (-2.5, -1.5), (2.8, -2.0)]
        .iter()
        .map(|&(x, y)| Station::equirect(DVec3::new(x, y, 1.5), 0.3, 180, 90))
        .collect();
    let (u, _) = run(
        &Scene::room(),
        &stations,
        0.2,
        f32::INFINITY,
        Occlusion::Union,
        false,
    );
    for (k, s) in u.iter().enumerate() {
        let mean = s.ao.iter().map(|&a| a as f64).sum::<f64>() / s.ao.len() as f64;
        let open = s.ao.iter().filter(|&&a| a > 0.05).count();
        eprintln!(
            "station {k}: mean {mean:.5}, {open} of {} above 0.05",
            s.ao.len()
        );
        assert!(mean < 0.002, "station {k}: mean AO {mean}");
        assert!(
            open * 200 < s.ao.len(),
            "station {k}: {open} points above 0.05"
        );
    }
}
