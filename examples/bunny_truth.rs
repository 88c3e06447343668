//! The surfel reference of the ten raw Stanford bunny scans against rays cast at the bunny's
//! reconstructed surface (`fixtures/stanford-bunny/reconstruction/bun_zipper.ply`) from the
//! same points: each point is moved to the nearest point of the reconstruction (within
//! 2 mm; farther points are left out) and takes that face's normal, turned to the scan's
//! own normal. Prints the metrics of each scan's reference computed against all ten scans
//! and against the scan alone.
//!
//! ```text
//! cargo run --release --example bunny_truth -- [TMAX|inf] [RAYS]
//! ```

use mvao::accuracy::{self, Geometry, RefConfig};
use mvao::io::dataset::{Dataset, PlaceOptions};
use mvao::synth::reference::mesh_obscurance;
use mvao::synth::{Mesh, MeshScene, Truth};
use mvao::testing::eval::metrics_concat;
use mvao::testing::reference::RefParams;
use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let tmax = match args.first().map(String::as_str) {
        None | Some("inf") => f32::INFINITY,
        Some(t) => t.parse()?,
    };
    let rays: u32 = args.get(1).map_or(Ok(256), |r| r.parse())?;
    let fx = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures/stanford-bunny");
    let mesh = Mesh::read(&fx.join("reconstruction/bun_zipper.ply"))?;
    let scene = MeshScene::new(&mesh);
    let mut scans: Vec<PathBuf> = std::fs::read_dir(&fx)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "ply"))
        .collect();
    scans.sort();
    let place = PlaceOptions {
        align: Some(fx.join("bun.conf")),
        ..PlaceOptions::default()
    };
    let out = std::env::temp_dir().join("mvao-bunny-truth");
    let reference = |files: &[PathBuf], place: &PlaceOptions, dir: PathBuf| -> anyhow::Result<()> {
        accuracy::run_reference(
            &RefConfig {
                scans: files.to_vec(),
                place: place.clone(),
                out_dir: dir,
                params: RefParams {
                    rays,
                    tmax,
                    falloff: Default::default(),
                    seed: 0,
                },
                geometry: Geometry::Surfels,
                sample: 200,
                projection: Default::default(),
                force: true,
            },
            &|_| {},
        )?;
        Ok(())
    };
    reference(&scans, &place, out.join("all"))?;
    let ds = Dataset::open(&scans, &place, &|| {})?;
    let (mut all_t, mut all_j, mut all_a) = (Vec::new(), Vec::new(), Vec::new());
    for (k, s) in ds.scans.iter().enumerate() {
        let alone = out.join(format!("alone{k}"));
        // The scan alone, at the pose the alignment gives it.
        let file = &scans[ds.origin[k].0];
        std::fs::create_dir_all(&alone)?;
        let mlp = alone.join("one.mlp");
        mvao::io::align::write_mlp(
            &mlp,
            &[mvao::io::align::AlignEntry {
                file: file
                    .file_name()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned(),
                pose: ds.file_to_world[k],
            }],
        )?;
        let one = PlaceOptions {
            align: Some(mlp),
            ..PlaceOptions::default()
        };
        reference(std::slice::from_ref(file), &one, alone.clone())?;
        let joint = accuracy::read_ao(&accuracy::reference_path(&out.join("all"), &s.name))?;
        let own = accuracy::read_ao(&accuracy::reference_path(&alone, &s.name))?;
        let ply = mvao::io::ply::PlyFile::from_path(&accuracy::reference_path(&alone, &s.name))?;
        let col = |c: &str| ply.scalar_column("vertex", c).unwrap_or_default();
        let (nx, ny, nz) = (col("nx"), col("ny"), col("nz"));
        let rot = glam::DMat3::from_mat4(s.pose);
        let (mut truth, mut keep) = (Vec::new(), Vec::new());
        for (i, p) in s.points.iter().enumerate() {
            let w = s.pose.transform_point3(p.as_dvec3());
            let Some((q, face)) = scene.nearest(w, 0.002) else {
                continue;
            };
            let mut n = scene.normal(face as usize);
            let est = rot * glam::DVec3::new(nx[i], ny[i], nz[i]);
            if n.dot(est) < 0.0 {
                n = -n;
            }
            truth.push(Truth {
                p: q,
                n,
                prim: face,
            });
            keep.push(i);
        }
        let t = mesh_obscurance(&scene, &truth, rays, (tmax, Default::default()), 0);
        let j: Vec<f32> = keep.iter().map(|&i| joint[i]).collect();
        let a: Vec<f32> = keep.iter().map(|&i| own[i]).collect();
        println!(
            "{} ({} of {} points on the mesh)\n  all ten: {}\n  alone:   {}",
            s.name,
            keep.len(),
            s.len(),
            metrics_concat(&[(&j, &t)]).one_line(),
            metrics_concat(&[(&a, &t)]).one_line()
        );
        all_t.push(t);
        all_j.push(j);
        all_a.push(a);
    }
    let parts = |v: &[Vec<f32>]| -> Vec<(Vec<f32>, Vec<f32>)> {
        v.iter().cloned().zip(all_t.iter().cloned()).collect()
    };
    for (label, v) in [("all ten", &all_j), ("alone", &all_a)] {
        let p = parts(v);
        let refs: Vec<(&[f32], &[f32])> = p
            .iter()
            .map(|(a, t)| (a.as_slice(), t.as_slice()))
            .collect();
        println!("every scan, {label}: {}", metrics_concat(&refs).one_line());
    }
    Ok(())
}
