//! The ray-traced reference against closed-form obscurance on synthetic surfels and
//! triangles, its self-hit bias on a plane and a sphere, determinism, and bad input.
//!
//! Tolerances: with R cosine-weighted rays a point's estimate has a standard deviation of at
//! most 0.5/√R (less with the stratified sets); averaging k points divides it by √k. Every
//! bound below is at least four such deviations.

use glam::{DMat4, DVec3, Vec3};
use mvao::testing::reference::{
    self, obscurance, rho, triangulate_grid, triangulate_grid_seen, RefParams, Scene, SceneBuilder,
    View,
};
use mvao::testing::scan::Grid;

const INF: f32 = f32::INFINITY;

/// Surfels on a grid `origin + i·su·u + j·sv·v` (coordinate lists `us`, `vs`), facing `n`,
/// radius 0.75 × the diagonal of the local cell (adjacent gaps), so the grid is covered.
struct Sheet {
    p: Vec<Vec3>,
    n: Vec<Vec3>,
    r: Vec<f32>,
}

fn gaps(xs: &[f32], i: usize) -> f32 {
    let a = if i > 0 { xs[i] - xs[i - 1] } else { 0.0 };
    let b = if i + 1 < xs.len() {
        xs[i + 1] - xs[i]
    } else {
        0.0
    };
    a.max(b)
}

fn sheet(origin: Vec3, u: Vec3, v: Vec3, us: &[f32], vs: &[f32], n: Vec3) -> Sheet {
    let mut s = Sheet {
        p: Vec::new(),
        n: Vec::new(),
        r: Vec::new(),
    };
    for (j, &b) in vs.iter().enumerate() {
        for (i, &a) in us.iter().enumerate() {
            s.p.push(origin + u * a + v * b);
            s.n.push(n);
            s.r.push(0.75 * (gaps(us, i).powi(2) + gaps(vs, j).powi(2)).sqrt());
        }
    }
    s
}

/// `lo, lo + step, …, hi` (inclusive).
fn range(lo: f32, hi: f32, step: f32) -> Vec<f32> {
    let n = ((hi - lo) / step).round() as usize;
    (0..=n)
        .map(|k| lo + (hi - lo) * k as f32 / n as f32)
        .collect()
}

/// Coordinates from 0 to `extent`: steps of `fine` up to `near`, then growing by 10 % each.
fn graded(fine: f32, near: f32, extent: f32) -> Vec<f32> {
    let mut v = range(0.0, near, fine);
    let mut step = fine;
    while *v.last().unwrap() < extent {
        step *= 1.1;
        v.push(v.last().unwrap() + step);
    }
    v
}

fn symmetric(half: &[f32]) -> Vec<f32> {
    let mut v: Vec<f32> = half.iter().rev().map(|x| -x).collect();
    v.extend_from_slice(&half[1..]);
    v
}

fn add(b: &mut SceneBuilder, s: &Sheet) {
    b.add_surfels("sheet", DMat4::IDENTITY, &s.p, &s.n, &s.r)
        .unwrap();
}

fn mean(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64
}

fn prm(rays: u32, tmax: f32) -> RefParams {
    RefParams {
        rays,
        tmax,
        falloff: Default::default(),
        seed: 7,
    }
}

/// Obscurance of points on the floor z = 0 with normal +z and radius `r`.
fn floor_points(scene: &Scene, pts: &[Vec3], r: f32, p: &RefParams) -> Vec<f32> {
    let n = vec![Vec3::Z; pts.len()];
    let rad = vec![r; pts.len()];
    obscurance(scene, pts, &n, &rad, p, &|_| {}).unwrap()
}

/// A floor of 1 cm surfels over [-0.6, 0.6]².
fn floor() -> Sheet {
    let xs = range(-0.6, 0.6, 0.01);
    sheet(Vec3::ZERO, Vec3::X, Vec3::Y, &xs, &xs, Vec3::Z)
}

#[test]
fn open_plane_is_open() {
    let f = floor();
    let mut b = Scene::builder(DMat4::IDENTITY);
    add(&mut b, &f);
    let scene = b.build();
    // Query points are surfel centres themselves (their own disks are in the scene).
    let pts: Vec<Vec3> = f.p.iter().step_by(97).copied().collect();
    for tmax in [0.4, INF] {
        let a = floor_points(&scene, &pts, f.r[0], &prm(128, tmax));
        assert!(a.iter().all(|&x| x == 1.0), "t_max {tmax}: {:?}", &a[..5]);
    }
    // The same plane as triangles of its grid.
    let xs = range(-0.6, 0.6, 0.01);
    let (p, g) = grid_points(&xs, &xs, |x, y| Vec3::new(x, y, 0.0));
    // Seen from above (a grid seen from the origin, which lies in this plane, is edge-on).
    let tris = triangulate_grid_seen(&p, &g, View::Parallel(Vec3::Z)).unwrap();
    let mut b = Scene::builder(DMat4::IDENTITY);
    b.add_triangles("plane", DMat4::IDENTITY, &p, None, &tris)
        .unwrap();
    let scene = b.build();
    assert_eq!(scene.triangle_count(), 2 * 120 * 120);
    let a = floor_points(&scene, &pts, 0.01, &prm(128, 0.4));
    assert!(a.iter().all(|&x| x == 1.0));
}

