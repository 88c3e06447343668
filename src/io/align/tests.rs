use super::*;
use std::fs;

fn manifest(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    fs::write(&p, text).unwrap();
    p
}

fn max_diff(a: DMat4, b: DMat4) -> f64 {
    (a - b)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
}

fn msg(e: Error) -> String {
    e.to_string()
}

fn rows(r: [[f64; 4]; 4]) -> DMat4 {
    DMat4::from_cols_array_2d(&r).transpose()
}

#[test]
fn conf_quaternion_uses_transpose_convention() {
    let dir = tempfile::tempdir().unwrap();
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let p = write(
        dir.path(),
        "a.conf",
        &format!(
            "# comment\ncamera 0 0 1 0 0 0 1\n\nbmesh id.ply 0 0 0 0 0 0 1\n\
                 bmesh rz.ply 1 2 3 0 0 {s} {s}\nfoo bar\n"
        ),
    );
    let al = read_alignment(&p).unwrap();
    assert_eq!(al.entries.len(), 2);
    assert_eq!(al.entries[0].file, "id.ply");
    assert_eq!(al.entries[0].pose, DMat4::IDENTITY);
    // R(q) for 90° about z is [[0,-1,0],[1,0,0],[0,0,1]]; the pose uses its transpose.
    let want = rows([
        [0.0, 1.0, 0.0, 1.0],
        [-1.0, 0.0, 0.0, 2.0],
        [0.0, 0.0, 1.0, 3.0],
        [0.0, 0.0, 0.0, 1.0],
    ]);
    assert!(max_diff(al.entries[1].pose, want) < 1e-15);
    // The local x axis lands on world -y, shifted by t.
    let w = al.entries[1].pose.transform_point3(DVec3::X);
    assert!((w - DVec3::new(1.0, 1.0, 3.0)).length() < 1e-15);
}

#[test]
fn conf_quaternion_is_normalised() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "a.conf", "bmesh a.ply 0 0 0 0 0 2 2\n");
    let pose = read_alignment(&p).unwrap().entries[0].pose;
    assert!(
        max_diff(
            pose,
            rows([
                [0.0, 1.0, 0.0, 0.0],
                [-1.0, 0.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
            ])
        ) < 1e-15
    );
}

#[test]
fn conf_errors_name_the_line() {
    let dir = tempfile::tempdir().unwrap();
    for (text, want) in [
        (
            "bmesh a.ply 0 0 0 0 0 0 1\nbmesh b.ply 0 0 x 0 0 0 1\n",
            "line 2",
        ),
        ("bmesh a.ply 0 0 0 0 0 1\n", "7 numbers"),
        ("\n\nbmesh a.ply 0 0 0 0 0 0 0\n", "line 3"),
        ("bmesh a.ply 0 0 0 0 0 0 NaN\n", "not a finite number"),
        ("camera 0 0 0 0 0 0 1\n", "names no scans"),
    ] {
        let p = write(dir.path(), "bad.conf", text);
        let e = msg(read_alignment(&p).unwrap_err());
        assert!(e.contains(want), "{text:?}: {e}");
        assert!(e.contains("bad.conf"), "{e}");
    }
}

const MLP: &str = r#"<!DOCTYPE MeshLabDocument>
<MeshLabProject>
 <MeshGroup>
  <MLMesh label="first" filename="sub/a.ply">
   <MLMatrix44>
1 0 0 0
0 1 0 0
0 0 1 0
0 0 0 1
</MLMatrix44>
  </MLMesh>
  <MLMesh label="b.ply">
   <MLMatrix44>
0 -1 0 10
1 0 0 20
0 0 1 30
0 0 0 1 </MLMatrix44>
  </MLMesh>
 </MeshGroup>
 <RasterGroup/>
</MeshLabProject>
"#;

#[test]
fn mlp_parse_row_major_and_label_fallback() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "proj.MLP", MLP);
    let al = read_alignment(&p).unwrap();
    assert_eq!(al.entries.len(), 2);
    assert_eq!(al.entries[0].file, "sub/a.ply");
    assert_eq!(al.entries[0].pose, DMat4::IDENTITY);
    assert_eq!(al.entries[1].file, "b.ply");
    let m = al.entries[1].pose;
    assert_eq!(m.w_axis, glam::DVec4::new(10.0, 20.0, 30.0, 1.0));
    assert_eq!(m.transform_point3(DVec3::X), DVec3::new(10.0, 21.0, 30.0));
}

