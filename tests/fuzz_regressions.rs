//! Regression tests for the fuzz targets under `fuzz/` (see `fuzz/README.md`).
//!
//! The checks are the fuzz targets' own (`fuzz/src/lib.rs`, included below), so each input here
//! goes through exactly the code path and the assertions of the target that found it: the
//! parser must return `Ok` or the right kind of `Err`, never panic, hang or allocate without
//! bound, and whatever parses must survive the column accessors, `scan_from_ply`,
//! `set_scalar_column`, `retain_vertices` and a write/read round trip unchanged.
//!
//! Every crash the fuzzer found is a named test with its input inline; the stored inputs under
//! `fuzz/regressions/<target>/` and the minimised corpus under `fuzz/corpus/<target>/` are run
//! too, plus a few hand-made nasty inputs per target.

#[allow(dead_code)]
#[path = "../fuzz/src/lib.rs"]
mod fuzz_checks;

use fuzz_checks::{
    check_align, check_e57, check_las, check_matrix, check_ply, check_ply_structured, check_ptx,
    ply_from_structure,
};
use mvao::io::align::{read_alignment, read_matrix_file, split_scale};
use mvao::io::las::LasInput;
use mvao::io::ply::PlyFile;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The files of `fuzz/<kind>/<target>/` (none if the directory does not exist), small ones only.
fn inputs(kind: &str, target: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz")
        .join(kind)
        .join(target);
    let Ok(rd) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = rd
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.is_file() && p.metadata().is_ok_and(|m| m.len() <= 64 << 10))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let b = std::fs::read(&p).unwrap();
            (p, b)
        })
        .collect()
}

/// Runs `check` on every stored input of `target`, naming the file on failure.
fn run_stored(target: &str, check: impl Fn(&[u8])) -> usize {
    let mut n = 0;
    for kind in ["regressions", "corpus"] {
        for (path, bytes) in inputs(kind, target) {
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| check(&bytes)));
            assert!(r.is_ok(), "{target}: input {} fails", path.display());
            n += 1;
        }
    }
    n
}

/// Runs `f` and asserts it takes less than `limit` (for inputs that used to hang).
fn within<T>(limit: Duration, what: &str, f: impl FnOnce() -> T) -> T {
    let t = Instant::now();
    let r = f();
    let took = t.elapsed();
    assert!(took < limit, "{what} took {took:?}, more than {limit:?}");
    r
}

// ---------------------------------------------------------------------------------------------
// Crashes found by the fuzzer (inputs minimised with `cargo fuzz tmin`)
// ---------------------------------------------------------------------------------------------

/// `ply_parse`: a carriage return inside a `comment` (or `obj_info`) line was kept by the
/// reader but turned into a space by the writer, so a written file did not read back the same.
#[test]
fn ply_parse_comment_inner_cr_roundtrip() {
    let input = b"ply\nformat ascii 1\ncomment se\r>\nend_header";
    assert_eq!(
        &input[..],
        include_bytes!("../fuzz/regressions/ply_parse/comment-inner-cr-roundtrip")
    );
    check_ply(input);
    let scratch = fuzz_checks::Scratch::new("regr-cr");
    let p = scratch.file("cr.ply");
    std::fs::write(
        &p,
        b"ply\nformat ascii 1.0\ncomment a\rb\r\nobj_info c\rd\nend_header\n",
    )
    .unwrap();
    let ply = PlyFile::from_path(&p).unwrap();
    assert_eq!(ply.header.comments, vec!["a b"]);
    assert_eq!(ply.header.obj_info, vec!["c d"]);
}

/// `ply_parse`: `retain_vertices` read a negative (or fractional, or NaN) list item with a
/// saturating cast, so `-1` in a face became a reference to vertex 0 instead of a dangling one
/// (the face was kept and pointed at the wrong vertex).
#[test]
fn ply_parse_retain_negative_face_index() {
    check_ply(include_bytes!(
        "../fuzz/regressions/ply_parse/retain-negative-face-index"
    ));

    // The same bug, by hand: faces referring to -1, 0.5 and NaN lose the reference (and so
    // are dropped); the range grid cell with -1 becomes empty; valid references survive.
    let scratch = fuzz_checks::Scratch::new("regr-retain");
    let p = scratch.file("neg.ply");
    std::fs::write(
        &p,
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
         property float z\nelement face 4\nproperty list uchar float vertex_indices\n\
         element range_grid 2\nproperty list uchar char vertex_indices\nend_header\n\
         0 0 0\n1 1 1\n1 -1\n1 0.5\n1 nan\n2 0 1\n1 -1\n1 1\n",
    )
    .unwrap();
    let kept = PlyFile::from_path(&p)
        .unwrap()
        .retain_vertices(&[true, true])
        .unwrap();
    assert_eq!(
        kept.list_column("face", "vertex_indices").unwrap(),
        vec![vec![0, 1]]
    );
    assert_eq!(
        kept.list_column("range_grid", "vertex_indices").unwrap(),
        vec![vec![], vec![1]]
    );
}