fn grid_points(xs: &[f32], ys: &[f32], f: impl Fn(f32, f32) -> Vec3) -> (Vec<Vec3>, Grid) {
    let (mut p, mut row, mut col) = (Vec::new(), Vec::new(), Vec::new());
    for (r, &y) in ys.iter().enumerate() {
        for (c, &x) in xs.iter().enumerate() {
            p.push(f(x, y));
            row.push(r as u32);
            col.push(c as u32);
        }
    }
    let g = Grid {
        rows: ys.len() as u32,
        cols: xs.len() as u32,
        row,
        col,
    };
    (p, g)
}

/// `A` of a floor point at distance `h` from an infinite wall, falloff `tmax`:
/// by Malley's method `A = 1 − (1/π) ∫₀¹ (1 − ρ(h/x)) 2√(1 − x²) dx` (x = the direction's
/// component towards the wall); with `x = sin θ` the integrand `(1 − ρ(h/sin θ)) 2cos²θ` is
/// smooth, integrated by Simpson's rule.
fn wall_closed_form(h: f64, tmax: f64) -> f64 {
    let m = 20_000;
    let half_pi = std::f64::consts::FRAC_PI_2;
    let f = |th: f64| {
        // The limit x → 0⁺ at the end point (a ray along the wall meets it infinitely far).
        let x = th.sin().max(1e-12);
        (1.0 - rho((h / x) as f32, tmax as f32) as f64) * 2.0 * th.cos().powi(2)
    };
    let dt = half_pi / m as f64;
    let mut s = f(0.0) + f(half_pi);
    for k in 1..m {
        s += f(k as f64 * dt) * if k % 2 == 1 { 4.0 } else { 2.0 };
    }
    1.0 - s * dt / 3.0 / std::f64::consts::PI
}

#[test]
fn closed_form_of_the_wall_is_right() {
    assert!((wall_closed_form(0.1, f64::INFINITY) - 0.5).abs() < 1e-6);
    assert!((wall_closed_form(0.5, 0.4) - 1.0).abs() < 1e-9);
}

#[test]
fn floor_beside_an_infinite_wall_is_half_open() {
    // Wall x = h, graded from 2 mm cells near the foot to 1000 m away.
    let h = 0.05f32;
    let ys = symmetric(&graded(0.002, 0.2, 1000.0));
    let zs = graded(0.002, 0.2, 1000.0);
    let wall = sheet(
        Vec3::new(h, 0.0, 0.0),
        Vec3::Y,
        Vec3::Z,
        &ys,
        &zs,
        Vec3::NEG_X,
    );
    let f = floor();
    let mut b = Scene::builder(DMat4::IDENTITY);
    add(&mut b, &wall);
    add(&mut b, &f);
    let scene = b.build();
    let pts: Vec<Vec3> = (0..24)
        .map(|k| Vec3::new(0.0, -0.12 + 0.01 * k as f32, 0.0))
        .collect();
    let a = floor_points(&scene, &pts, f.r[0], &prm(256, INF));
    let m = mean(&a);
    // σ ≤ 0.5/√(24·256) = 0.0064.
    assert!((m - 0.5).abs() < 0.025, "surfels: {m}");
    // Triangles: two of them, 10 km wide.
    let mut b = Scene::builder(DMat4::IDENTITY);
    let v = [
        Vec3::new(h, -1e4, 0.0),
        Vec3::new(h, 1e4, 0.0),
        Vec3::new(h, 1e4, 1e4),
        Vec3::new(h, -1e4, 1e4),
    ];
    b.add_triangles("wall", DMat4::IDENTITY, &v, None, &[[0, 1, 2], [0, 2, 3]])
        .unwrap();
    let scene = b.build();
    let m = mean(&floor_points(&scene, &pts, 0.01, &prm(256, INF)));
    assert!((m - 0.5).abs() < 0.025, "triangles: {m}");
}

#[test]
fn floor_beside_a_wall_with_finite_tmax_matches_the_integral() {
    let tmax = 0.4f32;
    let ys = range(-0.8, 0.8, 0.004);
    let zs = range(0.0, 0.6, 0.004);
    let wall = sheet(Vec3::ZERO, Vec3::Y, Vec3::Z, &ys, &zs, Vec3::NEG_X);
    let xs = range(-0.6, 0.0, 0.005);
    let fl = sheet(
        Vec3::ZERO,
        Vec3::X,
        Vec3::Y,
        &xs,
        &range(-0.5, 0.5, 0.005),
        Vec3::Z,
    );
    let mut b = Scene::builder(DMat4::IDENTITY);
    add(&mut b, &wall);
    add(&mut b, &fl);
    let scene = b.build();
    for h in [0.02f32, 0.1, 0.2, 0.35, 0.45] {
        let pts: Vec<Vec3> = (0..32)
            .map(|k| Vec3::new(-h, -0.16 + 0.01 * k as f32, 0.0))
            .collect();
        let m = mean(&floor_points(&scene, &pts, fl.r[0], &prm(256, tmax)));
        let want = wall_closed_form(h as f64, tmax as f64);
        // σ ≤ 0.5/√(32·256) = 0.0055.
        assert!((m - want).abs() < 0.02, "h {h}: {m} vs {want}");
    }
}

