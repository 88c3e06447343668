//! End-to-end runs on the bundled real scans: the ten Stanford bunny range scans (Cyberware,
//! `bun.conf`) and three 3DTK terrestrial stations (`alignment.mlp`).

mod common;

use common::*;
use mvao::config::ComputeParams;
use mvao::io::ply::PlyFile;
use mvao::pipeline;
use mvao::progress::Silent;
use mvao::testing::scan::normals;
use std::path::Path;

/// Runs `mvao merge` through the binary and checks the outputs of every scan.
fn run_and_check(dir: &str, extra: &[&str]) -> (tempfile::TempDir, serde_json::Value) {
    let out = tempfile::tempdir().unwrap();
    let scans = plys(dir);
    let mut args = vec!["merge", "-q", "-o", out.path().to_str().unwrap()];
    let s: Vec<String> = scans.iter().map(|p| p.display().to_string()).collect();
    args.extend(s.iter().map(|x| x.as_str()));
    args.extend(extra);
    let r = mvao(&args);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    for p in &scans {
        let stem = p.file_stem().unwrap().to_str().unwrap();
        let input = PlyFile::from_path(p).unwrap();
        let output = PlyFile::from_path(&out.path().join(format!("{stem}.mvao.ply"))).unwrap();
        let n = input.header.elements[0].count;
        assert_eq!(output.header.elements[0].count, n, "{stem}: vertex count");
        // Every input property and element is kept, values unchanged.
        for (ei, e) in input.header.elements.iter().enumerate() {
            assert_eq!(output.header.elements[ei].name, e.name);
            for pr in &e.props {
                if let mvao::io::ply::PropertyKind::Scalar(_) = pr.kind {
                    assert_eq!(
                        input.scalar_column(&e.name, &pr.name),
                        output.scalar_column(&e.name, &pr.name),
                        "{stem}: {}.{}",
                        e.name,
                        pr.name
                    );
                } else {
                    assert_eq!(
                        input.list_column(&e.name, &pr.name),
                        output.list_column(&e.name, &pr.name)
                    );
                }
            }
        }
        let ao = output.scalar_column("vertex", "ao").unwrap();
        assert!(
            ao.iter().all(|a| a.is_finite() && (0.0..=1.0).contains(a)),
            "{stem}: ao range"
        );
        let (mn, mx) = ao
            .iter()
            .fold((1f64, 0f64), |(a, b), &v| (a.min(v), b.max(v)));
        assert!(mx - mn > 0.2, "{stem}: ao nearly constant ({mn}..{mx})");
        let red = output.scalar_column("vertex", "red").unwrap();
        assert_eq!(red.len(), n);
        assert!(out.path().join(format!("{stem}.png")).exists());
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("report.json")).unwrap()).unwrap();
    (out, report)
}

/// Mean AO of the most concave and most convex tenth of each scan, from an in-memory run.
/// Mean AO of the most concave and the most convex 10 % of each scan's points, with the
/// given estimator and default parameters.
fn concave_vs_convex(
    dir: &str,
    align_file: &str,
    k: usize,
    estimator: mvao::testing::ssao::Estimator,
) -> Vec<(String, f32, f32)> {
    let scans = load_aligned(&plys(dir), &fixture(align_file));
    let prm = ComputeParams {
        estimator,
        ..ComputeParams::default()
    };
    let c = pipeline::compute(&scans, &prm, &Silent).unwrap();
    scans
        .iter()
        .zip(&c.scans)
        .map(|(s, r)| {
            let proj = &r.view.sensor.projection;
            let (n, _) = normals::estimate(&s.points, true, |p| proj.toward_sensor(p));
            let conc = concavity(&s.points, &n.unwrap(), k);
            let (cc, cv) = mean_by_extremes(&r.ao, &conc, 0.1);
            (s.name.clone(), cc, cv)
        })
        .collect()
}

#[test]
fn bunny_scans_are_aligned_by_bun_conf() {
    let scans = load_aligned(&plys("stanford-bunny"), &fixture("stanford-bunny/bun.conf"));
    assert_eq!(scans.len(), 10);
    for i in 0..scans.len() {
        let d = median_nn_to_others(&scans, i);
        assert!(d < 0.0005, "{}: median NN distance {d} m", scans[i].name);
    }
}

