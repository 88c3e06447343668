//! Ingest speeds on a warm page cache: `cargo bench --bench ingest`.
//!
//! A synthetic terrestrial scan of the room (1440×720, ≈1M vertices: float x y z, float
//! nx ny nz, int row col; binary little endian) is written to a temporary directory, then:
//! PLY parsing (`PlyFile::from_path`) and the whole scan reader in MB/s of the file, and the
//! prepared view's products (`save_view`, `load_view`, `load_maps_for_merge`) for both EXR
//! compressions, in seconds and MB/s of the product files.

use glam::DVec3;
use mvao::io::ply::scan;
use mvao::io::ply::PlyFile;
use mvao::synth::write_scan_ply;
use mvao::synth::{scan_scene, Scene, Station};
use mvao::testing::pipeline::occlusion::prepare_view;
use mvao::testing::products::{
    load_maps_for_merge, load_view, save_view_with, InputRecord, Manifest, MapCompression,
    SaveOptions,
};
use mvao::testing::sensor::ProjectionChoice;
use mvao::testing::ssao::{Estimator, SsaoParams};
use std::hint::black_box;
use std::time::Instant;

fn best_of<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..runs {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(black_box(r));
    }
    (best, out.expect("at least one run"))
}

fn mb(bytes: u64) -> f64 {
    bytes as f64 / 1e6
}

fn main() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let (w, h) = (1440, 720);
    let st = Station::equirect(DVec3::new(0.3, -0.2, 1.4), 0.3, w, h);
    let scan = scan_scene(&Scene::room(), &st, 0.002, 1, "room");
    let ply = dir.path().join("room.ply");
    write_scan_ply(&scan, &ply, &["sensor equirect".to_string()]).expect("write ply");
    let size = std::fs::metadata(&ply).expect("ply size").len();
    println!(
        "room {w}x{h}: {} vertices, {:.1} MB binary little endian ({} bytes/vertex)",
        scan.len(),
        mb(size),
        size / scan.len().max(1) as u64
    );

    let _warm = PlyFile::from_path(&ply).expect("read ply");
    let (t, _) = best_of(5, || PlyFile::from_path(&ply).expect("read ply"));
    println!(
        "PlyFile::from_path      {:7.3} s  {:7.0} MB/s",
        t,
        mb(size) / t
    );
    let (t, (s, _)) = best_of(3, || scan::read_scan(&ply).expect("read scan"));
    println!(
        "scan::read_scan         {:7.3} s  {:7.0} MB/s",
        t,
        mb(size) / t
    );
    // Where the scan reader's time goes beyond parsing.
    let parsed = PlyFile::from_path(&ply).expect("read ply");
    let (t_xyz, _) = best_of(3, || parsed.vertex_xyz().expect("xyz"));
    let (t_nrm, _) = best_of(3, || {
        parsed
            .map_scalars("vertex", ["nx", "ny", "nz"], |v| v.map(|c| c as f32))
            .expect("normals")
    });
    let (t_build, _) = best_of(3, || scan::scan_from_ply(&parsed, &ply).expect("scan"));
    println!(
        "  of which scan_from_ply {:7.3} s: vertex_xyz {:.3} s, normals in one pass {:.3} s \
         (row/col likewise)",
        t_build, t_xyz, t_nrm
    );
    let (t, _) = best_of(3, || InputRecord::capture(&ply).expect("hash"));
    println!(
        "InputRecord::capture    {:7.3} s  {:7.0} MB/s (xxh3-128, streamed)",
        t,
        mb(size) / t
    );

    let prm = SsaoParams {
        estimator: Estimator::Paper,
        radius: 0.2,
        tmax: 0.4,
        falloff: Default::default(),
        samples: 32,
        directions: 8,
        steps: 8,
        seed: 0,
        blur: true,
        sampling: Default::default(),
    };
    let view = prepare_view(&s, ProjectionChoice::Auto, &prm).expect("prepare");
    for comp in [MapCompression::None, MapCompression::Zip] {
        let wd = dir.path().join(format!("work-{comp:?}"));
        let opt = SaveOptions { compression: comp };
        let rec = InputRecord::capture(&ply).expect("hash");
        let (ts, files) = best_of(3, || {
            save_view_with(&wd, "room", &view, &opt).expect("save")
        });
        let mut m = Manifest::load(&wd);
        m.record("room", &[rec], &serde_json::json!({}), &files)
            .expect("record");
        let bytes = files.maps.size + files.points.size;
        let (tl, v) = best_of(5, || load_view(&wd, "room").expect("load"));
        assert_eq!(v.pixel, view.pixel);
        let (tm, _) = best_of(5, || load_maps_for_merge(&wd, "room").expect("load maps"));
        println!(
            "{comp:?}: maps {:.1} MB + points {:.1} MB; save_view {:.3} s, load_view {:.3} s \
             ({:.0} MB/s), load_maps_for_merge {:.3} s",
            mb(files.maps.size),
            mb(files.points.size),
            ts,
            tl,
            mb(bytes) / tl,
            tm
        );
    }
}