/// The six inward faces of the box [-0.5, 0.5]² × [0, 1] as surfels (2 cm cells).
fn closed_box() -> Vec<Sheet> {
    let c = range(-0.5, 0.5, 0.02);
    let z = range(0.0, 1.0, 0.02);
    vec![
        sheet(Vec3::ZERO, Vec3::X, Vec3::Y, &c, &c, Vec3::Z),
        sheet(Vec3::Z, Vec3::X, Vec3::Y, &c, &c, Vec3::NEG_Z),
        sheet(Vec3::new(-0.5, 0.0, 0.0), Vec3::Y, Vec3::Z, &c, &z, Vec3::X),
        sheet(
            Vec3::new(0.5, 0.0, 0.0),
            Vec3::Y,
            Vec3::Z,
            &c,
            &z,
            Vec3::NEG_X,
        ),
        sheet(Vec3::new(0.0, -0.5, 0.0), Vec3::X, Vec3::Z, &c, &z, Vec3::Y),
        sheet(
            Vec3::new(0.0, 0.5, 0.0),
            Vec3::X,
            Vec3::Z,
            &c,
            &z,
            Vec3::NEG_Y,
        ),
    ]
}

#[test]
fn closed_box_is_closed() {
    let mut b = Scene::builder(DMat4::IDENTITY);
    for s in closed_box() {
        add(&mut b, &s);
    }
    let scene = b.build();
    let pts: Vec<Vec3> = (0..9)
        .map(|k| Vec3::new(-0.04 + 0.01 * k as f32, 0.0, 0.0))
        .collect();
    let a = floor_points(&scene, &pts, 0.015, &prm(512, INF));
    assert!(a.iter().all(|&x| x == 0.0), "{a:?}");
    // Twelve triangles.
    let v: Vec<Vec3> = (0..8)
        .map(|k| {
            Vec3::new(
                [-0.5, 0.5][k & 1],
                [-0.5, 0.5][(k >> 1) & 1],
                [0.0, 1.0][k >> 2],
            )
        })
        .collect();
    let quads = [
        [0, 1, 3, 2],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 3, 7, 6],
        [0, 2, 6, 4],
        [1, 3, 7, 5],
    ];
    let tris: Vec<[u32; 3]> = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    let mut b = Scene::builder(DMat4::IDENTITY);
    b.add_triangles("box", DMat4::IDENTITY, &v, None, &tris)
        .unwrap();
    let scene = b.build();
    let a = floor_points(&scene, &pts, 0.015, &prm(512, INF));
    assert!(a.iter().all(|&x| x == 0.0), "{a:?}");
}

/// Surfels on a sphere (Fibonacci lattice), normals outward (`inward = false`) or inward.
fn sphere(center: Vec3, radius: f32, count: usize, inward: bool) -> Sheet {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let spacing = (4.0 * std::f32::consts::PI * radius * radius / count as f32).sqrt();
    let mut s = Sheet {
        p: Vec::new(),
        n: Vec::new(),
        r: Vec::new(),
    };
    for k in 0..count {
        let z = 1.0 - 2.0 * (k as f32 + 0.5) / count as f32;
        let q = (1.0 - z * z).sqrt();
        let a = golden * k as f32;
        let d = Vec3::new(q * a.cos(), q * a.sin(), z);
        s.p.push(center + d * radius);
        s.n.push(if inward { -d } else { d });
        // rad(p) = 2·sqrt(d_k²/k) of the lattice: about 1.1 × its spacing.
        s.r.push(1.1 * spacing);
    }
    s
}

