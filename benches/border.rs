//! The border field's stages on a synthetic 4096 × 2048 panorama (sky, a wavy wall, a box and a
//! pillar), best of five each: Laplacian, edge mask, distance field and the whole
//! `border_distance`: `cargo bench --bench border`. `MVAO_BENCH_WIDTH=W` uses a W × W/2 map.

use mvao::testing::merge::border::{
    border_distance, distance_field, edge_mask, laplacian, EDGE_QUANTILE,
};
use std::time::{Duration, Instant};

/// Minimum of a few runs: the machine may be shared.
fn best<T>(mut f: impl FnMut() -> T) -> (T, Duration) {
    let t = Instant::now();
    let mut out = f();
    let mut best = t.elapsed();
    for _ in 1..5 {
        let t = Instant::now();
        out = f();
        best = best.min(t.elapsed());
    }
    (out, best)
}

fn main() {
    let w: usize = std::env::var("MVAO_BENCH_WIDTH")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4096);
    let h = w / 2;
    let mut depth = vec![f32::INFINITY; w * h];
    for y in 0..h {
        for x in 0..w {
            let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
            if v < 0.15 {
                continue; // sky
            }
            let mut d = 8.0 + 3.0 * (u * std::f32::consts::TAU).sin() + 4.0 * v;
            if (0.2..0.3).contains(&u) && v > 0.5 {
                d = 3.0; // a box
            }
            if ((u - 0.7).powi(2) + (v - 0.6).powi(2)) < 0.01 {
                d = 2.0; // a pillar
            }
            depth[y * w + x] = d;
        }
    }
    let (lap, t_lap) = best(|| laplacian(&depth, w, h, true));
    let (edges, t_mask) = best(|| edge_mask(&lap, &depth, EDGE_QUANTILE));
    let (dist, t_field) = best(|| distance_field(&edges, w, h, true));
    let (total, t_total) = best(|| border_distance(&depth, w, h, true));
    assert_eq!(dist, total, "border_distance differs from its stages");
    println!(
        "{w}x{h} on {} threads (best of 5): laplacian {t_lap:?}, edge_mask {t_mask:?} \
         ({} edges), distance_field {t_field:?}; border_distance {t_total:?}",
        rayon::current_num_threads(),
        edges.iter().filter(|e| **e).count()
    );
}
