use super::clean::{clean, CleanParams};
use super::frames::{DepthFrame, Intrinsics};
use super::grid::{morton, unmorton, VoxelGrid, BIAS};
use super::*;
use glam::{DMat4, DVec3, Vec3};
use std::collections::HashMap;

#[test]
fn morton_keys_round_trip() {
    let mut cells = vec![
        [0, 0, 0],
        [-1, -1, -1],
        [BIAS - 1, -BIAS, 7],
        [-BIAS, BIAS - 1, -BIAS],
        [12345, -54321, 999_999],
    ];
    let mut x = 0x1234_5678_u64;
    for _ in 0..1000 {
        x = crate::rng::splitmix64(x);
        let c = [0, 21, 42].map(|s| ((x >> s) & 0x1f_ffff) as i64 - BIAS);
        cells.push(c);
    }
    for c in cells {
        let k = morton(c).unwrap();
        assert_eq!(unmorton(k), c, "key {k:#x}");
    }
    assert_eq!(morton([BIAS, 0, 0]), None);
    assert_eq!(morton([0, -BIAS - 1, 0]), None);
    // Neighbouring cells along x differ in the lowest bit of the interleave.
    assert_eq!(morton([1, 0, 0]).unwrap() ^ morton([0, 0, 0]).unwrap(), 1);
}

#[test]
fn keys_cover_points_far_from_the_first_frames() {
    let mut g = VoxelGrid::new(0.01);
    g.add(DVec3::new(0.005, 0.005, 0.005), Vec3::Z, 0.5, 1.0);
    g.add(DVec3::new(-9000.0, 5000.0, -300.0), Vec3::Z, 0.25, 2.0);
    assert_eq!(g.len(), 2);
    assert_eq!(g.out_of_range, 0);
    let pts = g.points();
    assert!(pts
        .iter()
        .any(|p| (p.position - DVec3::new(-9000.0, 5000.0, -300.0)).length() < 0.01));
    g.add(DVec3::new(1e6, 0.0, 0.0), Vec3::Z, 0.5, 1.0);
    assert_eq!(g.out_of_range, 1);
}

#[test]
fn table_stays_under_128_bytes_per_voxel() {
    let mut g = VoxelGrid::new(0.01);
    let mut worst = 0.0f64;
    for i in 0..200_000u64 {
        let p = DVec3::new(
            (i % 97) as f64,
            ((i / 97) % 89) as f64,
            (i / (97 * 89)) as f64,
        ) * 0.01;
        g.add(p + 0.005, Vec3::Z, 0.5, 1.0);
        if i > 1000 && i % 997 == 0 {
            worst = worst.max(g.table_bytes() as f64 / g.len() as f64);
        }
    }
    assert!(worst <= 128.0, "{worst} bytes per voxel");
}

/// A frame of two planes facing the camera: depth `near` on the left half, `far` on the right.
fn step_frame(w: usize, h: usize, near: f32, far: f32) -> Vec<f32> {
    (0..w * h)
        .map(|i| if i % w < w / 2 { near } else { far })
        .collect()
}

#[test]
fn cleaning_drops_one_band_each_side_of_a_5cm_step_and_nothing_at_1cm() {
    let (w, h) = (16, 8);
    let p = CleanParams::default();
    let out = clean(&step_frame(w, h, 1.0, 1.05), w, h, &p);
    for y in 0..h {
        for x in 0..w {
            let dropped = out[y * w + x] == 0.0;
            assert_eq!(dropped, x == w / 2 - 1 || x == w / 2, "pixel {x},{y}");
        }
    }
    let out = clean(&step_frame(w, h, 1.0, 1.01), w, h, &p);
    assert!(out.iter().all(|&d| d > 0.0));
    // Range limits.
    let p2 = CleanParams {
        max_range: 1.005,
        ..p
    };
    let out = clean(&step_frame(w, h, 1.0, 1.01), w, h, &p2);
    assert_eq!(out.iter().filter(|&&d| d > 0.0).count(), w * h / 2);
}

/// One 64 × 48 frame of the room (the modelled camera noise) and its pose.
fn one_room_frame() -> (super::synth::SynthStream, DMat4) {
    use super::synth::{look_pose, synth_stream, StreamSynthOptions};
    let pose = look_pose(DVec3::new(0.0, 0.0, 1.5), DVec3::new(-1.0, 0.6, -0.4));
    let o = StreamSynthOptions {
        width: 64,
        height: 48,
        truth_rays: 0,
        ..StreamSynthOptions::default()
    };
    (
        synth_stream(&crate::synth::Scene::room(), &[pose], &o),
        pose,
    )
}

