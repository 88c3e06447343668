//! Reference ray-casting throughput on the synthetic room (three 1440×720 equirect stations,
//! ≈1M points each, 2 mm range noise, exact normals, surfel radii from the kept grid edges
//! as `mvao reference` sizes them, `reference::grid_radii`): all
//! three scans as surfels in one scene, query points = every `STEP`-th point of station 0.
//! `cargo bench --bench reference` prints build time and rays/s for t_max = 0.4 m and ∞.
//! `MVAO_BENCH_STEP=1` traces every point of station 0, `MVAO_BENCH_RAYS=R` casts R rays per
//! point (default 64). The machine is shared: rays per
//! CPU-second (user + system time of this process) is the steadier figure.

use mvao::synth::{scan_scene, station_layout, SceneKind};
use mvao::testing::projection::SensorModel;
use mvao::testing::reference::{self, RefParams, Scene};
use mvao::testing::scan::normals;
use mvao::testing::sys;
use std::time::Instant;

fn main() {
    let step: usize = std::env::var("MVAO_BENCH_STEP")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let (w, h) = (1440, 720);
    let stations = station_layout(SceneKind::Room, SensorModel::Equirect, 3, w, h);
    let room = SceneKind::Room.scene();
    let scans: Vec<_> = stations
        .iter()
        .enumerate()
        .map(|(i, st)| {
            let mut s = scan_scene(&room, st, 0.002, i as u64, &format!("s{i}"));
            s.pose = st.pose();
            s
        })
        .collect();
    let radii: Vec<Vec<f32>> = scans
        .iter()
        .map(|s| {
            let g = s.grid.as_ref().expect("synthetic scans are gridded");
            let rad = normals::estimate_grid(&s.points, g, false, |p| -p.normalize_or_zero()).1;
            let n = s.normals.as_deref().unwrap_or(&[]);
            reference::grid_radii(&s.points, g, reference::View::Origin, n, &rad).expect("radii")
        })
        .collect();
    let t = Instant::now();
    let mut b = Scene::builder(scans[0].pose);
    for (s, r) in scans.iter().zip(&radii) {
        let n = s.normals.as_ref().expect("synthetic scans have normals");
        b.add_surfels(&s.name, s.pose, &s.points, n, r)
            .expect("surfels");
    }
    let scene = b.build();
    println!(
        "room, 3 equirect stations {w}x{h}: {} surfels, BVH build {:.2} s, {:.0} MB",
        scene.surfel_count(),
        t.elapsed().as_secs_f64(),
        scene.bytes() as f64 / 1e6
    );
    let s0 = &scans[0];
    let n0 = s0.normals.as_ref().expect("normals");
    let idx: Vec<usize> = (0..s0.len()).step_by(step).collect();
    let pts: Vec<_> = idx.iter().map(|&i| s0.points[i]).collect();
    let nrm: Vec<_> = idx.iter().map(|&i| n0[i]).collect();
    let rad: Vec<_> = idx.iter().map(|&i| radii[0][i]).collect();
    println!(
        "query: every {step}th point of station 0 = {} points",
        pts.len()
    );
    let rays: u32 = std::env::var("MVAO_BENCH_RAYS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(64);
    for tmax in [0.4f32, f32::INFINITY] {
        let prm = RefParams {
            rays,
            tmax,
            falloff: Default::default(),
            seed: 1,
        };
        let cpu0 = sys::cpu_seconds();
        let t = Instant::now();
        let a = reference::obscurance(&scene, &pts, &nrm, &rad, &prm, &|_| {}).expect("reference");
        let wall = t.elapsed().as_secs_f64();
        let cpu = sys::cpu_seconds() - cpu0;
        let cast = pts.len() as f64 * rays as f64;
        let conv = reference::convergence(&scene, &pts, &nrm, &rad, &prm, 2000).expect("conv");
        let mean = a.iter().map(|&x| x as f64).sum::<f64>() / a.len().max(1) as f64;
        println!(
            "t_max={tmax:>4}, {rays} rays/point: {wall:.2} s wall = {:.2} M rays/s; \
             {cpu:.2} cpu-s = {:.2} M rays per cpu-second; mean A {mean:.4}; \
             |A_R - A_4R| mean {:.4} max {:.4} (sample {})",
            cast / wall / 1e6,
            cast / cpu.max(1e-9) / 1e6,
            conv.mean_abs_diff_4r,
            conv.max_abs_diff_4r,
            conv.sample
        );
    }
}
