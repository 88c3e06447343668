//! Numerical stability and degenerate input: extreme depth ratios, the poles and seam of an
//! equirectangular map, tiny and huge radii and falloffs, degenerate point sets (collinear,
//! coplanar, duplicated, fewer than k, empty, one point), merges with no partner, identical
//! partners or no overlap, zero merge weights, georeferenced poses near 10⁷ m, poses with
//! rounding noise or scale, and non-finite coordinates and normals through the binary.
//!
//! Every case checks: no panic (a clean `Err` only where the input is truly broken), every AO
//! finite and in [0, 1], the qualitative behaviour stated in the test's doc comment, and, where
//! cheap, that two runs give the same bits.

mod common;

use common::{dome, mvao, report};
use glam::{DMat3, DMat4, DVec2, DVec3, Vec3};
use mvao::config::ComputeParams;
use mvao::io::align::check_rigid;
use mvao::io::ply::{PlyFile, ScalarType};
use mvao::pipeline::{self, Computed};
use mvao::progress::Silent;
use mvao::synth::{scan_scene, station_layout, Prim, Scene, SceneKind, Station};
use mvao::testing::projection::SensorModel;
use mvao::testing::scan::Scan;
use mvao::testing::ssao::Estimator;
use std::path::Path;

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

fn params(estimator: Estimator, radius: Option<f32>, tmax: Option<f32>) -> ComputeParams {
    ComputeParams {
        radius,
        tmax,
        estimator,
        ..Default::default()
    }
}

const BOTH: [Estimator; 2] = [Estimator::Paper, Estimator::Horizon];

/// Every per-point AO (merged and single-view) of every scan is finite and in [0, 1], one value
/// per point.
fn assert_ao_ok(c: &Computed, scans: &[Scan], what: &str) {
    assert_eq!(c.scans.len(), scans.len(), "{what}");
    for (r, s) in c.scans.iter().zip(scans) {
        assert_eq!(r.ao.len(), s.len(), "{what}: {}", s.name);
        assert_eq!(r.ssao.len(), s.len(), "{what}: {}", s.name);
        for (k, (&a, &o)) in r.ao.iter().zip(&r.ssao).enumerate() {
            assert!(
                a.is_finite() && (0.0..=1.0).contains(&a),
                "{what}: {} point {k}: ao {a}",
                s.name
            );
            assert!(
                o.is_finite() && (0.0..=1.0).contains(&o),
                "{what}: {} point {k}: ssao {o}",
                s.name
            );
        }
        assert!(r.no_sample <= s.len() as u64, "{what}");
        assert!(r.merge.zero_weight <= s.len() as u64, "{what}");
    }
}

/// Runs `compute` and checks the AO range.
fn run(scans: &[Scan], prm: &ComputeParams, what: &str) -> Computed {
    let c = pipeline::compute(scans, prm, &Silent)
        .unwrap_or_else(|e| panic!("{what}: compute failed: {e}"));
    assert_ao_ok(&c, scans, what);
    c
}

