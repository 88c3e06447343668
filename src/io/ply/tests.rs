use super::read::PARALLEL_READ_MIN;
use super::*;
use std::path::PathBuf;

/// Header text plus body bytes.
fn ply(header: &str, body: &[u8]) -> Vec<u8> {
    let mut v = header.as_bytes().to_vec();
    v.extend_from_slice(body);
    v
}

fn write_tmp(dir: &tempfile::TempDir, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.path().join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn read_bytes(bytes: &[u8]) -> Result<PlyFile> {
    let dir = tempfile::tempdir().unwrap();
    let p = write_tmp(&dir, "t.ply", bytes);
    PlyFile::from_path(&p)
}

fn read_warn(bytes: &[u8]) -> (PlyFile, Vec<String>) {
    let dir = tempfile::tempdir().unwrap();
    let p = write_tmp(&dir, "t.ply", bytes);
    match PlyFile::from_path_warn(&p) {
        Ok(r) => r,
        Err(e) => panic!("read failed: {e}"),
    }
}

fn read_ok(bytes: &[u8]) -> PlyFile {
    match read_bytes(bytes) {
        Ok(p) => p,
        Err(e) => panic!("read failed: {e}"),
    }
}

/// The message of a format error (panics on success or on another error kind).
fn format_err(bytes: &[u8]) -> String {
    match read_bytes(bytes) {
        Err(Error::Format { msg, .. }) => msg,
        Err(e) => panic!("expected a format error, got {e}"),
        Ok(_) => panic!("expected a format error, read succeeded"),
    }
}

/// Writes as binary LE and reads back.
fn round_trip(p: &PlyFile) -> PlyFile {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.ply");
    p.write_path(&out).unwrap();
    let back = PlyFile::from_path(&out).unwrap();
    assert_eq!(back.header.encoding, Encoding::BinaryLe);
    back
}

/// Same file apart from the recorded input encoding.
fn assert_same_content(a: &PlyFile, b: &PlyFile) {
    assert_eq!(a.header.comments, b.header.comments);
    assert_eq!(a.header.obj_info, b.header.obj_info);
    assert_eq!(a.header.elements, b.header.elements);
    assert_eq!(a.data, b.data);
}

#[test]
fn ascii_to_le_round_trip() {
    let src = "ply\nformat ascii 1.0\ncomment made by hand\n\
                   element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                   property uchar red\nproperty int16 s\n\
                   element face 2\nproperty list uchar int vertex_indices\nend_header\n\
                   0 0 0 255 -7\n1.5 -2.25 3e-3 0 32767\n-0.1 1e10 7 12 -32768\n\
                   3 0 1 2\n4 2 1 0 1\n";
    let p = read_ok(src.as_bytes());
    assert_eq!(p.header.encoding, Encoding::Ascii);
    assert_eq!(p.header.comments, vec!["made by hand".to_string()]);
    assert_eq!(
        p.scalar_column("vertex", "x").unwrap(),
        vec![0.0, 1.5, f64::from(-0.1f32)]
    );
    assert_eq!(
        p.scalar_column("vertex", "z").unwrap(),
        vec![0.0, f64::from(3e-3f32), 7.0]
    );
    assert_eq!(
        p.scalar_column("vertex", "red").unwrap(),
        vec![255.0, 0.0, 12.0]
    );
    assert_eq!(
        p.scalar_column("vertex", "s").unwrap(),
        vec![-7.0, 32767.0, -32768.0]
    );
    assert_eq!(
        p.list_column("face", "vertex_indices").unwrap(),
        vec![vec![0, 1, 2], vec![2, 1, 0, 1]]
    );
    assert!(p.data[0].row_offsets.is_none());
    assert_eq!(p.data[0].bytes.len(), 3 * 15);
    let back = round_trip(&p);
    assert_same_content(&p, &back);
    assert_eq!(
        back.vertex_xyz().unwrap()[1],
        [1.5, -2.25, f64::from(3e-3f32)]
    );
}

/// (classic name, numeric name, little-endian bytes, big-endian bytes, value).
type TypedValue = (&'static str, &'static str, Vec<u8>, Vec<u8>, f64);

/// One row with an extreme or awkward value of every type.
fn every_type_row() -> Vec<TypedValue> {
    let f32v = f32::from_bits(0x3f9d_f3b6);
    let sub = f32::from_bits(1); // smallest subnormal
    let f64v = std::f64::consts::PI;
    vec![
        ("char", "int8", vec![0x80], vec![0x80], -128.0),
        ("uchar", "uint8", vec![0xff], vec![0xff], 255.0),
        (
            "short",
            "int16",
            (-32768i16).to_le_bytes().to_vec(),
            (-32768i16).to_be_bytes().to_vec(),
            -32768.0,
        ),
        (
            "ushort",
            "uint16",
            0xfffeu16.to_le_bytes().to_vec(),
            0xfffeu16.to_be_bytes().to_vec(),
            65534.0,
        ),
        (
            "int",
            "int32",
            i32::MIN.to_le_bytes().to_vec(),
            i32::MIN.to_be_bytes().to_vec(),
            f64::from(i32::MIN),
        ),
        (
            "uint",
            "uint32",
            0xdead_beefu32.to_le_bytes().to_vec(),
            0xdead_beefu32.to_be_bytes().to_vec(),
            f64::from(0xdead_beefu32),
        ),
        (
            "float",
            "float32",
            f32v.to_le_bytes().to_vec(),
            f32v.to_be_bytes().to_vec(),
            f64::from(f32v),
        ),
        (
            "float",
            "float32",
            sub.to_le_bytes().to_vec(),
            sub.to_be_bytes().to_vec(),
            f64::from(sub),
        ),
        (
            "double",
            "float64",
            f64v.to_le_bytes().to_vec(),
            f64v.to_be_bytes().to_vec(),
            f64v,
        ),
    ]
}

#[test]
fn big_endian_to_le_bit_exact_every_type() {
    let row = every_type_row();
    let mut be_head = String::from("ply\nformat binary_big_endian 1.0\nelement vertex 2\n");
    let mut le_head = String::from("ply\nformat binary_little_endian 1.0\nelement vertex 2\n");
    let (mut be_body, mut le_body) = (Vec::new(), Vec::new());
    for (i, (classic, numeric, _, _, _)) in row.iter().enumerate() {
        be_head.push_str(&format!("property {numeric} p{i}\n"));
        le_head.push_str(&format!("property {classic} p{i}\n"));
    }
    be_head.push_str("end_header\n");
    le_head.push_str("end_header\n");
    for _ in 0..2 {
        for (_, _, le, be, _) in &row {
            le_body.extend_from_slice(le);
            be_body.extend_from_slice(be);
        }
    }
    let be = read_ok(&ply(&be_head, &be_body));
    let le = read_ok(&ply(&le_head, &le_body));
    assert_eq!(be.header.encoding, Encoding::BinaryBe);
    assert_eq!(be.data, le.data);
    assert_eq!(be.data[0].bytes, le_body);
    assert_eq!(be.header.elements, le.header.elements);
    for (i, (_, _, _, _, v)) in row.iter().enumerate() {
        let col = be.scalar_column("vertex", &format!("p{i}")).unwrap();
        assert_eq!(col.len(), 2);
        for c in col {
            assert_eq!(c.to_bits(), v.to_bits(), "property p{i}");
        }
    }
    let back = round_trip(&be);
    assert_same_content(&be, &back);
    // Written with the classic names.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.ply");
    be.write_path(&out).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    assert_eq!(bytes, ply(&le_head, &le_body));
}

#[test]
fn lists_faces_in_every_encoding() {
    let ascii = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n\
                     element face 3\nproperty list uint8 int32 vertex_indices\n\
                     property ushort flags\nend_header\n\
                     5\n3 0 1 2 9\n0 8\n4 10 11 12 13 65535\n";
    let a = read_ok(ascii.as_bytes());
    let want = vec![vec![0, 1, 2], vec![], vec![10, 11, 12, 13]];
    assert_eq!(a.list_column("face", "vertex_indices").unwrap(), want);
    assert_eq!(
        a.scalar_column("face", "flags").unwrap(),
        vec![9.0, 8.0, 65535.0]
    );
    assert_eq!(a.data[1].row_offsets.as_deref(), Some(&[0, 15, 18, 37][..]));

    let head = |fmt: &str| {
        format!(
            "ply\nformat {fmt} 1.0\nelement vertex 1\nproperty float x\n\
                 element face 3\nproperty list uchar int vertex_indices\n\
                 property uint16 flags\nend_header\n"
        )
    };
    let mut be = 5f32.to_be_bytes().to_vec();
    let mut le = 5f32.to_le_bytes().to_vec();
    for (list, flag) in [
        (&[0i32, 1, 2][..], 9u16),
        (&[], 8),
        (&[10, 11, 12, 13], 65535),
    ] {
        be.push(list.len() as u8);
        le.push(list.len() as u8);
        for &i in list {
            be.extend_from_slice(&i.to_be_bytes());
            le.extend_from_slice(&i.to_le_bytes());
        }
        be.extend_from_slice(&flag.to_be_bytes());
        le.extend_from_slice(&flag.to_le_bytes());
    }
    let b = read_ok(&ply(&head("binary_big_endian"), &be));
    let l = read_ok(&ply(&head("binary_little_endian"), &le));
    assert_eq!(a.data, b.data);
    assert_eq!(a.data, l.data);
    assert_eq!(b.list_column("face", "vertex_indices").unwrap(), want);
    assert_same_content(&b, &round_trip(&b));
}

/// A Stanford-style range scan: `obj_info` grid size and a `range_grid` element whose
/// entries are empty or hold one vertex index.
/// Columns of one type are read with the type fixed in the loop: the same values as the
/// general per-value reading, for every scalar type, in `map_scalars` and `count_scalars`.
#[test]
fn uniform_columns_read_as_the_general_path_does() {
    let types = [
        "char", "uchar", "short", "ushort", "int", "uint", "float", "double",
    ];
    let mut head = String::from("ply\nformat binary_little_endian 1.0\nelement vertex 4\n");
    for t in types {
        head += &format!("property {t} a_{t}\nproperty {t} b_{t}\n");
    }
    head += "property float last\nend_header\n";
    let mut body = Vec::new();
    for r in 0..4i32 {
        for (k, t) in types.iter().enumerate() {
            for v in [r * 37 - 60 + k as i32, 100 - r * 51] {
                match *t {
                    "char" => body.extend_from_slice(&(v as i8).to_le_bytes()),
                    "uchar" => body.extend_from_slice(&(v as u8).to_le_bytes()),
                    "short" => body.extend_from_slice(&(v as i16 * 300).to_le_bytes()),
                    "ushort" => body.extend_from_slice(&(v as u16).to_le_bytes()),
                    "int" => body.extend_from_slice(&(v * 70_000).to_le_bytes()),
                    "uint" => body.extend_from_slice(&(v as u32).to_le_bytes()),
                    "float" => {
                        let f = if r == 2 { f32::NAN } else { v as f32 / 3.0 };
                        body.extend_from_slice(&f.to_le_bytes())
                    }
                    _ => {
                        let f = if r == 1 {
                            f64::INFINITY
                        } else {
                            v as f64 / 7.0
                        };
                        body.extend_from_slice(&f.to_le_bytes())
                    }
                }
            }
        }
        body.extend_from_slice(&(r as f32).to_le_bytes());
    }
    let p = read_ok(&ply(&head, &body));
    for t in types {
        let (a, b) = (format!("a_{t}"), format!("b_{t}"));
        // Mixed with another type, the general path reads each value by its type.
        let other = if t == "float" { "a_uchar" } else { "last" };
        let general = p
            .map_scalars("vertex", [a.as_str(), b.as_str(), other], |v| v)
            .unwrap();
        let uniform = p
            .map_scalars("vertex", [a.as_str(), b.as_str()], |v| v)
            .unwrap();
        assert_eq!(uniform.len(), 4);
        for (u, g) in uniform.iter().zip(&general) {
            assert_eq!(u[0].to_bits(), g[0].to_bits(), "{t}");
            assert_eq!(u[1].to_bits(), g[1].to_bits(), "{t}");
        }
        let bad = |v: f64| !v.is_finite() || v < 0.0;
        let general = p
            .count_scalars("vertex", &[a.as_str(), b.as_str(), other], bad)
            .unwrap();
        let uniform = p
            .count_scalars("vertex", &[a.as_str(), b.as_str()], bad)
            .unwrap();
        assert_eq!(uniform[..], general[..2], "{t}");
    }
}

/// One pass over several columns reads what the columns read one by one do, with fixed
/// rows and with rows holding a list, and refuses what they refuse.
#[test]
fn map_scalars_equals_scalar_columns() {
    let fixed = read_ok(
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty uchar k\n\
              property double y\nend_header\n1.5 7 -2\n0.25 255 1e300\n-0 0 3.5\n",
    );
    let listed = read_ok(
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
              property list uchar int idx\nproperty double y\nend_header\n\
              1.5 2 4 5 -2\n0.25 0 1e300\n-0 1 9 3.5\n",
    );
    for p in [&fixed, &listed] {
        let both = p.map_scalars("vertex", ["y", "x"], |v| v).unwrap();
        let (x, y) = (
            p.scalar_column("vertex", "x").unwrap(),
            p.scalar_column("vertex", "y").unwrap(),
        );
        assert_eq!(both.len(), 3);
        for (i, v) in both.iter().enumerate() {
            assert_eq!(v[0].to_bits(), y[i].to_bits());
            assert_eq!(v[1].to_bits(), x[i].to_bits());
        }
        assert!(p.map_scalars("vertex", ["x", "nope"], |v| v).is_none());
        assert!(p.map_scalars("face", ["x"], |v| v).is_none());
    }
    assert!(listed.map_scalars("vertex", ["x", "idx"], |v| v).is_none());
    let k = fixed.map_scalars("vertex", ["k"], |[k]| k as u8).unwrap();
    assert_eq!(k, [7, 255, 0]);
}

const RANGE_SCAN: &str = "ply\nformat ascii 1.0\nobj_info is_cyberware_data 1\n\
        obj_info num_cols 3\nobj_info num_rows 2\nelement vertex 3\nproperty float x\n\
        property float y\nproperty float z\nelement range_grid 6\n\
        property list uchar int vertex_indices\nend_header\n\
        -0.06325 0.0359793 0.0420873 \n0.5 0.25 -1 \n1e-3 2 3 \n0 \n1 0 \n0 \n1 1 \n1 2 \n0 \n";

#[test]
fn count_scalars_equals_counting_the_columns() {
    // Enough rows for several parallel chunks, in both layouts.
    let rows = 40_000usize;
    let mut fixed = String::new();
    let mut listed = String::new();
    for (text, list) in [(&mut fixed, false), (&mut listed, true)] {
        text.push_str(&format!(
            "ply\nformat ascii 1.0\nelement vertex {rows}\nproperty float x\n{}\
                 property double y\nproperty uchar k\nend_header\n",
            if list {
                "property list uchar int idx\n"
            } else {
                ""
            }
        ));
        for i in 0..rows {
            let x = if i % 7 == 0 { "nan" } else { "1.5" };
            let y = if i % 11 == 0 { "inf" } else { "-2" };
            // Lists of 0, 1 or 2 items: rows of three lengths.
            let idx = match (list, i % 3) {
                (false, _) => String::new(),
                (true, 0) => " 0".to_string(),
                (true, 1) => " 1 4".to_string(),
                _ => " 2 4 5".to_string(),
            };
            text.push_str(&format!("{x}{idx} {y} {}\n", i % 256));
        }
    }
    for text in [&fixed, &listed] {
        let p = read_ok(text.as_bytes());
        let bad = |v: f64| !v.is_finite();
        let n = p.count_scalars("vertex", &["y", "x", "k"], bad).unwrap();
        let count = |name: &str| {
            let c = p.scalar_column("vertex", name).unwrap();
            c.iter().filter(|v| bad(**v)).count()
        };
        assert_eq!(n, [count("y"), count("x"), count("k")]);
        assert_eq!(n[0], rows.div_ceil(11));
        assert_eq!(n[1], rows.div_ceil(7));
        assert!(p.count_scalars("vertex", &["x", "nope"], bad).is_none());
        assert!(p.count_scalars("face", &["x"], bad).is_none());
    }
}
#[test]
fn range_grid_empty_and_single_lists() {
    let p = read_ok(RANGE_SCAN.as_bytes());
    let grid = p.list_column("range_grid", "vertex_indices").unwrap();
    assert_eq!(
        grid,
        vec![vec![], vec![0], vec![], vec![1], vec![2], vec![]]
    );
    assert_eq!(p.data[1].bytes.len(), 6 + 3 * 4);
    assert_eq!(
        p.vertex_xyz().unwrap()[0],
        [
            f64::from(-0.06325f32),
            f64::from(0.0359793f32),
            f64::from(0.0420873f32)
        ]
    );
    let back = round_trip(&p);
    assert_same_content(&p, &back);
    assert_eq!(
        back.list_column("range_grid", "vertex_indices").unwrap(),
        grid
    );
}

#[test]
fn comments_and_obj_info_kept_in_order() {
    let src = "ply\nformat ascii 1.0\ncomment first one\nobj_info num_cols 3\n\
                   comment second  with  spaces\nobj_info  num_rows 2\ncomment\n\
                   element vertex 0\nproperty float x\nend_header\n";
    let p = read_ok(src.as_bytes());
    assert_eq!(
        p.header.comments,
        vec!["first one", "second  with  spaces", ""]
    );
    assert_eq!(p.header.obj_info, vec!["num_cols 3", "num_rows 2"]);
    let back = round_trip(&p);
    assert_same_content(&p, &back);
    assert_eq!(
        back.scalar_column("vertex", "x").unwrap(),
        Vec::<f64>::new()
    );
}

#[test]
fn columns_written_row_by_row_equal_the_general_path() {
    use ScalarType as T;
    let types = [T::I8, T::U8, T::I16, T::U16, T::I32, T::U32, T::F32, T::F64];
    // Past one batch of rows, so that later batches start at their own offset.
    let n = 70_000;
    let special = [
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        2.5,
        -2.5,
        0.499_999_9,
        -0.0,
        300.0,
        65_535.5,
        -1e12,
        1e12,
        4_294_967_295.7,
    ];
    let value = |k: usize, c: usize| {
        if k % 7 == 0 {
            special[(k / 7 + c) % special.len()]
        } else {
            (k as f64 * 0.37 + c as f64).sin() * 10f64.powi((k % 11) as i32 - 2)
        }
    };
    let xyz: Vec<f64> = (0..n).map(|k| k as f64 * 0.01).collect();
    let existing: Vec<Vec<f64>> = (0..types.len())
        .map(|c| (0..n).map(|k| (k % 100) as f64 + c as f64).collect())
        .collect();
    let names: Vec<String> = (0..types.len()).map(|c| format!("p{c}")).collect();
    let mut cols: Vec<(&str, ScalarType, &[f64])> = vec![
        ("x", T::F32, &xyz),
        ("y", T::F32, &xyz),
        ("z", T::F32, &xyz),
    ];
    for (c, &t) in types.iter().enumerate() {
        cols.push((&names[c], t, &existing[c]));
    }
    let ply = PlyFile::from_vertex_columns(&cols, &[]).unwrap();
    // Each existing column overwritten (keeping its type) and one new of each type.
    let new_vals: Vec<Vec<f64>> = (0..2 * types.len())
        .map(|c| (0..n).map(|k| value(k, c)).collect())
        .collect();
    let new_names: Vec<String> = (0..types.len()).map(|c| format!("q{c}")).collect();
    let mut put: Vec<(&str, ScalarType, &[f64])> = Vec::new();
    for (c, &t) in types.iter().enumerate() {
        put.push((&names[c], T::F64, &new_vals[c]));
        put.push((&new_names[c], t, &new_vals[types.len() + c]));
    }
    let dir = tempfile::tempdir().unwrap();
    let (fast, general) = (dir.path().join("fast.ply"), dir.path().join("general.ply"));
    let comment = ["written".to_string()];
    ply.write_path_with_columns(&fast, "vertex", &put, &comment)
        .unwrap();
    let mut g = ply.clone();
    for &(name, t, vals) in &put {
        g.set_scalar_column("vertex", name, t, vals).unwrap();
    }
    g.header.comments.extend(comment.iter().cloned());
    g.write_path(&general).unwrap();
    assert!(std::fs::read(&fast).unwrap() == std::fs::read(&general).unwrap());
}

#[test]
fn set_scalar_column_overwrite_and_append_fixed() {
    let x = [1.0, 2.0, 3.0, 4.0];
    let flag = [1.0, 1.0, 1.0, 1.0];
    let mut p = PlyFile::from_vertex_columns(
        &[
            ("x", ScalarType::F32, &x),
            ("y", ScalarType::F64, &x),
            ("z", ScalarType::F32, &x),
            ("flag", ScalarType::U8, &flag),
        ],
        &["synthetic".to_string()],
    )
    .unwrap();
    assert_eq!(p.header.encoding, Encoding::BinaryLe);
    assert_eq!(p.header.comments, vec!["synthetic"]);
    // Overwrite keeps the existing type (u8): round, clamp, NaN -> 0.
    p.set_scalar_column(
        "vertex",
        "flag",
        ScalarType::F64,
        &[-3.0, 2.5, 300.0, f64::NAN],
    )
    .unwrap();
    assert_eq!(
        p.scalar_column("vertex", "flag").unwrap(),
        vec![0.0, 3.0, 255.0, 0.0]
    );
    p.set_scalar_column("vertex", "y", ScalarType::U8, &[0.1, 0.2, 0.3, 0.4])
        .unwrap();
    assert_eq!(
        p.scalar_column("vertex", "y").unwrap(),
        vec![0.1, 0.2, 0.3, 0.4]
    );
    // Append two new properties.
    p.set_scalar_column("vertex", "ao", ScalarType::F32, &[0.5, 0.25, f64::NAN, 1.0])
        .unwrap();
    p.set_scalar_column("vertex", "n", ScalarType::I16, &[40000.0, -1.4, -1.6, -1e9])
        .unwrap();
    let names: Vec<&str> = p.header.elements[0]
        .props
        .iter()
        .map(|q| q.name.as_str())
        .collect();
    assert_eq!(names, vec!["x", "y", "z", "flag", "ao", "n"]);
    assert_eq!(p.data[0].bytes.len(), 4 * (4 + 8 + 4 + 1 + 4 + 2));
    let ao = p.scalar_column("vertex", "ao").unwrap();
    assert_eq!((ao[0], ao[1], ao[3]), (0.5, 0.25, 1.0));
    assert!(ao[2].is_nan(), "floats keep NaN as written");
    assert_eq!(
        p.scalar_column("vertex", "n").unwrap(),
        vec![32767.0, -1.0, -2.0, -32768.0]
    );
    assert_eq!(p.scalar_column("vertex", "x").unwrap(), x.to_vec());
    assert_eq!(
        p.vertex_xyz().unwrap(),
        vec![
            [1.0, 0.1, 1.0],
            [2.0, 0.2, 2.0],
            [3.0, 0.3, 3.0],
            [4.0, 0.4, 4.0]
        ]
    );
    assert_same_content(&p, &round_trip(&p));
    // Errors.
    assert!(p
        .set_scalar_column("vertex", "ao", ScalarType::F32, &[1.0])
        .is_err());
    assert!(p
        .set_scalar_column("face", "ao", ScalarType::F32, &[])
        .is_err());
    assert!(p
        .set_scalar_column("vertex", "a b", ScalarType::F32, &x)
        .is_err());
}

#[test]
fn set_scalar_column_with_lists() {
    let src = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
                   property list uchar int nb\nproperty float y\nproperty float z\n\
                   end_header\n1 2 7 8 2 3\n4 0 5 6\n7 1 9 8 9\n";
    let mut p = read_ok(src.as_bytes());
    assert!(p.data[0].row_offsets.is_some());
    assert_eq!(
        p.vertex_xyz().unwrap(),
        vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]
    );
    p.set_scalar_column("vertex", "y", ScalarType::U8, &[-2.0, -5.0, 0.5])
        .unwrap();
    p.set_scalar_column("vertex", "ao", ScalarType::U16, &[1.4, 70000.0, f64::NAN])
        .unwrap();
    assert_eq!(
        p.scalar_column("vertex", "y").unwrap(),
        vec![-2.0, -5.0, 0.5]
    );
    assert_eq!(
        p.scalar_column("vertex", "ao").unwrap(),
        vec![1.0, 65535.0, 0.0]
    );
    assert_eq!(
        p.list_column("vertex", "nb").unwrap(),
        vec![vec![7, 8], vec![], vec![9]]
    );
    assert_eq!(p.scalar_column("vertex", "z").unwrap(), vec![3.0, 6.0, 9.0]);
    assert_eq!(p.data[0].row_offsets.as_deref(), Some(&[0, 23, 38, 57][..]));
    assert!(p
        .set_scalar_column("vertex", "nb", ScalarType::U8, &[1.0, 2.0, 3.0])
        .is_err());
    assert_same_content(&p, &round_trip(&p));
}

