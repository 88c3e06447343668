//! Projection round trips for the three sensor models: pixel → ray → point → pixel, across the
//! equirect azimuth seam and next to its poles, and with uneven-step grid warps.

use glam::{Mat2, Mat3, Vec2, Vec3};
use mvao::projection::{Model, Projection, Warp};

fn full_sphere(w: usize, h: usize) -> Projection {
    let tau = std::f32::consts::TAU;
    Projection::new(
        Model::Equirect {
            rot: Mat3::IDENTITY,
            az_ref: 0.3,
            sx: -(w as f32) / tau,
            ox: w as f32 / 2.0,
            sy: -(h as f32) / std::f32::consts::PI,
            oy: h as f32 / 2.0,
        },
        w,
        h,
        true,
    )
}

fn round_trip(p: &Projection, x: f32, y: f32, depth: f32, tol: f32) {
    let q = p.unproject(x, y, depth);
    let pr = p.project(q).expect("projects");
    let dx = (pr.x - x).rem_euclid(p.width as f32);
    let dx = dx.min(p.width as f32 - dx);
    assert!(
        dx < tol && (pr.y - y).abs() < tol,
        "({x},{y}) → {q:?} → ({},{})",
        pr.x,
        pr.y
    );
    assert!(
        (pr.depth - depth).abs() < 1e-3 * depth.max(1.0),
        "depth {} vs {depth}",
        pr.depth
    );
}

#[test]
fn equirect_round_trips_everywhere_including_seam() {
    let p = full_sphere(720, 360);
    for iy in 0..36 {
        for ix in 0..72 {
            round_trip(
                &p,
                ix as f32 * 10.0 + 0.5,
                iy as f32 * 10.0 + 0.5,
                7.0,
                1e-2,
            );
        }
    }
    // Either side of the seam: the first and last columns are neighbours.
    for x in [0.01f32, 719.99] {
        round_trip(&p, x, 100.5, 3.0, 2e-2);
    }
    let a = p.project(p.unproject(0.2, 100.5, 3.0)).unwrap();
    let b = p.project(p.unproject(719.8, 100.5, 3.0)).unwrap();
    assert_eq!(p.pixel_index(a.x, a.y), Some(100 * 720));
    assert_eq!(p.pixel_index(b.x, b.y), Some(100 * 720 + 719));
    assert_eq!(p.pixel_at(-1, 100), Some(100 * 720 + 719), "x wraps");
    assert_eq!(p.pixel_at(720, 100), Some(100 * 720));
}

#[test]
fn equirect_near_the_poles() {
    let p = full_sphere(720, 360);
    // Rows next to the poles: azimuth is ill-conditioned but the pixel must still come back.
    for y in [0.5f32, 1.5, 358.5, 359.5] {
        for x in [0.5f32, 200.5, 719.5] {
            round_trip(&p, x, y, 5.0, 5e-2);
        }
    }
    // The poles themselves project into the first/last row.
    let top = p.project(Vec3::new(0.0, 0.0, 2.0)).unwrap();
    let bottom = p.project(Vec3::new(0.0, 0.0, -2.0)).unwrap();
    assert!(top.y.abs() < 1e-3 && (bottom.y - 360.0).abs() < 1e-3);
    // The disk widens in x near the poles to stay a disk on the sphere, capped at half a row.
    let (rx_eq, ry_eq) = p.disk_radius(0.1, 2.0, 10.0, 180.0);
    let (rx_pole, ry_pole) = p.disk_radius(0.1, 2.0, 10.0, 2.0);
    assert!((ry_eq - ry_pole).abs() < 1e-4);
    assert!(rx_pole > 5.0 * rx_eq && rx_pole <= 360.0);
    assert!((rx_eq - ry_eq).abs() < 1e-3, "square pixels at the equator");
}