/// Runs `compute` twice and checks that both runs give the same bits and counters.
fn run_twice(scans: &[Scan], prm: &ComputeParams, what: &str) -> Computed {
    let a = run(scans, prm, what);
    let b = run(scans, prm, what);
    assert_same(&a, &b, what);
    a
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn assert_same(a: &Computed, b: &Computed, what: &str) {
    for (i, (x, y)) in a.scans.iter().zip(&b.scans).enumerate() {
        assert!(bits(&x.ao) == bits(&y.ao), "{what}: scan {i}: ao differs");
        assert!(
            bits(&x.ssao) == bits(&y.ssao),
            "{what}: scan {i}: ssao differs"
        );
        assert_eq!(x.no_sample, y.no_sample, "{what}: scan {i}");
        assert_eq!(x.merge, y.merge, "{what}: scan {i}");
    }
}

/// Mean of `v` over the points of `scan` whose world position satisfies `pick`, and how many.
fn mean_where(scan: &Scan, v: &[f32], pick: impl Fn(DVec3) -> bool) -> (f32, usize) {
    let (mut s, mut n) = (0.0f64, 0usize);
    for (p, a) in scan.points.iter().zip(v) {
        if pick(scan.pose.transform_point3(p.as_dvec3())) {
            s += *a as f64;
            n += 1;
        }
    }
    ((s / n.max(1) as f64) as f32, n)
}

/// Like [`mean_where`], with at least `min` points selected.
fn mean_of(scan: &Scan, v: &[f32], min: usize, pick: impl Fn(DVec3) -> bool) -> f32 {
    let (m, n) = mean_where(scan, v, pick);
    assert!(n >= min, "only {n} points selected (want {min})");
    m
}

fn mean(v: &[f32]) -> f32 {
    (v.iter().map(|&x| x as f64).sum::<f64>() / v.len().max(1) as f64) as f32
}

/// Collects failed checks so that one run reports every failing sub-case of a test.
#[derive(Default)]
struct Fails(Vec<String>);
impl Fails {
    fn check(&mut self, ok: bool, msg: impl FnOnce() -> String) {
        if !ok {
            self.0.push(msg());
        }
    }
    fn finish(self) {
        assert!(
            self.0.is_empty(),
            "{} failed:\n{}",
            self.0.len(),
            self.0.join("\n")
        );
    }
}

/// Scans `scene` from `st` (exact ranges) and sets the scan's pose.
fn scan(scene: &Scene, st: &Station, name: &str) -> Scan {
    let mut s = scan_scene(scene, st, 0.0, 7, name);
    s.pose = st.pose();
    s
}

/// The six inward-facing walls of the box `[lo, hi]`.
fn box_room(lo: DVec3, hi: DVec3) -> Vec<Prim> {
    let c = (lo + hi) * 0.5;
    let e = hi - lo;
    let (ex, ey, ez) = (
        DVec3::new(e.x, 0.0, 0.0),
        DVec3::new(0.0, e.y, 0.0),
        DVec3::new(0.0, 0.0, e.z),
    );
    vec![
        Prim::quad_facing(DVec3::new(c.x, c.y, lo.z), ex, ey, DVec3::Z),
        Prim::quad_facing(DVec3::new(c.x, c.y, hi.z), ex, ey, DVec3::NEG_Z),
        Prim::quad_facing(DVec3::new(lo.x, c.y, c.z), ey, ez, DVec3::X),
        Prim::quad_facing(DVec3::new(hi.x, c.y, c.z), ey, ez, DVec3::NEG_X),
        Prim::quad_facing(DVec3::new(c.x, lo.y, c.z), ex, ez, DVec3::Y),
        Prim::quad_facing(DVec3::new(c.x, hi.y, c.z), ex, ez, DVec3::NEG_Y),
    ]
}

/// A large floor at z = 0.
fn floor() -> Prim {
    Prim::Quad {
        center: DVec3::ZERO,
        u: DVec3::new(40.0, 0.0, 0.0),
        v: DVec3::new(0.0, 40.0, 0.0),
    }
}

/// Floor and a wall at x = 0 facing −x (a concave corner along the y axis).
fn corner_scene() -> Scene {
    Scene {
        prims: vec![
            floor(),
            Prim::quad_facing(
                DVec3::new(0.0, 0.0, 1.5),
                DVec3::new(0.0, 20.0, 0.0),
                DVec3::new(0.0, 0.0, 3.0),
                DVec3::NEG_X,
            ),
        ],
    }
}

/// A small equirect scan of the concave corner, scanner at (−1.5, 0, 1.5).
fn corner_scan() -> Scan {
    let st = Station::equirect(DVec3::new(-1.5, 0.0, 1.5), 0.3, 400, 200);
    scan(&corner_scene(), &st, "corner")
}

/// Floor points of the corner scan next to the wall, and in the open.
fn near_corner(p: DVec3) -> bool {
    p.z.abs() < 1e-3 && p.y.abs() < 1.0 && p.x > -0.12 && p.x < -0.02
}
fn open_floor(p: DVec3) -> bool {
    p.z.abs() < 1e-3 && p.y.abs() < 1.0 && p.x > -3.0 && p.x < -2.2
}

/// A 4 × 3 × 2.5 m box room.
fn room_scene() -> Scene {
    Scene {
        prims: box_room(DVec3::new(-2.0, -1.5, 0.0), DVec3::new(2.0, 1.5, 2.5)),
    }
}

/// One equirect scan of the box room (≈ 80 k points).
fn room_scan() -> Scan {
    let st = Station::equirect(DVec3::new(0.3, -0.2, 1.2), 0.4, 400, 200);
    scan(&room_scene(), &st, "room")
}

/// An orthographic view down onto `scene` over `centre ± half` (≈ 1 px per cm).
fn ortho(scene: &Scene, centre: DVec2, yaw: f64, half: DVec2, name: &str) -> Scan {
    let st = Station::ortho(
        centre.extend(2.0),
        yaw,
        half,
        (half.x * 200.0).round() as usize,
        (half.y * 200.0).round() as usize,
    );
    scan(scene, &st, name)
}

/// Deterministic pseudo-random numbers in [0, 1).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `n` points scattered on the plane z = −1 under the sensor, within ±`half` in x and y.
fn scattered(n: usize, half: f64, seed: u64) -> Vec<Vec3> {
    let mut r = Lcg(seed);
    (0..n)
        .map(|_| {
            Vec3::new(
                ((r.next() * 2.0 - 1.0) * half) as f32,
                ((r.next() * 2.0 - 1.0) * half) as f32,
                -1.0,
            )
        })
        .collect()
}

/// An error message that names the problem: not a panic, not empty.
fn assert_clean_err(e: &mvao::error::Error, needles: &[&str], what: &str) {
    let msg = e.to_string();
    assert!(!msg.trim().is_empty(), "{what}: empty error message");
    assert!(
        needles.iter().any(|n| msg.contains(n)),
        "{what}: error '{msg}' mentions none of {needles:?}"
    );
}

/// Writes a PLY of float x y z (and nx ny nz when given).
fn write_ply(path: &Path, pts: &[[f64; 3]], normals: Option<&[[f64; 3]]>) {
    let col = |v: &[[f64; 3]], k: usize| v.iter().map(|p| p[k]).collect::<Vec<f64>>();
    let (x, y, z) = (col(pts, 0), col(pts, 1), col(pts, 2));
    let mut cols: Vec<(&str, ScalarType, &[f64])> = vec![
        ("x", ScalarType::F32, &x),
        ("y", ScalarType::F32, &y),
        ("z", ScalarType::F32, &z),
    ];
    let n = normals.map(|n| (col(n, 0), col(n, 1), col(n, 2)));
    if let Some((nx, ny, nz)) = &n {
        cols.push(("nx", ScalarType::F32, nx));
        cols.push(("ny", ScalarType::F32, ny));
        cols.push(("nz", ScalarType::F32, nz));
    }
    PlyFile::from_vertex_columns(&cols, &[])
        .unwrap()
        .write_path(path)
        .unwrap();
}

/// A 16-number row-major JSON matrix.
fn json_matrix(m: DMat4) -> String {
    let rows: Vec<String> = (0..4)
        .flat_map(|r| (0..4).map(move |c| (r, c)))
        .map(|(r, c)| format!("{}", m.col(c)[r]))
        .collect();
    format!("[{}]", rows.join(", "))
}

// ---------------------------------------------------------------------------------------------
// Depth range, map topology, tiny rooms, grazing views
// ---------------------------------------------------------------------------------------------

/// A vertical concave corner: two walls meeting at 90° along the vertical line through
/// `corner`, opening towards the sensor at the origin (each wall seen at 45°), `len` long from
/// the corner along directions (1, ±1)/√2 rotated by `turn`, `height` tall, centred on z = 0.
fn v_corner(corner: DVec3, turn: f64, len: [f64; 2], height: f64) -> [Prim; 2] {
    let r = DMat3::from_rotation_z(turn);
    let h = DVec3::new(0.0, 0.0, height);
    let wall = |d: DVec3, n: DVec3, l: f64| {
        Prim::quad_facing(corner + r * d * (0.5 * l), r * d * l, h, r * n)
    };
    let s = std::f64::consts::FRAC_1_SQRT_2;
    [
        wall(DVec3::new(s, -s, 0.0), DVec3::new(s, s, 0.0), len[0]),
        wall(DVec3::new(s, s, 0.0), DVec3::new(s, -s, 0.0), len[1]),
    ]
}

/// One equirect scan sees a small concave corner whose edge is 8 cm from the sensor (walls
/// 5.7 cm away at their nearest) and a concave building corner 500 m away (walls 150 m long,
/// 200 m tall); one near wall hides part of a far wall, so neighbouring pixels jump in depth
/// by more than 10⁴. Every AO is finite and in [0, 1] with the default radius (set by the far
/// corner, ~10 m, so the near walls are inside the sphere) and with radii suited to either
/// structure; at each scale the open parts of the walls read at least as bright as the corner.
#[test]
fn depth_ratio_ten_thousand() {
    let near_c = DVec3::new(0.0, 0.08, 0.0);
    let far_c = DVec3::new(-500.0, 0.0, 0.0);
    let [n1, n2] = v_corner(near_c, -std::f64::consts::FRAC_PI_2, [0.096, 0.07], 0.08);
    let [f1, f2] = v_corner(far_c, 0.0, [150.0, 150.0], 200.0);
    let scene = Scene {
        prims: vec![n1, n2, f1, f2],
    };
    // The data spans azimuths 30°..195°: the map's seam (local −x) looks at world az −70°.
    let mut st = Station::equirect(DVec3::ZERO, 110f64.to_radians(), 720, 360);
    st.max_range = 1000.0;
    let scans = [scan(&scene, &st, "depths")];
    let s = &scans[0];
    let near = |p: DVec3| p.length() < 1.0;
    let zeros = vec![0.0; s.len()];
    let (nn, nf) = (
        mean_where(s, &zeros, near).1,
        mean_where(s, &zeros, |p| !near(p)).1,
    );
    assert!(nn > 5000 && nf > 1000, "near {nn}, far {nf} points");

    let mut f = Fails::default();
    // The native grid is the map, and some neighbouring pixels jump in depth by > 10³.
    let c = run(&scans, &params(Estimator::Paper, Some(0.01), None), "grid");
    let v = &c.scans[0].view;
    assert!(v.sensor.grid_pixels.is_some(), "{}", v.sensor.reason);
    let (w, d) = (v.gbuf.width, &v.gbuf.depth);
    let jumps = (0..d.len() - 1)
        .filter(|&i| (i + 1) % w != 0 && d[i].is_finite() && d[i + 1].is_finite())
        .filter(|&i| d[i].max(d[i + 1]) > 1e3 * d[i].min(d[i + 1]))
        .count();
    assert!(
        jumps >= 10,
        "only {jumps} depth jumps of 10³ between neighbours"
    );
    for est in BOTH {
        // Default radius (robust diagonal and point spacing).
        run_twice(
            &scans,
            &params(est, None, None),
            &format!("{est:?} default"),
        );
        // Near scale.
        let c = run(&scans, &params(est, Some(0.01), None), "near scale");
        let ao = &c.scans[0].ao;
        let hd = |p: DVec3| (p - near_c).truncate().length();
        let corner = mean_of(s, ao, 20, |p| near(p) && hd(p) < 0.006);
        let open = mean_of(s, ao, 100, |p| {
            near(p) && p.z.abs() < 0.02 && hd(p) > 0.03 && hd(p) < 0.05
        });
        f.check(open >= corner, || {
            format!("{est:?} near: open walls {open} < corner {corner}")
        });
        // Far scale.
        let c = run(&scans, &params(est, Some(40.0), None), "far scale");
        let ao = &c.scans[0].ao;
        let hd = |p: DVec3| (p - far_c).truncate().length();
        let corner = mean_of(s, ao, 10, |p| !near(p) && p.z.abs() < 50.0 && hd(p) < 15.0);
        let open = mean_of(s, ao, 50, |p| {
            !near(p) && p.z.abs() < 50.0 && p.y < 0.0 && hd(p) > 60.0 && hd(p) < 100.0
        });
        f.check(open >= corner, || {
            format!("{est:?} far: open walls {open} < corner {corner}")
        });
    }
    f.finish();
}

/// A terrestrial scanner inside a box room, full sphere (rows reach the poles), with the
/// azimuth seam 4° beside a vertical room corner.
/// - Seam: the same scanner turned by exactly 90° (100 columns of 400) sees the same points
///   in the middle of its map; the AO of the two columns on each side of the seam matches the
///   AO of those points mid-map (mean |Δ| < 0.03: the disk, the march and the blur wrap
///   around), and the mean jump between the first and last column is no larger than twice the
///   jump between neighbouring columns beside the seam (+0.01).
/// - Poles: the pole rows (ceiling straight above, floor straight below, both open flat areas
///   far from walls) read like the rows 3–7 pixels away (mean |Δ| < 0.05; from row 3 to row
///   8 the mean changes by ~0.02).
/// - The same points ungridded, plus one point exactly at the nadir and one exactly at the
///   zenith: every value finite, the nadir point reads like the floor around it (within 0.15).
/// - A scan whose data lies only around the seam (a partial view straddling columns 0 and
///   w−1, e.g. a facade behind the scanner) keeps its native grid as the map.
#[test]
fn equirect_poles_and_seam() {
    let scene = room_scene();
    let pos = DVec3::new(0.3, -0.2, 1.2);
    // Local −x (the seam) 4° beside the room corner (−2, −1.5).
    let to_corner = DVec2::new(-2.0, -1.5) - pos.truncate();
    let yaw = to_corner.y.atan2(to_corner.x) + std::f64::consts::PI + 4f64.to_radians();
    let (w, h) = (400usize, 200usize);
    let a = scan(&scene, &Station::equirect(pos, yaw, w, h), "seam");
    let b = scan(
        &scene,
        &Station::equirect(pos, yaw + std::f64::consts::FRAC_PI_2, w, h),
        "mid",
    );
    let shift = w / 4;
    let mut f = Fails::default();
    for est in BOTH {
        let ca = run_twice(
            std::slice::from_ref(&a),
            &params(est, Some(0.2), None),
            "seam",
        );
        let cb = run(
            std::slice::from_ref(&b),
            &params(est, Some(0.2), None),
            "mid",
        );
        let (ra, rb) = (&ca.scans[0], &cb.scans[0]);
        let (ga, gb) = (&ra.view.gbuf, &rb.view.gbuf);
        assert_eq!((ga.width, ga.height), (w, h), "native grid kept");
        assert!(ra.view.sensor.projection.wrap_x, "full circle must wrap");
        let at = |r: &pipeline::ScanResult, x: usize, y: usize| -> Option<f32> {
            let p = r.view.gbuf.point[y * w + x];
            (p != u32::MAX).then(|| r.ao[p as usize])
        };
        // The same pixel rays see the same points.
        for y in (0..h).step_by(7) {
            for x in [0, 1, w - 2, w - 1] {
                let (pa, pb) = (ga.point[y * w + x], gb.point[y * w + (x + shift) % w]);
                if pa == u32::MAX || pb == u32::MAX {
                    continue;
                }
                let wa = a.pose.transform_point3(a.points[pa as usize].as_dvec3());
                let wb = b.pose.transform_point3(b.points[pb as usize].as_dvec3());
                assert!(wa.distance(wb) < 1e-3, "{wa} vs {wb}");
            }
        }
        // Seam columns vs the same points mid-map.
        let (mut d_mid, mut n_mid) = (0.0f32, 0usize);
        let (mut d_seam, mut d_beside, mut n_seam) = (0.0f32, 0.0f32, 0usize);
        for y in 2..h - 2 {
            for x in [w - 2, w - 1, 0, 1] {
                if let (Some(u), Some(v)) = (at(ra, x, y), at(rb, (x + shift) % w, y)) {
                    d_mid += (u - v).abs();
                    n_mid += 1;
                }
            }
            if let (Some(l), Some(f), Some(f1), Some(f2), Some(l1), Some(l2)) = (
                at(ra, w - 1, y),
                at(ra, 0, y),
                at(ra, 1, y),
                at(ra, 2, y),
                at(ra, w - 2, y),
                at(ra, w - 3, y),
            ) {
                d_seam += (l - f).abs();
                d_beside += 0.5 * ((f1 - f2).abs() + (l1 - l2).abs());
                n_seam += 1;
            }
        }
        assert!(n_mid > 500 && n_seam > 150, "{n_mid} {n_seam}");
        let (d_mid, d_seam, d_beside) = (
            d_mid / n_mid as f32,
            d_seam / n_seam as f32,
            d_beside / n_seam as f32,
        );
        f.check(d_mid < 0.03, || {
            format!("{est:?}: seam columns differ from the same points mid-map by {d_mid}")
        });
        f.check(d_seam <= 2.0 * d_beside + 0.01, || {
            format!("{est:?}: jump across the seam {d_seam} vs beside it {d_beside}")
        });
        // Pole rows vs their neighbours.
        for (pole, next) in [(0usize, 3..8usize), (h - 1, h - 8..h - 3)] {
            let row = |y: usize| (0..w).filter_map(move |x| at(ra, x, y));
            let vp: Vec<f32> = row(pole).collect();
            let vn: Vec<f32> = next.clone().flat_map(row).collect();
            assert!(vp.len() == w && !vn.is_empty(), "pole row {pole} not full");
            let (mp, mn) = (mean(&vp), mean(&vn));
            f.check((mp - mn).abs() < 0.05, || {
                format!("{est:?}: pole row {pole} reads {mp}, rows {next:?} read {mn}")
            });
        }
    }

    // Ungridded, with points exactly at the poles.
    let mut pts = a.points.clone();
    let (nadir, zenith) = (Vec3::new(0.0, 0.0, -1.2), Vec3::new(0.0, 0.0, 1.3));
    pts.push(nadir);
    pts.push(zenith);
    let mut u = Scan::from_points("ungridded", pts);
    u.pose = a.pose;
    for est in BOTH {
        let c = run_twice(
            std::slice::from_ref(&u),
            &params(est, Some(0.2), None),
            "ungridded poles",
        );
        let r = &c.scans[0];
        assert_eq!(
            r.view.sensor.projection.sensor_model(),
            SensorModel::Equirect
        );
        let k = u.len() - 2;
        let around = mean_of(&u, &r.ao, 10, |p| {
            p.z.abs() < 1e-3 && (p.truncate() - pos.truncate()).length() < 0.15
        });
        f.check((r.ao[k] - around).abs() < 0.15, || {
            format!(
                "{est:?}: nadir point (ungridded) {} vs floor around it {around}",
                r.ao[k]
            )
        });
    }

    // Data only around the seam: a wall behind the scanner (local −x), nothing else.
    let wall = Scene {
        prims: vec![Prim::quad_facing(
            DVec3::new(-5.0, 0.0, 0.0),
            DVec3::new(0.0, 4.0, 0.0),
            DVec3::new(0.0, 0.0, 2.0),
            DVec3::X,
        )],
    };
    let behind = scan(&wall, &Station::equirect(DVec3::ZERO, 0.0, w, h), "behind");
    let cols: Vec<u32> = behind.grid.as_ref().unwrap().col.clone();
    assert!(cols.contains(&0) && cols.contains(&(w as u32 - 1)));
    let c = run_twice(
        std::slice::from_ref(&behind),
        &params(Estimator::Paper, Some(0.2), None),
        "behind",
    );
    let v = &c.scans[0].view;
    f.check(v.sensor.grid_pixels.is_some(), || {
        format!(
            "native grid straddling the seam not kept: {} (fit {:?})",
            v.sensor.reason, v.sensor.fit_rms_px
        )
    });
    f.finish();
}

/// A 0.4 m cube closet with the scanner in its middle: every AO finite; its floor (all of it
/// within 0.2 m of a wall) reads darker on average than the same patch of an open floor
/// scanned from the same height.
#[test]
fn scanner_in_tiny_closet() {
    let closet = Scene {
        prims: box_room(DVec3::new(-0.2, -0.2, 0.0), DVec3::new(0.2, 0.2, 0.4)),
    };
    let open = Scene {
        prims: vec![floor()],
    };
    let st = Station::equirect(DVec3::new(0.0, 0.0, 0.2), 0.1, 320, 160);
    let sc = scan(&closet, &st, "closet");
    let so = scan(&open, &st, "open");
    assert!(sc.len() == 320 * 160, "the closed closet fills the map");
    run_twice(
        std::slice::from_ref(&sc),
        &params(Estimator::Paper, None, None),
        "closet default radius",
    );
    let patch = |p: DVec3| p.z.abs() < 1e-4 && p.x.abs() < 0.19 && p.y.abs() < 0.19;
    for est in BOTH {
        let p = params(est, Some(0.1), None);
        let cc = run(std::slice::from_ref(&sc), &p, "closet");
        let co = run(std::slice::from_ref(&so), &p, "open floor");
        let mc = mean_of(&sc, &cc.scans[0].ao, 1000, patch);
        let mo = mean_of(&so, &co.scans[0].ao, 1000, patch);
        assert!(
            mc < mo - 0.02,
            "{est:?}: closet floor {mc} not darker than open floor {mo}"
        );
    }
}

/// Two cameras 2 mm above a floor look along it, so every point they see is at grazing
/// incidence (n·l < 0.1, down to ~0.002); their footprints overlap. With exact normals and
/// with normals estimated from the grid: AO finite, and the zero-weight counter is consistent:
/// at most the number of points, every counted point kept its own SSAO (so at least that many
/// points have `ao == ssao` bit for bit), and the counters are reproducible.
#[test]
fn grazing_views() {
    let scene = Scene {
        prims: vec![floor()],
    };
    let h = 0.002;
    let sa = Station::perspective(
        DVec3::new(-0.5, 0.0, h),
        DVec3::new(1.0, 0.0, h),
        60f64.to_radians(),
        240,
        40,
    );
    let sb = Station::perspective(
        DVec3::new(0.0, -0.5, h),
        DVec3::new(0.0, 1.0, h),
        60f64.to_radians(),
        240,
        40,
    );
    let a = scan(&scene, &sa, "graze_a");
    let b = scan(&scene, &sb, "graze_b");
    for s in [&a, &b] {
        assert!(s.len() > 2000, "{} sees {} points", s.name, s.len());
        let st = if s.name == "graze_a" { sa } else { sb };
        let worst = s
            .points
            .iter()
            .map(|p| {
                let w = s.pose.transform_point3(p.as_dvec3());
                (st.position - w).normalize().z
            })
            .fold(0.0f64, f64::max);
        assert!(worst < 0.1, "{}: n·l up to {worst}", s.name);
    }
    let mut a_est = a.clone();
    let mut b_est = b.clone();
    a_est.normals = None;
    b_est.normals = None;
    for (scans, what) in [([a, b], "exact normals"), ([a_est, b_est], "estimated")] {
        for est in BOTH {
            let c = run_twice(&scans, &params(est, Some(0.02), None), what);
            for (r, s) in c.scans.iter().zip(&scans) {
                let kept =
                    r.ao.iter()
                        .zip(&r.ssao)
                        .filter(|(x, y)| x.to_bits() == y.to_bits())
                        .count() as u64;
                assert!(
                    r.merge.zero_weight <= kept,
                    "{what} {est:?} {}: {} zero-weight points but only {kept} kept their SSAO",
                    s.name,
                    r.merge.zero_weight
                );
                assert!(
                    r.merge.point_views <= 2 * s.len() as u64,
                    "{what} {est:?}: {:?}",
                    r.merge
                );
                assert!(r.merge.samples_kept <= r.merge.point_views);
            }
        }
    }
}

/// Two orthographic strips of a floor with a box overlap only over x ∈ [−0.2, 0.2]. Points of
/// one strip the other never sees (|x| > 0.25) get exactly their own SSAO (within 1e-6); the
/// overlap does take samples from the other view.
#[test]
fn point_seen_by_no_other_scan() {
    let scene = Scene {
        prims: vec![
            floor(),
            Prim::Box {
                min: DVec3::new(-0.1, -0.2, 0.0),
                max: DVec3::new(0.1, 0.2, 0.3),
            },
        ],
    };
    let half = DVec2::new(1.1, 1.0);
    let a = ortho(&scene, DVec2::new(-0.9, 0.0), 0.0, half, "left");
    let b = ortho(
        &scene,
        DVec2::new(0.9, 0.0),
        std::f64::consts::PI,
        half,
        "right",
    );
    let scans = [a, b];
    for est in BOTH {
        let c = run_twice(&scans, &params(est, Some(0.1), None), "strips");
        for (k, (r, s)) in c.scans.iter().zip(&scans).enumerate() {
            let sign = if k == 0 { -1.0 } else { 1.0 };
            let mut n = 0;
            for (i, p) in s.points.iter().enumerate() {
                let w = s.pose.transform_point3(p.as_dvec3());
                if w.x * sign > 0.25 {
                    n += 1;
                    assert!(
                        (r.ao[i] - r.ssao[i]).abs() <= 1e-6,
                        "{est:?} {}: point at {w} seen only here: ao {} vs own ssao {}",
                        s.name,
                        r.ao[i],
                        r.ssao[i]
                    );
                }
            }
            assert!(n > 10_000, "{n}");
            assert!(
                r.merge.samples_kept > s.len() as u64,
                "{est:?} {}: no sample from the other view: {:?}",
                s.name,
                r.merge
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Radius and falloff extremes
// ---------------------------------------------------------------------------------------------

/// `--radius 1e-6` m: the sampling disk is far below a pixel, so no sample is valid: every
/// point keeps a = 1 (merged too) and every point is counted in `no_sample` (t_max = 2·radius,
/// so the horizon estimator's march is sub-pixel as well).
#[test]
fn radius_sub_pixel() {
    let s = room_scan();
    for est in BOTH {
        let c = run_twice(
            std::slice::from_ref(&s),
            &params(est, Some(1e-6), None),
            "radius 1e-6",
        );
        let r = &c.scans[0];
        assert_eq!(
            r.no_sample,
            s.len() as u64,
            "{est:?}: every point must be flagged"
        );
        assert!(r.ssao.iter().all(|&a| a >= 1.0 - 1e-6), "{est:?}");
        assert!(r.ao.iter().all(|&a| a >= 1.0 - 1e-6), "{est:?}");
    }
}

/// `--radius 1e3` m (t_max 2e3 m) in a 4 × 3 m room: the disk covers the whole map. Every AO
/// finite and in [0, 1]; the horizon estimator (plain ambient occlusion when t_max is this
/// large) reads the middle of the floor brighter than the floor along the walls.
#[test]
fn radius_larger_than_scene() {
    let s = room_scan();
    for est in BOTH {
        let c = run_twice(
            std::slice::from_ref(&s),
            &params(est, Some(1e3), None),
            "radius 1e3",
        );
        if est == Estimator::Horizon {
            let ao = &c.scans[0].ao;
            let on_floor = |p: DVec3| p.z.abs() < 1e-4;
            let mid = mean_of(&s, ao, 500, |p| {
                on_floor(p) && p.x.abs() < 0.8 && p.y.abs() < 0.6
            });
            let edge = mean_of(&s, ao, 200, |p| {
                on_floor(p) && (p.x.abs() > 1.9 || p.y.abs() > 1.4)
            });
            assert!(mid > edge, "floor middle {mid} vs along the walls {edge}");
        }
    }
}

/// `t_max` → 1e-9 m and 1e9 m (radius 0.2 m) on a floor meeting a 3 m wall, scanner 1.5 m
/// from the wall:
/// - 1e-9: ρ = 1 for every occluder, so the obscurance is 1 everywhere: the horizon estimator
///   reads ≥ 0.99 on average, and the paper estimator reads an open floor ≈ 1 (tangent samples
///   weigh 1, > 0.95) and the corner below it;
/// - 1e9: ρ ≈ 0 in range, so the obscurance is plain ambient occlusion: the horizon estimator
///   reads the floor 2.2–3 m from the wall within 0.08 of the analytic value for a 3 m wall,
///   `½ + ½·D/√(D² + H²)` (≈ 0.82; the default 8 × 8 budget, eight steps over half a great
///   circle, reads ≈ 0.89, and 16 × 32 within 0.03), and the corner (≈ 0.5) at least 0.1
///   darker; the paper estimator
///   (eq. 3–5 multiply every sample by ρ) reads ≈ 0 everywhere (< 0.01) — its documented bias
///   at its extreme.
#[test]
fn tmax_tiny_and_huge() {
    let s = corner_scan();
    let one = std::slice::from_ref(&s);
    let mut f = Fails::default();
    // Tiny.
    let c = run_twice(
        one,
        &params(Estimator::Horizon, Some(0.2), Some(1e-9)),
        "tmax 1e-9",
    );
    let m = mean(&c.scans[0].ao);
    f.check(m >= 0.99, || format!("horizon, t_max 1e-9: mean {m}"));
    let c = run(
        one,
        &params(Estimator::Paper, Some(0.2), Some(1e-9)),
        "tmax",
    );
    let ao = &c.scans[0].ao;
    let (corner, open) = (
        mean_of(&s, ao, 100, near_corner),
        mean_of(&s, ao, 100, open_floor),
    );
    f.check(open > 0.95, || {
        format!("paper, t_max 1e-9: open floor {open}")
    });
    f.check(corner < open, || {
        format!("paper, t_max 1e-9: corner {corner}, open {open}")
    });
    // Huge.
    let c = run_twice(
        one,
        &params(Estimator::Horizon, Some(0.2), Some(1e9)),
        "tmax 1e9",
    );
    let ao = &c.scans[0].ao;
    let plain: Vec<f32> = s
        .points
        .iter()
        .map(|p| {
            let d = -s.pose.transform_point3(p.as_dvec3()).x;
            (0.5 + 0.5 * d / (d * d + 9.0).sqrt()) as f32
        })
        .collect();
    let expected = mean_of(&s, &plain, 100, open_floor);
    let (corner, open) = (
        mean_of(&s, ao, 100, near_corner),
        mean_of(&s, ao, 100, open_floor),
    );
    f.check((open - expected).abs() < 0.08, || {
        format!("horizon, t_max 1e9: open floor {open}, plain AO {expected}")
    });
    // A larger budget converges to it.
    let big = ComputeParams {
        directions: 16,
        steps: 32,
        ..params(Estimator::Horizon, Some(0.2), Some(1e9))
    };
    let c = run(one, &big, "tmax 1e9, 16 × 32");
    let open_big = mean_of(&s, &c.scans[0].ao, 100, open_floor);
    eprintln!("t_max 1e9: open floor {open} at 8 × 8, {open_big} at 16 × 32, plain AO {expected}");
    f.check((open_big - expected).abs() < 0.03, || {
        format!("horizon, t_max 1e9, 16 × 32: open floor {open_big}, plain AO {expected}")
    });
    f.check(corner < open - 0.1, || {
        format!("horizon, t_max 1e9: corner {corner}, open {open}")
    });
    let c = run(one, &params(Estimator::Paper, Some(0.2), Some(1e9)), "tmax");
    let m = mean(&c.scans[0].ao);
    f.check(m < 0.01, || format!("paper, t_max 1e9: mean {m}"));
    f.finish();
}

// ---------------------------------------------------------------------------------------------
// Degenerate point sets
// ---------------------------------------------------------------------------------------------

/// Ungridded scans whose PCA is degenerate: 2000 points on a line (not through the sensor),
/// 100 × 100 points on a plane under the sensor, and a plane through the sensor (seen exactly
/// edge-on). The first two are valid scans: `compute` succeeds with the default radius, every
/// AO finite and in [0, 1], every normal finite and unit. The edge-on plane may be refused with
/// a clean error, never a panic.
#[test]
fn collinear_and_coplanar_points() {
    let line: Vec<Vec3> = (0..2000)
        .map(|i| {
            let t = i as f32 / 1999.0;
            Vec3::new(1.0 + 2.0 * t, -1.0 + 2.0 * t, -1.0)
        })
        .collect();
    let plane: Vec<Vec3> = (0..100 * 100)
        .map(|i| {
            Vec3::new(
                (i % 100) as f32 * 0.02 - 1.0,
                (i / 100) as f32 * 0.02 - 1.0,
                -1.0,
            )
        })
        .collect();
    let edge_on: Vec<Vec3> = (0..100 * 100)
        .map(|i| {
            Vec3::new(
                (i % 100) as f32 * 0.02 + 0.5,
                (i / 100) as f32 * 0.02 - 1.0,
                0.0,
            )
        })
        .collect();
    for (name, pts) in [("line", line), ("plane", plane)] {
        let s = Scan::from_points(name, pts);
        for est in BOTH {
            let c = run_twice(std::slice::from_ref(&s), &params(est, None, None), name);
            let g = &c.scans[0].view.gbuf;
            for (i, n) in g.normal.iter().enumerate() {
                if g.is_valid(i) {
                    assert!(
                        n.is_finite() && (n.length() - 1.0).abs() < 1e-3,
                        "{name}: normal {n}"
                    );
                }
            }
        }
    }
    let s = Scan::from_points("edge_on", edge_on);
    for est in BOTH {
        match pipeline::compute(std::slice::from_ref(&s), &params(est, None, None), &Silent) {
            Ok(c) => assert_ao_ok(&c, std::slice::from_ref(&s), "edge-on plane"),
            Err(e) => assert_clean_err(&e, &["edge_on"], "edge-on plane"),
        }
    }
}

/// 40 × 40 floor points each stored 40 times (more copies than k = 32, so d_k = 0), and 1000
/// copies of one single point: radii are floored at a positive minimum (never 0, never NaN),
/// normals finite, every AO finite and in [0, 1]. The all-identical scan needs an explicit
/// radius (its extent is 0).
#[test]
fn duplicate_points() {
    let mut pts = Vec::new();
    for i in 0..40 * 40 {
        let p = Vec3::new(
            (i % 40) as f32 * 0.05 - 1.0,
            (i / 40) as f32 * 0.05 - 1.0,
            -1.0,
        );
        pts.extend(std::iter::repeat_n(p, 40));
    }
    let dup = Scan::from_points("dup", pts);
    let same = Scan::from_points("same", vec![Vec3::new(0.3, 0.2, -1.0); 1000]);
    let cases = [
        (&dup, None, "40 copies each"),
        (&dup, Some(0.2), "40 copies each, radius 0.2"),
        (&same, Some(0.1), "1000 copies of one point"),
    ];
    for (s, radius, what) in cases {
        for est in BOTH {
            let c = run_twice(std::slice::from_ref(s), &params(est, radius, None), what);
            let v = &c.scans[0].view;
            assert!(
                v.radii.iter().all(|&r| r.is_finite() && r > 0.0),
                "{what}: radius not positive"
            );
            for (i, n) in v.gbuf.normal.iter().enumerate() {
                if v.gbuf.is_valid(i) {
                    assert!(n.is_finite() && n.length() > 0.5, "{what}: normal {n}");
                }
            }
        }
    }
}

/// Scans of 1, 2, 5 and 20 points (fewer than k = 32 and, but for 20, fewer than the 16 PCA
/// neighbours): with an explicit radius `compute` succeeds, radii positive, every AO finite and
/// in [0, 1]; with the default radius it succeeds or fails with a clean error about the radius
/// (the extent of one point is 0).
#[test]
fn fewer_points_than_k() {
    for n in [1usize, 2, 5, 20] {
        let s = Scan::from_points(format!("n{n}"), scattered(n, 0.3, n as u64));
        for est in BOTH {
            let what = format!("{n} points {est:?}");
            let c = run_twice(
                std::slice::from_ref(&s),
                &params(est, Some(0.2), None),
                &what,
            );
            assert!(
                c.scans[0]
                    .view
                    .radii
                    .iter()
                    .all(|&r| r.is_finite() && r > 0.0),
                "{what}"
            );
            match pipeline::compute(std::slice::from_ref(&s), &params(est, None, None), &Silent) {
                Ok(c) => assert_ao_ok(&c, std::slice::from_ref(&s), &what),
                Err(e) => assert_clean_err(&e, &["radius"], &what),
            }
        }
    }
}

/// A scan with no point is truly broken: `compute` returns an error naming that scan (alone,
/// or next to a good scan; with or without an explicit radius), and the binary exits 2 with
/// one line naming the file.
#[test]
fn empty_scan() {
    let empty = Scan::from_points("empty_scan", Vec::new());
    let good = Scan::from_points("good", scattered(500, 0.5, 3));
    let mut f = Fails::default();
    for scans in [vec![empty.clone()], vec![good, empty]] {
        for radius in [None, Some(0.1)] {
            let what = format!("{} scan(s), radius {radius:?}", scans.len());
            match pipeline::compute(&scans, &params(Estimator::Paper, radius, None), &Silent) {
                Ok(_) => f.check(false, || format!("{what}: an empty scan was accepted")),
                Err(e) => f.check(e.to_string().contains("empty_scan"), || {
                    format!("{what}: error '{e}' does not name the empty scan")
                }),
            }
        }
    }
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("nothing.ply");
    write_ply(&p, &[], None);
    let out = d.path().join("out");
    let r = mvao(&[
        "merge",
        "-q",
        "-o",
        out.to_str().unwrap(),
        p.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(
        err.contains("nothing.ply") && !err.contains("panicked"),
        "{err}"
    );
    assert!(!out.join("nothing.mvao.ply").exists());
    f.finish();
}

/// A scan of one point: with an explicit radius it has no neighbour to sample, so it keeps
/// a = 1 and is flagged; with the default radius (extent 0) it succeeds or fails cleanly about
/// the radius.
#[test]
fn one_point_scan() {
    let s = Scan::from_points("one", vec![Vec3::new(0.2, 0.1, -1.0)]);
    for est in BOTH {
        let c = run_twice(
            std::slice::from_ref(&s),
            &params(est, Some(0.1), None),
            "one point",
        );
        let r = &c.scans[0];
        assert_eq!(r.no_sample, 1, "{est:?}");
        assert!(r.ao[0] >= 1.0 - 1e-6, "{est:?}: {}", r.ao[0]);
        match pipeline::compute(std::slice::from_ref(&s), &params(est, None, None), &Silent) {
            Ok(c) => assert_ao_ok(&c, std::slice::from_ref(&s), "one point, default radius"),
            Err(e) => assert_clean_err(&e, &["radius"], "one point, default radius"),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Merges without partners, with identical partners, without overlap, with zero weights
// ---------------------------------------------------------------------------------------------

/// A single scan merged with nothing but itself (N = 1): every point's MVAO equals its own
/// SSAO within 1e-6.
#[test]
fn single_scan_no_partners() {
    let s = room_scan();
    for est in BOTH {
        let c = run_twice(
            std::slice::from_ref(&s),
            &params(est, Some(0.2), None),
            "alone",
        );
        let r = &c.scans[0];
        let worst =
            r.ao.iter()
                .zip(&r.ssao)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
        assert!(worst <= 1e-6, "{est:?}: MVAO differs from SSAO by {worst}");
    }
}

/// A scan merged with an identical copy of itself (same points, same pose) gives the merge of
/// the scan alone within 1e-6, for N = 1 and N = 3, and the copy gets the same values.
#[test]
fn two_identical_scans() {
    let s = room_scan();
    let mut copy = s.clone();
    copy.name = "copy".into();
    let pair = [s.clone(), copy];
    for est in BOTH {
        for n in [1u32, 3] {
            let p = ComputeParams {
                neighbors: n,
                ..params(est, Some(0.2), None)
            };
            let alone = run(std::slice::from_ref(&s), &p, "alone");
            let both = run(&pair, &p, "pair");
            for k in 0..2 {
                let worst = alone.scans[0]
                    .ao
                    .iter()
                    .zip(&both.scans[k].ao)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0f32, f32::max);
                assert!(
                    worst <= 1e-6,
                    "{est:?} N={n} scan {k}: merge with a copy differs by {worst}"
                );
            }
        }
    }
}

/// Two scans whose boxes overlap but whose surfaces do not: scan A sees a floor with a box,
/// scan B a plane 0.5 m above it (in another world), both from above. Every point of A projects
/// onto B's plane, which fails the distance test, and vice versa: each point keeps its own
/// SSAO within 1e-6. The same holds for two scans 100 m apart (the pair is skipped).
#[test]
fn scans_with_no_overlap() {
    let floor_box = Scene {
        prims: vec![
            floor(),
            Prim::Box {
                min: DVec3::new(-0.2, -0.2, 0.0),
                max: DVec3::new(0.2, 0.2, 0.2),
            },
        ],
    };
    let high = Scene {
        prims: vec![
            Prim::Quad {
                center: DVec3::new(0.0, 0.0, 0.5),
                u: DVec3::new(4.0, 0.0, 0.0),
                v: DVec3::new(0.0, 4.0, 0.0),
            },
            Prim::Box {
                min: DVec3::new(0.3, 0.3, 0.5),
                max: DVec3::new(0.6, 0.6, 0.8),
            },
        ],
    };
    let half = DVec2::new(1.0, 1.0);
    let a = ortho(&floor_box, DVec2::ZERO, 0.0, half, "floor");
    let b = ortho(&high, DVec2::ZERO, 0.3, half, "high");
    let mut far = a.clone();
    far.name = "far".into();
    far.pose = DMat4::from_translation(DVec3::new(100.0, 0.0, 0.0)) * far.pose;
    for (scans, what) in [([a.clone(), b], "stacked"), ([a, far], "100 m apart")] {
        for est in BOTH {
            let c = run_twice(&scans, &params(est, Some(0.1), None), what);
            for (r, s) in c.scans.iter().zip(&scans) {
                let worst =
                    r.ao.iter()
                        .zip(&r.ssao)
                        .map(|(x, y)| (x - y).abs())
                        .fold(0.0f32, f32::max);
                assert!(
                    worst <= 1e-6,
                    "{what} {est:?} {}: MVAO differs from own SSAO by {worst}",
                    s.name
                );
            }
        }
    }
}

/// Two overlapping orthographic views whose every normal is perpendicular to the viewing
/// direction (so n·l = 0 for every view, and no stored point faces either sensor; input
/// normals are turned to face their own sensor, so "facing away" from every sensor is reached
/// at its limit, n·l = 0): every merge weight is zero, every point falls back to its own SSAO
/// bit for bit, and every point is counted in `zero_weight`.
#[test]
fn all_merge_weights_zero() {
    let scene = Scene {
        prims: vec![floor()],
    };
    let half = DVec2::new(0.8, 0.6);
    let mut a = ortho(&scene, DVec2::new(-0.3, 0.0), 0.0, half, "za");
    let mut b = ortho(&scene, DVec2::new(0.3, 0.0), 0.5, half, "zb");
    a.normals = Some(vec![Vec3::X; a.len()]);
    b.normals = Some(vec![Vec3::Y; b.len()]);
    let scans = [a, b];
    for est in BOTH {
        let c = run_twice(&scans, &params(est, Some(0.1), None), "zero weights");
        for (r, s) in c.scans.iter().zip(&scans) {
            assert_eq!(
                r.merge.zero_weight,
                s.len() as u64,
                "{est:?} {}: {:?}",
                s.name,
                r.merge
            );
            assert!(bits(&r.ao) == bits(&r.ssao), "{est:?} {}", s.name);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Poses
// ---------------------------------------------------------------------------------------------

/// Three scans of the synthetic room (equirect, 400 × 200) merged with their poses as scanned,
/// and again with every pose moved by (1e7, 1e7, 0) m (georeferenced coordinates; the
/// scan-local points are the same small numbers): every AO agrees within 1e-4.
#[test]
fn coordinates_near_ten_million() {
    let scans = room_site();
    let moved: Vec<Scan> = scans
        .iter()
        .map(|s| {
            let mut m = s.clone();
            m.pose = DMat4::from_translation(DVec3::new(1e7, 1e7, 0.0)) * s.pose;
            m
        })
        .collect();
    for est in BOTH {
        let p = params(est, Some(0.2), None);
        let c0 = run(&scans, &p, "at the origin");
        let c1 = run(&moved, &p, "at 1e7");
        for (k, (x, y)) in c0.scans.iter().zip(&c1.scans).enumerate() {
            let worst =
                x.ao.iter()
                    .zip(&y.ao)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0f32, f32::max);
            assert!(worst <= 1e-4, "{est:?} scan {k}: differs by {worst}");
            assert_eq!(x.merge.zero_weight, y.merge.zero_weight, "{est:?} scan {k}");
        }
    }
}

/// Three equirect stations of the built-in room at 400 × 200, with their poses.
fn room_site() -> Vec<Scan> {
    let scene = SceneKind::Room.scene();
    station_layout(SceneKind::Room, SensorModel::Equirect, 3, 400, 200)
        .iter()
        .enumerate()
        .map(|(i, st)| scan(&scene, st, &format!("station_{i}")))
        .collect()
}

fn rot_z(deg: f64) -> DMat3 {
    DMat3::from_rotation_z(deg.to_radians())
}

/// Poses whose rotation is orthonormal only up to printing precision (6 decimals, as in hand-
/// written alignment files) or a 5e-4 perturbation are accepted; `check_rigid` returns an
/// exactly orthonormal rotation near the input with the translation untouched. Through the
/// binary, a JSON alignment with such a pose runs (exit 0).
#[test]
fn tiny_non_orthogonality_accepted() {
    let path = Path::new("test.json");
    let t = DVec3::new(1.0, -2.0, 3.0);
    let r = rot_z(30.0) * DMat3::from_rotation_x(0.3);
    let rounded = DMat3::from_cols_array(&r.to_cols_array().map(|v| (v * 1e6).round() / 1e6));
    let mut perturbed = r;
    perturbed.x_axis.y += 5e-4;
    for (m, what) in [(rounded, "6 decimals"), (perturbed, "5e-4")] {
        let pose = DMat4::from_mat3_translation(m, t);
        let out = check_rigid(pose, path, what).unwrap_or_else(|e| panic!("{what}: {e}"));
        let q = DMat3::from_mat4(out);
        let dev = (q.transpose() * q - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(dev < 1e-12, "{what}: result not orthonormal ({dev})");
        assert!((q.determinant() - 1.0).abs() < 1e-12);
        assert!(out.w_axis.truncate() == t, "{what}: translation changed");
        assert!(out.abs_diff_eq(pose, 1e-3), "{what}: moved too far");
        assert_eq!(out.row(3), glam::DVec4::W);
    }
    // Through the binary.
    let d = tempfile::tempdir().unwrap();
    let scan_p = d.path().join("dome.ply");
    write_ply(&scan_p, &dome(3000), None);
    let al = d.path().join("align.json");
    let pose = DMat4::from_mat3_translation(rounded, t);
    std::fs::write(&al, format!("{{\"dome.ply\": {}}}", json_matrix(pose))).unwrap();
    let out = d.path().join("out");
    let r = mvao(&[
        "merge",
        "-q",
        "--no-preview",
        "--align",
        al.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        scan_p.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(out.join("dome.mvao.ply").is_file());
}

/// Poses with scale (1 %, and 2×), shear (0.01) or a reflection are refused by `check_rigid`
/// with a message saying so; through the binary a JSON alignment with a scaled pose exits 2
/// with one line naming the alignment file and writes nothing.
#[test]
fn scale_or_shear_rejected() {
    let path = Path::new("bad.json");
    let r = rot_z(20.0);
    let t = DVec3::new(0.5, 0.5, 0.0);
    let mut shear = r;
    shear.y_axis.x += 0.01;
    let cases = [
        (r * 1.01, "scale or shear"),
        (r * 2.0, "scale or shear"),
        (shear, "scale or shear"),
        (
            r * DMat3::from_diagonal(DVec3::new(1.0, 1.0, -1.0)),
            "reflection",
        ),
    ];
    for (m, needle) in cases {
        let e = check_rigid(DMat4::from_mat3_translation(m, t), path, "s")
            .expect_err("a non-rigid pose must be refused");
        assert!(e.to_string().contains(needle), "{e}");
        assert!(e.to_string().contains("bad.json"), "{e}");
    }
    let d = tempfile::tempdir().unwrap();
    let scan_p = d.path().join("dome.ply");
    write_ply(&scan_p, &dome(2000), None);
    let al = d.path().join("scaled.json");
    let pose = DMat4::from_mat3_translation(r * 2.0, t);
    std::fs::write(&al, format!("{{\"dome.ply\": {}}}", json_matrix(pose))).unwrap();
    let out = d.path().join("out");
    let res = mvao(&[
        "merge",
        "-q",
        "--align",
        al.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        scan_p.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&res.stderr);
    assert_eq!(res.status.code(), Some(2), "{err}");
    assert!(
        err.contains("scaled.json") && err.contains("scale or shear"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(!out.join("dome.mvao.ply").exists());
}

// ---------------------------------------------------------------------------------------------
// Non-finite input through the binary
// ---------------------------------------------------------------------------------------------

/// A PLY whose vertices include NaN, +Inf and −Inf coordinates, and (on other, finite
/// vertices) NaN, infinite and zero-length normals. Through the binary: exit 0; the report
/// counts the skipped vertices and the processed points; its `normals` string says how many
/// normals were re-estimated; the output holds exactly the finite vertices, every `ao` finite
/// and in [0, 1], no non-finite coordinate.
#[test]
fn nan_inf_coordinates_and_normals() {
    let n = 4000;
    let mut pts = dome(n);
    let mut nrm: Vec<[f64; 3]> = pts
        .iter()
        .map(|p| {
            let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            [-p[0] / l, -p[1] / l, -p[2] / l]
        })
        .collect();
    let bad_xyz = [10usize, 11, 500, 1999, 3998];
    pts[10][0] = f64::NAN;
    pts[11][1] = f64::INFINITY;
    pts[500][2] = f64::NEG_INFINITY;
    pts[1999] = [f64::NAN; 3];
    pts[3998][2] = f64::NAN;
    let bad_n = [20usize, 21, 22, 700, 701, 3000];
    nrm[20] = [f64::NAN, 0.0, 1.0];
    nrm[21] = [0.0; 3];
    nrm[22] = [f64::INFINITY, 0.0, 0.0];
    nrm[700] = [0.0; 3];
    nrm[701] = [f64::NAN; 3];
    nrm[3000] = [0.0; 3];
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("holes.ply");
    write_ply(&p, &pts, Some(&nrm));
    let out = d.path().join("out");
    let r = mvao(&[
        "merge",
        "-q",
        "--no-preview",
        "-o",
        out.to_str().unwrap(),
        p.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let rep = report(&out);
    let s = &rep["scans"][0];
    assert_eq!(s["vertices"], n, "{s}");
    assert_eq!(s["skipped_nonfinite"], bad_xyz.len(), "{s}");
    assert_eq!(s["points"], n - bad_xyz.len(), "{s}");
    let note = s["normals"].as_str().unwrap_or_default();
    assert!(
        note.contains(&format!("{} re-estimated", bad_n.len())),
        "normals note: {note}"
    );
    for k in ["ao_min", "ao_mean", "ao_max"] {
        let v = s[k].as_f64().unwrap_or(f64::NAN);
        assert!(v.is_finite() && (0.0..=1.0).contains(&v), "{k} = {v}");
    }
    let res = PlyFile::from_path(&out.join("holes.mvao.ply")).unwrap();
    let ao = res.scalar_column("vertex", "ao").unwrap();
    assert_eq!(ao.len(), n - bad_xyz.len());
    assert!(ao.iter().all(|a| a.is_finite() && (0.0..=1.0).contains(a)));
    let xyz = res.vertex_xyz().unwrap();
    assert!(xyz.iter().all(|p| p.iter().all(|v| v.is_finite())));
}

// ---------------------------------------------------------------------------------------------
// Determinism of a heavier case
// ---------------------------------------------------------------------------------------------

/// The three-station room merge (≈ 240 k points), with both estimators and N = 3, gives the
/// same bits twice.
#[test]
fn stability_cases_are_deterministic() {
    let scans = room_site();
    for est in BOTH {
        let p = ComputeParams {
            neighbors: 3,
            ..params(est, None, None)
        };
        run_twice(&scans, &p, "room site");
    }
}

/// Points bunched in two tiny patches at opposite poles of a scanner placed between them (a
/// guessed scanner position a million metres off) would ask for a 16384×8192 map; the map is
/// capped at a few pixels per point, and so is a native grid declaring far more cells than
/// points.
#[test]
fn bunched_points_and_sparse_grids_keep_maps_small() {
    use mvao::testing::scan::Grid;
    use mvao::testing::sensor::{setup, ProjectionChoice};
    let mut pts = scattered(16_000, 5.0, 3);
    for p in pts.iter_mut() {
        p.z -= 1.0e6;
    }
    pts.extend((0..4000).map(|k| Vec3::new(0.001 * k as f32, 0.0, 1.0e6)));
    let n = pts.len();
    for choice in [
        ProjectionChoice::Auto,
        ProjectionChoice::Equirect,
        ProjectionChoice::Perspective,
        ProjectionChoice::Ortho,
    ] {
        let s = Scan::from_points("bunched", pts.clone());
        let Ok(st) = setup(&s, choice) else {
            continue;
        };
        let px = st.projection.width * st.projection.height;
        assert!(px <= 4 * n + 1000, "{choice:?}: {px} pixels for {n} points");
    }
    let mut s = Scan::from_points("sparse_grid", scattered(5000, 5.0, 4));
    s.grid = Some(Grid {
        rows: 100_000,
        cols: 100_000,
        row: (0..5000).map(|k| k * 20).collect(),
        col: (0..5000).map(|k| k * 20).collect(),
    });
    let st = setup(&s, ProjectionChoice::Auto).expect("resampled");
    let px = st.projection.width * st.projection.height;
    assert!(px <= 70_000, "{px} pixels for 5000 points");
    assert!(st.reason.contains("resampled"), "{}", st.reason);
    // A scan that is mostly sky keeps its grid.
    let mut sky = Scan::from_points("sky", scattered(1000, 5.0, 5));
    sky.grid = Some(Grid {
        rows: 200,
        cols: 400,
        row: (0..1000).map(|k| k / 10).collect(),
        col: (0..1000).map(|k| k % 10).collect(),
    });
    let st = setup(&sky, ProjectionChoice::Auto).expect("sky");
    assert!(!st.reason.contains("far more cells"), "{}", st.reason);
}