#[test]
fn bodies_read_by_several_threads_are_the_file_s_bytes() {
    // Above PARALLEL_READ_MIN, with a stretch that does not end on a chunk, then a second
    // element read after it from where the parallel read left the file.
    let rows = (PARALLEL_READ_MIN + (4 << 20) + 4099) / 12;
    for (format, le) in [("binary_little_endian", true), ("binary_big_endian", false)] {
        let head = format!(
            "ply\nformat {format} 1.0\nelement vertex {rows}\nproperty float x\n\
                 property float y\nproperty float z\nelement tail 2\nproperty int k\nend_header\n"
        );
        let mut body = Vec::with_capacity(rows * 12 + 8);
        for i in 0..rows * 3 {
            let v = (i as f32) * 0.5;
            body.extend_from_slice(&if le { v.to_le_bytes() } else { v.to_be_bytes() });
        }
        for k in [7i32, -9] {
            body.extend_from_slice(&if le { k.to_le_bytes() } else { k.to_be_bytes() });
        }
        let p = read_ok(&ply(&head, &body));
        let x = p.scalar_column("vertex", "x").unwrap();
        let z = p.scalar_column("vertex", "z").unwrap();
        assert_eq!(x.len(), rows);
        for i in [0, 1, rows / 2, rows - 1] {
            assert_eq!(x[i], (3 * i) as f64 * 0.5, "{format} row {i}");
            assert_eq!(z[i], (3 * i + 2) as f64 * 0.5, "{format} row {i}");
        }
        assert_eq!(p.scalar_column("tail", "k").unwrap(), vec![7.0, -9.0]);
        // One byte short: the same error as a serial read.
        let msg = format_err(&ply(&head, &body[..body.len() - 1]));
        assert_eq!(
            msg,
            "truncated: element 'tail' has 2 rows but data ends in row 1"
        );
    }
}

