//! Projection round trips for the three sensor models: pixel → ray → point → pixel, across the
//! equirect azimuth seam and next to its poles, and with uneven-step grid warps; and the
//! footprint of a ball holding every pixel its points project to.

use glam::{DVec3, Mat2, Mat3, Vec2, Vec3};
use mvao::testing::projection::{Model, Projection, Warp};
use mvao::testing::rng::Rng;

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

/// A 640×480 pinhole camera turned 0.3 rad about y, with pixel matrix `a`.
fn camera_640x480(a: Mat2) -> Projection {
    Projection::new(
        Model::Perspective {
            rot: Mat3::from_rotation_y(0.3),
            a,
            c: Vec2::new(320.0, 240.0),
        },
        640,
        480,
        false,
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

/// Every point of a ball lands in the ball's footprint (or outside the map when the footprint
/// is empty): equirect maps with and without wrap, seam, poles, warps, tilted sensors,
/// perspective and orthographic views; balls near and far, small and large.
#[test]
fn footprints_hold_every_projection_of_their_ball() {
    let mut tilted = full_sphere(1440, 720);
    tilted.model = match tilted.model {
        Model::Equirect {
            az_ref,
            sx,
            ox,
            sy,
            oy,
            ..
        } => Model::Equirect {
            rot: Mat3::from_rotation_x(0.4) * Mat3::from_rotation_z(1.1),
            az_ref,
            sx,
            ox,
            sy,
            oy,
        },
        m => m,
    };
    let mut partial = full_sphere(400, 300);
    partial.wrap_x = false;
    if let Model::Equirect { sx, ox, .. } = &mut partial.model {
        (*sx, *ox) = (-400.0, 200.0);
    }
    let mut warped = full_sphere(60, 40);
    warped.warp_x = Warp::new((0..60).map(|k| 0.5 + (k as f32).powf(1.2)).collect());
    warped.warp_y = Warp::new(
        (0..40)
            .map(|k| 0.5 + 2.0 * (k as f32) + 0.01 * (k * k) as f32)
            .collect(),
    );
    warped.wrap_x = false;
    let camera = camera_640x480(Mat2::from_cols(
        Vec2::new(300.0, 20.0),
        Vec2::new(-10.0, 310.0),
    ));
    let ortho = Projection::new(
        Model::Ortho {
            a: Vec3::new(100.0, 10.0, 0.0),
            a0: 50.0,
            b: Vec3::new(0.0, 80.0, 30.0),
            b0: 20.0,
            toward: Vec3::new(0.0, -0.35, 0.936_7).normalize(),
            depth0: 5.0,
        },
        300,
        200,
        false,
    );
    let views = [
        full_sphere(1440, 720),
        tilted,
        partial,
        warped,
        camera,
        ortho,
    ];
    let mut rng = Rng::new(7, 0);
    let mut u = || rng.next_f32() as f64 * 2.0 - 1.0;
    let (mut tried, mut outside, mut unbounded) = (0, 0, 0);
    for (vi, p) in views.iter().enumerate() {
        for ball in 0..400 {
            // Centres from 0.2 m to 40 m; radii from 1 mm to 2 m; some right on the seam
            // (−x after az_ref) or a pole.
            let dist = 0.2 * 200f64.powf(0.5 * (u() + 1.0));
            let mut dir = DVec3::new(u(), u(), u()).normalize();
            if ball % 10 == 0 {
                dir = DVec3::new(-(0.3f64.cos()), -(0.3f64.sin()), 0.01 * u()).normalize();
            } else if ball % 10 == 1 {
                dir = DVec3::new(0.01 * u(), 0.01 * u(), 1.0).normalize();
            }
            let c = dir * dist;
            let r = 0.001 * 2000f64.powf(0.5 * (u() + 1.0)) * dist.min(1.0);
            let Some(fp) = p.footprint(c, r, 0) else {
                unbounded += 1;
                continue;
            };
            tried += 1;
            for _ in 0..200 {
                let v = DVec3::new(u(), u(), u());
                let v = if v.length() > 1.0 { v.normalize() } else { v };
                let q = (c + v * r).as_vec3();
                let Some(pr) = p.project(q) else {
                    continue;
                };
                let Some(i) = p.pixel_index(pr.x, pr.y) else {
                    outside += 1;
                    continue;
                };
                let (x, y) = (i % p.width, i / p.width);
                assert!(
                    fp.spans > 0
                        && (fp.rows.0..=fp.rows.1).contains(&y)
                        && fp.col_spans().iter().any(|s| (s.0..=s.1).contains(&x)),
                    "view {vi}: ball {c:?} r {r}: point {q:?} at pixel ({x}, {y}) outside {fp:?}"
                );
            }
        }
    }
    assert!(
        tried > 2000 && outside > 0,
        "{tried} balls, {outside} points off the map"
    );
    assert!(
        unbounded > 0 && unbounded < 600,
        "{unbounded} balls with no bound"
    );
}

#[test]
fn footprints_say_when_there_is_no_bound() {
    let p = full_sphere(720, 360);
    // The ball holds the sensor.
    assert!(p.footprint(DVec3::new(0.1, 0.0, 0.0), 0.2, 1).is_none());
    assert!(p
        .footprint(DVec3::new(f64::NAN, 0.0, 0.0), 0.2, 1)
        .is_none());
    // Round a pole every column may be read; a small ball far away reads a few.
    let pole = p.footprint(DVec3::new(0.0, 0.0, 5.0), 0.1, 0).unwrap();
    assert_eq!(pole.col_spans(), &[(0, 719)]);
    let small = p.footprint(DVec3::new(5.0, 1.0, 0.5), 0.01, 1).unwrap();
    let cols: usize = small.col_spans().iter().map(|s| s.1 - s.0 + 1).sum();
    assert!(cols <= 6 && small.rows.1 - small.rows.0 <= 5, "{small:?}");
    // A camera: a ball crossing the image plane has no bound; one beside the image, no pixel.
    let cam = Projection::new(
        Model::Perspective {
            rot: Mat3::IDENTITY,
            a: Mat2::from_diagonal(Vec2::splat(100.0)),
            c: Vec2::new(50.0, 50.0),
        },
        100,
        100,
        false,
    );
    assert!(cam.footprint(DVec3::new(0.0, 0.0, 0.05), 0.1, 1).is_none());
    assert_eq!(
        cam.footprint(DVec3::new(10.0, 0.0, 1.0), 0.1, 1)
            .unwrap()
            .spans,
        0
    );
}

#[test]
fn four_points_project_as_one_at_a_time() {
    let knots: Vec<f32> = (0..50).map(|k| (k as f32).powf(1.3)).collect();
    let mut tilted = full_sphere(1440, 720);
    if let Model::Equirect { rot, az_ref, .. } = &mut tilted.model {
        *rot = Mat3::from_rotation_y(0.4) * Mat3::from_rotation_z(2.9);
        *az_ref = -3.1;
    }
    let mut warped = full_sphere(50, 40);
    warped.warp_x = Warp::new(knots.clone());
    warped.warp_y = Warp::new(knots[..40].to_vec());
    let camera = camera_640x480(Mat2::from_cols(
        Vec2::new(500.0, 3.0),
        Vec2::new(-2.0, 480.0),
    ));
    // Axes, signed zeros, the poles, behind the sensor, non-finite and huge coordinates.
    let special = [
        Vec3::ZERO,
        Vec3::new(-0.0, 0.0, 1.0),
        Vec3::new(0.0, -0.0, -1.0),
        Vec3::new(-1.0, 0.0, 0.0),
        Vec3::new(-1.0, -0.0, 0.0),
        Vec3::new(0.0, 2.0, 0.0),
        Vec3::new(0.0, -2.0, 0.0),
        Vec3::new(f32::NAN, 1.0, 1.0),
        Vec3::new(1.0, f32::INFINITY, 0.0),
        Vec3::new(3e19, -3e19, 1e19),
        Vec3::new(1e-30, 0.0, -1e-30),
    ];
    let mut rng = Rng::new(5, 0);
    let mut pts: Vec<Vec3> = special.to_vec();
    for _ in 0..4000 {
        let v = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
        pts.push(v * (0.01 + 30.0 * rng.next_f32()));
    }
    let bits = |p: Option<mvao::testing::projection::Projected>| {
        p.map(|p| (p.x.to_bits(), p.y.to_bits(), p.depth.to_bits()))
    };
    for proj in [&full_sphere(1440, 720), &tilted, &warped, &camera] {
        for (g, four) in pts.chunks_exact(4).enumerate() {
            let got = proj.project4([four[0], four[1], four[2], four[3]]);
            for (l, (&p, q)) in four.iter().zip(got).enumerate() {
                assert_eq!(bits(q), bits(proj.project(p)), "group {g} lane {l}: {p:?}");
            }
        }
    }
}

#[test]
fn four_lane_arctangent_is_the_scalar_one() {
    use glam::Vec4;
    use mvao::testing::projection::{atan2_4, fast_atan2};
    let v = [
        0.0f32,
        -0.0,
        1.0,
        -1.0,
        0.5,
        -2.5,
        1e-30,
        -3e38,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
        f32::MIN_POSITIVE,
    ];
    let pairs: Vec<(f32, f32)> = v
        .iter()
        .flat_map(|&y| v.iter().map(move |&x| (y, x)))
        .collect();
    for g in pairs.chunks_exact(4) {
        let y = Vec4::new(g[0].0, g[1].0, g[2].0, g[3].0);
        let x = Vec4::new(g[0].1, g[1].1, g[2].1, g[3].1);
        let got = atan2_4(y, x).to_array();
        for (l, &(y, x)) in g.iter().enumerate() {
            assert_eq!(
                got[l].to_bits(),
                fast_atan2(y, x).to_bits(),
                "atan2({y}, {x})"
            );
        }
    }
}
