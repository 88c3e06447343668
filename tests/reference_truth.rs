//! `mvao reference` against the exact ground truth of mesh scenes (issue 29): the virtual
//! scanner scans a built-in mesh scene and casts the same cosine-weighted ray sets at the
//! exact mesh from each point's noise-free position; the reference of the scans must agree.
//! Three stations per scene and 64 rays (the same direction sets on both sides when the
//! normals are exact). The bars hold from half-degree stations (720 × 360) on the colonnade,
//! whose columns and arch edges are a pixel or two wide at 1°; the vault meets them at 1°;
//! `scripts/reference_truth.sh` measures the full table of docs/reference.md.

use mvao::accuracy::{self, Geometry, RefConfig};
use mvao::io::dataset::PlaceOptions;
use mvao::synth::{self, MeshKind, MeshSource, Registration, SynthOptions, SynthSummary};
use mvao::testing::eval::{metrics_concat, Metrics};
use mvao::testing::projection::SensorModel;
use mvao::testing::reference::{RefParams, SelfCheck};
use std::path::Path;

const RAYS: u32 = 64;

struct Case {
    kind: MeshKind,
    tmax: f32,
    noise: f64,
    registration: Registration,
    normals: bool,
    model: SensorModel,
    width: usize,
    height: usize,
}

impl Case {
    fn new(kind: MeshKind, tmax: f32, (width, height): (usize, usize)) -> Case {
        Case {
            kind,
            tmax,
            noise: 0.0,
            registration: Registration::default(),
            normals: true,
            model: SensorModel::Equirect,
            width,
            height,
        }
    }

    /// The relief panel seen by three perspective views of 480 × 360.
    fn relief(tmax: f32) -> Case {
        Case {
            model: SensorModel::Perspective,
            ..Case::new(MeshKind::Relief, tmax, (480, 360))
        }
    }
}

/// Scans the case's scene with the virtual scanner, casting the exact truth at each point.
fn scan(dir: &Path, c: &Case) -> SynthSummary {
    synth::run(&SynthOptions {
        mesh: Some(MeshSource::Builtin(c.kind)),
        stations: 3,
        model: c.model,
        width: c.width,
        height: c.height,
        noise: c.noise,
        seed: 1,
        out_dir: dir.join("scans"),
        reference: Some(RefParams {
            rays: RAYS,
            tmax: c.tmax,
            ..RefParams::default()
        }),
        registration: c.registration,
        normals: c.normals,
        ..SynthOptions::default()
    })
    .unwrap()
}

/// The metrics of the reference of the scans against the truth over all stations, each
/// scan's self-check and own-surface height.
fn score(
    dir: &Path,
    sum: &SynthSummary,
    tmax: f32,
    geometry: Geometry,
) -> (Metrics, Vec<SelfCheck>, Vec<f32>) {
    let out = dir.join("ref");
    let rep = accuracy::run_reference(
        &RefConfig {
            scans: sum.files.iter().map(|f| f.path.clone()).collect(),
            place: PlaceOptions {
                align: Some(sum.alignment.clone()),
                ..PlaceOptions::default()
            },
            out_dir: out.clone(),
            params: RefParams {
                rays: RAYS,
                tmax,
                falloff: Default::default(),
                seed: 0,
            },
            geometry,
            surface: None,
            sample: 300,
            projection: Default::default(),
            force: true,
        },
        &|_| {},
    )
    .unwrap();
    let mut a = Vec::new();
    let mut t = Vec::new();
    for s in &rep.scans {
        a.push(accuracy::read_ao(&accuracy::reference_path(&out, &s.name)).unwrap());
        t.push(
            accuracy::read_ao(&accuracy::reference_path(
                &sum.out_dir.join("reference-mesh"),
                &s.name,
            ))
            .unwrap(),
        );
    }
    let parts: Vec<(&[f32], &[f32])> = a
        .iter()
        .zip(&t)
        .map(|(a, t)| (a.as_slice(), t.as_slice()))
        .collect();
    let checks = rep.scans.iter().filter_map(|s| s.self_check).collect();
    let heights = rep.scans.iter().map(|s| s.own_height).collect();
    (metrics_concat(&parts), checks, heights)
}

/// Scans the case and scores both references against its truth, asserting the bars
/// for noise-free scans with exact normals: e_A ≤ 0.01, shaded e_A ≤ 0.05, Pearson r ≥ 0.95.
/// Returns the surfels' self-checks and own-surface heights.
fn assert_both_meet_the_bars(dir: &Path, c: &Case, what: &str) -> (Vec<SelfCheck>, Vec<f32>) {
    let sum = scan(dir, c);
    let (m, checks, heights) = score(dir, &sum, c.tmax, Geometry::Surfels);
    assert_close(&m, 0.01, 0.05, 0.95, &format!("{what} surfels"));
    let (m, _, _) = score(dir, &sum, c.tmax, Geometry::Mesh);
    assert_close(&m, 0.01, 0.05, 0.95, &format!("{what} mesh"));
    (checks, heights)
}

fn assert_close(m: &Metrics, e_a: f64, shaded: f64, r: f64, what: &str) {
    let line = m.one_line();
    assert!(m.e_a <= e_a, "{what}: {line}");
    assert!(m.shaded_e_a.unwrap_or(0.0) <= shaded, "{what}: {line}");
    assert!(m.pearson_r.unwrap_or(0.0) >= r, "{what}: {line}");
}

