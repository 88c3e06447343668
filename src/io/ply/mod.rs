//! PLY reading and writing that keeps everything: every element, every property with its
//! original type, comments and `obj_info` lines. Element bodies are held as little-endian
//! binary rows whatever the input encoding, so writing binary little endian is a copy and
//! reading a fixed-stride vertex block is one bulk read.

mod ascii;
mod columns;
mod header;
mod read;
mod retain;
pub mod scan;
mod write;

use crate::error::{Error, Result};
use std::path::Path;

/// How the body of a PLY file is encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// `format ascii 1.0`
    Ascii,
    /// `format binary_little_endian 1.0`
    BinaryLe,
    /// `format binary_big_endian 1.0`
    BinaryBe,
}

/// A PLY scalar type (both the `char`/`uchar`/… and `int8`/`uint8`/… spellings are read).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScalarType {
    /// int8 / char
    I8,
    /// uint8 / uchar
    U8,
    /// int16 / short
    I16,
    /// uint16 / ushort
    U16,
    /// int32 / int
    I32,
    /// uint32 / uint
    U32,
    /// float32 / float
    F32,
    /// float64 / double
    F64,
}

/// Whether a property is a single scalar or a counted list.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PropertyKind {
    /// `property <type> <name>`
    Scalar(ScalarType),
    /// `property list <count type> <item type> <name>`
    List {
        /// Type of the count that precedes the items.
        count: ScalarType,
        /// Type of each item.
        item: ScalarType,
    },
}

/// One property of an element.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Property {
    /// Name as written in the header.
    pub name: String,
    /// Scalar or list, with types.
    pub kind: PropertyKind,
}

/// One `element` declaration of the header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ElementDef {
    /// Element name (`vertex`, `face`, `range_grid`, …).
    pub name: String,
    /// Number of rows.
    pub count: usize,
    /// Properties in file order.
    pub props: Vec<Property>,
}

/// The parsed header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    /// Body encoding of the file as read.
    pub encoding: Encoding,
    /// `comment` lines, text after the keyword, in order.
    pub comments: Vec<String>,
    /// `obj_info` lines, text after the keyword, in order.
    pub obj_info: Vec<String>,
    /// Elements in file order.
    pub elements: Vec<ElementDef>,
}

/// The body of one element as little-endian binary rows.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ElementData {
    /// Rows back to back, each encoded as in a `binary_little_endian` file.
    pub bytes: Vec<u8>,
    /// Start offset of each row in `bytes` plus a final end offset; `None` when the element has
    /// no list property, so every row has the same stride.
    pub row_offsets: Option<Vec<usize>>,
}

/// A whole PLY file in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct PlyFile {
    /// Header as read (the encoding records the input's; writing is always binary LE).
    pub header: Header,
    /// One body per element, in header order.
    pub data: Vec<ElementData>,
}

impl PlyFile {
    /// Index of the element named `name`.
    pub fn element(&self, name: &str) -> Option<usize> {
        self.header.elements.iter().position(|e| e.name == name)
    }

    /// The kind of property `prop` of element `element`, if both exist.
    pub fn property_kind(&self, element: &str, prop: &str) -> Option<PropertyKind> {
        self.header
            .elements
            .iter()
            .find(|e| e.name == element)?
            .props
            .iter()
            .find(|p| p.name == prop)
            .map(|p| p.kind)
    }

    /// Whether the element named `element` exists and has a property (scalar or list) named
    /// `prop`.
    pub fn has_property(&self, element: &str, prop: &str) -> bool {
        self.header
            .elements
            .iter()
            .find(|e| e.name == element)
            .is_some_and(|e| e.props.iter().any(|p| p.name == prop))
    }

    /// One scalar property of an element converted to f64, in row order. `None` if the element
    /// or property does not exist or the property is a list.
    pub fn scalar_column(&self, element: &str, prop: &str) -> Option<Vec<f64>> {
        self.map_scalars(element, [prop], |[v]| v)
    }

    /// The lists of a list property as `u32` indices, one `Vec` per row (used for `range_grid`
    /// and `face`). `None` if missing or not a list.
    ///
    /// Also `None` if any item is not a whole number in `0..=u32::MAX` (a negative index, or a
    /// fractional value in a float-typed list).
    pub fn list_column(&self, element: &str, prop: &str) -> Option<Vec<Vec<u32>>> {
        self.map_lists(element, prop, to_u32)
    }

