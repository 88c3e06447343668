//! The AO of a result opens as a scalar field in CloudCompare and as vertex quality in
//! MeshLab, without an import dialog (issue 34). CloudCompare's command line (`CloudCompare`
//! on the PATH, or `$MVAO_CLOUDCOMPARE`) loads each result and saves it as ASCII with a
//! header naming the fields it loaded; MeshLab's reader is pymeshlab's (`$MVAO_PYTHON`, then
//! `python3`). Each test is skipped, with the reason printed, when its tool is missing.

mod common;

use common::*;
use mvao::io::ply::PlyFile;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Result PLYs to open: a merged synthetic station (a PLY written back with the AO added),
/// the same station through `--format las` and back to PLY (a table written anew) and a
/// Stanford bunny scan (a `range_grid` element beside the vertices).
fn results(dir: &Path) -> Vec<PathBuf> {
    let scans = synth_room(&dir.join("synth"), 1, 180, 90);
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let out = dir.join("out");
    mvao_ok(&["merge", &s(&scans[0]), "-o", &s(&out), "-q", "--no-preview"]);
    let las = dir.join("las");
    mvao_ok(&[
        "merge",
        &s(&scans[0]),
        "-o",
        &s(&las),
        "-q",
        "--no-preview",
        "--format",
        "las",
    ]);
    let table = dir.join("table");
    let las_file = las.join("station_000.mvao.las");
    mvao_ok(&[
        "merge",
        &s(&las_file),
        "-o",
        &s(&table),
        "-q",
        "--no-preview",
        "--format",
        "ply",
        "--radius",
        "0.3",
    ]);
    // Alone, away from the other scans its alignment file names.
    let bun = dir.join("bun000.ply");
    std::fs::copy(fixture("stanford-bunny/bun000.ply"), &bun).unwrap();
    let bunny = dir.join("bunny");
    mvao_ok(&["merge", &s(&bun), "-o", &s(&bunny), "-q", "--no-preview"]);
    vec![
        out.join("station_000.mvao.ply"),
        table.join("station_000.mvao.mvao.ply"),
        bunny.join("bun000.mvao.ply"),
    ]
}

fn ao_of(path: &Path) -> Vec<f64> {
    PlyFile::from_path(path)
        .unwrap()
        .scalar_column("vertex", "ao")
        .unwrap()
}

/// Values equal to `ao` within `tol`, one per vertex.
fn assert_same(got: &[f64], ao: &[f64], tol: f64, what: &str) {
    assert_eq!(got.len(), ao.len(), "{what}: one value per vertex");
    let worst = got
        .iter()
        .zip(ao)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(worst <= tol, "{what}: differs from ao by up to {worst}");
    let (lo, hi) = ao
        .iter()
        .fold((1f64, 0f64), |(l, h), &v| (l.min(v), h.max(v)));
    assert!(hi - lo > 0.1, "{what}: ao nearly constant ({lo}..{hi})");
}

/// The CloudCompare command, or why there is none.
fn cloudcompare() -> Result<String, String> {
    let cc = std::env::var("MVAO_CLOUDCOMPARE")
        .ok()
        .filter(|p| !p.is_empty())
        .unwrap_or_else(|| "CloudCompare".into());
    match Command::new(&cc)
        .args(["-SILENT", "-AUTO_SAVE", "OFF"])
        .env("QT_QPA_PLATFORM", "offscreen")
        .output()
    {
        Ok(o) if o.status.success() => Ok(cc),
        Ok(o) => Err(format!(
            "{cc} failed: {}",
            String::from_utf8_lossy(&o.stderr)
        )),
        Err(e) => Err(format!(
            "no CloudCompare ({cc}: {e}); install it (Debian: apt-get install cloudcompare) or \
             set MVAO_CLOUDCOMPARE"
        )),
    }
}

