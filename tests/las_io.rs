//! LAS/LAZ in and out: files generated here with the `las` crate go through `LasInput::from_path` →
//! `write_las` and are read back with the `las` crate, comparing raw record bytes.

use glam::{DMat4, DVec3};
use las::Reader;
use mvao::io::las::{read_ao, write_las, write_table_las, LasInput};
use mvao::io::output::{grey, ColorMode};
use mvao::io::raw::PointTable;
use mvao::Error;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

#[path = "common/las_gen.rs"]
mod las_gen;
use las_gen::*;

/// Runs `write_las` on `spec` and checks every byte of the output records.
fn round_trip(dir: &Path, spec: &Spec, mode: ColorMode, gamma: f32, out_ext: &str) -> PathBuf {
    let ext = if spec.compress { "laz" } else { "las" };
    let tag = format!(
        "v{}{}_f{}_{mode:?}_{}",
        spec.version.0,
        spec.version.1,
        spec.format,
        spec.dims.len()
    );
    let inp = dir.join(format!("{tag}.{ext}"));
    let recs = make_las(&inp, spec);
    let input = LasInput::from_path(&inp).unwrap();
    assert_eq!(input.len(), spec.n);
    assert_eq!(input.records(), &recs[..], "{tag}: records read exactly");
    assert_eq!(input.is_compressed(), spec.compress);
    let ao = ao_values(spec.n);
    let out = dir.join(format!("{tag}.out.{out_ext}"));
    write_las(&input, &ao, &[], gamma, mode, &out, out_ext == "laz").unwrap();

    let (h, got) = read_back(&out);
    let in_id = spec.format;
    let out_id = match in_id {
        0 => 2,
        1 => 3,
        4 => 5,
        6 => 7,
        9 => 10,
        x => x,
    };
    assert_eq!(h.point_format().to_u8().unwrap(), out_id, "{tag}: format");
    assert_eq!(h.point_format().is_compressed, out_ext == "laz");
    let in_len = STD_LEN[in_id as usize] + spec.extra_len();
    let out_len = STD_LEN[out_id as usize] + spec.extra_len() + 4;
    assert_eq!(
        h.point_format().len() as usize,
        out_len,
        "{tag}: record length"
    );
    assert_eq!(got.len(), spec.n * out_len);
    let version_ok = match (spec.version, out_id) {
        ((1, 0 | 1), 2 | 3) => (1, 4),
        ((1, 2), 5) => (1, 4),
        ((1, 0..=3), _) if spec.evlrs => (1, 4),
        (v, _) => v,
    };
    assert_eq!(
        (h.version().major, h.version().minor),
        version_ok,
        "{tag}: version"
    );
    assert_eq!(*h.transforms(), transforms(), "{tag}: scale and offset");
    assert_eq!(h.system_identifier(), "HERITAGE TLS");
    assert_eq!(
        h.generating_software(),
        format!("mvao {}", env!("CARGO_PKG_VERSION"))
    );
    assert_eq!(h.number_of_points(), spec.n as u64);
    let crs = h
        .vlrs()
        .iter()
        .find(|v| v.user_id == "LASF_Projection")
        .expect("CRS VLR kept");
    assert_eq!(crs.data, WKT.as_bytes());
    if spec.evlrs {
        // The las crate reads only the first EVLR: count them in the header, read them all
        // with `LasInput::from_path`.
        let o = std::fs::read(&out).unwrap();
        assert_eq!(u32::from_le_bytes(o[243..247].try_into().unwrap()), 2);
        assert_eq!(h.evlrs()[0].data.len(), 100);
        let back = LasInput::from_path(&out).unwrap();
        assert_eq!(back.evlrs().len(), 2, "{tag}: EVLRs kept");
        for (k, e) in back.evlrs().iter().enumerate() {
            let size = [100, 70_000][k];
            assert_eq!(e.record_id as usize, k + 1);
            assert_eq!(e.data.len(), size);
            assert!(e
                .data
                .iter()
                .enumerate()
                .all(|(i, &b)| b == (i * 7 + k + 1) as u8));
        }
    }
    assert!(!h.vlrs().iter().any(|v| v.user_id == "laszip encoded") || out_ext == "laz");

    // Every original byte, at its place in the output format.
    let rgb_at = match out_id {
        2 => 20,
        3 | 5 => 28,
        _ => 30,
    };
    let (ins, add) = if out_id != in_id {
        (rgb_at, STD_LEN[out_id as usize] - STD_LEN[in_id as usize])
    } else {
        (in_len, 0)
    };
    let had_colour = out_id == in_id;
    for (k, (o, i)) in got
        .chunks_exact(out_len)
        .zip(recs.chunks_exact(in_len))
        .enumerate()
    {
        // The input record with zero colour (and NIR) bytes inserted, then the ao.
        let mut want = i[..ins].to_vec();
        want.extend(std::iter::repeat_n(0u8, add));
        want.extend(&i[ins..]);
        let g = grey(ao[k], gamma) as u32;
        for c in 0..3 {
            let at = rgb_at + 2 * c;
            let old = u16_at(&want, at) as u32;
            let new = match (had_colour, mode) {
                (false, _) | (true, ColorMode::Replace) => g * 257,
                (true, ColorMode::Keep) => old,
                (true, ColorMode::Modulate) => (old * g + 127) / 255,
            };
            want[at..at + 2].copy_from_slice(&(new as u16).to_le_bytes());
        }
        want.extend(ao[k].to_le_bytes());
        assert_eq!(o, &want[..], "{tag}: point {k}");
    }
    // Decoded with the las crate: the raw integers and scaled coordinates agree.
    let inp_pd = Reader::from_path(&inp).unwrap().read_all().unwrap();
    let out_pd = Reader::from_path(&out).unwrap().read_all().unwrap();
    assert!(inp_pd.x_raw().eq(out_pd.x_raw()));
    assert!(inp_pd.y_raw().eq(out_pd.y_raw()));
    assert!(inp_pd.z_raw().eq(out_pd.z_raw()));
    assert!(inp_pd.intensity().eq(out_pd.intensity()));
    assert!(inp_pd.classification().eq(out_pd.classification()));
    assert!(inp_pd.user_data().eq(out_pd.user_data()));
    assert!(inp_pd.point_source_id().eq(out_pd.point_source_id()));
    assert!(inp_pd
        .scan_angle_degrees()
        .map(f32::to_bits)
        .eq(out_pd.scan_angle_degrees().map(f32::to_bits)));
    if let Some(t) = inp_pd.gps_time() {
        assert!(t
            .map(f64::to_bits)
            .eq(out_pd.gps_time().unwrap().map(f64::to_bits)));
    }
    // The AO is found by its description.
    let back = read_ao(&out).unwrap();
    assert_eq!(back, ao);
    let dims = LasInput::from_path(&out).unwrap().extra_dims().to_vec();
    assert_eq!(dims.iter().filter(|d| d.name == "ao").count(), 1);
    let ao_dim = dims.iter().find(|d| d.name == "ao").unwrap();
    assert_eq!((ao_dim.data_type, ao_dim.offset), (9, out_len - 4));
    out
}

