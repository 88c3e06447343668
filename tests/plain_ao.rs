//! `--tmax inf` and `--falloff` end to end: merge and prepare accept plain ambient occlusion,
//! report.json records it, products are recomputed when the falloff changes, and a result is
//! never scored against a reference of another t_max or falloff.

mod common;

use common::{mvao, mvao_ok};
use std::path::{Path, PathBuf};

fn json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

fn plys(dir: &Path) -> Vec<String> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ply"))
        .collect();
    v.sort();
    v.iter().map(|p| p.to_str().unwrap().to_string()).collect()
}

fn mean_ao(dir: &Path) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for p in plys(dir) {
        for a in mvao::io::reference::read_ao(Path::new(&p)).unwrap() {
            assert!(a.is_finite() && (0.0..=1.0).contains(&a), "{p}: {a}");
            sum += a as f64;
            n += 1;
        }
    }
    assert!(n > 0);
    sum / n as f64
}

#[test]
fn plain_ambient_occlusion_runs_is_recorded_and_is_checked_against_its_reference() {
    let tmp = tempfile::tempdir().unwrap();
    let scans = tmp.path().join("scans");
    let s = scans.to_str().unwrap();
    // A courtyard under open sky: at t_max = ∞ the walls shade the whole floor.
    mvao_ok(&[
        "synth",
        "--scene",
        "courtyard",
        "--stations",
        "2",
        "--width",
        "240",
        "--height",
        "120",
        "--reference-rays",
        "64",
        "--reference-tmax",
        "inf",
        "--reference-falloff",
        "none",
        "-o",
        s,
    ]);
    let truth = scans.join("reference-analytic");
    let rj = json(&truth.join("reference.json"));
    assert_eq!(rj["params"]["tmax"], "inf", "{rj}");
    assert_eq!(rj["params"]["falloff"], "none", "{rj}");
    let inputs = plys(&scans);
    let args = |out: &Path, extra: &[&str]| -> Vec<String> {
        let mut a: Vec<String> = vec!["merge".into()];
        a.extend(inputs.iter().cloned());
        a.extend([
            "-o".into(),
            out.to_str().unwrap().into(),
            "--radius".into(),
            "0.3".into(),
        ]);
        a.extend(["--no-preview".into(), "--quiet".into(), "--force".into()]);
        a.extend(extra.iter().map(|x| x.to_string()));
        a
    };
    let run = |out: &Path, extra: &[&str]| -> std::process::Output {
        let a = args(out, extra);
        mvao(&a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let ok = |out: &Path, extra: &[&str]| {
        let r = run(out, extra);
        assert!(
            r.status.success(),
            "{extra:?}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
    };

    // Prepare, then merge at t_max = ∞ scored against the exact reference.
    let inf = tmp.path().join("inf");
    let work = tmp.path().join("work");
    let w = work.to_str().unwrap();
    let mut prep = args(&inf, &["--tmax", "inf", "--falloff", "none", "--work", w]);
    prep[0] = "prepare".into();
    mvao_ok(&prep.iter().map(String::as_str).collect::<Vec<_>>());
    let t = truth.to_str().unwrap();
    ok(
        &inf,
        &[
            "--tmax",
            "inf",
            "--falloff",
            "none",
            "--work",
            w,
            "--reference",
            t,
        ],
    );
    let rep = json(&inf.join("report.json"));
    let ssao = &rep["parameters"]["ssao"];
    assert_eq!(ssao["tmax"], "inf", "{ssao}");
    assert_eq!(ssao["falloff"], "none", "{ssao}");
    assert_eq!(
        rep["products"][0], 0,
        "prepared products are reused: {}",
        rep["products"]
    );
    // Eight steps over half a great circle miss much of the far occlusion: too bright at
    // the default budget, but ordered right (the convergence is a unit test of the march).
    let acc = &rep["accuracy"]["result"];
    let (e_a, r) = (
        acc["e_a"].as_f64().unwrap(),
        acc["pearson_r"].as_f64().unwrap(),
    );
    assert!(e_a.is_finite() && r > 0.7, "e_A {e_a}, Pearson r {r}");
    let at_inf = mean_ao(&inf);

    // Another falloff is another product; a short reach shades far less.
    let short = tmp.path().join("short");
    ok(
        &short,
        &["--tmax", "0.6", "--falloff", "exp:0.3", "--work", w],
    );
    let rep = json(&short.join("report.json"));
    assert_eq!(rep["parameters"]["ssao"]["falloff"], "exp:0.3");
    assert_eq!(rep["products"][1], 0, "nothing reused: {}", rep["products"]);
    let at_short = mean_ao(&short);
    assert!(at_inf + 0.05 < at_short, "∞ {at_inf} vs 0.6 m {at_short}");

    // The same quantity under another name is accepted: at ∞ smoothstep is plain AO too.
    ok(
        &tmp.path().join("smooth"),
        &["--tmax", "inf", "--reference", t],
    );
    // Another t_max or falloff is refused, naming both.
    for (extra, want) in [
        (&["--tmax", "0.6", "--reference", t][..], "t_max 0.6 m"),
        (
            &["--tmax", "inf", "--falloff", "exp:2", "--reference", t][..],
            "falloff exp:2",
        ),
    ] {
        let r = run(&tmp.path().join("refused"), extra);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{extra:?} should be refused");
        assert!(
            err.contains("reference.json") && err.contains(want),
            "{err}"
        );
        assert!(err.contains("t_max inf"), "{err}");
    }
    // eval reads the result's report.json beside its files.
    let mut ev: Vec<String> = vec!["eval".into()];
    ev.extend(plys(&short));
    ev.extend(["--reference".into(), t.into()]);
    let r = mvao(&ev.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("falloff exp:0.3"));
    let mut ev: Vec<String> = vec!["eval".into()];
    ev.extend(plys(&inf));
    ev.extend(["--reference".into(), t.into()]);
    let out = mvao_ok(&ev.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(out.contains("all:"), "{out}");
}

#[test]
fn bad_tmax_and_falloff_values_are_refused_with_the_flag_named() {
    for (flag, value) in [
        ("--tmax", "0"),
        ("--tmax", "-1"),
        ("--tmax", "nan"),
        ("--falloff", "cubic"),
        ("--falloff", "exp:0"),
    ] {
        let r = mvao(&["merge", "nothing.ply", &format!("{flag}={value}")]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success());
        assert!(
            err.contains(flag) && err.contains(value),
            "{flag} {value}: {err}"
        );
    }
}