/// Self-hit bias on convex and concave curved surfaces; see the `reference` module docs.
#[test]
fn sphere_outside_is_open_and_inside_matches_closed_form() {
    let (radius, count) = (0.15f32, 6000);
    let mut out = Vec::new();
    for inward in [false, true] {
        let s = sphere(Vec3::new(0.0, 0.0, 1.0), radius, count, inward);
        let mut b = Scene::builder(DMat4::IDENTITY);
        add(&mut b, &s);
        let scene = b.build();
        let idx: Vec<usize> = (0..count).step_by(23).collect();
        let p: Vec<Vec3> = idx.iter().map(|&i| s.p[i]).collect();
        let n: Vec<Vec3> = idx.iter().map(|&i| s.n[i]).collect();
        let r: Vec<f32> = idx.iter().map(|&i| s.r[i]).collect();
        for tmax in [0.4f32, INF] {
            let a = obscurance(&scene, &p, &n, &r, &prm(256, tmax), &|_| {}).unwrap();
            out.push((inward, tmax, mean(&a)));
        }
    }
    println!("sphere (inward, t_max, mean A): {out:?}");
    // Convex: exactly open; the self-hit rules leave no bias.
    assert!(out[0].2 > 0.999, "{out:?}");
    assert!(out[1].2 > 0.999, "{out:?}");
    // Concave, t_max = 0.4 ≥ 2R: 6R²/t² − 32R³/(5t³) = 0.50625; σ ≤ 0.5/√(261·256).
    let (r, t) = (radius as f64, 0.4f64);
    let want = 6.0 * r * r / (t * t) - 32.0 * r * r * r / (5.0 * t * t * t);
    assert!((out[2].2 - want).abs() < 0.01, "{out:?} vs {want}");
    // Concave, t_max = ∞: closed.
    assert!(out[3].2 < 0.002, "{out:?}");
}

#[test]
fn surfels_and_triangles_of_one_grid_agree() {
    let xs = range(-0.5, 0.5, 0.01);
    let height = |x: f32, y: f32| 0.06 * (x / 0.05).sin() * (y / 0.07).cos();
    let (p, g) = grid_points(&xs, &xs, |x, y| Vec3::new(x, y, height(x, y)));
    let n: Vec<Vec3> = p
        .iter()
        .map(|q| {
            let (x, y) = (q.x, q.y);
            let dx = 0.06 / 0.05 * (x / 0.05).cos() * (y / 0.07).cos();
            let dy = -0.06 / 0.07 * (x / 0.05).sin() * (y / 0.07).sin();
            Vec3::new(-dx, -dy, 1.0).normalize()
        })
        .collect();
    let r = vec![0.0113f32; p.len()];
    let tris = triangulate_grid_seen(&p, &g, View::Parallel(Vec3::Z)).unwrap();
    assert_eq!(tris.len(), 2 * 100 * 100);
    let mut b = Scene::builder(DMat4::IDENTITY);
    b.add_surfels("bumps", DMat4::IDENTITY, &p, &n, &r).unwrap();
    let surf = b.build();
    let mut b = Scene::builder(DMat4::IDENTITY);
    b.add_triangles("bumps", DMat4::IDENTITY, &p, None, &tris)
        .unwrap();
    let tri = b.build();
    // Interior points only (the border sees past the edge of the patch differently).
    let idx: Vec<usize> = (0..p.len())
        .filter(|&i| p[i].x.abs() < 0.3 && p[i].y.abs() < 0.3)
        .step_by(7)
        .collect();
    let (q, qn): (Vec<Vec3>, Vec<Vec3>) = idx.iter().map(|&i| (p[i], n[i])).unzip();
    let qr = vec![0.0113f32; q.len()];
    let pr = prm(256, 0.2);
    let a = obscurance(&surf, &q, &qn, &qr, &pr, &|_| {}).unwrap();
    let b = obscurance(&tri, &q, &qn, &qr, &pr, &|_| {}).unwrap();
    let diff: Vec<f32> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
    let mean_diff = mean(&diff);
    let mean_abs = diff.iter().map(|d| d.abs() as f64).sum::<f64>() / diff.len() as f64;
    println!(
        "bumps: {} points, mean A surfels {:.4} triangles {:.4}, mean diff {mean_diff:.4}, mean |diff| {mean_abs:.4}",
        q.len(),
        mean(&a),
        mean(&b)
    );
    // The surface is visibly shaded, and the two models agree.
    assert!(mean(&a) < 0.97);
    assert!(mean_diff.abs() < 0.01, "{mean_diff}");
    assert!(mean_abs < 0.03, "{mean_abs}");
}

/// A small scene with something to see: a floor and a wall of surfels.
fn corner_scene() -> (Scene, Vec<Vec3>, Vec<Vec3>, Vec<f32>) {
    let f = floor();
    let wall = sheet(
        Vec3::new(0.2, 0.0, 0.0),
        Vec3::Y,
        Vec3::Z,
        &range(-0.6, 0.6, 0.01),
        &range(0.0, 0.6, 0.01),
        Vec3::NEG_X,
    );
    let mut b = Scene::builder(DMat4::IDENTITY);
    add(&mut b, &f);
    add(&mut b, &wall);
    let idx = (0..f.p.len()).step_by(41);
    let p: Vec<Vec3> = idx.clone().map(|i| f.p[i]).collect();
    (
        b.build(),
        p.clone(),
        vec![Vec3::Z; p.len()],
        vec![f.r[0]; p.len()],
    )
}

