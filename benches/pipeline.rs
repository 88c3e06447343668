//! Stage throughput on synthetic terrestrial scans of the room (three 1440×720 stations,
//! ≈1M points each): `cargo bench`. Prints points/s for each per-view stage and
//! point-views/s for the merge.

use mvao::synth::{scan_scene, station_layout, SceneKind};
use mvao::testing::merge::cull::PointCells;
use mvao::testing::merge::{self, MergeParams};
use mvao::testing::pipeline::occlusion::prepare_view;
use mvao::testing::projection::SensorModel;
use mvao::testing::sensor::ProjectionChoice;
use mvao::testing::ssao::{self, Estimator, SsaoParams};
use mvao::testing::view::{merge_views, view_cells, view_maps};
use std::time::Instant;

fn best_of<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..runs {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(r);
    }
    (best, out.expect("at least one run"))
}

fn main() {
    let (w, h) = (1440, 720);
    let stations = station_layout(SceneKind::Room, SensorModel::Equirect, 3, w, h);
    let scene = SceneKind::Room.scene();
    let scans: Vec<_> = stations
        .iter()
        .enumerate()
        .map(|(i, st)| {
            let mut s = scan_scene(&scene, st, 0.002, i as u64, &format!("s{i}"));
            s.pose = st.pose();
            s
        })
        .collect();
    let n: usize = scans.iter().map(|s| s.len()).sum();
    println!(
        "room, 3 equirect stations {w}x{h}: {n} points ({} per scan)",
        scans[0].len()
    );
    let base = SsaoParams {
        estimator: Estimator::Paper,
        radius: 0.2,
        tmax: 0.4,
        falloff: Default::default(),
        samples: 32,
        directions: 8,
        steps: 8,
        seed: 0,
        blur: true,
        sampling: Default::default(),
    };
    let (t_prep, views) = best_of(1, || {
        scans
            .iter()
            .map(|s| prepare_view(s, ProjectionChoice::Auto, &base).expect("prepare"))
            .collect::<Vec<_>>()
    });
    println!("prepare (sensor+normals+gbuffer+ssao+border), 3 scans: {t_prep:.2} s");
    let stage = |name: &str| -> f64 {
        views
            .iter()
            .map(|v| {
                v.times
                    .iter()
                    .filter(|t| t.0 == name)
                    .map(|t| t.1)
                    .sum::<f64>()
            })
            .sum()
    };
    for name in ["sensor", "normals", "gbuffer", "ssao", "border"] {
        let t = stage(name);
        println!(
            "  {name:8} {t:6.3} s  {:8.2} M points/s",
            n as f64 / t / 1e6
        );
    }
    let g = &views[0].gbuf;
    let proj = &views[0].sensor.projection;
    let px = g.filled();
    for (label, prm) in [
        ("paper, 32 samples", base),
        (
            "paper, 32 samples, no blur",
            SsaoParams {
                blur: false,
                sampling: Default::default(),
                ..base
            },
        ),
        (
            "horizon, 8x8",
            SsaoParams {
                estimator: Estimator::Horizon,
                ..base
            },
        ),
        (
            "horizon, 16x16",
            SsaoParams {
                estimator: Estimator::Horizon,
                directions: 16,
                steps: 16,
                ..base
            },
        ),
    ] {
        let (t, _) = best_of(3, || ssao::compute(g, proj, &prm));
        println!(
            "ssao {label:28}: {:.3} s for {px} pixels = {:.2} M points/s",
            t,
            px as f64 / t / 1e6
        );
    }
    let packed = view_maps(
        &views,
        &MergeParams {
            neighbors: 1,
            dmin: 0.0,
            dmax: 10.0,
            border_px: 64.0,
            spacing: 0.04,
            largest_all_round: false,
        },
    );
    let cells = view_cells(&views, &scans);
    let mv = merge_views(&views, &packed, &scans, Some(&cells));
    let own_cells = PointCells::new(&scans[0].points, &views[0].radii, scans[0].pose);
    for nb in [1u32, 3, 5] {
        let mp = MergeParams {
            neighbors: nb,
            dmin: 0.0,
            dmax: 10.0,
            border_px: 64.0,
            spacing: 0.04,
            largest_all_round: false,
        };
        let (own, _) = views[0].point_ssao();
        let (t, (_, st)) = best_of(3, || {
            merge::merge_scan(
                0,
                &scans[0].points,
                &views[0].radii,
                &own,
                &views[0].pixel,
                Some(&own_cells),
                &mv,
                &[false; 3],
                &mp,
                &|_| {},
            )
        });
        println!(
            "merge N={nb}, 3 views: {:.3} s, {} point-views = {:.2} M point-views/s",
            t,
            st.point_views,
            st.point_views as f64 / t / 1e6
        );
    }
}
