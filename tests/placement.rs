//! Placing scans: every alignment format gives the same poses, per-scan matrix sidecars and
//! `--pose` override them, scaled poses need `--allow-scale`, a site moved to survey
//! coordinates gives the same AO, and `mvao info` describes what `merge` would see.

mod common;

use common::*;
use glam::{DMat4, DVec3};
use mvao::io::align::{read_alignment, write_mlp, AlignEntry};
use mvao::io::ply::PlyFile;
use std::path::{Path, PathBuf};

/// Copies the three 3DTK stations into `dir` (without their alignment).
fn copy_3dtk(dir: &Path) -> Vec<PathBuf> {
    plys("3dtk-uos-3scans")
        .iter()
        .map(|p| {
            let q = dir.join(p.file_name().unwrap());
            std::fs::copy(p, &q).unwrap();
            q
        })
        .collect()
}

fn poses_3dtk() -> Vec<AlignEntry> {
    read_alignment(&fixture("3dtk-uos-3scans/alignment.mlp"))
        .unwrap()
        .entries
}

fn row_major(m: &DMat4) -> String {
    (0..4)
        .map(|r| {
            let v = m.row(r);
            format!("{:?} {:?} {:?} {:?}\n", v.x, v.y, v.z, v.w)
        })
        .collect()
}

fn ao_of(path: &Path) -> Vec<f64> {
    PlyFile::from_path(path)
        .unwrap()
        .scalar_column("vertex", "ao")
        .unwrap()
}

