//! Horizon SSAO alone on one 1440×720 equirect station of the synthetic room (best of five),
//! for tuning the estimator: `cargo bench --bench ssao` (`-- suite` for a suite station, `-- once`
//! for the 8×8 budget run once, under an instruction counter). The 1×1 row is the per-pixel cost
//! that does not depend on the budget.

use mvao::synth::{scan_scene, station_layout, SceneKind};
use mvao::testing::pipeline::occlusion::prepare_view;
use mvao::testing::projection::SensorModel;
use mvao::testing::sensor::ProjectionChoice;
use mvao::testing::ssao::{self, Estimator, SsaoParams};
use std::time::Instant;

fn main() {
    // `-- suite`: the sixth of eight stations in the two-room suite instead.
    let (kind, count, k) = if std::env::args().any(|a| a == "suite") {
        (SceneKind::Suite { rooms: 2 }, 8, 5)
    } else {
        (SceneKind::Room, 1, 0)
    };
    let st = station_layout(kind, SensorModel::Equirect, count, 1440, 720)[k];
    let mut s = scan_scene(&kind.scene(), &st, 0.002, 0, "s0");
    s.pose = st.pose();
    let prm = SsaoParams {
        estimator: Estimator::Horizon,
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
    let v = prepare_view(&s, ProjectionChoice::Auto, &prm).expect("prepare");
    let (g, proj) = (&v.gbuf, &v.sensor.projection);
    // `-- once`: the 8×8 budget once (for instruction-level profilers).
    let once = std::env::args().any(|a| a == "once");
    let budgets: &[(u32, u32)] = if once {
        &[(8, 8)]
    } else {
        &[(8, 8), (1, 8), (8, 1), (1, 1)]
    };
    for &(d, st) in budgets {
        let p = SsaoParams {
            directions: d,
            steps: st,
            ..prm
        };
        let mut best = f64::INFINITY;
        let mut sum = 0.0f64;
        for _ in 0..if once { 1 } else { 5 } {
            let t = Instant::now();
            let m = ssao::compute(g, proj, &p);
            best = best.min(t.elapsed().as_secs_f64());
            sum = m.ao.iter().map(|&a| a as f64).sum();
        }
        println!(
            "horizon {d}x{st}: {best:.3} s for {} pixels = {:.2} M px/s (sum {sum:.3})",
            g.filled(),
            g.filled() as f64 / best / 1e6
        );
    }
}
