//! The accuracy table of `docs/performance.md` for depth streams: a noisy synthetic stream
//! of the room integrated with given settings, the voxel grid's e_A against the exact ground
//! truth beside the mean single-frame e_A.
//!
//! `cargo run --release --example stream_truth -- WIDTH HEIGHT FRAMES VOXEL EDGE [SCALE...]`
//! prints one row per SSAO scale (default 1 2 4), without and with history.

use mvao::stream::score::score;
use mvao::stream::synth::{room_trajectory, synth_stream, StreamSynthOptions};
use mvao::stream::StreamParams;
use mvao::synth::Scene;

fn main() {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() < 5 {
        eprintln!("usage: stream_truth WIDTH HEIGHT FRAMES VOXEL EDGE [SCALE...]");
        std::process::exit(2);
    }
    let num = |i: usize| -> f64 {
        a[i].parse().unwrap_or_else(|_| {
            eprintln!("not a number: {}", a[i]);
            std::process::exit(2)
        })
    };
    let (w, h, frames) = (num(0) as usize, num(1) as usize, num(2) as usize);
    let (voxel, edge) = (num(3), num(4) as f32);
    let scales: Vec<usize> = if a.len() > 5 {
        (5..a.len()).map(|i| num(i) as usize).collect()
    } else {
        vec![1, 2, 4]
    };
    let o = StreamSynthOptions {
        frames,
        width: w,
        height: h,
        truth_rays: 64,
        ..StreamSynthOptions::default()
    };
    let s = synth_stream(&Scene::room(), &room_trajectory(frames), &o);
    let order: Vec<usize> = (0..frames).collect();
    println!(
        "| stream | SSAO scale | history | voxel e_A | per pixel | single-frame e_A | voxels |"
    );
    println!("|---|---|---|---|---|---|---|");
    for &f in &scales {
        for history in [false, true] {
            let mut p = StreamParams {
                voxel,
                history,
                ssao_scale: f,
                ..StreamParams::default()
            };
            p.clean.edge = edge;
            let r = score(&s, p, &order);
            println!(
                "| {w}×{h}, {frames} frames, {} mm voxels | 1/{f} | {} | {:.4} | {:.4} | {:.4} | {} |",
                voxel * 1000.0,
                if history { "on" } else { "off" },
                r.voxel,
                r.voxel_per_pixel,
                r.single,
                r.voxels
            );
        }
    }
}
