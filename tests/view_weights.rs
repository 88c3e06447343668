//! The spacing weight of the merge: on a colonnade scanned from three stations at different
//! distances, the paper's weights average coarse far views into sharp near ones and the merge
//! is worse than each scan's own SSAO; with the default spacing weight it is better. Scored
//! against rays cast at the exact mesh.

mod common;

use common::{mvao_ok, report, synth_site};

#[test]
fn sharp_views_outweigh_coarse_ones() {
    let tmp = tempfile::tempdir().unwrap();
    let site = tmp.path().join("colonnade");
    let files = synth_site(
        &site,
        "colonnade",
        3,
        360,
        180,
        &[
            "--no-normals",
            "--reference-rays",
            "64",
            "--reference-tmax",
            "0.4",
        ],
    );
    let truth = site.join("reference-mesh");
    let work = tmp.path().join("work");
    let run = |name: &str, extra: &[&str]| {
        let out = tmp.path().join(name);
        let (o, t, w) = (
            out.to_str().unwrap(),
            truth.to_str().unwrap(),
            work.to_str().unwrap(),
        );
        let mut args = vec![
            "merge",
            "-q",
            "--no-preview",
            "--radius",
            "0.2",
            "--tmax",
            "0.4",
            "--reference",
            t,
            "--work",
            w,
            "-o",
            o,
        ];
        args.extend_from_slice(extra);
        args.extend(files.iter().map(|f| f.to_str().unwrap()));
        mvao_ok(&args);
        report(&out)
    };
    let default = run("default", &[]);
    let paper = run("paper", &["--spacing-weight", "0"]);
    assert!((default["parameters"]["merge"]["spacing"].as_f64().unwrap() - 0.04).abs() < 1e-6);

    let e = |r: &serde_json::Value, part: &str| r["accuracy"][part]["e_a"].as_f64().unwrap();
    let single = e(&default, "ssao");
    assert_eq!(single, e(&paper, "ssao"), "the same SSAO under both");
    let (weighted, plain) = (e(&default, "result"), e(&paper, "result"));
    assert!(
        plain > single,
        "paper weights {plain} vs single view {single}"
    );
    assert!(
        weighted < single && weighted < 0.85 * plain,
        "spacing weight {weighted}, paper weights {plain}, single view {single}"
    );
}
