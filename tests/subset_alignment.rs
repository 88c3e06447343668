//! An alignment file beside the scans and a subset of its scans (issue 34, item 1): trying one
//! scan of a site, or shading part of it, works; a scan the alignment does not name is taken
//! as it is when alone and refused (naming `--pose` and `--align`) among scans it places; a
//! broken alignment beside the scans only stops runs that need a pose from it; a file's own
//! problem is reported before any alignment problem; `mvao info` describes every file it can
//! read. An explicit `--align` stays strict.

mod common;

use common::*;
use mvao::io::align::read_alignment;
use mvao::io::dataset::{Dataset, PlaceOptions};
use mvao::io::ply::{PlyFile, ScalarType};
use std::path::{Path, PathBuf};

fn s(p: &Path) -> String {
    p.display().to_string()
}

/// A small valid scan written to `dir/name`.
fn small_scan(dir: &Path, name: &str) -> PathBuf {
    let pts = dome(500);
    let col = |k: usize| -> Vec<f64> { pts.iter().map(|p| p[k]).collect() };
    let (x, y, z) = (col(0), col(1), col(2));
    let ply = PlyFile::from_vertex_columns(
        &[
            ("x", ScalarType::F32, &x),
            ("y", ScalarType::F32, &y),
            ("z", ScalarType::F32, &z),
        ],
        &[],
    )
    .unwrap();
    let p = dir.join(name);
    ply.write_path(&p).unwrap();
    p
}

/// A binary PLY cut in the middle of its vertices.
fn truncated_scan(dir: &Path, name: &str) -> PathBuf {
    let good = std::fs::read(fixture("3dtk-uos-3scans/scan000.ply")).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, &good[..good.len() / 2]).unwrap();
    p
}

/// `poses.json` in `dir` placing each of `names` at x = 10·(its index + 1).
fn alignment(dir: &Path, names: &[&str]) -> PathBuf {
    let body: Vec<String> = names
        .iter()
        .enumerate()
        .map(|(i, n)| {
            format!(
                "\"{n}\": [1,0,0,{}, 0,1,0,0, 0,0,1,0, 0,0,0,1]",
                10 * (i + 1)
            )
        })
        .collect();
    let p = dir.join("poses.json");
    std::fs::write(&p, format!("{{{}}}", body.join(", "))).unwrap();
    p
}

fn open(paths: &[PathBuf]) -> mvao::Result<Dataset> {
    Dataset::open(paths, &PlaceOptions::default(), &|| {})
}

/// `mvao merge` that must fail with exit 2 and one line holding every `needles`.
fn merge_fails(args: &[&str], needles: &[&str]) -> String {
    let r = mvao(args);
    let err = String::from_utf8_lossy(&r.stderr).to_string();
    assert_eq!(r.status.code(), Some(2), "expected exit 2, stderr: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    for n in needles {
        assert!(err.contains(n), "expected '{n}' in: {err}");
    }
    err
}

/// One of the ten bunny scans, alone beside `bun.conf`: placed by its entry, no complaint
/// about the nine others.
#[test]
fn one_scan_beside_its_alignment() {
    let conf = fixture("stanford-bunny/bun.conf");
    let al = read_alignment(&conf).unwrap();
    let want = al.entries.iter().find(|e| e.file == "bun045.ply").unwrap();
    let ds = open(&[fixture("stanford-bunny/bun045.ply")]).unwrap();
    assert_eq!(ds.scans.len(), 1);
    assert_eq!(ds.alignment.as_deref(), Some(conf.as_path()));
    assert!(
        ds.pose_source[0].contains("bun.conf"),
        "{}",
        ds.pose_source[0]
    );
    let d = (ds.file_to_world[0] - want.pose)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(d < 1e-12, "pose differs from the entry by {d:e}");
    assert!(ds.warnings.is_empty(), "{:?}", ds.warnings);
}

/// Two of the ten bunny scans: each gets its own entry's pose.
#[test]
fn a_subset_of_the_alignment() {
    let al = read_alignment(&fixture("stanford-bunny/bun.conf")).unwrap();
    let names = ["top2.ply", "bun180.ply"];
    let paths: Vec<PathBuf> = names
        .iter()
        .map(|n| fixture(&format!("stanford-bunny/{n}")))
        .collect();
    let ds = open(&paths).unwrap();
    assert_eq!(ds.scans.len(), 2);
    for (k, n) in names.iter().enumerate() {
        let e = al.entries.iter().find(|e| e.file == *n).unwrap();
        let d = (ds.file_to_world[k] - e.pose)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(d < 1e-12, "{n}: pose differs from its entry by {d:e}");
    }
    assert!(ds.warnings.is_empty(), "{:?}", ds.warnings);
}

