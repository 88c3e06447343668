use glam::DMat4;
use mvao::stream::synth::{room_trajectory, synth_stream, StreamSynthOptions};
use mvao::stream::{Integrator, StreamParams};
use mvao::synth::Scene;

#[test]
fn probe() {
    let w: usize = std::env::var("W")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(320);
    let frames: usize = std::env::var("FR")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(40);
    let h = w * 3 / 4;
    let o = StreamSynthOptions {
        frames,
        width: w,
        height: h,
        truth_rays: 32,
        ..Default::default()
    };
    let s = synth_stream(&Scene::room(), &room_trajectory(frames), &o);
    for hist in [true, false] {
        for scale in [1usize, 2, 3, 4] {
            let mut p = StreamParams {
                voxel: 2.0 / w as f64,
                ssao_scale: scale,
                history: hist,
                ..Default::default()
            };
            p.clean.edge = 0.02 * 640.0 / w as f32;
            let mut it = Integrator::new(p, s.intrinsics);
            let t = std::time::Instant::now();
            let (mut psad, mut pn) = (0.0f64, 0usize);
            for i in 0..frames {
                let pose: DMat4 = s.poses[i];
                let (geo, ao, _) = it.frame_ssao(&s.frames[i], pose);
                for (k, a) in ao.iter().enumerate() {
                    let tr = s.truth[i][k];
                    if let (Some(a), true, true) = (a, tr.is_finite(), geo.is_valid(k)) {
                        psad += (a - tr).abs() as f64;
                        pn += 1;
                    }
                }
                it.add_frame_truth(&s.frames[i], pose, Some(&s.truth[i]));
            }
            let secs = t.elapsed().as_secs_f64();
            let (mut sad, mut n, mut wsad, mut wn) = (0.0f64, 0usize, 0.0f64, 0u64);
            for vp in it.grid.points() {
                if let Some(&(sum, c)) = it.truth.get(&vp.key) {
                    let d = (vp.ao as f64 - sum / c as f64).abs();
                    sad += d;
                    n += 1;
                    wsad += d * c as f64;
                    wn += c;
                }
            }
            eprintln!("w {w} hist {hist} scale {scale}: voxel e_A {:.4} per-pixel voxel e_A {:.4} frame SSAO e_A {:.4} ({n} voxels, {secs:.1} s)", sad / n as f64, wsad / wn as f64, psad / pn as f64);
        }
    }
}