#[test]
fn deterministic_for_a_seed_and_any_thread_count() {
    let (scene, p, n, r) = corner_scene();
    let pr = prm(64, 0.4);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| obscurance(&scene, &p, &n, &r, &pr, &|_| {}).unwrap())
    };
    let one = run(1);
    let two = run(2);
    assert!(one
        .iter()
        .zip(&two)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
    assert_eq!(one, run(2));
    // Shaded somewhere (the wall), and a different seed changes some values.
    assert!(one.iter().any(|&a| a < 0.9));
    let other = obscurance(&scene, &p, &n, &r, &RefParams { seed: 8, ..pr }, &|_| {}).unwrap();
    assert!(one.iter().zip(&other).any(|(a, b)| a != b));
    // A point's value does not depend on the other points.
    let half = obscurance(
        &scene,
        &p[..p.len() / 2],
        &n[..p.len() / 2],
        &r[..p.len() / 2],
        &pr,
        &|_| {},
    )
    .unwrap();
    assert_eq!(&one[..p.len() / 2], &half[..]);
}

#[test]
fn convergence_and_reference_report() {
    let (scene, p, n, r) = corner_scene();
    let pr = prm(64, 0.4);
    let count = std::sync::atomic::AtomicU64::new(0);
    let res = reference::reference(&scene, &p, &n, &r, &pr, 100, &|k| {
        count.fetch_add(k, std::sync::atomic::Ordering::Relaxed);
    })
    .unwrap();
    assert_eq!(count.into_inner(), p.len() as u64);
    let c = res.convergence;
    assert_eq!(c.sample, 100);
    assert_eq!(c.rays, 64);
    assert_eq!(c.rays_cast, p.len() as u64 * 64);
    assert!(c.rays_per_second > 0.0);
    assert!(c.max_abs_diff_4r >= c.mean_abs_diff_4r);
    // σ of one point with 64 rays ≤ 0.0625; the mean over 100 is far below.
    assert!(c.mean_abs_diff_4r < 0.05, "{c:?}");
    assert_eq!(res.a, obscurance(&scene, &p, &n, &r, &pr, &|_| {}).unwrap());
    // Sample larger than the input: all points.
    let c = reference::convergence(&scene, &p[..10], &n[..10], &r[..10], &pr, 2000).unwrap();
    assert_eq!(c.sample, 10);
    assert!(serde_json::to_string(&c)
        .unwrap()
        .contains("mean_abs_diff_4r"));
}

#[test]
fn georeferenced_poses_give_the_same_answer() {
    let (scene, p, n, r) = corner_scene();
    let pr = prm(64, 0.4);
    let want = obscurance(&scene, &p, &n, &r, &pr, &|_| {}).unwrap();
    // The same geometry as two scans far from the world origin, each in its own local frame.
    let f = floor();
    let wall = sheet(
        Vec3::new(0.2, 0.0, 0.0),
        Vec3::Y,
        Vec3::Z,
        &range(-0.6, 0.6, 0.01),
        &range(0.0, 0.6, 0.01),
        Vec3::NEG_X,
    );
    let base = DMat4::from_translation(DVec3::new(4.5e5, 5.2e6, 310.0));
    let pose_b =
        base * DMat4::from_rotation_z(0.3) * DMat4::from_translation(DVec3::new(3.0, -2.0, 0.5));
    let to_b = pose_b.inverse() * base;
    let wall_b: Vec<Vec3> = wall
        .p
        .iter()
        .map(|q| to_b.transform_point3(q.as_dvec3()).as_vec3())
        .collect();
    let wall_nb: Vec<Vec3> = wall
        .n
        .iter()
        .map(|q| to_b.transform_vector3(q.as_dvec3()).as_vec3())
        .collect();
    let mut b = Scene::builder(base);
    b.add_surfels("floor", base, &f.p, &f.n, &f.r).unwrap();
    b.add_surfels("wall", pose_b, &wall_b, &wall_nb, &wall.r)
        .unwrap();
    let geo = b.build();
    let (q, qn) = geo.to_frame(base, &p, &n).unwrap();
    let got = obscurance(&geo, &q, &qn, &r, &pr, &|_| {}).unwrap();
    let worst = want
        .iter()
        .zip(&got)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    // Round-trips through f32 local frames move surfels by ~1e-7 m; a ray may rarely flip.
    assert!(worst <= 2.0 / 64.0 + 1e-6, "{worst}");
    assert!(mean(&want) - mean(&got) < 1e-3);
}