#[test]
fn formats_and_versions_keep_every_field() {
    let dir = tempfile::tempdir().unwrap();
    let cases: &[((u8, u8), u8)] = &[
        ((1, 0), 0),
        ((1, 1), 1),
        ((1, 2), 0),
        ((1, 2), 1),
        ((1, 2), 2),
        ((1, 2), 3),
        ((1, 3), 4),
        ((1, 3), 5),
        ((1, 4), 0),
        ((1, 4), 3),
        ((1, 4), 6),
        ((1, 4), 7),
        ((1, 4), 8),
        ((1, 4), 9),
        ((1, 4), 10),
    ];
    for &(v, f) in cases {
        for mode in [ColorMode::Modulate, ColorMode::Replace, ColorMode::Keep] {
            let mut spec = Spec::new(v, f);
            spec.seed = v.1 as u64 * 100 + f as u64;
            round_trip(dir.path(), &spec, mode, 1.0, "las");
        }
    }
}

#[test]
fn gamma_and_existing_extra_dims() {
    let dir = tempfile::tempdir().unwrap();
    for (v, f) in [((1, 2), 1), ((1, 2), 3), ((1, 4), 6), ((1, 4), 7)] {
        let mut spec = Spec::new(v, f);
        spec.dims = vec![
            dim("reflectance", 9),
            dim("echo_width", 3),
            Dim {
                name: "vendor",
                data_type: 0,
                bytes: 3,
            },
            dim("range", 10),
        ];
        spec.undocumented = 5;
        spec.evlrs = v == (1, 4);
        let out = round_trip(dir.path(), &spec, ColorMode::Modulate, 2.2, "las");
        let dims = LasInput::from_path(&out).unwrap().extra_dims().to_vec();
        let names: Vec<&str> = dims.iter().map(|d| d.name.as_str()).collect();
        // The undocumented bytes are described so 'ao' lands after them.
        assert_eq!(
            names,
            [
                "reflectance",
                "echo_width",
                "vendor",
                "range",
                "undocumented_0",
                "ao"
            ]
        );
        let new_std = STD_LEN[match f {
            1 => 3,
            6 => 7,
            x => x as usize,
        }];
        assert_eq!(dims[0].offset, new_std);
        assert_eq!(dims[5].offset, new_std + 4 + 2 + 3 + 8 + 5);
    }
}

#[test]
fn rerun_overwrites_ao() {
    let dir = tempfile::tempdir().unwrap();
    let mut spec = Spec::new((1, 4), 6);
    spec.dims = vec![dim("reflectance", 9)];
    let first = round_trip(dir.path(), &spec, ColorMode::Modulate, 1.0, "las");
    let input = LasInput::from_path(&first).unwrap();
    let len = input.record_len();
    let ao2: Vec<f32> = (0..spec.n).map(|k| (k % 7) as f32 / 6.0).collect();
    let second = dir.path().join("second.las");
    write_las(&input, &ao2, &[], 1.0, ColorMode::Keep, &second, false).unwrap();
    let again = LasInput::from_path(&second).unwrap();
    assert_eq!(again.record_len(), len, "no second ao dimension");
    assert_eq!(again.point_format(), 7);
    let names: Vec<String> = again.extra_dims().iter().map(|d| d.name.clone()).collect();
    assert_eq!(names, ["reflectance", "ao"]);
    assert_eq!(read_ao(&second).unwrap(), ao2);
    // Everything but the ao bytes is the first output's (colour kept).
    for (a, b) in input
        .records()
        .chunks_exact(len)
        .zip(again.records().chunks_exact(len))
    {
        assert_eq!(a[..len - 4], b[..len - 4]);
    }
}

