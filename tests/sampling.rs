//! `merge` samples adaptively by default (multi-resolution horizon march) and `--sampling
//! uniform` still marches every pixel: both scored against the room's exact ground truth.

mod common;

use common::{mvao_ok, report};

#[test]
fn adaptive_by_default_with_the_error_of_every_pixel() {
    let tmp = tempfile::tempdir().unwrap();
    let site = tmp.path().join("room");
    mvao_ok(&[
        "synth",
        "--scene",
        "room",
        "--stations",
        "2",
        "--width",
        "320",
        "--height",
        "160",
        "--reference-rays",
        "32",
        "--reference-tmax",
        "0.4",
        "-o",
        site.to_str().unwrap(),
    ]);
    let truth = site.join("reference-analytic");
    let run = |name: &str, extra: &[&str]| {
        let out = tmp.path().join(name);
        let mut args = vec![
            "merge",
            "-q",
            "--no-preview",
            "--radius",
            "0.2",
            "--tmax",
            "0.4",
        ];
        args.extend_from_slice(extra);
        let (o, t) = (out.to_str().unwrap(), truth.to_str().unwrap());
        args.extend(["--reference", t, "-o", o]);
        let files = ["station_000.ply", "station_001.ply"].map(|f| site.join(f));
        args.extend(files.iter().map(|f| f.to_str().unwrap()));
        mvao_ok(&args);
        report(&out)
    };
    let default = run("default", &[]);
    let uniform = run("uniform", &["--sampling", "uniform"]);

    // The default reports its levels; uniform has none (it marched every valid pixel).
    let levels: Vec<u64> = default["totals"]["ssao_levels"]["pixels"]
        .as_array()
        .expect("the default run reports its SSAO levels")
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    let points = default["totals"]["points"].as_u64().unwrap();
    assert_eq!(levels.len(), 5);
    assert_eq!(levels.iter().sum::<u64>(), points, "{levels:?}");
    assert!(
        levels[1] + levels[2] > points / 5,
        "the room's open floor and walls run at a coarse level: {levels:?}"
    );
    assert!(uniform["totals"].get("ssao_levels").is_none());

    let e = |r: &serde_json::Value, k: &str| r["accuracy"]["result"][k].as_f64().unwrap();
    for k in ["e_a", "shaded_e_a"] {
        let (ada, uni) = (e(&default, k), e(&uniform, k));
        assert!(
            ada <= 1.05 * uni + 5e-4,
            "{k}: adaptive {ada} vs uniform {uni}"
        );
    }
}
