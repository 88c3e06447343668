//! Every format end to end through `mvao merge`: the real E57 station, multi-scan E57 and PTX
//! files of synthetic stations with known poses, LAS in world coordinates placed by a scanner
//! pose, cross-format outputs, and bad files of each format.

mod common;

use common::*;
use glam::{DMat4, DQuat, DVec3};
use mvao::io::e57::{write_e57_scans, E57Input, E57ScanOut};
use mvao::io::raw::{PointTable, RawGrid};
use mvao::io::source::{read_input, Format};
use mvao::synth::{scan_scene, Scene, Station};
use std::path::PathBuf;

/// Three equirect stations of the synthetic room (small maps), scan-local points with poses.
fn stations() -> Vec<mvao::testing::scan::Scan> {
    let scene = Scene::room();
    [
        (DVec3::new(-1.0, -1.5, 1.5), 0.0),
        (DVec3::new(2.0, 0.5, 1.4), 0.7),
        (DVec3::new(-2.5, 1.8, 1.6), -1.2),
    ]
    .iter()
    .enumerate()
    .map(|(i, (p, yaw))| {
        let st = Station::equirect(*p, *yaw, 360, 180);
        scan_scene(&scene, &st, 0.0, i as u64, &format!("st{i}"))
    })
    .collect()
}

fn grid_of(s: &mvao::testing::scan::Scan) -> RawGrid {
    let g = s.grid.as_ref().unwrap();
    RawGrid {
        rows: g.rows,
        cols: g.cols,
        row: g.row.clone(),
        col: g.col.clone(),
    }
}

fn local_xyz(s: &mvao::testing::scan::Scan) -> Vec<[f64; 3]> {
    s.points.iter().map(|p| p.as_dvec3().to_array()).collect()
}

fn ao_record() -> e57::RecordName {
    e57::RecordName::Unknown {
        namespace: "mvao".into(),
        name: "ao".into(),
    }
}

fn all_in_unit(v: &[f64]) -> bool {
    v.iter().all(|a| a.is_finite() && (0.0..=1.0).contains(a))
}

#[test]
fn the_real_e57_station_is_read_as_its_source_states_and_merged() {
    let e57 = fixture("libe57-pumpA/pumpAVisualReferenceImage.e57");
    let f = read_input(&e57).unwrap();
    assert_eq!(f.format, Format::E57);
    assert_eq!(f.scans.len(), 1);
    let s = &f.scans[0];
    assert_eq!(s.name, "pumpA");
    assert_eq!(s.len(), 155_201);
    assert!(s.pose.abs_diff_eq(DMat4::IDENTITY, 0.0));
    let g = s.grid.as_ref().unwrap();
    assert_eq!((g.rows, g.cols), (1074, 345));
    let range = s
        .points
        .iter()
        .map(|p| p.length())
        .fold((f32::INFINITY, 0f32), |(a, b), r| (a.min(r), b.max(r)));
    assert!(range.0 > 1.97 && range.1 < 5.44, "{range:?}");

    let d = tempfile::tempdir().unwrap();
    mvao_ok(&[
        "merge",
        "-q",
        "--no-preview",
        "-o",
        d.path().to_str().unwrap(),
        e57.to_str().unwrap(),
    ]);
    let out = E57Input::from_path(&d.path().join("pumpAVisualReferenceImage.mvao.e57")).unwrap();
    assert_eq!(out.scans.len(), 1);
    let ao = out.scans[0].values(&ao_record()).unwrap();
    assert_eq!(ao.len(), 155_201);
    assert!(all_in_unit(&ao));
    let mean = ao.iter().sum::<f64>() / ao.len() as f64;
    assert!(mean > 0.2 && mean < 0.99, "mean ao {mean}");
    assert!(out.scans[0].pose.abs_diff_eq(DMat4::IDENTITY, 0.0));
    // The input is untouched.
    assert_eq!(
        std::fs::metadata(&e57).unwrap().len(),
        4_110_336,
        "input modified"
    );
}

