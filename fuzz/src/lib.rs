//! The checks the fuzz targets run on every input, shared with `tests/fuzz_regressions.rs`
//! (which includes this file with `#[path]`), so a regression test runs exactly the code path
//! of the target that found the input.
//!
//! Each check feeds bytes through the public, path-based API (a scratch file per process and
//! thread, under `/dev/shm` when it exists so that the atomic writer's `fsync` costs nothing)
//! and asserts the library's invariants. A failed assertion is a bug in the library (or in
//! these checks); an `Err` from the library is fine as long as it is the right kind of error
//! and names the file.

use glam::{DMat3, DMat4, DVec4};
use mvao::io::align::{check_rigid, match_scans, poses_for_scans, read_alignment};
use mvao::io::ply::scan::scan_from_ply;
use mvao::io::ply::{ElementData, ElementDef, Encoding, PlyFile, PropertyKind, ScalarType};
use mvao::Error;
use std::path::{Path, PathBuf};

pub mod scans;
pub use scans::{check_e57, check_las, check_matrix, check_ptx};

/// Elements with more rows than this are not given to the harness's own per-row allocations
/// (masks, value columns); the library still reads them.
pub const MAX_HARNESS_ROWS: usize = 1 << 16;

// ---------------------------------------------------------------------------------------------
// Scratch files
// ---------------------------------------------------------------------------------------------

/// A scratch directory for one check, unique per process and thread, removed on drop.
pub struct Scratch(PathBuf);

