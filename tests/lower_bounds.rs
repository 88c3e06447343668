//! Plain ambient occlusion (`t_max = ∞`) merged from stations that look all round: each
//! station's far field takes what lies behind its surfaces as solid, so its value is a lower
//! bound of the truth, and the merge takes the largest such value instead of the weighted
//! average (`--occlusion average`). The rule on a view's maps, and end to end on a colonnade
//! under open sky scored against rays cast at the exact mesh, beside the default (`auto`),
//! which shades those stations' points by the union instead.

mod common;

use common::{mvao_ok, report, synth_site};
use glam::DVec3;
use mvao::synth::{scan_scene, Scene, Station};
use mvao::testing::gbuffer::EMPTY;
use mvao::testing::merge::{merge_scan, MergeParams, View, ViewMaps};
use mvao::testing::pipeline::occlusion::prepare_view;
use mvao::testing::projection::Projection;
use mvao::testing::sensor::ProjectionChoice;
use mvao::testing::ssao::{Estimator, SsaoParams};

/// Stations of a mesh `scene` under open sky with a 32-ray truth at `t_max = ∞`; their files
/// and the truth's directory.
fn open_site(
    dir: &std::path::Path,
    scene: &str,
    stations: u32,
    w: u32,
    h: u32,
) -> (Vec<std::path::PathBuf>, std::path::PathBuf) {
    let site = dir.join(scene);
    let mut extra = vec!["--no-normals", "--reference-rays", "32"];
    extra.extend(["--reference-tmax", "inf", "--reference-falloff", "none"]);
    let files = synth_site(&site, scene, stations, w, h, &extra);
    (files, site.join("reference-mesh"))
}

/// `mvao merge` of `files` at `t_max = ∞` with `args`, scored against `truth`: its report.
fn merge_at_inf(
    files: &[std::path::PathBuf],
    truth: &std::path::Path,
    args: &[&str],
    out: &std::path::Path,
) -> serde_json::Value {
    let mut all = vec!["merge", "-q", "--no-preview", "--radius", "0.2"];
    all.extend(["--tmax", "inf", "--falloff", "none"]);
    all.extend_from_slice(args);
    all.extend(["--reference", truth.to_str().unwrap()]);
    all.extend(["-o", out.to_str().unwrap()]);
    all.extend(files.iter().map(|f| f.to_str().unwrap()));
    mvao_ok(&all);
    report(out)
}

#[test]
fn all_round_views_give_their_largest_value_whatever_the_order() {
    let station = Station::equirect(DVec3::new(0.0, 0.0, 1.5), 0.0, 120, 60);
    let mut scan = scan_scene(&Scene::room(), &station, 0.0, 1, "s");
    scan.pose = station.pose();
    let sp = SsaoParams {
        estimator: Estimator::Horizon,
        radius: 0.2,
        tmax: 0.4,
        falloff: Default::default(),
        samples: 8,
        directions: 4,
        steps: 4,
        seed: 1,
        blur: false,
        sampling: Default::default(),
    };
    let v = prepare_view(&scan, ProjectionChoice::Auto, &sp).unwrap();
    let round = v.sensor.projection.clone();
    assert!(round.all_round());
    // The same map without its wrap: a sensor that did not look all round.
    let framed = Projection {
        wrap_x: false,
        ..round.clone()
    };
    assert!(!framed.all_round());
    let n = v.gbuf.point.len();
    let border = vec![1e6f32; n];
    // Every view holds the scan's own geometry with one AO value; weights are equal.
    let merged = |largest: bool, order: &[(bool, f32)]| {
        let prm = MergeParams {
            neighbors: 1,
            dmin: 0.0,
            dmax: 0.0,
            border_px: 64.0,
            spacing: 0.0,
            largest_all_round: largest,
        };
        let maps: Vec<ViewMaps> = order
            .iter()
            .map(|&(_, a)| ViewMaps::new(&round, &v.gbuf, &vec![a; n], &border, &prm))
            .collect();
        let views: Vec<View<'_>> = order
            .iter()
            .zip(&maps)
            .map(|(&(r, _), maps)| View {
                proj: if r { &round } else { &framed },
                maps,
                pose: scan.pose,
                cells: None,
            })
            .collect();
        let own = vec![0.0f32; scan.len()];
        let skip = vec![false; views.len()];
        let (ao, _) = merge_scan(
            0,
            &scan.points,
            &v.radii,
            &own,
            &v.pixel,
            None,
            &views,
            &skip,
            &prm,
            &|_| {},
        );
        (0..ao.len())
            .filter(|&k| v.pixel[k] != EMPTY)
            .map(|k| ao[k])
            .collect::<Vec<f32>>()
    };
    let check = |ao: Vec<f32>, want: f32, what: &str| {
        assert!(ao.len() > 1000, "{what}: {} points seen", ao.len());
        let off = ao.iter().filter(|a| (*a - want).abs() > 1e-5).count();
        // A point whose only match sits at a grazing pixel may weigh zero in every view.
        assert!(
            off * 100 < ao.len(),
            "{what}: {off} of {} not {want}",
            ao.len()
        );
    };
    // Two all-round views (0.3, 0.6) and a framed one (0.95).
    let views = [(true, 0.3), (true, 0.6), (false, 0.95)];
    check(merged(false, &views), (0.3 + 0.6 + 0.95) / 3.0, "average");
    check(merged(true, &views), 0.6, "largest, framed view last");
    let reversed = [(false, 0.95), (true, 0.6), (true, 0.3)];
    check(merged(true, &reversed), 0.6, "framed view first");
    // Framed views alone are still averaged.
    check(
        merged(true, &[(false, 0.2), (false, 0.4)]),
        0.3,
        "framed only",
    );
}