fn small_params() -> StreamParams {
    let mut p = StreamParams {
        voxel: 0.05,
        history: false,
        ssao_scale: 1,
        ..StreamParams::default()
    };
    p.clean.edge = 0.15;
    p
}

#[test]
fn one_frame_gives_each_voxel_the_weighted_mean_of_its_pixels() {
    let (s, pose) = one_room_frame();
    let mut it = Integrator::new(small_params(), s.intrinsics);
    let (geo, ao, _) = it.clone().frame_ssao(&s.frames[0], pose);
    let st = it.add_frame(&s.frames[0], pose);
    assert!(st.integrated > 1000, "{st:?}");
    let p = it.params.clean;
    let mut sums: HashMap<u64, (f64, f64)> = HashMap::new();
    for (i, a) in ao.iter().enumerate() {
        let (Some(a), true) = (*a, geo.is_valid(i)) else {
            continue;
        };
        let w = frame::weight(geo.points[i], geo.normals[i], p.min_range, p.max_range);
        if !(w > 0.0) {
            continue;
        }
        let k = it
            .grid
            .key_of(pose.transform_point3(geo.points[i].as_dvec3()))
            .unwrap();
        let e = sums.entry(k).or_default();
        e.0 += (a * w) as f64;
        e.1 += w as f64;
    }
    assert_eq!(sums.len(), it.grid.len());
    for vp in it.grid.points() {
        let (aw, w) = sums[&vp.key];
        assert!(
            (vp.ao as f64 - aw / w).abs() < 1e-5,
            "{} vs {}",
            vp.ao,
            aw / w
        );
    }
}

#[test]
fn without_history_frame_order_does_not_matter() {
    use super::synth::{room_trajectory, synth_stream, StreamSynthOptions};
    let o = StreamSynthOptions {
        frames: 12,
        width: 48,
        height: 36,
        truth_rays: 0,
        ..StreamSynthOptions::default()
    };
    let s = synth_stream(&crate::synth::Scene::room(), &room_trajectory(12), &o);
    let run = |order: Vec<usize>| {
        let mut it = Integrator::new(small_params(), s.intrinsics);
        for i in order {
            it.add_frame(&s.frames[i], s.poses[i]);
        }
        it.grid.points()
    };
    let a = run((0..12).collect());
    let b = run((0..12).rev().collect());
    assert_eq!(a.len(), b.len());
    assert!(a.len() > 500);
    for (p, q) in a.iter().zip(&b) {
        assert_eq!(p.key, q.key);
        assert!((p.ao - q.ao).abs() < 1e-5);
        assert!((p.position - q.position).length() < 1e-5);
    }
}

#[test]
fn checkpoint_round_trips() {
    let mut g = VoxelGrid::new(0.02);
    for i in 0..500 {
        let f = i as f64;
        g.add(
            DVec3::new(f * 0.013, -f * 0.007, 1.0),
            Vec3::Y,
            0.3 + 0.001 * f as f32,
            0.5,
        );
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("ck");
    let head = grid::CheckpointHead {
        frames_done: 7,
        settings: 42,
    };
    grid::write_checkpoint(&p, &g, None, head).unwrap();
    let (g2, v2, h2) = grid::read_checkpoint(&p).unwrap();
    assert_eq!(h2, head);
    assert_eq!(g.points(), g2.points());
    assert!(v2.is_none());
    // With a history volume: the same casts after reading it back.
    let (vol, k) = noisy_plane_volume(DMat4::IDENTITY, 5, 0.0);
    grid::write_checkpoint(&p, &g, Some(&vol), head).unwrap();
    let (g3, v3, _) = grid::read_checkpoint(&p).unwrap();
    assert_eq!(g.points(), g3.points());
    let v3 = v3.expect("volume");
    assert_eq!((v3.voxel, v3.mu, &v3.keys), (vol.voxel, vol.mu, &vol.keys));
    for x in [0.0f32, 10.0, -20.0] {
        let dir = Vec3::new(x / k.fx as f32, 0.1, 1.0);
        let a = vol.cast(&DMat4::IDENTITY, dir, 0.5, 4.0);
        assert_eq!(a, v3.cast(&DMat4::IDENTITY, dir, 0.5, 4.0));
        assert!(a.is_some());
    }
    // A truncated checkpoint is refused, not half read.
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() - 100]).unwrap();
    assert!(grid::read_checkpoint(&p).is_err());
}