impl Scratch {
    /// Creates (or reuses) `mvao-fuzz-<tag>-<pid>-<thread>` in `/dev/shm` or the temp dir.
    pub fn new(tag: &str) -> Scratch {
        let shm = Path::new("/dev/shm");
        let base = if shm.is_dir() {
            shm.to_path_buf()
        } else {
            std::env::temp_dir()
        };
        let tid = format!("{:?}", std::thread::current().id());
        let tid: String = tid.chars().filter(char::is_ascii_digit).collect();
        let dir = base.join(format!("mvao-fuzz-{tag}-{}-{tid}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("create scratch dir");
        Scratch(dir)
    }

    /// A file in the scratch directory.
    pub fn file(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    /// The scratch directory.
    pub fn dir(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

// ---------------------------------------------------------------------------------------------
// PLY
// ---------------------------------------------------------------------------------------------

/// Target `ply_parse`: arbitrary bytes as a PLY file.
pub fn check_ply(bytes: &[u8]) {
    let scratch = Scratch::new("ply");
    let path = scratch.file("input.ply");
    std::fs::write(&path, bytes).expect("write scratch input");
    let ply = match PlyFile::from_path(&path) {
        Ok(p) => p,
        Err(e) => {
            assert!(
                matches!(e, Error::Format { .. }),
                "a bad ply must give a format error, got {e:?}"
            );
            assert!(e.to_string().contains(&path.display().to_string()), "{e}");
            return;
        }
    };
    check_parsed(&ply, &path, bytes, &scratch);
}

/// Target `ply_header`: a header built from the bytes (see [`ply_from_structure`]).
pub fn check_ply_structured(data: &[u8]) {
    check_ply(&ply_from_structure(data));
}

/// Everything done with a file that parsed.
fn check_parsed(ply: &PlyFile, path: &Path, bytes: &[u8], scratch: &Scratch) {
    assert_eq!(ply.data.len(), ply.header.elements.len());
    let decoded: Vec<Option<Rows>> = ply
        .header
        .elements
        .iter()
        .zip(&ply.data)
        .map(|(d, b)| decode(d, b))
        .collect();
    check_columns(ply, &decoded);
    check_scan(ply, path, &decoded);
    roundtrip(ply, scratch, "as read");
    check_set_column(ply, bytes, scratch);
    check_retain(ply, bytes, scratch);
}

/// One decoded value: a scalar or a list, as f64.
#[derive(Debug, Clone)]
pub enum Val {
    /// A scalar property.
    S(f64),
    /// A list property's items.
    L(Vec<f64>),
}

impl PartialEq for Val {
    /// Bitwise, so NaN equals the same NaN.
    fn eq(&self, other: &Val) -> bool {
        match (self, other) {
            (Val::S(a), Val::S(b)) => a.to_bits() == b.to_bits(),
            (Val::L(a), Val::L(b)) => {
                a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
            }
            _ => false,
        }
    }
}

/// The rows of an element.
pub type Rows = Vec<Vec<Val>>;

/// Size in bytes of a scalar type.
pub fn size_of(t: ScalarType) -> usize {
    match t {
        ScalarType::I8 | ScalarType::U8 => 1,
        ScalarType::I16 | ScalarType::U16 => 2,
        ScalarType::I32 | ScalarType::U32 | ScalarType::F32 => 4,
        ScalarType::F64 => 8,
    }
}

/// The little-endian value of type `t` at the start of `b`.
fn read_le(t: ScalarType, b: &[u8]) -> Option<f64> {
    let a = |n: usize| b.get(..n);
    Some(match t {
        ScalarType::I8 => f64::from(i8::from_le_bytes(a(1)?.try_into().ok()?)),
        ScalarType::U8 => f64::from(u8::from_le_bytes(a(1)?.try_into().ok()?)),
        ScalarType::I16 => f64::from(i16::from_le_bytes(a(2)?.try_into().ok()?)),
        ScalarType::U16 => f64::from(u16::from_le_bytes(a(2)?.try_into().ok()?)),
        ScalarType::I32 => f64::from(i32::from_le_bytes(a(4)?.try_into().ok()?)),
        ScalarType::U32 => f64::from(u32::from_le_bytes(a(4)?.try_into().ok()?)),
        ScalarType::F32 => f64::from(f32::from_le_bytes(a(4)?.try_into().ok()?)),
        ScalarType::F64 => f64::from_le_bytes(a(8)?.try_into().ok()?),
    })
}

/// Decodes an element body independently of the library; `None` for a property-less element
/// (whose count may be huge). Panics if the body does not match the declaration: the reader
/// and every mutation must keep them consistent.
pub fn decode(def: &ElementDef, data: &ElementData) -> Option<Rows> {
    if def.props.is_empty() {
        assert!(
            data.bytes.is_empty(),
            "element '{}' without properties holds bytes",
            def.name
        );
        return None;
    }
    let ranges: Vec<(usize, usize)> = match &data.row_offsets {
        Some(offs) => {
            assert_eq!(offs.len(), def.count + 1, "row offsets of '{}'", def.name);
            assert_eq!(offs.first(), Some(&0));
            assert_eq!(offs.last(), Some(&data.bytes.len()));
            offs.windows(2).map(|w| (w[0], w[1])).collect()
        }
        None => {
            let stride: usize = def
                .props
                .iter()
                .map(|p| match p.kind {
                    PropertyKind::Scalar(t) => size_of(t),
                    PropertyKind::List { .. } => {
                        panic!("list element '{}' without row offsets", def.name)
                    }
                })
                .sum();
            assert_eq!(
                data.bytes.len(),
                def.count * stride,
                "fixed body of '{}'",
                def.name
            );
            (0..def.count)
                .map(|i| (i * stride, (i + 1) * stride))
                .collect()
        }
    };
    let mut rows = Vec::with_capacity(ranges.len());
    for (a, b) in ranges {
        assert!(a <= b, "row offsets of '{}' decrease", def.name);
        let row = &data.bytes[a..b];
        let mut off = 0;
        let mut vals = Vec::with_capacity(def.props.len());
        for p in &def.props {
            match p.kind {
                PropertyKind::Scalar(t) => {
                    vals.push(Val::S(
                        read_le(t, &row[off..]).expect("scalar inside its row"),
                    ));
                    off += size_of(t);
                }
                PropertyKind::List { count, item } => {
                    let n = read_le(count, &row[off..]).expect("list count inside its row");
                    assert!(n >= 0.0 && n.fract() == 0.0, "stored list count {n}");
                    off += size_of(count);
                    let mut items = Vec::with_capacity(n as usize);
                    for _ in 0..n as usize {
                        items.push(read_le(item, &row[off..]).expect("list item inside its row"));
                        off += size_of(item);
                    }
                    vals.push(Val::L(items));
                }
            }
        }
        assert_eq!(off, row.len(), "row of '{}' has trailing bytes", def.name);
        rows.push(vals);
    }
    Some(rows)
}

/// `scalar_column`, `list_column` and `vertex_xyz` against the independent decoding.
fn check_columns(ply: &PlyFile, decoded: &[Option<Rows>]) {
    for (ei, def) in ply.header.elements.iter().enumerate() {
        // The accessors find the first element and property of a name.
        if ply.element(&def.name) != Some(ei) {
            continue;
        }
        let rows = decoded[ei].as_ref();
        for (pi, p) in def.props.iter().enumerate() {
            assert!(ply.has_property(&def.name, &p.name));
            if def.props.iter().position(|q| q.name == p.name) != Some(pi) {
                continue;
            }
            let rows = rows.expect("element with properties decodes");
            let col = ply.scalar_column(&def.name, &p.name);
            let list = ply.list_column(&def.name, &p.name);
            match p.kind {
                PropertyKind::Scalar(_) => {
                    assert!(list.is_none());
                    let col = col.expect("scalar column of a parsed file");
                    assert_eq!(col.len(), def.count);
                    for (v, r) in col.iter().zip(rows) {
                        assert_eq!(Val::S(*v), r[pi]);
                    }
                }
                PropertyKind::List { .. } => {
                    assert!(col.is_none());
                    let whole = rows.iter().all(|r| match &r[pi] {
                        Val::L(items) => items.iter().all(|&v| as_index(v).is_some()),
                        Val::S(_) => false,
                    });
                    assert_eq!(list.is_some(), whole, "list_column of '{}'", p.name);
                    if let Some(list) = list {
                        assert_eq!(list.len(), def.count);
                        for (l, r) in list.iter().zip(rows) {
                            let Val::L(items) = &r[pi] else {
                                unreachable!()
                            };
                            let want: Vec<Option<u32>> =
                                items.iter().map(|&v| as_index(v)).collect();
                            let got: Vec<Option<u32>> = l.iter().map(|&v| Some(v)).collect();
                            assert_eq!(got, want, "list_column of '{}'", p.name);
                        }
                    }
                }
            }
        }
    }
    let xyz = ply.vertex_xyz();
    let want = vertex_xyz_ref(ply, decoded);
    match (&xyz, &want) {
        (Some(a), Some(b)) => {
            assert_eq!(a.len(), b.len());
            for (p, q) in a.iter().zip(b) {
                for k in 0..3 {
                    assert_eq!(p[k].to_bits(), q[k].to_bits());
                }
            }
        }
        (None, None) => {}
        _ => panic!(
            "vertex_xyz is {:?} but should be {:?}",
            xyz.is_some(),
            want.is_some()
        ),
    }
}

/// A list item as a vertex index: a whole number in `0..=u32::MAX`.
fn as_index(v: f64) -> Option<u32> {
    (v.fract() == 0.0 && (0.0..=f64::from(u32::MAX)).contains(&v)).then_some(v as u32)
}

/// What `vertex_xyz` should return.
fn vertex_xyz_ref(ply: &PlyFile, decoded: &[Option<Rows>]) -> Option<Vec<[f64; 3]>> {
    let vi = ply.element("vertex")?;
    let def = &ply.header.elements[vi];
    let idx = |n: &str| {
        let i = def.props.iter().position(|p| p.name == n)?;
        matches!(def.props[i].kind, PropertyKind::Scalar(_)).then_some(i)
    };
    let (x, y, z) = (idx("x")?, idx("y")?, idx("z")?);
    let rows = decoded[vi].as_ref()?;
    let get = |r: &[Val], i: usize| match r[i] {
        Val::S(v) => v,
        Val::L(_) => unreachable!(),
    };
    Some(
        rows.iter()
            .map(|r| [get(r, x), get(r, y), get(r, z)])
            .collect(),
    )
}

/// `scan_from_ply` and the invariants of the scan it builds.
fn check_scan(ply: &PlyFile, path: &Path, decoded: &[Option<Rows>]) {
    let xyz_ok = vertex_xyz_ref(ply, decoded).is_some();
    let scan = match scan_from_ply(ply, path) {
        Ok(s) => s,
        Err(e) => {
            assert!(!xyz_ok, "scan_from_ply failed on a file with x/y/z: {e}");
            assert!(matches!(e, Error::Format { .. }), "{e:?}");
            return;
        }
    };
    assert!(xyz_ok, "scan_from_ply succeeded without x/y/z");
    let n = ply.header.elements[ply.element("vertex").unwrap()].count;
    assert_eq!(scan.vertex_count, n);
    assert_eq!(scan.points.len() + scan.skipped_nonfinite, n);
    assert_eq!(scan.source_index.len(), scan.points.len());
    assert!(scan.source_index.windows(2).all(|w| w[0] < w[1]));
    assert!(scan.source_index.iter().all(|&i| (i as usize) < n));
    assert!(scan.points.iter().all(|p| p.is_finite()));
    if let Some(nm) = &scan.normals {
        assert_eq!(nm.len(), scan.points.len());
        assert!(nm.iter().all(|v| v.is_finite()));
    }
    if let Some(g) = &scan.grid {
        assert_eq!(g.row.len(), scan.points.len());
        assert_eq!(g.col.len(), scan.points.len());
        // A point is in the grid, or marked as without a cell in both indices.
        let none = mvao::testing::scan::NO_CELL;
        assert!(
            g.row
                .iter()
                .zip(&g.col)
                .all(|(&r, &c)| (r < g.rows && c < g.cols) || (r == none && c == none)),
            "grid cell out of range"
        );
        assert!(g.occupied_cells() <= scan.points.len());
    }
}

/// Whether the writer can put `name` into a header.
fn writable_name(name: &str) -> bool {
    !name.is_empty() && !name.chars().any(|c| c.is_whitespace() || c.is_control())
}

/// `write_path` then `from_path` must give back the same header (but the encoding) and data.
fn roundtrip(ply: &PlyFile, scratch: &Scratch, what: &str) {
    let writable = ply
        .header
        .elements
        .iter()
        .all(|e| writable_name(&e.name) && e.props.iter().all(|p| writable_name(&p.name)));
    let out = scratch.file("roundtrip.ply");
    match ply.write_path(&out) {
        Ok(()) => assert!(writable, "{what}: wrote an unwritable name"),
        Err(e) => {
            assert!(!writable, "{what}: write failed: {e}");
            assert!(!out.exists(), "{what}: a failed write left a file");
            return;
        }
    }
    let back = PlyFile::from_path(&out)
        .unwrap_or_else(|e| panic!("{what}: the written file does not read back: {e}"));
    assert_eq!(back.header.encoding, Encoding::BinaryLe);
    assert_eq!(
        back.header.elements, ply.header.elements,
        "{what}: elements"
    );
    assert_eq!(
        back.header.comments, ply.header.comments,
        "{what}: comments"
    );
    assert_eq!(
        back.header.obj_info, ply.header.obj_info,
        "{what}: obj_info"
    );
    assert!(
        back.data == ply.data,
        "{what}: element data differs after a round trip"
    );
    let _ = std::fs::remove_file(&out);
}

/// A scalar type chosen by a byte.
fn pick_type(b: u8) -> ScalarType {
    [
        ScalarType::I8,
        ScalarType::U8,
        ScalarType::I16,
        ScalarType::U16,
        ScalarType::I32,
        ScalarType::U32,
        ScalarType::F32,
        ScalarType::F64,
    ][usize::from(b % 8)]
}

/// What a value reads back as after being stored with type `t` (integers: NaN → 0, rounded,
/// saturated).
fn stored(t: ScalarType, v: f64) -> f64 {
    let i = if v.is_nan() { 0.0 } else { v.round() };
    match t {
        ScalarType::I8 => f64::from(i as i8),
        ScalarType::U8 => f64::from(i as u8),
        ScalarType::I16 => f64::from(i as i16),
        ScalarType::U16 => f64::from(i as u16),
        ScalarType::I32 => f64::from(i as i32),
        ScalarType::U32 => f64::from(i as u32),
        ScalarType::F32 => f64::from(v as f32),
        ScalarType::F64 => v,
    }
}

/// `set_scalar_column` on `vertex` (a new property, or an existing one the input named
/// `fuzz_ao`), then a round trip.
fn check_set_column(ply: &PlyFile, bytes: &[u8], scratch: &Scratch) {
    const NAME: &str = "fuzz_ao";
    let Some(vi) = ply.element("vertex") else {
        assert!(ply
            .clone()
            .set_scalar_column("vertex", NAME, ScalarType::F32, &[])
            .is_err());
        return;
    };
    let def = &ply.header.elements[vi];
    let n = def.count;
    if n > MAX_HARNESS_ROWS {
        return;
    }
    let pick = |i: usize| bytes.get(i % bytes.len().max(1)).copied().unwrap_or(0);
    let values: Vec<f64> = (0..n)
        .map(|i| match pick(i) % 8 {
            0 => f64::NAN,
            1 => f64::INFINITY,
            2 => f64::NEG_INFINITY,
            3 => i as f64,
            4 => -(i as f64) * 1.5,
            5 => 1e300,
            6 => 0.5,
            _ => -0.5,
        })
        .collect();
    let ty = pick_type(pick(n));
    let mut wrong = ply.clone();
    let mut longer = values.clone();
    longer.push(1.0);
    assert!(wrong
        .set_scalar_column("vertex", NAME, ty, &longer)
        .is_err());
    assert!(wrong == *ply, "a failed set_scalar_column changed the file");

    let before = decode(def, &ply.data[vi]);
    let existing = def.props.iter().position(|p| p.name == NAME);
    let mut after = ply.clone();
    let res = after.set_scalar_column("vertex", NAME, ty, &values);
    let (pi, ty) = match existing.map(|i| (i, def.props[i].kind)) {
        Some((_, PropertyKind::List { .. })) => {
            assert!(res.is_err(), "set a list property as a scalar");
            assert!(after == *ply, "a failed set_scalar_column changed the file");
            return;
        }
        Some((i, PropertyKind::Scalar(t))) => (i, t),
        None => (def.props.len(), ty),
    };
    res.unwrap_or_else(|e| panic!("set_scalar_column on a parsed file: {e}"));
    let adef = &after.header.elements[vi];
    assert_eq!(adef.count, n);
    assert_eq!(adef.props[pi].name, NAME);
    assert_eq!(adef.props[pi].kind, PropertyKind::Scalar(ty));
    let rows = decode(adef, &after.data[vi]).expect("vertex has a property now");
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(
            r[pi],
            Val::S(stored(ty, values[i])),
            "row {i} of the set column"
        );
        if let Some(b) = &before {
            for (j, v) in b[i].iter().enumerate() {
                if j != pi {
                    assert_eq!(&r[j], v, "set_scalar_column changed another property");
                }
            }
        }
    }
    for (ei, (d, b)) in after.header.elements.iter().zip(&after.data).enumerate() {
        if ei != vi {
            assert_eq!(d, &ply.header.elements[ei]);
            assert_eq!(b, &ply.data[ei]);
        }
    }
    roundtrip(&after, scratch, "after set_scalar_column");
}

/// Whether a list property holds vertex references (`retain_vertices` renumbers those).
fn is_index_list(name: &str, kind: PropertyKind) -> bool {
    matches!(kind, PropertyKind::List { .. })
        && (name == "vertex_indices" || name == "vertex_index")
}

/// `retain_vertices` with a mask drawn from the input, against a reference model.
fn check_retain(ply: &PlyFile, bytes: &[u8], scratch: &Scratch) {
    let Some(vi) = ply.element("vertex") else {
        assert!(ply.clone().retain_vertices(&[]).is_err());
        return;
    };
    let n = ply.header.elements[vi].count;
    if n > MAX_HARNESS_ROWS {
        return;
    }
    assert!(ply.clone().retain_vertices(&vec![true; n + 1]).is_err());
    let keep: Vec<bool> = (0..n)
        .map(|i| {
            bytes.get(i % bytes.len().max(1)).is_none_or(|b| {
                (b.rotate_right((i / bytes.len().max(1)) as u32) >> (i % 8)) & 1 == 1
            })
        })
        .collect();
    let mut new_index = vec![None; n];
    let mut k = 0usize;
    for (i, &kp) in keep.iter().enumerate() {
        if kp {
            new_index[i] = Some(k as f64);
            k += 1;
        }
    }
    let after = ply
        .clone()
        .retain_vertices(&keep)
        .unwrap_or_else(|e| panic!("retain_vertices on a parsed file: {e}"));
    assert_eq!(after.header.comments, ply.header.comments);
    assert_eq!(after.header.obj_info, ply.header.obj_info);
    assert_eq!(after.header.elements.len(), ply.header.elements.len());
    assert_eq!(after.data.len(), ply.data.len());
    for (ei, def) in ply.header.elements.iter().enumerate() {
        let adef = &after.header.elements[ei];
        assert_eq!(adef.name, def.name);
        assert_eq!(adef.props, def.props);
        let got = decode(adef, &after.data[ei]);
        let Some(rows) = decode(def, &ply.data[ei]) else {
            let want = if ei == vi { k } else { def.count };
            assert_eq!(adef.count, want, "count of property-less '{}'", def.name);
            continue;
        };
        let got = got.expect("decodes");
        assert_eq!(got.len(), adef.count);
        let want: Rows = if ei == vi {
            rows.into_iter()
                .zip(&keep)
                .filter(|(_, &kp)| kp)
                .map(|(r, _)| r)
                .collect()
        } else if def.props.iter().any(|p| is_index_list(&p.name, p.kind)) {
            let is_face = def.name == "face";
            let mut out = Vec::new();
            for r in rows {
                let mut drop_row = false;
                let mut nr = Vec::with_capacity(r.len());
                for (p, v) in def.props.iter().zip(r) {
                    match v {
                        Val::L(items) if is_index_list(&p.name, p.kind) => {
                            let mapped: Vec<f64> = items
                                .iter()
                                .filter_map(|&v| {
                                    let i = usize::try_from(as_index(v)?).ok()?;
                                    *new_index.get(i)?
                                })
                                .collect();
                            drop_row |= is_face && mapped.len() != items.len();
                            nr.push(Val::L(mapped));
                        }
                        other => nr.push(other),
                    }
                }
                if !drop_row {
                    out.push(nr);
                }
            }
            out
        } else {
            rows
        };
        assert_eq!(
            adef.count,
            want.len(),
            "rows of '{}' after retain",
            def.name
        );
        assert!(
            got == want,
            "rows of '{}' after retain_vertices differ from the model",
            def.name
        );
    }
    roundtrip(&after, scratch, "after retain_vertices");
}

// ---------------------------------------------------------------------------------------------
// Structured PLY headers
// ---------------------------------------------------------------------------------------------

/// Reads the fuzz bytes one at a time, zeros once they run out.
struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn byte(&mut self) -> u8 {
        match self.0.split_first() {
            Some((&b, rest)) => {
                self.0 = rest;
                b
            }
            None => 0,
        }
    }

    fn pick<'s>(&mut self, from: &[&'s str]) -> &'s str {
        from[usize::from(self.byte()) % from.len()]
    }

