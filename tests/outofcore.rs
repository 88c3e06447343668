//! The work directory and the memory budget: a rerun reuses products, a crash between steps
//! resumes to identical outputs, a changed parameter or input invalidates exactly what
//! depends on it, the plan skips pairs that cannot meet, per-scan jobs (`prepare`, `merge
//! --only`) give the same result as one run, and a merge over more scans than fit in the
//! budget stays under it.

mod common;

use common::*;
use std::path::{Path, PathBuf};

fn merge(scans: &[PathBuf], out: &Path, extra: &[&str]) -> serde_json::Value {
    let mut a = vec![
        "merge",
        "-q",
        "--force",
        "--no-preview",
        "--radius",
        "0.2",
        "-o",
        out.to_str().unwrap(),
    ];
    a.extend_from_slice(extra);
    a.extend(scans.iter().map(|p| p.to_str().unwrap()));
    mvao_ok(&a);
    report(out)
}

fn outputs(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().ends_with(".mvao.ply"))
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

fn products(r: &serde_json::Value) -> (u64, u64) {
    (
        r["products"][0].as_u64().unwrap(),
        r["products"][1].as_u64().unwrap(),
    )
}

#[test]
fn reruns_reuse_products_and_crashes_resume_to_identical_outputs() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("site"), 3, 240, 120);
    let out = d.path().join("out");
    let r = merge(&scans, &out, &[]);
    assert_eq!(products(&r), (3, 0));
    let first = outputs(&out);
    assert_eq!(first.len(), 3);

    // Rerun: every product reused, outputs byte-identical.
    let r = merge(&scans, &out, &[]);
    assert_eq!(products(&r), (0, 3));
    assert_eq!(outputs(&out), first);

    // A crash between steps: one product's entry never written, another's maps gone, a
    // temporary file left behind.
    let work = out.join("work");
    std::fs::remove_file(work.join("station_001.manifest.json")).unwrap();
    let maps: Vec<PathBuf> = std::fs::read_dir(&work)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let n = p.file_name().unwrap().to_string_lossy();
            n.starts_with("station_002.") && n.ends_with(".maps.exr")
        })
        .collect();
    std::fs::remove_file(&maps[0]).unwrap();
    std::fs::write(work.join(".station_000.x.tmp-999999"), b"half").unwrap();
    let r = merge(&scans, &out, &[]);
    assert_eq!(products(&r), (2, 1), "{}", r["warnings"]);
    assert_eq!(outputs(&out), first, "resumed run differs");

    // A merge-only parameter recomputes no product; an SSAO parameter recomputes all.
    let r = merge(&scans, &out, &["--neighbors", "3"]);
    assert_eq!(products(&r), (0, 3));
    let r = merge(&scans, &out, &["--directions", "4"]);
    assert_eq!(products(&r), (3, 0));
    // A changed input recomputes only its own product.
    let r = merge(&scans, &out, &["--directions", "4"]);
    assert_eq!(products(&r), (0, 3));
    let mut ply = mvao::io::ply::PlyFile::from_path(&scans[1]).unwrap();
    let mut x = ply.scalar_column("vertex", "x").unwrap();
    x[0] += 0.001;
    ply.set_scalar_column("vertex", "x", mvao::io::ply::ScalarType::F32, &x)
        .unwrap();
    ply.write_path(&scans[1]).unwrap();
    let r = merge(&scans, &out, &["--directions", "4"]);
    assert_eq!(products(&r), (1, 2));
}

#[test]
fn per_scan_jobs_give_the_same_result_as_one_run() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("site"), 3, 200, 100);
    let whole = d.path().join("whole");
    merge(&scans, &whole, &[]);
    let jobs = d.path().join("jobs");
    let work = d.path().join("work");
    let s: Vec<&str> = scans.iter().map(|p| p.to_str().unwrap()).collect();
    for name in ["station_000", "station_001", "station_002"] {
        let mut a = vec![
            "prepare",
            "-q",
            "--radius",
            "0.2",
            "--work",
            work.to_str().unwrap(),
            "--only",
            name,
            "-o",
            jobs.to_str().unwrap(),
        ];
        a.extend(&s);
        mvao_ok(&a);
    }
    for name in ["station_000", "station_001", "station_002"] {
        let mut a = vec![
            "merge",
            "-q",
            "--no-preview",
            "--radius",
            "0.2",
            "--work",
            work.to_str().unwrap(),
            "--only",
            name,
            "-o",
            jobs.to_str().unwrap(),
        ];
        a.extend(&s);
        mvao_ok(&a);
        let r: serde_json::Value = serde_json::from_slice(
            &std::fs::read(jobs.join(format!("report.{name}.json"))).unwrap(),
        )
        .unwrap();
        assert_eq!(products(&r).0, 0, "merge --only recomputed a product");
    }
    assert_eq!(outputs(&jobs), outputs(&whole));
}

