//! `scripts/Snakefile` run by Snakemake on a small site: per-scan `prepare` and `merge
//! --only` jobs give byte-identical results to one `mvao merge`. Skipped, with the reason
//! printed, when snakemake is not installed (set `SNAKEMAKE` to its path).

#[test]
fn snakefile_jobs_match_one_merge() {
    let snakemake = std::env::var("SNAKEMAKE").unwrap_or_else(|_| "snakemake".into());
    let found = std::process::Command::new(&snakemake)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !found {
        eprintln!("skipped: snakemake not found (pip install snakemake, or set SNAKEMAKE)");
        return;
    }
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/test_snakefile.sh");
    let out = std::process::Command::new("bash")
        .arg(script)
        .arg(env!("CARGO_BIN_EXE_mvao"))
        .env("SNAKEMAKE", &snakemake)
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("identical to one merge"), "{text}");
}
