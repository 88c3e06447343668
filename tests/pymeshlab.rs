//! MeshLab's ambient occlusion through `scripts/compare_pymeshlab.py`: the mapping of the
//! filter's values to [0, 1] on analytic scenes, the per-scan outputs on the bundled bunny and
//! 3DTK scans, every PLY encoding the script reads, and its error line. Every test is skipped,
//! with the reason printed, when no Python with pymeshlab is found (`$MVAO_PYTHON`, then
//! `python3`); `scripts/README.md` says how to install one.

mod common;

use common::*;
use glam::Vec3;
use mvao::io::ply::PlyFile;
use mvao::testing::scan::normals;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The column list of the script's CSV row.
const CSV_HEADER: &str = "label,estimator,dirs,wall_s,filter_s,points";

/// A Python interpreter that can import pymeshlab, or why there is none.
fn python() -> Result<String, String> {
    let mut tried = Vec::new();
    let candidates = std::env::var("MVAO_PYTHON")
        .ok()
        .filter(|p| !p.is_empty())
        .into_iter()
        .chain(["python3".to_string()]);
    for py in candidates {
        match Command::new(&py)
            .args(["-c", "import pymeshlab"])
            .env("QT_QPA_PLATFORM", "offscreen")
            .output()
        {
            Ok(o) if o.status.success() => return Ok(py),
            Ok(o) => {
                let err = String::from_utf8_lossy(&o.stderr);
                let last = err.lines().last().unwrap_or("").trim().to_string();
                tried.push(format!("{py}: {last}"));
            }
            Err(e) => tried.push(format!("{py}: {e}")),
        }
    }
    Err(format!(
        "no Python with pymeshlab ({}); set MVAO_PYTHON to one, see scripts/README.md",
        tried.join("; ")
    ))
}

/// The interpreter to use, or `None` after printing why the test is skipped.
fn python_or_skip(test: &str) -> Option<String> {
    match python() {
        Ok(p) => Some(p),
        Err(why) => {
            eprintln!("{test}: skipped: {why}");
            None
        }
    }
}

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/compare_pymeshlab.py")
}

fn run_script(py: &str, args: &[String]) -> Output {
    Command::new(py)
        .arg(script())
        .args(args)
        .env("QT_QPA_PLATFORM", "offscreen")
        .output()
        .unwrap()
}

fn ok(o: &Output) -> String {
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "script failed: {err}");
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn s(p: &Path) -> String {
    p.display().to_string()
}

fn ao_of(path: &Path) -> Vec<f64> {
    PlyFile::from_path(path)
        .unwrap()
        .scalar_column("vertex", "ao")
        .unwrap()
}

/// Reads `<stem>.pymeshlab.ply` for every input and checks what every output must satisfy:
/// the input's vertex count and coordinates, ao finite in [0, 1] and not constant.
fn check_outputs(inputs: &[PathBuf], out: &Path) -> Vec<Vec<f64>> {
    inputs
        .iter()
        .map(|p| {
            let stem = p.file_stem().unwrap().to_str().unwrap();
            let o = out.join(format!("{stem}.pymeshlab.ply"));
            let input = PlyFile::from_path(p).unwrap();
            let output = PlyFile::from_path(&o).unwrap();
            assert_eq!(
                output.header.elements[0].count, input.header.elements[0].count,
                "{stem}: vertex count"
            );
            for c in ["x", "y", "z"] {
                assert_eq!(
                    output.scalar_column("vertex", c),
                    input.scalar_column("vertex", c),
                    "{stem}: {c} must be written as read"
                );
            }
            let ao = output.scalar_column("vertex", "ao").unwrap();
            assert!(
                ao.iter().all(|a| a.is_finite() && (0.0..=1.0).contains(a)),
                "{stem}: ao outside [0, 1] or not finite"
            );
            let (lo, hi) = ao
                .iter()
                .fold((1f64, 0f64), |(l, h), &v| (l.min(v), h.max(v)));
            assert!(hi - lo > 0.2, "{stem}: ao nearly constant ({lo}..{hi})");
            ao
        })
        .collect()
}