/// Through the binary: one scan and a subset of a site beside its alignment are merged with
/// the alignment's poses, and the report names the alignment.
#[test]
fn merge_runs_on_part_of_a_site() {
    let d = tempfile::tempdir().unwrap();
    let a = small_scan(d.path(), "a.ply");
    let b = small_scan(d.path(), "b.ply");
    small_scan(d.path(), "c.ply");
    alignment(d.path(), &["a.ply", "b.ply", "c.ply"]);
    let out = d.path().join("out");
    let text = mvao_ok(&["merge", "-q", "-o", &s(&out), &s(&b), "--radius", "0.3"]);
    assert!(!text.contains("warning"), "{text}");
    let rep: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert!(
        rep["alignment"].as_str().unwrap().ends_with("poses.json"),
        "{rep}"
    );
    let out2 = d.path().join("out2");
    mvao_ok(&[
        "merge",
        "-q",
        "-o",
        &s(&out2),
        &s(&a),
        &s(&b),
        "--radius",
        "0.3",
    ]);
    assert!(out2.join("a.mvao.ply").is_file() && out2.join("b.mvao.ply").is_file());
    assert!(!out2.join("c.mvao.ply").exists());
}

/// A scan the alignment beside it does not name: alone it is taken as it is, with a warning;
/// among scans the alignment places it is an error naming the fix.
#[test]
fn a_scan_the_alignment_does_not_name() {
    let d = tempfile::tempdir().unwrap();
    let a = small_scan(d.path(), "a.ply");
    let x = small_scan(d.path(), "x.ply");
    alignment(d.path(), &["a.ply", "b.ply"]);
    let ds = open(std::slice::from_ref(&x)).unwrap();
    assert_eq!(ds.pose_source[0], "none (identity)");
    assert_eq!(ds.scans[0].pose, glam::DMat4::IDENTITY);
    assert_eq!(ds.alignment, None);
    assert_eq!(ds.warnings.len(), 1, "{:?}", ds.warnings);
    let w = &ds.warnings[0];
    assert!(
        w.contains("x.ply: not named in the alignment file")
            && w.contains("poses.json")
            && w.contains("taken as it is"),
        "{w}"
    );

    let out = d.path().join("out");
    let text = mvao_ok(&["merge", "-q", "-o", &s(&out), &s(&x), "--radius", "0.3"]);
    assert!(
        text.contains("x.ply: not named in the alignment file"),
        "{text}"
    );

    let out = d.path().join("out2");
    merge_fails(
        &["merge", "-o", &s(&out), &s(&a), &s(&x)],
        &[
            "x.ply: not named in the alignment file",
            "poses.json",
            "--pose x=FILE",
            "--align",
        ],
    );
    assert!(!out.exists());
}

/// A file that is broken and not named by the alignment beside it reports its own problem,
/// alone or among placed scans; so does one the alignment names.
#[test]
fn a_truncated_file_beside_an_alignment_names_its_own_problem() {
    let d = tempfile::tempdir().unwrap();
    let a = small_scan(d.path(), "a.ply");
    let cut = truncated_scan(d.path(), "cut.ply");
    let named_cut = truncated_scan(d.path(), "b.ply");
    alignment(d.path(), &["a.ply", "b.ply"]);
    let out = d.path().join("out");
    for args in [
        vec![s(&cut)],
        vec![s(&a), s(&cut)],
        vec![s(&cut), s(&a)],
        vec![s(&a), s(&named_cut)],
    ] {
        let mut all = vec!["merge".to_string(), "-o".into(), s(&out)];
        all.extend(args);
        let all: Vec<&str> = all.iter().map(String::as_str).collect();
        let err = merge_fails(&all, &["truncated"]);
        assert!(!err.contains("alignment"), "{err}");
    }
    // The same through `Dataset::open`: a format error naming the file.
    let e = open(&[a.clone(), cut.clone()]).unwrap_err();
    assert!(matches!(e, mvao::Error::Format { .. }), "{e:?}");
    assert!(e.to_string().starts_with(&s(&cut)), "{e}");
    assert!(!out.exists());
}

