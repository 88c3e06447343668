//! Radii (and PCA normals) from the native grid of one 1440×720 equirect suite station, best
//! of five: `cargo bench --bench normals` (`-- radii` or `-- normals` for one path only;
//! `-- kdtree` for the same points without their grid, through the k-d tree and the cell grid).

use mvao::synth::{scan_scene, station_layout, SceneKind};
use mvao::testing::projection::SensorModel;
use mvao::testing::scan::normals;
use std::time::Instant;

fn main() {
    let kind = SceneKind::Suite { rooms: 2 };
    let st = station_layout(kind, SensorModel::Equirect, 8, 1440, 720)[5];
    let s = scan_scene(&kind.scene(), &st, 0.002, 0, "s0");
    let grid = s.grid.as_ref().expect("synthetic scans are gridded");
    let toward = |p: glam::Vec3| (-p).normalize_or_zero();
    // `-- once`: one run of each (for an instruction count under callgrind).
    let runs = if std::env::args().any(|a| a == "once") {
        1
    } else {
        5
    };
    let only = |a: &str| std::env::args().any(|x| x == a);
    // Best of `runs` of one estimate, printed with a checksum of its radii and normals.
    let time = |label: &str, runs: usize, f: &dyn Fn() -> (Option<Vec<glam::Vec3>>, Vec<f32>)| {
        let mut best = f64::INFINITY;
        let mut sum = 0.0f64;
        for _ in 0..runs {
            let t = Instant::now();
            let (n, r) = f();
            best = best.min(t.elapsed().as_secs_f64());
            sum = r.iter().map(|&x| x as f64).sum::<f64>()
                + n.map_or(0.0, |n| n.iter().map(|v| v.x as f64).sum());
        }
        println!(
            "{label}: {best:.3} s for {} points = {:.2} M points/s (checksum {sum:.6})",
            s.len(),
            s.len() as f64 / best / 1e6
        );
    };
    if only("kdtree") {
        time("k-d tree radii+normals", runs.min(3), &|| {
            normals::estimate_kdtree(&s.points, true, toward)
        });
        time("cell grid radii+normals", runs.min(3), &|| {
            normals::estimate(&s.points, true, toward)
        });
        return;
    }
    for need in [false, true] {
        if (only("radii") && need) || (only("normals") && !need) {
            continue;
        }
        let label = if need {
            "grid radii+normals"
        } else {
            "grid radii"
        };
        time(label, runs, &|| {
            normals::estimate_grid(&s.points, grid, need, toward)
        });
    }
}
