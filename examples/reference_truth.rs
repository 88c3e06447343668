//! Scores `mvao reference` against the exact ground truth of a mesh scene: scans the scene
//! with the virtual scanner (exact reference per point against the mesh), runs the reference
//! on the scans, and prints the error metrics per station and over all. With `--alone` each
//! scan's reference is also computed against that scan alone.
//!
//! ```text
//! cargo run --release --example reference_truth -- SCENE [key=value ...]
//!   keys: stations=3 width=360 height=180 model=equirect|perspective noise=0 reg=M,DEG
//!         tmax=inf rays=128 truth_rays=256 geometry=surfels|mesh normals=1 alone=0 out=DIR
//! ```
//! SCENE is a built-in mesh scene (colonnade, vault, relief, porch) or a PLY/OBJ mesh.

use mvao::accuracy::{self, Geometry, RefConfig};
use mvao::io::dataset::PlaceOptions;
use mvao::synth::{self, MeshKind, MeshSource, Registration, SynthOptions};
use mvao::testing::eval::metrics_concat;
use mvao::testing::projection::SensorModel;
use mvao::testing::reference::RefParams;
use std::collections::HashMap;
use std::path::PathBuf;
use std::process::ExitCode;

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("reference_truth: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scene = args.first().cloned().unwrap_or_else(|| "colonnade".into());
    let kv: HashMap<String, String> = args[1..]
        .iter()
        .filter_map(|a| {
            a.split_once('=')
                .map(|(k, v)| (k.to_string(), v.to_string()))
        })
        .collect();
    let get = |k: &str, d: &str| kv.get(k).cloned().unwrap_or_else(|| d.to_string());
    let num = |k: &str, d: &str| -> anyhow::Result<f64> { Ok(get(k, d).parse::<f64>()?) };
    let tmax = match get("tmax", "inf").as_str() {
        "inf" => f32::INFINITY,
        t => t.parse::<f32>()?,
    };
    let reg: Vec<f64> = get("reg", "0,0")
        .split(',')
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    let out = PathBuf::from(get("out", "/tmp/mvao-reference-truth"));
    let mesh = match MeshKind::from_name(&scene) {
        Some(k) => MeshSource::Builtin(k),
        None => MeshSource::File(PathBuf::from(&scene)),
    };
    let model = match get("model", "equirect").as_str() {
        "perspective" => SensorModel::Perspective,
        "ortho" => SensorModel::Ortho,
        _ => SensorModel::Equirect,
    };
    let scans_dir = out.join("scans");
    let _ = std::fs::remove_dir_all(&out);
    let opts = SynthOptions {
        mesh: Some(mesh),
        stations: num("stations", "3")? as usize,
        model,
        width: num("width", "360")? as usize,
        height: num("height", "180")? as usize,
        noise: num("noise", "0")?,
        seed: num("seed", "1")? as u64,
        out_dir: scans_dir.clone(),
        reference: Some(mvao::RefParams {
            rays: num("truth_rays", "256")? as u32,
            tmax,
            ..Default::default()
        }),
        registration: Registration {
            translation: reg.first().copied().unwrap_or(0.0),
            angle_deg: reg.get(1).copied().unwrap_or(0.0),
        },
        normals: num("normals", "1")? != 0.0,
        ..SynthOptions::default()
    };
    let t0 = std::time::Instant::now();
    let sum = synth::run(&opts)?;
    eprintln!(
        "{}: {} scans, {} points, truth in {:.1} s",
        sum.label,
        sum.files.len(),
        sum.files.iter().map(|f| f.points).sum::<usize>(),
        t0.elapsed().as_secs_f64()
    );
    let geometry = match get("geometry", "surfels").as_str() {
        "mesh" => Geometry::Mesh,
        _ => Geometry::Surfels,
    };
    let params = RefParams {
        rays: num("rays", "128")? as u32,
        tmax,
        falloff: Default::default(),
        seed: 0,
    };
    let files: Vec<PathBuf> = sum.files.iter().map(|f| f.path.clone()).collect();
    let truth_dir = scans_dir.join("reference-mesh");
    let score = |scans: &[PathBuf], dir: PathBuf, label: &str| -> anyhow::Result<()> {
        let cfg = RefConfig {
            scans: scans.to_vec(),
            place: PlaceOptions {
                align: Some(sum.alignment.clone()),
                ..PlaceOptions::default()
            },
            out_dir: dir.clone(),
            params,
            geometry,
            surface: None,
            sample: 100,
            projection: Default::default(),
            force: true,
        };
        let t = std::time::Instant::now();
        let rep = accuracy::run_reference(&cfg, &|_| {})?;
        let names: Vec<String> = rep.scans.iter().map(|s| s.name.clone()).collect();
        for s in &rep.scans {
            println!("{label} {} self-check: {:?}", s.name, s.self_check);
        }
        let mut all_a = Vec::new();
        let mut all_t = Vec::new();
        for name in &names {
            let a = accuracy::read_ao(&accuracy::reference_path(&dir, name))?;
            let t = accuracy::read_ao(&accuracy::reference_path(&truth_dir, name))?;
            let m = metrics_concat(&[(&a, &t)]);
            println!("{label} {name}: {}", m.one_line());
            if get("classes", "0") != "0" {
                classes(
                    &accuracy::reference_path(&truth_dir, name),
                    &accuracy::reference_path(&dir, name),
                    &a,
                    &t,
                )?;
            }
            all_a.push(a);
            all_t.push(t);
        }
        let parts: Vec<(&[f32], &[f32])> = all_a
            .iter()
            .zip(&all_t)
            .map(|(a, t)| (a.as_slice(), t.as_slice()))
            .collect();
        println!(
            "{label} all: {}  ({:.2} M rays/s, {:.1} s)",
            metrics_concat(&parts).one_line(),
            rep.rays_per_second / 1e6,
            t.elapsed().as_secs_f64()
        );
        Ok(())
    };
    score(&files, out.join("ref"), "joint")?;
    if get("alone", "0") != "0" {
        for (i, f) in files.iter().enumerate() {
            score(
                std::slice::from_ref(f),
                out.join(format!("alone{i}")),
                "alone",
            )?;
        }
    }
    Ok(())
}