#[test]
fn mlp_errors() {
    let dir = tempfile::tempdir().unwrap();
    let fifteen = MLP.replace("0 0 1 30\n", "0 0 1\n");
    let word = MLP.replace("0 0 1 30", "0 0 one 30");
    let no_matrix = "<MeshLabProject><MeshGroup><MLMesh filename=\"a.ply\"></MLMesh>\
                         </MeshGroup></MeshLabProject>";
    let broken = "<MeshLabProject><MeshGroup></MLMesh></MeshLabProject>";
    for (text, want) in [
        (fifteen.as_str(), "expected 16 numbers, found 15"),
        (word.as_str(), "'one' is not a finite number"),
        (no_matrix, "no MLMatrix44"),
        (broken, "line 1"),
    ] {
        let p = write(dir.path(), "bad.mlp", text);
        let e = msg(read_alignment(&p).unwrap_err());
        assert!(e.contains(want), "{e}");
    }
}

#[test]
fn json_parse() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "a.Json",
        r#"{ "x.ply": [0,-1,0,1, 1,0,0,2, 0,0,1,3, 0,0,0,1], "y.ply": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1] }"#,
    );
    let al = read_alignment(&p).unwrap();
    assert_eq!(al.entries.len(), 2);
    assert_eq!(al.entries[0].file, "x.ply");
    assert_eq!(
        al.entries[0].pose.w_axis,
        glam::DVec4::new(1.0, 2.0, 3.0, 1.0)
    );
    assert_eq!(
        al.entries[0].pose.transform_vector3(DVec3::X),
        DVec3::new(0.0, 1.0, 0.0)
    );
    assert_eq!(al.entries[1].pose, DMat4::IDENTITY);
}

#[test]
fn json_errors() {
    let dir = tempfile::tempdir().unwrap();
    for (text, want) in [
        ("[1, 2]", "expected a JSON object"),
        ("{\"a.ply\": 3}", "expected an array of 16 numbers"),
        ("{\"a.ply\": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0]}", "found 15"),
        (
            "{\"a.ply\": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,\"1\"]}",
            "not a finite",
        ),
        (
            "{\"a.ply\": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1e999]}",
            "a.json",
        ),
        ("{}", "names no scans"),
        (
            "{\"a.ply\": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1",
            "expected a JSON object",
        ),
    ] {
        let p = write(dir.path(), "a.json", text);
        let e = msg(read_alignment(&p).unwrap_err());
        assert!(e.contains(want), "{text}: {e}");
    }
}

#[test]
fn missing_file_and_unknown_extension() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("none.conf");
    let e = read_alignment(&p).unwrap_err();
    assert!(matches!(e, Error::Io { .. }), "{e}");
    assert!(msg(e).contains("none.conf"));
    let p = write(dir.path(), "poses.txt", "bmesh a.ply 0 0 0 0 0 0 1\n");
    let e = msg(read_alignment(&p).unwrap_err());
    assert!(
        e.contains("poses.txt") && e.contains("unknown alignment format"),
        "{e}"
    );
}

