//! Bad input through the real binary: one clear line naming the file, a non-zero exit, no
//! panic, inputs untouched and nothing half-written.

mod common;

use common::*;
use mvao::io::ply::{PlyFile, ScalarType};
use std::path::{Path, PathBuf};

fn s(p: &Path) -> String {
    p.display().to_string()
}

/// Runs `mvao merge` and expects failure with `needle` in the message.
fn fails(args: &[String], needle: &str) -> String {
    let a: Vec<&str> = args.iter().map(|x| x.as_str()).collect();
    let r = mvao(&a);
    let err = String::from_utf8_lossy(&r.stderr).to_string();
    assert_eq!(r.status.code(), Some(2), "expected exit 2, stderr: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.contains(needle), "expected '{needle}' in: {err}");
    err
}

/// A small valid scan written to `dir/name`.
fn small_scan(dir: &Path, name: &str, xyz: &[[f64; 3]]) -> PathBuf {
    let x: Vec<f64> = xyz.iter().map(|p| p[0]).collect();
    let y: Vec<f64> = xyz.iter().map(|p| p[1]).collect();
    let z: Vec<f64> = xyz.iter().map(|p| p[2]).collect();
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

#[test]
fn missing_file_is_named() {
    let out = tempfile::tempdir().unwrap();
    let err = fails(
        &[
            "merge".into(),
            "-o".into(),
            s(out.path()),
            "no/such/scan.ply".into(),
        ],
        "no/such/scan.ply",
    );
    assert_eq!(err.lines().count(), 1, "{err}");
}

#[test]
fn not_a_ply_truncated_and_missing_coordinates() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    let txt = d.path().join("notes.ply");
    std::fs::write(&txt, "hello world\n").unwrap();
    fails(
        &["merge".into(), "-o".into(), s(&out), s(&txt)],
        "notes.ply",
    );

    let good = std::fs::read(fixture("3dtk-uos-3scans/scan000.ply")).unwrap();
    let cut = d.path().join("cut.ply");
    std::fs::write(&cut, &good[..good.len() / 2]).unwrap();
    fails(
        &["merge".into(), "-o".into(), s(&out), s(&cut)],
        "truncated",
    );

    let x = vec![1.0, 2.0];
    let noz = PlyFile::from_vertex_columns(
        &[("x", ScalarType::F32, &x), ("y", ScalarType::F32, &x)],
        &[],
    )
    .unwrap();
    let p = d.path().join("noz.ply");
    noz.write_path(&p).unwrap();
    fails(
        &["merge".into(), "-o".into(), s(&out), s(&p)],
        "no 'z' coordinate",
    );
    assert!(!out.exists(), "a failed run left an output directory");
}

#[test]
fn non_finite_points_are_skipped_counted_and_never_written() {
    let d = tempfile::tempdir().unwrap();
    let mut pts = dome(3000);
    pts[10] = [f64::NAN, 0.0, 0.0];
    pts[20] = [0.0, f64::INFINITY, 1.0];
    let p = small_scan(d.path(), "nan.ply", &pts);
    let before = std::fs::read(&p).unwrap();
    let out = d.path().join("out");
    let r = mvao(&["merge", "-q", "-o", &s(&out), &s(&p), "--radius", "0.3"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(String::from_utf8_lossy(&r.stderr).contains("2 vertices with non-finite coordinates"));
    let o = PlyFile::from_path(&out.join("nan.mvao.ply")).unwrap();
    assert_eq!(o.header.elements[0].count, 2998);
    let xyz = o.vertex_xyz().unwrap();
    assert!(xyz.iter().all(|p| p.iter().all(|v| v.is_finite())));
    assert!(o
        .scalar_column("vertex", "ao")
        .unwrap()
        .iter()
        .all(|a| (0.0..=1.0).contains(a)));
    let rep: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(rep["scans"][0]["skipped_nonfinite"], 2);
    assert_eq!(std::fs::read(&p).unwrap(), before, "input modified");
}

/// A scan with no point (an empty PLY beside a good one; a PTX grid of no-returns) stops the
/// run before any work with one line naming the file, and leaves no output directory.
#[test]
fn a_scan_without_points_names_its_file() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    let good = small_scan(d.path(), "good.ply", &dome(500));
    let empty = small_scan(d.path(), "empty.ply", &[]);
    let msg = fails(
        &["merge".into(), "-o".into(), s(&out), s(&good), s(&empty)],
        "empty.ply: scan empty has no point to shade",
    );
    assert_eq!(msg.trim().lines().count(), 1, "{msg}");
    let mut ptx = String::from("3\n2\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n");
    ptx += "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
    ptx += &"0 0 0 0.5\n".repeat(6);
    let none = d.path().join("none.ptx");
    std::fs::write(&none, ptx).unwrap();
    fails(
        &["merge".into(), "-o".into(), s(&out), s(&none)],
        "none.ptx: scan none has no point to shade",
    );
    assert!(!out.exists(), "a failed run left an output directory");
}

/// A face that names a vertex the file does not have (beyond the count, negative) is dropped
/// with a warning, so the output is a PLY that viewers load; the good faces stay.
#[test]
fn faces_naming_missing_vertices_are_dropped_with_a_warning() {
    let d = tempfile::tempdir().unwrap();
    let pts = dome(2000);
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\nelement face 3\nproperty list uchar int vertex_indices\nend_header\n",
        pts.len()
    );
    for p in &pts {
        text += &format!("{} {} {}\n", p[0], p[1], p[2]);
    }
    text += "3 0 1 2\n3 0 1 2000\n3 -1 1 2\n";
    let p = d.path().join("faces.ply");
    std::fs::write(&p, &text).unwrap();
    let out = d.path().join("out");
    let r = mvao(&["merge", "-q", "-o", &s(&out), &s(&p), "--radius", "0.3"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.contains("faces.ply: 2 faces refer to vertices the file does not have"),
        "{err}"
    );
    let o = PlyFile::from_path(&out.join("faces.mvao.ply")).unwrap();
    assert_eq!(o.header.elements[0].count, 2000);
    assert_eq!(
        o.list_column("face", "vertex_indices").unwrap(),
        vec![vec![0, 1, 2]]
    );
    assert_eq!(std::fs::read_to_string(&p).unwrap(), text, "input modified");
}

/// NaN normals and colours of the input are written as 0 with a warning: no NaN reaches an
/// output, and the AO does not suffer (normals are estimated anew).
#[test]
fn non_finite_properties_are_written_as_zero() {
    let d = tempfile::tempdir().unwrap();
    let pts = dome(2000);
    let col = |k: usize| -> Vec<f64> { pts.iter().map(|p| p[k]).collect() };
    let (x, y, z) = (col(0), col(1), col(2));
    let nan: Vec<f64> = (0..pts.len())
        .map(|i| if i % 3 == 0 { f64::NAN } else { 0.5 })
        .collect();
    let ply = PlyFile::from_vertex_columns(
        &[
            ("x", ScalarType::F32, &x),
            ("y", ScalarType::F32, &y),
            ("z", ScalarType::F32, &z),
            ("nx", ScalarType::F32, &nan),
            ("red", ScalarType::F32, &nan),
            ("green", ScalarType::F32, &nan),
            ("blue", ScalarType::F64, &nan),
        ],
        &[],
    )
    .unwrap();
    let p = d.path().join("nan_props.ply");
    ply.write_path(&p).unwrap();
    let out = d.path().join("out");
    let text = mvao_ok(&["merge", "-q", "-o", &s(&out), &s(&p), "--radius", "0.3"]);
    let n = pts.len().div_ceil(3);
    assert!(
        text.contains(&format!(
            "non-finite values in vertex properties nx ({n}), red ({n}), green ({n}), blue ({n})"
        )),
        "{text}"
    );
    let o = PlyFile::from_path(&out.join("nan_props.mvao.ply")).unwrap();
    for prop in ["nx", "red", "green", "blue", "ao"] {
        let c = o.scalar_column("vertex", prop).unwrap();
        assert!(
            c.iter().all(|v| v.is_finite()),
            "{prop} has a non-finite value"
        );
    }
    assert!(o.scalar_column("vertex", "nx").unwrap()[0] == 0.0);
}

#[test]
fn alignment_mismatches_are_errors() {
    let d = tempfile::tempdir().unwrap();
    let a = small_scan(d.path(), "a.ply", &dome(500));
    let b = small_scan(d.path(), "b.ply", &dome(500));
    let out = d.path().join("out");
    let al = d.path().join("poses.json");
    let id = "[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]";
    std::fs::write(&al, format!("{{\"a.ply\": {id}, \"c.ply\": {id}}}")).unwrap();
    fails(
        &[
            "merge".into(),
            "-o".into(),
            s(&out),
            "--align".into(),
            s(&al),
            s(&a),
            s(&b),
        ],
        "poses.json",
    );
    std::fs::write(
        &al,
        format!("{{\"a.ply\": {id}, \"b.ply\": [2,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]}}"),
    )
    .unwrap();
    let err = fails(
        &[
            "merge".into(),
            "-o".into(),
            s(&out),
            "--align".into(),
            s(&al),
            s(&a),
            s(&b),
        ],
        "poses.json",
    );
    assert!(err.contains("scale") || err.contains("shear"), "{err}");
    assert!(!out.exists());
}

/// `--pose` overrides the alignment beside the scans for its scan (whose entry then counts as
/// given); a `--pose` or `--only` naming no scan is an error, as is a file given twice.
#[test]
fn pose_overrides_and_names_that_match_nothing() {
    let d = tempfile::tempdir().unwrap();
    let a = small_scan(d.path(), "a.ply", &dome(500));
    let b = small_scan(d.path(), "b.ply", &dome(500));
    let id = "[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]";
    std::fs::write(
        d.path().join("poses.json"),
        format!("{{\"a.ply\": {id}, \"b.ply\": {id}}}"),
    )
    .unwrap();
    let m = d.path().join("a_pose.txt");
    std::fs::write(&m, "1 0 0 0.5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
    let out = d.path().join("out");
    let pose = format!("a={}", s(&m));
    let r = mvao(&["info", "--pose", &pose, &s(&a), &s(&b)]);
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(text.contains("--pose"), "{text}");
    let ghost = format!("ghost={}", s(&m));
    let err = fails(
        &[
            "merge".into(),
            "-o".into(),
            s(&out),
            "--pose".into(),
            ghost,
            s(&a),
            s(&b),
        ],
        "no input file or scan is named 'ghost'",
    );
    assert_eq!(err.lines().count(), 1, "{err}");
    let r = mvao(&["prepare", "-o", &s(&out), "--only", "ghost", &s(&a), &s(&b)]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("--only ghost"), "{err}");
    fails(
        &[
            "merge".into(),
            "-o".into(),
            s(&out),
            "--align".into(),
            s(&d.path().join("poses.json")),
            s(&a),
            s(&a),
        ],
        "a.ply",
    );
    assert!(!out.join("report.json").exists());
}

/// Coordinates scaled far past anything scanned, or into nanometres, are refused naming the
/// file (by `merge` and by `prepare`); a scan with every point at one place needs a radius.
#[test]
fn coordinates_out_of_usable_range() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    for (name, scale) in [("huge.ply", 1e25), ("tiny.ply", 1e-25)] {
        let pts: Vec<[f64; 3]> = dome(500)
            .iter()
            .map(|p| [p[0] * scale, p[1] * scale, p[2] * scale])
            .collect();
        let p = small_scan(d.path(), name, &pts);
        for cmd in ["merge", "prepare"] {
            let r = mvao(&[cmd, "-q", "-o", &s(&out), &s(&p)]);
            let err = String::from_utf8_lossy(&r.stderr);
            assert_eq!(r.status.code(), Some(2), "{cmd} {name}: {err}");
            assert!(err.contains(name) && !err.contains("panicked"), "{err}");
        }
    }
    let same = small_scan(d.path(), "same.ply", &[[0.3, 0.2, -1.0]; 50]);
    let err = fails(
        &["merge".into(), "-o".into(), s(&out), s(&same)],
        "give --radius",
    );
    assert!(err.contains("one place"), "{err}");
    assert!(!out.join("report.json").exists());
}

/// An output path that is a file, a sidecar of prose, and two sidecars for one scan.
#[test]
fn output_paths_and_sidecars() {
    let d = tempfile::tempdir().unwrap();
    let a = small_scan(d.path(), "a.ply", &dome(500));
    let file = d.path().join("afile");
    std::fs::write(&file, b"x").unwrap();
    fails(
        &["merge".into(), "-o".into(), s(&file), s(&a)],
        "exists and is not a directory",
    );
    std::fs::write(d.path().join("a.txt"), "scanned on Tuesday\n").unwrap();
    let out = d.path().join("out");
    fails(
        &["merge".into(), "-o".into(), s(&out), s(&a)],
        "'scanned' is not a finite number",
    );
    std::fs::write(d.path().join("a.mat"), "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1").unwrap();
    fails(
        &["merge".into(), "-o".into(), s(&out), s(&a)],
        "several sidecar pose files",
    );
    assert_eq!(std::fs::read(&file).unwrap(), b"x");
}

#[test]
fn existing_outputs_need_force() {
    let d = tempfile::tempdir().unwrap();
    let a = small_scan(d.path(), "a.ply", &dome(2000));
    let out = d.path().join("out");
    let args = ["merge", "-q", "--radius", "0.3", "-o", &s(&out), &s(&a)];
    assert!(mvao(&args).status.success());
    let first = std::fs::read(out.join("a.mvao.ply")).unwrap();
    fails(
        &args.iter().map(|x| x.to_string()).collect::<Vec<_>>(),
        "--force",
    );
    let mut forced: Vec<&str> = args.to_vec();
    forced.push("--force");
    assert!(mvao(&forced).status.success());
    // Same seed, same bytes.
    assert_eq!(std::fs::read(out.join("a.mvao.ply")).unwrap(), first);
    // No temporary files left behind.
    let stray: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    assert!(stray.is_empty());
    // A forced rerun that fails half way (an output it cannot replace) leaves no report
    // beside its new outputs.
    let b = small_scan(d.path(), "b.ply", &dome(2000));
    let both = [
        "merge",
        "-q",
        "--radius",
        "0.3",
        "-o",
        &s(&out),
        &s(&a),
        &s(&b),
        "--force",
    ];
    assert!(mvao(&both).status.success());
    assert!(out.join("report.json").exists());
    std::fs::remove_file(out.join("b.mvao.ply")).unwrap();
    std::fs::create_dir(out.join("b.mvao.ply")).unwrap();
    std::fs::write(out.join("b.mvao.ply").join("keep"), b"x").unwrap();
    let mut other = both.to_vec();
    other[3] = "0.5";
    let r = mvao(&other);
    assert_eq!(
        r.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    assert!(!out.join("report.json").exists());
}

#[test]
fn bad_flag_values_are_rejected() {
    let d = tempfile::tempdir().unwrap();
    let a = small_scan(d.path(), "a.ply", &dome(100));
    fails(&["merge".into(), s(&a), "--radius=-1".into()], "--radius");
    let r = mvao(&["merge", &s(&a), "--neighbors", "4"]);
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("1, 3, 5, 7, 9"));
    fails(
        &["merge".into(), s(&a), "--dmin=5".into(), "--dmax=1".into()],
        "--dmin 5 must be below --dmax 1",
    );
    fails(
        &["merge".into(), s(&a), "--spacing-weight=-0.1".into()],
        "--spacing-weight must be 0 or positive",
    );
    let m = d.path().join("a_pose.txt");
    std::fs::write(&m, "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
    let pose = format!("a={}", s(&m));
    fails(
        &[
            "merge".into(),
            "--pose".into(),
            pose.clone(),
            "--pose".into(),
            pose,
            s(&a),
        ],
        "--pose a is given twice",
    );
}

/// A small stream of `n` synthetic depth frames in `dir` (`depth/`, `trajectory.log`).
fn small_stream(dir: &Path, n: u32) -> PathBuf {
    let out = dir.join("stream");
    mvao_ok(&[
        "synth",
        "--frames",
        &n.to_string(),
        "--width",
        "32",
        "--height",
        "24",
        "-o",
        &s(&out),
    ]);
    out
}

/// See issue 33: bad depth streams fail with one line naming the file, and nothing is
/// written.
#[test]
fn issue_33_bad_streams_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let st = small_stream(d.path(), 3);
    let k = std::fs::read_to_string(st.join("intrinsics.txt")).unwrap();
    let traj = st.join("trajectory.log");
    let out = d.path().join("out");
    let run = |frames: Vec<String>, traj: &Path| {
        let mut a = vec!["stream".to_string()];
        a.extend(frames);
        a.extend([
            "-t".into(),
            s(traj),
            "--intrinsics".into(),
            k.trim().into(),
            "-o".into(),
            s(&out),
            "-q".into(),
        ]);
        a
    };
    let frame = |i: u32| s(&st.join(format!("depth/{i:05}.png")));
    // A frame that does not exist.
    let missing = s(&st.join("depth/00009.png"));
    let err = fails(
        &run(vec![frame(0), frame(1), missing.clone()], &traj),
        &missing,
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    // An 8-bit PNG among the frames.
    let eight = d.path().join("eight.png");
    mvao::testing::preview::write_png(&eight, 32, 24, &vec![128u8; 32 * 24 * 2]).unwrap();
    fails(&run(vec![frame(0), frame(1), s(&eight)], &traj), "16-bit");
    // A malformed trajectory line.
    let bad = d.path().join("bad.log");
    let text = std::fs::read_to_string(&traj).unwrap();
    let bad_lines: Vec<&str> = text.lines().collect();
    let mut broken = bad_lines.clone();
    broken[2] = "1 0 zero 0";
    std::fs::write(&bad, broken.join("\n")).unwrap();
    fails(&run(vec![s(&st.join("depth"))], &bad), "bad.log: line 3");
    // Frames and poses that do not match in number.
    fails(
        &run(vec![frame(0), frame(1)], &traj),
        "3 poses for 2 depth frames",
    );
    assert!(!out.join("report.json").exists());
    // The good stream runs and writes its outputs.
    let ok = run(vec![s(&st.join("depth"))], &traj);
    let a: Vec<&str> = ok.iter().map(|x| x.as_str()).collect();
    mvao_ok(&a);
    assert!(out.join("report.json").exists() && out.join("stream.ply").exists());
    assert!(!out.join("stream.checkpoint").exists());
}

/// Coordinates given as comma lists may start with a minus sign.
#[test]
fn negative_coordinates_are_values_not_flags() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("porch");
    mvao_ok(&[
        "synth",
        "--scene",
        "porch",
        "--projection",
        "perspective",
        "--stations",
        "1",
        "--width",
        "24",
        "--height",
        "16",
        "--at",
        "-1.5,-6,1.6",
        "--look-at",
        "-0.5,0,1",
        "-o",
        &s(&out),
    ]);
    let head = std::fs::read(out.join("station_000.ply")).unwrap();
    let text = String::from_utf8_lossy(&head[..400.min(head.len())]).into_owned();
    assert!(text.contains("station position -1.5"), "{text}");
}