#[test]
fn the_plan_skips_pairs_that_cannot_meet() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("site"), 2, 120, 60);
    // Move the second station's pose 1 km away.
    let mlp = d.path().join("site/alignment.mlp");
    let mut al = mvao::io::align::read_alignment(&mlp).unwrap();
    al.entries[1].pose =
        glam::DMat4::from_translation(glam::DVec3::new(1000.0, 0.0, 0.0)) * al.entries[1].pose;
    mvao::io::align::write_mlp(&mlp, &al.entries).unwrap();
    let out = d.path().join("out");
    let mut a = vec![
        "merge",
        "--dry-run",
        "--radius",
        "0.2",
        "-o",
        out.to_str().unwrap(),
    ];
    a.extend(scans.iter().map(|p| p.to_str().unwrap()));
    let text = mvao_ok(&a);
    assert!(text.contains("pairs kept 0, skipped 2"), "{text}");
    // Both stations are named as meeting no other, with the distance between them.
    for name in ["station_000", "station_001"] {
        assert!(
            text.contains(&format!(
                "scan {name} shares no surface with any other scan"
            )),
            "{text}"
        );
    }
    assert!(text.contains("1000.0 m away"), "{text}");
    assert!(!out.join("work").exists(), "a dry run wrote products");
    let r = merge(&scans, &out, &[]);
    assert_eq!(r["plan"]["pairs_skipped"], 2);
    // Each scan merged against its own view only.
    for s in r["scans"].as_array().unwrap() {
        assert_eq!(s["point_views"], s["points"]);
    }
}

/// Eight stations whose maps do not all fit in a 200 MiB budget: the merge reloads maps
/// instead of holding them, the output equals an unbounded run (which merges the views its
/// prepare pass made, reading none back), and the peak stays under the budget plus 10 %;
/// under a budget that holds some of the views, the merge takes those from the prepare pass.
#[test]
fn a_merge_over_more_scans_than_fit_stays_under_the_budget() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("site"), 8, 1024, 512);
    let free = d.path().join("free");
    let r_free = merge(&scans, &free, &[]);
    assert_eq!(r_free["map_loads"], 0);
    let all = r_free["plan"]["all_views_bytes"].as_u64().unwrap();
    let budget: u64 = 200 << 20;
    assert!(all > budget, "views {all} fit in the budget: not a test");
    let tight = d.path().join("tight");
    let r = merge(&scans, &tight, &["--max-memory", "200M"]);
    assert_eq!(outputs(&tight), outputs(&free));
    let loads = r["map_loads"].as_u64().unwrap();
    assert!(
        loads > r_free["map_loads"].as_u64().unwrap(),
        "no reloads under the budget: {loads}"
    );
    let peak = r["peak_rss_bytes"].as_u64().unwrap();
    eprintln!(
        "peak {} MiB under a {} MiB budget",
        peak >> 20,
        budget >> 20
    );
    assert!(
        peak as f64 <= budget as f64 * 1.1,
        "peak {} MiB over the {} MiB budget",
        peak >> 20,
        budget >> 20
    );

    // What one step needs as the plan counts it (five times an input file, three views and
    // 16 MiB); the views of the first scans that fit beside it are kept.
    let file = scans
        .iter()
        .map(|p| std::fs::metadata(p).unwrap().len())
        .max()
        .unwrap();
    let view = r_free["plan"]["largest_view_bytes"].as_u64().unwrap();
    assert_eq!(all, 8 * view, "the stations' views differ in size");
    let floor = 5 * file + 3 * view + (16 << 20);
    assert_eq!(r_free["views_kept"], 8);
    assert!(r["views_kept"].as_u64().unwrap() <= budget.saturating_sub(floor) / view);

    // A budget that holds four and a half views beside twice what one step needs.
    let part_budget = 2 * floor + 9 * view / 2;
    let part = d.path().join("part");
    let r = merge(
        &scans,
        &part,
        &["--max-memory", &format!("{}M", part_budget >> 20)],
    );
    assert_eq!(outputs(&part), outputs(&free));
    // At least the four that fit beside twice a step, as many as the estimate and the
    // resident memory measured as each one is kept allow; the others' maps are read back.
    let kept = r["views_kept"].as_u64().unwrap();
    assert!(kept >= 4, "{kept} views kept");
    assert!(
        r["map_loads"].as_u64().unwrap() >= 8 - kept,
        "{}",
        r["map_loads"]
    );
    let peak = r["peak_rss_bytes"].as_u64().unwrap();
    assert!(
        peak as f64 <= part_budget as f64 * 1.1,
        "peak {} MiB over the {} MiB budget",
        peak >> 20,
        part_budget >> 20
    );

    // One step and four and a half views: few views are kept, most partner maps are read
    // back while the step's own memory grows, and the peak still stays within the budget.
    let tight_budget = floor + 9 * view / 2;
    let one_step = d.path().join("one-step");
    let r = merge(
        &scans,
        &one_step,
        &["--max-memory", &format!("{}M", tight_budget >> 20)],
    );
    assert_eq!(outputs(&one_step), outputs(&free));
    let peak = r["peak_rss_bytes"].as_u64().unwrap();
    assert!(
        peak as f64 <= tight_budget as f64 * 1.1,
        "peak {} MiB over the {} MiB budget",
        peak >> 20,
        tight_budget >> 20
    );
}