#[test]
fn truncated_binary_and_ascii() {
    let head = "ply\nformat binary_little_endian 1.0\nelement vertex 4\n\
                    property float x\nproperty float y\nend_header\n";
    let msg = format_err(&ply(head, &[0u8; 8 * 2 + 5]));
    assert_eq!(
        msg,
        "truncated: element 'vertex' has 4 rows but data ends in row 2"
    );

    let head = "ply\nformat binary_big_endian 1.0\nelement face 3\n\
                    property list uchar int vertex_indices\nend_header\n";
    let mut body = vec![1u8, 0, 0, 0, 1, 3, 0, 0, 0, 1, 0, 0];
    let msg = format_err(&ply(head, &body));
    assert!(
        msg.starts_with("truncated: element 'face' has 3 rows but data ends in row 1"),
        "{msg}"
    );
    body.truncate(5);
    let msg = format_err(&ply(head, &body));
    assert_eq!(
        msg,
        "truncated: element 'face' has 3 rows but data ends in row 1"
    );

    let src = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
                   property float y\nend_header\n1 2\n3 4\n5";
    assert_eq!(
        format_err(src.as_bytes()),
        "truncated: element 'vertex' has 3 rows but data ends in row 2"
    );
    let src = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n";
    assert_eq!(
        format_err(src.as_bytes()),
        "truncated: element 'vertex' has 1 rows but data ends in row 0"
    );
}

