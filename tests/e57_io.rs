//! E57 input and output: the real libE57 "pumpA" scan, multi-scan files with known poses and
//! grids written by the crate's own writer, the result round trip, cross-format tables, and
//! truncated or corrupt files (clean errors, never a panic).

use e57::RecordName;
use glam::{DMat4, DQuat, DVec3};
use mvao::io::e57::*;
use mvao::io::output::{grey, ColorMode};
use mvao::io::raw::{PointTable, RawGrid};
use mvao::Error;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

fn pump() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/libe57-pumpA/pumpAVisualReferenceImage.e57")
}

fn ao_name() -> RecordName {
    RecordName::Unknown {
        namespace: MVAO_NAMESPACE.into(),
        name: AO_ATTRIBUTE.into(),
    }
}

fn finite(p: &[f64; 3]) -> bool {
    p.iter().all(|v| v.is_finite())
}

/// Pearson correlation.
fn corr(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    sab / (saa * sbb).sqrt()
}

#[test]
fn pump_fixture() {
    let inp = E57Input::from_path(&pump()).unwrap();
    assert_eq!(inp.scans.len(), 1);
    let s = &inp.scans[0];
    assert_eq!(s.name, "pumpA");
    assert_eq!(s.len(), 155_201);
    assert_eq!(s.invalid, 0);
    // The file has no pose element: identity, and the scanner is left to the caller.
    assert!(!s.has_pose);
    assert_eq!(s.pose, DMat4::IDENTITY);
    let raw = inp.raw_scans();
    assert_eq!(raw.len(), 1);
    assert_eq!(raw[0].pose, Some(DMat4::IDENTITY));
    assert_eq!(raw[0].scanner, None);
    assert_eq!(raw[0].xyz.len(), 155_201);

    // Ranges from the scanner at the origin.
    let r: Vec<f64> = s.xyz.iter().map(|p| DVec3::from(*p).length()).collect();
    let (rmin, rmax) = r
        .iter()
        .fold((f64::MAX, f64::MIN), |m, &v| (m.0.min(v), m.1.max(v)));
    assert!((1.98..1.99).contains(&rmin), "{rmin}");
    assert!((5.42..5.44).contains(&rmax), "{rmax}");

    // Grid: 1074 rows (elevation) × 345 columns (azimuth).
    let g = s.grid.as_ref().unwrap();
    assert_eq!((g.rows, g.cols), (1074, 345));
    assert_eq!(*g.row.iter().max().unwrap(), 1073);
    assert_eq!(*g.col.iter().max().unwrap(), 344);
    let el: Vec<f64> = s
        .xyz
        .iter()
        .map(|p| (p[2] / DVec3::from(*p).length()).asin())
        .collect();
    let az: Vec<f64> = s.xyz.iter().map(|p| p[1].atan2(p[0])).collect();
    let rows: Vec<f64> = g.row.iter().map(|&v| v as f64).collect();
    let cols: Vec<f64> = g.col.iter().map(|&v| v as f64).collect();
    assert!(corr(&rows, &el) > 0.9999, "row ~ elevation");
    assert!(corr(&cols, &az) < -0.9999, "column ~ -azimuth");

    // Intensity 0.38–0.70 (scaled integers, limits 0–1), colour present.
    let i = s.intensity.as_ref().unwrap();
    let (imin, imax) = i
        .iter()
        .fold((f32::MAX, f32::MIN), |m, &v| (m.0.min(v), m.1.max(v)));
    assert!(
        (0.38..0.39).contains(&imin) && (0.69..0.70).contains(&imax),
        "{imin} {imax}"
    );
    let rgb = s.rgb.as_ref().unwrap();
    assert_eq!(rgb.len(), 155_201);
    assert!(rgb.iter().any(|c| c[0] != c[1]), "real colours, not grey");
    assert_eq!(rgb[0], [51, 65, 49]);
}