    /// Like [`PlyFile::list_column`], but an item that is not a whole number in
    /// `0..u32::MAX` becomes `u32::MAX` instead of failing the whole column, so a caller can
    /// count and drop bad references one by one (`u32::MAX` is never a vertex index).
    pub fn list_indices(&self, element: &str, prop: &str) -> Option<Vec<Vec<u32>>> {
        self.map_lists(element, prop, |v| Some(to_u32(v).unwrap_or(u32::MAX)))
    }

    /// Faces (rows of a `face` element's `vertex_indices` or `vertex_index` list) that refer to
    /// a vertex the file does not have: negative, fractional or beyond the vertex count.
    /// Writing drops them, as it drops faces that lose a vertex.
    pub fn faces_out_of_range(&self) -> usize {
        let n = self
            .element("vertex")
            .and_then(|i| self.header.elements.get(i))
            .map_or(0, |e| e.count);
        let count = |prop: &str| {
            let mut bad = 0usize;
            self.visit_lists("face", prop, |items| {
                let vertex = |v: Option<f64>| to_u32(v?).filter(|&i| (i as usize) < n);
                for v in items {
                    if vertex(v).is_none() {
                        bad += 1;
                        break;
                    }
                }
                Some(())
            })
            .map(|()| bad)
        };
        count("vertex_indices")
            .or_else(|| count("vertex_index"))
            .unwrap_or(0)
    }

    /// The items of a list property through `item`, one `Vec` per row; `None` if missing,
    /// not a list, unreadable, or `item` refuses a value.
    fn map_lists(
        &self,
        element: &str,
        prop: &str,
        item_of: impl Fn(f64) -> Option<u32>,
    ) -> Option<Vec<Vec<u32>>> {
        let rows = self.element_parts(element).map_or(0, |(def, _)| def.count);
        let mut out = Vec::with_capacity(rows);
        self.visit_lists(element, prop, |items| {
            out.push(items.map(|v| item_of(v?)).collect::<Option<Vec<u32>>>()?);
            Some(())
        })?;
        Some(out)
    }

    /// Calls `visit` with the items of each row's list `prop` of `element`, read as f64 (an
    /// item that cannot be read is `None`); `None` if the list is missing, unreadable, or
    /// `visit` returns `None`.
    fn visit_lists(
        &self,
        element: &str,
        prop: &str,
        mut visit: impl FnMut(&mut dyn Iterator<Item = Option<f64>>) -> Option<()>,
    ) -> Option<()> {
        let (def, data) = self.element_parts(element)?;
        let pi = def.props.iter().position(|p| p.name == prop)?;
        let PropertyKind::List { count, item } = def.props.get(pi)?.kind else {
            return None;
        };
        let layout = Layout::of(def, data)?;
        layout.for_each_row(|row| {
            let off = field_offset(&def.props, row, pi)?;
            let n = list_len(count, row, off)?;
            let first = off.checked_add(count.size())?;
            let end = first.checked_add(n.checked_mul(item.size())?)?;
            let items = row.get(first..end)?;
            visit(
                &mut items
                    .chunks_exact(item.size())
                    .map(|it| item.read_f64(it, 0)),
            )
        })
    }