#[test]
fn bad_magic_format_and_header_lines() {
    assert_eq!(
        format_err(b"PLY\nformat ascii 1.0\nend_header\n"),
        "not a PLY file (missing 'ply' magic)"
    );
    assert_eq!(format_err(b""), "not a PLY file (missing 'ply' magic)");
    assert_eq!(
        format_err(&[0x89, b'P', b'N', b'G', 0, 0, 0xff]),
        "not a PLY file (missing 'ply' magic)"
    );
    assert_eq!(
        format_err(b"ply\nformat ascii 1.0\nelement vertex 1\n"),
        "header ends before 'end_header'"
    );
    assert_eq!(
        format_err(b"ply\nformat binary 1.0\nend_header\n"),
        "line 2: unknown format 'binary'"
    );
    assert_eq!(
        format_err(b"ply\nformat ascii 2.0\nend_header\n"),
        "line 2: unsupported ply version '2.0'"
    );
    assert_eq!(
        format_err(b"ply\nelement vertex 0\nend_header\n"),
        "header has no 'format' line"
    );
    assert_eq!(
        format_err(b"ply\nformat ascii 1.0\nproperty float x\nend_header\n"),
        "line 3: property declared before any element"
    );
    assert_eq!(
        format_err(b"ply\nformat ascii 1.0\nelement vertex -1\nend_header\n"),
        "line 3: element count '-1' is not a non-negative integer"
    );
    assert_eq!(
        format_err(b"ply\nformat ascii 1.0\nvertex 3\nend_header\n"),
        "line 3: unknown header keyword 'vertex'"
    );
    assert_eq!(
            format_err(
                b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float x\nend_header\n"
            ),
            "line 5: element 'vertex' declares property 'x' twice"
        );
    assert_eq!(
            format_err(
                b"ply\nformat ascii 1.0\nelement vertex 0\nelement face 0\nelement vertex 0\nend_header\n"
            ),
            "line 5: element 'vertex' is declared twice"
        );
    let long = format!("ply\ncomment {}\n", "x".repeat(100_000));
    assert!(format_err(long.as_bytes()).contains("header line longer than"));
}