#[cfg(feature = "laz")]
#[test]
fn laz_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    for (v, f) in [
        ((1, 2), 1),
        ((1, 2), 3),
        ((1, 4), 6),
        ((1, 4), 7),
        ((1, 3), 4),
    ] {
        let mut spec = Spec::new(v, f);
        spec.compress = true;
        spec.n = 70_000; // more than one LAZ chunk and one write batch
        spec.dims = vec![dim("reflectance", 9)];
        spec.evlrs = v == (1, 4);
        let out = round_trip(dir.path(), &spec, ColorMode::Modulate, 1.0, "laz");
        // LAZ → LAS too.
        let input = LasInput::from_path(&out).unwrap();
        assert!(input.is_compressed());
        let plain = dir.path().join(format!("plain_{f}.las"));
        let ao = read_ao(&out).unwrap();
        write_las(&input, &ao, &[], 1.0, ColorMode::Keep, &plain, false).unwrap();
        let back = LasInput::from_path(&plain).unwrap();
        assert!(!back.is_compressed());
        assert_eq!(back.records(), input.records());
    }
    // LAS → LAZ.
    let spec = Spec::new((1, 2), 0);
    round_trip(dir.path(), &spec, ColorMode::Replace, 1.0, "laz");
}

/// Sets LAS header bytes of a written file.
fn patch(path: &Path, at: u64, bytes: &[u8]) {
    let mut f = std::fs::OpenOptions::new().write(true).open(path).unwrap();
    f.seek(SeekFrom::Start(at)).unwrap();
    f.write_all(bytes).unwrap();
}

fn header_u64(bytes: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap())
}

#[test]
fn internal_waveform_packets_stay_addressable() {
    let dir = tempfile::tempdir().unwrap();
    let inp = dir.path().join("wave.las");
    let mut spec = Spec::new((1, 4), 4);
    spec.evlrs = true;
    make_las(&inp, &spec);
    // Make the first EVLR the waveform data packet record, as a 1.4 writer would.
    let bytes = std::fs::read(&inp).unwrap();
    let first = header_u64(&bytes, 235);
    patch(
        &inp,
        6,
        &(u16::from_le_bytes([bytes[6], bytes[7]]) | 2).to_le_bytes(),
    );
    patch(&inp, 227, &first.to_le_bytes());
    let packets: Vec<u8> = bytes[first as usize + 60..first as usize + 160].to_vec();

    let input = LasInput::from_path(&inp).unwrap();
    let out = dir.path().join("wave.out.las");
    write_las(
        &input,
        &ao_values(spec.n),
        &[],
        1.0,
        ColorMode::Modulate,
        &out,
        false,
    )
    .unwrap();
    let o = std::fs::read(&out).unwrap();
    assert_eq!(o[104], 5, "format 4 gains colour");
    assert_eq!(
        u16::from_le_bytes([o[6], o[7]]) & 6,
        2,
        "internal waveform bit kept"
    );
    let start = header_u64(&o, 227) as usize;
    assert_eq!(start as u64, header_u64(&o, 235));
    assert_eq!(&o[start + 60..start + 160], &packets[..]);
}

#[test]
fn las13_waveform_packets_move_into_a_las14_evlr() {
    let dir = tempfile::tempdir().unwrap();
    let inp = dir.path().join("wave13.las");
    let spec = Spec::new((1, 3), 4);
    let recs = make_las(&inp, &spec);
    // LAS 1.3 stores the packets after the points, behind an EVLR header.
    let mut bytes = std::fs::read(&inp).unwrap();
    let start = bytes.len() as u64;
    let packets: Vec<u8> = (0..300).map(|i| (i % 251) as u8).collect();
    let mut head = vec![0u8; 60];
    head[2..11].copy_from_slice(b"LASF_Spec");
    head[18..20].copy_from_slice(&65535u16.to_le_bytes());
    head[20..28].copy_from_slice(&(packets.len() as u64).to_le_bytes());
    bytes.extend(head);
    bytes.extend(&packets);
    bytes[227..235].copy_from_slice(&start.to_le_bytes());
    bytes[6] |= 2;
    std::fs::write(&inp, &bytes).unwrap();

    let input = LasInput::from_path(&inp).unwrap();
    assert_eq!(input.records(), &recs[..]);
    assert_eq!(input.evlrs().len(), 1);
    let out = dir.path().join("wave13.out.las");
    write_las(
        &input,
        &ao_values(spec.n),
        &[],
        1.0,
        ColorMode::Keep,
        &out,
        false,
    )
    .unwrap();
    let o = std::fs::read(&out).unwrap();
    assert_eq!((o[24], o[25], o[104]), (1, 4, 5), "LAS 1.4, format 5");
    assert_eq!(o[6] & 6, 2);
    let at = header_u64(&o, 227) as usize;
    assert_eq!(at as u64, header_u64(&o, 235));
    assert_eq!(&o[at + 2..at + 11], b"LASF_Spec");
    assert_eq!(&o[at + 60..at + 360], &packets[..]);
    assert_eq!(read_ao(&out).unwrap(), ao_values(spec.n));
}