/// A synthetic station: an equirect grid over a wavy room-sized surface, some cells invalid.
fn station(name: &str, pose: Option<DMat4>, rows: u32, cols: u32, spherical: bool) -> E57ScanOut {
    let (mut xyz, mut row, mut col, mut inten, mut rgb) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for c in 0..cols {
        for r in 0..rows {
            let az = -PI + (c as f64 + 0.5) * 2.0 * PI / cols as f64;
            let el = -PI / 3.0 + (r as f64 + 0.5) * (2.0 * PI / 3.0) / rows as f64;
            let range = 3.0 + 0.5 * (3.0 * az).sin() + 0.3 * el;
            let p = if (r * 7 + c * 3) % 23 == 0 {
                [f64::NAN; 3]
            } else {
                [
                    range * el.cos() * az.cos(),
                    range * el.cos() * az.sin(),
                    range * el.sin(),
                ]
            };
            xyz.push(p);
            row.push(r);
            col.push(c);
            inten.push(((r + c) % 100) as f32 / 99.0);
            rgb.push([(r * 5 % 256) as u8, (c * 3 % 256) as u8, 77]);
        }
    }
    E57ScanOut {
        name: name.into(),
        pose,
        xyz,
        grid: Some(RawGrid {
            rows,
            cols,
            row,
            col,
        }),
        intensity: Some(inten),
        rgb: Some(rgb),
        spherical,
    }
}

fn three_poses() -> [DMat4; 3] {
    [
        DMat4::from_rotation_translation(
            DQuat::from_rotation_z(30f64.to_radians()),
            DVec3::new(1_000_000.125, -250_000.5, 312.75),
        ),
        DMat4::from_rotation_translation(
            DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 1.1),
            DVec3::new(-12.5, 7.25, 0.5),
        ),
        DMat4::from_translation(DVec3::new(999_999.999, 0.0, -3.0)),
    ]
}

fn three_stations() -> Vec<E57ScanOut> {
    let p = three_poses();
    vec![
        station("north", Some(p[0]), 40, 90, false),
        station("court yard", Some(p[1]), 30, 60, true),
        station("north", Some(p[2]), 20, 50, false),
    ]
}

#[test]
fn multi_scan_file_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("site.e57");
    let st = three_stations();
    write_e57_scans(&st, &f).unwrap();
    let inp = E57Input::from_path(&f).unwrap();
    assert_eq!(inp.scans.len(), 3);
    // Duplicate stored names are made unique; spaces are kept.
    let names: Vec<&str> = inp.scans.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["north", "court yard", "north_1"]);
    assert_eq!(inp.scans[2].descriptor.name.as_deref(), Some("north"));
    let raw = inp.raw_scans();
    for ((s, r), want) in inp.scans.iter().zip(&raw).zip(&st) {
        let n = want.xyz.len();
        assert_eq!(s.len(), n);
        assert!(s.has_pose);
        assert!(s.pose.abs_diff_eq(want.pose.unwrap(), 1e-9), "{}", s.name);
        assert_eq!(r.pose, Some(s.pose));
        assert_eq!(r.scanner, Some(DVec3::ZERO));
        assert_eq!(s.grid.as_ref(), want.grid.as_ref());
        assert_eq!(r.grid.as_ref(), want.grid.as_ref());
        let bad = want.xyz.iter().filter(|p| !finite(p)).count();
        assert!(bad > 0);
        assert_eq!(s.invalid, bad);
        for (a, b) in s.xyz.iter().zip(&want.xyz) {
            assert_eq!(finite(a), finite(b), "invalid records keep their slot");
            if finite(b) {
                let tol = if want.spherical { 1e-12 } else { 0.0 };
                for i in 0..3 {
                    assert!((a[i] - b[i]).abs() <= tol, "{a:?} {b:?}");
                }
            }
        }
        let i = s.intensity.as_ref().unwrap();
        for (a, b) in i.iter().zip(want.intensity.as_ref().unwrap()) {
            assert_eq!(a, b);
        }
        assert_eq!(s.rgb.as_ref(), want.rgb.as_ref());
    }
    // The spherical station stores range/azimuth/elevation, no Cartesian records.
    let proto = &inp.scans[1].descriptor.prototype;
    assert!(proto.iter().any(|r| r.name == RecordName::SphericalRange));
    assert!(!proto.iter().any(|r| r.name == RecordName::CartesianX));
}