/// Error by surface class (true normal up, down, sideways) and by radius.
fn classes(
    truth: &std::path::Path,
    refp: &std::path::Path,
    a: &[f32],
    t: &[f32],
) -> anyhow::Result<()> {
    let tp = mvao::io::ply::PlyFile::from_path(truth)?;
    let rp = mvao::io::ply::PlyFile::from_path(refp)?;
    let nz = tp.scalar_column("vertex", "nz").unwrap_or_default();
    let rad = rp.scalar_column("vertex", "radius").unwrap_or_default();
    let mut sorted = rad.clone();
    sorted.sort_by(f64::total_cmp);
    let q = |f: f64| sorted[((sorted.len() - 1) as f64 * f) as usize];
    let (q1, q2, q3) = (q(0.25), q(0.5), q(0.75));
    let mut buckets: Vec<(String, Vec<f32>, Vec<f32>)> = Vec::new();
    let mut push = |k: String, x: f32, y: f32| {
        if let Some(b) = buckets.iter_mut().find(|b| b.0 == k) {
            b.1.push(x);
            b.2.push(y);
        } else {
            buckets.push((k, vec![x], vec![y]));
        }
    };
    for i in 0..a.len() {
        let c = if nz[i] > 0.9 {
            "up"
        } else if nz[i] < -0.9 {
            "down"
        } else {
            "side"
        };
        let r = if rad[i] < q1 {
            "r<q1"
        } else if rad[i] < q2 {
            "r<q2"
        } else if rad[i] < q3 {
            "r<q3"
        } else {
            "r>q3"
        };
        push(format!("{c} {r}"), a[i], t[i]);
    }
    buckets.sort_by(|x, y| x.0.cmp(&y.0));
    println!("   radius quartiles {q1:.4} {q2:.4} {q3:.4}");
    for (k, x, y) in &buckets {
        let m = metrics_concat(&[(x, y)]);
        println!(
            "   {k:12} n={:6} e_A={:.4} bias={:+.4} shaded_e_A={:?}",
            m.n,
            m.e_a,
            m.bias,
            m.shaded_e_a.map(|v| (v * 1e4).round() / 1e4)
        );
    }
    Ok(())
}
