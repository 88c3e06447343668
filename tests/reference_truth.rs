//! `mvao reference` against the exact ground truth of mesh scenes (issue 29): the virtual
//! scanner scans a built-in mesh scene and casts the same cosine-weighted ray sets at the
//! exact mesh from each point's noise-free position; the reference of the scans must agree.
//! Scans are small (180 × 90 equirect, three stations) and rays few (64, the same direction
//! sets on both sides when the normals are exact), so the bounds below are those of this
//! size; `scripts/reference_truth.sh` measures the full-size figures of docs/reference.md.

use mvao::accuracy::{self, Geometry, RefConfig};
use mvao::io::dataset::PlaceOptions;
use mvao::synth::{self, MeshKind, MeshSource, Registration, SynthOptions};
use mvao::testing::eval::{metrics_concat, Metrics};
use mvao::testing::projection::SensorModel;
use mvao::testing::reference::{RefParams, SelfCheck};
use std::path::Path;

struct Case {
    kind: MeshKind,
    tmax: f32,
    geometry: Geometry,
    noise: f64,
    registration: Registration,
    normals: bool,
    model: SensorModel,
    width: usize,
    height: usize,
}

impl Case {
    fn new(kind: MeshKind, tmax: f32, geometry: Geometry) -> Case {
        Case {
            kind,
            tmax,
            geometry,
            noise: 0.0,
            registration: Registration::default(),
            normals: true,
            model: SensorModel::Equirect,
            width: 180,
            height: 90,
        }
    }
}

/// The metrics of the reference against the truth over all stations, each scan's self-check
/// and own-surface height.
fn score(dir: &Path, c: &Case) -> (Metrics, Vec<SelfCheck>, Vec<f32>) {
    let scans = dir.join("scans");
    let rays = 64;
    let sum = synth::run(&SynthOptions {
        mesh: Some(MeshSource::Builtin(c.kind)),
        stations: 3,
        model: c.model,
        width: c.width,
        height: c.height,
        noise: c.noise,
        seed: 1,
        out_dir: scans.clone(),
        reference: Some(RefParams {
            rays,
            tmax: c.tmax,
            ..RefParams::default()
        }),
        registration: c.registration,
        normals: c.normals,
        ..SynthOptions::default()
    })
    .unwrap();
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
                rays,
                tmax: c.tmax,
                falloff: Default::default(),
                seed: 0,
            },
            geometry: c.geometry,
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
                &scans.join("reference-mesh"),
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

/// The vaulted hall, noise-free with exact normals: the surfel and mesh references against
/// the exact truth at t_max = 0.4 m (the bar) and at ∞.
#[test]
fn vault_references_match_the_exact_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let (m, checks, _) = score(
        dir.path(),
        &Case::new(MeshKind::Vault, 0.4, Geometry::Surfels),
    );
    assert_close(&m, 0.01, 0.05, 0.95, "vault surfels 0.4");
    assert_checks_pass(&checks, 0.01, "vault surfels 0.4");
    // Points open by the data exist at t_max = 0.4 and none is darkened.
    assert!(
        checks.iter().map(|c| c.open).sum::<usize>() > 30,
        "{checks:?}"
    );
    let (m, _, _) = score(
        dir.path(),
        &Case::new(MeshKind::Vault, f32::INFINITY, Geometry::Surfels),
    );
    assert_close(&m, 0.015, 0.015, 0.99, "vault surfels inf");
    let (m, _, _) = score(dir.path(), &Case::new(MeshKind::Vault, 0.4, Geometry::Mesh));
    // Grid triangles across the hall's creases (floor to wall, wall to vault) stood in front
    // of both faces: before they were cut this read shaded e_A 0.139, Pearson r 0.925.
    assert_close(&m, 0.01, 0.05, 0.95, "vault mesh 0.4");
    let (m, _, _) = score(
        dir.path(),
        &Case::new(MeshKind::Vault, f32::INFINITY, Geometry::Mesh),
    );
    // Grid triangles stop at a silhouette's last sample: without the disks that close it
    // the mesh read e_A 0.0152 with bias +0.0142 here.
    assert_close(&m, 0.014, 0.015, 0.99, "vault mesh inf");
    assert!(m.bias.abs() <= 0.006, "vault mesh inf: {}", m.one_line());
}