#[test]
fn non_rigid_poses_are_rejected() {
    let p = Path::new("x.mlp");
    let scale = DMat4::from_scale(DVec3::splat(1.1));
    let e = msg(check_rigid(scale, p, "s.ply").unwrap_err());
    assert!(
        e.contains("'s.ply' has scale or shear") && e.contains("2.100e-1"),
        "{e}"
    );
    let shear = rows([
        [1.0, 0.1, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]);
    let e = msg(check_rigid(shear, p, "sh.ply").unwrap_err());
    assert!(
        e.contains("scale or shear") && e.contains("1.000e-1"),
        "{e}"
    );
    let mirror = DMat4::from_scale(DVec3::new(1.0, 1.0, -1.0));
    let e = msg(check_rigid(mirror, p, "m.ply").unwrap_err());
    assert!(e.contains("'m.ply' is a reflection"), "{e}");
    let mut proj = DMat4::IDENTITY;
    proj.x_axis.w = 0.5;
    let e = msg(check_rigid(proj, p, "p.ply").unwrap_err());
    assert!(e.contains("projective bottom row"), "{e}");
    let mut nan = DMat4::IDENTITY;
    nan.w_axis.x = f64::NAN;
    assert!(msg(check_rigid(nan, p, "n.ply").unwrap_err()).contains("non-finite"));
    let zero = DMat4::from_scale(DVec3::ZERO);
    assert!(msg(check_rigid(zero, p, "z.ply").unwrap_err()).contains("scale or shear"));
    // ... and they are rejected when read from a file too.
    let dir = tempfile::tempdir().unwrap();
    let f = write(
        dir.path(),
        "s.json",
        r#"{"a.ply": [1.1,0,0,0, 0,1.1,0,0, 0,0,1.1,0, 0,0,0,1]}"#,
    );
    assert!(msg(read_alignment(&f).unwrap_err()).contains("scale or shear"));
}

#[test]
fn tiny_non_orthogonality_is_repaired() {
    let r = DMat3::from_quat(DQuat::from_axis_angle(
        DVec3::new(1.0, 2.0, 3.0).normalize(),
        0.7,
    ));
    let noisy = DMat3::from_cols(
        r.x_axis + DVec3::new(1e-6, -2e-7, 5e-7),
        r.y_axis * (1.0 + 1e-6),
        r.z_axis + DVec3::new(-3e-7, 1e-6, 0.0),
    );
    let t = DVec3::new(4.0, -5.0, 6.5);
    let m = DMat4::from_cols(
        noisy.x_axis.extend(0.0),
        noisy.y_axis.extend(0.0),
        noisy.z_axis.extend(0.0),
        t.extend(1.0),
    );
    assert!(orthogonality_error(noisy) > 1e-7);
    let fixed = check_rigid(m, Path::new("x"), "x").unwrap();
    let fr = DMat3::from_mat4(fixed);
    assert!(
        orthogonality_error(fr) < 1e-15,
        "{}",
        orthogonality_error(fr)
    );
    assert!((fr.determinant() - 1.0).abs() < 1e-15);
    assert!(max_diff(fixed, m) < 3e-6);
    assert_eq!(fixed.w_axis, t.extend(1.0));
    assert_eq!(fixed.row(3), glam::DVec4::W);
}

fn al(path: &Path, names: &[&str]) -> Alignment {
    Alignment {
        path: path.to_path_buf(),
        entries: names
            .iter()
            .enumerate()
            .map(|(i, n)| AlignEntry {
                file: n.to_string(),
                pose: DMat4::from_translation(DVec3::splat(i as f64)),
            })
            .collect(),
    }
}

#[test]
fn matching_by_name_in_scan_order() {
    let a = al(Path::new("/d/x.conf"), &["a.ply", "sub/b.ply", "c.ply"]);
    let scans = [
        PathBuf::from("/e/c.ply"),
        PathBuf::from("a.ply"),
        PathBuf::from("/q/b.ply"),
    ];
    let p = poses_for_scans(&a, &scans).unwrap();
    let tx: Vec<f64> = p.iter().map(|m| m.w_axis.x).collect();
    assert_eq!(tx, vec![2.0, 0.0, 1.0]);
}

#[test]
fn matching_errors() {
    let a = al(Path::new("/d/x.conf"), &["bun000.ply", "bun090.ply"]);
    let scans = [
        PathBuf::from("/d/bun000.ply"),
        PathBuf::from("/d/bun090.ply"),
        PathBuf::from("/d/x.ply"),
    ];
    let e = msg(poses_for_scans(&a, &scans).unwrap_err());
    assert!(
        e.contains("scan '/d/x.ply' is not in the alignment file") && e.contains("--pose"),
        "{e}"
    );
    assert!(e.starts_with("/d/x.conf: "), "{e}");
    let dup = al(Path::new("/d/x.conf"), &["a.ply", "./a.ply"]);
    let e = msg(poses_for_scans(&dup, &[PathBuf::from("/d/a.ply")]).unwrap_err());
    assert!(e.contains("'./a.ply' is named more than once"), "{e}");
    let one = al(Path::new("/d/x.conf"), &["a.ply"]);
    let e = msg(poses_for_scans(
        &one,
        &[PathBuf::from("/d/a.ply"), PathBuf::from("/d/./a.ply")],
    )
    .unwrap_err());
    assert!(e.contains("both match"), "{e}");
}

/// Part of a site: entries that match no scan are fine, and `match_scans` leaves a scan
/// the file does not name without a pose instead of failing.
#[test]
fn a_subset_of_the_entries_is_normal() {
    let a = al(Path::new("/d/x.conf"), &["a.ply", "b.ply", "c.ply"]);
    let p = poses_for_scans(&a, &[PathBuf::from("/d/c.ply")]).unwrap();
    assert_eq!(p, vec![DMat4::from_translation(DVec3::splat(2.0))]);
    let m = match_scans(&a, &[PathBuf::from("/d/z.ply"), PathBuf::from("/d/b.ply")]).unwrap();
    assert_eq!(
        m,
        vec![None, Some(DMat4::from_translation(DVec3::splat(1.0)))]
    );
    assert_eq!(match_scans(&a, &[]).unwrap(), vec![]);
}

#[test]
fn ambiguous_names_fall_back_to_relative_paths() {
    let a = al(Path::new("/d/x.mlp"), &["l/s.ply", "r\\s.ply", "t.ply"]);
    let scans = [
        PathBuf::from("/d/r/s.ply"),
        PathBuf::from("/d/l/../l/s.ply"),
        PathBuf::from("/other/t.ply"),
    ];
    let p = poses_for_scans(&a, &scans).unwrap();
    let tx: Vec<f64> = p.iter().map(|m| m.w_axis.x).collect();
    assert_eq!(tx, vec![1.0, 0.0, 2.0]);
    let e = msg(poses_for_scans(&a, &[PathBuf::from("/d/q/s.ply")]).unwrap_err());
    assert!(
        e.contains("scan '/d/q/s.ply' is not in the alignment file"),
        "{e}"
    );
}

#[test]
fn find_alignment_beside_counts_candidates() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scan = write(d, "s.ply", "");
    write(d, "notes.txt", "");
    write(d, ".hidden.json", "");
    assert_eq!(
        find_alignment_beside(std::slice::from_ref(&scan)).unwrap(),
        None
    );
    let conf = write(d, "poses.CONF", "");
    assert_eq!(
        find_alignment_beside(&[scan.clone(), scan.clone()]).unwrap(),
        Some(conf)
    );
    write(d, "poses.mlp", "");
    let e = find_alignment_beside(&[scan]).unwrap_err();
    assert!(matches!(e, Error::Param(_)));
    let e = msg(e);
    assert!(
        e.contains("poses.CONF") && e.contains("poses.mlp") && e.contains("--align"),
        "{e}"
    );
}