/// A volume of `frames` frames (64 × 48, 60° wide) of a wall 2 m in front of camera-to-world
/// `pose`, tilted 30° about the camera's y axis, with Gaussian depth noise `sigma` (metres).
fn noisy_plane_volume(pose: DMat4, frames: u64, sigma: f64) -> (tsdf::Tsdf, Intrinsics) {
    let (w, h) = (64usize, 48usize);
    let f = 32.0 / (30f64.to_radians()).tan();
    let k = Intrinsics {
        fx: f,
        fy: f,
        cx: 31.5,
        cy: 23.5,
    };
    let mut vol = tsdf::Tsdf::new(0.02);
    let n = DVec3::new(
        -(30f64.to_radians()).sin(),
        0.0,
        -(30f64.to_radians()).cos(),
    );
    for fr in 0..frames {
        let mut rng = crate::rng::SplitMix64::new(7, fr);
        let depth: Vec<f32> = (0..w * h)
            .map(|i| {
                let dir = DVec3::new(
                    ((i % w) as f64 - k.cx) / f,
                    ((i / w) as f64 - k.cy) / f,
                    1.0,
                );
                // The plane n·p = n·(0, 0, 2) along the ray p = t·dir.
                let t = n.dot(DVec3::new(0.0, 0.0, 2.0)) / n.dot(dir);
                (t + sigma * rng.gaussian()) as f32
            })
            .collect();
        vol.integrate(&tsdf::DepthView {
            depth: &depth,
            width: w,
            height: h,
            k,
            pose,
        });
    }
    (vol, k)
}

/// The exact z-depth of the tilted wall of [`noisy_plane_volume`] along camera ray `dir`.
fn plane_depth(dir: Vec3) -> f64 {
    let n = DVec3::new(
        -(30f64.to_radians()).sin(),
        0.0,
        -(30f64.to_radians()).cos(),
    );
    n.dot(DVec3::new(0.0, 0.0, 2.0)) / n.dot(dir.as_dvec3())
}

#[test]
fn history_volume_averages_depth_noise_away() {
    // Far from the world origin and at negative coordinates, so blocks straddle the signs.
    let pose = DMat4::from_translation(DVec3::new(-1234.56, 7.89, -0.3));
    let sigma = 0.01;
    let (vol, k) = noisy_plane_volume(pose, 40, sigma);
    let (mut sum, mut n) = (0.0, 0);
    for y in (4..44).step_by(3) {
        for x in (4..60).step_by(3) {
            let dir = Vec3::new(
                (x as f32 - k.cx as f32) / k.fx as f32,
                (y as f32 - k.cy as f32) / k.fy as f32,
                1.0,
            );
            let t = vol.cast(&pose, dir, 0.5, 6.0).expect("the wall");
            sum += (t - plane_depth(dir)).abs();
            n += 1;
        }
    }
    let err = sum / n as f64;
    eprintln!("mean |depth error| {err} m over {n} rays");
    // One frame's mean |error| is 0.8 σ; forty frames average it to a fraction of that
    // (what remains is the running mean's noise and the trilinear reading between voxels).
    assert!(err < 0.25 * sigma, "mean |depth error| {err} m");
    // A ray beside the wall meets nothing, and nothing is met in front of it.
    assert_eq!(vol.cast(&pose, Vec3::new(5.0, 0.0, 1.0), 0.5, 6.0), None);
    assert_eq!(vol.cast(&pose, Vec3::new(0.0, 0.0, 1.0), 0.5, 1.5), None);
}

#[test]
fn depth_png_round_trips_and_intrinsics_parse() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("d.png");
    let f = DepthFrame {
        width: 3,
        height: 2,
        depth: vec![0.0, 1.0, 1.234, 65.535, 2.5, 0.001],
    };
    frames::write_depth_png(&p, &f, 1000.0).unwrap();
    let g = frames::read_depth_png(&p, 1000.0).unwrap();
    assert_eq!(g.width, 3);
    for (a, b) in f.depth.iter().zip(&g.depth) {
        assert!((a - b).abs() < 1e-6);
    }
    let k = frames::parse_intrinsics("525 525 319.5 239.5").unwrap();
    assert_eq!(
        k,
        Intrinsics {
            fx: 525.0,
            fy: 525.0,
            cx: 319.5,
            cy: 239.5
        }
    );
    let j = dir.path().join("cam.json");
    std::fs::write(
        &j,
        r#"{"width": 640, "height": 480, "intrinsic_matrix": [525, 0, 0, 0, 525, 0, 319.5, 239.5, 1]}"#,
    )
    .unwrap();
    assert_eq!(frames::parse_intrinsics(j.to_str().unwrap()).unwrap(), k);
    assert!(frames::parse_intrinsics("1 2 3").is_err());
    // The intrinsics.txt that `mvao synth --frames` writes.
    let t = dir.path().join("intrinsics.txt");
    std::fs::write(&t, "525 525 319.5 239.5\n").unwrap();
    assert_eq!(frames::parse_intrinsics(t.to_str().unwrap()).unwrap(), k);
    std::fs::write(&t, "525 525\n").unwrap();
    let e = frames::parse_intrinsics(t.to_str().unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("intrinsics.txt") && e.contains("fx fy cx cy"),
        "{e}"
    );
}

