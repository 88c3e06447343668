//! PTX input and output: a two-block file written by `write_ptx` (with no-return cells and
//! cells without a point), a hand-written file that pins the column-major order and the
//! row-vector matrix, and errors that name the file, the block and the line.

use glam::{DMat4, DQuat, DVec3};
use mvao::io::output::ColorMode;
use mvao::io::ptx::*;
use mvao::io::raw::{PointTable, RawGrid};
use mvao::Error;
use std::path::Path;

fn finite(p: &[f64; 3]) -> bool {
    p.iter().all(|v| v.is_finite())
}

/// A gridded table over `rows × cols`; every 5th cell has no return, cell (0, 1) no point.
fn table(name: &str, pose: DMat4, rows: u32, cols: u32, colour: bool) -> PointTable {
    let (mut xyz, mut row, mut col, mut inten, mut rgb) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    // Written in row-major order on purpose: the writer must reorder.
    for r in 0..rows {
        for c in 0..cols {
            if (r, c) == (0, 1) {
                continue;
            }
            let k = r * cols + c;
            let p = if k % 5 == 3 {
                [f64::NAN; 3]
            } else {
                [
                    1.0 + c as f64 * 0.125,
                    -2.5 + r as f64 / 3.0,
                    0.1 * k as f64,
                ]
            };
            xyz.push(p);
            row.push(r);
            col.push(c);
            inten.push(k as f32 / 64.0);
            rgb.push([k as u8, 255 - k as u8, 7]);
        }
    }
    PointTable {
        name: name.into(),
        xyz,
        pose,
        rgb: colour.then_some(rgb),
        intensity: Some(inten),
        ao: Vec::new(),
        grid: Some(RawGrid {
            rows,
            cols,
            row,
            col,
        }),
        extra: Vec::new(),
    }
}

#[test]
fn two_blocks_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("site.ptx");
    let poses = [
        DMat4::from_rotation_translation(
            DQuat::from_axis_angle(DVec3::new(1.0, -2.0, 0.5).normalize(), 0.7),
            DVec3::new(1_000_000.25, -3.5, 250.125),
        ),
        DMat4::IDENTITY,
    ];
    let tables = [
        table("a", poses[0], 4, 6, true),
        table("b", poses[1], 3, 5, false),
    ];
    write_ptx(&tables, &f).unwrap();
    let inp = PtxInput::from_path(&f).unwrap();
    assert_eq!(inp.scans.len(), 2);
    let raw = inp.raw_scans();
    for (k, (t, s)) in tables.iter().zip(&inp.scans).enumerate() {
        let g = t.grid.as_ref().unwrap();
        assert_eq!(s.name, format!("site_{k}"));
        assert_eq!((s.rows, s.cols), (g.rows, g.cols));
        assert_eq!(s.len(), (g.rows * g.cols) as usize, "full grid");
        // The pose comes back exactly (round-trip precision), the header agrees with it.
        assert_eq!(s.pose, poses[k]);
        assert_eq!(s.header_mismatch, 0.0);
        assert_eq!(raw[k].pose, Some(poses[k]));
        assert_eq!(raw[k].scanner, Some(DVec3::ZERO));
        let rg = raw[k].grid.as_ref().unwrap();
        assert_eq!((rg.rows, rg.cols), (g.rows, g.cols));
        // Every table point is found in its cell with its values.
        for (i, (&r, &c)) in g.row.iter().zip(&g.col).enumerate() {
            let at = (c * g.rows + r) as usize;
            assert_eq!((rg.row[at], rg.col[at]), (r, c));
            let (p, q) = (t.xyz[i], s.xyz[at]);
            assert_eq!(finite(&p), finite(&q));
            if finite(&p) {
                assert_eq!(p, q);
                assert_eq!(s.intensity[at], t.intensity.as_ref().unwrap()[i]);
            }
            match (&t.rgb, &s.rgb) {
                (Some(a), Some(b)) => assert_eq!(a[i], b[at]),
                (None, None) => {}
                _ => panic!("colour presence differs"),
            }
        }
        // The cell without a point reads as no return.
        assert!(!finite(&s.xyz[g.rows as usize]));
    }
    // A table for another format: grid, pose, intensity in [0, 1], AO grey.
    let ao: Vec<f32> = (0..inp.scans[1].len()).map(|k| k as f32 / 20.0).collect();
    let t = inp.point_table(1, &ao, 1.0, ColorMode::Modulate).unwrap();
    assert_eq!(t.pose, DMat4::IDENTITY);
    assert!(t
        .intensity
        .as_ref()
        .unwrap()
        .iter()
        .all(|v| (0.0..=1.0).contains(v)));
    assert_eq!(t.rgb.as_ref().unwrap()[10], [128; 3]);
    assert!(inp.point_table(1, &ao[1..], 1.0, ColorMode::Keep).is_err());
    // A table without a grid cannot be written as PTX.
    let mut nogrid = tables[1].clone();
    nogrid.grid = None;
    let g = dir.path().join("nogrid.ptx");
    assert!(write_ptx(&[nogrid], &g).is_err());
    assert!(!g.exists());
}