/// Three stations in one E57 with their poses, one of them at survey coordinates: merged as
/// one file, the output keeps names and poses and has AO for every point; the same AO as the
/// PLY route with the same poses.
#[test]
fn a_multi_scan_e57_is_merged_with_its_poses() {
    let sts = stations();
    let d = tempfile::tempdir().unwrap();
    let site = d.path().join("site.e57");
    let out: Vec<E57ScanOut> = sts
        .iter()
        .map(|s| E57ScanOut {
            name: s.name.clone(),
            pose: Some(s.pose),
            xyz: local_xyz(s),
            grid: Some(grid_of(s)),
            intensity: None,
            rgb: None,
            spherical: false,
        })
        .collect();
    write_e57_scans(&out, &site).unwrap();

    let info = mvao(&["info", "--json", site.to_str().unwrap()]);
    let v: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let list = v["scans"].as_array().unwrap();
    assert_eq!(list.len(), 3);
    for (e, s) in list.iter().zip(&sts) {
        assert_eq!(e["name"], s.name.as_str());
        assert_eq!(e["points"], s.len());
        assert_eq!(e["sensor_model"], "equirect");
        assert_eq!(e["pose_source"], "e57 pose");
        let t = s.pose.w_axis;
        for k in 0..3 {
            assert!((e["pose"][k][3].as_f64().unwrap() - t[k]).abs() < 1e-9);
        }
    }

    let o = d.path().join("out");
    mvao_ok(&[
        "merge",
        "-q",
        "--no-preview",
        "--radius",
        "0.2",
        "--tmax",
        "0.4",
        "-o",
        o.to_str().unwrap(),
        site.to_str().unwrap(),
    ]);
    let res = E57Input::from_path(&o.join("site.mvao.e57")).unwrap();
    assert_eq!(res.scans.len(), 3);
    let mut e57_ao = Vec::new();
    for (r, s) in res.scans.iter().zip(&sts) {
        assert_eq!(r.name, s.name);
        assert!(r.pose.abs_diff_eq(s.pose, 1e-12));
        let ao = r.values(&ao_record()).unwrap();
        assert_eq!(ao.len(), s.len());
        assert!(all_in_unit(&ao));
        e57_ao.push(ao);
    }

    // Cross-format: the same file to per-scan PLYs, named after the scans, world coordinates.
    let op = d.path().join("ply");
    mvao_ok(&[
        "merge",
        "-q",
        "--no-preview",
        "--radius",
        "0.2",
        "--tmax",
        "0.4",
        "--format",
        "ply",
        "-o",
        op.to_str().unwrap(),
        site.to_str().unwrap(),
    ]);
    for (s, ao) in sts.iter().zip(&e57_ao) {
        let p =
            mvao::io::ply::PlyFile::from_path(&op.join(format!("{}.mvao.ply", s.name))).unwrap();
        let a = p.scalar_column("vertex", "ao").unwrap();
        assert_eq!(&a, ao, "{}: PLY and E57 outputs differ", s.name);
        let x = p.scalar_column("vertex", "x").unwrap();
        let w = s.pose.transform_point3(s.points[0].as_dvec3());
        assert!((x[0] - w.x).abs() < 1e-4);
        assert!(p.has_property("vertex", "row") && p.has_property("vertex", "col"));
    }
}