#[test]
fn bad_input_is_an_error_or_open_never_nan() {
    let (scene, p, n, r) = corner_scene();
    let pr = prm(16, 0.4);
    assert!(obscurance(&scene, &p, &n[..1], &r, &pr, &|_| {}).is_err());
    assert!(obscurance(&scene, &p, &n, &r, &RefParams { rays: 0, ..pr }, &|_| {}).is_err());
    let huge = RefParams {
        rays: u32::MAX,
        ..pr
    };
    assert!(obscurance(&scene, &p, &n, &r, &huge, &|_| {}).is_err());
    assert!(reference::convergence(&scene, &p, &n, &r, &huge, 10).is_err());
    for t in [0.0, -1.0, f32::NAN] {
        assert!(obscurance(&scene, &p, &n, &r, &RefParams { tmax: t, ..pr }, &|_| {}).is_err());
    }
    let q = [
        Vec3::NAN,
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(0.1, 0.0, 0.0),
    ];
    let qn = [Vec3::Z, Vec3::ZERO, Vec3::new(0.0, 0.0, f32::INFINITY)];
    let a = obscurance(&scene, &q, &qn, &[0.01, f32::NAN, -1.0], &pr, &|_| {}).unwrap();
    assert_eq!(a, vec![1.0, 1.0, 1.0]);
    let a = obscurance(
        &scene,
        &[Vec3::new(0.1, 0.0, 0.0)],
        &[Vec3::Z],
        &[f32::NAN],
        &pr,
        &|_| {},
    )
    .unwrap();
    assert!(a[0].is_finite() && (0.0..=1.0).contains(&a[0]));
    // Builder: mismatched slices and bad indices are errors naming the scan; invalid
    // primitives are skipped and counted.
    let mut b = Scene::builder(DMat4::IDENTITY);
    let e = b
        .add_surfels("scan7", DMat4::IDENTITY, &p, &n[..2], &r)
        .unwrap_err();
    assert!(e.to_string().contains("scan7"), "{e}");
    let e = b
        .add_triangles("mesh3", DMat4::IDENTITY, &p[..3], None, &[[0, 1, 5]])
        .unwrap_err();
    assert!(
        e.to_string().contains("mesh3") && e.to_string().contains('5'),
        "{e}"
    );
    assert!(b
        .add_surfels("nan", DMat4::from_cols_array(&[f64::NAN; 16]), &p, &n, &r)
        .is_err());
    let added = b
        .add_surfels(
            "mixed",
            DMat4::IDENTITY,
            &[Vec3::ZERO, Vec3::NAN, Vec3::ONE, Vec3::X],
            &[Vec3::Z, Vec3::Z, Vec3::ZERO, Vec3::Z],
            &[0.1, 0.1, 0.1, 0.0],
        )
        .unwrap();
    assert_eq!(added, 1);
    let added = b
        .add_triangles(
            "flat",
            DMat4::IDENTITY,
            &[Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
            None,
            &[[0, 1, 2]],
        )
        .unwrap();
    assert_eq!(added, 0);
    let s = b.build();
    assert_eq!(
        (s.surfel_count(), s.triangle_count(), s.skipped()),
        (1, 0, 4)
    );
    let mut bad_frame = Scene::builder(DMat4::ZERO);
    assert!(bad_frame
        .add_surfels("s", DMat4::IDENTITY, &p, &n, &r)
        .is_err());
    // An empty scene is open everywhere.
    let empty = Scene::builder(DMat4::IDENTITY).build();
    let a = obscurance(&empty, &p, &n, &r, &pr, &|_| {}).unwrap();
    assert!(a.iter().all(|&x| x == 1.0));
    assert!(obscurance(&empty, &[], &[], &[], &pr, &|_| {})
        .unwrap()
        .is_empty());
}

#[test]
fn nearest_hit_finds_the_wall() {
    let (scene, _, _, _) = corner_scene();
    // From the floor towards the wall at x = 0.2.
    let o = Vec3::new(0.0, 0.0, 0.1);
    for tmax in [1.0, INF] {
        let t = scene.nearest_hit(o, Vec3::X, 0.01, tmax).unwrap();
        assert!((t - 0.2).abs() < 1e-5, "{t}");
    }
    assert_eq!(scene.nearest_hit(o, Vec3::X, 0.01, 0.15), None);
    assert_eq!(scene.nearest_hit(o, Vec3::NEG_X, 0.01, INF), None);
    // Straight down onto the floor (seen from its front).
    let t = scene.nearest_hit(o, Vec3::NEG_Z, 0.01, INF).unwrap();
    assert!((t - 0.1).abs() < 1e-5, "{t}");
}

#[test]
fn rho_is_the_smoothstep() {
    assert_eq!(rho(0.0, 0.4), 0.0);
    assert_eq!(rho(0.2, 0.4), 0.5);
    assert_eq!(rho(0.4, 0.4), 1.0);
    assert_eq!(rho(9.0, 0.4), 1.0);
    assert_eq!(rho(0.1, INF), 0.0);
    assert_eq!(rho(INF, INF), 1.0);
    // x = 0.25: 0.0625·2.5 = 0.15625.
    assert!((rho(0.1, 0.4) - 0.15625).abs() < 1e-6);
}

/// A real range scan (the Stanford bunny, front view, with its native grid): the reference
/// from surfels of `rad(p)` and from the triangulated grid agree.
#[test]
fn real_scan_surfels_and_grid_triangles_agree() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/stanford-bunny/bun000.ply");
    let (scan, _) = mvao::io::ply::scan::read_scan(&path).unwrap();
    let grid = scan.grid.as_ref().expect("bun000 has a range grid");
    // Orthographic scanner looking along −z: the sensor is towards +z.
    let (normals, radii) =
        mvao::testing::scan::normals::estimate_grid(&scan.points, grid, true, |_| Vec3::Z);
    let normals = normals.unwrap();
    let tris = triangulate_grid(&scan.points, grid).unwrap();
    let mut b = Scene::builder(scan.pose);
    b.add_surfels("bun000", scan.pose, &scan.points, &normals, &radii)
        .unwrap();
    let surf = b.build();
    let mut b = Scene::builder(scan.pose);
    b.add_triangles("bun000", scan.pose, &scan.points, Some(&normals), &tris)
        .unwrap();
    let tri = b.build();
    let idx: Vec<usize> = (0..scan.len()).step_by(97).collect();
    let p: Vec<Vec3> = idx.iter().map(|&i| scan.points[i]).collect();
    let n: Vec<Vec3> = idx.iter().map(|&i| normals[i]).collect();
    let r: Vec<f32> = idx.iter().map(|&i| radii[i]).collect();
    let pr = prm(128, 0.05);
    let a = obscurance(&surf, &p, &n, &r, &pr, &|_| {}).unwrap();
    let t = obscurance(&tri, &p, &n, &r, &pr, &|_| {}).unwrap();
    let d: Vec<f32> = a.iter().zip(&t).map(|(x, y)| x - y).collect();
    let mean_abs = d.iter().map(|x| x.abs() as f64).sum::<f64>() / d.len() as f64;
    println!(
        "bun000: {} triangles, {} points, mean A surfels {:.4} triangles {:.4}, mean diff {:.4}, mean |diff| {mean_abs:.4}",
        tris.len(),
        p.len(),
        mean(&a),
        mean(&t),
        mean(&d)
    );
    assert!(mean(&a) < 0.95, "the bunny is shaded");
    assert!(mean(&d).abs() < 0.02);
    assert!(mean_abs < 0.05);
}