#[test]
fn legacy_counts_are_zero_for_extended_formats() {
    let dir = tempfile::tempdir().unwrap();
    let inp = dir.path().join("ext.las");
    make_las(&inp, &Spec::new((1, 4), 6));
    let out = dir.path().join("ext.out.las");
    let input = LasInput::from_path(&inp).unwrap();
    write_las(
        &input,
        &ao_values(257),
        &[],
        1.0,
        ColorMode::Keep,
        &out,
        false,
    )
    .unwrap();
    let o = std::fs::read(&out).unwrap();
    assert!(o[107..131].iter().all(|&b| b == 0));
    assert_eq!(header_u64(&o, 247), 257);
}

#[test]
fn raw_scan_and_available_fields() {
    let dir = tempfile::tempdir().unwrap();
    let inp = dir.path().join("geo.las");
    let mut spec = Spec::new((1, 4), 6);
    spec.dims = vec![dim("NormalX", 9), dim("NormalY", 9), dim("NormalZ", 9)];
    let recs = make_las(&inp, &spec);
    let input = LasInput::from_path(&inp).unwrap();
    let scan = input.raw_scan("geo");
    assert_eq!(scan.name, "geo");
    assert!(scan.pose.is_none() && scan.scanner.is_none() && scan.grid.is_none());
    let pd = Reader::from_path(&inp).unwrap().read_all().unwrap();
    for ((p, x), (y, z)) in scan.xyz.iter().zip(pd.x()).zip(pd.y().zip(pd.z())) {
        assert_eq!(p[0].to_bits(), x.to_bits());
        assert_eq!(p[1].to_bits(), y.to_bits());
        assert_eq!(p[2].to_bits(), z.to_bits());
        assert!((p[0] - 512000.0).abs() <= 1000.0);
        assert!((p[1] - 5200000.0).abs() <= 1000.0);
    }
    let normals = scan.normals.expect("normals from NormalX/Y/Z");
    assert!(normals
        .iter()
        .all(|n| n.length() == 0.0 || (n.length() - 1.0).abs() < 1e-5));
    let ids = input.point_source_ids().unwrap();
    assert!(ids.iter().zip(pd.point_source_id()).all(|(a, b)| *a == b));
    let angles = input.scan_angles().unwrap();
    assert!(angles
        .iter()
        .zip(recs.chunks_exact(input.record_len()))
        .all(|(a, r)| *a == i16::from_le_bytes([r[18], r[19]]) as f32 * 0.006));
    // Unused fields (all zero) are reported absent.
    let mut zero = Spec::new((1, 2), 0);
    zero.n = 3;
    let p = dir.path().join("zero.las");
    make_las(&p, &zero);
    let bytes = std::fs::read(&p).unwrap();
    let off = u32::from_le_bytes(bytes[96..100].try_into().unwrap()) as u64;
    for k in 0..3u64 {
        patch(&p, off + k * 20 + 16, &[0, 0, 0, 0]);
    }
    let z = LasInput::from_path(&p).unwrap();
    assert!(z.point_source_ids().is_none() && z.scan_angles().is_none());
}

#[test]
fn columns_for_other_formats() {
    let dir = tempfile::tempdir().unwrap();
    let mut spec = Spec::new((1, 4), 7);
    spec.dims = vec![dim("reflectance", 9), dim("ao", 9)];
    let inp = dir.path().join("cols.las");
    let recs = make_las(&inp, &spec);
    let input = LasInput::from_path(&inp).unwrap();
    let len = input.record_len();
    let inten = input.intensities();
    let cols = input.extra_columns();
    assert_eq!(cols.len(), 1, "ao is not an extra column");
    assert_eq!(cols[0].0, "reflectance");
    let rgb = input.rgb8().unwrap();
    for (k, r) in recs.chunks_exact(len).enumerate() {
        assert_eq!(inten[k], u16_at(r, 12) as f32 / 65535.0);
        let refl = f32::from_le_bytes(r[36..40].try_into().unwrap());
        assert_eq!(cols[0].1[k], refl as f64);
        // Random 16-bit colours: the high byte.
        assert_eq!(
            rgb[k],
            [0, 1, 2].map(|c| (u16_at(r, 30 + 2 * c) >> 8) as u8)
        );
    }
    // Colours that all fit in 8 bits are taken as 8-bit.
    let mut small = recs.clone();
    for r in small.chunks_exact_mut(len) {
        for c in 0..3 {
            r[31 + 2 * c] = 0;
        }
    }
    let p = dir.path().join("cols8.las");
    make_las_from(&p, &spec, small.clone());
    let rgb = LasInput::from_path(&p).unwrap().rgb8().unwrap();
    for (k, r) in small.chunks_exact(len).enumerate() {
        assert_eq!(rgb[k], [r[30], r[32], r[34]]);
    }
    assert!(LasInput::from_path(&dir.path().join("cols.las"))
        .unwrap()
        .ao()
        .is_some());
    let mut plain = Spec::new((1, 2), 1);
    plain.n = 4;
    let q = dir.path().join("plain.las");
    make_las(&q, &plain);
    let plain = LasInput::from_path(&q).unwrap();
    assert!(plain.rgb8().is_none() && plain.ao().is_none() && plain.extra_columns().is_empty());
    assert!(read_ao(&q).is_err());
}