#[test]
fn poses_required_for_several_scans() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("loose.e57");
    let st = vec![
        station("a", None, 5, 8, false),
        station("b", None, 5, 8, false),
    ];
    write_e57_scans(&st, &f).unwrap();
    let e = E57Input::from_path(&f).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, Error::Format { .. }));
    assert!(msg.contains("loose.e57"), "{msg}");
    assert!(
        msg.contains("2 scans and none has a pose; the scans cannot be placed"),
        "{msg}"
    );
    // One given pose is enough; the missing one is identity and stays marked missing.
    let g = dir.path().join("half.e57");
    let st = vec![
        station("a", Some(three_poses()[1]), 5, 8, false),
        station("b", None, 5, 8, false),
    ];
    write_e57_scans(&st, &g).unwrap();
    let inp = E57Input::from_path(&g).unwrap();
    assert!(inp.scans[0].has_pose && !inp.scans[1].has_pose);
    assert_eq!(inp.scans[1].pose, DMat4::IDENTITY);
    assert!(inp.scans[1].descriptor.transform.is_none());
    let raw = inp.raw_scans();
    assert_eq!(raw[1].scanner, None);
    // A single scan without a pose is fine.
    let h = dir.path().join("one.e57");
    write_e57_scans(&[station("solo", None, 5, 8, false)], &h).unwrap();
    assert_eq!(E57Input::from_path(&h).unwrap().scans[0].name, "solo");
}

fn ao_pattern(n: usize, salt: usize) -> Vec<f32> {
    (0..n)
        .map(|k| ((k * 37 + salt) % 101) as f32 / 100.0)
        .collect()
}