/// A broken alignment beside the scans is named as such; it stops only runs that need a pose
/// from it (several scans without another pose), not one scan alone nor scans with sidecars.
#[test]
fn a_broken_alignment_beside_the_scans() {
    let d = tempfile::tempdir().unwrap();
    let a = small_scan(d.path(), "a.ply");
    let b = small_scan(d.path(), "b.ply");
    std::fs::write(d.path().join("poses.json"), "{\"a.ply\": [1, 2, 3]").unwrap();

    let ds = open(std::slice::from_ref(&a)).unwrap();
    assert_eq!(ds.pose_source[0], "none (identity)");
    assert_eq!(ds.warnings.len(), 1, "{:?}", ds.warnings);
    assert!(
        ds.warnings[0].contains("poses.json")
            && ds.warnings[0].contains("not used: no scan given needs a pose from it"),
        "{}",
        ds.warnings[0]
    );

    let out = d.path().join("out");
    let err = merge_fails(
        &["merge", "-o", &s(&out), &s(&a), &s(&b)],
        &[
            "poses.json",
            "expected a JSON object",
            "found beside the scans",
            "--align",
        ],
    );
    assert!(!err.contains("a.ply") || err.contains("\"a.ply\""), "{err}");

    // With a sidecar each, no scan needs the alignment.
    let id = "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
    std::fs::write(d.path().join("a.txt"), id).unwrap();
    std::fs::write(
        d.path().join("b.txt"),
        "1 0 0 5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
    )
    .unwrap();
    let ds = open(&[a.clone(), b.clone()]).unwrap();
    assert!(ds.pose_source.iter().all(|p| p.starts_with("sidecar")));
    assert_eq!(ds.file_to_world[1].w_axis.x, 5.0);
    assert_eq!(ds.alignment, None);
    // A broken file among them is still reported as itself.
    let cut = truncated_scan(d.path(), "cut.ply");
    merge_fails(
        &["merge", "-o", &s(&out), &s(&a), &s(&cut)],
        &["cut.ply", "truncated"],
    );
    // So is one whose sidecar is not a matrix either.
    std::fs::write(d.path().join("cut.txt"), "not a matrix").unwrap();
    merge_fails(
        &["merge", "-o", &s(&out), &s(&a), &s(&cut)],
        &["cut.ply", "truncated"],
    );
    let e = open(&[a.clone(), b.clone(), cut.clone()]).unwrap_err();
    assert!(e.to_string().contains("truncated"), "{e}");
    std::fs::remove_file(&cut).unwrap();
    let c = small_scan(d.path(), "cut.ply");
    let e = open(&[a.clone(), c]).unwrap_err().to_string();
    assert!(
        e.contains("cut.txt") && e.contains("not a 4×4 matrix"),
        "{e}"
    );
    assert!(!out.exists());
}

/// `--align` given explicitly stays strict: a scan it does not name is an error even alone,
/// and a broken one is an error even for one scan. A subset of its entries is fine.
#[test]
fn an_explicit_alignment_stays_strict() {
    let d = tempfile::tempdir().unwrap();
    let sub = d.path().join("site");
    std::fs::create_dir(&sub).unwrap();
    let a = small_scan(&sub, "a.ply");
    let x = small_scan(&sub, "x.ply");
    let al = alignment(d.path(), &["a.ply", "b.ply"]);
    let opts = PlaceOptions {
        align: Some(al.clone()),
        ..Default::default()
    };
    let ds = Dataset::open(std::slice::from_ref(&a), &opts, &|| {}).unwrap();
    assert_eq!(ds.file_to_world[0].w_axis.x, 10.0);
    let e = Dataset::open(std::slice::from_ref(&x), &opts, &|| {}).unwrap_err();
    let m = e.to_string();
    assert!(
        m.starts_with(&s(&al)) && m.contains("scan '") && m.contains("--pose x=FILE"),
        "{m}"
    );
    std::fs::write(&al, "{").unwrap();
    let out = d.path().join("out");
    merge_fails(
        &["merge", "-o", &s(&out), "--align", &s(&al), &s(&a)],
        &["poses.json"],
    );
}

/// `mvao info` describes every file it can read: a subset of a site with its poses, a scan
/// the alignment does not name among placed ones (a warning, described as it is), and the
/// readable files beside a truncated one, which is listed with its problem (exit 2).
#[test]
fn info_on_a_subset_and_never_refusing_a_file() {
    let bun = |n: &str| s(&fixture(&format!("stanford-bunny/{n}")));
    let r = mvao(&["info", "--json", &bun("bun000.ply"), &bun("chin.ply")]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert!(
        v["alignment"].as_str().unwrap().ends_with("bun.conf"),
        "{v}"
    );
    assert_eq!(v["scans"].as_array().unwrap().len(), 2);
    for sc in v["scans"].as_array().unwrap() {
        assert!(sc["pose_source"].as_str().unwrap().contains("bun.conf"));
    }
    assert_eq!(v["problems"].as_array().unwrap().len(), 0);

    let d = tempfile::tempdir().unwrap();
    let a = small_scan(d.path(), "a.ply");
    let x = small_scan(d.path(), "x.ply");
    let cut = truncated_scan(d.path(), "cut.ply");
    alignment(d.path(), &["a.ply"]);
    let r = mvao(&["info", &s(&a), &s(&x)]);
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(
        text.contains("x.ply: not named in the alignment file")
            && text.contains("described as it is"),
        "{text}"
    );
    assert!(text.contains("a (") && text.contains("x ("), "{text}");

    let r = mvao(&["info", "--json", &s(&a), &s(&cut), &s(&x)]);
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.contains("cut.ply") && err.contains("truncated"),
        "{err}"
    );
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let names: Vec<&str> = v["scans"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["a", "x"]);
    let problems = v["problems"].as_array().unwrap();
    assert_eq!(problems.len(), 1);
    assert!(problems[0].as_str().unwrap().contains("cut.ply"), "{v}");

    // A broken alignment given explicitly does not stop `info` either.
    std::fs::write(d.path().join("bad.conf"), "bmesh a.ply 1 2\n").unwrap();
    let r = mvao(&["info", "--align", &s(&d.path().join("bad.conf")), &s(&a)]);
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(
        text.contains("bad.conf") && text.contains("7 numbers"),
        "{text}"
    );
}