#[test]
fn bad_property_types() {
    let src = "ply\nformat ascii 1.0\ncomment a\ncomment b\nelement vertex 1\n\
                   property float x\nproperty float y\nproperty float z\nproperty uchar r\n\
                   property uchar g\nproperty uchar b\nproperty flot q\nend_header\n";
    assert_eq!(
        format_err(src.as_bytes()),
        "line 12: unknown property type 'flot'"
    );
    assert_eq!(
        format_err(
            b"ply\nformat ascii 1.0\nelement f 1\nproperty list uchar int64 v\nend_header\n"
        ),
        "line 4: unknown property type 'int64'"
    );
    assert_eq!(
        format_err(b"ply\nformat ascii 1.0\nelement f 1\nproperty list float int v\nend_header\n"),
        "line 4: list count type 'float' is not an integer type"
    );
    assert_eq!(
        format_err(b"ply\nformat ascii 1.0\nelement f 1\nproperty float\nend_header\n"),
        "line 4: malformed property line 'property float'"
    );
}

#[test]
fn huge_counts_with_tiny_file() {
    // Would need 12 PB: must fail on the file length, not try to allocate.
    let head = "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000000\n\
                    property float x\nproperty float y\nproperty float z\nend_header\n";
    assert_eq!(
        format_err(&ply(head, &[0u8; 25])),
        "truncated: element 'vertex' has 1000000000000000 rows but data ends in row 2"
    );
    // count * stride overflows usize.
    let head = format!(
        "ply\nformat binary_big_endian 1.0\nelement vertex {}\nproperty double x\n\
             end_header\n",
        usize::MAX
    );
    assert!(format_err(&ply(&head, &[0u8; 8])).contains("more than can be addressed"));
    // Huge list-bearing element.
    let head = "ply\nformat binary_little_endian 1.0\nelement face 999999999999999\n\
                    property list uchar int v\nend_header\n";
    assert!(format_err(&ply(head, &[0u8; 3])).starts_with("truncated: element 'face'"));
    // Huge list count in a tiny file.
    let head = "ply\nformat binary_little_endian 1.0\nelement face 1\n\
                    property list uint int v\nend_header\n";
    let msg = format_err(&ply(head, &[0xff, 0xff, 0xff, 0xff, 1, 2, 3, 4]));
    assert!(
        msg.starts_with("truncated: element 'face' has 1 rows"),
        "{msg}"
    );
    // Negative list count.
    let head = "ply\nformat binary_little_endian 1.0\nelement face 1\n\
                    property list int int v\nend_header\n";
    assert_eq!(
        format_err(&ply(head, &(-1i32).to_le_bytes())),
        "element 'face' row 0: list count -1 is negative"
    );
    let src = "ply\nformat ascii 1.0\nelement face 2\nproperty list uchar int v\n\
                   end_header\n1 5\n-1 3\n";
    assert_eq!(
        format_err(src.as_bytes()),
        "element 'face' row 1: list count -1 is negative"
    );
    // Huge ascii counts.
    let src = "ply\nformat ascii 1.0\nelement vertex 18446744073709551615\n\
                   property double x\nelement face 99999999999999\n\
                   property list uint int v\nend_header\n1\n2\n";
    assert!(format_err(src.as_bytes()).starts_with("truncated: element 'vertex'"));
    let src = "ply\nformat ascii 1.0\nelement face 1\nproperty list uint int v\n\
                   end_header\n4000000000 1 2\n";
    assert!(format_err(src.as_bytes()).starts_with("truncated: element 'face'"));
    // A property-less element with a huge count holds nothing and reads instantly.
    let src = "ply\nformat ascii 1.0\nelement nothing 18446744073709551615\nend_header\n";
    let p = read_ok(src.as_bytes());
    assert_eq!(p.data[0].bytes.len(), 0);
}

