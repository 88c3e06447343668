//! Neighbours from the native grid agree with the k-d tree on real gridded scans, within the
//! tolerance the docs state: median radius difference under 5 %, median normal angle under 5°.

mod common;

use common::*;
use mvao::io::scan_ply;
use mvao::scan::normals;
use mvao::sensor::{self, ProjectionChoice};

fn compare(path: &std::path::Path) -> (f32, f32) {
    let (scan, _) = scan_ply::read_scan(path).unwrap();
    let setup = sensor::setup(&scan, ProjectionChoice::Auto).unwrap();
    let toward = |p| setup.projection.toward_sensor(p);
    let (nt, rt) = normals::estimate(&scan.points, true, toward);
    let (ng, rg) = normals::estimate_grid(&scan.points, scan.grid.as_ref().unwrap(), true, toward);
    let (nt, ng) = (nt.unwrap(), ng.unwrap());
    let mut dr: Vec<f32> = rt
        .iter()
        .zip(&rg)
        .map(|(a, b)| (a - b).abs() / a.max(1e-9))
        .collect();
    let mut da: Vec<f32> = nt
        .iter()
        .zip(&ng)
        .map(|(a, b)| a.dot(*b).clamp(-1.0, 1.0).acos().to_degrees())
        .collect();
    dr.sort_by(f32::total_cmp);
    da.sort_by(f32::total_cmp);
    (dr[dr.len() / 2], da[da.len() / 2])
}

#[test]
fn grid_neighbours_match_the_kd_tree() {
    for p in plys("stanford-bunny")
        .iter()
        .take(3)
        .chain(plys("3dtk-uos-3scans").iter())
    {
        let (dr, da) = compare(p);
        eprintln!("{}: radius {dr:.4}, normal {da:.2}°", p.display());
        assert!(dr < 0.05, "{}: median radius difference {dr}", p.display());
        assert!(da < 5.0, "{}: median normal angle {da}°", p.display());
    }
}
