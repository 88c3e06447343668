//! The virtual scanner: analytic scenes with exact geometry ([`Scene`], built from [`Prim`]s),
//! scanned from [`Station`]s in any of the three sensor models into [`Scan`]s with exact
//! normals and native grids, written as PLY files plus a MeshLab `.mlp` alignment. It exists to
//! test and benchmark the pipeline and to let users try the tool without data; it is never on
//! the production path. World geometry is f64 (z up, metres); scans store f32 local points.
//!
//! [`run`] is the whole job: scene, station layout ([`station_layout`]), scans, files.

mod mesh;
mod mesh_run;
mod meshes;
mod output;
mod prim;
mod scanner;
mod scene;

pub mod reference;

pub use mesh::{Mesh, MeshScene, MAX_TRIANGLES};
pub use meshes::{colonnade, porch, relief, vaulted_room, MeshKind};
pub use output::{describe_station, write_scan_ply};
pub use prim::Prim;
pub use scanner::{scan_scene, scan_with_truth, Geometry, Station, Truth};
pub use scene::{Hit, Scene, T_EPS};

use crate::error::{Error, Result};
use crate::io::align::{write_mlp, AlignEntry};
use crate::projection::SensorModel;
use crate::rng;
use crate::scan::Scan;
use glam::{DMat4, DVec2, DVec3, Vec3};
use serde::Serialize;
use std::f64::consts::{FRAC_PI_4, PI, TAU};
use std::path::{Path, PathBuf};

/// Which built-in scene to scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SceneKind {
    /// [`Scene::room`]: a furnished closed room.
    Room,
    /// [`Scene::courtyard`]: an open courtyard with an arcade and a fountain.
    Courtyard,
    /// [`Scene::suite`]: `rooms` rooms in a row joined by doorways.
    Suite {
        /// Number of rooms.
        rooms: usize,
    },
}

impl SceneKind {
    /// The scene's geometry.
    pub fn scene(self) -> Scene {
        match self {
            SceneKind::Room => Scene::room(),
            SceneKind::Courtyard => Scene::courtyard(),
            SceneKind::Suite { rooms } => Scene::suite(rooms),
        }
    }
}

impl std::fmt::Display for SceneKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SceneKind::Room => "room",
            SceneKind::Courtyard => "courtyard",
            SceneKind::Suite { .. } => "suite",
        })
    }
}

impl std::str::FromStr for SceneKind {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "room" => Ok(SceneKind::Room),
            "courtyard" => Ok(SceneKind::Courtyard),
            "suite" => Ok(SceneKind::Suite { rooms: 6 }),
            t => match t.strip_prefix("suite:").map(str::parse::<usize>) {
                Some(Ok(rooms)) if (1..=1000).contains(&rooms) => Ok(SceneKind::Suite { rooms }),
                _ => Err(Error::Param(format!(
                    "unknown synthetic scene '{s}' (expected room, courtyard, suite or suite:ROOMS)"
                ))),
            },
        }
    }
}

/// What [`run`] generates.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthOptions {
    /// Scene to scan.
    pub scene: SceneKind,
    /// Number of stations (≥ 1).
    pub stations: usize,
    /// Sensor model of every station.
    pub model: SensorModel,
    /// Map width in pixels; 0 = the model's default ([`default_map_size`]).
    pub width: usize,
    /// Map height in pixels; 0 = the model's default ([`default_map_size`]).
    pub height: usize,
    /// Standard deviation of the range noise (metres, 0 = exact).
    pub noise: f64,
    /// Seed of the noise (station `i` uses [`station_seed`]`(seed, i)`).
    pub seed: u64,
    /// Output directory (created if missing).
    pub out_dir: PathBuf,
    /// Also write the exact reference obscurance of every point into
    /// `out_dir/reference-analytic/` (analytic scenes) or `out_dir/reference-mesh/` (mesh
    /// scenes) with these rays per point, t_max and falloff (the seed is 0).
    pub reference: Option<crate::reference::RefParams>,
    /// Scan a triangle mesh instead of `scene` (see [`run`]).
    pub mesh: Option<MeshSource>,
    /// Mesh scenes: station positions (world), used in turn; empty = the scene's own.
    pub at: Vec<DVec3>,
    /// Mesh scenes: where perspective stations look; `None` = the scene's own.
    pub look_at: Option<DVec3>,
    /// Registration error written into the poses (mesh scenes).
    pub registration: Registration,
    /// Write the exact normals into the scans (real scans seldom carry them).
    pub normals: bool,
    /// Write each point's row and column (many exports drop the scanner's grid).
    pub grid: bool,
}

