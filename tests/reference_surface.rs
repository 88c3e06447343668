//! `mvao reference --surface`: the reference of scans cast at a true surface given apart from
//! them. On a mesh scene from the virtual scanner the surface is the scene's own mesh, so the
//! reference must agree with the scanner's exact ground truth even where the scans carry range
//! noise, registration error and no normals (where the surfel reference cannot).

use mvao::accuracy::{self, Geometry, RefConfig, SurfaceSpec};
use mvao::io::dataset::PlaceOptions;
use mvao::synth::{self, MeshKind, MeshSource, Registration, SynthOptions};
use mvao::testing::eval::{metrics_concat, Metrics};
use mvao::testing::reference::RefParams;
use std::path::{Path, PathBuf};

const RAYS: u32 = 64;
const TMAX: f32 = 0.4;

/// Three noisy, misregistered 180 × 90 stations of the vault without normals, its mesh as a
/// PLY file, and the synthetic run's files.
fn vault(dir: &Path) -> (synth::SynthSummary, PathBuf) {
    let sum = synth::run(&SynthOptions {
        mesh: Some(MeshSource::Builtin(MeshKind::Vault)),
        stations: 3,
        width: 180,
        height: 90,
        noise: 0.002,
        seed: 1,
        out_dir: dir.join("scans"),
        reference: Some(RefParams {
            rays: RAYS,
            tmax: TMAX,
            ..RefParams::default()
        }),
        registration: Registration {
            translation: 0.002,
            angle_deg: 0.05,
        },
        normals: false,
        ..SynthOptions::default()
    })
    .unwrap();
    let mesh = dir.join("vault.ply");
    synth::vaulted_room().write_ply(&mesh).unwrap();
    (sum, mesh)
}

fn config(sum: &synth::SynthSummary, out: PathBuf, surface: Option<SurfaceSpec>) -> RefConfig {
    RefConfig {
        scans: sum.files.iter().map(|f| f.path.clone()).collect(),
        place: PlaceOptions {
            align: Some(sum.alignment.clone()),
            ..PlaceOptions::default()
        },
        out_dir: out,
        params: RefParams {
            rays: RAYS,
            tmax: TMAX,
            ..RefParams::default()
        },
        geometry: Geometry::Surfels,
        surface,
        sample: 200,
        projection: Default::default(),
        force: true,
    }
}

/// The metrics of the reference in `out` against the scanner's truth, over every station.
fn against_truth(sum: &synth::SynthSummary, out: &Path) -> Metrics {
    let truth_dir = sum.alignment.parent().unwrap().join("reference-mesh");
    let names: Vec<String> = (0..sum.files.len())
        .map(|k| format!("station_{k:03}"))
        .collect();
    let a: Vec<Vec<f32>> = names
        .iter()
        .map(|n| accuracy::read_reference_ao(&accuracy::reference_path(out, n)).unwrap())
        .collect();
    let t: Vec<Vec<f32>> = names
        .iter()
        .map(|n| accuracy::read_ao(&accuracy::reference_path(&truth_dir, n)).unwrap())
        .collect();
    let parts: Vec<(&[f32], &[f32])> = a
        .iter()
        .zip(&t)
        .map(|(a, t)| (a.as_slice(), t.as_slice()))
        .collect();
    metrics_concat(&parts)
}

#[test]
fn a_true_surface_gives_the_exact_truth_of_noisy_scans() {
    let dir = tempfile::tempdir().unwrap();
    let (sum, mesh) = vault(dir.path());
    let spec = SurfaceSpec {
        path: mesh,
        tolerance: None,
    };
    let out = dir.path().join("surface");
    let rep = accuracy::run_reference(&config(&sum, out.clone(), Some(spec)), &|_| {}).unwrap();
    assert_eq!(rep.geometry, Geometry::Surface);
    let off: usize = rep.scans.iter().map(|s| s.off_surface.unwrap()).sum();
    let total: usize = rep.scans.iter().map(|s| s.points).sum();
    assert!(off * 100 < total, "{off} of {total} points off the surface");
    assert!(rep.scans.iter().all(|s| s.self_check.is_none()));
    let m = against_truth(&sum, &out);
    assert!(m.e_a <= 0.002, "surface: {}", m.one_line());
    assert!(m.pearson_r.unwrap() >= 0.99, "surface: {}", m.one_line());
    assert_eq!(m.skipped, off, "points off the surface are not scored");

    // The surfel reference of the same scans, for scale: noise and registration error.
    let surfels = dir.path().join("surfels");
    accuracy::run_reference(&config(&sum, surfels.clone(), None), &|_| {}).unwrap();
    let s = against_truth(&sum, &surfels);
    eprintln!("surface {}\nsurfels {}", m.one_line(), s.one_line());
    assert!(
        s.e_a > 2.0 * m.e_a,
        "surfels {} against surface {}",
        s.one_line(),
        m.one_line()
    );
}

#[test]
fn points_off_the_surface_are_marked_and_not_scored() {
    let dir = tempfile::tempdir().unwrap();
    let (sum, mesh) = vault(dir.path());
    // 0.5 mm: closer than the 2 mm range noise puts most points.
    let spec = SurfaceSpec {
        path: mesh,
        tolerance: Some(0.0005),
    };
    let out = dir.path().join("tight");
    let rep = accuracy::run_reference(&config(&sum, out.clone(), Some(spec)), &|_| {}).unwrap();
    let s0 = &rep.scans[0];
    let off = s0.off_surface.unwrap();
    assert!(
        off > s0.points / 2 && off < s0.points,
        "{off} of {}",
        s0.points
    );
    let path = accuracy::reference_path(&out, &s0.name);
    let ply = mvao::io::ply::PlyFile::from_path(&path).unwrap();
    let on = ply.scalar_column("vertex", "on_surface").unwrap();
    let ao = ply.scalar_column("vertex", "ao").unwrap();
    assert_eq!(on.iter().filter(|&&v| v == 0.0).count(), off);
    assert!(
        ao.iter().all(|v| (0.0..=1.0).contains(v)),
        "written values stay finite"
    );
    let read = accuracy::read_reference_ao(&path).unwrap();
    assert_eq!(read.iter().filter(|v| v.is_nan()).count(), off);
    // `mvao eval` against it scores the points on the surface only.
    let acc = accuracy::eval_files(&out, std::slice::from_ref(&path)).unwrap();
    assert_eq!(acc.result.n, s0.points - off);
}

#[test]
fn a_surface_in_another_frame_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (sum, _) = vault(dir.path());
    let mut far = synth::vaulted_room();
    for v in &mut far.vertices {
        v.x += 1000.0;
    }
    let path = dir.path().join("elsewhere.obj");
    far.write_obj(&path).unwrap();
    let spec = SurfaceSpec {
        path: path.clone(),
        tolerance: None,
    };
    let out = dir.path().join("far");
    let err = accuracy::run_reference(&config(&sum, out.clone(), Some(spec)), &|_| {})
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("elsewhere.obj") && err.contains("world frame"),
        "{err}"
    );
    assert!(!out.join("reference.json").exists());

    let missing = SurfaceSpec {
        path: dir.path().join("missing.ply"),
        tolerance: None,
    };
    let err = accuracy::run_reference(&config(&sum, out, Some(missing)), &|_| {})
        .unwrap_err()
        .to_string();
    assert!(err.contains("missing.ply"), "{err}");
}
