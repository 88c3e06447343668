//! How good the AO is: the ray-traced reference of a dataset (`mvao reference`), its files,
//! and the error metrics of a result against it (`merge --reference`, `mvao eval`).
//!
//! A reference directory holds `<scan>.ref.ply` per scan — the scan's valid points in input
//! order with world `x y z`, the normal, `radius` and `ao` = the reference obscurance `A` —
//! and `reference.json` with the parameters and the convergence report. The rays hit the
//! scans themselves (surfels or triangles), or a known true surface ([`surface`]).

mod surface;

use crate::error::{Error, Result};
use crate::eval::{metrics_concat, Metrics};
use crate::io::dataset::{Dataset, PlaceOptions};
pub use crate::io::reference::{
    load_reference, load_reference_named, read_ao, read_reference_ao, reference_path,
    write_reference_ply, RefExtras,
};
use crate::io::source::Container;
use crate::reference::{self, Convergence, RefParams, Scene};
pub use crate::report::{Accuracy, ScanAccuracy};
use crate::scan::Scan;
use crate::sensor::{self, ProjectionChoice};
use glam::Vec3;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;
pub use surface::{SurfaceSpec, TOLERANCE_RADII};

/// What the reference rays hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Geometry {
    /// Oriented disks of radius rad(p) at every point.
    #[default]
    Surfels,
    /// Triangles: the input's faces, else its native grid triangulated, else surfels.
    Mesh,
    /// A true surface given apart from the scans (`--surface`).
    #[value(skip)]
    Surface,
}

/// Everything `mvao reference` needs.
#[derive(Debug, Clone)]
pub struct RefConfig {
    /// Input scans.
    pub scans: Vec<PathBuf>,
    /// Placement.
    pub place: PlaceOptions,
    /// Output directory.
    pub out_dir: PathBuf,
    /// Rays, t_max, seed.
    pub params: RefParams,
    /// Geometry the rays hit (the scans'; ignored when `surface` is given).
    pub geometry: Geometry,
    /// A true surface to cast at instead of the scans.
    pub surface: Option<SurfaceSpec>,
    /// Points in the convergence sample of each scan.
    pub sample: usize,
    /// Sensor model choice (orients estimated normals).
    pub projection: ProjectionChoice,
    /// Overwrite existing outputs.
    pub force: bool,
}

/// Per-scan part of `reference.json`.
#[derive(Debug, Clone, Serialize)]
pub struct RefScan {
    /// Scan name.
    pub name: String,
    /// Points (valid ones).
    pub points: usize,
    /// Mean reference A.
    pub mean_a: f64,
    /// |A_R − A_4R| on a sample, and the timing of the main run.
    pub convergence: Convergence,
    /// Open points (by the data) that the reference darkens, on a sample (not run against a
    /// true surface).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub self_check: Option<reference::SelfCheck>,
    /// Against a true surface: points farther from it than the tolerance, not scored.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub off_surface: Option<usize>,
    /// Height over a point's tangent plane below which a surface parallel to it is taken as
    /// its own: the separation measured between this scan and the others that overlap it
    /// (scene units; 0 when none does).
    pub own_height: f32,
}

/// `reference.json`.
#[derive(Debug, Clone, Serialize)]
pub struct RefReport {
    /// mvao version.
    pub version: String,
    /// Rays, t_max (`"inf"` = ∞), falloff, seed.
    pub params: RefParams,
    /// Geometry the rays hit.
    pub geometry: Geometry,
    /// The true surface cast at (`--surface`), if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub surface: Option<String>,
    /// Surfels in the scene.
    pub surfels: usize,
    /// Triangles in the scene.
    pub triangles: usize,
    /// Per scan.
    pub scans: Vec<RefScan>,
    /// Rays per second over all scans' main runs.
    pub rays_per_second: f64,
    /// Seconds spent building the BVH.
    pub build_s: f64,
    /// Wall time of the whole command.
    pub wall_s: f64,
}