    /// Sets a scalar property of an element from f64 values (one per row), converting to
    /// `ty` (integers are rounded and clamped to the type's range; NaN becomes 0 in integer types). If the
    /// property exists it is overwritten in place with its existing type (`ty` ignored);
    /// otherwise it is appended as the element's last property.
    pub fn set_scalar_column(
        &mut self,
        element: &str,
        prop: &str,
        ty: ScalarType,
        values: &[f64],
    ) -> Result<()> {
        let PlyFile { header, data } = self;
        let ei = header
            .elements
            .iter()
            .position(|e| e.name == element)
            .ok_or_else(|| {
                Error::Param(format!(
                    "cannot set property '{prop}': no element '{element}' in the ply file"
                ))
            })?;
        let bad_data = || {
            Error::Param(format!(
                "element '{element}': stored rows do not match the header declaration"
            ))
        };
        let (Some(def), Some(body)) = (header.elements.get_mut(ei), data.get_mut(ei)) else {
            return Err(bad_data());
        };
        if values.len() != def.count {
            return Err(Error::Param(format!(
                "cannot set property '{prop}' of element '{element}': {} values for {} rows",
                values.len(),
                def.count
            )));
        }
        let layout = match Layout::of(def, body) {
            Some(Layout::Fixed { stride, .. }) => LayoutKind::Fixed(stride),
            Some(Layout::Rows { .. }) => LayoutKind::Rows,
            None => return Err(bad_data()),
        };
        match def.props.iter().position(|p| p.name == prop) {
            Some(pi) => {
                let kind = def.props.get(pi).map(|p| p.kind).ok_or_else(bad_data)?;
                let PropertyKind::Scalar(ty) = kind else {
                    return Err(Error::Param(format!(
                        "cannot set property '{prop}' of element '{element}': it is a list"
                    )));
                };
                let size = ty.size();
                match layout {
                    LayoutKind::Fixed(stride) => {
                        let off = field_offset(&def.props, &[], pi).ok_or_else(bad_data)?;
                        if stride == 0 || off + size > stride {
                            return Err(bad_data());
                        }
                        for (row, &v) in body.bytes.chunks_exact_mut(stride).zip(values) {
                            if let Some(dst) = row.get_mut(off..off + size) {
                                dst.copy_from_slice(ty.encode(v).as_slice());
                            }
                        }
                    }
                    LayoutKind::Rows => {
                        // Byte position of the field in every row, all computed (and checked)
                        // before anything changes.
                        let offs = body.row_offsets.as_deref().ok_or_else(bad_data)?;
                        let mut positions = Vec::with_capacity(def.count);
                        for w in offs.windows(2) {
                            let &[a, b] = w else { return Err(bad_data()) };
                            let row = body.bytes.get(a..b).ok_or_else(bad_data)?;
                            let off = field_offset(&def.props, row, pi).ok_or_else(bad_data)?;
                            if off.checked_add(size).is_none_or(|e| e > row.len()) {
                                return Err(bad_data());
                            }
                            positions.push(a + off);
                        }
                        for (&at, &v) in positions.iter().zip(values) {
                            if let Some(dst) = body.bytes.get_mut(at..at + size) {
                                dst.copy_from_slice(ty.encode(v).as_slice());
                            }
                        }
                    }
                }
            }
            None => {
                check_name(prop).map_err(|m| {
                    Error::Param(format!("cannot add property to element '{element}': {m}"))
                })?;
                let size = ty.size();
                let extra = values
                    .len()
                    .checked_mul(size)
                    .and_then(|x| x.checked_add(body.bytes.len()))
                    .ok_or_else(bad_data)?;
                let mut bytes = Vec::with_capacity(extra);
                match layout {
                    LayoutKind::Fixed(stride) => {
                        if stride == 0 {
                            for &v in values {
                                bytes.extend_from_slice(ty.encode(v).as_slice());
                            }
                        } else {
                            for (row, &v) in body.bytes.chunks_exact(stride).zip(values) {
                                bytes.extend_from_slice(row);
                                bytes.extend_from_slice(ty.encode(v).as_slice());
                            }
                        }
                        body.bytes = bytes;
                    }
                    LayoutKind::Rows => {
                        let offs = body.row_offsets.as_deref().ok_or_else(bad_data)?;
                        let mut new_offs = Vec::with_capacity(offs.len());
                        new_offs.push(0);
                        for (w, &v) in offs.windows(2).zip(values) {
                            let &[a, b] = w else { return Err(bad_data()) };
                            bytes.extend_from_slice(body.bytes.get(a..b).ok_or_else(bad_data)?);
                            bytes.extend_from_slice(ty.encode(v).as_slice());
                            new_offs.push(bytes.len());
                        }
                        body.bytes = bytes;
                        body.row_offsets = Some(new_offs);
                    }
                }
                def.props.push(Property {
                    name: prop.to_string(),
                    kind: PropertyKind::Scalar(ty),
                });
            }
        }
        Ok(())
    }