#[test]
fn selftest_maps_open_plane_to_one_and_closed_box_to_zero() {
    let Some(py) = python_or_skip("selftest") else {
        return;
    };
    let out = run_script(&py, &["--selftest".into(), "--dirs".into(), "256".into()]);
    let r: serde_json::Value = serde_json::from_str(&ok(&out)).unwrap();
    assert_eq!(r["passed"], true, "{r:#}");
    let case = |name: &str| -> f64 {
        r["cases"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["case"] == name)
            .unwrap_or_else(|| panic!("no case {name}"))["a"]
            .as_f64()
            .unwrap()
    };
    // Exact by construction of the mapping.
    assert!(case("open_plane") >= 0.9999, "{r:#}");
    assert!(case("closed_box_floor_centre") <= 1e-4, "{r:#}");
    // Approximations by 256 directions of scenes with finite walls.
    let open_box =
        4.0 / std::f64::consts::TAU * 2.0 * (0.5 / 1.25f64.sqrt()) * (0.5 / 1.25f64.sqrt()).atan();
    assert!(
        (case("open_box_floor_centre") - open_box).abs() < 0.03,
        "{r:#}"
    );
    assert!((case("wall_foot") - 0.5).abs() < 0.04, "{r:#}");
    assert!(
        (case("wall_wall_floor_corner") - 0.25).abs() < 0.05,
        "{r:#}"
    );
    // Handing the filter a scaled mesh (how --min-hit works) does not change the values.
    assert!(
        (case("open_box_floor_centre_scaled") - case("open_box_floor_centre")).abs() < 1e-3,
        "{r:#}"
    );
    // The filter's own vertex step is the area-weighted mean of its face values.
    for c in r["cases"].as_array().unwrap() {
        assert!(
            c["vertex_step_max_rel_diff"].as_f64().unwrap() < 1e-5,
            "{c}"
        );
    }
}

#[test]
fn bunny_outputs_and_concave_points_darker() {
    let Some(py) = python_or_skip("bunny") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let csv = dir.path().join("sweep.csv");
    let scans = plys("stanford-bunny");
    let mut args: Vec<String> = scans.iter().map(|p| s(p)).collect();
    for a in [
        "--align",
        &s(&fixture("stanford-bunny/bun.conf")),
        "-o",
        &s(&out),
        "--dirs",
        "16",
        "--csv",
        &s(&csv),
        "--label",
        "bunny",
    ] {
        args.push(a.to_string());
    }
    ok(&run_script(&py, &args));
    let ao = check_outputs(&scans, &out);

    let all: Vec<f64> = ao.iter().flatten().copied().collect();
    let mean = all.iter().sum::<f64>() / all.len() as f64;
    assert!(mean > 0.3 && mean < 0.99, "mean ao {mean}");

    // The creases (ears, neck, between the legs) are darker than the bumps.
    let aligned = load_aligned(&scans, &fixture("stanford-bunny/bun.conf"));
    let mut gap = 0.0;
    for (scan, ao) in aligned.iter().zip(&ao) {
        // Cyberware scans look along local -z (tests/real_scans.rs).
        let (n, _) = normals::estimate(&scan.points, true, |_| Vec3::Z);
        let conc = concavity(&scan.points, &n.unwrap(), 48);
        let a: Vec<f32> = scan
            .source_index
            .iter()
            .map(|&i| ao[i as usize] as f32)
            .collect();
        let (concave, convex) = mean_by_extremes(&a, &conc, 0.1);
        eprintln!("{}: concave {concave} vs convex {convex}", scan.name);
        assert!(
            concave < convex - 0.01,
            "{}: concave {concave} vs convex {convex}",
            scan.name
        );
        gap += (convex - concave) / aligned.len() as f32;
    }
    // Measured with 16 directions: 0.015 (bun090, a side view) to 0.14, mean 0.09.
    assert!(gap > 0.05, "mean concave-convex gap {gap}");

    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("pymeshlab.json")).unwrap())
            .unwrap();
    assert_eq!(report["dirs"], 16);
    assert_eq!(report["points"], 362_272);
    assert_eq!(report["scans"].as_array().unwrap().len(), 10);
    assert!(report["timings_s"]["filter"].as_f64().unwrap() > 0.0);
    assert!(report["alignment"].as_str().unwrap().ends_with("bun.conf"));
    // Silhouette points of the range grids: a few hundred of 362 k, nearly all filled.
    let untri = report["untriangulated"].as_u64().unwrap();
    assert!(untri < 3_000, "{untri} points in no triangle");
    assert!(report["fallback_open"].as_u64().unwrap() <= untri / 10);

    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2, "{text}");
    assert_eq!(lines[0], CSV_HEADER);
    let row: Vec<&str> = lines[1].split(',').collect();
    assert_eq!(row[..3], ["bunny", "pymeshlab", "16"]);
    assert!(row[3].parse::<f64>().unwrap() >= row[4].parse::<f64>().unwrap());
    assert_eq!(row[5], "362272");

    // Outputs are not overwritten without --force.
    let again = run_script(&py, &args);
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));
}

