//! `merge --bent-normals` end to end: the `bnx bny bnz` columns, the frame each output writes
//! them in, and the outputs that cannot carry them.

mod common;

use common::*;
use glam::{DMat4, DVec3};
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
/// LAS written as PLY in world coordinates, so the two agree once turned by the placement; a
/// LAS written back as LAS is refused before anything is computed.
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

    let ol = d.path().join("ol");
    let r = merge(&ol, &las, &[]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.contains("tls.mvao.las") && err.contains("--format ply"),
        "{err}"
    );
    assert!(!ol.join("tls.mvao.las").exists());

    let ow = d.path().join("ow");
    let r = merge(&ow, &las, &["--format", "ply"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let world = bent_of(&ow.join("tls.mvao.ply"));
    assert_eq!(world.len(), local.len());

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