#[test]
fn crlf_header_and_extra_spaces() {
    let head = "ply\r\nformat  binary_little_endian   1.0 \r\n  comment hello\r\n\r\n\
                    obj_info num_cols 2\r\nelement   vertex  2 \r\nproperty   float32 x\r\n\
                    property\tuint8  i\r\nend_header\r\n";
    let mut body = Vec::new();
    for (x, i) in [(1.5f32, 7u8), (-2.0, 9)] {
        body.extend_from_slice(&x.to_le_bytes());
        body.push(i);
    }
    let p = read_ok(&ply(head, &body));
    assert_eq!(p.header.comments, vec!["hello"]);
    assert_eq!(p.header.obj_info, vec!["num_cols 2"]);
    assert_eq!(p.scalar_column("vertex", "x").unwrap(), vec![1.5, -2.0]);
    assert_eq!(p.scalar_column("vertex", "i").unwrap(), vec![7.0, 9.0]);
    // An ascii body with CRLF and tabs.
    let src = "ply\r\nformat ascii 1.0\r\nelement vertex 2\r\nproperty float x\r\n\
                   property float y\r\nend_header\r\n1\t2 \r\n  3   4\r\n";
    let p = read_ok(src.as_bytes());
    assert_eq!(p.scalar_column("vertex", "y").unwrap(), vec![2.0, 4.0]);
}

#[test]
fn ascii_value_errors_and_leniency() {
    let src = "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\n\
                   property float y\nend_header\n1 2\n3 4\n1 2\n3 4\n5 6\n7 abc\n";
    assert_eq!(
        format_err(src.as_bytes()),
        "line 12: ascii value 'abc' in element 'vertex' row 5 is not a number (property 'y')"
    );
    let src = "ply\nformat ascii 1.0\nelement vertex 1\nproperty uchar r\nend_header\n300\n";
    assert_eq!(
        format_err(src.as_bytes()),
        "line 6: ascii value '300' in element 'vertex' row 0 is out of range for type \
             uchar (property 'r')"
    );
    let src = "ply\nformat ascii 1.0\nelement vertex 1\nproperty int r\nend_header\n1.5\n";
    assert!(format_err(src.as_bytes()).contains("is not an integer"));
    let src = format!(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float r\nend_header\n{}\n",
        "1".repeat(5000)
    );
    assert!(format_err(src.as_bytes()).contains("is longer than"));
    // Whole numbers written as floats are accepted for integer types, as are nan/inf for
    // floats; trailing garbage after the last element is ignored, with a warning.
    let src = "ply\nformat ascii 1.0\nelement vertex 2\nproperty int r\nproperty double d\n\
                   end_header\n2.0 nan\n+3 -inf\n\n trailing garbage\n";
    let (p, w) = read_warn(src.as_bytes());
    assert_eq!(w.len(), 1);
    assert!(
        w[0].ends_with("t.ply: line 10: data after the last element ignored"),
        "{w:?}"
    );
    assert_eq!(p.scalar_column("vertex", "r").unwrap(), vec![2.0, 3.0]);
    let d = p.scalar_column("vertex", "d").unwrap();
    assert!(d[0].is_nan() && d[1] == f64::NEG_INFINITY);
}

#[test]
fn trailing_garbage_after_binary_is_ignored_with_a_warning() {
    let head = "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty short a\n\
                    end_header\n";
    let (p, w) = read_warn(&ply(head, &[1, 2, 3, 4, 5]));
    assert_eq!(p.scalar_column("vertex", "a").unwrap(), vec![513.0]);
    assert_eq!(w.len(), 1);
    assert!(
        w[0].ends_with("t.ply: 3 bytes after the last element ignored"),
        "{w:?}"
    );
    // Exactly the declared data: nothing to say.
    assert!(read_warn(&ply(head, &[1, 2])).1.is_empty());
    // Blank lines after an ascii body are no data.
    let src = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n\n \r\n";
    assert!(read_warn(src.as_bytes()).1.is_empty());
}