#[test]
fn result_round_trip_pump() {
    let inp = E57Input::from_path(&pump()).unwrap();
    let s = &inp.scans[0];
    let n = s.len();
    let ao = vec![ao_pattern(n, 3)];
    let dir = tempfile::tempdir().unwrap();
    let gamma = 2.2;
    for mode in [ColorMode::Modulate, ColorMode::Replace, ColorMode::Keep] {
        let out = dir.path().join(format!("pump-{mode:?}.e57"));
        write_e57(&inp, &ao, &[], gamma, mode, &out).unwrap();
        let back = E57Input::from_path(&out).unwrap();
        let b = &back.scans[0];
        assert_eq!(b.name, "pumpA");
        assert_eq!(b.len(), n);
        assert_eq!(b.descriptor.transform.is_some(), s.has_pose);
        assert_eq!(b.pose, s.pose);
        // Every coordinate exactly (the stored scaled integers, now as doubles).
        assert_eq!(b.xyz, s.xyz);
        // Grid indices and intensity exactly as stored.
        assert_eq!(b.grid, s.grid);
        for name in [
            RecordName::Intensity,
            RecordName::RowIndex,
            RecordName::ColumnIndex,
        ] {
            assert_eq!(b.values(&name), s.values(&name), "{name:?}");
        }
        assert_eq!(b.intensity, s.intensity);
        // The intensity record keeps its scaled-integer type and its limits their meaning.
        let ip = b
            .descriptor
            .prototype
            .iter()
            .find(|r| r.name == RecordName::Intensity)
            .unwrap();
        assert!(matches!(
            ip.data_type,
            e57::RecordDataType::ScaledInteger { max: 32767, .. }
        ));
        // The AO comes back bit for bit.
        let got = b.values(&ao_name()).expect("mvao:ao");
        assert!(got.iter().zip(&ao[0]).all(|(g, a)| *g == *a as f64));
        // Colours by mode.
        let rgb = b.rgb.as_ref().unwrap();
        let orig = s.rgb.as_ref().unwrap();
        for k in (0..n).step_by(997) {
            let g = grey(ao[0][k], gamma);
            let want = match mode {
                ColorMode::Keep => orig[k],
                ColorMode::Replace => [g; 3],
                ColorMode::Modulate => orig[k].map(|c| (c as f32 * g as f32 / 255.0).round() as u8),
            };
            assert_eq!(rgb[k], want, "{mode:?} record {k}");
        }
        // Provenance and reproducibility.
        let og = b.descriptor.original_guids.as_ref().unwrap();
        assert_eq!(og, &vec![s.descriptor.guid.clone().unwrap()]);
        assert_ne!(b.descriptor.guid, s.descriptor.guid);
        assert!(back
            .extensions
            .iter()
            .any(|e| e.namespace == MVAO_NAMESPACE));
        let again = dir.path().join("again.e57");
        write_e57(&inp, &ao, &[], gamma, mode, &again).unwrap();
        assert_eq!(std::fs::read(&again).unwrap(), std::fs::read(&out).unwrap());
    }
    // Writing the result of a result replaces mvao:ao instead of adding a second one.
    let first = dir.path().join("pump-Modulate.e57");
    let r1 = E57Input::from_path(&first).unwrap();
    let ao2 = vec![ao_pattern(n, 50)];
    let second = dir.path().join("second.e57");
    write_e57(&r1, &ao2, &[], 1.0, ColorMode::Keep, &second).unwrap();
    let r2 = E57Input::from_path(&second).unwrap();
    let count = r2.scans[0]
        .descriptor
        .prototype
        .iter()
        .filter(|r| r.name == ao_name())
        .count();
    assert_eq!(count, 1);
    assert_eq!(r2.scans[0].values(&ao_name()).unwrap()[7], ao2[0][7] as f64);
    // Nothing but the outputs in the directory: every write was renamed into place.
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn result_round_trip_multi_scan_with_invalid_records() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("site.e57");
    write_e57_scans(&three_stations(), &f).unwrap();
    let inp = E57Input::from_path(&f).unwrap();
    let ao: Vec<Vec<f32>> = inp
        .scans
        .iter()
        .enumerate()
        .map(|(k, s)| ao_pattern(s.len(), k))
        .collect();
    let out = dir.path().join("site.mvao.e57");
    write_e57(&inp, &ao, &[], 1.0, ColorMode::Modulate, &out).unwrap();
    let back = E57Input::from_path(&out).unwrap();
    assert_eq!(back.scans.len(), 3);
    for ((a, b), want_ao) in inp.scans.iter().zip(&back.scans).zip(&ao) {
        assert_eq!(a.name, b.name);
        // The stored pose is written back as stored.
        let (ta, tb) = (
            a.descriptor.transform.as_ref().unwrap(),
            b.descriptor.transform.as_ref().unwrap(),
        );
        assert_eq!(
            (ta.rotation.w, ta.rotation.x, ta.rotation.y, ta.rotation.z),
            (tb.rotation.w, tb.rotation.x, tb.rotation.y, tb.rotation.z)
        );
        assert_eq!(
            (ta.translation.x, ta.translation.y, ta.translation.z),
            (tb.translation.x, tb.translation.y, tb.translation.z)
        );
        assert_eq!(a.pose, b.pose);
        assert_eq!(a.grid, b.grid);
        assert_eq!(a.invalid, b.invalid);
        for (p, q) in a.xyz.iter().zip(&b.xyz) {
            assert_eq!(finite(p), finite(q));
            if finite(p) {
                assert_eq!(p, q);
            }
        }
        // Invalid records are written flagged, in their slot.
        let state = b.values(&RecordName::CartesianInvalidState).unwrap();
        for (p, s) in a.xyz.iter().zip(&state) {
            assert_eq!(*s == 0.0, finite(p));
        }
        assert_eq!(b.intensity, a.intensity);
        let got = b.values(&ao_name()).unwrap();
        assert!(got.iter().zip(want_ao).all(|(g, w)| *g == *w as f64));
    }
    // The spherical station keeps its spherical records and gains Cartesian ones.
    let proto = &back.scans[1].descriptor.prototype;
    assert!(proto.iter().any(|r| r.name == RecordName::SphericalRange));
    assert!(proto.iter().any(|r| r.name == RecordName::CartesianX));
}