const HAND: &str = "2
3
10 20 30
0 1 0
-1 0 0
0 0 1
0 1 0 0
-1 0 0 0
0 0 1 0
10 20 30 1
1 0 0 0.5 255 0 0
0 0 0 0.5 0 0 0
0 2 0 0.25 0 255 0
0 0 3 0.75 0 0 255
1 1 1 1 10 20 30
2 2 2 0 40 50 60
";

#[test]
fn hand_written_block_pins_conventions() {
    let inp = PtxInput::from_bytes(HAND.as_bytes(), Path::new("hand.ptx")).unwrap();
    let s = &inp.scans[0];
    assert_eq!(s.name, "hand");
    assert_eq!((s.cols, s.rows), (2, 3));
    assert_eq!(s.header_line, 1);
    assert_eq!(s.header_mismatch, 0.0);
    // Row-vector matrix: p' = p·M, so local x (1, 0, 0) goes to row 1 = (0, 1, 0) + t.
    let w = s.pose.transform_point3(DVec3::new(1.0, 0.0, 0.0));
    assert!(w.abs_diff_eq(DVec3::new(10.0, 21.0, 30.0), 1e-12), "{w}");
    // Column-major: records 0–2 are column 0, rows 0–2.
    let g = s.grid();
    assert_eq!(g.row, [0, 1, 2, 0, 1, 2]);
    assert_eq!(g.col, [0, 0, 0, 1, 1, 1]);
    assert_eq!(s.xyz[0], [1.0, 0.0, 0.0]);
    assert!(!finite(&s.xyz[1]), "0 0 0 is no return");
    assert_eq!(s.xyz[5], [2.0, 2.0, 2.0]);
    assert_eq!(s.intensity, [0.5, 0.5, 0.25, 0.75, 1.0, 0.0]);
    assert_eq!(s.rgb.as_ref().unwrap()[2], [0, 255, 0]);

    // Header and matrix that disagree (a user coordinate system at export): the matrix wins.
    let ucs = HAND.replacen("10 20 30\n0 1 0", "0 0 0\n1 0 0", 1);
    let s = &PtxInput::from_bytes(ucs.as_bytes(), Path::new("ucs.ptx"))
        .unwrap()
        .scans[0];
    assert_eq!(s.header_mismatch, 30.0);
    assert_eq!(s.scanner_position, DVec3::ZERO);
    assert!(s
        .pose
        .transform_point3(DVec3::X)
        .abs_diff_eq(DVec3::new(10.0, 21.0, 30.0), 1e-12));

    // A byte order mark before the first line is skipped.
    let bom = format!("\u{feff}{HAND}");
    assert_eq!(
        PtxInput::from_bytes(bom.as_bytes(), Path::new("b.ptx"))
            .unwrap()
            .scans[0]
            .cols,
        2
    );

    // Colours as 0–1 floats are scaled to 8 bits; CRLF line ends are fine.
    let float = HAND
        .replace("255 0 0", "1 0 0")
        .replace("0 255 0", "0 0.5 0")
        .replace("0 0 255", "0 0 1")
        .replace("10 20 30\n", "0.1 0.2 0.3\n")
        .replace("40 50 60", "0.4 0.5 0.6")
        .replace('\n', "\r\n");
    let s = &PtxInput::from_bytes(float.as_bytes(), Path::new("f.ptx"))
        .unwrap()
        .scans[0];
    let c = s.rgb.as_ref().unwrap();
    assert_eq!(c[0], [255, 0, 0]);
    assert_eq!(c[2], [0, 128, 0]);
    assert_eq!(c[4], [26, 51, 77]);
    // Four values per line: no colour.
    let four: String = HAND
        .lines()
        .enumerate()
        .map(|(i, l)| {
            let t: Vec<&str> = l.split(' ').collect();
            if i >= 10 {
                t[..4].join(" ") + "\n"
            } else {
                l.to_string() + "\n"
            }
        })
        .collect();
    assert!(PtxInput::from_bytes(four.as_bytes(), Path::new("g.ptx"))
        .unwrap()
        .scans[0]
        .rgb
        .is_none());
}

fn err(text: &str) -> String {
    let Err(e) = PtxInput::from_bytes(text.as_bytes(), Path::new("dir/scan.ptx")) else {
        panic!("expected an error");
    };
    assert!(matches!(e, Error::Format { .. }));
    let m = e.to_string();
    assert!(m.starts_with("dir/scan.ptx: "), "{m}");
    m
}

