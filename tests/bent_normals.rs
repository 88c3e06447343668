//! `merge --bent-normals` end to end: the `bnx bny bnz` columns, the frame each output writes
//! them in, and the outputs that cannot carry them.

mod common;

use common::*;
use e57::RecordName;
use glam::{DMat4, DVec3};
use mvao::io::e57::{write_e57_scans, E57Input, E57ScanOut};
use mvao::io::las::LasInput;
use mvao::io::ply::PlyFile;
use mvao::io::raw::PointTable;
use mvao::synth::{scan_scene, Scene, Station};
use std::path::Path;

fn bent_of(path: &Path) -> Vec<DVec3> {
    let p = PlyFile::from_path(path).unwrap();
    let col = |n: &str| p.scalar_column("vertex", n).unwrap();
    let (x, y, z) = (col("bnx"), col("bny"), col("bnz"));
    (0..x.len()).map(|k| DVec3::new(x[k], y[k], z[k])).collect()
}

fn merge(out: &Path, input: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "merge",
        "-q",
        "--no-preview",
        "--radius",
        "0.2",
        "--bent-normals",
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    args.push(input.to_str().unwrap());
    mvao(&args)
}

/// One station as a scan-local PLY and as a LAS in world coordinates turned a quarter turn
/// and moved far away: the PLY written back carries the bent normals in its own frame, the
/// LAS written as PLY in world coordinates, so the two agree once turned by the placement; the
/// LAS written back as LAS carries the same world-frame values as extra-bytes dimensions.
#[test]
fn bent_normals_follow_the_output_frame() {
    let scene = Scene::room();
    let st = Station::equirect(DVec3::new(0.5, -0.5, 1.5), 0.3, 240, 120);
    let s = scan_scene(&scene, &st, 0.0, 0, "tls");
    let d = tempfile::tempdir().unwrap();

    let ply = d.path().join("tls.ply");
    mvao::synth::write_scan_ply(&s, &ply, &[]).unwrap();
    let op = d.path().join("op");
    let r = merge(&op, &ply, &[]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let local = bent_of(&op.join("tls.mvao.ply"));
    assert_eq!(local.len(), s.len());

    let pose = DMat4::from_translation(DVec3::new(512_000.0, 5_200_000.0, 300.0))
        * DMat4::from_rotation_z(std::f64::consts::FRAC_PI_2)
        * s.pose;
    let las = d.path().join("tls.las");
    let table = PointTable {
        name: "tls".into(),
        xyz: s.points.iter().map(|p| p.as_dvec3().to_array()).collect(),
        pose,
        rgb: None,
        intensity: None,
        ao: vec![1.0; s.len()],
        grid: None,
        extra: Vec::new(),
    };
    mvao::io::las::write_table_las(&table, &las, false).unwrap();
    write_pose_sidecar(&las, pose);

    let ow = d.path().join("ow");
    let r = merge(&ow, &las, &["--format", "ply"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let world = bent_of(&ow.join("tls.mvao.ply"));
    assert_eq!(world.len(), local.len());

    // Written back into the LAS's own records: the same values in its (world) coordinates,
    // as float extra-bytes dimensions beside `ao`.
    let ol = d.path().join("ol");
    let r = merge(&ol, &las, &[]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let back = LasInput::from_path(&ol.join("tls.mvao.las")).unwrap();
    let cols = back.extra_columns();
    let col = |n: &str| &cols.iter().find(|c| c.0 == n).expect(n).1;
    let (x, y, z) = (col("bnx"), col("bny"), col("bnz"));
    assert_eq!(x.len(), world.len());
    for (k, w) in world.iter().enumerate() {
        let v = DVec3::new(x[k], y[k], z[k]);
        assert!((v - *w).length() < 1e-6, "record {k}: {v} against {w}");
    }
    // A result run again overwrites its own columns rather than adding more.
    let again = d.path().join("again");
    let r = merge(&again, &ol.join("tls.mvao.las"), &[]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let twice = LasInput::from_path(&again.join("tls.mvao.mvao.las")).unwrap();
    assert_eq!(twice.record_len(), back.record_len());

    e57_written_back_in_the_scan_frame(d.path(), &s.points, pose);

    let (mut sum, mut n, mut zero) = (0.0, 0usize, 0usize);
    for (l, w) in local.iter().zip(&world) {
        for v in [l, w] {
            let len = v.length();
            assert!(
                len.is_finite() && (len < 1e-6 || (len - 1.0).abs() < 1e-4),
                "{v}"
            );
        }
        if l.length() < 0.5 || w.length() < 0.5 {
            zero += 1;
            continue;
        }
        let turned = pose.transform_vector3(*l).normalize();
        sum += turned.dot(*w).clamp(-1.0, 1.0).acos().to_degrees();
        n += 1;
    }
    assert!(zero * 100 < local.len(), "{zero} zero bent normals");
    let mean = sum / n as f64;
    assert!(
        mean < 3.0,
        "bent normals differ by {mean}° between the two frames"
    );
}

/// The station as an E57 scan stored in its own frame under `pose`: written back as E57, the
/// bent normals are `mvao:` attributes in the scan's frame, which `pose` turns into the world
/// frame a PLY result of the same file is written in.
fn e57_written_back_in_the_scan_frame(dir: &Path, points: &[glam::Vec3], pose: DMat4) {
    let e57 = dir.join("station.e57");
    let scan = E57ScanOut {
        name: "station".into(),
        pose: Some(pose),
        xyz: points.iter().map(|p| p.as_dvec3().to_array()).collect(),
        grid: None,
        intensity: None,
        rgb: None,
        spherical: false,
    };
    write_e57_scans(&[scan], &e57).unwrap();
    let ow = dir.join("e57w");
    let r = merge(&ow, &e57, &["--format", "ply"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let world = bent_of(&ow.join("station.mvao.ply"));
    let ob = dir.join("e57b");
    let r = merge(&ob, &e57, &[]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let back = E57Input::from_path(&ob.join("station.mvao.e57")).unwrap();
    let attr = |n: &str| {
        back.scans[0]
            .values(&RecordName::Unknown {
                namespace: "mvao".into(),
                name: n.into(),
            })
            .expect(n)
    };
    let (x, y, z) = (attr("bnx"), attr("bny"), attr("bnz"));
    assert_eq!(x.len(), world.len());
    for (k, w) in world.iter().enumerate() {
        let v = pose.transform_vector3(DVec3::new(x[k], y[k], z[k]));
        assert!((v - *w).length() < 1e-5, "record {k}: {v} against {w}");
    }
}