#[test]
fn bad_ao_is_refused_and_nothing_written() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("s.e57");
    write_e57_scans(&[station("a", None, 4, 6, false)], &f).unwrap();
    let inp = E57Input::from_path(&f).unwrap();
    let out = dir.path().join("out.e57");
    let mut ao = vec![vec![0.5f32; inp.scans[0].len()]];
    ao[0][3] = f32::NAN;
    assert!(write_e57(&inp, &ao, &[], 1.0, ColorMode::Keep, &out).is_err());
    assert!(write_e57(&inp, &[vec![0.5; 3]], &[], 1.0, ColorMode::Keep, &out).is_err());
    assert!(write_e57(&inp, &[], &[], 1.0, ColorMode::Keep, &out).is_err());
    assert!(!out.exists());
    // A missing directory: an I/O error naming the target, no temporary left behind.
    let missing = dir.path().join("no/such/dir/out.e57");
    let ao = vec![vec![0.5f32; inp.scans[0].len()]];
    let e = write_e57(&inp, &ao, &[], 1.0, ColorMode::Keep, &missing).unwrap_err();
    assert!(matches!(e, Error::Io { .. }), "{e}");
}

#[test]
fn tables_from_other_formats() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tables.e57");
    let p = three_poses();
    let mk = |name: &str, pose: DMat4, n: usize, grid: bool| {
        let xyz: Vec<[f64; 3]> = (0..n)
            .map(|k| {
                if k == 2 {
                    [f64::NAN; 3]
                } else {
                    [k as f64 * 0.5, 1.0 + k as f64, -2.0]
                }
            })
            .collect();
        PointTable {
            name: name.into(),
            xyz,
            pose,
            rgb: None,
            intensity: Some((0..n).map(|k| k as f32 / n as f32).collect()),
            ao: ao_pattern(n, 1),
            grid: grid.then(|| RawGrid {
                rows: 2,
                cols: n.div_ceil(2) as u32,
                row: (0..n as u32).map(|k| k % 2).collect(),
                col: (0..n as u32).map(|k| k / 2).collect(),
            }),
            extra: vec![
                (
                    "scalar field".into(),
                    (0..n).map(|k| k as f64 * 1.5).collect(),
                ),
                ("ao".into(), vec![f64::NAN; n]),
                ("normalX".into(), vec![0.0; n]),
                ("normalY".into(), vec![0.0; n]),
                ("normalZ".into(), (0..n).map(|k| 1.0 + k as f64).collect()),
            ],
        }
    };
    let tables = vec![mk("bun000", p[0], 10, true), mk("bun045", p[1], 7, false)];
    write_table_e57(&tables, &out).unwrap();
    let back = E57Input::from_path(&out).unwrap();
    assert_eq!(back.scans.len(), 2);
    for (t, s) in tables.iter().zip(&back.scans) {
        assert_eq!(s.name, t.name);
        assert!(s.pose.abs_diff_eq(t.pose, 1e-9));
        assert_eq!(s.len(), t.len());
        assert_eq!(s.invalid, 1);
        assert!(!finite(&s.xyz[2]));
        assert_eq!(s.xyz[3], t.xyz[3]);
        assert_eq!(s.grid, t.grid);
        let ao = s.values(&ao_name()).unwrap();
        assert!(ao.iter().zip(&t.ao).all(|(a, b)| *a == *b as f64));
        // Without colours in the table, the AO grey (gamma 1) is written.
        assert_eq!(s.rgb.as_ref().unwrap()[5], [grey(t.ao[5], 1.0); 3]);
        let extra = s
            .values(&RecordName::Unknown {
                namespace: MVAO_NAMESPACE.into(),
                name: "scalar_field".into(),
            })
            .unwrap();
        assert_eq!(extra[4], 6.0);
        // An extra field called "ao" does not clash with the AO; its NaNs became 0.
        let other = s
            .values(&RecordName::Unknown {
                namespace: MVAO_NAMESPACE.into(),
                name: "ao_1".into(),
            })
            .unwrap();
        assert!(other.iter().all(|v| *v == 0.0));
        // normalX/Y/Z attributes (any namespace) become unit normals.
        let nrm = s.normals.as_ref().unwrap();
        assert!(nrm.iter().all(|v| *v == glam::Vec3::Z));
        assert_eq!(nrm.len(), t.len());
    }
    assert_eq!(back.raw_scans()[1].normals.as_ref().unwrap().len(), 7);
    // A table of another E57 input round-trips its extras.
    let inp = E57Input::from_path(&out).unwrap();
    let t = inp
        .point_table(0, &ao_pattern(10, 9), 1.0, ColorMode::Keep)
        .unwrap();
    assert!(t.extra.iter().any(|(n, _)| n == "mvao:scalar_field"));
    assert!(!t.extra.iter().any(|(n, _)| n == "mvao:ao"));
    assert_eq!(t.pose, inp.scans[0].pose);
    // A table pose with scale is refused.
    let mut bad = tables.clone();
    bad[0].pose = DMat4::from_scale(DVec3::splat(2.0));
    let o2 = dir.path().join("bad.e57");
    assert!(write_table_e57(&bad, &o2).is_err());
    assert!(!o2.exists());
}