/// CloudCompare loads `ply` on its command line (no dialog) and saves it as ASCII: the
/// field names of the header line and the rows.
fn cloudcompare_fields(cc: &str, ply: &Path, dir: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let asc = dir.join("cc.asc");
    let o = Command::new(cc)
        .args(["-SILENT", "-AUTO_SAVE", "OFF", "-O"])
        .arg(ply)
        .args([
            "-C_EXPORT_FMT",
            "ASC",
            "-ADD_HEADER",
            "-SAVE_CLOUDS",
            "FILE",
        ])
        .arg(&asc)
        .env("QT_QPA_PLATFORM", "offscreen")
        .output()
        .unwrap();
    let text = std::fs::read_to_string(&asc).unwrap_or_else(|e| {
        panic!(
            "{}: CloudCompare wrote no file ({e}): {}",
            ply.display(),
            String::from_utf8_lossy(&o.stdout)
        )
    });
    let mut lines = text.lines();
    let header = lines.next().unwrap_or("");
    let names = header
        .trim_start_matches("//")
        .split_whitespace()
        .map(String::from)
        .collect();
    let rows = lines
        .map(|l| {
            l.split_whitespace()
                .map(|v| v.parse::<f64>().unwrap())
                .collect()
        })
        .collect();
    (names, rows)
}

/// CloudCompare shows the AO as a scalar field named `ao` (from `scalar_ao`), in the
/// points' order; a plain `ao` alone, as results had before, is not loaded at all.
#[test]
fn cloudcompare_loads_the_ao_as_a_scalar_field() {
    let cc = match cloudcompare() {
        Ok(cc) => cc,
        Err(why) => {
            eprintln!("cloudcompare: skipped: {why}");
            return;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    for ply in results(dir.path()) {
        let (names, rows) = cloudcompare_fields(&cc, &ply, dir.path());
        let k = names
            .iter()
            .position(|n| n == "ao")
            .unwrap_or_else(|| panic!("{}: no ao field in {names:?}", ply.display()));
        let got: Vec<f64> = rows.iter().map(|r| r[k]).collect();
        assert_same(&got, &ao_of(&ply), 1e-6, &ply.display().to_string());
    }
    // The control: the same file with only `ao` loses it.
    let xs: &[f64] = &[0.0, 1.0, 0.0];
    let plain = PlyFile::from_vertex_columns(
        &[
            ("x", mvao::io::ply::ScalarType::F32, xs),
            ("y", mvao::io::ply::ScalarType::F32, &[0.0, 0.0, 1.0]),
            ("z", mvao::io::ply::ScalarType::F32, xs),
            ("ao", mvao::io::ply::ScalarType::F32, &[0.2, 0.5, 0.9]),
        ],
        &[],
    )
    .unwrap();
    let p = dir.path().join("plain.ply");
    plain.write_path(&p).unwrap();
    let (names, _) = cloudcompare_fields(&cc, &p, dir.path());
    assert_eq!(names, ["X", "Y", "Z"]);
}

/// A Python that imports pymeshlab, or why there is none.
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
                tried.push(format!("{py}: {}", err.lines().last().unwrap_or("").trim()));
            }
            Err(e) => tried.push(format!("{py}: {e}")),
        }
    }
    Err(format!(
        "no Python with pymeshlab ({}); set MVAO_PYTHON to one, see scripts/README.md",
        tried.join("; ")
    ))
}

/// MeshLab's reader gives every vertex the AO as its quality.
#[test]
fn meshlab_reads_the_ao_as_vertex_quality() {
    let py = match python() {
        Ok(p) => p,
        Err(why) => {
            eprintln!("meshlab: skipped: {why}");
            return;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    const SCRIPT: &str = "import sys, json, pymeshlab\n\
        ms = pymeshlab.MeshSet()\n\
        ms.load_new_mesh(sys.argv[1])\n\
        m = ms.current_mesh()\n\
        print(json.dumps(m.vertex_scalar_array().tolist() if m.has_vertex_scalar() else None))\n";
    for ply in results(dir.path()) {
        let o = Command::new(&py)
            .args(["-c", SCRIPT])
            .arg(&ply)
            .env("QT_QPA_PLATFORM", "offscreen")
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{}: {}",
            ply.display(),
            String::from_utf8_lossy(&o.stderr)
        );
        let q: Option<Vec<f64>> = serde_json::from_slice(&o.stdout).unwrap();
        let q = q.unwrap_or_else(|| panic!("{}: MeshLab found no quality", ply.display()));
        assert_same(&q, &ao_of(&ply), 1e-6, &ply.display().to_string());
    }
}