#[test]
fn uos_stations_with_row_col_grids_and_mlp() {
    let Some(py) = python_or_skip("uos") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let scans = plys("3dtk-uos-3scans");
    let mut args: Vec<String> = scans.iter().map(|p| s(p)).collect();
    // The alignment is found beside the scans.
    args.extend(["-o".into(), s(&out), "--dirs".into(), "16".into()]);
    ok(&run_script(&py, &args));
    check_outputs(&scans, &out);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("pymeshlab.json")).unwrap())
            .unwrap();
    assert!(report["alignment"]
        .as_str()
        .unwrap()
        .ends_with("alignment.mlp"));
    for sc in report["scans"].as_array().unwrap() {
        assert_eq!(sc["mesh_from"], "grid");
        assert_eq!(sc["sensor"], "origin");
        assert!(sc["triangles"].as_u64().unwrap() > 100_000, "{sc}");
    }
}

/// A V-shaped trough `z = |x|` (90° opening, 2 m wide, 10 m long), 21 × 51 points with
/// per-vertex `row`/`col`, seen from above by an orthographic sensor.
fn trough() -> Vec<[f32; 5]> {
    let mut v = Vec::new();
    for r in 0..51 {
        for c in 0..21 {
            let x = -1.0 + c as f32 * 0.1;
            let y = -5.0 + r as f32 * 0.2;
            v.push([x, y, x.abs(), r as f32, c as f32]);
        }
    }
    v
}

fn trough_header(format: &str, n: usize) -> String {
    format!(
        "ply\nformat {format} 1.0\ncomment sensor ortho\nelement vertex {n}\n\
         property float x\nproperty float y\nproperty float z\n\
         property int row\nproperty int col\nend_header\n"
    )
}

#[test]
fn every_ply_encoding_gives_the_same_ao_and_the_crease_is_darker() {
    let Some(py) = python_or_skip("encodings") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let v = trough();
    let mut ascii = trough_header("ascii", v.len());
    for p in &v {
        ascii.push_str(&format!(
            "{:?} {:?} {:?} {} {}\n",
            p[0], p[1], p[2], p[3] as i32, p[4] as i32
        ));
    }
    let mut le = trough_header("binary_little_endian", v.len()).into_bytes();
    let mut be = trough_header("binary_big_endian", v.len()).into_bytes();
    for p in &v {
        for x in &p[..3] {
            le.extend(x.to_le_bytes());
            be.extend(x.to_be_bytes());
        }
        for x in &p[3..] {
            le.extend((*x as i32).to_le_bytes());
            be.extend((*x as i32).to_be_bytes());
        }
    }
    let mut results = Vec::new();
    for (name, bytes) in [("ascii", ascii.into_bytes()), ("le", le), ("be", be)] {
        let sub = dir.path().join(name);
        std::fs::create_dir(&sub).unwrap();
        let input = sub.join("trough.ply");
        std::fs::write(&input, bytes).unwrap();
        let out = sub.join("out");
        ok(&run_script(
            &py,
            &[
                s(&input),
                "-o".into(),
                s(&out),
                "--dirs".into(),
                "256".into(),
                // One scan, nothing overlaps: the filter's own near limit.
                "--min-hit".into(),
                "0".into(),
            ],
        ));
        results.push(ao_of(&out.join("trough.pymeshlab.ply")));
    }
    assert_eq!(results[0], results[1], "ascii vs little endian");
    assert_eq!(results[1], results[2], "little vs big endian");

    // Cross-section: from a point at distance L from the crease the other flank (length L,
    // at 90°) hides the elevations 0..45° on its side, (1 − cos 45°)/2 ≈ 0.15 of the cosine
    // weight; at the crease it hides half. The trough's open ends let in a little more.
    let ao = &results[0];
    let at = |r: usize, c: usize| ao[r * 21 + c];
    let (crease, rim) = (at(25, 10), at(25, 0).min(at(25, 20)));
    assert!(crease > 0.4 && crease < 0.62, "crease {crease}");
    assert!(rim > 0.8 && rim < 0.95, "rim {rim}");
}

#[test]
fn bad_input_is_one_error_line_and_exit_code_2() {
    let Some(py) = python_or_skip("bad input") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.ply");
    let o = run_script(&py, &[s(&missing), "-o".into(), s(&dir.path().join("out"))]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.starts_with("compare_pymeshlab: error: "), "{err}");
    assert!(err.contains("nope.ply"), "{err}");
    assert!(!dir.path().join("out").exists());

    let not_ply = dir.path().join("text.ply");
    std::fs::write(&not_ply, "hello\n").unwrap();
    let o = run_script(&py, &[s(&not_ply), "-o".into(), s(&dir.path().join("out"))]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("not a PLY file"));
}