/// `align_mlp` (found by running the target binary on a large input, beyond the fuzzer's
/// default 4 KiB `-max_len`): the line number of every `MLMesh` was counted from the start of
/// the file as it was met, which is quadratic; 50 000 unclosed meshes in 1 MB ran past the
/// fuzzer's 10 s hang limit (more than 90 s under AddressSanitizer).
#[test]
fn align_mlp_many_meshes_line_numbers_not_quadratic() {
    let input = "<MLMesh filename=\"a\">".repeat(100_000);
    within(Duration::from_secs(3), "100 000 unclosed MLMesh", || {
        check_align("mlp", input.as_bytes())
    });
    let scratch = fuzz_checks::Scratch::new("regr-mlp");
    let p = scratch.file("a.mlp");
    let mut s = String::from("<MeshLabProject>\n");
    for i in 0..20_000 {
        s.push_str(&format!(
            "<MLMesh filename=\"s{i}.ply\"><MLMatrix44>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\
             </MLMatrix44></MLMesh>\n"
        ));
    }
    s.push_str("<MLMesh filename=\"bad.ply\"><MLMatrix44>1 0</MLMatrix44></MLMesh>\n");
    std::fs::write(&p, &s).unwrap();
    let e = within(Duration::from_secs(3), "20 000 meshes", || {
        read_alignment(&p).unwrap_err()
    });
    // The error still names the right line.
    assert!(
        e.to_string().contains("line 20002: matrix of 'bad.ply'"),
        "{e}"
    );
}

/// `align_conf` (same large-input probe): matching scans to entries counted every base name
/// against all others, 2·n² string comparisons (about 10^10 for 80 000 entries).
#[test]
fn align_conf_many_entries_matching_not_quadratic() {
    let mut s = String::new();
    for i in 0..80_000 {
        s.push_str(&format!("bmesh s{i}.ply {i} 0 0 0 0 0 1\n"));
    }
    within(Duration::from_secs(4), "80 000 bmesh entries", || {
        check_align("conf", s.as_bytes())
    });
}

/// `pose_matrix` (found by the target's check on a hand-made input while it was written): with
/// `--allow-scale`, a matrix whose scale is beyond double precision (`1e308` on the diagonal)
/// was accepted, because its determinant overflowed to infinity, and splitting it into a
/// rotation and a stretch gave NaN; a scale of 1e12 was split into a "rotation" still scaled,
/// because the polar iteration stopped after 20 halvings. The iteration is now scaled by the
/// determinant, and a pose that cannot be split is an error naming the file.
#[test]
fn pose_matrix_extreme_scale_split() {
    check_matrix(b"\x011e308 0 0 0 0 1e308 0 0 0 0 1e308 0 0 0 0 1");
    let scratch = fuzz_checks::Scratch::new("regr-split");
    let p = scratch.file("scan.txt");
    std::fs::write(&p, "1e308 0 0 0\n0 1e308 0 0\n0 0 1e308 0\n0 0 0 1\n").unwrap();
    let e = read_matrix_file(&p, "scan", true).unwrap_err().to_string();
    assert!(e.starts_with(&p.display().to_string()), "{e}");
    std::fs::write(&p, "1e200 0 0 0\n0 1 0 0\n0 0 1e-200 0\n0 0 0 1\n").unwrap();
    let e = read_matrix_file(&p, "scan", true).unwrap_err().to_string();
    assert!(
        e.contains("cannot be split into a rotation and a stretch"),
        "{e}"
    );
    // Large and small uniform scales with a rotation split exactly.
    for k in [1e-3, 1e6, 1e12] {
        let (c, s) = (0.6 * k, 0.8 * k);
        std::fs::write(
            &p,
            format!("{c} {} 0 1\n{s} {c} 0 2\n0 0 {k} 3\n0 0 0 1\n", -s),
        )
        .unwrap();
        let m = read_matrix_file(&p, "scan", true).unwrap();
        let (rigid, stretch) = split_scale(m);
        fuzz_checks::assert_rigid(rigid, "scan");
        assert!((rigid.x_axis.x - 0.6).abs() < 1e-12, "{rigid:?}");
        assert!((stretch.x_axis.x / k - 1.0).abs() < 1e-12, "{stretch:?}");
        check_matrix(&[&[1u8][..], std::fs::read(&p).unwrap().as_slice()].concat());
    }
}

