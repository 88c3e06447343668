//! Per-scan products on disk: exact round trips of prepared views, damage detection,
//! freshness of the manifest and recovery from interrupted runs.

mod common;

use glam::{DVec3, Vec3};
use mvao::synth::{scan_scene, Scene, Station};
use mvao::testing::pipeline::occlusion::prepare_view;
use mvao::testing::products::manifest::{self, write_entry, MVAO_VERSION};
use mvao::testing::products::{
    load_maps_for_merge, load_view, save_view, save_view_with, Check, InputRecord, Manifest,
    MapCompression, SaveOptions,
};
use mvao::testing::sensor::ProjectionChoice;
use mvao::testing::ssao::{Estimator, SsaoParams};
use mvao::testing::view::PreparedView;
use serde_json::json;
use std::fs::{self, File};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::{Duration, SystemTime};

fn params(seed: u64) -> SsaoParams {
    SsaoParams {
        estimator: Estimator::Paper,
        radius: 0.2,
        tmax: 0.4,
        falloff: Default::default(),
        samples: 8,
        directions: 8,
        steps: 8,
        seed,
        blur: true,
        sampling: Default::default(),
    }
}

/// A terrestrial scan of the synthetic courtyard (native grid, equirect, open sky so some
/// pixels are empty).
fn yard_view(seed: u64) -> PreparedView {
    let st = Station::equirect(DVec3::new(0.3, -0.2, 1.4), 0.3, 240, 120);
    let scan = scan_scene(&Scene::courtyard(), &st, 0.002, 1, "yard");
    prepare_view(&scan, ProjectionChoice::Auto, &params(seed)).unwrap()
}

fn yard() -> &'static PreparedView {
    static V: OnceLock<PreparedView> = OnceLock::new();
    V.get_or_init(|| yard_view(0))
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn bits3(v: &[Vec3]) -> Vec<[u32; 3]> {
    v.iter()
        .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
        .collect()
}

/// Every field, compared bit for bit.
fn assert_identical(a: &PreparedView, b: &PreparedView) {
    assert_eq!(a.sensor.projection, b.sensor.projection);
    assert_eq!(
        format!("{:?}", a.sensor.projection),
        format!("{:?}", b.sensor.projection)
    );
    assert_eq!(a.sensor.grid_pixels, b.sensor.grid_pixels);
    assert_eq!(
        a.sensor.fit_rms_px.map(f64::to_bits),
        b.sensor.fit_rms_px.map(f64::to_bits)
    );
    assert_eq!(a.sensor.reason, b.sensor.reason);
    let (g, h) = (&a.gbuf, &b.gbuf);
    assert_eq!((g.width, g.height), (h.width, h.height));
    assert_eq!(g.point, h.point);
    assert_eq!(bits(&g.depth), bits(&h.depth));
    assert_eq!(bits3(&g.position), bits3(&h.position));
    assert_eq!(bits3(&g.normal), bits3(&h.normal));
    assert_eq!(bits(&g.radius), bits(&h.radius));
    assert_eq!(bits(&a.ssao.ao), bits(&b.ssao.ao));
    assert_eq!(a.ssao.no_sample, b.ssao.no_sample);
    assert_eq!(bits(&a.border), bits(&b.border));
    assert_eq!(bits(&a.radii), bits(&b.radii));
    assert_eq!(a.pixel, b.pixel);
    assert_eq!(bits(&a.depth), bits(&b.depth));
    assert_eq!(a.normals_note, b.normals_note);
    let t = |v: &PreparedView| -> Vec<(String, u64)> {
        v.times
            .iter()
            .map(|(n, s)| (n.to_string(), s.to_bits()))
            .collect()
    };
    assert_eq!(t(a), t(b));
}

fn input_file(dir: &Path, name: &str, content: &[u8]) -> PathBuf {
    let p = dir.join(name);
    fs::write(&p, content).unwrap();
    p
}

/// Sets a file's mtime (to make it look old, or to put it back after an edit).
fn set_mtime(p: &Path, t: SystemTime) {
    File::options()
        .write(true)
        .open(p)
        .unwrap()
        .set_modified(t)
        .unwrap();
}

