//! Accuracy end to end through the binary: `mvao reference`, `merge --reference`, `mvao
//! eval`, `mvao sweep`, `mvao plot`, and the converging estimator's target on the synthetic
//! TLS room.

mod common;

use common::*;
use std::path::PathBuf;

fn strs(v: &[PathBuf]) -> Vec<&str> {
    v.iter().map(|p| p.to_str().unwrap()).collect()
}

/// The target at a third of the resolution (so the default test run stays short):
/// three TLS stations of the room, `--radius 0.2 --tmax 0.4`, the horizon estimator against
/// the surfel reference: e_A ≤ 0.015 overall, ≤ 0.08 on shaded points, and the merge beats
/// its own single-view SSAO.
#[test]
fn the_converging_estimator_meets_the_room_target() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("room"), 3, 480, 240);
    let refdir = d.path().join("ref");
    let mut a = vec!["reference", "-q", "--tmax", "0.4", "--rays", "64", "-o"];
    a.push(refdir.to_str().unwrap());
    a.extend(strs(&scans));
    mvao_ok(&a);
    let rep: serde_json::Value =
        serde_json::from_slice(&std::fs::read(refdir.join("reference.json")).unwrap()).unwrap();
    for s in rep["scans"].as_array().unwrap() {
        let c = s["convergence"]["mean_abs_diff_4r"].as_f64().unwrap();
        assert!(c < 0.01, "reference not converged: {c}");
    }

    let out = d.path().join("out");
    let mut m = vec![
        "merge",
        "-q",
        "--no-preview",
        "--radius",
        "0.2",
        "--tmax",
        "0.4",
        "--estimator",
        "horizon",
        "--reference",
        refdir.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ];
    m.extend(strs(&scans));
    mvao_ok(&m);
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let acc = &r["accuracy"];
    let e = acc["result"]["e_a"].as_f64().unwrap();
    let es = acc["result"]["shaded_e_a"].as_f64().unwrap();
    let s = acc["ssao"]["e_a"].as_f64().unwrap();
    let ss = acc["ssao"]["shaded_e_a"].as_f64().unwrap();
    let white = acc["result"]["baseline_shaded_e_a"].as_f64().unwrap();
    assert!(e <= 0.015, "e_A {e}");
    assert!(es <= 0.08, "shaded e_A {es} (a = 1 scores {white})");
    assert!(e < s && es < ss, "merge {e}/{es} vs single view {s}/{ss}");
    assert!(white > 0.15, "shaded baseline {white}");
    assert_eq!(acc["scans"].as_array().unwrap().len(), 3);

    // `mvao eval` on the written results gives the same figures; its CSV row and the plot.
    let results: Vec<PathBuf> = scans
        .iter()
        .map(|p| {
            out.join(format!(
                "{}.mvao.ply",
                p.file_stem().unwrap().to_str().unwrap()
            ))
        })
        .collect();
    let csv = d.path().join("rows.csv");
    let mut ev = vec![
        "eval",
        "--json",
        "--reference",
        refdir.to_str().unwrap(),
        "--csv",
        csv.to_str().unwrap(),
        "--method",
        "other",
        "--wall-s",
        "1.5",
    ];
    ev.extend(strs(&results));
    let r = mvao(&ev);
    assert!(r.status.success());
    let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert!((j["result"]["e_a"].as_f64().unwrap() - e).abs() < 1e-6);
    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2);
    assert_eq!(
        lines[0].split(',').count(),
        lines[1].split(',').count(),
        "{text}"
    );
    mvao_ok(&["plot", csv.to_str().unwrap()]);
    let svg = std::fs::read_to_string(csv.with_extension("svg")).unwrap();
    assert!(svg.contains("<circle") && !svg.contains("NaN"));
}

#[test]
fn sweep_writes_csv_and_plot_and_a_wrong_reference_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("room"), 3, 160, 80);
    let refdir = d.path().join("ref");
    let mut a = vec!["reference", "-q", "--tmax", "0.4", "--rays", "16", "-o"];
    a.push(refdir.to_str().unwrap());
    a.extend(strs(&scans));
    mvao_ok(&a);
    let sw = d.path().join("sweep");
    let mut s = vec![
        "sweep",
        "--quick",
        "--radius",
        "0.2",
        "--tmax",
        "0.4",
        "--dataset",
        "tiny, room",
        "--union-rays",
        "8",
        "--reference",
        refdir.to_str().unwrap(),
        "-o",
        sw.to_str().unwrap(),
    ];
    s.extend(strs(&scans));
    mvao_ok(&s);
    let text = std::fs::read_to_string(sw.join("sweep.csv")).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    // 4 settings × (1 single-view row + 2 merge rows), and a union row per horizon setting.
    assert_eq!(lines.len(), 1 + 4 * 3 + 2, "{text}");
    let cols = lines[0].split(',').count();
    for l in &lines[1..] {
        assert_eq!(l.split(',').count(), cols, "{l}");
        assert!(l.starts_with("tiny  room,"));
    }
    let union: Vec<&&str> = lines.iter().filter(|l| l.contains(",union,")).collect();
    assert_eq!(union.len(), 2, "{text}");
    for l in union {
        let f: Vec<&str> = l.split(',').collect();
        assert_eq!((f[2], f[3]), ("horizon", "8"), "{l}");
        let e_a: f64 = f[11].parse().unwrap();
        assert!(e_a.is_finite() && e_a < 0.2, "{l}");
    }
    let svg = std::fs::read_to_string(sw.join("sweep.svg")).unwrap();
    assert!(svg.contains("Pareto") && svg.contains("union horizon"));

    // A reference of other scans: named, refused.
    let other = d.path().join("other");
    let few = synth_room(&d.path().join("few"), 3, 120, 60);
    let mut a = vec!["reference", "-q", "--tmax", "0.4", "--rays", "4", "-o"];
    a.push(other.to_str().unwrap());
    a.extend(strs(&few));
    mvao_ok(&a);
    let mut m = vec!["merge", "-q", "--reference", other.to_str().unwrap(), "-o"];
    let o = d.path().join("o");
    m.push(o.to_str().unwrap());
    m.extend(strs(&scans));
    let r = mvao(&m);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("not the reference of this scan"), "{err}");
    assert!(!o.exists());
}
