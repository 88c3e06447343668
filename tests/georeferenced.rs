//! Georeferenced coordinates in the file itself (double precision, 10⁶ m offsets): the scan
//! is re-centred in f64 so its f32 local data stays exact, the output keeps the original
//! coordinates bit for bit, and every AO value is finite.

mod common;

use common::*;
use glam::DVec3;
use mvao::io::ply::{PlyFile, ScalarType};
use mvao::synth::{scan_scene, Scene, Station};

#[test]
fn double_coordinates_far_from_the_origin_are_recentred() {
    let scene = Scene::room();
    let st = Station::equirect(DVec3::new(0.0, 0.0, 1.5), 0.0, 360, 180);
    let s = scan_scene(&scene, &st, 0.0, 1, "geo");
    let off = DVec3::new(512_000.0, 5_200_000.0, 300.0);
    let cols: Vec<Vec<f64>> = (0..3)
        .map(|k| s.points.iter().map(|p| p[k] as f64 + off[k]).collect())
        .collect();
    let ply = PlyFile::from_vertex_columns(
        &[
            ("x", ScalarType::F64, &cols[0]),
            ("y", ScalarType::F64, &cols[1]),
            ("z", ScalarType::F64, &cols[2]),
        ],
        &[],
    )
    .unwrap();
    let d = tempfile::tempdir().unwrap();
    let input = d.path().join("geo.ply");
    ply.write_path(&input).unwrap();
    let out = d.path().join("out");
    let r = mvao(&[
        "merge",
        "-q",
        "--radius",
        "0.2",
        "-o",
        out.to_str().unwrap(),
        input.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{err}");
    assert!(err.contains("re-centred"), "{err}");

    let (scan, _) = mvao::io::ply::scan::read_scan(&input).unwrap();
    let o = scan.pose.w_axis.truncate();
    assert!((o - off).length() < 10.0, "offset {o}");
    // Local f32 data is small again: sub-millimetre exact.
    for (p, q) in scan.points.iter().zip(&s.points) {
        assert!((p.as_dvec3() + o - (q.as_dvec3() + off)).length() < 1e-3);
    }
    let res = PlyFile::from_path(&out.join("geo.mvao.ply")).unwrap();
    for (k, c) in ["x", "y", "z"].iter().enumerate() {
        assert_eq!(
            res.scalar_column("vertex", c).unwrap(),
            cols[k],
            "{c} changed"
        );
    }
    let ao = res.scalar_column("vertex", "ao").unwrap();
    assert!(ao.iter().all(|a| a.is_finite() && (0.0..=1.0).contains(a)));
    let (mn, mx) = ao
        .iter()
        .fold((1f64, 0f64), |(a, b), &v| (a.min(v), b.max(v)));
    assert!(mx - mn > 0.2, "AO nearly constant: {mn}..{mx}");
}