fn save_and_record(dir: &Path, key: &str, v: &PreparedView, input: &Path, prm: &serde_json::Value) {
    let rec = InputRecord::capture(input).unwrap();
    let files = save_view(dir, key, v).unwrap();
    let mut m = Manifest::load(dir);
    m.record(key, &[rec], prm, &files).unwrap();
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn synthetic_view_round_trips_bit_for_bit() {
    let v = yard();
    assert!(v.sensor.grid_pixels.is_some());
    assert!(
        v.gbuf.point.contains(&mvao::testing::gbuffer::EMPTY),
        "some pixels are empty"
    );
    let dir = tempfile::tempdir().unwrap();
    let input = input_file(dir.path(), "yard.ply", b"yard scan stand-in");
    for comp in [MapCompression::None, MapCompression::Zip] {
        let w = dir.path().join(format!("{comp:?}"));
        let rec = InputRecord::capture(&input).unwrap();
        let files = save_view_with(&w, "yard", v, &SaveOptions { compression: comp }).unwrap();
        // Not visible before the entry is recorded.
        assert!(load_view(&w, "yard").is_err());
        let mut m = Manifest::load(&w);
        m.record("yard", &[rec], &json!({"seed": 0}), &files)
            .unwrap();
        let back = load_view(&w, "yard").unwrap();
        assert_identical(v, &back);
        let mm = load_maps_for_merge(&w, "yard").unwrap();
        assert_eq!(mm.projection, v.sensor.projection);
        assert_eq!(mm.gbuf.point, v.gbuf.point);
        assert_eq!(bits3(&mm.gbuf.position), bits3(&v.gbuf.position));
        assert_eq!(bits(&mm.ao), bits(&v.ssao.ao));
        assert_eq!(bits(&mm.border), bits(&v.border));
        assert_eq!(mm.points, v.radii.len() as u64);
        // A generic EXR reader sees named channels.
        let img = exr::prelude::read_all_flat_layers_from_file(w.join(&files.maps.name)).unwrap();
        let mut ch: Vec<String> = img.layer_data[0]
            .channel_data
            .list
            .iter()
            .map(|c| c.name.to_string())
            .collect();
        ch.sort();
        assert_eq!(
            ch,
            [
                "N.X",
                "N.Y",
                "N.Z",
                "P.X",
                "P.Y",
                "P.Z",
                "border",
                "depth",
                "index",
                "no_sample",
                "radius",
                "ssao"
            ]
        );
    }
}

#[test]
fn bunny_scan_round_trips_bit_for_bit() {
    // A real Cyberware scan: native grid fitted by the orthographic model.
    let (scan, _) =
        mvao::io::ply::scan::read_scan(&common::fixture("stanford-bunny/bun045.ply")).unwrap();
    let v = prepare_view(&scan, ProjectionChoice::Auto, &params(3)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let input = common::fixture("stanford-bunny/bun045.ply");
    save_and_record(dir.path(), "bun045", &v, &input, &json!({"seed": 3}));
    assert_identical(&v, &load_view(dir.path(), "bun045").unwrap());
    let m = Manifest::load(dir.path());
    assert!(m.is_fresh("bun045", &[&input], &json!({"seed": 3})));
}

#[test]
fn damaged_products_are_errors_and_not_fresh() {
    let v = yard();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let input = input_file(d, "in.ply", b"input");
    let prm = json!({"seed": 0});
    save_and_record(d, "k", v, &input, &prm);
    let e = Manifest::load(d).entry("k").unwrap().clone();
    let maps = d.join(&e.products.maps.name);
    let pts = d.join(&e.products.points.name);
    let good_maps = fs::read(&maps).unwrap();
    let good_pts = fs::read(&pts).unwrap();
    let entry_file = manifest::entry_path(d, "k");
    let good_entry_file = fs::read(&entry_file).unwrap();
    // A failed load drops the entry: restoring puts it back too.
    let restore = || {
        fs::write(&maps, &good_maps).unwrap();
        fs::write(&pts, &good_pts).unwrap();
        fs::write(&entry_file, &good_entry_file).unwrap();
    };

    // One flipped bit in the middle of the maps.
    let mut b = good_maps.clone();
    let mid = b.len() / 2;
    b[mid] ^= 0x10;
    fs::write(&maps, &b).unwrap();
    let err = load_view(d, "k").unwrap_err().to_string();
    assert!(
        err.contains("checksum") && err.contains("run again"),
        "{err}"
    );
    assert!(load_maps_for_merge(d, "k").is_err());
    // The damaged product's entry is gone: the next run recomputes instead of failing again.
    assert!(!Manifest::load(d).is_fresh("k", &[&input], &prm));
    restore();

    // Truncated products: errors, and the quick check already sees the size.
    fs::write(&maps, &good_maps[..good_maps.len() - 100]).unwrap();
    assert!(load_view(d, "k").is_err());
    assert!(!Manifest::load(d).is_fresh("k", &[&input], &prm));
    restore();
    fs::write(&pts, &good_pts[..good_pts.len() / 2]).unwrap();
    let err = load_view(d, "k").unwrap_err().to_string();
    assert!(err.contains("truncated"), "{err}");
    restore();
    fs::remove_file(&pts).unwrap();
    assert!(load_view(d, "k").is_err());
    assert!(!Manifest::load(d).is_fresh("k", &[&input], &prm));
    restore();
    assert_identical(v, &load_view(d, "k").unwrap());
    assert!(Manifest::load(d).is_fresh("k", &[&input], &prm));

    // A damaged entry: ignored with a warning, not fresh, load is an error.
    let ep = manifest::entry_path(d, "k");
    let good_entry = fs::read_to_string(&ep).unwrap();
    let reason = e.products.view.reason.clone();
    fs::write(&ep, good_entry.replacen(&reason, &format!("{reason}!"), 1)).unwrap();
    let m = Manifest::load(d);
    assert!(
        m.warnings.iter().any(|w| w.contains("checksum")),
        "{:?}",
        m.warnings
    );
    assert!(!m.is_fresh("k", &[&input], &prm));
    assert!(load_view(d, "k").is_err());
    fs::write(&ep, &good_entry[..good_entry.len() / 2]).unwrap();
    let m = Manifest::load(d);
    assert_eq!(m.warnings.len(), 1);
    assert!(m.entry("k").is_none());
    fs::write(&ep, &good_entry).unwrap();

    // Another mvao version (a valid entry otherwise): not fresh, not loadable.
    let mut old = e.clone();
    old.mvao_version = "0.0.1-old".into();
    write_entry(d, &old).unwrap();
    let m = Manifest::load(d);
    assert!(m.warnings.is_empty());
    let why = m.why_stale("k", &[&input], &prm, Check::Quick).unwrap();
    assert!(
        why.contains("0.0.1-old") && why.contains(MVAO_VERSION),
        "{why}"
    );
    assert!(load_view(d, "k").is_err());
    // The same version built from other sources (an estimator changed, the version not).
    old.mvao_version = format!("{}+000000000000", env!("CARGO_PKG_VERSION"));
    assert_ne!(old.mvao_version, MVAO_VERSION);
    write_entry(d, &old).unwrap();
    let m = Manifest::load(d);
    assert!(!m.is_fresh("k", &[&input], &prm));
    assert!(load_view(d, "k").is_err());
    let mut other = e.clone();
    other.format += 1;
    write_entry(d, &other).unwrap();
    assert!(!Manifest::load(d).is_fresh("k", &[&input], &prm));
    assert!(load_view(d, "k").is_err());
}

#[test]
fn freshness_follows_inputs_and_parameters() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let w = d.join("work");
    let v = yard();
    let old = SystemTime::now() - Duration::from_secs(3600);
    let inputs: Vec<PathBuf> = ["a", "b", "c"]
        .iter()
        .map(|k| {
            let p = input_file(d, &format!("{k}.ply"), format!("scan {k} v1").as_bytes());
            set_mtime(&p, old);
            p
        })
        .collect();
    let prm = |k: &str, radius: f64| json!({"key": k, "ssao": {"radius": radius, "samples": 8}});
    for (k, p) in ["a", "b", "c"].iter().zip(&inputs) {
        save_and_record(&w, k, v, p, &prm(k, 0.2));
    }
    let m = Manifest::load(&w);
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    assert_eq!(m.keys().collect::<Vec<_>>(), ["a", "b", "c"]);
    for (k, p) in ["a", "b", "c"].iter().zip(&inputs) {
        assert!(m.is_fresh(k, &[p], &prm(k, 0.2)), "{k}");
        assert!(m.why_stale(k, &[p], &prm(k, 0.2), Check::Content).is_none());
    }
    // Key order inside the parameters does not matter.
    let reordered: serde_json::Value =
        serde_json::from_str(r#"{"ssao": {"samples": 8, "radius": 0.2}, "key": "a"}"#).unwrap();
    assert!(m.is_fresh("a", &[&inputs[0]], &reordered));
    // Other inputs or none: not fresh.
    assert!(!m.is_fresh("a", &[&inputs[1]], &prm("a", 0.2)));
    assert!(!m.is_fresh("a", &[] as &[PathBuf], &prm("a", 0.2)));
    assert!(!m.is_fresh("zzz", &[&inputs[0]], &prm("a", 0.2)));

    // A changed parameter: exactly that key is stale.
    assert!(!m.is_fresh("b", &[&inputs[1]], &prm("b", 0.3)));
    assert!(m.is_fresh("a", &[&inputs[0]], &prm("a", 0.2)));
    assert!(m.is_fresh("c", &[&inputs[2]], &prm("c", 0.2)));

    // Touched but unchanged: still fresh (the content is hashed again).
    set_mtime(&inputs[0], SystemTime::now());
    assert!(m.is_fresh("a", &[&inputs[0]], &prm("a", 0.2)));

    // Same size, new content, a new mtime: stale; the others are not affected.
    fs::write(&inputs[2], b"scan c v2").unwrap();
    let why = m
        .why_stale("c", &[&inputs[2]], &prm("c", 0.2), Check::Quick)
        .unwrap();
    assert!(why.contains("content changed"), "{why}");
    assert!(m.is_fresh("b", &[&inputs[1]], &prm("b", 0.2)));
    // Different size.
    fs::write(&inputs[2], b"scan c version 3").unwrap();
    assert!(!m.is_fresh("c", &[&inputs[2]], &prm("c", 0.2)));

    // A content change that keeps size, mtime and inode: the quick check cannot see it
    // (documented); the content check does.
    let ino_mtime = fs::metadata(&inputs[1]).unwrap().modified().unwrap();
    {
        use std::io::{Seek, SeekFrom, Write};
        let mut f = File::options().write(true).open(&inputs[1]).unwrap();
        f.seek(SeekFrom::Start(0)).unwrap();
        f.write_all(b"S").unwrap();
    }
    set_mtime(&inputs[1], ino_mtime);
    assert!(m.is_fresh("b", &[&inputs[1]], &prm("b", 0.2)));
    assert!(m
        .why_stale("b", &[&inputs[1]], &prm("b", 0.2), Check::Content)
        .is_some());
}

#[test]
fn recent_inputs_are_always_hashed() {
    // An input written just before it was hashed is "racy": its mtime may not move on a
    // quick rewrite, so its content is checked every time.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let input = input_file(d, "new.ply", b"fresh content A");
    let prm = json!({});
    save_and_record(&d.join("w"), "k", yard(), &input, &prm);
    let m = Manifest::load(&d.join("w"));
    assert!(m.is_fresh("k", &[&input], &prm));
    let t = fs::metadata(&input).unwrap().modified().unwrap();
    fs::write(&input, b"fresh content B").unwrap();
    set_mtime(&input, t);
    assert!(!m.is_fresh("k", &[&input], &prm));
}

#[test]
fn interrupted_runs_leave_a_consistent_state() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let w = d.join("work");
    let input = input_file(d, "s.ply", b"scan");
    let prm0 = json!({"seed": 0});

    // Crash before the first entry: products written, no entry, a temp file left behind by
    // a writer that died (pid beyond any real one) long ago, another one just now.
    let v0 = yard();
    let files0 = save_view(&w, "s", v0).unwrap();
    let dead_old = w.join(format!(".{}.tmp-4000000000", files0.maps.name));
    let dead_new = w.join(".s.manifest.json.tmp-4000000001");
    fs::write(&dead_old, b"partial").unwrap();
    fs::write(&dead_new, b"partial").unwrap();
    set_mtime(&dead_old, SystemTime::now() - Duration::from_secs(3600));
    let m = Manifest::load(&w);
    assert!(!m.is_fresh("s", &[&input], &prm0));
    assert!(load_view(&w, "s").is_err());
    assert_eq!(m.cleaned, vec![dead_old.clone()]);
    assert!(!dead_old.exists());
    // A temp file of a writer that may still be at work is left alone.
    assert!(dead_new.exists());
    fs::remove_file(&dead_new).unwrap();

    // The rerun records; the crashed run's identical products are reused by name.
    save_and_record(&w, "s", v0, &input, &prm0);
    let m = Manifest::load(&w);
    assert!(m.is_fresh("s", &[&input], &prm0));
    let before = names(&w);
    assert_eq!(before.len(), 3, "{before:?}");

    // New parameters; the new products are written, then the run dies before the entry:
    // the old entry and its products are intact and still load.
    let v1 = yard_view(7);
    let prm1 = json!({"seed": 7});
    let files1 = save_view(&w, "s", &v1).unwrap();
    assert_ne!(files1.maps.name, files0.maps.name);
    assert_identical(v0, &load_view(&w, "s").unwrap());
    let m = Manifest::load(&w);
    assert!(m.is_fresh("s", &[&input], &prm0));
    assert!(!m.is_fresh("s", &[&input], &prm1));

    // The rerun with the new parameters commits and removes the old products.
    let mut m = Manifest::load(&w);
    m.record(
        "s",
        &[InputRecord::capture(&input).unwrap()],
        &prm1,
        &files1,
    )
    .unwrap();
    assert_identical(&v1, &load_view(&w, "s").unwrap());
    let after = names(&w);
    assert_eq!(after.len(), 3, "{after:?}");
    assert!(!after.contains(&files0.maps.name));
    // The seed changes only the SSAO: the per-point file is the same one, kept.
    assert_eq!(files0.points.name, files1.points.name);
    assert!(Manifest::load(&w).is_fresh("s", &[&input], &prm1));

    // The index snapshot lists the entry; removing the key removes everything of it.
    m.save().unwrap();
    let index: serde_json::Value =
        serde_json::from_slice(&fs::read(w.join("manifest.json")).unwrap()).unwrap();
    assert!(index["entries"]["s"]["products"]["maps"]["name"] == files1.maps.name.as_str());
    m.remove("s").unwrap();
    assert_eq!(names(&w), ["manifest.json"]);
    assert!(!Manifest::load(&w).is_fresh("s", &[&input], &prm1));
}

#[test]
fn a_missing_work_directory_is_empty_and_bad_keys_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let m = Manifest::load(&dir.path().join("nothing here"));
    assert_eq!(m.keys().count(), 0);
    assert!(m.warnings.is_empty());
    assert!(save_view(dir.path(), "../x", yard()).is_err());
    assert!(save_view(dir.path(), ".x", yard()).is_err());
    assert!(load_view(dir.path(), "x").is_err());
}

