//! The stages run the same way over both view stores: the in-memory computation
//! (`pipeline::compute`, a `MemoryStore`) and `mvao merge` (the work directory, with a map
//! cache that holds every view or must evict) give every point the same AO to the bit.

mod common;

use common::*;
use mvao::config::ComputeParams;
use mvao::io::dataset::{Dataset, PlaceOptions};
use mvao::io::reference::read_ao;
use mvao::pipeline;
use mvao::progress::Silent;
use mvao::testing::ssao::Estimator;
use std::path::{Path, PathBuf};

/// `mvao merge` of `scans` into `out` with `extra` flags: each scan's AO as written, and the
/// report.
fn merged(scans: &[PathBuf], out: &Path, extra: &[&str]) -> (Vec<Vec<f32>>, serde_json::Value) {
    let mut a = vec![
        "merge",
        "-q",
        "--no-preview",
        "--radius",
        "0.2",
        "--tmax",
        "0.4",
        "--seed",
        "5",
        "-o",
        out.to_str().unwrap(),
    ];
    a.extend_from_slice(extra);
    a.extend(scans.iter().map(|p| p.to_str().unwrap()));
    mvao_ok(&a);
    let ao = scans
        .iter()
        .map(|p| {
            let stem = p.file_stem().unwrap().to_string_lossy();
            read_ao(&out.join(format!("{stem}.mvao.ply"))).unwrap()
        })
        .collect();
    let report = serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    (ao, report)
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn the_memory_store_and_the_work_directory_give_the_same_ao() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("site"), 3, 240, 120);
    let ds = Dataset::open(&scans, &PlaceOptions::default(), &|| {}).unwrap();
    for (est, extra) in [
        (Estimator::Horizon, vec![]),
        (
            Estimator::Paper,
            vec!["--estimator", "paper", "--neighbors", "3"],
        ),
    ] {
        let prm = ComputeParams {
            radius: Some(0.2),
            tmax: Some(0.4),
            seed: 5,
            estimator: est,
            neighbors: if est == Estimator::Paper { 3 } else { 1 },
            ..Default::default()
        };
        let mem = pipeline::compute(&ds.scans, &prm, &Silent).unwrap();
        let tag = format!("{est:?}");
        let (all, r) = merged(&scans, &d.path().join(format!("all-{tag}")), &extra);
        assert_eq!(r["map_loads"], 0, "every view fits: none read back");
        // A budget below two views: the merge reads maps back and evicts them.
        let mut tight = extra.clone();
        tight.extend(["--max-memory", "20M"]);
        let (few, r) = merged(&scans, &d.path().join(format!("few-{tag}")), &tight);
        assert!(r["map_loads"].as_u64().unwrap() > 3, "{}", r["map_loads"]);
        for (i, s) in mem.scans.iter().enumerate() {
            assert_eq!(s.ao.len(), ds.scans[i].len());
            assert_eq!(
                bits(&s.ao),
                bits(&all[i]),
                "{tag}: scan {i}, memory vs merge"
            );
            assert_eq!(
                bits(&s.ao),
                bits(&few[i]),
                "{tag}: scan {i}, memory vs tight merge"
            );
            // The merge changed something: the views do overlap.
            assert_ne!(bits(&s.ao), bits(&s.ssao), "{tag}: scan {i} was not merged");
        }
        assert_eq!(mem.merge.neighbors, prm.neighbors);
    }
}

#[test]
fn ssao_only_is_the_own_view_in_both_stores() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("site"), 2, 200, 100);
    let ds = Dataset::open(&scans, &PlaceOptions::default(), &|| {}).unwrap();
    let prm = ComputeParams {
        radius: Some(0.2),
        tmax: Some(0.4),
        seed: 5,
        ssao_only: true,
        ..Default::default()
    };
    let mem = pipeline::compute(&ds.scans, &prm, &Silent).unwrap();
    let (ao, r) = merged(&scans, &d.path().join("out"), &["--ssao-only"]);
    for (i, s) in mem.scans.iter().enumerate() {
        assert_eq!(bits(&s.ao), bits(&s.ssao));
        assert_eq!(bits(&s.ao), bits(&ao[i]), "scan {i}");
        assert_eq!(s.merge.point_views, 0);
        assert_eq!(r["scans"][i]["point_views"], 0);
    }
}

#[test]
fn union_occlusion_is_the_same_in_both_stores() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("site"), 3, 160, 80);
    let ds = Dataset::open(&scans, &PlaceOptions::default(), &|| {}).unwrap();
    let prm = ComputeParams {
        radius: Some(0.2),
        tmax: Some(0.4),
        seed: 5,
        occlusion: mvao::Occlusion::Union,
        rays: Some(4),
        ..Default::default()
    };
    let mem = pipeline::compute(&ds.scans, &prm, &Silent).unwrap();
    let extra = ["--occlusion", "union", "--rays", "4"];
    let (all, _) = merged(&scans, &d.path().join("all"), &extra);
    let mut tight = extra.to_vec();
    tight.extend(["--max-memory", "20M"]);
    let (few, r) = merged(&scans, &d.path().join("few"), &tight);
    assert!(r["map_loads"].as_u64().unwrap() > 0, "{}", r["map_loads"]);
    for (i, s) in mem.scans.iter().enumerate() {
        assert!(s
            .ao
            .iter()
            .all(|a| a.is_finite() && (0.0..=1.0).contains(a)));
        assert_eq!(bits(&s.ao), bits(&all[i]), "scan {i}, memory vs merge");
        assert_eq!(
            bits(&s.ao),
            bits(&few[i]),
            "scan {i}, memory vs tight merge"
        );
        assert_ne!(
            bits(&s.ao),
            bits(&s.ssao),
            "scan {i}: the union changed nothing"
        );
    }
}