/// A valid file's bytes, for corrupting.
fn sample(dir: &Path, spec: &Spec, name: &str) -> (PathBuf, Vec<u8>) {
    let p = dir.join(name);
    make_las(&p, spec);
    let b = std::fs::read(&p).unwrap();
    (p, b)
}

fn expect_format_error(path: &Path, what: &str) -> String {
    let err = LasInput::from_path(path).expect_err(what);
    let msg = err.to_string();
    assert!(
        matches!(err, Error::Format { .. }),
        "{what}: not a format error: {msg}"
    );
    let name = path.file_name().unwrap().to_str().unwrap();
    assert!(msg.contains(name), "{what}: message names the file: {msg}");
    msg
}

#[test]
fn corrupt_inputs_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let mut spec = Spec::new((1, 4), 6);
    spec.dims = vec![dim("reflectance", 9)];
    spec.evlrs = true;
    let (p, good) = sample(dir.path(), &spec, "good.las");
    let bad = dir.path().join("bad.las");
    let off = u32::from_le_bytes(good[96..100].try_into().unwrap()) as usize;

    // Truncated anywhere: header, VLRs, points, EVLRs.
    for cut in [
        0,
        3,
        100,
        374,
        380,
        off - 10,
        off + 5,
        off + 1000,
        good.len() - 1,
    ] {
        std::fs::write(&bad, &good[..cut]).unwrap();
        expect_format_error(&bad, &format!("cut at {cut}"));
    }
    // Wrong signature.
    let mut b = good.clone();
    b[..4].copy_from_slice(b"LASG");
    std::fs::write(&bad, &b).unwrap();
    assert!(expect_format_error(&bad, "signature").contains("not a LAS file"));
    // More points than the data holds.
    let mut b = good.clone();
    b[107..111].copy_from_slice(&(spec.n as u32 + 1).to_le_bytes());
    std::fs::write(&bad, &b).unwrap();
    let msg = expect_format_error(&bad, "count");
    assert!(msg.contains("258 points"), "{msg}");
    let mut b = good.clone();
    b[107..111].copy_from_slice(&0u32.to_le_bytes());
    b[247..255].copy_from_slice(&u64::MAX.to_le_bytes());
    std::fs::write(&bad, &b).unwrap();
    expect_format_error(&bad, "huge count");
    // A VLR longer than the space before the points.
    let mut b = good.clone();
    b[375 + 20..375 + 22].copy_from_slice(&60000u16.to_le_bytes());
    std::fs::write(&bad, &b).unwrap();
    assert!(expect_format_error(&bad, "vlr").contains("VLR 1 of 2"));
    // More VLRs than fit.
    let mut b = good.clone();
    b[100..104].copy_from_slice(&1_000_000u32.to_le_bytes());
    std::fs::write(&bad, &b).unwrap();
    expect_format_error(&bad, "vlr count");
    // An EVLR claiming exabytes.
    let mut b = good.clone();
    let e = header_u64(&good, 235) as usize;
    b[e + 20..e + 28].copy_from_slice(&(u64::MAX / 2).to_le_bytes());
    std::fs::write(&bad, &b).unwrap();
    assert!(expect_format_error(&bad, "evlr").contains("EVLR 1 of 2"));
    // An extra-bytes VLR that describes more bytes than the records have.
    let mut b = good.clone();
    let wkt_vlr = 54 + WKT.len();
    let eb = 375 + wkt_vlr + 54;
    b[eb + 2] = 10; // f32 → f64: 8 bytes, records have 4
    std::fs::write(&bad, &b).unwrap();
    assert!(expect_format_error(&bad, "extra bytes").contains("extra-bytes VLR"));
    // Record length shorter than the format.
    let mut b = good.clone();
    b[105..107].copy_from_slice(&10u16.to_le_bytes());
    std::fs::write(&bad, &b).unwrap();
    expect_format_error(&bad, "record length");
    // Unknown version and format (also with the compression bits set), zero scale.
    for (at, val) in [
        (25usize, 9u8),
        (104, 11),
        (104, 0x8b),
        (104, 0xf2),
        (131 + 7, 0),
    ] {
        let mut b = good.clone();
        if at == 138 {
            b[131..139].copy_from_slice(&0f64.to_le_bytes());
        } else {
            b[at] = val;
        }
        std::fs::write(&bad, &b).unwrap();
        expect_format_error(&bad, &format!("byte {at}"));
    }
    // The untouched file still reads.
    assert_eq!(LasInput::from_path(&p).unwrap().len(), spec.n);
}