/// The surfel reference of the synthetic room (three stations, exact ranges) against
/// obscurance ray-cast on the room's exact analytic geometry: the surfel model itself is
/// close to the surface it samples.
#[test]
fn synthetic_room_matches_its_analytic_geometry() {
    use mvao::synth::{scan_scene, station_layout, SceneKind};
    use mvao::testing::projection::SensorModel;
    let room = SceneKind::Room.scene();
    let stations = station_layout(SceneKind::Room, SensorModel::Equirect, 3, 480, 240);
    let scans: Vec<_> = stations
        .iter()
        .enumerate()
        .map(|(i, st)| {
            let mut s = scan_scene(&room, st, 0.0, i as u64, &format!("s{i}"));
            s.pose = st.pose();
            s
        })
        .collect();
    let mut b = Scene::builder(scans[0].pose);
    let mut radii0 = Vec::new();
    for s in &scans {
        let g = s.grid.as_ref().unwrap();
        let (_, r) = mvao::testing::scan::normals::estimate_grid(&s.points, g, false, |p| -p);
        b.add_surfels(&s.name, s.pose, &s.points, s.normals.as_ref().unwrap(), &r)
            .unwrap();
        if radii0.is_empty() {
            radii0 = r;
        }
    }
    let scene = b.build();
    let s0 = &scans[0];
    let idx: Vec<usize> = (0..s0.len()).step_by(211).collect();
    let p: Vec<Vec3> = idx.iter().map(|&i| s0.points[i]).collect();
    let n: Vec<Vec3> = idx
        .iter()
        .map(|&i| s0.normals.as_ref().unwrap()[i])
        .collect();
    let r: Vec<f32> = idx.iter().map(|&i| radii0[i]).collect();
    let (rays, tmax) = (256u32, 0.4f32);
    let a = obscurance(&scene, &p, &n, &r, &prm(rays, tmax), &|_| {}).unwrap();
    // Exact geometry, same estimator (stratified cosine-weighted directions), in f64.
    let exact: Vec<f32> = p
        .iter()
        .zip(&n)
        .map(|(p, n)| {
            let pw = s0.pose.transform_point3(p.as_dvec3());
            let nw = s0.pose.transform_vector3(n.as_dvec3()).normalize();
            let (t, b) = nw.any_orthonormal_pair();
            let o = pw + nw * 1e-6;
            let mut sum = 0.0;
            for j in 0..rays {
                let u1 = (j as f64 + 0.5) / rays as f64;
                let phi = std::f64::consts::TAU * (j as f64 * 0.618_033_988_749_895).fract();
                let d = t * (u1.sqrt() * phi.cos())
                    + b * (u1.sqrt() * phi.sin())
                    + nw * (1.0 - u1).sqrt();
                let hit = room.intersect_range(o, d, 1e-9, tmax as f64);
                sum += hit.map_or(1.0, |h| rho(h.t as f32, tmax) as f64);
            }
            (sum / rays as f64) as f32
        })
        .collect();
    let d: Vec<f32> = a.iter().zip(&exact).map(|(x, y)| x - y).collect();
    let mean_abs = d.iter().map(|x| x.abs() as f64).sum::<f64>() / d.len() as f64;
    let shaded = exact.iter().filter(|&&x| x < 0.9).count();
    let shaded_abs = d
        .iter()
        .zip(&exact)
        .filter(|(_, &x)| x < 0.9)
        .map(|(x, _)| x.abs() as f64)
        .sum::<f64>()
        / shaded.max(1) as f64;
    println!(
        "room 3×480×240: {} points ({shaded} shaded, mean |diff| there {shaded_abs:.4}), mean A surfels {:.4} exact {:.4}, mean diff {:.4}, mean |diff| {mean_abs:.4}",
        p.len(),
        mean(&a),
        mean(&exact),
        mean(&d)
    );
    assert!(shaded > 20);
    assert!(mean(&d).abs() < 0.01, "{}", mean(&d));
    assert!(mean_abs < 0.03, "{mean_abs}");
    assert!(shaded_abs < 0.06, "{shaded_abs}");
}