    /// Builds a file with a single `vertex` element from named scalar columns of equal length
    /// (each with its type), plus comments. Used by writers of new scans (synthetic scenes).
    pub fn from_vertex_columns(
        columns: &[(&str, ScalarType, &[f64])],
        comments: &[String],
    ) -> Result<PlyFile> {
        let Some(&(first, _, first_vals)) = columns.first() else {
            return Err(Error::Param("ply vertex columns: no columns given".into()));
        };
        let n = first_vals.len();
        let mut props: Vec<Property> = Vec::with_capacity(columns.len());
        for &(name, ty, vals) in columns {
            check_name(name)
                .map_err(|m| Error::Param(format!("ply vertex column '{name}': {m}")))?;
            if props.iter().any(|p| p.name == name) {
                return Err(Error::Param(format!(
                    "ply vertex column '{name}' is given twice"
                )));
            }
            if vals.len() != n {
                return Err(Error::Param(format!(
                    "ply vertex column '{name}' has {} values but '{first}' has {n}",
                    vals.len()
                )));
            }
            props.push(Property {
                name: name.to_string(),
                kind: PropertyKind::Scalar(ty),
            });
        }
        let stride: usize = columns.iter().map(|c| c.1.size()).sum();
        let total = n
            .checked_mul(stride)
            .ok_or_else(|| Error::Param(format!("ply vertex columns: {n} rows are too many")))?;
        let mut bytes = vec![0u8; total];
        // Column by column into the interleaved rows: one type dispatch per column.
        let mut off = 0;
        for &(_, ty, vals) in columns {
            let size = ty.size();
            if stride > 0 {
                for (row, &v) in bytes.chunks_exact_mut(stride).zip(vals) {
                    if let Some(dst) = row.get_mut(off..off + size) {
                        dst.copy_from_slice(ty.encode(v).as_slice());
                    }
                }
            }
            off += size;
        }
        Ok(PlyFile {
            header: Header {
                encoding: Encoding::BinaryLe,
                comments: comments.to_vec(),
                obj_info: Vec::new(),
                elements: vec![ElementDef {
                    name: "vertex".into(),
                    count: n,
                    props,
                }],
            },
            data: vec![ElementData {
                bytes,
                row_offsets: None,
            }],
        })
    }

    /// Declaration and body of the element named `name`.
    fn element_parts(&self, name: &str) -> Option<(&ElementDef, &ElementData)> {
        let i = self.element(name)?;
        Some((self.header.elements.get(i)?, self.data.get(i)?))
    }
}

// ---------------------------------------------------------------------------------------------
// Private helpers
// ---------------------------------------------------------------------------------------------

impl ScalarType {
    /// Size in bytes.
    fn size(self) -> usize {
        match self {
            ScalarType::I8 | ScalarType::U8 => 1,
            ScalarType::I16 | ScalarType::U16 => 2,
            ScalarType::I32 | ScalarType::U32 | ScalarType::F32 => 4,
            ScalarType::F64 => 8,
        }
    }

    /// Classic PLY name, used when writing.
    fn name(self) -> &'static str {
        match self {
            ScalarType::I8 => "char",
            ScalarType::U8 => "uchar",
            ScalarType::I16 => "short",
            ScalarType::U16 => "ushort",
            ScalarType::I32 => "int",
            ScalarType::U32 => "uint",
            ScalarType::F32 => "float",
            ScalarType::F64 => "double",
        }
    }

    /// Parses either spelling of a type name.
    fn parse(s: &str) -> Option<ScalarType> {
        Some(match s {
            "char" | "int8" => ScalarType::I8,
            "uchar" | "uint8" => ScalarType::U8,
            "short" | "int16" => ScalarType::I16,
            "ushort" | "uint16" => ScalarType::U16,
            "int" | "int32" => ScalarType::I32,
            "uint" | "uint32" => ScalarType::U32,
            "float" | "float32" => ScalarType::F32,
            "double" | "float64" => ScalarType::F64,
            _ => return None,
        })
    }

    /// Range of an integer type; `None` for floats.
    fn int_range(self) -> Option<(i64, i64)> {
        Some(match self {
            ScalarType::I8 => (i8::MIN.into(), i8::MAX.into()),
            ScalarType::U8 => (0, u8::MAX.into()),
            ScalarType::I16 => (i16::MIN.into(), i16::MAX.into()),
            ScalarType::U16 => (0, u16::MAX.into()),
            ScalarType::I32 => (i32::MIN.into(), i32::MAX.into()),
            ScalarType::U32 => (0, u32::MAX.into()),
            ScalarType::F32 | ScalarType::F64 => return None,
        })
    }

    /// The little-endian value at `off` in `b`, as f64 (exact for every type).
    #[inline]
    fn read_f64(self, b: &[u8], off: usize) -> Option<f64> {
        Some(match self {
            ScalarType::I8 => f64::from(i8::from_le_bytes(le_array(b, off)?)),
            ScalarType::U8 => f64::from(u8::from_le_bytes(le_array(b, off)?)),
            ScalarType::I16 => f64::from(i16::from_le_bytes(le_array(b, off)?)),
            ScalarType::U16 => f64::from(u16::from_le_bytes(le_array(b, off)?)),
            ScalarType::I32 => f64::from(i32::from_le_bytes(le_array(b, off)?)),
            ScalarType::U32 => f64::from(u32::from_le_bytes(le_array(b, off)?)),
            ScalarType::F32 => f64::from(f32::from_le_bytes(le_array(b, off)?)),
            ScalarType::F64 => f64::from_le_bytes(le_array(b, off)?),
        })
    }

    /// `v` as this type, little endian: for integer types NaN becomes 0 and values are
    /// rounded and clamped (Rust's float-to-int `as` saturates); floats are kept as they are.
    #[inline]
    fn encode(self, v: f64) -> Encoded {
        let v = if v.is_nan() && self.int_range().is_some() {
            0.0
        } else {
            v
        };
        let mut e = Encoded {
            buf: [0; 8],
            len: self.size(),
        };
        match self {
            ScalarType::I8 => e.buf[..1].copy_from_slice(&(round(v) as i8).to_le_bytes()),
            ScalarType::U8 => e.buf[..1].copy_from_slice(&(round(v) as u8).to_le_bytes()),
            ScalarType::I16 => e.buf[..2].copy_from_slice(&(round(v) as i16).to_le_bytes()),
            ScalarType::U16 => e.buf[..2].copy_from_slice(&(round(v) as u16).to_le_bytes()),
            ScalarType::I32 => e.buf[..4].copy_from_slice(&(round(v) as i32).to_le_bytes()),
            ScalarType::U32 => e.buf[..4].copy_from_slice(&(round(v) as u32).to_le_bytes()),
            ScalarType::F32 => e.buf[..4].copy_from_slice(&(v as f32).to_le_bytes()),
            ScalarType::F64 => e.buf.copy_from_slice(&v.to_le_bytes()),
        }
        e
    }
}

