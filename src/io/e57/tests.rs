use super::read::*;
use super::write::*;
use super::*;

#[test]
fn guid_shape_and_determinism() {
    let g = derived_guid("a");
    assert_eq!(g.len(), 38);
    assert!(g.starts_with('{') && g.ends_with('}'));
    assert_eq!(g, derived_guid("a"));
    assert_ne!(g, derived_guid("b"));
}

#[test]
fn names_are_file_safe_and_unique() {
    let pc = |n: Option<&str>| {
        let mut p = PointCloud::default();
        p.name = n.map(str::to_string);
        p
    };
    let names = scan_names(
        &[pc(Some("a/b")), pc(Some("a/b")), pc(None), pc(Some(".."))],
        "f",
    );
    assert_eq!(names, ["a_b", "a_b_1", "f_2", "f_3"]);
    assert_eq!(scan_names(&[pc(None)], "f"), ["f"]);
}

#[test]
fn pose_quaternion_checked() {
    let mut t = Transform::default();
    assert_eq!(pose_matrix(&t).unwrap(), DMat4::IDENTITY);
    t.rotation.w = 2.0;
    assert!(pose_matrix(&t).unwrap_err().contains("length 2"));
    // 90° about z, round trip through the writer's conversion.
    let m = DMat4::from_rotation_translation(
        DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2),
        DVec3::new(1e6, -2.5, 3.0),
    );
    let back = pose_matrix(&transform_of(m)).unwrap();
    assert!(back.abs_diff_eq(m, 1e-12));
}

#[test]
fn attribute_names() {
    let mut used = vec!["ao".to_string()];
    assert_eq!(attribute_name("ao", &mut used), "ao_1");
    assert_eq!(attribute_name("scalar field", &mut used), "scalar_field");
    assert_eq!(attribute_name("1x", &mut used), "x_1x");
    assert_eq!(attribute_name("xmlish", &mut used), "x_xmlish");
}

#[test]
fn colours_by_mode() {
    let input = [[200u8, 100, 0], [10, 20, 30]];
    let ao = [0.5f32, 1.0];
    let valid = [true, false];
    let m = result_colours(Some(&input), Some(&valid), &ao, 1.0, ColorMode::Modulate);
    // 200·128/255 = 100.4 → 100; the second colour is flagged invalid → grey.
    assert_eq!(m, [[100, 50, 0], [255, 255, 255]]);
    let k = result_colours(Some(&input), None, &ao, 1.0, ColorMode::Keep);
    assert_eq!(k, input);
    let r = result_colours(Some(&input), None, &ao, 1.0, ColorMode::Replace);
    assert_eq!(r, [[128; 3], [255; 3]]);
    assert_eq!(result_colours(None, None, &ao, 1.0, ColorMode::Keep), r);
}

#[test]
fn ranges() {
    let si = RecordDataType::ScaledInteger {
        min: 0,
        max: 32767,
        scale: 1.0 / 32767.0,
        offset: 0.0,
    };
    let r = value_range(None, None, &si).unwrap();
    assert!((r.1 - 1.0).abs() < 1e-12);
    let l = value_range(
        Some(&RecordValue::Integer(0)),
        Some(&RecordValue::Integer(255)),
        &RecordDataType::U8,
    );
    assert_eq!(l, Some((0.0, 255.0)));
    assert_eq!(value_range(None, None, &RecordDataType::F32), None);
    // Degenerate limits fall back to the type range.
    let d = value_range(
        Some(&RecordValue::Integer(5)),
        Some(&RecordValue::Integer(5)),
        &RecordDataType::U8,
    );
    assert_eq!(d, Some((0.0, 255.0)));
}