/// Each ascii row is one line: a row short of values, or one with values to spare, is an
/// error naming the line, not read on into the next line.
#[test]
fn ascii_rows_are_lines() {
    let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                    property float z\nend_header\n";
    let src = format!("{head}0 0 0 9 9\n1 1 1\n2 2 2\n");
    assert_eq!(
        format_err(src.as_bytes()),
        "line 8: vertex 0 has 5 values, expected 3"
    );
    let src = format!("{head}0 0 0\n1 1\n2 2 2\n");
    assert_eq!(
        format_err(src.as_bytes()),
        "line 9: vertex 1 has 2 values, expected 3"
    );
    let src = format!("{head}0 0 0\n1 1 1\n2 2 2 3\n");
    assert_eq!(
        format_err(src.as_bytes()),
        "line 10: vertex 2 has 4 values, expected 3"
    );
    // The message names the file.
    let dir = tempfile::tempdir().unwrap();
    let p = write_tmp(&dir, "bad.ply", src.as_bytes());
    let msg = PlyFile::from_path(&p).unwrap_err().to_string();
    assert!(msg.contains("bad.ply") && msg.contains("line 10"), "{msg}");
    // Lists: the count says how many items the line holds.
    let lhead = "ply\nformat ascii 1.0\nelement face 2\nproperty list uchar int v\n\
                     property uchar f\nend_header\n";
    let src = format!("{lhead}3 0 1 2 7\n2 5 6 7 8\n");
    assert_eq!(
        format_err(src.as_bytes()),
        "line 8: face 1 has 5 values, expected 4"
    );
    let src = format!("{lhead}3 0 1\n2 7\n");
    assert_eq!(
        format_err(src.as_bytes()),
        "line 7: face 0 has 3 values, expected 5"
    );
    let src = format!("{lhead}\n");
    assert!(format_err(src.as_bytes()).starts_with("truncated: element 'face'"));
    let two = "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int v\n\
                   property list uchar int w\nend_header\n1 4\n";
    assert_eq!(
        format_err(format!("{two}1 5\n").as_bytes()),
        "line 7: face 0 has 2 values, expected at least 3"
    );
    // CRLF line ends, blank lines between rows and trailing blank lines are fine.
    let src = "ply\r\nformat ascii 1.0\r\nelement vertex 2\r\nproperty float x\r\n\
                   property float y\r\nelement face 1\r\nproperty list uchar int v\r\n\
                   end_header\r\n1 2\r\n\r\n3 4\r\n2 0 1\r\n\r\n\r\n";
    let (p, w) = read_warn(src.as_bytes());
    assert!(w.is_empty(), "{w:?}");
    assert_eq!(p.scalar_column("vertex", "y").unwrap(), vec![2.0, 4.0]);
    assert_eq!(p.list_column("face", "v").unwrap(), vec![vec![0, 1]]);
    // The last row may end without a line end.
    let src = format!("{head}0 0 0\n1 1 1\n2 2 2");
    assert_eq!(read_ok(src.as_bytes()).vertex_xyz().unwrap()[2], [2.0; 3]);
}

#[test]
fn missing_file_is_io_error_with_path() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nope.ply");
    match PlyFile::from_path(&p) {
        Err(Error::Io { path, .. }) => assert_eq!(path, p),
        other => panic!("expected io error, got {other:?}"),
    }
    let msg = PlyFile::from_path(&p).unwrap_err().to_string();
    assert!(msg.contains("nope.ply"), "{msg}");
}

#[test]
fn vertex_xyz_any_types_and_order() {
    let z = [1.0, 2.0];
    let y = [-0.5, 0.25];
    let x = [-300.0, 7.0];
    let p = PlyFile::from_vertex_columns(
        &[
            ("z", ScalarType::U8, &z),
            ("y", ScalarType::F64, &y),
            ("w", ScalarType::F32, &y),
            ("x", ScalarType::I16, &x),
        ],
        &[],
    )
    .unwrap();
    assert_eq!(
        p.vertex_xyz().unwrap(),
        vec![[-300.0, -0.5, 1.0], [7.0, 0.25, 2.0]]
    );
    let q = PlyFile::from_vertex_columns(
        &[
            ("x", ScalarType::F64, &x),
            ("y", ScalarType::F64, &y),
            ("z", ScalarType::F64, &z),
        ],
        &[],
    )
    .unwrap();
    assert_eq!(
        q.vertex_xyz().unwrap(),
        vec![[-300.0, -0.5, 1.0], [7.0, 0.25, 2.0]]
    );
    let r = PlyFile::from_vertex_columns(
        &[("x", ScalarType::F64, &x), ("y", ScalarType::F64, &y)],
        &[],
    )
    .unwrap();
    assert!(r.vertex_xyz().is_none());
    let src = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n\
                   property list uchar float y\nproperty float z\nend_header\n1 1 2 3\n";
    assert!(read_ok(src.as_bytes()).vertex_xyz().is_none());
}

#[test]
fn has_property_and_missing_columns() {
    let p = read_ok(RANGE_SCAN.as_bytes());
    assert!(p.has_property("vertex", "x"));
    assert!(p.has_property("range_grid", "vertex_indices"));
    assert!(!p.has_property("vertex", "vertex_indices"));
    assert!(!p.has_property("face", "x"));
    assert_eq!(p.element("range_grid"), Some(1));
    assert!(p.scalar_column("vertex", "w").is_none());
    assert!(p.scalar_column("range_grid", "vertex_indices").is_none());
    assert!(p.list_column("vertex", "x").is_none());
    assert!(p.list_column("nope", "x").is_none());
}

#[test]
fn list_column_rejects_negative_and_fractional_items() {
    let src = "ply\nformat ascii 1.0\nelement face 2\nproperty list uchar int v\n\
                   property list uchar float w\nend_header\n1 2 1 3\n1 -1 1 0.5\n";
    let p = read_ok(src.as_bytes());
    assert!(p.list_column("face", "v").is_none());
    assert!(p.list_column("face", "w").is_none());
}

#[test]
fn from_vertex_columns_rejects_bad_input() {
    let a = [1.0, 2.0];
    let b = [1.0];
    assert!(PlyFile::from_vertex_columns(&[], &[]).is_err());
    assert!(PlyFile::from_vertex_columns(
        &[("x", ScalarType::F32, &a), ("y", ScalarType::F32, &b)],
        &[]
    )
    .is_err());
    assert!(PlyFile::from_vertex_columns(
        &[("x", ScalarType::F32, &a), ("x", ScalarType::F32, &a)],
        &[]
    )
    .is_err());
    assert!(PlyFile::from_vertex_columns(&[("a b", ScalarType::F32, &a)], &[]).is_err());
}