// --- truncated and corrupt files ---------------------------------------------------------

/// CRC-32C (Castagnoli), as E57 pages carry it (stored big-endian).
fn crc32c(data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in data {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0x82F6_3B78
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// Recomputes the checksum of every 1024-byte page, so a mutation reaches the decoder.
fn fix_crcs(bytes: &mut [u8]) {
    for page in bytes.chunks_mut(1024) {
        if page.len() == 1024 {
            let c = crc32c(&page[..1020]);
            page[1020..].copy_from_slice(&c.to_be_bytes());
        }
    }
}

fn expect_clean_error(bytes: &[u8], dir: &Path, tag: &str) -> String {
    let f = dir.join(format!("bad-{tag}.e57"));
    std::fs::write(&f, bytes).unwrap();
    let e = E57Input::from_path(&f).expect_err(tag);
    let msg = e.to_string();
    assert!(matches!(e, Error::Format { .. }), "{tag}: {msg}");
    assert!(msg.contains(&format!("bad-{tag}.e57")), "{tag}: {msg}");
    msg
}

#[test]
fn truncated_and_corrupt_files_are_clean_errors() {
    let dir = tempfile::tempdir().unwrap();
    let good = std::fs::read(pump()).unwrap();
    let len = good.len();
    for cut in [0, 10, 47, 48, 1024, 4096, len / 2, len - 1024, len - 1] {
        expect_clean_error(&good[..cut], dir.path(), &format!("cut{cut}"));
    }
    // A flipped byte in the point data: the page checksum fails, the message names the scan.
    let mut flipped = good.clone();
    flipped[200_000] ^= 0x55;
    let msg = expect_clean_error(&flipped, dir.path(), "flip");
    assert!(msg.contains("scan pumpA"), "{msg}");
    // A zero scale on a scaled-integer coordinate (same length, so the XML stays valid).
    let at = good
        .windows(31)
        .position(|w| w == b"scale=\"9.9999999999999995e-007\"")
        .expect("cartesianX scale in the fixture");
    let mut zero = good.clone();
    zero[at..at + 31].copy_from_slice(b"scale=\"0.0000000000000000e+000\"");
    fix_crcs(&mut zero);
    let msg = expect_clean_error(&zero, dir.path(), "scale0");
    assert!(
        msg.contains("cartesianX") && msg.contains("scale 0"),
        "{msg}"
    );
    // Not an E57 file at all.
    let msg = expect_clean_error(b"ply\nformat ascii 1.0\nend_header\n", dir.path(), "ply");
    assert!(msg.contains("not a readable E57 file"), "{msg}");
    // A missing file is an I/O error naming it.
    let e = E57Input::from_path(&dir.path().join("absent.e57")).unwrap_err();
    assert!(matches!(e, Error::Io { .. }) && e.to_string().contains("absent.e57"));
}

#[test]
fn mutated_files_with_valid_checksums_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    // A small gridded file with invalid records keeps the loop fast.
    let src = dir.path().join("small.e57");
    write_e57_scans(&[station("s", Some(three_poses()[1]), 12, 20, false)], &src).unwrap();
    let good = std::fs::read(&src).unwrap();
    let f = dir.path().join("m.e57");
    let mut x = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let (mut ok, mut err) = (0, 0);
    for _ in 0..std::env::var("E57_FUZZ")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(400)
    {
        let mut b = good.clone();
        for _ in 0..1 + rnd() % 4 {
            let at = (rnd() % b.len() as u64) as usize;
            b[at] = rnd() as u8;
        }
        fix_crcs(&mut b);
        std::fs::write(&f, &b).unwrap();
        match E57Input::from_path(&f) {
            Ok(inp) => {
                ok += 1;
                // Whatever was decoded is consistent.
                for s in &inp.scans {
                    if let Some(g) = &s.grid {
                        assert_eq!(g.row.len(), s.len());
                        assert!(g.row.iter().all(|&r| r < g.rows));
                    }
                    assert!(s.pose.is_finite());
                }
            }
            Err(e) => {
                err += 1;
                assert!(matches!(e, Error::Format { .. }), "{e}");
            }
        }
    }
    eprintln!("mutations: ok {ok} err {err}");
    assert!(err > 0 && ok > 0, "ok {ok} err {err}");

    // Targeted XML edits of the same length: a record count beyond the data, and an
    // integer range the stored values do not fit.
    let xml_edit = |from: &str, to: &str| {
        assert_eq!(from.len(), to.len());
        // Strip checksums, edit, put them back.
        let mut logical: Vec<u8> = good.chunks(1024).flat_map(|p| p[..1020].to_vec()).collect();
        let pos = logical
            .windows(from.len())
            .position(|w| w == from.as_bytes())
            .unwrap_or_else(|| panic!("{from} not in XML"));
        logical[pos..pos + from.len()].copy_from_slice(to.as_bytes());
        let mut b: Vec<u8> = logical
            .chunks(1020)
            .flat_map(|p| {
                let mut v = p.to_vec();
                v.extend_from_slice(&[0; 4]);
                v
            })
            .collect();
        b.truncate(good.len());
        fix_crcs(&mut b);
        b
    };
    let msg = expect_clean_error(
        &xml_edit("recordCount=\"240\"", "recordCount=\"999\""),
        dir.path(),
        "count",
    );
    assert!(msg.contains("scan s"), "{msg}");
    let msg = expect_clean_error(
        &xml_edit(
            "<rowIndex type=\"Integer\" minimum=\"0\" maximum=\"11\"",
            "<rowIndex type=\"Integer\" minimum=\"0\" maximum=\"10\"",
        ),
        dir.path(),
        "range",
    );
    assert!(msg.contains("rowIndex"), "{msg}");
}
