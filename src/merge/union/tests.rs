//! Unit tests of the union's bounds and runs.

use super::*;
use crate::gbuffer::rasterize;
use crate::merge::MergeParams;
use glam::{Mat2, Mat3, Vec2};

/// A wavy height field with holes, 48 × 40 points 1 cm apart, seen by `proj` from
/// `pose` (its local frame → the field's), rasterized one point per pixel it falls in.
fn wavy_view(proj: &Projection, pose: DMat4) -> ViewMaps {
    let (w, h) = (proj.width, proj.height);
    let back = pose.inverse().as_mat4();
    let (mut px, mut depth, mut pts) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..48 * 40 {
        let (x, y) = ((i % 48) as f32 * 0.01, (i / 48) as f32 * 0.01);
        if (i * 7919) % 13 == 0 {
            continue; // holes
        }
        let z = 0.05 * (9.0 * x).sin() * (7.0 * y).cos();
        let q = back.transform_point3(Vec3::new(x, y, z));
        let Some(pr) = proj.project(q) else { continue };
        let (fx, fy) = (floor_i64(pr.x), floor_i64(pr.y));
        if let Some(c) = proj.pixel_at(fx, fy) {
            px.push(c as u32);
            depth.push(pr.depth);
            pts.push(q);
        }
    }
    let normals = vec![Vec3::Z; pts.len()];
    let rad = vec![0.006; pts.len()];
    let g = rasterize(w, h, &px, &depth, &pts, &normals, &rad);
    let prm = MergeParams::single_pixel(4.0);
    ViewMaps::new(proj, &g, &vec![1.0; w * h], &vec![1e3; w * h], &prm)
}

#[test]
fn runs_of_samples_agree_with_every_sample_they_cover() {
    let ortho = Projection::new(
        Model::Ortho {
            a: Vec3::new(80.0, 0.0, 0.0),
            a0: 2.0,
            b: Vec3::new(0.0, 80.0, 0.0),
            b0: 3.0,
            toward: Vec3::Z,
            depth0: 1.0,
        },
        44,
        36,
        false,
    );
    // A camera 0.6 m above the field's middle looking down, turned a little.
    let pinhole = Projection::new(
        Model::Perspective {
            rot: Mat3::from_rotation_z(0.3),
            a: Mat2::from_diagonal(Vec2::splat(90.0)),
            c: Vec2::new(40.0, 30.0),
        },
        80,
        60,
        false,
    );
    let down = DMat4::from_translation(glam::DVec3::new(0.24, 0.2, 0.6))
        * DMat4::from_rotation_x(std::f64::consts::PI);
    let mut rng = Rng::new(11, 0);
    let mut settled = [0usize; 2];
    for (proj, pose) in [(&ortho, DMat4::IDENTITY), (&pinhole, down)] {
        let maps = wavy_view(proj, pose);
        let front = FrontTiles::new(maps.width, &maps.near, |q| depth_in(proj, q.truncate()));
        let stored = pack_stored(proj, &maps);
        let l = Lens {
            proj,
            maps: &maps,
            rel: Affine3A::from_mat4(pose.inverse().as_mat4()),
            pixel: pixel_size(proj),
            front: Some(&front),
            stored: &stored,
        };
        for _ in 0..3000 {
            let mut r = || rng.next_f32();
            let a = Vec3::new(0.5 * r(), 0.4 * r(), 0.12 * r() - 0.06);
            let dir = Vec3::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize_or_zero();
            let len = 0.2 * r();
            let b = a + dir * len;
            let Some(run) = l.run(l.spot(a), l.spot(b), 0.004) else {
                continue;
            };
            settled[(run == Run::DeepOrEmpty) as usize] += 1;
            for k in 0..=16 {
                let seen = l.probe_spot(l.spot(a + dir * (len * k as f32 / 16.0)), 0.004);
                let agrees = match run {
                    Run::FrontOrEmpty => matches!(seen, Probe::Front | Probe::Nothing),
                    Run::DeepOrEmpty => matches!(seen, Probe::Deep | Probe::Nothing),
                };
                assert!(agrees, "{run:?} but {seen:?} at {k}/16 of {a} → {b}");
            }
        }
    }
    assert!(
        settled.iter().all(|&n| n > 100),
        "runs settled: {settled:?}"
    );
}

#[test]
fn a_ray_has_left_the_bounds_only_outside_and_moving_away() {
    let b = Bounds {
        lo: Vec3::new(-1.0, -2.0, 0.0),
        hi: Vec3::new(1.0, 2.0, 3.0),
    };
    let up = Vec3::Z;
    assert!(!b.left(Vec3::new(0.0, 0.0, 2.9), up), "inside");
    assert!(b.left(Vec3::new(0.0, 0.0, 3.1), up), "above, rising");
    assert!(!b.left(Vec3::new(0.0, 0.0, 3.1), -up), "above, coming back");
    // Outside along x while moving along x towards the box: not yet; once past, yes.
    let d = Vec3::new(1.0, 0.0, 0.1).normalize();
    assert!(!b.left(Vec3::new(-1.5, 0.0, 1.0), d));
    assert!(b.left(Vec3::new(1.5, 0.0, 1.0), d));
    // Parallel to a face beyond it stays beyond it.
    assert!(b.left(Vec3::new(0.0, 2.5, 1.0), Vec3::X));
    assert!(!Bounds::ALL.left(Vec3::splat(1e30), up));
}

#[test]
fn a_point_keeps_its_own_view_then_those_that_observed_it_finest_first() {
    let r = Reading {
        s: 0.0,
        d: 1.0,
        rad: 0.01,
        idx: 0,
        px: (0, 0),
    };
    // (class, pixel size): 0 own, 1 observed the point, 2 holds its image only.
    let mut held = vec![
        ((2, 0.001), 0, r),
        ((1, 0.05), 1, r),
        ((0, 0.09), 2, r),
        ((1, 0.02), 3, r),
        ((1, 0.02), 4, r),
        ((2, 0.0001), 5, r),
    ];
    let kept = keep_best(&mut held, 3);
    let order: Vec<usize> = held[..kept].iter().map(|e| e.1).collect();
    // Own, then the two finest observers (tied, so both kept by index), in view order.
    assert_eq!(order, [2, 3, 4]);
    let kept = keep_best(&mut held, 5);
    let mut order: Vec<usize> = held[..kept].iter().map(|e| e.1).collect();
    // Past the observers, the finer of the views that only hold the image.
    assert_eq!(order, [1, 2, 3, 4, 5]);
    // No cap, or a cap above the count: every view, untouched.
    assert_eq!(keep_best(&mut held, 0), 6);
    assert_eq!(keep_best(&mut held, 6), 6);
    order = held.iter().map(|e| e.1).collect();
    order.sort_unstable();
    assert_eq!(order, [0, 1, 2, 3, 4, 5]);
}
