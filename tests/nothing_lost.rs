//! Nothing is lost: inputs are never modified or overwritten (even when the output directory
//! is the input directory), outputs are not clobbered without `--force`, and a run that fails
//! for lack of space or a bad output path says which path and leaves no complete-looking file.

mod common;

use common::*;
use std::path::Path;

fn copy_scans(dst: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for p in plys("3dtk-uos-3scans") {
        let d = dst.join(p.file_name().unwrap());
        std::fs::copy(&p, &d).unwrap();
        out.push(d);
    }
    std::fs::copy(
        fixture("3dtk-uos-3scans/alignment.mlp"),
        dst.join("alignment.mlp"),
    )
    .unwrap();
    out
}

#[test]
fn output_into_the_input_directory_keeps_inputs() {
    let d = tempfile::tempdir().unwrap();
    let scans = copy_scans(d.path());
    let before: Vec<Vec<u8>> = scans.iter().map(|p| std::fs::read(p).unwrap()).collect();
    let mut args = vec![
        "merge".to_string(),
        "-q".into(),
        "-o".into(),
        d.path().display().to_string(),
    ];
    args.extend(scans.iter().map(|p| p.display().to_string()));
    let a: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
    let r = mvao(&a);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    for (p, b) in scans.iter().zip(&before) {
        assert_eq!(&std::fs::read(p).unwrap(), b, "{} modified", p.display());
        let stem = p.file_stem().unwrap().to_string_lossy();
        assert!(d.path().join(format!("{stem}.mvao.ply")).exists());
    }
    // The report in the scan directory is not mistaken for an alignment on the next run, and
    // the existing outputs stop it without --force.
    let r = mvao(&a);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2));
    assert!(err.contains("--force"), "{err}");
}

#[test]
fn an_output_that_would_overwrite_an_input_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let scans = copy_scans(d.path());
    // An input named like the output another input would write.
    let victim = d.path().join("scan000.mvao.ply");
    std::fs::copy(&scans[1], &victim).unwrap();
    let before = std::fs::read(&victim).unwrap();
    let r = mvao(&[
        "merge",
        "-q",
        "--force",
        "--align",
        &fixture("3dtk-uos-3scans/json/alignment.json")
            .display()
            .to_string(),
        "-o",
        &d.path().display().to_string(),
        &scans[0].display().to_string(),
        &scans[1].display().to_string(),
        &scans[2].display().to_string(),
        &victim.display().to_string(),
    ]);
    assert_eq!(r.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&r.stderr).contains("overwrite an input"));
    assert_eq!(std::fs::read(&victim).unwrap(), before);
}

#[test]
fn bad_output_path_is_named() {
    let d = tempfile::tempdir().unwrap();
    let scans = copy_scans(d.path());
    let file = d.path().join("not-a-dir");
    std::fs::write(&file, b"x").unwrap();
    let out = file.join("out");
    let mut args = vec![
        "merge".to_string(),
        "-q".into(),
        "-o".into(),
        out.display().to_string(),
    ];
    args.extend(scans.iter().map(|p| p.display().to_string()));
    let a: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
    let r = mvao(&a);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("not-a-dir"), "{err}");
    assert!(!err.contains("panicked"));
}

/// Needs a small filesystem; mounts a 64 KiB tmpfs when the machine allows it (root, mount
/// permitted) and says why it is skipped otherwise.
#[test]
fn disk_full_is_reported_with_the_path_and_leaves_nothing_complete() {
    let d = tempfile::tempdir().unwrap();
    let scans = copy_scans(d.path());
    let mnt = d.path().join("small");
    std::fs::create_dir(&mnt).unwrap();
    let ok = std::process::Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=64k", "tmpfs"])
        .arg(&mnt)
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok {
        eprintln!("skipped: cannot mount a small tmpfs here (needs root and mount permission)");
        return;
    }
    let mut args = vec![
        "merge".to_string(),
        "-q".into(),
        "-o".into(),
        mnt.display().to_string(),
    ];
    args.extend(scans.iter().map(|p| p.display().to_string()));
    let a: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
    let r = mvao(&a);
    let listing: Vec<String> = std::fs::read_dir(&mnt)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    let _ = std::process::Command::new("umount").arg(&mnt).status();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains(&mnt.display().to_string()), "{err}");
    assert!(err.to_lowercase().contains("space"), "{err}");
    // Only whole files (the 64 KiB cannot hold one 1.6 MB result) and no temporary leftovers.
    assert!(listing.iter().all(|n| !n.starts_with('.')), "{listing:?}");
    assert!(
        !listing.iter().any(|n| n.ends_with(".mvao.ply")),
        "{listing:?}"
    );
}
