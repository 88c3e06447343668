//! Helpers shared by the integration tests.
#![allow(dead_code)]

use glam::{DVec3, Vec3};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use mvao::io::align;
use mvao::io::ply::scan::read_scan;
use mvao::testing::scan::Scan;
use std::path::{Path, PathBuf};

/// A fixture path relative to the crate root.
pub fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(rel)
}

/// All `*.ply` files of a fixture folder, sorted.
pub fn plys(dir: &str) -> Vec<PathBuf> {
    ply_files(&fixture(dir))
}

/// All `*.ply` files of `dir`, sorted.
pub fn ply_files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ply"))
        .collect();
    v.sort();
    v
}

/// Reads scans and applies the alignment file.
pub fn load_aligned(paths: &[PathBuf], align_file: &Path) -> Vec<Scan> {
    let al = align::read_alignment(align_file).unwrap();
    let poses = align::poses_for_scans(&al, paths).unwrap();
    paths
        .iter()
        .zip(poses)
        .map(|(p, m)| {
            let (mut s, _) = read_scan(p).unwrap();
            s.pose = m * s.pose;
            s
        })
        .collect()
}

/// World coordinates of a scan's points.
pub fn world(s: &Scan) -> Vec<DVec3> {
    s.points
        .iter()
        .map(|p| s.pose.transform_point3(p.as_dvec3()))
        .collect()
}

/// Median distance from scan `i`'s points to the union of the other scans.
pub fn median_nn_to_others(scans: &[Scan], i: usize) -> f64 {
    let others: Vec<[f64; 3]> = scans
        .iter()
        .enumerate()
        .filter(|(j, _)| *j != i)
        .flat_map(|(_, s)| world(s).into_iter().map(|p| p.to_array()))
        .collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&others);
    let mut d: Vec<f64> = world(&scans[i])
        .iter()
        .map(|p| {
            tree.nearest_one::<SquaredEuclidean>(&p.to_array())
                .distance
                .sqrt()
        })
        .collect();
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

/// Signed concavity of each point: mean height of its k nearest neighbours above its tangent
/// plane (positive = neighbours rise around it = concave), normals facing the sensor.
pub fn concavity(points: &[Vec3], normals: &[Vec3], k: usize) -> Vec<f32> {
    let coords: Vec<[f32; 3]> = points.iter().map(|p| p.to_array()).collect();
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(&coords);
    let k = std::num::NonZeroUsize::new(k).unwrap();
    points
        .iter()
        .zip(normals)
        .map(|(p, n)| {
            let nb = tree.nearest_n::<SquaredEuclidean>(&p.to_array(), k);
            nb.iter()
                .map(|x| n.dot(points[x.item as usize] - *p))
                .sum::<f32>()
                / nb.len() as f32
        })
        .collect()
}

/// Mean of `v` over the indices of the largest and smallest `frac` of `key`.
pub fn mean_by_extremes(v: &[f32], key: &[f32], frac: f64) -> (f32, f32) {
    let mut idx: Vec<usize> = (0..key.len()).collect();
    idx.sort_by(|&a, &b| key[a].total_cmp(&key[b]));
    let m = ((key.len() as f64 * frac) as usize).max(1);
    let mean = |ix: &[usize]| ix.iter().map(|&i| v[i]).sum::<f32>() / ix.len() as f32;
    (mean(&idx[idx.len() - m..]), mean(&idx[..m]))
}

/// The `report.json` a run wrote into `dir`.
pub fn report(dir: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap()
}

/// Runs the `mvao` binary.
pub fn mvao(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_mvao"))
        .args(args)
        .output()
        .unwrap()
}

/// Runs the `mvao` binary, expects success, and returns stderr followed by stdout.
pub fn mvao_ok(args: &[&str]) -> String {
    let r = mvao(args);
    let err = String::from_utf8_lossy(&r.stderr).into_owned();
    assert!(r.status.success(), "{args:?}: {err}");
    err + &String::from_utf8_lossy(&r.stdout)
}

/// `mvao synth` of the room with `stations` equirect stations of `w × h` into `dir`; the
/// station files, sorted.
pub fn synth_room(dir: &Path, stations: u32, w: u32, h: u32) -> Vec<PathBuf> {
    synth_site(dir, "room", stations, w, h, &[])
}

/// `mvao synth --scene SCENE` with `stations` stations of `w × h` and the `extra` options
/// into `dir`; the station files, sorted.
pub fn synth_site(
    dir: &Path,
    scene: &str,
    stations: u32,
    w: u32,
    h: u32,
    extra: &[&str],
) -> Vec<PathBuf> {
    let (stations, w, h) = (stations.to_string(), w.to_string(), h.to_string());
    let mut args = vec!["synth", "--scene", scene, "--stations", &stations];
    args.extend(["--width", &w, "--height", &h]);
    args.extend_from_slice(extra);
    args.extend(["-o", dir.to_str().unwrap()]);
    mvao_ok(&args);
    ply_files(dir)
}

/// A hemisphere of points around a scanner at the origin (radius 3 m, below and around it).
pub fn dome(n: usize) -> Vec<[f64; 3]> {
    (0..n)
        .map(|i| {
            let a = i as f64 * 0.618_033_988_75 * std::f64::consts::TAU;
            let e = (i as f64 / n as f64) * 1.2;
            [
                3.0 * e.cos() * a.cos(),
                3.0 * e.cos() * a.sin(),
                3.0 * e.sin() - 1.0,
            ]
        })
        .collect()
}

/// Writes `pose` (scan → world) as the sidecar matrix beside `scan` (`scan.txt`, four rows).
pub fn write_pose_sidecar(scan: &Path, pose: glam::DMat4) {
    let rows: String = (0..4)
        .map(|r| {
            let v = pose.row(r);
            format!("{:?} {:?} {:?} {:?}\n", v.x, v.y, v.z, v.w)
        })
        .collect();
    std::fs::write(scan.with_extension("txt"), rows).unwrap();
}
