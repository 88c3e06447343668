//! Leaving out (point, view) pairs that cannot correspond must never change the merge: on a
//! row of rooms joined by doorways (most pairs of points and partner views are far apart, or
//! hidden from each other), in a local and in a georeferenced frame, for scanners, cameras and
//! linear sweeps, the merged values are bit-identical with and without the cells, and the
//! cells leave out most pairs that find no partner.

use glam::{DMat4, DVec3};
use mvao::synth::{scan_scene, station_layout, SceneKind};
use mvao::testing::merge::cull::PointCells;
use mvao::testing::merge::{self, MergeParams};
use mvao::testing::pipeline::occlusion::prepare_view;
use mvao::testing::projection::SensorModel;
use mvao::testing::scan::Scan;
use mvao::testing::sensor::ProjectionChoice;
use mvao::testing::ssao::{Estimator, SsaoParams};
use mvao::testing::view::{merge_views, view_cells, view_maps};

fn site(offset: DVec3, model: SensorModel) -> Vec<Scan> {
    let kind = SceneKind::Suite { rooms: 2 };
    let scene = kind.scene();
    station_layout(kind, model, 8, 480, 240)
        .iter()
        .enumerate()
        .map(|(i, st)| {
            let mut s = scan_scene(&scene, st, 0.002, i as u64, &format!("s{i}"));
            s.pose = DMat4::from_translation(offset) * st.pose();
            s
        })
        .collect()
}

fn check(offset: DVec3, model: SensorModel) {
    let scans = site(offset, model);
    let sp = SsaoParams {
        estimator: Estimator::Horizon,
        radius: 0.2,
        tmax: 0.4,
        falloff: Default::default(),
        samples: 32,
        directions: 4,
        steps: 4,
        seed: 0,
        blur: true,
        sampling: Default::default(),
    };
    let views: Vec<_> = scans
        .iter()
        .map(|s| prepare_view(s, ProjectionChoice::Auto, &sp).expect("prepare"))
        .collect();
    for neighbors in [1, 3] {
        let mp = MergeParams {
            neighbors,
            dmin: 0.0,
            dmax: 20.0,
            border_px: 16.0,
            spacing: 0.04,
            largest_all_round: false,
        };
        let packed = view_maps(&views, &mp);
        let cells = view_cells(&views, &scans);
        let plain = merge_views(&views, &packed, &scans, None);
        let culled = merge_views(&views, &packed, &scans, Some(&cells));
        let none = vec![false; scans.len()];
        let (mut left_out, mut tried) = (0, 0);
        for (i, (s, v)) in scans.iter().zip(&views).enumerate() {
            let (own, _) = v.point_ssao();
            let pc = PointCells::new(&s.points, &v.radii, s.pose);
            let run = |mv, pc| {
                merge::merge_scan(
                    i,
                    &s.points,
                    &v.radii,
                    &own,
                    &v.pixel,
                    pc,
                    mv,
                    &none,
                    &mp,
                    &|_| {},
                )
            };
            let (a, sa) = run(&plain, None);
            let (b, sb) = run(&culled, Some(&pc));
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&a), bits(&b), "scan {i}, N = {neighbors}");
            assert_eq!(sa.samples_kept, sb.samples_kept, "scan {i}");
            assert_eq!(sa.zero_weight, sb.zero_weight, "scan {i}");
            // An equirect view projects every point; a camera's pairs behind it count as
            // neither tried nor projected without the cells, but as left out with them.
            assert!(sb.point_views <= sa.point_views, "scan {i}");
            if model == SensorModel::Equirect {
                assert_eq!(sa.point_views, sb.point_views + sb.culled, "scan {i}");
            }
            assert!(sb.samples_kept > 0);
            left_out += sb.culled;
            tried += sa.point_views;
            if neighbors == 1 {
                // With one sample per pair, samples kept = pairs that found a partner: the
                // cells leave out most pairs that would find none (points hidden from the
                // view as well as points far from it).
                assert!(
                    3 * sb.samples_kept > 2 * sb.point_views,
                    "scan {i}: {} of {} projected pairs found a partner",
                    sb.samples_kept,
                    sb.point_views
                );
            }
        }
        // Two rooms, four stations each: most points are far from what the other room's
        // stations stored.
        assert!(
            left_out * 5 > tried,
            "only {left_out} of {tried} point-views left out"
        );
    }
}

#[test]
fn culling_leaves_the_merge_unchanged() {
    check(DVec3::ZERO, SensorModel::Equirect);
}

#[test]
fn culling_leaves_the_merge_of_cameras_and_sweeps_unchanged() {
    check(DVec3::ZERO, SensorModel::Perspective);
    check(DVec3::ZERO, SensorModel::Ortho);
}

#[test]
fn culling_leaves_the_merge_unchanged_in_a_georeferenced_frame() {
    check(
        DVec3::new(512_345.678, 5_234_567.891, 312.5),
        SensorModel::Equirect,
    );
}