    /// Up to `max` raw bytes.
    fn take(&mut self, max: usize) -> &[u8] {
        let n = (usize::from(self.byte()) % (max + 1)).min(self.0.len());
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        a
    }
}

const ELEMENT_NAMES: [&str; 8] = [
    "vertex",
    "vertex",
    "face",
    "range_grid",
    "edge",
    "vertex",
    "a\u{0b}b",
    "é",
];
const PROP_NAMES: [&str; 16] = [
    "x",
    "y",
    "z",
    "nx",
    "ny",
    "nz",
    "row",
    "col",
    "vertex_indices",
    "vertex_index",
    "fuzz_ao",
    "x",
    "intensity",
    "row_index",
    "column_index",
    "red",
];
const TYPE_NAMES: [&str; 20] = [
    "char", "uchar", "short", "ushort", "int", "uint", "float", "double", "int8", "uint8", "int16",
    "uint16", "int32", "uint32", "float32", "float64", "float", "uchar", "int64", "list",
];
const COUNTS: [&str; 12] = [
    "4294967295",
    "2147483647",
    "4294967296",
    "18446744073709551615",
    "18446744073709551616",
    "1000000000000000",
    "-1",
    "1.5",
    "0x10",
    "",
    "00003",
    "+2",
];

/// Builds a PLY file from the fuzz bytes: a header of formats, elements, properties, comments,
/// `obj_info` lines and junk, then a body (number tokens for ascii, raw bytes for binary).
pub fn ply_from_structure(data: &[u8]) -> Vec<u8> {
    let mut u = Bytes(data);
    let mut out: Vec<u8> = match u.byte() % 16 {
        0 => b"ply\r\n".to_vec(),
        1 => b"  ply \n".to_vec(),
        _ => b"ply\n".to_vec(),
    };
    let format = u.byte() % 16;
    let ascii = format < 6;
    let fmt_line = match format {
        0..=5 => "format ascii 1.0\n",
        6..=10 => "format binary_little_endian 1.0\n",
        11..=13 => "format binary_big_endian 1.0\n",
        14 => "",
        _ => "format ascii 2.0\n",
    };
    out.extend_from_slice(fmt_line.as_bytes());
    let lines = u.byte() % 24;
    for _ in 0..lines {
        match u.byte() % 16 {
            0 => {
                out.extend_from_slice(b"comment ");
                let text = u.take(12).to_vec();
                out.extend(text.iter().filter(|&&b| b != b'\n'));
                out.push(b'\n');
            }
            1 => {
                let key = u.pick(&["num_cols", "num_rows", "is_mesh", ""]);
                let val = u.byte();
                out.extend_from_slice(format!("obj_info {key} {val}\n").as_bytes());
            }
            2..=4 => {
                let name = u.pick(&ELEMENT_NAMES);
                let count = match u.byte() % 8 {
                    0..=3 => (u.byte() % 8).to_string(),
                    4 => u.byte().to_string(),
                    5 => u16::from_le_bytes([u.byte(), u.byte()]).to_string(),
                    _ => u.pick(&COUNTS).to_string(),
                };
                out.extend_from_slice(format!("element {name} {count}\n").as_bytes());
            }
            5..=9 => {
                let t = u.pick(&TYPE_NAMES);
                let name = u.pick(&PROP_NAMES);
                out.extend_from_slice(format!("property {t} {name}\n").as_bytes());
            }
            10..=12 => {
                let c = u.pick(&[
                    "uchar", "uchar", "int", "uint", "char", "ushort", "float", "uint8",
                ]);
                let t = u.pick(&TYPE_NAMES);
                let name = u.pick(&["vertex_indices", "vertex_indices", "vertex_index", "x", "l"]);
                out.extend_from_slice(format!("property list {c} {t} {name}\n").as_bytes());
            }
            13 => {
                let junk = u.take(16).to_vec();
                out.extend(junk);
                out.push(b'\n');
            }
            14 => {
                let ws = u.pick(&["\n", "\r\n", " \t\n", "\n\n"]);
                out.extend_from_slice(ws.as_bytes());
            }
            _ => {
                let l = u.pick(&[
                    "property float\n",
                    "property list uchar int\n",
                    "element vertex\n",
                    "format binary_little_endian 1.0\n",
                    "obj_info\n",
                    "comment\n",
                    "comment a\rb\n",
                    "property list list int x\n",
                ]);
                out.extend_from_slice(l.as_bytes());
            }
        }
    }
    out.extend_from_slice(b"end_header\n");
    if ascii {
        const TOKENS: [&str; 16] = [
            "-1",
            "255",
            "256",
            "1.5",
            "nan",
            "-inf",
            "4294967295",
            "1e39",
            "\n",
            "x",
            "-0",
            "2",
            "3",
            "65536",
            "-129",
            "1e-320",
        ];
        for &b in u.0 {
            if b < 0x80 {
                out.extend_from_slice((b % 10).to_string().as_bytes());
            } else {
                out.extend_from_slice(TOKENS[usize::from(b % 16)].as_bytes());
            }
            out.push(if b % 7 == 0 { b'\n' } else { b' ' });
        }
    } else {
        out.extend_from_slice(u.0);
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Alignment files
// ---------------------------------------------------------------------------------------------

/// Targets `align_conf`, `align_mlp`, `align_json`: the bytes as `alignment.<ext>`.
pub fn check_align(ext: &str, bytes: &[u8]) {
    let scratch = Scratch::new(&format!("align-{ext}"));
    let path = scratch.file(&format!("alignment.{ext}"));
    std::fs::write(&path, bytes).expect("write scratch input");
    let al = match read_alignment(&path) {
        Ok(a) => a,
        Err(e) => {
            match &e {
                Error::Align { .. } => {}
                // Only an undecodable (non-UTF-8) file may fail as I/O.
                Error::Io { err, .. } => {
                    assert_eq!(err.kind(), std::io::ErrorKind::InvalidData, "{e}")
                }
                other => panic!("unexpected error kind: {other:?}"),
            }
            assert!(e.to_string().contains(&path.display().to_string()), "{e}");
            return;
        }
    };
    assert_eq!(al.path, path);
    assert!(!al.entries.is_empty());
    for e in &al.entries {
        assert_rigid(e.pose, &e.file);
        let again = check_rigid(e.pose, &path, &e.file)
            .unwrap_or_else(|err| panic!("check_rigid rejects its own output: {err}"));
        let d = (again - e.pose)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(d <= 1e-12, "check_rigid is not idempotent ({d:e})");
    }
    let scans: Vec<PathBuf> = al
        .entries
        .iter()
        .map(|e| scratch.dir().join(&e.file))
        .collect();
    let simple = |f: &str| {
        !f.is_empty()
            && f != "."
            && f != ".."
            && !f.contains(['/', '\\'])
            && Path::new(f).file_name().and_then(|n| n.to_str()) == Some(f)
    };
    let mut names: Vec<&str> = al.entries.iter().map(|e| e.file.as_str()).collect();
    names.sort_unstable();
    let distinct = names.windows(2).all(|w| w[0] != w[1]);
    let plain = distinct && al.entries.iter().all(|e| simple(&e.file));
    match poses_for_scans(&al, &scans) {
        Ok(poses) => {
            assert_eq!(poses.len(), scans.len());
            if plain {
                for (p, e) in poses.iter().zip(&al.entries) {
                    assert!(*p == e.pose, "pose of '{}' is not its entry's", e.file);
                }
            }
            if al.entries.len() <= 1000 {
                for p in &poses {
                    assert!(al.entries.iter().any(|e| e.pose == *p));
                }
            }
        }
        Err(e) => {
            assert!(
                !plain,
                "poses_for_scans failed on distinct plain names: {e}"
            );
            assert!(matches!(e, Error::Align { .. }), "{e:?}");
        }
    }
    if plain {
        let rev: Vec<PathBuf> = scans.iter().rev().cloned().collect();
        let poses = poses_for_scans(&al, &rev).expect("reversed scans");
        for (p, e) in poses.iter().rev().zip(&al.entries) {
            assert!(*p == e.pose);
        }
        let mut extra = scans.clone();
        extra.push(scratch.dir().join("no such scan \u{1}.ply"));
        assert!(poses_for_scans(&al, &extra).is_err());
        let found = match_scans(&al, &extra).expect("match_scans with one unnamed scan");
        assert!(found.last() == Some(&None), "an unnamed scan got a pose");
        // Part of a site: every scan but the first, each with its own entry's pose.
        let part = poses_for_scans(&al, &scans[1..]).expect("a subset of the entries");
        for (p, e) in part.iter().zip(&al.entries[1..]) {
            assert!(*p == e.pose, "pose of '{}' is not its entry's", e.file);
        }
    }
}

/// A pose as `check_rigid` returns it: finite, orthonormal rotation with positive
/// determinant, bottom row exactly `(0, 0, 0, 1)`.
pub fn assert_rigid(m: DMat4, what: &str) {
    assert!(m.is_finite(), "pose of '{what}' is not finite: {m:?}");
    assert!(
        m.row(3) == DVec4::W,
        "pose of '{what}' has bottom row {:?}",
        m.row(3)
    );
    let r = DMat3::from_mat4(m);
    let d = r.transpose() * r - DMat3::IDENTITY;
    let dev = d.to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()));
    assert!(dev <= 1e-9, "rotation of '{what}' is off by {dev:e}");
    assert!(
        r.determinant() > 0.0,
        "rotation of '{what}' is a reflection"
    );
}