/// A triangle mesh to scan: a file or a built-in scene.
#[derive(Debug, Clone, PartialEq)]
pub enum MeshSource {
    /// A PLY or OBJ mesh file (world coordinates, metres).
    File(PathBuf),
    /// A built-in mesh scene.
    Builtin(MeshKind),
}

/// Size of the random rigid error put into each station's written pose: a rotation about
/// the scanner's origin by exactly `angle_deg` about a random axis, then a shift by exactly
/// `translation` metres in a random direction (drawn per station from the run's seed). The
/// points stay where the true pose puts them, so a registration residual of that size
/// separates the scans.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Registration {
    /// Shift, metres.
    pub translation: f64,
    /// Rotation, degrees.
    pub angle_deg: f64,
}

impl Registration {
    /// The local error transform of station `index` (identity when both sizes are 0).
    pub fn error(&self, seed: u64, index: usize) -> DMat4 {
        if self.translation == 0.0 && self.angle_deg == 0.0 {
            return DMat4::IDENTITY;
        }
        let mut r = rng::SplitMix64::new(seed ^ 0x5EED_4E61_u64, index as u64);
        let mut unit = || {
            let v = DVec3::new(r.gaussian(), r.gaussian(), r.gaussian());
            v.try_normalize().unwrap_or(DVec3::Z)
        };
        let (axis, shift) = (unit(), unit());
        DMat4::from_translation(shift * self.translation)
            * DMat4::from_axis_angle(axis, self.angle_deg.to_radians())
    }
}

impl Default for SynthOptions {
    /// Four equirect stations in the room at the default size, 2 mm noise, into `synth/`.
    fn default() -> Self {
        SynthOptions {
            scene: SceneKind::Room,
            stations: 4,
            model: SensorModel::Equirect,
            width: 0,
            height: 0,
            noise: 0.002,
            seed: 1,
            out_dir: PathBuf::from("synth"),
            reference: None,
            mesh: None,
            at: Vec::new(),
            look_at: None,
            registration: Registration::default(),
            normals: true,
            grid: true,
        }
    }
}

/// One written scan.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SynthFile {
    /// Path of the PLY file.
    pub path: PathBuf,
    /// Station index.
    pub station: usize,
    /// Number of points written.
    pub points: usize,
}

/// What [`run`] wrote.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SynthSummary {
    /// The scene scanned (the analytic scene's kind; see `label` for mesh scenes).
    pub scene: SceneKind,
    /// The scene's name: an analytic or built-in mesh scene's name, or the mesh file.
    pub label: String,
    /// The sensor model used.
    pub model: SensorModel,
    /// Output directory.
    pub out_dir: PathBuf,
    /// One entry per station, in station order.
    pub files: Vec<SynthFile>,
    /// The MeshLab project with the poses.
    pub alignment: PathBuf,
}

/// Default map size `(width, height)` of a sensor model: equirect 1440 × 720 (0.25° steps),
/// perspective 1024 × 768, ortho 1024 columns and height 0, meaning "as many rows as give
/// square pixels over the station's rectangle".
pub fn default_map_size(model: SensorModel) -> (usize, usize) {
    match model {
        SensorModel::Equirect => (1440, 720),
        SensorModel::Perspective => (1024, 768),
        SensorModel::Ortho => (1024, 0),
    }
}