/// One encoded scalar (at most 8 bytes).
#[derive(Clone, Copy)]
struct Encoded {
    buf: [u8; 8],
    len: usize,
}

impl Encoded {
    fn as_slice(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }
}

/// `N` bytes of `b` at `off`.
#[inline]
fn le_array<const N: usize>(b: &[u8], off: usize) -> Option<[u8; N]> {
    b.get(off..off.checked_add(N)?)?.try_into().ok()
}

/// A scalar type fixed at compile time: a little-endian value read as f64 (exactly), NaN where
/// the row is too short, as [`ScalarType::read_f64`] with the type's branch taken once per
/// column set instead of once per value.
trait LeScalar {
    fn at(row: &[u8], off: usize) -> f64;
}

macro_rules! le_scalars {
    ($($name:ident: $t:ty, $n:literal;)*) => {$(
        struct $name;
        impl LeScalar for $name {
            #[inline(always)]
            fn at(row: &[u8], off: usize) -> f64 {
                le_array::<$n>(row, off).map_or(f64::NAN, |a| f64::from(<$t>::from_le_bytes(a)))
            }
        }
    )*};
}

le_scalars! {
    LeI8: i8, 1;
    LeU8: u8, 1;
    LeI16: i16, 2;
    LeU16: u16, 2;
    LeI32: i32, 4;
    LeU32: u32, 4;
    LeF32: f32, 4;
    LeF64: f64, 8;
}

/// The type all of `cols` (offset, type) share, if they share one.
fn uniform_type(cols: &[(usize, ScalarType)]) -> Option<ScalarType> {
    let t = cols.first().map_or(ScalarType::F64, |c| c.1);
    cols.iter().all(|c| c.1 == t).then_some(t)
}

/// Expands `$body!(L)` with the [`LeScalar`] of scalar type `$t`.
macro_rules! uniform_dispatch {
    ($t:expr, $body:ident) => {
        match $t {
            ScalarType::I8 => $body!(LeI8),
            ScalarType::U8 => $body!(LeU8),
            ScalarType::I16 => $body!(LeI16),
            ScalarType::U16 => $body!(LeU16),
            ScalarType::I32 => $body!(LeI32),
            ScalarType::U32 => $body!(LeU32),
            ScalarType::F32 => $body!(LeF32),
            ScalarType::F64 => $body!(LeF64),
        }
    };
}
use uniform_dispatch;

/// `v` as a `u32` index if it is a whole number in range.
fn to_u32(v: f64) -> Option<u32> {
    (v.fract() == 0.0 && (0.0..=f64::from(u32::MAX)).contains(&v)).then_some(v as u32)
}

/// Length of the list whose count (of type `ct`) is at `off` in `row`.
fn list_len(ct: ScalarType, row: &[u8], off: usize) -> Option<usize> {
    let n = ct.read_f64(row, off)?;
    (n.fract() == 0.0 && n >= 0.0 && n <= usize::MAX as f64).then_some(n as usize)
}