#[test]
fn a_ptx_file_with_two_blocks_is_merged() {
    let sts = stations();
    let d = tempfile::tempdir().unwrap();
    let ptx = d.path().join("two.ptx");
    // PTX stores whole grids: fill every cell, zero for no return.
    let tables: Vec<PointTable> = sts[..2]
        .iter()
        .map(|s| {
            let g = s.grid.as_ref().unwrap();
            let cells = (g.rows * g.cols) as usize;
            let mut xyz = vec![[0.0f64; 3]; cells];
            let (mut row, mut col) = (vec![0u32; cells], vec![0u32; cells]);
            for c in 0..cells {
                row[c] = c as u32 / g.cols;
                col[c] = c as u32 % g.cols;
            }
            for (k, p) in s.points.iter().enumerate() {
                xyz[(g.row[k] * g.cols + g.col[k]) as usize] = p.as_dvec3().to_array();
            }
            PointTable {
                name: s.name.clone(),
                xyz,
                pose: s.pose,
                rgb: None,
                intensity: Some(vec![0.5; cells]),
                ao: vec![1.0; cells],
                grid: Some(RawGrid {
                    rows: g.rows,
                    cols: g.cols,
                    row,
                    col,
                }),
                extra: Vec::new(),
            }
        })
        .collect();
    mvao::io::ptx::write_ptx(&tables, &ptx).unwrap();
    let f = read_input(&ptx).unwrap();
    assert_eq!(f.scans.len(), 2);
    for (s, t) in f.scans.iter().zip(&sts) {
        assert_eq!(s.len(), t.len());
        assert!(s.pose.abs_diff_eq(t.pose, 1e-9), "{} vs {}", s.pose, t.pose);
    }
    let o = d.path().join("o");
    mvao_ok(&[
        "merge",
        "-q",
        "--radius",
        "0.2",
        "-o",
        o.to_str().unwrap(),
        ptx.to_str().unwrap(),
    ]);
    for s in &f.scans {
        let p = mvao::io::ply::PlyFile::from_path(&o.join(format!("{}.mvao.ply", s.name))).unwrap();
        let a = p.scalar_column("vertex", "ao").unwrap();
        assert_eq!(a.len(), s.len());
        assert!(all_in_unit(&a));
        assert!(o.join(format!("{}.png", s.name)).is_file());
    }
}

/// One station stored as a georeferenced LAS (world coordinates, 0.1 mm scale) with a
/// scanner-pose sidecar: LAS → merge → LAS keeps every original record and adds `ao`, and the
/// AO matches the PLY route with the scan-local points.
#[test]
fn las_in_world_coordinates_with_a_scanner_pose_round_trips() {
    let scene = Scene::room();
    let st = Station::equirect(DVec3::new(0.5, -0.5, 1.5), 0.3, 360, 180);
    let s = scan_scene(&scene, &st, 0.0, 0, "tls");
    let off = DVec3::new(512_000.0, 5_200_000.0, 300.0);
    let pose = DMat4::from_translation(off) * s.pose;
    let d = tempfile::tempdir().unwrap();
    let las = d.path().join("tls.las");
    let table = PointTable {
        name: "tls".into(),
        xyz: local_xyz(&s),
        pose,
        rgb: None,
        intensity: Some(vec![0.25; s.len()]),
        ao: vec![1.0; s.len()],
        grid: None,
        extra: Vec::new(),
    };
    mvao::io::las::write_table_las(&table, &las, false).unwrap();
    // Without a scanner position: a clear warning naming what is missing.
    let o0 = d.path().join("o0");
    let err = mvao_ok(&[
        "merge",
        "--radius",
        "0.2",
        "--no-preview",
        "-o",
        o0.to_str().unwrap(),
        las.to_str().unwrap(),
    ]);
    assert!(
        err.contains("no scanner position") && err.contains("--pose"),
        "{err}"
    );

    // With the scanner pose as a sidecar.
    write_pose_sidecar(&las, pose);
    let o = d.path().join("o");
    mvao_ok(&[
        "merge",
        "-q",
        "--radius",
        "0.2",
        "--no-preview",
        "-o",
        o.to_str().unwrap(),
        las.to_str().unwrap(),
    ]);
    let out = o.join("tls.mvao.las");
    let ao = mvao::io::las::read_ao(&out).unwrap();
    assert_eq!(ao.len(), s.len());
    assert!(ao.iter().all(|a| a.is_finite() && (0.0..=1.0).contains(a)));
    // Every original dimension kept (raw integers, intensity, classification).
    let inp = las::Reader::from_path(&las).unwrap().read_all().unwrap();
    let res = las::Reader::from_path(&out).unwrap().read_all().unwrap();
    assert!(inp.x_raw().eq(res.x_raw()));
    assert!(inp.y_raw().eq(res.y_raw()));
    assert!(inp.z_raw().eq(res.z_raw()));
    assert!(inp.intensity().eq(res.intensity()));
    assert!(inp.classification().eq(res.classification()));
    assert!(inp.point_source_id().eq(res.point_source_id()));

    // The same station as a scan-local PLY: the same AO up to the 0.1 mm quantisation.
    let ply = d.path().join("tls.ply");
    mvao::synth::write_scan_ply(&s, &ply, &[]).unwrap();
    let op = d.path().join("op");
    mvao_ok(&[
        "merge",
        "-q",
        "--radius",
        "0.2",
        "--no-preview",
        "-o",
        op.to_str().unwrap(),
        ply.to_str().unwrap(),
    ]);
    let pa = mvao::io::ply::PlyFile::from_path(&op.join("tls.mvao.ply"))
        .unwrap()
        .scalar_column("vertex", "ao")
        .unwrap();
    let mean = pa
        .iter()
        .zip(&ao)
        .map(|(x, y)| (x - *y as f64).abs())
        .sum::<f64>()
        / ao.len() as f64;
    assert!(mean < 0.02, "mean |Δao| LAS vs PLY = {mean}");

    // LAS → LAZ and LAS → E57 outputs.
    for (fmt, name) in [("laz", "tls.mvao.laz"), ("e57", "tls.mvao.e57")] {
        let of = d.path().join(fmt);
        mvao_ok(&[
            "merge",
            "-q",
            "--radius",
            "0.2",
            "--no-preview",
            "--format",
            fmt,
            "-o",
            of.to_str().unwrap(),
            las.to_str().unwrap(),
        ]);
        assert!(of.join(name).is_file(), "{name}");
    }
}