#[test]
fn inconsistent_data_is_an_error_not_a_panic() {
    let x = [1.0, 2.0, 3.0];
    let mut p = PlyFile::from_vertex_columns(
        &[
            ("x", ScalarType::F32, &x),
            ("y", ScalarType::F32, &x),
            ("z", ScalarType::F32, &x),
        ],
        &["multi\nline".to_string()],
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.ply");
    p.write_path(&out).unwrap();
    assert_eq!(
        PlyFile::from_path(&out).unwrap().header.comments,
        vec!["multi line"]
    );
    p.data[0].bytes.pop();
    assert!(p.write_path(&dir.path().join("bad.ply")).is_err());
    assert!(!dir.path().join("bad.ply").exists());
    assert!(p.scalar_column("vertex", "x").is_none());
    assert!(p.vertex_xyz().is_none());
    assert!(p
        .set_scalar_column("vertex", "x", ScalarType::F32, &x)
        .is_err());
    assert!(p
        .set_scalar_column("vertex", "n", ScalarType::F32, &x)
        .is_err());
    p.data[0].row_offsets = Some(vec![0, 5, 2, 11]);
    assert!(p.scalar_column("vertex", "x").is_none());
    assert!(p.write_path(&out).is_err());
    p.data.clear();
    assert!(p.write_path(&out).is_err());
    assert!(p.scalar_column("vertex", "x").is_none());
    // A list row whose stored count runs past the row.
    let mut q = read_ok(RANGE_SCAN.as_bytes());
    q.data[1].bytes[0] = 200;
    assert!(q.list_column("range_grid", "vertex_indices").is_none());
}

/// Byte-level mutations of valid files (flips, truncations, insertions) must give `Ok` or
/// `Err`, never a panic or a runaway allocation.
#[test]
fn mutated_files_never_panic() {
    let mut seeds: Vec<Vec<u8>> = vec![RANGE_SCAN.as_bytes().to_vec()];
    let le = read_ok(RANGE_SCAN.as_bytes());
    let dir = tempfile::tempdir().unwrap();
    let lep = dir.path().join("le.ply");
    le.write_path(&lep).unwrap();
    seeds.push(std::fs::read(&lep).unwrap());
    let mut be = std::fs::read(&lep).unwrap();
    let pos = be
        .windows(20)
        .position(|w| w == b"binary_little_endian")
        .unwrap();
    be.splice(pos..pos + 20, b"binary_big_endian".iter().copied());
    seeds.push(be);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut rnd = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let path = dir.path().join("m.ply");
    for i in 0..1500 {
        let mut b = seeds[i % seeds.len()].clone();
        for _ in 0..(1 + rnd() % 4) {
            let at = (rnd() as usize) % b.len().max(1);
            match rnd() % 5 {
                0 => b.truncate(at),
                1 if !b.is_empty() => b[at] = rnd() as u8,
                2 => b.insert(
                    at.min(b.len()),
                    b"0123456789 -\n\xff"[(rnd() % 14) as usize],
                ),
                3 if !b.is_empty() => b[at] ^= 1 << (rnd() % 8),
                _ => {
                    let digits = format!("{}", rnd());
                    let at = at.min(b.len());
                    b.splice(at..at, digits.bytes());
                }
            }
        }
        std::fs::write(&path, &b).unwrap();
        if let Ok(p) = PlyFile::from_path(&path) {
            for (def, _) in p.header.elements.iter().zip(&p.data) {
                for prop in &def.props {
                    let _ = p.scalar_column(&def.name, &prop.name);
                    let _ = p.list_column(&def.name, &prop.name);
                }
            }
            let _ = p.vertex_xyz();
            if i % 25 == 0 {
                // Writing syncs to disk: only now and then.
                let _ = p.write_path(&dir.path().join("w.ply"));
            }
        }
    }
}

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(rel)
}

/// The binary copies of the Stanford bunny scans keep every vertex and the full
/// 400 x 512 range grid (see `fixtures/stanford-bunny/SOURCE.md`).
#[test]
fn fixture_stanford_bunny_counts() {
    let scans = [
        ("bun000", 40256),
        ("bun045", 40097),
        ("bun090", 30379),
        ("bun180", 40251),
        ("bun270", 31701),
        ("bun315", 35336),
        ("chin", 37738),
        ("ear_back", 32193),
        ("top2", 38298),
        ("top3", 36023),
    ];
    for (name, n) in scans {
        let p = PlyFile::from_path(&fixture(&format!("stanford-bunny/{name}.ply"))).unwrap();
        assert_eq!(p.header.encoding, Encoding::BinaryLe, "{name}");
        assert!(
            p.header.obj_info.iter().any(|o| o == "num_cols 512"),
            "{name}"
        );
        assert!(
            p.header.obj_info.iter().any(|o| o == "num_rows 400"),
            "{name}"
        );
        let xyz = p.vertex_xyz().unwrap();
        assert_eq!(xyz.len(), n, "{name}");
        let grid = p.list_column("range_grid", "vertex_indices").unwrap();
        assert_eq!(grid.len(), 400 * 512, "{name}");
        // Every vertex appears in exactly one grid cell, in grid order.
        let idx: Vec<u32> = grid.iter().flatten().copied().collect();
        assert!(grid.iter().all(|c| c.len() <= 1), "{name}");
        assert_eq!(idx, (0..n as u32).collect::<Vec<_>>(), "{name}");
    }
    let p = PlyFile::from_path(&fixture("stanford-bunny/bun000.ply")).unwrap();
    assert_eq!(
        p.vertex_xyz().unwrap()[0],
        [
            f64::from(-0.06325f32),
            f64::from(0.0359793f32),
            f64::from(0.0420873f32)
        ]
    );
}

/// The 3DTK scans: 81360 points each on a 226 x 360 grid given by `row` and `col`.
#[test]
fn fixture_3dtk_counts() {
    for name in ["scan000", "scan001", "scan002"] {
        let p = PlyFile::from_path(&fixture(&format!("3dtk-uos-3scans/{name}.ply"))).unwrap();
        assert_eq!(p.vertex_xyz().unwrap().len(), 81360, "{name}");
        let row = p.scalar_column("vertex", "row").unwrap();
        let col = p.scalar_column("vertex", "col").unwrap();
        assert_eq!(
            row.iter().copied().fold(f64::MIN, f64::max),
            225.0,
            "{name}"
        );
        assert_eq!(
            col.iter().copied().fold(f64::MIN, f64::max),
            359.0,
            "{name}"
        );
        assert_eq!(row.iter().copied().fold(f64::MAX, f64::min), 0.0, "{name}");
    }
}