/// Row stride of an element without list properties; `None` if it has one.
fn fixed_stride(props: &[Property]) -> Option<usize> {
    props.iter().try_fold(0usize, |acc, p| match p.kind {
        PropertyKind::Scalar(t) => acc.checked_add(t.size()),
        PropertyKind::List { .. } => None,
    })
}

/// Byte offset of property `target` inside `row` (lists before it are walked; `row` may be
/// empty when no list precedes the target).
fn field_offset(props: &[Property], row: &[u8], target: usize) -> Option<usize> {
    let mut off = 0usize;
    for p in props.get(..target)? {
        off = match p.kind {
            PropertyKind::Scalar(t) => off.checked_add(t.size())?,
            PropertyKind::List { count, item } => {
                let n = list_len(count, row, off)?;
                off.checked_add(count.size())?
                    .checked_add(n.checked_mul(item.size())?)?
            }
        };
    }
    Some(off)
}

/// Whether a name can be written into a header.
fn check_name(name: &str) -> std::result::Result<(), String> {
    if name.is_empty() {
        Err("empty name".into())
    } else if name.chars().any(|c| c.is_whitespace() || c.is_control()) {
        Err(format!("name '{name}' contains whitespace"))
    } else {
        Ok(())
    }
}

/// A comment or obj_info text on one header line.
fn one_line(s: &str) -> String {
    s.replace(['\r', '\n'], " ")
}

/// How the rows of an element are laid out (used while mutating).
#[derive(Clone, Copy)]
enum LayoutKind {
    Fixed(usize),
    Rows,
}

/// A checked view of an element body.
#[derive(Clone, Copy)]
enum Layout<'a> {
    /// Every row has `stride` bytes; `bytes.len() == count * stride` (so `bytes` is empty when
    /// `stride` is 0: iterate with `chunks_exact(stride.max(1))`).
    Fixed { stride: usize, bytes: &'a [u8] },
    /// Rows delimited by `offs` (`count + 1` non-decreasing offsets from 0 to `bytes.len()`).
    Rows { offs: &'a [usize], bytes: &'a [u8] },
}

impl<'a> Layout<'a> {
    /// The layout of an element body, `None` if the body does not match the declaration.
    fn of(def: &ElementDef, data: &'a ElementData) -> Option<Layout<'a>> {
        match &data.row_offsets {
            None => {
                let stride = fixed_stride(&def.props)?;
                if def.count.checked_mul(stride)? != data.bytes.len() {
                    return None;
                }
                Some(Layout::Fixed {
                    stride,
                    bytes: &data.bytes,
                })
            }
            Some(offs) => {
                let ok = offs.len() == def.count.checked_add(1)?
                    && offs.first() == Some(&0)
                    && offs.last() == Some(&data.bytes.len())
                    && offs.windows(2).all(|w| w.first() <= w.last());
                ok.then_some(Layout::Rows {
                    offs,
                    bytes: &data.bytes,
                })
            }
        }
    }

    /// Calls `f` on every row in order; stops with `None` as soon as `f` does.
    fn for_each_row(&self, mut f: impl FnMut(&[u8]) -> Option<()>) -> Option<()> {
        match *self {
            Layout::Fixed { stride, bytes } => {
                for row in bytes.chunks_exact(stride.max(1)) {
                    f(row)?;
                }
            }
            Layout::Rows { offs, bytes } => {
                for w in offs.windows(2) {
                    let &[a, b] = w else { return None };
                    f(bytes.get(a..b)?)?;
                }
            }
        }
        Some(())
    }
}

/// `v.round()` (halves away from zero) for the integer conversions of [`ScalarType::encode`],
/// without the libm call baseline x86-64 makes for it: the output writer rounds every colour
/// of every point. Same value as `f64::round` up to the sign of a zero, which the integer
/// conversion that follows drops.
#[inline]
pub fn round(v: f64) -> f64 {
    // Beyond 2^52 every f64 is an integer (and ±∞, NaN pass through).
    if !(v.abs() < 4_503_599_627_370_496.0) {
        return v;
    }
    let t = v as i64 as f64;
    // Exact: v and trunc(v) are within 1 of each other.
    let d = v - t;
    if d >= 0.5 {
        t + 1.0
    } else if d <= -0.5 {
        t - 1.0
    } else {
        t
    }
}

#[cfg(test)]
mod tests;