#[test]
fn bunny_merge_outputs_every_scan() {
    let (_dir, report) = run_and_check("stanford-bunny", &[]);
    let scans = report["scans"].as_array().unwrap();
    assert_eq!(scans.len(), 10);
    for s in scans {
        // Cyberware scans are near-orthographic sweeps: the grid is the map.
        assert_eq!(s["sensor_model"], "ortho", "{}", s["name"]);
        assert_eq!(s["native_grid"], true);
        assert_eq!(s["map_size"], serde_json::json!([512, 400]));
        assert!(s["grid_fit_rms_px"].as_f64().unwrap() < 2.0);
    }
    assert!(report["alignment"].as_str().unwrap().ends_with("bun.conf"));
    for key in [
        "catalog", "prepare", "sensor", "normals", "gbuffer", "ssao", "border", "merge", "write",
    ] {
        assert!(report["timings_s"][key].as_f64().is_some(), "timing {key}");
    }
}

#[test]
fn bunny_scans_are_orthographic_looking_along_minus_z() {
    for p in plys("stanford-bunny") {
        let (scan, _) = mvao::io::ply::scan::read_scan(&p).unwrap();
        let setup =
            mvao::testing::sensor::setup(&scan, mvao::testing::sensor::ProjectionChoice::Auto)
                .unwrap();
        match setup.projection.model {
            mvao::testing::projection::Model::Ortho { toward, .. } => {
                assert!(
                    toward.z > 0.99,
                    "{}: sensor direction {toward}",
                    p.display()
                )
            }
            m => panic!("{}: {m:?}", p.display()),
        }
    }
}

#[test]
fn bunny_concave_regions_are_darker() {
    use mvao::testing::ssao::Estimator;
    // The paper's estimator darkens everything (open floor ≈ 0.275), so its contrast is
    // larger; the horizon estimator reads open surface as 1.
    for (est, margin) in [(Estimator::Paper, 0.02), (Estimator::Horizon, 0.01)] {
        for (name, concave, convex) in
            concave_vs_convex("stanford-bunny", "stanford-bunny/bun.conf", 48, est)
        {
            assert!(
                concave < convex - margin,
                "{est:?} {name}: concave {concave} vs convex {convex}"
            );
        }
    }
}

#[test]
fn uos_stations_are_aligned_by_mlp() {
    let scans = load_aligned(
        &plys("3dtk-uos-3scans"),
        &fixture("3dtk-uos-3scans/alignment.mlp"),
    );
    // SOURCE.md: scan001 within 3.0 cm of scan000; scan002 (3.4 m away, partial overlap) 8.3 cm.
    assert!(median_nn_to_others(&scans, 1) < 0.05);
    assert!(median_nn_to_others(&scans, 2) < 0.1);
}

#[test]
fn uos_merge_outputs_every_station() {
    let (_dir, report) = run_and_check("3dtk-uos-3scans", &[]);
    for s in report["scans"].as_array().unwrap() {
        assert_eq!(s["sensor_model"], "equirect", "{}", s["name"]);
        assert_eq!(s["native_grid"], true);
        assert_eq!(s["vertices"], 81360);
        assert!(s["grid_fit_rms_px"].as_f64().unwrap() < 0.5);
    }
}

#[test]
fn uos_concave_regions_are_darker() {
    use mvao::testing::ssao::Estimator;
    for est in [Estimator::Paper, Estimator::Horizon] {
        for (name, concave, convex) in
            concave_vs_convex("3dtk-uos-3scans", "3dtk-uos-3scans/alignment.mlp", 24, est)
        {
            assert!(
                concave < convex,
                "{est:?} {name}: concave {concave} vs convex {convex}"
            );
        }
    }
}

#[test]
fn json_alignment_gives_the_same_result_as_mlp() {
    let json = fixture("3dtk-uos-3scans/json/alignment.json");
    let (a, _) = run_and_check("3dtk-uos-3scans", &[]);
    let (b, _) = run_and_check("3dtk-uos-3scans", &["--align", json.to_str().unwrap()]);
    for stem in ["scan000", "scan001", "scan002"] {
        let f = |d: &Path| {
            PlyFile::from_path(&d.join(format!("{stem}.mvao.ply")))
                .unwrap()
                .scalar_column("vertex", "ao")
                .unwrap()
        };
        assert_eq!(f(a.path()), f(b.path()), "{stem}");
    }
}