/// `las_parse`: a LAS 1.4 header whose first EVLR starts beyond what a seek can reach
/// (byte 13 565 215 727 793 863 655) failed as an operating-system error, "Invalid argument
/// (os error 22)", instead of a format error saying what is wrong. The EVLR start (and the
/// LAS 1.3 waveform start) is now checked against the file's size; it is ignored when the
/// header counts no EVLR.
#[test]
fn las_parse_evlr_start_beyond_the_file() {
    check_las(include_bytes!(
        "../fuzz/regressions/las_parse/evlr-start-beyond-seek-range"
    ));
    let seed = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus/las_parse/seed-las14-f8"),
    )
    .unwrap();
    // The harness's first byte chooses the extension; the LAS header follows.
    let file = &seed[1..];
    let scratch = fuzz_checks::Scratch::new("regr-evlr");
    let p = scratch.file("s.las");
    for (start, count, ok) in [
        (u64::MAX, 1u32, false),
        (1 << 40, 2, false),
        (u64::MAX, 0, true),
    ] {
        let mut b = file.to_vec();
        b[235..243].copy_from_slice(&start.to_le_bytes());
        b[243..247].copy_from_slice(&count.to_le_bytes());
        check_las(&[&[0u8][..], &b].concat());
        std::fs::write(&p, &b).unwrap();
        match LasInput::from_path(&p) {
            Ok(l) => assert!(ok && l.len() == 5, "{start} {count}"),
            Err(e) => {
                assert!(!ok, "{e}");
                assert!(matches!(e, mvao::Error::Format { .. }), "{e:?}");
                assert!(e.to_string().contains("past the end of the file"), "{e}");
            }
        }
    }
}