#[test]
fn tum_and_log_trajectories_read() {
    let dir = tempfile::tempdir().unwrap();
    let tum = dir.path().join("t.txt");
    std::fs::write(
        &tum,
        "# comment\n1.0 1 2 3 0 0 0 1\n2.0 0 0 0 0 0 0.7071068 0.7071068\n",
    )
    .unwrap();
    let t = frames::read_trajectory(&tum).unwrap();
    assert_eq!(t.stamps, vec![1.0, 2.0]);
    assert_eq!(t.poses[0].w_axis.truncate(), DVec3::new(1.0, 2.0, 3.0));
    let x = t.poses[1].transform_vector3(DVec3::X);
    assert!((x - DVec3::Y).length() < 1e-6);
    let log = dir.path().join("t.log");
    std::fs::write(&log, "0 0 1\n1 0 0 0.5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
    let t = frames::read_trajectory(&log).unwrap();
    assert_eq!(
        t.poses,
        vec![DMat4::from_translation(DVec3::new(0.5, 0.0, 0.0))]
    );
    std::fs::write(&log, "0 0 1\n1 0 0 0.5\n0 1 0 x\n0 0 1 0\n0 0 0 1\n").unwrap();
    let e = frames::read_trajectory(&log).unwrap_err().to_string();
    assert!(e.contains("t.log") && e.contains("line 3"), "{e}");
}

#[test]
fn frame_pixels_project_back_to_their_own_pixels() {
    let k = Intrinsics {
        fx: 100.0,
        fy: 90.0,
        cx: 31.5,
        cy: 23.5,
    };
    let proj = frame::projection(&k, 64, 48);
    let depth = vec![2.0f32; 64 * 48];
    let pts = frame::unproject(&depth, 64, &k);
    for (i, p) in pts.iter().enumerate() {
        let pr = proj.project(*p).unwrap();
        assert_eq!(proj.pixel_index(pr.x, pr.y), Some(i));
    }
    let n = frame::depth_normals(&pts, 64, 48);
    assert!(n
        .iter()
        .all(|v| (*v - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-5));
}

/// A TUM trajectory of `n` poses at 30 Hz from `t0`, pose `k` translated to `x = k`.
fn tum_trajectory(t0: f64, n: usize) -> frames::Trajectory {
    frames::Trajectory {
        poses: (0..n)
            .map(|k| DMat4::from_translation(DVec3::new(k as f64, 0.0, 0.0)))
            .collect(),
        stamps: (0..n).map(|k| t0 + k as f64 / 30.0).collect(),
    }
}

fn xs(poses: &[DMat4]) -> Vec<f64> {
    poses.iter().map(|p| p.w_axis.x).collect()
}

#[test]
fn tum_poses_are_matched_to_timestamped_frames_by_time() {
    let traj = tum_trajectory(1305031102.0, 30);
    let path = std::path::Path::new("groundtruth.txt");
    let named = |ts: &[f64]| -> Vec<std::path::PathBuf> {
        ts.iter()
            .map(|t| format!("depth/{t:.6}.png").into())
            .collect()
    };
    // Fewer frames than poses, each 4 ms off a pose: the nearest one.
    let f = named(&[1305031102.004, 1305031102.329, 1305031102.670]);
    let p = frames::match_poses(&f, &traj, path, 0.02).unwrap();
    assert_eq!(xs(&p), vec![0.0, 10.0, 20.0]);
    // As many frames as poses but starting later: time, not order, decides.
    let ts: Vec<f64> = (0..30)
        .map(|k| 1305031102.0 + (k + 5).min(29) as f64 / 30.0)
        .collect();
    let p = frames::match_poses(&named(&ts), &traj, path, 0.02).unwrap();
    assert_eq!(p[0].w_axis.x, 5.0);
    assert_eq!(p[29].w_axis.x, 29.0);
    // A frame far from every pose is refused, naming the trajectory and the frame.
    let f = named(&[1305031102.004, 1305031109.0]);
    let e = frames::match_poses(&f, &traj, path, 0.02)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("groundtruth.txt")
            && e.contains("1305031109.000000.png")
            && e.contains("s away"),
        "{e}"
    );
}

#[test]
fn frames_without_timestamps_are_matched_by_order_only_when_counts_agree() {
    let traj = tum_trajectory(1305031102.0, 3);
    let path = std::path::Path::new("groundtruth.txt");
    let f: Vec<std::path::PathBuf> = (0..3).map(|k| format!("{k:05}.png").into()).collect();
    let p = frames::match_poses(&f, &traj, path, 0.02).unwrap();
    assert_eq!(xs(&p), vec![0.0, 1.0, 2.0]);
    let e = frames::match_poses(&f[..2], &traj, path, 0.02)
        .unwrap_err()
        .to_string();
    assert!(e.contains("3 poses for 2 depth frames"), "{e}");
    // A .log trajectory carries no times.
    let log = frames::Trajectory {
        stamps: Vec::new(),
        ..traj
    };
    let e = frames::match_poses(&f[..2], &log, std::path::Path::new("t.log"), 0.02)
        .unwrap_err()
        .to_string();
    assert!(e.contains("t.log") && e.contains("matched by order"), "{e}");
}

/// A 16 × 16 z-depth frame at `z`, with the pixels of block (1, 1) of 4 × 4 set to `zs`
/// except one in four, so that block is too sparse for a reduced-resolution value.
fn sparse_block_frame(z: f32, zs: f32) -> Vec<f32> {
    let mut d = vec![z; 256];
    for y in 4..8 {
        for x in 4..8 {
            d[y * 16 + x] = if x % 2 == 0 && y % 2 == 0 { zs } else { 0.0 };
        }
    }
    d
}

#[test]
fn kept_pixels_of_a_sparse_block_read_a_neighbour_on_their_surface_only() {
    // Blocks 12.5 cm wide at 2 m: a neighbour may lend its value within 25 cm.
    let k = Intrinsics {
        fx: 64.0,
        fy: 64.0,
        cx: 7.5,
        cy: 7.5,
    };
    let p = small_params().ssao;
    let values = |zs: f32| {
        let depth = sparse_block_frame(2.0, zs);
        let own = frame::geometry(&depth, 16, 16, &k);
        let (low, lw, lh) = frame::downsample(&depth, 16, 16, 4);
        let low = frame::geometry(&low, lw, lh, &k.scaled_down(4));
        let ao = frame::frame_ssao(&low, &k.scaled_down(4), &p, &own, &k, 4);
        (own, ao)
    };
    // On the plane: every kept pixel of the sparse block gets a value.
    let (own, ao) = values(2.0);
    let block: Vec<usize> = (0..256)
        .filter(|i| (4..8).contains(&(i % 16)) && (4..8).contains(&(i / 16)) && own.is_valid(*i))
        .collect();
    assert!(!block.is_empty());
    assert!(block.iter().all(|&i| ao[i].is_some()), "{ao:?}");
    // Half a metre in front of the plane: a depth edge, no value borrowed across it.
    let (own, ao) = values(1.5);
    let front: Vec<usize> = block.iter().copied().filter(|&i| own.is_valid(i)).collect();
    assert!(!front.is_empty());
    assert!(front.iter().all(|&i| ao[i].is_none()), "{ao:?}");
}

#[test]
fn history_volume_starts_at_the_first_frame_with_a_depth() {
    let (s, pose) = one_room_frame();
    let mut it = Integrator::new(
        StreamParams {
            history: true,
            ..small_params()
        },
        s.intrinsics,
    );
    let empty = DepthFrame {
        depth: vec![0.0; 64 * 48],
        ..s.frames[0].clone()
    };
    assert_eq!(it.add_frame(&empty, pose).integrated, 0);
    assert!(it.volume.is_none());
    let st = it.add_frame(&s.frames[0], pose);
    assert!(st.integrated > 1000, "{st:?}");
    let vol = it
        .volume
        .as_ref()
        .expect("a volume after a frame with depth");
    // A pixel's footprint at the median depth (about 3 m at 55 px per radian), never under
    // the grid's 5 cm.
    assert!((0.05..0.07).contains(&vol.voxel), "{}", vol.voxel);
    assert!(vol.observed() > 1000);
}
