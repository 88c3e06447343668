use super::read::*;
use super::table::*;
use super::write::*;
use super::*;

#[test]
fn grid_step_follows_the_extent() {
    assert_eq!(pow10(-4), 1e-4);
    assert_eq!(pow10(-9), 1e-9);
    assert_eq!(pow10(2), 100.0);
    for (extent, e) in [
        (1e5, -4),
        (1.0, -4),
        (0.99, -5),
        (0.15, -5),
        (0.05, -6),
        (2e-6, -9),
        (0.0, -9),
        (f64::INFINITY, -4),
        (f64::NAN, -4),
    ] {
        assert_eq!(grid_exponent(extent), e, "{extent}");
    }
}

#[test]
fn extra_dims_layout() {
    let mut data = Vec::new();
    data.extend(descriptor("a", 3, 0, "", None));
    data.extend(descriptor("gap", 0, 5, "", None));
    data.extend(descriptor("b", 10, 0, "", None));
    let dims = parse_extra_dims(&data, 20, 16).unwrap();
    let at: Vec<_> = dims.iter().map(|d| (d.offset, d.size)).collect();
    assert_eq!(at, vec![(20, 2), (22, 5), (27, 8)]);
    assert!(parse_extra_dims(&data, 20, 14).is_err());
    assert!(parse_extra_dims(&data[..100], 20, 16).is_err());
    let mut bad = descriptor("x", 31, 0, "", None).to_vec();
    bad.extend(descriptor("y", 1, 0, "", None));
    assert!(parse_extra_dims(&bad, 20, 16).is_err());
}

#[test]
fn descriptor_fields() {
    let d = descriptor(AO_NAME, 9, 0, AO_DESCRIPTION, Some((0.0, 1.0)));
    assert_eq!(d[2], 9);
    assert_eq!(d[3], 0b110);
    assert_eq!(&d[4..6], b"ao");
    assert_eq!(f64::from_le_bytes(d[88..96].try_into().unwrap()), 1.0);
    assert_eq!(c_string(&d[160..192]), AO_DESCRIPTION);
    assert!(AO_DESCRIPTION.len() <= 32);
}

#[test]
fn truncation_keeps_characters_whole() {
    assert_eq!(truncate_utf8("abc", 2), "ab");
    assert_eq!(truncate_utf8("aé", 2), "a");
    assert_eq!(las_ascii("Größe", 4), "Gr??");
}

#[test]
fn extra_values() {
    let d = ExtraDim {
        name: "h".into(),
        data_type: 4,
        offset: 1,
        size: 2,
        scale: Some(0.5),
        value_offset: Some(10.0),
    };
    assert_eq!(d.value(&[0, 0xfe, 0xff]), Some(9.0));
    assert_eq!(d.value(&[0, 0]), None);
}

#[cfg(not(feature = "laz"))]
#[test]
fn compressed_needs_the_feature() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.laz");
    let output_err = check_compress(true, &p).unwrap_err().to_string();
    assert!(output_err.contains("--features laz") && output_err.contains("a.laz"));
    // A LAS file whose point format says compressed.
    let mut w = Writer::new(std::io::Cursor::new(Vec::new()), Header::default()).unwrap();
    w.write_point(Default::default()).unwrap();
    let mut bytes = w.into_inner().unwrap().into_inner();
    bytes[104] |= 0x80;
    std::fs::write(&p, bytes).unwrap();
    let input_err = LasInput::from_path(&p).unwrap_err().to_string();
    assert!(input_err.contains("--features laz") && input_err.contains("a.laz"));
}
