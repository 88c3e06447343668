//! `mvao synth` on a triangle mesh: station placement over the mesh, the scans with their
//! exact surface points, the registration error written into the poses, and the exact
//! reference obscurance of every point against the mesh.

use super::mesh::{Mesh, MeshScene};
use super::reference::mesh_obscurance;
use super::scanner::{scan_with_truth, Station, Truth};
use super::{
    default_map_size, describe_station, station_seed, write_scan_ply, MeshSource, SynthFile,
    SynthOptions, SynthSummary,
};
use crate::error::{Error, Result};
use crate::io::align::{write_mlp, AlignEntry};
use crate::projection::SensorModel;
use crate::scan::Scan;
use glam::{DMat3, DVec2, DVec3};
use std::f64::consts::{PI, TAU};

/// Stations over a mesh: positions from `opts.at`, else the built-in scene's, else a ring
/// (equirect: around the bounds' centre at a quarter of the smaller horizontal side, 1.5 m
/// above the lowest point or half the height if lower; perspective: 1.2 half-diagonals from
/// the centre, half a half-diagonal above it), station `k` at position `k mod count`, yaw
/// `0.7·k`. Perspective stations look at `opts.look_at`, else the scene's target, else the
/// centre, with a 75° field of view (30° for the relief). Ortho stations are strips over the
/// bounds looking down from just above the top, as for the analytic scenes.
pub fn mesh_layout(
    mesh: &Mesh,
    builtin: Option<(Vec<DVec3>, DVec3)>,
    opts: &SynthOptions,
) -> Vec<Station> {
    let (lo, hi) = mesh.bounds();
    let centre = (lo + hi) / 2.0;
    let half_diag = ((hi - lo) / 2.0).length().max(1e-6);
    let (def_pos, def_target) = builtin.unwrap_or_else(|| {
        let r = 0.25 * (hi.x - lo.x).min(hi.y - lo.y);
        let z = lo.z + 1.5f64.min(0.5 * (hi.z - lo.z));
        let ring = (0..opts.stations.max(1))
            .map(|k| {
                let a = PI / 4.0 + TAU * k as f64 / opts.stations.max(1) as f64;
                match opts.model {
                    SensorModel::Perspective => {
                        centre
                            + DVec3::new(a.cos(), a.sin(), 0.0) * 1.2 * half_diag
                            + DVec3::Z * 0.5 * half_diag
                    }
                    _ => DVec3::new(centre.x + r * a.cos(), centre.y + r * a.sin(), z),
                }
            })
            .collect();
        (ring, centre)
    });
    let positions = if opts.at.is_empty() {
        def_pos
    } else {
        opts.at.clone()
    };
    let target = opts.look_at.unwrap_or(def_target);
    let (dw, dh) = default_map_size(opts.model);
    let width = if opts.width == 0 { dw } else { opts.width };
    let height = if opts.height == 0 { dh } else { opts.height };
    let count = opts.stations;
    let fov = if half_diag < 0.5 { 30f64 } else { 75f64 };
    (0..count)
        .map(|k| {
            let p = positions[k % positions.len()];
            match opts.model {
                SensorModel::Equirect => {
                    let mut s = Station::equirect(p, (0.7 * k as f64) % TAU, width, height);
                    s.max_range = 1e3f64.max(4.0 * half_diag);
                    s
                }
                SensorModel::Perspective => {
                    let mut s = Station::perspective(p, target, fov.to_radians(), width, height);
                    s.max_range = 1e3f64.max(4.0 * half_diag);
                    s
                }
                SensorModel::Ortho => {
                    let s = (hi.x - lo.x) / count as f64;
                    let pad = if count > 1 { 0.25 * s } else { 0.0 };
                    let x0 = (lo.x + k as f64 * s - pad).max(lo.x);
                    let x1 = (lo.x + (k + 1) as f64 * s + pad).min(hi.x);
                    let c = DVec3::new((x0 + x1) / 2.0, centre.y, hi.z + 0.01 * half_diag);
                    let half =
                        DVec2::new((x1 - x0) / 2.0, (hi.y - lo.y) / 2.0).max(DVec2::splat(1e-6));
                    let yaw = if k % 2 == 1 { PI } else { 0.0 };
                    let rows = match opts.height {
                        0 => ((width as f64 * half.y / half.x).round() as usize).max(1),
                        h => h,
                    };
                    let mut st = Station::ortho(c, yaw, half, width, rows);
                    st.max_range = 4.0 * half_diag + 1.0;
                    st
                }
            }
        })
        .collect()
}