/// Triangles of scan `s` from its PLY faces (fans over polygons, indices remapped to the
/// valid points), else from its native grid cut at creases of `normals`, with whether they
/// came from the grid; `None` when it has neither.
fn mesh_of(
    s: &Scan,
    container: &Container,
    normals: &[Vec3],
) -> Result<Option<(Vec<[u32; 3]>, bool)>> {
    let view = reference::scan_view(s);
    let grid = || {
        s.grid
            .as_ref()
            .map(|g| reference::triangulate_grid_creased(&s.points, g, view, normals))
            .transpose()
            .map(|t| t.map(|t| (t, true)))
    };
    let Container::Ply(ply) = container else {
        return grid();
    };
    if let Some(faces) = ply.list_column("face", "vertex_indices") {
        let mut remap = vec![u32::MAX; s.vertex_count];
        for (k, &vi) in s.source_index.iter().enumerate() {
            remap[vi as usize] = k as u32;
        }
        let mut tris = Vec::with_capacity(faces.len());
        for f in &faces {
            let idx: Vec<u32> = f
                .iter()
                .map(|&v| remap.get(v as usize).copied().unwrap_or(u32::MAX))
                .collect();
            if idx.len() < 3 || idx.contains(&u32::MAX) {
                continue;
            }
            for k in 1..idx.len() - 1 {
                tris.push([idx[0], idx[k], idx[k + 1]]);
            }
        }
        return Ok(Some((tris, false)));
    }
    grid()
}

/// Adds the disks that close the silhouettes and creases of scan `s`'s grid triangulation
/// ([`reference::grid_skirts`]).
fn add_skirts(b: &mut reference::SceneBuilder, s: &Scan, normals: &[Vec3]) -> Result<()> {
    let Some(g) = &s.grid else {
        return Ok(());
    };
    let skirt = reference::grid_skirts(&s.points, g, reference::scan_view(s), normals)?;
    let edge: Vec<usize> = (0..skirt.len()).filter(|&i| skirt[i] > 0.0).collect();
    let pick = |v: &[Vec3]| edge.iter().map(|&i| v[i]).collect::<Vec<_>>();
    let radii: Vec<f32> = edge.iter().map(|&i| skirt[i]).collect();
    b.add_surfels(&s.name, s.pose, &pick(&s.points), &pick(normals), &radii)?;
    Ok(())
}

/// `mvao reference`: the reference obscurance of every point of every scan, cast against all
/// scans together; writes `<scan>.ref.ply` and `reference.json` into `cfg.out_dir`.
pub fn run_reference(cfg: &RefConfig, progress: &(dyn Fn(u64) + Sync)) -> Result<RefReport> {
    let t_all = Instant::now();
    let ds = Dataset::open(&cfg.scans, &cfg.place, &|| {})?;
    let outs: Vec<PathBuf> = ds
        .scans
        .iter()
        .map(|s| reference_path(&cfg.out_dir, &s.name))
        .chain([cfg.out_dir.join("reference.json")])
        .collect();
    for o in &outs {
        if o.exists() && !cfg.force {
            return Err(Error::Param(format!(
                "{}: exists; use --force to overwrite or choose another -o",
                o.display()
            )));
        }
    }
    if let Some(spec) = &cfg.surface {
        return run_surface(cfg, spec, &ds, t_all, progress);
    }
    let frame = ds.scans[0].pose;
    let mut b = Scene::builder(frame);
    let mut geo = Vec::with_capacity(ds.scans.len());
    for (i, s) in ds.scans.iter().enumerate() {
        let setup = sensor::setup(s, cfg.projection)?;
        let (normals, radii, _) = crate::view::scan_normals(s, &setup);
        let radii = reference::surfel_radii(s, &normals, &radii)?;
        let mesh = match cfg.geometry {
            Geometry::Surfels | Geometry::Surface => None,
            Geometry::Mesh => mesh_of(s, &ds.files[ds.origin[i].0].container, &normals)?,
        };
        match &mesh {
            Some((t, from_grid)) if !t.is_empty() => {
                // The sensor saw each grid triangle's front (one across a structure one or two
                // cells wide has vertex normals that disagree); a file's faces go by its normals.
                let proj = &setup.projection;
                let toward: Vec<Vec3>;
                let fronts = if *from_grid {
                    toward = s.points.iter().map(|&p| proj.toward_sensor(p)).collect();
                    &toward
                } else {
                    &normals
                };
                b.add_triangles(&s.name, s.pose, &s.points, Some(fronts), t)?;
                if *from_grid {
                    add_skirts(&mut b, s, &normals)?;
                }
            }
            _ => {
                b.add_surfels(&s.name, s.pose, &s.points, &normals, &radii)?;
            }
        }
        geo.push((normals, radii));
    }
    let t0 = Instant::now();
    let mut scene = b.build();
    let mut framed = Vec::with_capacity(ds.scans.len());
    for (s, (normals, _)) in ds.scans.iter().zip(&geo) {
        framed.push(scene.to_frame(s.pose, &s.points, normals)?);
    }
    let views: Vec<reference::residual::ScanGeometry> = framed
        .iter()
        .zip(&geo)
        .map(
            |((points, normals), (_, radii))| reference::residual::ScanGeometry {
                points,
                normals,
                radii,
            },
        )
        .collect();
    let heights = reference::residual::own_heights(&views);
    let build_s = t0.elapsed().as_secs_f64();
    std::fs::create_dir_all(&cfg.out_dir).map_err(|e| Error::io(&cfg.out_dir, e))?;
    let mut scans = Vec::with_capacity(ds.scans.len());
    let (mut rays, mut secs) = (0u64, 0.0f64);
    for (((s, (normals, radii)), (pts, nrm)), &h) in
        ds.scans.iter().zip(&geo).zip(&framed).zip(&heights)
    {
        scene.set_self_height(h);
        let r = reference::reference(&scene, pts, nrm, radii, &cfg.params, cfg.sample, progress)?;
        rays += r.convergence.rays_cast;
        secs += r.convergence.seconds;
        let check = reference::self_check(&scene, pts, nrm, radii, &r, &cfg.params, cfg.sample);
        write_reference_ply(
            &reference_path(&cfg.out_dir, &s.name),
            s,
            normals,
            radii,
            &r.a,
            RefExtras {
                self_hits: Some(&r.self_hits),
                on_surface: None,
            },
        )?;
        scans.push(RefScan {
            own_height: scene.self_height(),
            self_check: Some(check),
            off_surface: None,
            name: s.name.clone(),
            points: s.len(),
            mean_a: r.a.iter().map(|&v| v as f64).sum::<f64>() / s.len().max(1) as f64,
            convergence: r.convergence,
        });
    }
    let what = (
        cfg.geometry,
        None,
        scene.surfel_count(),
        scene.triangle_count(),
    );
    write_report(cfg, what, scans, (rays, secs, build_s), t_all)
}