#[test]
fn inconsistent_views_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut v = yard().clone();
    v.border.pop();
    let err = save_view(dir.path(), "x", &v).unwrap_err().to_string();
    assert!(err.contains("border"), "{err}");
    let mut v = yard().clone();
    v.sensor.fit_rms_px = Some(f64::NAN);
    assert!(save_view(dir.path(), "x", &v).is_err());
}

#[test]
fn warps_round_trip_and_bad_ones_are_refused() {
    use mvao::testing::projection::Warp;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut v = yard().clone();
    let p = &mut v.sensor.projection;
    let kx: Vec<f32> = (0..p.width).map(|i| i as f32 * 1.01 + 0.1 / 3.0).collect();
    let ky: Vec<f32> = (0..p.height).map(|i| (i as f32).powf(1.1)).collect();
    p.warp_x = Warp::new(kx);
    p.warp_y = Warp::new(ky);
    assert!(p.warp_x.is_some() && p.warp_y.is_some());
    let input = input_file(d, "in.ply", b"x");
    save_and_record(&d.join("w"), "w", &v, &input, &json!(null));
    assert_identical(&v, &load_view(&d.join("w"), "w").unwrap());

    // An entry (with a valid checksum) whose knots do not increase is refused, not used.
    let mut e = Manifest::load(&d.join("w")).entry("w").unwrap().clone();
    let mut pj = serde_json::to_value(&e.products.view.projection).unwrap();
    pj["warp_x"]["knots"] = json!([0.0, 2.0, 1.0]);
    e.products.view.projection = serde_json::from_value(pj).unwrap();
    write_entry(&d.join("w"), &e).unwrap();
    let err = load_view(&d.join("w"), "w").unwrap_err().to_string();
    assert!(err.contains("warp"), "{err}");
    assert!(load_maps_for_merge(&d.join("w"), "w").is_err());
}