/// The reference file of the exact truth: the true surface point (as a scan-local point of
/// the true pose) and its true normal.
fn truth_scan(scan: &Scan, truth: &[Truth], true_pose: glam::DMat4) -> (Scan, Vec<glam::Vec3>) {
    let inv = true_pose.inverse();
    let rot = DMat3::from_mat4(inv);
    let mut s = scan.clone();
    s.pose = true_pose;
    s.points = truth
        .iter()
        .map(|t| inv.transform_point3(t.p).as_vec3())
        .collect();
    let normals = truth.iter().map(|t| (rot * t.n).as_vec3()).collect();
    (s, normals)
}

/// [`super::run`] on a mesh: writes `station_NNN.ply`, `alignment.mlp` (poses with the
/// registration error) and, with `opts.reference`, `reference-mesh/station_NNN.ref.ply`.
pub fn run_mesh(opts: &SynthOptions, src: &MeshSource) -> Result<SynthSummary> {
    let (mesh, label, builtin) = match src {
        MeshSource::File(p) => (Mesh::read(p)?, p.display().to_string(), None),
        MeshSource::Builtin(k) => (k.mesh(), k.name().to_string(), Some(k.stations())),
    };
    let stations = mesh_layout(&mesh, builtin, opts);
    for st in &stations {
        st.validate()?;
    }
    let scene = MeshScene::new(&mesh);
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| Error::io(&opts.out_dir, e))?;
    let mut files = Vec::with_capacity(stations.len());
    let mut entries = Vec::with_capacity(stations.len());
    for (i, st) in stations.iter().enumerate() {
        let name = format!("station_{i:03}");
        let file = format!("{name}.ply");
        let seed = station_seed(opts.seed, i);
        let (mut scan, truth) = scan_with_truth(&scene, st, opts.noise, seed, &name);
        let true_pose = scan.pose;
        scan.pose = true_pose * opts.registration.error(opts.seed, i);
        if !opts.normals {
            scan.normals = None;
        }
        if !opts.grid {
            scan.grid = None;
        }
        let mut comments = vec![format!(
            "mvao synthetic scan: mesh {label} station {i} of {}",
            opts.stations
        )];
        comments.extend(describe_station(st));
        comments.push(format!("range_noise_sigma_m {} seed {seed}", opts.noise));
        comments.push(format!(
            "registration_error_m {} deg {}",
            opts.registration.translation, opts.registration.angle_deg
        ));
        let path = opts.out_dir.join(&file);
        write_scan_ply(&scan, &path, &comments)?;
        if let Some(rp) = opts.reference {
            let dir = opts.out_dir.join("reference-mesh");
            std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
            if i == 0 {
                super::write_truth_params(&dir, &rp, "mesh")?;
            }
            let a = mesh_obscurance(&scene, &truth, rp.rays, (rp.tmax, rp.falloff), 0);
            let (ts, normals) = truth_scan(&scan, &truth, true_pose);
            super::write_truth(&dir, &name, &ts, &normals, &a)?;
        }
        files.push(SynthFile {
            path,
            station: i,
            points: scan.len(),
        });
        entries.push(AlignEntry {
            file,
            pose: scan.pose,
        });
    }
    let alignment = opts.out_dir.join("alignment.mlp");
    write_mlp(&alignment, &entries)?;
    Ok(SynthSummary {
        scene: opts.scene,
        label,
        model: opts.model,
        out_dir: opts.out_dir.clone(),
        files,
        alignment,
    })
}