/// Noise seed of station `index` for the run seed `seed`.
pub fn station_seed(seed: u64, index: usize) -> u64 {
    seed ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

/// Where [`run`] puts `count` stations of `model` in a scene (deterministic):
/// - **equirect**: on a circle at scanner height 1.5 m — room: centre (0.3, 0), radius 1.2;
///   courtyard: centre (0, 0), radius 6 — at angles `45° + 360°·k/count`, yaw `0.7·k` rad;
/// - **perspective**: 75° horizontal field of view, on a ring looking at a target — room:
///   ellipse of radii 2.8 × 1.9 m at height 1.6 m aiming at (0.3, 0.2, 0.8); courtyard:
///   circle of radius 8.5 m at 1.7 m aiming at (0, 2, 2) — same angles;
/// - **ortho**: looking down from a sensor plane above the contents — room: z = 2.95 (under
///   the ceiling) over x ∈ [-4, 4], y ∈ [-3, 3]; courtyard: z = 10 over the whole ground —
///   split into `count` strips along x that overlap by a quarter strip on each side (clipped
///   to the area); odd stations have yaw π. Pixels are square when the height is 0 (the
///   rows then follow each strip's aspect), otherwise the map is stretched over the strip.
///
/// A zero `width` or `height` takes the model's [`default_map_size`].
pub fn station_layout(
    kind: SceneKind,
    model: SensorModel,
    count: usize,
    width: usize,
    height: usize,
) -> Vec<Station> {
    if let SceneKind::Suite { rooms } = kind {
        // Each room gets a room's layout of its share of the stations, moved to it.
        let rooms = rooms.max(1);
        let per = count.div_ceil(rooms).max(1);
        return (0..count)
            .map(|k| {
                let (r, l) = ((k / per).min(rooms - 1), k % per);
                let n = per.min(count - (k / per) * per).max(l + 1);
                let mut s = station_layout(SceneKind::Room, model, n, width, height)[l];
                s.position.x += 9.0 * r as f64;
                s
            })
            .collect();
    }
    let (centre, radius, z_eq, ring, z_cam, target, z_ortho, area) = match kind {
        SceneKind::Room => (
            DVec2::new(0.3, 0.0),
            1.2,
            1.5,
            DVec2::new(2.8, 1.9),
            1.6,
            DVec3::new(0.3, 0.2, 0.8),
            2.95,
            (DVec2::new(-4.0, -3.0), DVec2::new(4.0, 3.0)),
        ),
        SceneKind::Courtyard | SceneKind::Suite { .. } => (
            DVec2::ZERO,
            6.0,
            1.5,
            DVec2::splat(8.5),
            1.7,
            DVec3::new(0.0, 2.0, 2.0),
            10.0,
            (DVec2::splat(-15.0), DVec2::splat(15.0)),
        ),
    };
    let (dw, dh) = default_map_size(model);
    let width = if width == 0 { dw } else { width };
    let height = if height == 0 { dh } else { height };
    (0..count)
        .map(|k| {
            let a = FRAC_PI_4 + TAU * k as f64 / count as f64;
            let dir = DVec2::new(a.cos(), a.sin());
            match model {
                SensorModel::Equirect => {
                    let p = centre + dir * radius;
                    let yaw = (0.7 * k as f64) % TAU;
                    Station::equirect(p.extend(z_eq), yaw, width, height)
                }
                SensorModel::Perspective => {
                    let p = (dir * ring).extend(z_cam);
                    Station::perspective(p, target, 75f64.to_radians(), width, height)
                }
                SensorModel::Ortho => {
                    let (lo, hi) = area;
                    let s = (hi.x - lo.x) / count as f64;
                    let pad = if count > 1 { 0.25 * s } else { 0.0 };
                    let x0 = (lo.x + k as f64 * s - pad).max(lo.x);
                    let x1 = (lo.x + (k + 1) as f64 * s + pad).min(hi.x);
                    let c = DVec3::new((x0 + x1) / 2.0, (lo.y + hi.y) / 2.0, z_ortho);
                    let half = DVec2::new((x1 - x0) / 2.0, (hi.y - lo.y) / 2.0);
                    let yaw = if k % 2 == 1 { PI } else { 0.0 };
                    let rows = match height {
                        0 => ((width as f64 * half.y / half.x).round() as usize).max(1),
                        h => h,
                    };
                    Station::ortho(c, yaw, half, width, rows)
                }
            }
        })
        .collect()
}

/// Local → world poses of the stations [`run`] would scan with `opts`.
pub fn station_poses(opts: &SynthOptions) -> Vec<DMat4> {
    station_layout(
        opts.scene,
        opts.model,
        opts.stations,
        opts.width,
        opts.height,
    )
    .iter()
    .map(Station::pose)
    .collect()
}

/// Writes the exact obscurance `a` of a scan's points as a reference file in `dir` (no
/// radii: the truth comes from the scene, not from surfels).
/// `reference.json` of an exact reference directory: what `merge --reference` and `eval`
/// compare a run's t_max and falloff with.
fn write_truth_params(dir: &Path, rp: &crate::reference::RefParams, geometry: &str) -> Result<()> {
    let json = serde_json::json!({
        "version": env!("CARGO_PKG_VERSION"),
        "params": rp,
        "geometry": geometry,
    });
    crate::io::atomic::write_atomic(&dir.join("reference.json"), |w| {
        serde_json::to_writer_pretty(&mut *w, &json).map_err(std::io::Error::other)?;
        std::io::Write::write_all(w, b"\n")
    })
}

fn write_truth(dir: &Path, name: &str, scan: &Scan, normals: &[Vec3], a: &[f32]) -> Result<()> {
    crate::io::reference::write_reference_ply(
        &crate::io::reference::reference_path(dir, name),
        scan,
        normals,
        &vec![0.0f32; scan.len()],
        a,
        Default::default(),
    )
}

/// Scans the chosen scene from `opts.stations` stations ([`station_layout`]) and writes
/// `station_000.ply`, `station_001.ply`, … ([`write_scan_ply`]) and `alignment.mlp` with
/// their poses into `opts.out_dir`.
pub fn run(opts: &SynthOptions) -> Result<SynthSummary> {
    check_options(opts)?;
    if let Some(src) = &opts.mesh {
        return mesh_run::run_mesh(opts, src);
    }
    let stations = station_layout(
        opts.scene,
        opts.model,
        opts.stations,
        opts.width,
        opts.height,
    );
    for st in &stations {
        st.validate()?;
    }
    let scene = opts.scene.scene();
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| Error::io(&opts.out_dir, e))?;
    let mut files = Vec::with_capacity(stations.len());
    let mut entries = Vec::with_capacity(stations.len());
    for (i, st) in stations.iter().enumerate() {
        let name = format!("station_{i:03}");
        let file = format!("{name}.ply");
        let seed = station_seed(opts.seed, i);
        let scan = scan_scene(&scene, st, opts.noise, seed, &name);
        let mut comments = vec![format!(
            "mvao synthetic scan: scene {} station {i} of {}",
            opts.scene, opts.stations
        )];
        comments.extend(describe_station(st));
        comments.push(format!("range_noise_sigma_m {} seed {seed}", opts.noise));
        let path = opts.out_dir.join(&file);
        write_scan_ply(&as_written(&scan, opts), &path, &comments)?;
        files.push(SynthFile {
            path,
            station: i,
            points: scan.len(),
        });
        if let Some(rp) = opts.reference {
            let dir = opts.out_dir.join("reference-analytic");
            std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
            if i == 0 {
                write_truth_params(&dir, &rp, "analytic scene")?;
            }
            let a =
                reference::analytic_obscurance(&scene, &scan, rp.rays, (rp.tmax, rp.falloff), 0);
            let normals = scan.normals.clone().unwrap_or_default();
            write_truth(&dir, &name, &scan, &normals, &a)?;
        }
        entries.push(AlignEntry {
            file,
            pose: scan.pose,
        });
    }
    let alignment = opts.out_dir.join("alignment.mlp");
    write_mlp(&alignment, &entries)?;
    Ok(SynthSummary {
        scene: opts.scene,
        label: opts.scene.to_string(),
        model: opts.model,
        out_dir: opts.out_dir.clone(),
        files,
        alignment,
    })
}