/// Writes `reference.json` for the scans' reports `scans`, cast at `what` (geometry, true
/// surface, surfels, triangles) with `rays` rays in `secs` after `build_s` of building, and
/// hands the report back.
fn write_report(
    cfg: &RefConfig,
    what: (Geometry, Option<String>, usize, usize),
    scans: Vec<RefScan>,
    (rays, secs, build_s): (u64, f64, f64),
    t_all: Instant,
) -> Result<RefReport> {
    let (geometry, surface, surfels, triangles) = what;
    let report = RefReport {
        version: env!("CARGO_PKG_VERSION").to_string(),
        params: cfg.params,
        geometry,
        surface,
        surfels,
        triangles,
        scans,
        rays_per_second: if secs > 0.0 { rays as f64 / secs } else { 0.0 },
        build_s,
        wall_s: t_all.elapsed().as_secs_f64(),
    };
    let json = serde_json::to_vec_pretty(&report)
        .map_err(|e| Error::Param(format!("cannot encode the reference report: {e}")))?;
    crate::io::atomic::write_atomic(&cfg.out_dir.join("reference.json"), |w| {
        std::io::Write::write_all(w, &json)
    })?;
    Ok(report)
}

/// `mvao reference --surface`: every point's reference cast at the true surface `spec`
/// ([`surface`]), written as [`run_reference`] writes it, with `on_surface` per point.
fn run_surface(
    cfg: &RefConfig,
    spec: &SurfaceSpec,
    ds: &Dataset,
    t_all: Instant,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<RefReport> {
    let t0 = Instant::now();
    let scene = surface::load(spec)?;
    let build_s = t0.elapsed().as_secs_f64();
    // Every point is placed before any ray is cast, so that a surface in another frame is
    // refused at once.
    let mut placed = Vec::with_capacity(ds.scans.len());
    for s in &ds.scans {
        let setup = sensor::setup(s, cfg.projection)?;
        let (normals, radii, _) = crate::view::scan_normals(s, &setup);
        let (truth, on) = surface::place(&scene, s, &normals, &radii, spec.tolerance);
        placed.push((normals, radii, truth, on));
    }
    let on: usize = placed
        .iter()
        .map(|d| d.3.iter().filter(|&&b| b).count())
        .sum();
    let total: usize = ds.scans.iter().map(|s| s.len()).sum();
    surface::check_any_on(&spec.path, on, total)?;
    std::fs::create_dir_all(&cfg.out_dir).map_err(|e| Error::io(&cfg.out_dir, e))?;
    let mut scans = Vec::with_capacity(ds.scans.len());
    let (mut rays, mut secs) = (0u64, 0.0f64);
    for (s, (normals, radii, truth, on)) in ds.scans.iter().zip(&placed) {
        let r = surface::reference(&scene, truth, cfg, progress)?;
        rays += r.convergence.rays_cast;
        secs += r.convergence.seconds;
        let extras = RefExtras {
            self_hits: None,
            on_surface: Some(on),
        };
        let path = reference_path(&cfg.out_dir, &s.name);
        write_reference_ply(&path, s, normals, radii, &r.a, extras)?;
        let (sum, scored) =
            r.a.iter()
                .zip(on)
                .filter(|p| *p.1)
                .fold((0.0f64, 0usize), |acc, p| (acc.0 + *p.0 as f64, acc.1 + 1));
        scans.push(RefScan {
            name: s.name.clone(),
            points: s.len(),
            mean_a: sum / scored.max(1) as f64,
            convergence: r.convergence,
            self_check: None,
            off_surface: Some(s.len() - scored),
            own_height: 0.0,
        });
    }
    let surface = Some(spec.path.display().to_string());
    let what = (Geometry::Surface, surface, 0, scene.triangle_count());
    write_report(cfg, what, scans, (rays, secs, build_s), t_all)
}

/// Metrics of the result (and optionally the single-view SSAO) of every scan.
pub fn evaluate(
    reference_dir: &Path,
    names: &[String],
    ssao: Option<&[Vec<f32>]>,
    result: &[Vec<f32>],
    refs: &[Vec<f32>],
) -> Accuracy {
    let scans = names
        .iter()
        .enumerate()
        .map(|(i, n)| ScanAccuracy {
            name: n.clone(),
            ssao: ssao.map(|s| metrics_concat(&[(&s[i], &refs[i])])),
            result: metrics_concat(&[(&result[i], &refs[i])]),
        })
        .collect();
    let pairs = |v: &[Vec<f32>]| -> Metrics {
        let parts: Vec<(&[f32], &[f32])> = v
            .iter()
            .zip(refs)
            .map(|(a, r)| (a.as_slice(), r.as_slice()))
            .collect();
        metrics_concat(&parts)
    };
    Accuracy {
        reference: reference_dir.display().to_string(),
        scans,
        ssao: ssao.map(pairs),
        result: pairs(result),
    }
}

/// `mvao eval`: result files (any PLY with a per-vertex `ao`, named `<scan>.<anything>.ply`)
/// against the reference directory, matched by scan name.
pub fn eval_files(reference_dir: &Path, results: &[PathBuf]) -> Result<Accuracy> {
    if results.is_empty() {
        return Err(Error::Param("no result file given".into()));
    }
    let mut names = Vec::with_capacity(results.len());
    let mut vals = Vec::with_capacity(results.len());
    let mut refs = Vec::with_capacity(results.len());
    for p in results {
        let file = p
            .file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .unwrap_or_default();
        let name = file.split('.').next().unwrap_or("").to_string();
        let rp = reference_path(reference_dir, &name);
        if !rp.is_file() {
            return Err(Error::Param(format!(
                "{}: no reference {} for scan '{name}'",
                p.display(),
                rp.display()
            )));
        }
        let dir = p.parent().unwrap_or(Path::new("."));
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        if let Some((t, f)) = crate::io::reference::run_falloff(dir)? {
            crate::io::reference::check_reference_matches(reference_dir, t, f)?;
        }
        let a = read_ao(p)?;
        let r = read_reference_ao(&rp)?;
        if a.len() != r.len() {
            return Err(Error::format(
                p,
                format!(
                    "{} points, but the reference {} has {}",
                    a.len(),
                    rp.display(),
                    r.len()
                ),
            ));
        }
        names.push(name);
        vals.push(a);
        refs.push(r);
    }
    Ok(evaluate(reference_dir, &names, None, &vals, &refs))
}