/// Damaged files of every format: exit code 2, the file named, nothing written.
#[test]
fn corrupt_files_of_every_format_are_named_and_nothing_is_written() {
    let d = tempfile::tempdir().unwrap();
    let e57 = std::fs::read(fixture("libe57-pumpA/pumpAVisualReferenceImage.e57")).unwrap();
    let cases: Vec<(PathBuf, Vec<u8>)> =
        vec![
        (d.path().join("cut.e57"), e57[..e57.len() / 3].to_vec()),
        (d.path().join("junk.las"), b"LASF\x00\x01not a header".to_vec()),
        (
            d.path().join("short.ptx"),
            b"10\n10\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n1 2 3 0.5\n"
                .to_vec(),
        ),
        (d.path().join("text.e57"), b"hello".to_vec()),
    ];
    for (p, bytes) in &cases {
        std::fs::write(p, bytes).unwrap();
        let o = d.path().join("out");
        let r = mvao(&[
            "merge",
            "-q",
            "-o",
            o.to_str().unwrap(),
            p.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{}: {err}", p.display());
        assert!(
            err.contains(p.file_name().unwrap().to_str().unwrap()),
            "{}: {err}",
            p.display()
        );
        assert!(!err.contains("panicked"), "{err}");
        assert!(!o.exists(), "{}: output written", p.display());
    }
    // Several E57 scans and none with a pose.
    let sts = stations();
    let noposes: Vec<E57ScanOut> = sts
        .iter()
        .map(|s| E57ScanOut {
            name: s.name.clone(),
            pose: None,
            xyz: local_xyz(s),
            grid: None,
            intensity: None,
            rgb: None,
            spherical: false,
        })
        .collect();
    let np = d.path().join("noposes.e57");
    write_e57_scans(&noposes, &np).unwrap();
    let r = mvao(&["info", np.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2));
    assert!(err.contains("noposes.e57") && err.contains("pose"), "{err}");
    let _ = DQuat::IDENTITY;
}

/// A 40 × 40 height field 1 m below the scanner, with `extra` vertex columns, as a PLY.
fn field_ply(path: &std::path::Path, extra: &[(&str, mvao::io::ply::ScalarType, &[f64])]) {
    use mvao::io::ply::{PlyFile, ScalarType};
    let n = 40usize;
    let (mut x, mut y, mut z) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..n {
        for j in 0..n {
            let (u, v) = (i as f64 * 0.01 - 0.2, j as f64 * 0.01 - 0.2);
            x.push(u);
            y.push(v);
            z.push(-1.0 + 0.05 * (-(u * u + v * v) / 0.005).exp());
        }
    }
    let mut cols: Vec<(&str, ScalarType, &[f64])> = vec![
        ("x", ScalarType::F32, &x),
        ("y", ScalarType::F32, &y),
        ("z", ScalarType::F32, &z),
    ];
    cols.extend_from_slice(extra);
    PlyFile::from_vertex_columns(&cols, &[])
        .unwrap()
        .write_path(path)
        .unwrap();
}

/// PLY colours on a 0–1 float scale or in 16 bits, and a 16-bit intensity, reach LAS and E57
/// outputs on their scale (`--color keep`): not black, not white.
#[test]
fn ply_colours_and_intensity_on_their_own_scale_reach_las_and_e57() {
    use mvao::io::ply::ScalarType;
    let d = tempfile::tempdir().unwrap();
    let n = 1600;
    let unit = (vec![0.8; n], vec![0.2; n], vec![0.1; n]);
    let wide = (vec![50000.0; n], vec![65535.0; n], vec![257.0; n]);
    let inten = vec![32768.0; n];
    let cases = [
        ("unit", ScalarType::F32, &unit, [204u8, 51, 26]),
        ("wide", ScalarType::U16, &wide, [195, 255, 1]),
    ];
    for (name, t, (r, g, b), want) in cases {
        let ply = d.path().join(format!("{name}.ply"));
        field_ply(
            &ply,
            &[
                ("red", t, r),
                ("green", t, g),
                ("blue", t, b),
                ("intensity", ScalarType::U16, &inten),
            ],
        );
        for fmt in ["las", "e57"] {
            let o = d.path().join(format!("{name}_{fmt}"));
            mvao_ok(&[
                "merge",
                "-q",
                "--no-preview",
                "--color",
                "keep",
                "--format",
                fmt,
                "-o",
                o.to_str().unwrap(),
                ply.to_str().unwrap(),
            ]);
            let out = o.join(format!("{name}.mvao.{fmt}"));
            if fmt == "las" {
                let pd = las::Reader::from_path(&out).unwrap().read_all().unwrap();
                assert_eq!(pd.len(), n);
                let w = want.map(|c| c as u16 * 257);
                assert!(pd.rgb().unwrap().all(|c| c == (w[0], w[1], w[2])), "{name}");
                assert!(pd.intensity().all(|i| i == 32768), "{name}");
            } else {
                let e = E57Input::from_path(&out).unwrap();
                let s = &e.scans[0];
                assert!(s.rgb.as_ref().unwrap().iter().all(|c| *c == want), "{name}");
                let i = s.intensity.as_ref().unwrap();
                assert!(
                    i.iter().all(|v| (v - 0.5).abs() < 1e-4),
                    "{name}: {:?}",
                    i[0]
                );
            }
        }
    }
}

/// A binary PLY with bytes after its data is read with a warning to the user; an ascii PLY
/// whose row runs on past its properties is an error naming the file and the line.
#[test]
fn ply_trailing_bytes_warn_and_ascii_rows_are_checked() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("padded.ply");
    field_ply(&ply, &[]);
    let mut bytes = std::fs::read(&ply).unwrap();
    bytes.extend_from_slice(&[0; 7]);
    std::fs::write(&ply, &bytes).unwrap();
    let out = mvao_ok(&["info", ply.to_str().unwrap()]);
    assert!(
        out.contains("padded.ply: 7 bytes after the last element ignored"),
        "{out}"
    );
    let bad = d.path().join("bad.ply");
    std::fs::write(
        &bad,
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
         property float z\nend_header\n0 0 0 9 9\n1 1 1\n",
    )
    .unwrap();
    let r = mvao(&["info", bad.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success());
    assert!(
        err.contains("bad.ply: line 8: vertex 0 has 5 values, expected 3"),
        "{err}"
    );
}