/// LAS 1.0–1.3 headers count points by return for returns 1–5 only, yet legacy records hold
/// up to 7: such a file is written as LAS 1.4, every record kept.
#[test]
fn return_numbers_above_five_move_to_las14() {
    let dir = tempfile::tempdir().unwrap();
    let spec = Spec::new((1, 2), 0);
    let inp = dir.path().join("returns.las");
    let recs = make_las(&inp, &spec);
    // The las crate will not write such a file: patch the records in place.
    let bytes = std::fs::read(&inp).unwrap();
    let start = u32::from_le_bytes(bytes[96..100].try_into().unwrap()) as u64;
    for k in 0..3 {
        let flags = (recs[k * STD_LEN[0] + 14] & 0xc0) | (5 + k as u8) | 7 << 3;
        patch(&inp, start + (k * STD_LEN[0] + 14) as u64, &[flags]);
    }
    let input = LasInput::from_path(&inp).unwrap();
    let out = dir.path().join("returns.out.las");
    write_las(
        &input,
        &ao_values(spec.n),
        &[],
        1.0,
        ColorMode::Modulate,
        &out,
        false,
    )
    .unwrap();
    let (h, got) = read_back(&out);
    assert_eq!(h.version(), las::Version::new(1, 4));
    assert_eq!(got.len() / h.point_format().len() as usize, spec.n);
    let len = h.point_format().len() as usize;
    for (k, r) in got.chunks_exact(len).take(3).enumerate() {
        assert_eq!(r[14] & 7, 5 + k as u8, "record {k}");
    }
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        2,
        "no temporary left"
    );
}

#[test]
fn random_damage_never_panics() {
    let dir = tempfile::tempdir().unwrap();
    let mut spec = Spec::new((1, 4), 7);
    spec.n = 3000;
    spec.dims = vec![dim("reflectance", 9)];
    spec.evlrs = true;
    let (_, las) = sample(dir.path(), &spec, "d.las");
    spec.compress = cfg!(feature = "laz");
    let (_, laz) = sample(dir.path(), &spec, "d.laz");
    let mut rng = Lcg(99);
    let bad = dir.path().join("damaged.bin");
    // The LAZ decoder asserts on some corrupt streams; `LasInput::from_path` turns that into an error
    // (the panic message still shows below).
    for round in 0..200 {
        let src = if round % 2 == 0 { &las } else { &laz };
        let mut b = src.clone();
        if round % 3 == 0 {
            b.truncate(rng.below(b.len() as u64) as usize);
        }
        for _ in 0..1 + rng.below(8) {
            if b.is_empty() {
                break;
            }
            let at = rng.below(b.len() as u64) as usize;
            b[at] = rng.byte();
        }
        std::fs::write(&bad, &b).unwrap();
        // Ok or Err, but never a panic or an abort.
        if let Err(e) = LasInput::from_path(&bad) {
            assert!(e.to_string().contains("damaged.bin"), "{e}");
        }
    }
}

#[cfg(feature = "laz")]
#[test]
fn truncated_laz_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let mut spec = Spec::new((1, 2), 3);
    spec.compress = true;
    spec.n = 120_000;
    let (_, good) = sample(dir.path(), &spec, "t.laz");
    let bad = dir.path().join("cut.laz");
    for frac in [0.3, 0.6, 0.9, 0.999] {
        let cut = (good.len() as f64 * frac) as usize;
        std::fs::write(&bad, &good[..cut]).unwrap();
        expect_format_error(&bad, &format!("laz cut at {cut}"));
    }
}

#[test]
fn refused_writes_leave_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let inp = dir.path().join("in.las");
    make_las(&inp, &Spec::new((1, 2), 1));
    let input = LasInput::from_path(&inp).unwrap();
    let out = dir.path().join("out.las");
    let short = write_las(&input, &[0.5; 3], &[], 1.0, ColorMode::Keep, &out, false);
    assert!(matches!(short, Err(Error::Param(_))));
    let mut ao = ao_values(257);
    ao[5] = f32::NAN;
    let nan = write_las(&input, &ao, &[], 1.0, ColorMode::Keep, &out, false);
    assert!(matches!(nan, Err(Error::Param(_))));
    let missing = dir.path().join("no/such/dir/out.las");
    let r = write_las(
        &input,
        &ao_values(257),
        &[],
        1.0,
        ColorMode::Keep,
        &missing,
        false,
    );
    assert!(matches!(r, Err(Error::Io { .. })));
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, vec![std::ffi::OsString::from("in.las")]);
}