/// The arcade of thin columns and arches under open sky at t_max = 0.4 m: before the grid
/// radii and the own-patch rule the surfel reference read e_A 0.038 on this scene (worse
/// than answering "open", 0.009), and 0.28 at ∞.
#[test]
fn colonnade_surfel_reference_beats_answering_open() {
    let dir = tempfile::tempdir().unwrap();
    let (m, checks, _) = score(
        dir.path(),
        &Case::new(MeshKind::Colonnade, 0.4, Geometry::Surfels),
    );
    assert_close(&m, 0.01, 0.05, 0.8, "colonnade surfels 0.4");
    assert!(m.skill.unwrap() > 0.2, "{}", m.one_line());
    // At this size one scan has about fifty open points, one of them beside a column's
    // boundary disk at 0.88: 1 % of fifty is less than one point, so one is let through.
    for c in &checks {
        assert!(c.passed() || c.darkened <= 1, "{c:?}");
        assert!(c.min_open_a > 0.8 && c.mean_self_hit_share < 0.05, "{c:?}");
    }
}

/// Range noise 2 mm, registration error 2 mm / 0.05° per station and estimated normals (no
/// normals in the scans): the bar e_A ≤ 0.02 at t_max = 0.4 m.
#[test]
fn noisy_misregistered_scans_without_normals() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = Case::new(MeshKind::Vault, 0.4, Geometry::Surfels);
    c.noise = 0.002;
    c.registration = Registration {
        translation: 0.002,
        angle_deg: 0.05,
    };
    c.normals = false;
    let (m, checks, _) = score(dir.path(), &c);
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

/// The arcade under open sky at t_max = ∞ (360 × 180 stations): every disk that overhangs a
/// column's or an arch's true edge, or spans the floor behind a one-cell-wide column, darkens
/// every point that sees it. Before the tangent-plane edges and the smaller boundary disks
/// the surfels read e_A 0.031 with bias −0.030 here (128 rays); before boundary disks were
/// held to their own pixel, e_A 0.0129 with bias −0.0068 (this size, 64 rays).
#[test]
fn colonnade_open_sky_at_infinity() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = Case::new(MeshKind::Colonnade, f32::INFINITY, Geometry::Surfels);
    (c.width, c.height) = (360, 180);
    let (m, _, heights) = score(dir.path(), &c);
    assert_close(&m, 0.013, 0.014, 0.99, "colonnade surfels inf");
    assert!(m.bias.abs() <= 0.006, "{}", m.one_line());
    // Exact registration, noise-free: the stations' samples of a surface coincide.
    assert!(heights.iter().all(|&h| h < 1e-3), "{heights:?}");
}

/// The millimetre relief panel (three perspective views, 240 × 180) at t_max = 5 mm: its
/// grooves are narrower than two sample spacings on their walls, so a ray from one wall meets
/// the facing wall within the own-patch distance. Before a surface facing back at the point
/// was told from the point's own (by how steeply it stands over the tangent plane), the
/// surfels read e_A 0.0144, shaded 0.105, Pearson r 0.939 at 128 rays, and the noisy scans
/// without normals 0.0246 (`scripts/reference_truth.sh`).
#[test]
fn relief_grooves_are_closed_by_their_facing_walls() {
    let dir = tempfile::tempdir().unwrap();
    let relief = |geometry| {
        let mut c = Case::new(MeshKind::Relief, 0.005, geometry);
        (c.model, c.width, c.height) = (SensorModel::Perspective, 240, 180);
        c
    };
    let (m, _, _) = score(dir.path(), &relief(Geometry::Surfels));
    assert_close(&m, 0.01, 0.07, 0.97, "relief surfels 5 mm");
    let (m, _, _) = score(dir.path(), &relief(Geometry::Mesh));
    assert_close(&m, 0.01, 0.06, 0.97, "relief mesh 5 mm");
    let mut c = relief(Geometry::Surfels);
    c.noise = 0.000_05;
    c.normals = false;
    let (m, _, _) = score(dir.path(), &c);
    assert!(m.e_a <= 0.02, "relief noisy: {}", m.one_line());
}