/// The peak resident memory of this process so far, in bytes (Linux only).
fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// `las_parse`: a 1.2 KB LAZ file with a layered point format (7, with extra bytes) whose
/// chunk table describes no chunk made the decoder read a chunk anyway and allocate the layer
/// size its first chunk states, 1.8 GB and 3.8 GB, before failing. The chunk table must now
/// describe every point, and every chunk's layer sizes must fit in the chunk; a layer size
/// corrupted in a valid file is refused the same way.
#[test]
fn las_parse_laz_layer_sizes_are_bounded() {
    let before = peak_rss();
    let scratch = fuzz_checks::Scratch::new("regr-laz-layers");
    let p = scratch.file("s.laz");
    for (name, bytes) in [
        (
            "1.8GB",
            &include_bytes!("../fuzz/regressions/las_parse/laz-extra-bytes-layer-1.8GB")[..],
        ),
        (
            "3.8GB",
            &include_bytes!("../fuzz/regressions/las_parse/laz-extra-bytes-layer-3.8GB")[..],
        ),
    ] {
        within(Duration::from_secs(5), name, || check_las(bytes));
        std::fs::write(&p, &bytes[1..]).unwrap();
        let e = LasInput::from_path(&p).expect_err(name);
        assert!(matches!(e, mvao::Error::Format { .. }), "{e:?}");
        assert!(e.to_string().contains("chunk table"), "{e}");
        assert!(e.to_string().contains("s.laz"), "{e}");
    }
    // A valid layered LAZ (point format 6 and above) reads; its first chunk's first layer
    // size set to 3.75 GiB is refused before decoding.
    let seed = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus/las_parse/seed-table-laz14"),
    )
    .unwrap();
    let file = &seed[1..];
    let format = file[104] & 0x3f;
    assert!(
        format >= 6,
        "the seed should be layered, point format {format}"
    );
    std::fs::write(&p, file).unwrap();
    let n = LasInput::from_path(&p).expect("the seed reads").len();
    assert!(n > 0);
    let offset = u32::from_le_bytes(file[96..100].try_into().unwrap()) as usize;
    let record_len = u16::from_le_bytes(file[105..107].try_into().unwrap()) as usize;
    let layer0 = offset + 8 + record_len + 4;
    let mut b = file.to_vec();
    b[layer0..layer0 + 4].copy_from_slice(&0xF000_0000u32.to_le_bytes());
    check_las(&[&[1u8][..], &b].concat());
    std::fs::write(&p, &b).unwrap();
    let e = LasInput::from_path(&p).expect_err("corrupt layer size");
    assert!(e.to_string().contains("its layers claim"), "{e}");
    // Variable-size chunks whose table describes fewer points than the header: the decoder
    // indexed past the table's end (a panic, caught as "the decompressor failed"); the table
    // is now checked first.
    let short = include_bytes!("../fuzz/regressions/las_parse/laz-variable-chunks-short-table");
    within(Duration::from_secs(5), "short table", || check_las(short));
    std::fs::write(&p, &short[1..]).unwrap();
    let e = LasInput::from_path(&p).expect_err("short chunk table");
    assert!(e.to_string().contains("chunk table"), "{e}");
    // Records of almost 64 KiB: a batch of 65536 of them asked for 4 GiB before decoding.
    let long = include_bytes!("../fuzz/regressions/las_parse/laz-long-records-batch-4GB");
    within(Duration::from_secs(5), "long records", || check_las(long));
    // LASzip items whose sizes overflow 16 bits when summed (the decoder's own sum).
    let wide = include_bytes!("../fuzz/regressions/las_parse/laz-item-sizes-overflow");
    within(Duration::from_secs(5), "item sizes", || check_las(wide));
    // A corrupt arithmetic-coded stream makes the decoder assert deep inside; the panic is
    // caught and becomes a format error naming the file.
    let sym = include_bytes!("../fuzz/regressions/las_parse/laz-decoder-symbol-assertion");
    within(Duration::from_secs(5), "decoder assertion", || {
        check_las(sym)
    });
    std::fs::write(&p, &sym[1..]).unwrap();
    let e = LasInput::from_path(&p).expect_err("decoder assertion");
    assert!(matches!(e, mvao::Error::Format { .. }), "{e:?}");
    // A LASzip VLR that lists no items: the decoder's constructor panicked.
    let empty = include_bytes!("../fuzz/regressions/las_parse/laz-vlr-without-items");
    within(Duration::from_secs(5), "no items", || check_las(empty));
    std::fs::write(&p, &empty[1..]).unwrap();
    let e = LasInput::from_path(&p).expect_err("no items");
    assert!(e.to_string().contains("LASzip VLR"), "{e}");
    if let (Some(a), Some(b)) = (before, peak_rss()) {
        assert!(
            b.saturating_sub(a) < 512 << 20,
            "peak memory grew by {} bytes",
            b - a
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Stored inputs and hand-made nasty inputs, one test per target
// ---------------------------------------------------------------------------------------------

#[test]
fn ply_parse_stored_and_nasty_inputs() {
    let n = run_stored("ply_parse", check_ply);
    assert!(n > 0, "no stored inputs found under fuzz/");
    let cases: &[&[u8]] = &[
        b"",
        b"ply",
        b"ply\n",
        b"\xff\xfe\x00ply\n",
        b"ply\nformat ascii 1.0\n",
        b"ply\nformat ascii 1.0\nend_header\n",
        // Non-UTF-8 in names, comments and obj_info.
        b"ply\nformat ascii 1.0\ncomment \xff\xfe\nobj_info \xc3\nelement v\xffx 1\n\
          property float \x80\nend_header\n1\n",
        // Names the writer cannot write (control characters, unicode whitespace).
        "ply\nformat ascii 1.0\nelement a\u{b}b 1\nproperty float x\u{a0}y\nend_header\n1\n"
            .as_bytes(),
        // Huge element counts: binary, ascii, with and without properties.
        b"ply\nformat binary_little_endian 1.0\nelement vertex 18446744073709551615\n\
          property float x\nend_header\n\0\0\0\0",
        b"ply\nformat binary_little_endian 1.0\nelement vertex 2305843009213693952\n\
          property double x\nproperty double y\nend_header\n",
        b"ply\nformat ascii 1.0\nelement vertex 18446744073709551615\nproperty float x\n\
          end_header\n1 2 3\n",
        b"ply\nformat ascii 1.0\nelement vertex 18446744073709551615\nend_header\n",
        b"ply\nformat binary_big_endian 1.0\nelement vertex 99999999999\nelement face 3\n\
          property list uchar int vertex_indices\nend_header\n\x01\0\0\0\x05\x00\x00",
        b"ply\nformat ascii 1.0\nelement vertex 18446744073709551616\nend_header\n",
        b"ply\nformat ascii 1.0\nelement vertex -1\nend_header\n",
        // Negative and huge list counts.
        b"ply\nformat binary_little_endian 1.0\nelement face 1\n\
          property list int int vertex_indices\nend_header\n\xff\xff\xff\xff",
        b"ply\nformat binary_little_endian 1.0\nelement face 1\n\
          property list uint double vertex_indices\nend_header\n\xff\xff\xff\xff",
        b"ply\nformat binary_big_endian 1.0\nelement face 1\n\
          property list char uchar vertex_indices\nend_header\n\x80",
        b"ply\nformat ascii 1.0\nelement face 2\nproperty list uchar int vertex_indices\n\
          end_header\n1 0\n-1 3\n",
        b"ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\n\
          end_header\n256 1\n",
        b"ply\nformat ascii 1.0\nelement face 1\nproperty list float int vertex_indices\n\
          end_header\n1 1\n",
        // Values out of range, NaN and infinities, over-long tokens.
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
          property float z\nproperty uchar red\nend_header\nnan inf -inf 255\n1e39 -0 1e-46 0\n\
          1 2 3 256\n",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty int x\nend_header\n1e300\n",
        // Vertex indices that are negative, fractional, NaN, out of range, with a mask.
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
          property float z\nelement face 3\nproperty list uchar double vertex_indices\n\
          property list uchar int vertex_index\nend_header\n0 0 0\n1 1 1\nnan 2 2\n\
          3 0 1 2 1 -5\n2 -1 1e300 0\n1 nan 2 0 2\n",
        // A Stanford range grid whose size does not match, and one that does.
        b"ply\nformat ascii 1.0\nobj_info num_cols 2\nobj_info num_rows 3\nelement vertex 1\n\
          property float x\nproperty float y\nproperty float z\nelement range_grid 2\n\
          property list uchar int vertex_indices\nend_header\n0 0 0\n1 0\n0\n",
        b"ply\nformat ascii 1.0\nobj_info num_cols 1\nobj_info num_rows 2\nelement vertex 2\n\
          property float x\nproperty float y\nproperty float z\nelement range_grid 2\n\
          property list uchar int vertex_indices\nend_header\n0 0 0\n1 1 1\n1 1\n1 0\n",
        // Row/column indices, normals, a sensor comment.
        b"ply\nformat ascii 1.0\ncomment sensor ortho\nelement vertex 2\nproperty float x\n\
          property float y\nproperty float z\nproperty float nx\nproperty float ny\n\
          property float nz\nproperty int row\nproperty int col\nend_header\n\
          0 0 0 0 0 0 0 0\n1 1 1 nan 1 0 9999999 3\n",
        // x/y/z present but one of them a list.
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n\
          property list uchar float y\nproperty float z\nend_header\n1 1 2 3\n",
        // Duplicate elements and properties, the property to be set already present.
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float x\n\
          property list uchar int fuzz_ao\nelement vertex 1\nproperty float y\nend_header\n\
          1 2 0\n3\n",
        b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty short fuzz_ao\n\
          end_header\n1 2\n3 4\n",
        // A header line without a newline and a header that never ends.
        b"ply\nformat binary_little_endian 1.0\ncomment aaaaaaaaaaaaaaaaaaaaaaaaaa",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n",
    ];
    for c in cases {
        check_ply(c);
    }
    // A header line longer than the limit.
    let mut long = b"ply\nformat ascii 1.0\ncomment ".to_vec();
    long.extend(std::iter::repeat_n(b'x', 70 << 10));
    long.extend_from_slice(b"\nend_header\n");
    check_ply(&long);
}

#[test]
fn ply_header_stored_and_nasty_inputs() {
    let n = run_stored("ply_header", check_ply_structured);
    assert!(n > 0, "no stored inputs found under fuzz/");
    // Every byte value as the first few choices, then a run of each body byte.
    for a in 0..=255u8 {
        let data = [
            a,
            a.wrapping_mul(7),
            5,
            a,
            a ^ 0x55,
            3,
            a,
            11,
            a,
            0x80 | a,
            a,
            2,
            a,
        ];
        check_ply_structured(&data);
    }
    check_ply_structured(&[]);
    check_ply_structured(&[0xff; 200]);
    // The generator itself: a fixed input gives a fixed file.
    let made = ply_from_structure(&[2, 6, 1, 2, 0, 0, 2]);
    assert!(made.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
    assert!(made.ends_with(b"end_header\n"));
}

#[test]
fn align_conf_stored_and_nasty_inputs() {
    let n = run_stored("align_conf", |b| check_align("conf", b));
    assert!(n > 0, "no stored inputs found under fuzz/");
    let cases: &[&[u8]] = &[
        b"",
        b"\xff\xfe bmesh",
        b"bmesh\n",
        b"bmesh a.ply\n",
        b"bmesh a.ply 0 0 0 0 0 0 1 extra\n",
        b"bmesh a.ply nan 0 0 0 0 0 1\n",
        b"bmesh a.ply 0 0 0 nan 0 0 1\n",
        b"bmesh a.ply 0 0 0 0 0 0 0\n",
        b"bmesh a.ply 0 0 0 1e200 1e200 0 0\n",
        b"bmesh a.ply 0 0 0 1e-200 0 0 0\n",
        b"bmesh a.ply 1e308 1e308 1e308 0 0 0 1\n",
        b"bmesh a.ply inf 0 0 0 0 0 1\n",
        b"bmesh a.ply 0 0 0 0.5 0.5 0.5 0.5\nbmesh a.ply 0 0 0 0 0 0 1\n",
        b"bmesh a.ply 0 0 0 0 0 0 1\nbmesh ./a.ply 0 0 0 0 0 0 1\n",
        b"bmesh x/a.ply 0 0 0 0 0 0 1\nbmesh y/a.ply 0 0 0 0 0 0 1\n",
        b"bmesh ../a.ply 0 0 0 0 0 0 1\nbmesh /abs/b.ply 0 0 0 0 0 0 1\n",
        b"bmesh . 0 0 0 0 0 0 1\n",
        b"camera 0 0 0 0 0 0 1\n# bmesh commented.ply\n",
        b"\r\nbmesh a.ply\t0\t0\t0\t0\t0\t0\t1\r\n",
    ];
    for c in cases {
        check_align("conf", c);
    }
}

#[test]
fn align_mlp_stored_and_nasty_inputs() {
    let n = run_stored("align_mlp", |b| check_align("mlp", b));
    assert!(n > 0, "no stored inputs found under fuzz/");
    let m = |body: &str| format!("<MeshLabProject><MeshGroup>{body}</MeshGroup></MeshLabProject>");
    let id = "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1";
    let cases: Vec<String> = vec![
        String::new(),
        "<".into(),
        "<MLMesh".into(),
        m(&format!("<MLMesh filename=\"a.ply\"><MLMatrix44>{id}</MLMatrix44></MLMesh>")),
        m(&format!("<MLMesh label=\"a.ply\"><MLMatrix44>{id}</MLMatrix44></MLMesh>")),
        m(&format!("<MLMesh><MLMatrix44>{id}</MLMatrix44></MLMesh>")),
        m("<MLMesh filename=\"a.ply\"/>"),
        m("<MLMesh filename=\"a.ply\"></MLMesh>"),
        m("<MLMesh filename=\"a.ply\"><MLMatrix44>nan 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</MLMatrix44></MLMesh>"),
        m("<MLMesh filename=\"a.ply\"><MLMatrix44>2 0 0 0 0 2 0 0 0 0 2 0 0 0 0 1</MLMatrix44></MLMesh>"),
        m("<MLMesh filename=\"a.ply\"><MLMatrix44>-1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</MLMatrix44></MLMesh>"),
        m("<MLMesh filename=\"a.ply\"><MLMatrix44>1 0 0 0 0 1 0 0 0 0 1 0 1 0 0 1</MLMatrix44></MLMesh>"),
        m("<MLMesh filename=\"a.ply\"><MLMatrix44>1e308 0 0 0 0 1e308 0 0 0 0 1 0 0 0 0 1</MLMatrix44></MLMesh>"),
        m(&format!("<MLMesh filename=\"a&amp;&#x0;.ply\"><MLMatrix44>{id}</MLMatrix44></MLMesh>")),
        m(&format!("<MLMesh filename=\"&bogus;\"><MLMatrix44>{id}</MLMatrix44></MLMesh>")),
        m(&format!("<MLMesh filename=\"a.ply\"><MLMatrix44><![CDATA[{id}]]><!-- c --></MLMatrix44></MLMesh>")),
        m("<MLMesh filename=\"a.ply\"><MLMatrix44>1 0 0 0 <x>0 1 0 0</x> 0 0 1 0 0 0 0 1</MLMatrix44></MLMesh>"),
        m(&format!("<MLMesh filename=\"a.ply\"><MLMatrix44>{id}</MLMatrix44><MLMatrix44>{id}</MLMatrix44></MLMesh>")),
        m(&format!("<MLMesh filename=\"a.ply\"><MLMatrix44>{id}</MLMatrix44></MLMesh><MLMesh filename=\"a.ply\"><MLMatrix44>{id}</MLMatrix44></MLMesh>")),
        m(&format!("<MLMesh filename=\"a.ply\" filename=\"b.ply\"><MLMatrix44>{id}</MLMatrix44></MLMesh>")),
        m(&format!("<MLMesh filename=a.ply><MLMatrix44>{id}</MLMatrix44></MLMesh>")),
        m(&format!("<MLMesh filename=\"a.ply\"><MLMatrix44>{id}</MLMatrix44></Other></MLMesh>")),
        format!("<MLMatrix44>{id}</MLMatrix44>"),
    ];
    for c in &cases {
        check_align("mlp", c.as_bytes());
    }
    check_align(
        "mlp",
        b"<MLMesh filename=\"\xff\"><MLMatrix44>1</MLMatrix44></MLMesh>",
    );
    // Deeply nested XML, closed and unclosed.
    let deep = format!("{}{}", "<a>".repeat(100_000), "</a>".repeat(100_000));
    check_align("mlp", deep.as_bytes());
    check_align(
        "mlp",
        "<MLMesh filename=\"a\"><MLMatrix44>"
            .repeat(20_000)
            .as_bytes(),
    );
}

#[test]
fn align_json_stored_and_nasty_inputs() {
    let n = run_stored("align_json", |b| check_align("json", b));
    assert!(n > 0, "no stored inputs found under fuzz/");
    let id = "[1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]";
    let cases: Vec<String> = vec![
        String::new(),
        "{}".into(),
        "[]".into(),
        "null".into(),
        format!("{{\"a.ply\": {id}}}"),
        format!("{{\"a.ply\": {id}, \"a.ply\": {id}}}"),
        format!("{{\"\": {id}}}"),
        format!("{{\"\\u0000\": {id}, \"x/../a\": {id}}}"),
        "{\"a.ply\": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0]}".into(),
        "{\"a.ply\": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1,1]}".into(),
        "{\"a.ply\": [1e400,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}".into(),
        "{\"a.ply\": [\"1\",0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}".into(),
        "{\"a.ply\": [null,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}".into(),
        "{\"a.ply\": [NaN,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}".into(),
        "{\"a.ply\": [0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,1]}".into(),
        "{\"a.ply\": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1e-300]}".into(),
        "{\"a.ply\": [18446744073709551615,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}".into(),
        "{\"a.ply\": {\"m\": 1}}".into(),
        format!("{{\"a.ply\": {id}}} trailing"),
        format!("{}{}", "[".repeat(100_000), "]".repeat(100_000)),
        format!(
            "{{\"a\":{}{}}}",
            "{\"a\":".repeat(50_000),
            "}".repeat(50_000)
        ),
    ];
    for c in &cases {
        check_align("json", c.as_bytes());
    }
    check_align("json", b"{\"\xff\": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}");
}

#[test]
fn ptx_parse_stored_and_nasty_inputs() {
    let n = run_stored("ptx_parse", check_ptx);
    assert!(n > 0, "no stored inputs found under fuzz/");
    let header = "1\n2\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
    let cases: Vec<String> = vec![
        String::new(),
        "\n\n \r\n".into(),
        "\u{feff}".into(),
        "1\n".into(),
        "1\n1\n".into(),
        format!("{header}1 2 3 0.5\n4 5 6 0.5\n"),
        format!("{header}1 2 3 0.5 1 2 3\n4 5 6 0.5 1 2 3\n"),
        // Too few and too many points, a wrong field count, colours out of range.
        format!("{header}1 2 3 0.5\n"),
        format!("{header}1 2 3 0.5\n4 5 6 0.5\n7 8 9 0.5\n"),
        format!("{header}1 2 3\n4 5 6 0.5\n"),
        format!("{header}1 2 3 0.5 256 0 0\n4 5 6 0.5 0 0 0\n"),
        format!("{header}1 2 3 0.5 -1 0 0\n4 5 6 0.5 0 0 0\n"),
        // Non-finite and huge values in points and in the matrix.
        format!("{header}nan 2 3 0.5\ninf 5 6 0.5\n"),
        format!("{header}1e308 1e308 1e308 0.5\n-1e308 0 0 0.5\n"),
        format!("{header}1e-320 0 0 0.5\n0 0 0 0.5\n"),
        header.replace("1 0 0 0\n0 1 0 0", "2 0 0 0\n0 1 0 0") + "1 2 3 0.5\n4 5 6 0.5\n",
        header.replace("0 0 0 1\n", "0 0 0 nan\n") + "1 2 3 0.5\n4 5 6 0.5\n",
        header.replace("0 0 0 1\n", "1e308 0 0 1\n") + "1 2 3 0.5\n4 5 6 0.5\n",
        header.replace("1 0 0 0\n", "-1 0 0 0\n") + "1 2 3 0.5\n4 5 6 0.5\n",
        // Huge, zero and overflowing sizes.
        header.replacen("1\n2\n", "4294967295\n4294967295\n", 1),
        header.replacen("1\n2\n", "0\n0\n", 1),
        header.replacen("1\n2\n", "0\n5\n", 1) + "1 2 3 0.5\n",
        header.replacen("1\n2\n", "4294967296\n1\n", 1),
        header.replacen("1\n2\n", "-1\n2\n", 1),
        // Two blocks, the second cut short in its header and in its points.
        format!("{header}1 2 3 0.5\n4 5 6 0.5\n{header}1 2 3 0.5\n"),
        format!("{header}1 2 3 0.5\n4 5 6 0.5\n1\n2\n0 0 0\n"),
        // Every point without a return.
        format!("{header}0 0 0 0.5\n0 0 0 0.5\n"),
        // All points at the scanner but one within 1e-12 m.
        format!("{header}1e-12 0 0 0.5\n0 0 0 0.5\n"),
    ];
    for c in &cases {
        check_ptx(c.as_bytes());
    }
    check_ptx(
        b"1\n1\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n\xff 2 3 0.5\n",
    );
}

#[test]
fn las_parse_stored_and_nasty_inputs() {
    let n = run_stored("las_parse", check_las);
    assert!(n > 0, "no stored inputs found under fuzz/");
    // The hand-made seeds (the grown corpus runs once, above).
    let seeds = inputs("corpus", "las_parse").into_iter().filter(|(p, _)| {
        p.file_name()
            .is_some_and(|f| f.to_string_lossy().starts_with("seed"))
    });
    for (_, seed) in seeds {
        // Every prefix of a seed (a truncated file), as LAS and as LAZ.
        for cut in (0..seed.len()).step_by(7) {
            let mut b = seed[..cut].to_vec();
            check_las(&b);
            if let Some(first) = b.first_mut() {
                *first ^= 1;
                check_las(&b);
            }
        }
        // Each header byte set to 0xff.
        for at in 1..seed.len().min(400) {
            let mut b = seed.clone();
            b[at] = 0xff;
            check_las(&b);
        }
    }
    check_las(b"");
    check_las(b"\0LASF");
    check_las(b"\x01LASF");
}

#[test]
fn e57_parse_stored_and_nasty_inputs() {
    let n = run_stored("e57_parse", check_e57);
    assert!(n > 0, "no stored inputs found under fuzz/");
    for (_, seed) in inputs("corpus", "e57_parse") {
        // Truncated at every 97th byte, and each byte of the file header and of the XML
        // section's start flipped (checksums are recomputed, so the reader sees the damage).
        for cut in (0..seed.len()).step_by(97) {
            check_e57(&seed[..cut]);
        }
        for at in (0..seed.len()).step_by(13) {
            let mut b = seed.clone();
            b[at] ^= 0x5a;
            check_e57(&b);
        }
    }
    check_e57(b"");
    check_e57(b"ASTM-E57");
    // The checksum helpers are each other's inverse on whole pages.
    let data: Vec<u8> = (0..3000u32).map(|i| (i * 7 % 251) as u8).collect();
    let paged = fuzz_checks::scans::e57_with_checksums(&data);
    assert_eq!(paged.len(), 3 * 1024);
    assert_eq!(
        &fuzz_checks::scans::e57_without_checksums(&paged)[..3000],
        &data[..]
    );
}

#[test]
fn align_aln_stored_and_nasty_inputs() {
    let n = run_stored("align_aln", |b| check_align("aln", b));
    assert!(n > 0, "no stored inputs found under fuzz/");
    let id = "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
    let cases: Vec<String> = vec![
        String::new(),
        "0\n".into(),
        "-1\n".into(),
        "18446744073709551616\n".into(),
        "18446744073709551615\na.ply\n".into(),
        "1\n".into(),
        "1\na.ply\n".into(),
        format!("1\na.ply\n#\n{id}"),
        format!("1\na.ply\n{id}0\n"),
        format!("2\na.ply\n#\n{id}a.ply\n#\n{id}0\n"),
        format!("2\na.ply\n#\n{id}./a.ply\n#\n{id}0\n"),
        format!("1\na.ply\n#\n1 0 0 0 0 1 0 0\n0 0 1 0 0 0 0 1\n"),
        format!("1\na.ply\n#\n1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1 9\n"),
        "1\na.ply\n#\n2 0 0 0\n0 2 0 0\n0 0 2 0\n0 0 0 1\n".into(),
        "1\na.ply\n#\nnan 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n".into(),
        "1\na.ply\n#\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n".into(),
        "1\n#\n#\n#\n".into(),
        format!("1\n\u{0}\n#\n{id}"),
    ];
    for c in &cases {
        check_align("aln", c.as_bytes());
    }
    check_align(
        "aln",
        b"1\n\xff.ply\n#\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
    );
}

#[test]
fn pose_matrix_stored_and_nasty_inputs() {
    let n = run_stored("pose_matrix", check_matrix);
    assert!(n > 0, "no stored inputs found under fuzz/");
    let cases: &[&str] = &[
        "",
        "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1",
        "1,0,0,0;0,1,0,0;0,0,1,0;0,0,0,1",
        "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0",
        "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1 1",
        "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1 # trailing comment",
        "# only a comment",
        "2 0 0 0 0 2 0 0 0 0 2 0 0 0 0 1",
        "0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 1",
        "-1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1",
        "1 1e308 0 0 0 1 0 0 0 0 1 0 0 0 0 1",
        "1e308 0 0 0 0 1e308 0 0 0 0 1e308 0 0 0 0 1",
        "1e-300 0 0 0 0 1e-300 0 0 0 0 1e-300 0 0 0 0 1",
        "1 0 0 0 0 1 0 0 0 0 1 0 0 0 1e-10 1",
        "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1.0000000001",
        "nan 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1",
        "1 0 0 inf 0 1 0 0 0 0 1 0 0 0 0 1",
        "1 2 0 0 0 1 0 0 0 0 1 0 0 0 0 1",
    ];
    for c in cases {
        for scale in [0u8, 1] {
            let mut b = vec![scale];
            b.extend_from_slice(c.as_bytes());
            check_matrix(&b);
        }
    }
    check_matrix(&[]);
    check_matrix(b"\x00\xff\xfe");
}