/// `scan` as written: without its normals or its grid unless `opts` keeps them.
fn as_written<'a>(scan: &'a Scan, opts: &SynthOptions) -> std::borrow::Cow<'a, Scan> {
    if opts.normals && opts.grid {
        return std::borrow::Cow::Borrowed(scan);
    }
    let mut s = scan.clone();
    if !opts.normals {
        s.normals = None;
    }
    if !opts.grid {
        s.grid = None;
    }
    std::borrow::Cow::Owned(s)
}

fn check_options(opts: &SynthOptions) -> Result<()> {
    if opts.stations == 0 || opts.stations > 10_000 {
        return Err(Error::Param(format!(
            "synthetic stations: {} out of 1..10000",
            opts.stations
        )));
    }
    if !(opts.noise.is_finite() && opts.noise >= 0.0) {
        return Err(Error::Param(format!(
            "synthetic noise {} must be a non-negative number of metres",
            opts.noise
        )));
    }
    let reg = opts.registration;
    let shift_ok = reg.translation.is_finite() && reg.translation >= 0.0;
    let angle_ok = reg.angle_deg.is_finite() && (0.0..=180.0).contains(&reg.angle_deg);
    if !(shift_ok && angle_ok) {
        return Err(Error::Param(format!(
            "registration error {} m / {}° must be non-negative (angle at most 180°)",
            reg.translation, reg.angle_deg
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const MODELS: [SensorModel; 3] = [
        SensorModel::Equirect,
        SensorModel::Perspective,
        SensorModel::Ortho,
    ];

    #[test]
    fn layout_stations_are_in_free_space_and_see_the_scene() {
        for kind in [SceneKind::Room, SceneKind::Courtyard] {
            let scene = kind.scene();
            for model in MODELS {
                for count in [1, 3, 4] {
                    let st = station_layout(kind, model, count, 96, 64);
                    assert_eq!(st.len(), count);
                    for s in &st {
                        s.validate().unwrap();
                        assert!(!scene.inside_solid(s.position), "{kind} {model} {s:?}");
                        let scan = scan_scene(&scene, s, 0.0, 0, "t");
                        assert!(scan.len() > 96 * 64 / 3, "{kind} {model} {}", scan.len());
                    }
                }
            }
        }
    }

    #[test]
    fn ortho_room_layout_stays_inside_the_room() {
        let scene = Scene::room();
        for count in [1, 2, 5] {
            for s in station_layout(SceneKind::Room, SensorModel::Ortho, count, 64, 48) {
                let scan = scan_scene(&scene, &s, 0.0, 0, "o");
                for p in &scan.points {
                    let w = scan.pose.transform_point3(p.as_dvec3());
                    assert!(w.x.abs() <= 4.0 + 1e-9 && w.y.abs() <= 3.0 + 1e-9, "{w}");
                }
            }
        }
    }

    #[test]
    fn poses_match_layout_and_options() {
        let opts = SynthOptions {
            stations: 3,
            width: 0,
            height: 0,
            ..SynthOptions::default()
        };
        let poses = station_poses(&opts);
        let size = |m, k: usize| {
            let s = station_layout(SceneKind::Room, m, k, 0, 0)[k - 1];
            (s.width, s.height)
        };
        assert_eq!(size(SensorModel::Equirect, 1), (1440, 720));
        assert_eq!(size(SensorModel::Perspective, 1), (1024, 768));
        assert_eq!(size(SensorModel::Ortho, 1), (1024, 768));
        // Ortho strips with default height get square pixels.
        for s in station_layout(SceneKind::Courtyard, SensorModel::Ortho, 3, 500, 0) {
            let (px, py) = (
                2.0 * s.half_extent.x / 500.0,
                2.0 * s.half_extent.y / s.height as f64,
            );
            assert!((px / py - 1.0).abs() < 0.01, "{px} {py}");
        }
        assert_eq!(poses.len(), 3);
        let p = poses[1].transform_point3(DVec3::ZERO);
        assert!((p.z - 1.5).abs() < 1e-12);
        assert!(((p.truncate() - DVec2::new(0.3, 0.0)).length() - 1.2).abs() < 1e-12);
        assert_eq!(
            "Courtyard".parse::<SceneKind>().unwrap(),
            SceneKind::Courtyard
        );
        assert!("attic".parse::<SceneKind>().is_err());
    }

    #[test]
    fn run_rejects_bad_options() {
        let dir = tempfile::tempdir().unwrap();
        let base = SynthOptions {
            out_dir: dir.path().join("out"),
            ..SynthOptions::default()
        };
        assert!(run(&SynthOptions {
            stations: 0,
            ..base.clone()
        })
        .is_err());
        assert!(run(&SynthOptions {
            noise: -1.0,
            ..base.clone()
        })
        .is_err());
        assert!(!base.out_dir.exists());
    }

    #[test]
    fn mesh_run_writes_truth_and_registration_error() {
        let dir = tempfile::tempdir().unwrap();
        let opts = SynthOptions {
            mesh: Some(MeshSource::Builtin(MeshKind::Vault)),
            stations: 2,
            width: 64,
            height: 32,
            noise: 0.0,
            out_dir: dir.path().join("m"),
            reference: Some(crate::reference::RefParams {
                rays: 32,
                ..Default::default()
            }),
            registration: Registration {
                translation: 0.01,
                angle_deg: 0.5,
            },
            normals: false,
            ..SynthOptions::default()
        };
        let sum = run(&opts).unwrap();
        assert_eq!(sum.label, "vault");
        let al = crate::io::align::read_alignment(&sum.alignment).unwrap();
        let (pos, _) = MeshKind::Vault.stations();
        for (i, f) in sum.files.iter().enumerate() {
            let ply = crate::io::ply::PlyFile::from_path(&f.path).unwrap();
            assert!(ply.scalar_column("vertex", "nx").is_none());
            let a = crate::io::reference::read_ao(
                &dir.path()
                    .join(format!("m/reference-mesh/station_{i:03}.ref.ply")),
            )
            .unwrap();
            assert_eq!(a.len(), f.points);
            // Inside the hall most of the sky is closed, yet the openings let some light in.
            let mean = a.iter().sum::<f32>() / a.len() as f32;
            assert!(mean > 0.02 && mean < 0.9, "{mean}");
            // The written pose is off by exactly the registration error.
            let e = Station::equirect(pos[i], 0.0, 1, 1).pose().inverse() * al.entries[i].pose;
            let shift = e.transform_point3(DVec3::ZERO).length();
            assert!((shift - 0.01).abs() < 1e-9, "{shift}");
            let ang =
                (glam::DQuat::from_mat4(&e).angle_between(glam::DQuat::IDENTITY)).to_degrees();
            let yaw = (0.7 * i as f64).to_degrees();
            assert!(ang > 0.0 && ang <= yaw + 0.5 + 1e-6, "{ang}");
        }
    }

    /// Needs the PLY writer (`PlyFile::from_vertex_columns`, `write_path`) and `write_mlp`.
    #[test]
    fn run_writes_plys_and_mlp() {
        let dir = tempfile::tempdir().unwrap();
        let opts = SynthOptions {
            scene: SceneKind::Courtyard,
            stations: 3,
            model: SensorModel::Perspective,
            width: 64,
            height: 48,
            noise: 0.001,
            seed: 9,
            out_dir: dir.path().join("synth"),
            reference: Some(crate::reference::RefParams {
                rays: 16,
                tmax: 0.5,
                ..Default::default()
            }),
            ..SynthOptions::default()
        };
        let sum = run(&opts).unwrap();
        assert_eq!(sum.files.len(), 3);
        // The analytic reference: one file per station, A in [0, 1].
        for i in 0..3 {
            let p = dir
                .path()
                .join(format!("synth/reference-analytic/station_{i:03}.ref.ply"));
            let a = crate::io::reference::read_ao(&p).unwrap();
            assert_eq!(a.len(), sum.files[i].points);
            assert!(a.iter().all(|v| (0.0..=1.0).contains(v)));
        }
        for (i, f) in sum.files.iter().enumerate() {
            assert!(f.path.ends_with(format!("station_{i:03}.ply")));
            assert!(f.path.is_file() && f.points > 0);
            let bytes = std::fs::read(&f.path).unwrap();
            assert!(bytes.starts_with(b"ply\n"));
            let head = String::from_utf8_lossy(&bytes[..bytes.len().min(2000)]).into_owned();
            assert!(
                head.contains(&format!("element vertex {}", f.points)),
                "{head}"
            );
            assert!(head.contains("format binary_little_endian"));
            assert!(head.contains("sensor perspective 64x48"));
            let ply = crate::io::ply::PlyFile::from_path(&f.path).unwrap();
            for c in ["x", "y", "z", "nx", "ny", "nz", "row", "col"] {
                let v = ply.scalar_column("vertex", c).unwrap();
                assert_eq!(v.len(), f.points, "{c}");
            }
            let rows = ply.scalar_column("vertex", "row").unwrap();
            assert!(rows.iter().all(|&r| (0.0..48.0).contains(&r)));
        }
        assert!(sum.alignment.is_file());
        let mlp = std::fs::read_to_string(&sum.alignment).unwrap();
        assert!(mlp.contains("station_002.ply"));
        let al = crate::io::align::read_alignment(&sum.alignment).unwrap();
        let poses = station_poses(&opts);
        assert_eq!(al.entries.len(), 3);
        for (e, p) in al.entries.iter().zip(&poses) {
            assert!(e.pose.abs_diff_eq(*p, 1e-9), "{} {}", e.pose, p);
        }
    }
}