#[test]
fn write_mlp_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let r = DMat3::from_quat(DQuat::from_axis_angle(
        DVec3::new(-1.0, 0.5, 2.0).normalize(),
        2.1,
    ));
    let pose = DMat4::from_cols(
        r.x_axis.extend(0.0),
        r.y_axis.extend(0.0),
        r.z_axis.extend(0.0),
        DVec4::new(1e-7, -123.456, 1.0 / 3.0, 1.0),
    );
    let pose = check_rigid(pose, Path::new("x"), "x").unwrap();
    let entries = vec![
        AlignEntry {
            file: "a&b <1>.ply".into(),
            pose,
        },
        AlignEntry {
            file: "sub/c.ply".into(),
            pose: DMat4::IDENTITY,
        },
    ];
    let p = dir.path().join("out.mlp");
    write_mlp(&p, &entries).unwrap();
    let back = read_alignment(&p).unwrap();
    assert_eq!(back.entries.len(), 2);
    assert_eq!(back.entries[0].file, "a&b <1>.ply");
    assert_eq!(back.entries[1].file, "sub/c.ply");
    assert!(max_diff(back.entries[0].pose, pose) < 1e-15);
    assert_eq!(back.entries[1].pose, DMat4::IDENTITY);
}

#[test]
fn real_bunny_conf() {
    let p = manifest("fixtures/stanford-bunny/bun.conf");
    let al = read_alignment(&p).unwrap();
    assert_eq!(al.entries.len(), 10);
    assert_eq!(al.entries[0].file, "bun000.ply");
    assert_eq!(al.entries[0].pose, DMat4::IDENTITY);
    let names: Vec<&str> = al.entries.iter().map(|e| e.file.as_str()).collect();
    assert!(names.contains(&"ear_back.ply") && names.contains(&"chin.ply"));
    // bun180: q ≈ (0, 1, 0, 0), a half turn about y, so local x maps to about world -x.
    let b180 = al
        .entries
        .iter()
        .find(|e| e.file == "bun180.ply")
        .unwrap()
        .pose;
    assert!((b180.transform_vector3(DVec3::X) - DVec3::NEG_X).length() < 1e-2);
    let scans: Vec<PathBuf> = names.iter().rev().map(|n| p.with_file_name(n)).collect();
    let poses = poses_for_scans(&al, &scans).unwrap();
    assert_eq!(poses.len(), 10);
    assert_eq!(poses[9], DMat4::IDENTITY);
}

#[test]
fn real_3dtk_mlp_and_json_agree() {
    let mlp = read_alignment(&manifest("fixtures/3dtk-uos-3scans/alignment.mlp")).unwrap();
    let json = read_alignment(&manifest("fixtures/3dtk-uos-3scans/json/alignment.json")).unwrap();
    assert_eq!(mlp.entries.len(), 3);
    assert_eq!(json.entries.len(), 3);
    for (a, b) in mlp.entries.iter().zip(&json.entries) {
        assert_eq!(a.file, b.file);
        assert!(max_diff(a.pose, b.pose) < 1e-12, "{}", a.file);
    }
    assert_eq!(mlp.entries[0].pose, DMat4::IDENTITY);
    let t = mlp.entries[1].pose.w_axis;
    assert_eq!(t, glam::DVec4::new(1.56796, 0.036331, -0.0908315, 1.0));
}