/// A floor under a ceiling 1 cm above it, nearer than two of the floor points' radii: the
/// ceiling faces back at the floor and stands over it, so it is an occluder, not the points'
/// own surface tilted by error, and the slot reads closed at ∞. When every surface within
/// `2·rad(p)` facing either way was taken as the point's own, the rays steeper than
/// `acos(g / 2 rad)` passed through the ceiling (A ≈ 0.56 here).
#[test]
fn a_facing_surface_nearer_than_the_own_patch_closes_a_slot() {
    let g = 0.01f32;
    let xs = range(-0.6, 0.6, 0.002);
    let ceiling = sheet(Vec3::Z * g, Vec3::X, Vec3::Y, &xs, &xs, Vec3::NEG_Z);
    let pts: Vec<Vec3> = (0..16)
        .map(|k| Vec3::new(0.003 * k as f32, -0.02, 0.0))
        .collect();
    let rad = 0.75 * g;
    let mut b = Scene::builder(DMat4::IDENTITY);
    add(&mut b, &ceiling);
    let a = mean(&floor_points(&b.build(), &pts, rad, &prm(256, INF)));
    assert!(a < 0.01, "surfels: {a}");
    // The same ceiling as two triangles wound to face up, and vertex normals facing down:
    // the normals decide the front.
    let v = [
        Vec3::new(-1.0, -1.0, g),
        Vec3::new(1.0, -1.0, g),
        Vec3::new(1.0, 1.0, g),
        Vec3::new(-1.0, 1.0, g),
    ];
    let tris = [[0, 1, 2], [0, 2, 3]];
    let mut b = Scene::builder(DMat4::IDENTITY);
    b.add_triangles(
        "ceiling",
        DMat4::IDENTITY,
        &v,
        Some(&[Vec3::NEG_Z; 4]),
        &tris,
    )
    .unwrap();
    let a = mean(&floor_points(&b.build(), &pts, rad, &prm(256, INF)));
    assert!(a < 0.01, "triangles facing down: {a}");
    // Without normals the winding is the front: facing up, the ceiling is taken as the
    // points' own surface where it is nearer than 2·rad(p).
    let mut b = Scene::builder(DMat4::IDENTITY);
    b.add_triangles("ceiling", DMat4::IDENTITY, &v, None, &tris)
        .unwrap();
    let a = mean(&floor_points(&b.build(), &pts, rad, &prm(256, INF)));
    let open = 1.0 - (g / (2.0 * rad)).powi(2) as f64;
    assert!(
        (a - open).abs() < 0.03,
        "triangles facing up: {a} against {open}"
    );
    let mut b = Scene::builder(DMat4::IDENTITY);
    let err = b
        .add_triangles("ceiling", DMat4::IDENTITY, &v, Some(&[Vec3::Z; 3]), &tris)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("ceiling") && err.contains("3 front directions for 4 vertices"),
        "{err}"
    );
}

/// Samples of the point's own floor whose estimated normals are tilted by up to 25° and
/// half of them flipped (normal estimation at grazing range): none of them stands over the
/// tangent plane, so none darkens the floor, whichever way it faces.
#[test]
fn own_samples_facing_back_do_not_darken_their_floor() {
    let xs = range(-0.3, 0.3, 0.01);
    let mut f = sheet(Vec3::ZERO, Vec3::X, Vec3::Y, &xs, &xs, Vec3::Z);
    for (k, n) in f.n.iter_mut().enumerate() {
        let t = (k as f32 * 0.618_034).fract();
        let tilt = 25f32.to_radians() * t;
        let az = k as f32 * 2.399_963;
        let m = Vec3::new(tilt.sin() * az.cos(), tilt.sin() * az.sin(), tilt.cos());
        *n = if k % 2 == 0 { m } else { -m };
    }
    let mut b = Scene::builder(DMat4::IDENTITY);
    add(&mut b, &f);
    let pts: Vec<Vec3> = f.p.iter().step_by(131).copied().collect();
    let a = floor_points(&b.build(), &pts, f.r[0], &prm(128, 0.4));
    assert!(mean(&a) > 0.99, "{}", mean(&a));
}