#[test]
fn table_output_keeps_world_coordinates() {
    let dir = tempfile::tempdir().unwrap();
    let n = 1000;
    let mut rng = Lcg(5);
    let xyz: Vec<[f64; 3]> = (0..n)
        .map(|_| {
            [
                rng.below(100_000) as f64 * 1e-3,
                rng.below(100_000) as f64 * 1e-3,
                rng.below(10_000) as f64 * 1e-3,
            ]
        })
        .collect();
    let mut xyz = xyz;
    xyz[3] = [f64::NAN; 3]; // no return: not written
    let pose = DMat4::from_translation(DVec3::new(1_000_000.0, 5_200_000.0, 300.0))
        * DMat4::from_rotation_z(0.3);
    let long = "a_dimension_name_well_beyond_thirty_two_bytes";
    let mut range: Vec<f64> = (0..n).map(|k| k as f64 * 0.25).collect();
    range[10] = f64::NAN;
    let table = PointTable {
        name: "station".into(),
        xyz: xyz.clone(),
        pose,
        rgb: Some((0..n).map(|k| [k as u8, (2 * k) as u8, 255]).collect()),
        intensity: Some((0..n).map(|k| k as f32 / n as f32).collect()),
        ao: ao_values(n),
        grid: None,
        extra: vec![
            ("range".into(), range),
            (long.into(), vec![1.5; n]),
            (format!("{long}_too"), vec![2.5; n]),
            ("ao".into(), vec![0.0; n]),
        ],
    };
    for compress in [false, cfg!(feature = "laz")] {
        let out = dir.path().join(if compress { "t.laz" } else { "t.las" });
        write_table_las(&table, &out, compress).unwrap();
        let mut r = Reader::from_path(&out).unwrap();
        let h = r.header().clone();
        assert_eq!((h.version().major, h.version().minor), (1, 4));
        assert_eq!(h.point_format().to_u8().unwrap(), 7);
        assert_eq!(h.transforms().x.scale, 1e-4);
        assert!((h.transforms().x.offset - 1_000_050.0).abs() < 100.0);
        let pd = r.read_all().unwrap();
        assert_eq!(pd.len(), n - 1);
        let kept: Vec<usize> = (0..n).filter(|&k| k != 3).collect();
        for ((&k, (x, y)), z) in kept.iter().zip(pd.x().zip(pd.y())).zip(pd.z()) {
            let w = pose.transform_point3(DVec3::from(xyz[k]));
            assert!((x - w.x).abs() <= 0.5e-4 + 1e-9, "x {k}: {x} vs {}", w.x);
            assert!((y - w.y).abs() <= 0.5e-4 + 1e-9);
            assert!((z - w.z).abs() <= 0.5e-4 + 1e-9);
        }
        for ((&k, c), i) in kept.iter().zip(pd.rgb().unwrap()).zip(pd.intensity()) {
            let want = table.rgb.as_ref().unwrap()[k];
            assert_eq!(
                c,
                (
                    want[0] as u16 * 257,
                    want[1] as u16 * 257,
                    want[2] as u16 * 257
                )
            );
            assert_eq!(i, (k as f32 / n as f32 * 65535.0).round() as u16);
        }
        let ao = read_ao(&out).unwrap();
        let want: Vec<f32> = kept.iter().map(|&k| table.ao[k]).collect();
        assert_eq!(ao, want);
        let input = LasInput::from_path(&out).unwrap();
        let dims = input.extra_dims();
        let names: Vec<&str> = dims.iter().map(|d| d.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "ao",
                "range",
                &long[..32],
                &format!("{}_2", &long[..30]),
                "ao_2"
            ]
        );
        let rec = input.record_len();
        let ranges: Vec<f64> = input
            .records()
            .chunks_exact(rec)
            .map(|r| dims[1].value(r).unwrap())
            .collect();
        assert_eq!(ranges[2], 0.5);
        assert_eq!(ranges[3], 1.0, "point 4 of the table is record 3");
        assert_eq!(ranges[9], f64::MIN, "NaN became the no-data value");
        assert!(ranges.iter().all(|v| v.is_finite()));
    }
}

#[test]
fn empty_files_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let mut spec = Spec::new((1, 2), 0);
    spec.n = 0;
    let inp = dir.path().join("empty.las");
    make_las(&inp, &spec);
    let input = LasInput::from_path(&inp).unwrap();
    assert!(input.is_empty());
    assert!(input.raw_scan("empty").xyz.is_empty());
    let out = dir.path().join("empty.out.las");
    write_las(&input, &[], &[], 1.0, ColorMode::Modulate, &out, false).unwrap();
    assert_eq!(read_ao(&out).unwrap(), Vec::<f32>::new());
    // A table whose every point lacks a return.
    let table = PointTable {
        name: "void".into(),
        xyz: vec![[f64::NAN; 3]],
        pose: DMat4::IDENTITY,
        ao: vec![0.5],
        ..Default::default()
    };
    let t = dir.path().join("void.las");
    write_table_las(&table, &t, false).unwrap();
    assert!(LasInput::from_path(&t).unwrap().is_empty());
}

#[test]
fn table_far_from_origin_stays_exact() {
    let dir = tempfile::tempdir().unwrap();
    let xyz = vec![
        [1.0e6 + 0.1234, 2.0e6 + 0.5678, 1.0e3 + 0.0001],
        [1.0e6 + 10.0, 2.0e6 - 10.0, 1.0e3],
    ];
    let table = PointTable {
        name: "far".into(),
        xyz: xyz.clone(),
        pose: DMat4::IDENTITY,
        ao: vec![0.25, 1.0],
        ..Default::default()
    };
    let out = dir.path().join("far.las");
    write_table_las(&table, &out, false).unwrap();
    let mut r = Reader::from_path(&out).unwrap();
    assert_eq!(r.header().point_format().to_u8().unwrap(), 6, "no colour");
    let pd = r.read_all().unwrap();
    for ((p, x), (y, z)) in xyz.iter().zip(pd.x()).zip(pd.y().zip(pd.z())) {
        assert!((p[0] - x).abs() < 1e-6 && (p[1] - y).abs() < 1e-6 && (p[2] - z).abs() < 1e-6);
    }
}