#[test]
fn errors_name_block_and_line() {
    let two = format!("{HAND}{HAND}");
    // The first block one point short: the second header starts early.
    let mut lines: Vec<&str> = two.lines().collect();
    lines.remove(12);
    let short = lines.join("\n") + "\n";
    let m = err(&short);
    assert!(
        m.ends_with("block 1 declares 2 × 3 = 6 points, found 5"),
        "{m}"
    );
    // One point too many in block 1.
    let long = format!("{HAND}3 3 3 0.5 1 1 1\n{HAND}");
    let m = err(&long);
    assert!(
        m.contains("block 1 declares 2 × 3 = 6 points, found more: line 17"),
        "{m}"
    );
    // Truncated in the points of block 2, and in its header.
    let m = err(&two[..two.len() - 20]);
    assert!(
        m.ends_with("block 2 declares 2 × 3 = 6 points, found 4; the file ends early (truncated)"),
        "{m}"
    );
    let m = err(&two[..two.len() - 17]);
    assert!(
        m.ends_with("found 5; the file ends early (truncated)"),
        "{m}"
    );
    let m = err(&two[..HAND.len() + 12]);
    assert!(m.contains("block 2: the file ends in the header"), "{m}");
    // A non-numeric value: block, line and token.
    let bad = two.replacen("2 2 2 0 40 50 60", "2 2 abc 0 40 50 60", 2);
    let bad = bad.replacen("2 2 abc 0 40 50 60", "2 2 2 0 40 50 60", 1);
    let m = err(&bad);
    assert!(
        m.contains("block 2, line 32: 'abc' is not a finite number"),
        "{m}"
    );
    // A wrong number of values.
    let m = err(&HAND.replace("0 0 3 0.75 0 0 255", "0 0 3 0.75 0 0"));
    assert!(m.contains("block 1, line 14: expected 7 values"), "{m}");
    // Bad header lines.
    let m = err(&HAND.replacen("10 20 30\n", "10 20\n", 1));
    assert!(
        m.contains("block 1, line 3: scanner position: expected 3 numbers, found 2"),
        "{m}"
    );
    let m = err(&HAND.replacen("2\n3\n", "2\nthree\n", 1));
    assert!(
        m.contains("block 1, line 2: expected the number of rows, found 'three'"),
        "{m}"
    );
    let m = err(&HAND.replacen("0 0 1 0\n", "0 0 1 nan\n", 1));
    assert!(
        m.contains("line 9: registration matrix row 3: 'nan' is not a finite number"),
        "{m}"
    );
    let m = err(&HAND.replace("1 1 1 1 10 20 30", "1 1 1 1 10 20 300"));
    assert!(m.contains("line 15: colour value 300 outside 0–255"), "{m}");
    // Empty and blank files.
    assert!(err("").contains("no PTX block"));
    assert!(err("\n  \n").contains("no PTX block"));
    // A missing file is an I/O error.
    let e = PtxInput::from_path(Path::new("/nonexistent/x.ptx")).unwrap_err();
    assert!(matches!(e, Error::Io { .. }));
}

#[test]
fn many_points_in_parallel_pieces() {
    // Large enough for several parse pieces; every value must land in its slot.
    let (rows, cols) = (300u32, 1000u32);
    let mut s =
        format!("{cols}\n{rows}\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
    for k in 0..rows * cols {
        s += &format!("{} {}.5 -{} 0.{}\n", k, k % 977, k % 13, k % 10);
    }
    let t = std::time::Instant::now();
    let inp = PtxInput::from_bytes(s.as_bytes(), Path::new("big.ptx")).unwrap();
    eprintln!("{} MB parsed in {:?}", s.len() >> 20, t.elapsed());
    let sc = &inp.scans[0];
    assert_eq!(sc.len(), 300_000);
    for k in [0usize, 1, 12345, 150_000, 299_999] {
        let want = [k as f64, (k % 977) as f64 + 0.5, -((k % 13) as f64)];
        assert_eq!(sc.xyz[k], want, "{k}");
        assert_eq!(sc.intensity[k], (k % 10) as f32 / 10.0);
    }
    // A bad value deep inside gets its exact line number.
    let bad = s.replacen("\n150000 519.5 ", "\n150000 5x9.5 ", 1);
    assert_ne!(bad, s);
    let m = err(&bad);
    assert!(m.contains("block 1, line 150011: '5x9.5'"), "{m}");
}

#[test]
fn reading_from_memory_equals_reading_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("site.ptx");
    let tables = [
        table(
            "a",
            DMat4::from_translation(DVec3::new(5.0, -1.0, 2.5)),
            4,
            6,
            true,
        ),
        table("b", DMat4::IDENTITY, 3, 5, false),
    ];
    write_ptx(&tables, &f).unwrap();
    let file = PtxInput::from_path(&f).unwrap();
    let mut mem = PtxInput::new(std::io::Cursor::new(std::fs::read(&f).unwrap())).unwrap();
    assert_eq!(mem.scans.len(), 2);
    // Scans are named after the file; a stream has none. Debug output compares NaN cells too.
    for (m, s) in mem.scans.iter_mut().zip(&file.scans) {
        m.name.clone_from(&s.name);
    }
    assert_eq!(format!("{:?}", mem.scans), format!("{:?}", file.scans));
    let err = PtxInput::new(std::io::Cursor::new(b"3\n".to_vec())).unwrap_err();
    assert!(err.to_string().contains("(PTX stream)"), "{err}");
}