fn assert_checks_pass(checks: &[SelfCheck], self_share: f32, what: &str) {
    for c in checks {
        assert!(c.passed(), "{what}: {c:?}");
        assert!(c.mean_self_hit_share < self_share, "{what}: {c:?}");
    }
}

/// The vaulted hall with open doors, noise-free with exact normals, 1° stations: both
/// references at t_max = 0.4 m and at ∞.
#[test]
fn vault_references_meet_the_bars() {
    let dir = tempfile::tempdir().unwrap();
    let (checks, _) = assert_both_meet_the_bars(
        dir.path(),
        &Case::new(MeshKind::Vault, 0.4, (360, 180)),
        "vault 0.4",
    );
    assert_checks_pass(&checks, 0.01, "vault surfels 0.4");
    // Points open by the data exist at t_max = 0.4 and none is darkened.
    assert!(
        checks.iter().map(|c| c.open).sum::<usize>() > 30,
        "{checks:?}"
    );
    // Grid triangles stop at a silhouette's last sample: without the disks that close it
    // the mesh reference read e_A 0.0152 with bias +0.0142 at 180 × 90.
    assert_both_meet_the_bars(
        dir.path(),
        &Case::new(MeshKind::Vault, f32::INFINITY, (360, 180)),
        "vault inf",
    );
}

/// The arcade of thin columns and arches under open sky, half-degree stations: both
/// references at t_max = 0.4 m and at ∞. Before the grid radii and the own-patch rule the
/// surfels read e_A 0.038 at 0.4 m on 1° stations (worse than answering "open", 0.009) and
/// 0.28 at ∞; at 1° Pearson r at 0.4 m stays near 0.93 (features under a pixel,
/// docs/reference.md).
#[test]
fn colonnade_references_meet_the_bars() {
    let dir = tempfile::tempdir().unwrap();
    let (checks, _) = assert_both_meet_the_bars(
        dir.path(),
        &Case::new(MeshKind::Colonnade, 0.4, (720, 360)),
        "colonnade 0.4",
    );
    for c in &checks {
        assert!(c.passed(), "{c:?}");
        assert!(c.min_open_a > 0.8 && c.mean_self_hit_share < 0.05, "{c:?}");
    }
    let (_, heights) = assert_both_meet_the_bars(
        dir.path(),
        &Case::new(MeshKind::Colonnade, f32::INFINITY, (720, 360)),
        "colonnade inf",
    );
    // Exact registration, noise-free: the stations' samples of a surface coincide.
    assert!(heights.iter().all(|&h| h < 1e-3), "{heights:?}");
}

/// Range noise 2 mm, registration error 2 mm / 0.05° per station and estimated normals (no
/// normals in the scans): the bar e_A ≤ 0.02 at t_max = 0.4 m.
#[test]
fn noisy_misregistered_scans_without_normals() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = Case::new(MeshKind::Vault, 0.4, (180, 90));
    c.noise = 0.002;
    c.registration = Registration {
        translation: 0.002,
        angle_deg: 0.05,
    };
    c.normals = false;
    let sum = scan(dir.path(), &c);
    let (m, checks, _) = score(dir.path(), &sum, c.tmax, Geometry::Surfels);
    assert!(m.e_a <= 0.02, "{}", m.one_line());
    assert!(m.bias.abs() <= 0.01, "{}", m.one_line());
    // Noise and estimated normals make a fifth to a quarter of the rays meet their own surface.
    assert_checks_pass(&checks, 0.35, "vault noisy 0.4");
    // Every reference file carries the per-point count of rays that met their own surface.
    let ply = mvao::io::ply::PlyFile::from_path(&accuracy::reference_path(
        &dir.path().join("ref"),
        "station_000",
    ))
    .unwrap();
    let hits = ply.scalar_column("vertex", "self_hits").unwrap();
    assert!(hits.iter().all(|&h| (0.0..=64.0).contains(&h)));
    assert!(hits.iter().any(|&h| h > 0.0));
}

/// The millimetre relief panel at t_max = 5 mm and at ∞: its grooves are narrower than two
/// sample spacings on their walls, so a ray from one wall meets the facing wall within the
/// own-patch distance. Before a surface facing back at the point was told from the point's
/// own (by how steeply it stands over the tangent plane), the surfels read e_A 0.0144,
/// shaded 0.105, Pearson r 0.939 at 240 × 180 and 128 rays. With noise of 0.05 mm and
/// estimated normals the bar is e_A ≤ 0.02.
#[test]
fn relief_references_meet_the_bars() {
    let dir = tempfile::tempdir().unwrap();
    for tmax in [0.005, f32::INFINITY] {
        let what = format!("relief {tmax}");
        assert_both_meet_the_bars(dir.path(), &Case::relief(tmax), &what);
        let mut c = Case::relief(tmax);
        c.noise = 0.000_05;
        c.normals = false;
        let sum = scan(dir.path(), &c);
        let (m, _, _) = score(dir.path(), &sum, tmax, Geometry::Surfels);
        assert!(m.e_a <= 0.02, "{what} noisy: {}", m.one_line());
    }
}