/// A 2 µm object keeps its points apart: the grid step follows the data's extent (1 nm here),
/// where a fixed 0.1 mm grid put them all on one position.
#[test]
fn table_of_a_tiny_object_keeps_its_points_apart() {
    let dir = tempfile::tempdir().unwrap();
    let at = DVec3::new(3.7, -12.2, 0.4);
    let xyz: Vec<[f64; 3]> = (0..1000)
        .map(|k| {
            let (i, j, l) = ((k % 10) as f64, ((k / 10) % 10) as f64, (k / 100) as f64);
            (at + DVec3::new(i, j, l) * 2e-7).to_array()
        })
        .collect();
    let table = PointTable {
        name: "tiny".into(),
        xyz: xyz.clone(),
        pose: DMat4::IDENTITY,
        ao: vec![0.5; xyz.len()],
        ..Default::default()
    };
    let out = dir.path().join("tiny.las");
    let warnings = write_table_las(&table, &out, false).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    let mut r = Reader::from_path(&out).unwrap();
    assert_eq!(r.header().transforms().x.scale, 1e-9);
    let pd = r.read_all().unwrap();
    let back: Vec<[f64; 3]> = pd
        .x()
        .zip(pd.y())
        .zip(pd.z())
        .map(|((x, y), z)| [x, y, z])
        .collect();
    let mut keys: Vec<[i64; 3]> = back
        .iter()
        .map(|p| p.map(|c| (c * 1e9).round() as i64))
        .collect();
    keys.sort_unstable();
    keys.dedup();
    assert_eq!(keys.len(), xyz.len(), "distinct points stay distinct");
    for (p, q) in xyz.iter().zip(&back) {
        assert!(
            (0..3).all(|a| (p[a] - q[a]).abs() <= 1e-9),
            "{p:?} vs {q:?}"
        );
    }
}

/// Points a scene's grid cannot tell apart are written, with a warning that counts them.
#[test]
fn table_points_merged_by_the_grid_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let mut xyz: Vec<[f64; 3]> = (0..100).map(|k| [k as f64, 0.0, 1.0]).collect();
    // Two points 10 µm from others in a 100 m scene (0.1 mm grid), and an exact duplicate,
    // which the input did not keep apart either.
    xyz.push([5.0 + 1e-5, 0.0, 1.0]);
    xyz.push([7.0, 1e-5, 1.0]);
    xyz.push([9.0, 0.0, 1.0]);
    let table = PointTable {
        name: "scene".into(),
        ao: vec![0.5; xyz.len()],
        xyz,
        pose: DMat4::IDENTITY,
        ..Default::default()
    };
    let out = dir.path().join("scene.las");
    let warnings = write_table_las(&table, &out, false).unwrap();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(
        warnings[0].contains("scene.las") && warnings[0].contains("2 of 103 points"),
        "{warnings:?}"
    );
    assert_eq!(LasInput::from_path(&out).unwrap().len(), 103);
}

/// `scripts/check_las_ao.py` reads the output with laspy (and PDAL when installed).
#[test]
fn python_readers_see_ao() {
    let has_laspy = std::process::Command::new("python3")
        .args(["-c", "import laspy"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !has_laspy {
        println!("skipped: python3 with laspy not available (pip install laspy)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/check_las_ao.py");
    let mut spec = Spec::new((1, 2), 1);
    spec.dims = vec![dim("reflectance", 9)];
    let out = round_trip(dir.path(), &spec, ColorMode::Modulate, 1.0, "las");
    let mut spec14 = Spec::new((1, 4), 7);
    spec14.evlrs = true;
    let out14 = round_trip(dir.path(), &spec14, ColorMode::Keep, 1.0, "las");
    let table = PointTable {
        name: "t".into(),
        xyz: (0..50).map(|k| [k as f64, 0.5 * k as f64, 1.0]).collect(),
        pose: DMat4::from_translation(DVec3::new(512000.0, 5200000.0, 300.0)),
        rgb: Some(vec![[10, 20, 30]; 50]),
        intensity: Some(vec![0.5; 50]),
        ao: ao_values(50),
        grid: None,
        extra: vec![("range".into(), vec![2.0; 50])],
    };
    let out_table = dir.path().join("table.las");
    write_table_las(&table, &out_table, false).unwrap();
    let mut wave = Spec::new((1, 3), 4);
    wave.dims = vec![dim("reflectance", 9)];
    let out_wave = round_trip(dir.path(), &wave, ColorMode::Modulate, 1.0, "las");
    let mut files = vec![out, out14, out_table, out_wave];
    let has_lazrs = std::process::Command::new("python3")
        .args(["-c", "import laspy; laspy.LazBackend.detect_available()[0]"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if has_lazrs && cfg!(feature = "laz") {
        let mut z = Spec::new((1, 4), 6);
        z.compress = true;
        files.push(round_trip(dir.path(), &z, ColorMode::Keep, 1.0, "laz"));
    } else {
        println!("LAZ check skipped: no laspy LAZ backend (pip install 'laspy[lazrs]')");
    }
    for f in files {
        let want = read_ao(&f).unwrap();
        let o = std::process::Command::new("python3")
            .arg(&script)
            .arg(&f)
            .args(["--expect-count", &want.len().to_string()])
            .args(["--expect-first", &want[1].to_string()])
            .output()
            .unwrap();
        let text =
            String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
        println!("{text}");
        assert!(o.status.success(), "{}: {text}", f.display());
    }
}
