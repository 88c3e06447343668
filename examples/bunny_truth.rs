//! The surfel reference of the ten raw Stanford bunny scans against rays cast at the bunny's
//! reconstructed surface (`fixtures/stanford-bunny/reconstruction/bun_zipper.ply`) from the
//! same points, as `mvao reference --surface` casts them: each point is moved to the nearest
//! point of the reconstruction (within 2 mm; farther points are left out) and takes that
//! face's normal, turned to the scan's own normal. Prints the metrics of each scan's reference computed against all ten scans
//! and against the scan alone.
//!
//! ```text
//! cargo run --release --example bunny_truth -- [TMAX|inf] [RAYS]
//! ```

use mvao::accuracy::{self, Geometry, RefConfig, SurfaceSpec};
use mvao::io::dataset::{Dataset, PlaceOptions};
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
    // The surfel reference of `files`, or with `surface` the truth cast at that surface.
    let reference = |files: &[PathBuf],
                     place: &PlaceOptions,
                     dir: PathBuf,
                     surface: Option<SurfaceSpec>|
     -> anyhow::Result<()> {
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
                surface,
                sample: 200,
                projection: Default::default(),
                force: true,
            },
            &|_| {},
        )?;
        Ok(())
    };
    reference(&scans, &place, out.join("all"), None)?;
    // The truth: rays at the reconstruction from each point's nearest position on it.
    let truth_dir = out.join("truth");
    let surface = SurfaceSpec {
        path: fx.join("reconstruction/bun_zipper.ply"),
        tolerance: Some(0.002),
    };
    reference(&scans, &place, truth_dir.clone(), Some(surface))?;
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
        reference(std::slice::from_ref(file), &one, alone.clone(), None)?;
        let joint = accuracy::read_ao(&accuracy::reference_path(&out.join("all"), &s.name))?;
        let own = accuracy::read_ao(&accuracy::reference_path(&alone, &s.name))?;
        // NaN where a point lies farther than 2 mm from the reconstruction: not scored.
        let t = accuracy::read_reference_ao(&accuracy::reference_path(&truth_dir, &s.name))?;
        let on = t.iter().filter(|v| v.is_finite()).count();
        println!(
            "{} ({on} of {} points on the mesh)\n  all ten: {}\n  alone:   {}",
            s.name,
            s.len(),
            metrics_concat(&[(&joint, &t)]).one_line(),
            metrics_concat(&[(&own, &t)]).one_line()
        );
        all_t.push(t);
        all_j.push(joint);
        all_a.push(own);
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