/// At `t_max = ∞` the far-field sweeps' line families count in what one step needs: a budget
/// that holds a step of the march but not the sweeps beside it is reported as too small.
#[test]
fn the_far_field_sweeps_and_the_union_count_in_the_budget() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("site"), 2, 256, 128);
    let inf = ["--tmax", "inf", "--falloff", "none"];
    let r = merge(&scans, &d.path().join("inf"), &inf);
    let pixels = r["plan"]["scans"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["map_pixels"].as_u64().unwrap())
        .max()
        .unwrap();
    // Eleven bytes per pixel for each of the 32 families of the default 8 directions.
    let sweeps = r["plan"]["occlusion_bytes"].as_u64().unwrap();
    assert_eq!(sweeps, 11 * 32 * pixels);
    let near = merge(&scans, &d.path().join("near"), &[]);
    assert_eq!(near["plan"]["occlusion_bytes"], 0);

    let file = scans
        .iter()
        .map(|p| std::fs::metadata(p).unwrap().len())
        .max()
        .unwrap();
    let view = r["plan"]["largest_view_bytes"].as_u64().unwrap();
    let floor = 5 * file + 3 * view + (16 << 20);
    let budget = format!("{}M", (floor + sweeps / 2).div_ceil(1 << 20));
    let warned = |r: &serde_json::Value| {
        r["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w.as_str().unwrap().contains("for the far-field sweeps"))
    };
    let mut tight = inf.to_vec();
    tight.extend(["--max-memory", &budget]);
    let r = merge(&scans, &d.path().join("inf-tight"), &tight);
    assert!(warned(&r));
    // The union that `auto` runs at ∞ holds both views beside one step: it fits here...
    let united = |r: &serde_json::Value| {
        let scans = r["scans"].as_array().unwrap();
        scans.iter().all(|s| s["union_points"] == s["points"])
    };
    assert!(united(&r), "{}", r["warnings"]);
    // ...and not under a budget of one step alone, where the views are averaged instead.
    let mut tighter = inf.to_vec();
    let one_step = format!("{}M", floor.div_ceil(1 << 20));
    tighter.extend(["--max-memory", &one_step]);
    let r = merge(&scans, &d.path().join("inf-tighter"), &tighter);
    let said = r["warnings"].as_array().unwrap().iter().any(|w| {
        let w = w.as_str().unwrap();
        w.contains("the union") && w.contains("averaged instead")
    });
    assert!(said, "{}", r["warnings"]);
    let scans_r = r["scans"].as_array().unwrap();
    assert!(scans_r.iter().all(|s| s["union_points"] == 0));
    let r = merge(
        &scans,
        &d.path().join("near-tight"),
        &["--max-memory", &budget],
    );
    assert!(!warned(&r), "{}", r["warnings"]);
}

/// A damaged summary in the work directory is written again by the next run (it does not
/// stop every later merge), and the outputs are the same as before.
#[test]
fn a_damaged_summary_is_prepared_again() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("site"), 2, 120, 60);
    let out = d.path().join("out");
    merge(&scans, &out, &[]);
    let before = outputs(&out);
    let sum = out.join("work/station_000.summary.json");
    assert!(sum.is_file(), "no summary at {}", sum.display());
    std::fs::write(&sum, "zzz").unwrap();
    let r = merge(&scans, &out, &[]);
    assert_eq!(products(&r), (1, 1), "{}", r["products"]);
    assert_eq!(outputs(&out), before);
    assert!(serde_json::from_slice::<serde_json::Value>(&std::fs::read(&sum).unwrap()).is_ok());
}

/// A run killed while writing its outputs leaves them beside a list of what it was writing
/// and no report: the rerun replaces them without `--force`, and a finished run's outputs
/// are protected again.
#[test]
fn a_run_killed_while_writing_is_rerun_without_force() {
    let d = tempfile::tempdir().unwrap();
    let scans = synth_room(&d.path().join("site"), 2, 120, 60);
    let out = d.path().join("out");
    merge(&scans, &out, &[]);
    let before = outputs(&out);
    let marker = out.join(".mvao-unfinished");
    assert!(!marker.exists(), "a finished run left its marker");
    let run = |force: bool| {
        let mut a = vec!["merge", "-q", "--no-preview", "--radius", "0.2", "-o"];
        a.push(out.to_str().unwrap());
        if force {
            a.push("--force");
        }
        a.extend(scans.iter().map(|p| p.to_str().unwrap()));
        mvao(&a)
    };
    assert!(
        !run(false).status.success(),
        "finished outputs were replaced without --force"
    );
    // The state a kill leaves after the first output: the marker, no report.
    std::fs::remove_file(out.join("report.json")).unwrap();
    std::fs::remove_file(out.join("station_001.mvao.ply")).unwrap();
    std::fs::write(
        &marker,
        "station_000.mvao.ply\nstation_001.mvao.ply\nreport.json\n",
    )
    .unwrap();
    let r = run(false);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert_eq!(outputs(&out), before);
    assert!(out.join("report.json").is_file());
    assert!(!marker.exists());
}