#[test]
fn all_round_stations_merge_plain_occlusion_by_their_largest_value_or_by_the_union() {
    let tmp = tempfile::tempdir().unwrap();
    let (files, truth) = open_site(tmp.path(), "colonnade", 3, 240, 120);
    let run = |args: &[&str], out: &str| merge_at_inf(&files, &truth, args, &tmp.path().join(out));
    let r = run(&["--occlusion", "average"], "average");
    assert_eq!(r["parameters"]["merge"]["largest_all_round"], true);
    for s in r["scans"].as_array().unwrap() {
        let (by_largest, points) = (s["merged_by_largest"].as_u64(), s["points"].as_u64());
        // Every point seen by an all-round station (all of them, here) took the largest.
        assert!(by_largest.unwrap() * 100 >= points.unwrap() * 95, "{s}");
    }
    let acc = |k: &str, m: &str| r["accuracy"][k][m].as_f64().unwrap();
    let (single, merged) = (acc("ssao", "e_a"), acc("result", "e_a"));
    // Every station reads the colonnade darker than it is; the largest value is the nearest
    // to the truth (the weighted average was darker than each station's own value).
    assert!(acc("ssao", "bias") < -0.05, "{}", acc("ssao", "bias"));
    assert!(
        merged < 0.85 * single,
        "merged e_A {merged}, single view {single}"
    );
    assert!(acc("result", "bias") > acc("ssao", "bias") + 0.02);

    // The default shades every point of these stations by the union, whose free-space
    // evidence undoes what each station's far field takes as solid.
    let u = run(&[], "auto");
    assert_eq!(u["parameters"]["occlusion"], "auto");
    assert_eq!(u["parameters"]["union"]["rays"], 8);
    for s in u["scans"].as_array().unwrap() {
        assert_eq!(s["union_points"], s["points"], "{s}");
        assert_eq!(s["merged_by_largest"], 0, "{s}");
    }
    let united = u["accuracy"]["result"]["e_a"].as_f64().unwrap();
    let bias = u["accuracy"]["result"]["bias"].as_f64().unwrap();
    assert!(
        united < 0.6 * merged,
        "union e_A {united}, largest {merged}"
    );
    assert!(
        bias.abs() < acc("result", "bias").abs(),
        "union bias {bias}"
    );
}

#[test]
fn the_union_marches_each_point_through_a_few_of_many_all_round_views() {
    // Six stations under open sky: at ∞ every station holds every point's image, so each
    // point's rays go through four of them by default instead of all six.
    let tmp = tempfile::tempdir().unwrap();
    let (files, truth) = open_site(tmp.path(), "porch", 6, 200, 100);
    let run = |args: &[&str], out: &str| merge_at_inf(&files, &truth, args, &tmp.path().join(out));
    let capped = run(&[], "capped");
    let all = run(&["--union-views", "0"], "all");
    assert_eq!(capped["parameters"]["union"]["views"], 4);
    assert_eq!(all["parameters"]["union"]["views"], 0);
    let e = |r: &serde_json::Value, k: &str| r["accuracy"][k]["e_a"].as_f64().unwrap();
    let (e4, e6, single) = (e(&capped, "result"), e(&all, "result"), e(&capped, "ssao"));
    eprintln!("single view {single:.4}, union of 4 views {e4:.4}, of all 6 {e6:.4}");
    assert!(
        e4 < 0.5 * single,
        "union of 4 views {e4}, single view {single}"
    );
    assert!(
        e4 <= 1.1 * e6 + 0.002,
        "union of 4 views {e4}, of all 6 {e6}"
    );
}