fn merge(args: &[&str]) -> String {
    let mut a = vec!["merge", "-q", "--no-preview", "--force"];
    if !args.contains(&"--tmax") {
        a.extend(["--radius", "0.3"]);
    } else {
        a.extend(["--radius", "0.2"]);
    }
    a.extend_from_slice(args);
    let r = mvao(&a);
    let err = String::from_utf8_lossy(&r.stderr).into_owned();
    assert!(r.status.success(), "{err}");
    err
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[test]
fn aln_sidecars_and_pose_flags_place_scans_like_the_mlp() {
    let d = tempfile::tempdir().unwrap();
    let entries = poses_3dtk();
    // Reference run with the .mlp.
    let src = d.path().join("src");
    std::fs::create_dir(&src).unwrap();
    let scans = copy_3dtk(&src);
    let s: Vec<&str> = scans.iter().map(|p| p.to_str().unwrap()).collect();
    let mlp = fixture("3dtk-uos-3scans/alignment.mlp");
    let out_ref = d.path().join("ref");
    merge(&[
        "--align",
        mlp.to_str().unwrap(),
        "-o",
        out_ref.to_str().unwrap(),
        s[0],
        s[1],
        s[2],
    ]);

    // MeshLab .aln with the same matrices.
    let aln = d.path().join("a.aln");
    let mut text = format!("{}\n", entries.len());
    for e in &entries {
        text += &format!("{}\n#\n{}", e.file, row_major(&e.pose));
    }
    text += "0\n";
    std::fs::write(&aln, text).unwrap();
    let al = read_alignment(&aln).unwrap();
    for (a, b) in al.entries.iter().zip(&entries) {
        assert_eq!(a.file, b.file);
        assert!(a.pose.abs_diff_eq(b.pose, 1e-12));
    }
    let out_aln = d.path().join("aln");
    merge(&[
        "--align",
        aln.to_str().unwrap(),
        "-o",
        out_aln.to_str().unwrap(),
        s[0],
        s[1],
        s[2],
    ]);

    // Per-scan sidecars (no alignment file in the directory).
    let sc = d.path().join("sidecar");
    std::fs::create_dir(&sc).unwrap();
    let scans_sc = copy_3dtk(&sc);
    for (p, e) in scans_sc.iter().zip(&entries) {
        assert_eq!(p.file_name().unwrap().to_str().unwrap(), e.file);
        std::fs::write(p.with_extension("txt"), row_major(&e.pose)).unwrap();
    }
    let out_sc = d.path().join("sc-out");
    let ssc: Vec<&str> = scans_sc.iter().map(|p| p.to_str().unwrap()).collect();
    merge(&["-o", out_sc.to_str().unwrap(), ssc[0], ssc[1], ssc[2]]);

    // --pose for every scan, comma-separated matrices.
    let pd = d.path().join("pose");
    std::fs::create_dir(&pd).unwrap();
    let scans_p = copy_3dtk(&pd);
    let mut flags: Vec<String> = Vec::new();
    for (p, e) in scans_p.iter().zip(&entries) {
        let m = d.path().join(format!("{}.mat4", e.file));
        std::fs::write(&m, row_major(&e.pose).replace(' ', ", ")).unwrap();
        flags.push("--pose".into());
        flags.push(format!(
            "{}={}",
            p.file_stem().unwrap().to_str().unwrap(),
            m.display()
        ));
    }
    let out_p = d.path().join("p-out");
    let mut args: Vec<&str> = flags.iter().map(String::as_str).collect();
    args.extend(["-o", out_p.to_str().unwrap()]);
    args.extend(scans_p.iter().map(|p| p.to_str().unwrap()));
    merge(&args);

    for name in ["scan000", "scan001", "scan002"] {
        let f = format!("{name}.mvao.ply");
        let r = ao_of(&out_ref.join(&f));
        assert_eq!(r, ao_of(&out_aln.join(&f)), "{name}: .aln differs");
        assert_eq!(r, ao_of(&out_sc.join(&f)), "{name}: sidecar differs");
        assert_eq!(r, ao_of(&out_p.join(&f)), "{name}: --pose differs");
    }
}

#[test]
fn a_bad_sidecar_names_itself() {
    let d = tempfile::tempdir().unwrap();
    let scans = copy_3dtk(d.path());
    std::fs::write(scans[1].with_extension("txt"), "1 0 0\n0 1 0\n").unwrap();
    let r = mvao(&[
        "merge",
        "-q",
        "-o",
        d.path().join("o").to_str().unwrap(),
        scans[0].to_str().unwrap(),
        scans[1].to_str().unwrap(),
        scans[2].to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(
        err.contains("scan001.txt") && err.contains("16 numbers"),
        "{err}"
    );
}

#[test]
fn scaled_poses_need_allow_scale_and_then_match_metric_data() {
    let d = tempfile::tempdir().unwrap();
    let entries = poses_3dtk();
    // The same scans stored in millimetres, with poses that scale by 1/1000.
    let mut files = Vec::new();
    let mut aln = format!("{}\n", entries.len());
    for (p, e) in plys("3dtk-uos-3scans").iter().zip(&entries) {
        let mut ply = PlyFile::from_path(p).unwrap();
        for c in ["x", "y", "z"] {
            let v: Vec<f64> = ply
                .scalar_column("vertex", c)
                .unwrap()
                .iter()
                .map(|x| x * 1000.0)
                .collect();
            ply.set_scalar_column("vertex", c, mvao::io::ply::ScalarType::F64, &v)
                .unwrap();
        }
        let q = d.path().join(p.file_name().unwrap());
        ply.write_path(&q).unwrap();
        files.push(q);
        let m = e.pose * DMat4::from_scale(DVec3::splat(1e-3));
        aln += &format!("{}\n#\n{}", e.file, row_major(&m));
    }
    aln += "0\n";
    let alnp = d.path().join("mm.aln");
    std::fs::write(&alnp, aln).unwrap();
    let f: Vec<&str> = files.iter().map(|p| p.to_str().unwrap()).collect();
    let out = d.path().join("o");
    let r = mvao(&[
        "merge",
        "-q",
        "--radius",
        "0.3",
        "-o",
        out.to_str().unwrap(),
        f[0],
        f[1],
        f[2],
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("mm.aln") && err.contains("scale"), "{err}");

    merge(&[
        "--allow-scale",
        "-o",
        out.to_str().unwrap(),
        f[0],
        f[1],
        f[2],
    ]);
    let metric = d.path().join("metric");
    merge(&[
        "--align",
        fixture("3dtk-uos-3scans/alignment.mlp").to_str().unwrap(),
        "-o",
        metric.to_str().unwrap(),
        plys("3dtk-uos-3scans")[0].to_str().unwrap(),
        plys("3dtk-uos-3scans")[1].to_str().unwrap(),
        plys("3dtk-uos-3scans")[2].to_str().unwrap(),
    ]);
    for name in ["scan000", "scan001", "scan002"] {
        let f = format!("{name}.mvao.ply");
        let (a, b) = (ao_of(&out.join(&f)), ao_of(&metric.join(&f)));
        let mean = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len() as f64;
        assert!(mean < 1e-3, "{name}: mean |Δao| {mean}");
    }
}

/// The synthetic room, three stations, placed at the origin and again at survey coordinates
/// (512 000, 5 200 000, 300) m through the alignment: AO agrees within 1e-4.
#[test]
fn a_site_at_survey_coordinates_gives_the_same_ao() {
    let d = tempfile::tempdir().unwrap();
    let site = d.path().join("site");
    let r = mvao(&[
        "synth",
        "--stations",
        "3",
        "--width",
        "480",
        "--height",
        "240",
        "-o",
        site.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let mlp = site.join("alignment.mlp");
    let al = read_alignment(&mlp).unwrap();
    let off = DVec3::new(512_000.0, 5_200_000.0, 300.0);
    let moved: Vec<AlignEntry> = al
        .entries
        .iter()
        .map(|e| AlignEntry {
            file: e.file.clone(),
            pose: DMat4::from_translation(off) * e.pose,
        })
        .collect();
    let geo = d.path().join("geo.mlp");
    write_mlp(&geo, &moved).unwrap();
    let mut scans: Vec<PathBuf> = std::fs::read_dir(&site)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ply"))
        .collect();
    scans.sort();
    assert_eq!(scans.len(), 3);
    let s: Vec<&str> = scans.iter().map(|p| p.to_str().unwrap()).collect();
    let (o1, o2) = (d.path().join("o1"), d.path().join("o2"));
    for (a, o) in [(&mlp, &o1), (&geo, &o2)] {
        merge(&[
            "--tmax",
            "0.4",
            "--align",
            a.to_str().unwrap(),
            "-o",
            o.to_str().unwrap(),
            s[0],
            s[1],
            s[2],
        ]);
    }
    for p in &scans {
        let f = format!("{}.mvao.ply", p.file_stem().unwrap().to_str().unwrap());
        let (a, b) = (ao_of(&o1.join(&f)), ao_of(&o2.join(&f)));
        let m = max_diff(&a, &b);
        assert!(m <= 1e-4, "{f}: max |Δao| = {m}");
    }
}

#[test]
fn info_describes_scans_poses_grids_and_overlaps() {
    let scans = plys("3dtk-uos-3scans");
    let mut args = vec!["info", "--json"];
    args.extend(scans.iter().map(|p| p.to_str().unwrap()));
    let r = mvao(&args);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let list = v["scans"].as_array().unwrap();
    assert_eq!(list.len(), 3);
    for s in list {
        assert_eq!(s["format"], "ply");
        assert_eq!(s["points"], 81360);
        assert_eq!(s["grid"], serde_json::json!([226, 360]));
        assert_eq!(s["sensor_model"], "equirect");
        assert_eq!(s["overlaps"].as_array().unwrap().len(), 2);
        assert!(s["pose_source"].as_str().unwrap().contains("alignment.mlp"));
    }
    // scan001's pose as the .mlp gives it.
    let e = &poses_3dtk()[1];
    let p = &list[1]["pose"];
    for r in 0..4 {
        for c in 0..4 {
            let got = p[r][c].as_f64().unwrap();
            assert!((got - e.pose.row(r)[c]).abs() < 1e-9);
        }
    }
    // Text form.
    let mut args = vec!["info"];
    args.extend(scans.iter().map(|p| p.to_str().unwrap()));
    let t = String::from_utf8_lossy(&mvao(&args).stdout).into_owned();
    assert!(
        t.contains("226 rows × 360 columns") && t.contains("overlaps:   scan001, scan002"),
        "{t}"
    );
}