#[test]
fn perspective_round_trips_and_behind_camera() {
    let rot = Mat3::from_rotation_y(0.3) * Mat3::from_rotation_x(-0.2);
    let p = Projection::new(
        Model::Perspective {
            rot,
            a: Mat2::from_cols(Vec2::new(500.0, 3.0), Vec2::new(-2.0, 480.0)),
            c: Vec2::new(320.0, 240.0),
        },
        640,
        480,
        false,
    );
    for iy in 0..12 {
        for ix in 0..16 {
            round_trip(
                &p,
                ix as f32 * 40.0 + 0.5,
                iy as f32 * 40.0 + 0.5,
                2.5,
                1e-2,
            );
        }
    }
    let behind = rot.transpose() * Vec3::new(0.0, 0.0, -1.0);
    assert!(p.project(behind).is_none());
    assert!(p.project(Vec3::ZERO).is_none());
    assert!(p.pixel_index(-0.5, 10.0).is_none() && p.pixel_index(640.0, 10.0).is_none());
}

#[test]
fn ortho_round_trips_including_oblique_axis() {
    // The bunny-like case: x from columns, y mixed with a little z (an oblique sweep).
    let p = Projection::new(
        Model::Ortho {
            a: Vec3::new(2000.0, 0.0, 0.0),
            a0: 254.75,
            b: Vec3::new(-1.5, 1405.0, -31.7),
            b0: -21.7,
            toward: Vec3::new(0.0, 0.0225, 0.9997).normalize(),
            depth0: 0.3,
        },
        512,
        400,
        false,
    );
    for iy in 0..10 {
        for ix in 0..10 {
            round_trip(
                &p,
                ix as f32 * 51.0 + 0.5,
                iy as f32 * 40.0 + 0.5,
                0.2,
                1e-2,
            );
        }
    }
}

#[test]
fn warped_grid_axes_round_trip() {
    // Uneven row steps (a scanner head turning at varying speed).
    let knots: Vec<f32> = (0..50).map(|k| (k as f32).powf(1.3)).collect();
    let mut p = full_sphere(50, 40);
    p.wrap_x = false;
    p.warp_x = Warp::new(knots.clone());
    assert!(
        Warp::new(vec![0.0, 1.0, 1.0]).is_none(),
        "knots must increase"
    );
    let w = p.warp_x.clone().unwrap();
    for (k, &kn) in knots.iter().enumerate().take(49) {
        let x = k as f32 + 0.5;
        assert!((w.apply(w.invert(x)) - x).abs() < 1e-3);
        assert!((w.apply(kn) - x).abs() < 1e-4);
    }
}

#[test]
fn equirect_image_derivative_matches_finite_differences() {
    let mut p = full_sphere(1440, 720);
    if let Model::Equirect { rot, .. } = &mut p.model {
        *rot = Mat3::from_rotation_x(0.4) * Mat3::from_rotation_z(1.1);
    }
    let dirs = [Vec3::X, Vec3::Y, Vec3::Z, Vec3::new(0.3, -0.7, 0.2)];
    for k in 0..200 {
        let t = k as f32 * 0.37;
        let q = Vec3::new(3.0 * t.cos(), 2.0 * (1.3 * t).sin(), 1.5 * (0.7 * t).cos()) + 0.1;
        let at = p.project(q).expect("projects");
        for d in dirs {
            let (dx, dy) = p.image_derivative(q, d).expect("closed form");
            let h = 1e-3f32;
            let fd = p.project(q + d * h).expect("projects");
            let mut fx = fd.x - at.x;
            fx -= p.width as f32 * (fx / p.width as f32).round();
            let (fx, fy) = (fx / h, (fd.y - at.y) / h);
            let scale = dx.abs().max(dy.abs()).max(1.0);
            assert!(
                (fx - dx).abs() < 0.02 * scale && (fy - dy).abs() < 0.02 * scale,
                "{q:?} {d:?}: ({dx}, {dy}) vs ({fx}, {fy})"
            );
        }
    }
    // Undefined at the sensor itself.
    assert!(p.image_derivative(Vec3::ZERO, Vec3::X).is_none());
}
