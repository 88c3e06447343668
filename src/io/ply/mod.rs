//! PLY reading and writing that keeps everything: every element, every property with its
//! original type, comments and `obj_info` lines. Element bodies are held as little-endian
//! binary rows whatever the input encoding, so writing binary little endian is a copy and
//! reading a fixed-stride vertex block is one bulk read.

mod retain;
pub mod scan;

use crate::error::{Error, Result};
use rayon::prelude::*;
use std::fs::File;
use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
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
    /// Reads a PLY file (ascii, binary little or big endian). Errors name `path` and say what is
    /// wrong: not a PLY, bad header line, unknown type, truncated body (with element and row),
    /// unparsable ascii value, an ascii row with too few or too many values (with its line).
    /// Data after the last element is ignored ([`PlyFile::read_path_warn`] reports it).
    pub fn read_path(path: &Path) -> Result<PlyFile> {
        Self::read_path_warn(path).map(|(ply, _)| ply)
    }

    /// [`PlyFile::read_path`], with what the user should know about the file: data after the
    /// last element (some writers pad their files, so it is not an error).
    pub fn read_path_warn(path: &Path) -> Result<(PlyFile, Vec<String>)> {
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        let len = file
            .metadata()
            .ok()
            .filter(|m| m.is_file())
            .map(|m| m.len());
        // Small files get a small buffer; big ones a large one so the body streams in big reads.
        let cap = len.map_or(READ_BUF, |l| {
            usize::try_from(l.saturating_add(1))
                .unwrap_or(READ_BUF)
                .clamp(8 << 10, READ_BUF)
        });
        let mut src = Source {
            r: BufReader::with_capacity(cap, file),
            pos: 0,
            line: 1,
            len,
            path,
        };
        let header = parse_header(&mut src)?;
        let mut data = Vec::with_capacity(header.elements.len());
        for def in &header.elements {
            data.push(read_element(&mut src, header.encoding, def)?);
        }
        let mut warnings = Vec::new();
        if let Some(w) = trailing_data(&mut src, header.encoding)? {
            warnings.push(w);
        }
        Ok((PlyFile { header, data }, warnings))
    }

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

    /// The items of a list property through `item`, one `Vec` per row; `None` if missing,
    /// not a list, unreadable, or `item` refuses a value.
    fn map_lists(
        &self,
        element: &str,
        prop: &str,
        item_of: impl Fn(f64) -> Option<u32>,
    ) -> Option<Vec<Vec<u32>>> {
        let (def, data) = self.element_parts(element)?;
        let pi = def.props.iter().position(|p| p.name == prop)?;
        let PropertyKind::List { count, item } = def.props.get(pi)?.kind else {
            return None;
        };
        let layout = Layout::of(def, data)?;
        let mut out = Vec::with_capacity(def.count);
        layout.for_each_row(|row| {
            let off = field_offset(&def.props, row, pi)?;
            let n = list_len(count, row, off)?;
            let first = off.checked_add(count.size())?;
            let end = first.checked_add(n.checked_mul(item.size())?)?;
            let items = row.get(first..end)?;
            let mut list = Vec::with_capacity(n);
            for it in items.chunks_exact(item.size()) {
                list.push(item_of(item.read_f64(it, 0)?)?);
            }
            out.push(list);
            Some(())
        })?;
        Some(out)
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

    /// Writes the file as `binary_little_endian`, keeping comments, obj_info and every element,
    /// atomically (temporary file, then rename).
    pub fn write_path(&self, path: &Path) -> Result<()> {
        let head = self.header_text(path)?;
        crate::io::atomic::write_atomic(path, |w| {
            w.write_all(head.as_bytes())?;
            for body in &self.data {
                w.write_all(&body.bytes)?;
            }
            Ok(())
        })
    }

    /// Writes this file with scalar columns of `element` set to `columns` (name, type of a new
    /// column, one value per row) and `comments` added, without changing `self`: the result
    /// equals [`PlyFile::set_scalar_column`] for each column, then the comments, then
    /// [`PlyFile::write_path`]. Existing columns keep their type. Rows of fixed size are
    /// copied and extended once, in parallel; other layouts take the general path.
    pub fn write_path_with_columns(
        &self,
        path: &Path,
        element: &str,
        columns: &[(&str, ScalarType, &[f64])],
        comments: &[String],
    ) -> Result<()> {
        let general = || -> Result<()> {
            let mut ply = self.clone();
            for &(name, ty, vals) in columns {
                ply.set_scalar_column(element, name, ty, vals)?;
            }
            ply.header.comments.extend(comments.iter().cloned());
            ply.write_path(path)
        };
        let Some(ei) = self.header.elements.iter().position(|e| e.name == element) else {
            return general();
        };
        let (Some(def), Some(body)) = (self.header.elements.get(ei), self.data.get(ei)) else {
            return general();
        };
        let Some(Layout::Fixed { stride, bytes }) = Layout::of(def, body) else {
            return general();
        };
        if stride == 0 || columns.iter().any(|c| c.2.len() != def.count) {
            return general();
        }
        // Where each column goes: (offset in the output row, type, values).
        let mut out_def = def.clone();
        let mut fields: Vec<(usize, ScalarType, &[f64])> = Vec::with_capacity(columns.len());
        let mut out_stride = stride;
        for &(name, ty, vals) in columns {
            match out_def.props.iter().position(|p| p.name == name) {
                Some(pi) => {
                    let PropertyKind::Scalar(t) = out_def.props[pi].kind else {
                        return general();
                    };
                    let Some(off) = field_offset(&out_def.props, &[], pi) else {
                        return general();
                    };
                    fields.push((off, t, vals));
                }
                None => {
                    if check_name(name).is_err() {
                        return general();
                    }
                    fields.push((out_stride, ty, vals));
                    out_stride += ty.size();
                    out_def.props.push(Property {
                        name: name.to_string(),
                        kind: PropertyKind::Scalar(ty),
                    });
                }
            }
        }
        let mut header = self.header.clone();
        header.elements[ei] = out_def;
        header.comments.extend(comments.iter().cloned());
        let shell = PlyFile {
            header,
            data: Vec::new(),
        };
        // Every body must match its declaration, as for `write_path`.
        self.header_text(path)?;
        let head = shell.header_text_unchecked(path)?;
        // Rows are built in parallel, a batch at a time, so the copy stays small.
        const ROWS: usize = 1 << 15;
        let build = |first: usize, chunk: &[u8]| -> Vec<u8> {
            let n = chunk.len() / stride;
            let mut out = vec![0u8; n * out_stride];
            for (src, dst) in chunk
                .chunks_exact(stride)
                .zip(out.chunks_exact_mut(out_stride))
            {
                dst[..stride].copy_from_slice(src);
            }
            // A column at a time, so that each loop encodes one type.
            for &(off, ty, vals) in &fields {
                put_column(&mut out, out_stride, off, ty, &vals[first..first + n]);
            }
            out
        };
        crate::io::atomic::write_atomic(path, |w| {
            w.write_all(head.as_bytes())?;
            for (k, b) in self.data.iter().enumerate() {
                if k != ei {
                    w.write_all(&b.bytes)?;
                    continue;
                }
                let chunks: Vec<&[u8]> = bytes.chunks(stride * ROWS).collect();
                for batch in chunks.chunks(8).enumerate() {
                    let (bi, batch) = batch;
                    let built: Vec<Vec<u8>> = batch
                        .par_iter()
                        .enumerate()
                        .map(|(ci, c)| build((bi * 8 + ci) * ROWS, c))
                        .collect();
                    for b in &built {
                        w.write_all(b)?;
                    }
                }
            }
            Ok(())
        })
    }

    /// The header as written by [`PlyFile::write_path`] (binary little-endian), after checking
    /// that every body matches its declaration.
    fn header_text(&self, path: &Path) -> Result<String> {
        if self.data.len() != self.header.elements.len() {
            return Err(Error::Param(format!(
                "cannot write {}: {} element bodies for {} declared elements",
                path.display(),
                self.data.len(),
                self.header.elements.len()
            )));
        }
        for (def, body) in self.header.elements.iter().zip(&self.data) {
            if Layout::of(def, body).is_none() {
                return Err(Error::Param(format!(
                    "cannot write {}: element '{}': stored rows do not match the header \
                     declaration",
                    path.display(),
                    def.name
                )));
            }
        }
        self.header_text_unchecked(path)
    }

    /// The header text alone (names checked, bodies not).
    fn header_text_unchecked(&self, path: &Path) -> Result<String> {
        let mut head = String::with_capacity(1024);
        head.push_str("ply\nformat binary_little_endian 1.0\n");
        for c in &self.header.comments {
            head.push_str("comment ");
            head.push_str(&one_line(c));
            head.push('\n');
        }
        for c in &self.header.obj_info {
            head.push_str("obj_info ");
            head.push_str(&one_line(c));
            head.push('\n');
        }
        for def in &self.header.elements {
            let bad = |m: String| {
                Error::Param(format!(
                    "cannot write {}: element '{}': {m}",
                    path.display(),
                    def.name
                ))
            };
            check_name(&def.name).map_err(bad)?;
            head.push_str(&format!("element {} {}\n", def.name, def.count));
            for p in &def.props {
                check_name(&p.name).map_err(bad)?;
                match p.kind {
                    PropertyKind::Scalar(t) => {
                        head.push_str(&format!("property {} {}\n", t.name(), p.name));
                    }
                    PropertyKind::List { count, item } => head.push_str(&format!(
                        "property list {} {} {}\n",
                        count.name(),
                        item.name(),
                        p.name
                    )),
                }
            }
        }
        head.push_str("end_header\n");
        Ok(head)
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

    /// `f` of the values of scalar properties `props` of `element`, one result per row, in
    /// one pass (in parallel for fixed-size rows). `None` when the element or a property is
    /// missing or a list, or a fixed-size row is too short for a property; a value that cannot
    /// be read in a fixed-size row is NaN, in other layouts it makes the whole answer `None`.
    pub fn map_scalars<const K: usize, T: Send>(
        &self,
        element: &str,
        props: [&str; K],
        f: impl Fn([f64; K]) -> T + Sync,
    ) -> Option<Vec<T>> {
        let (def, data) = self.element_parts(element)?;
        let mut cols = [(0usize, ScalarType::U8); K];
        for (c, name) in cols.iter_mut().zip(props) {
            let i = def.props.iter().position(|p| p.name == name)?;
            let PropertyKind::Scalar(t) = def.props.get(i)?.kind else {
                return None;
            };
            *c = (i, t);
        }
        let layout = Layout::of(def, data)?;
        let mut out = Vec::with_capacity(def.count);
        match layout {
            Layout::Fixed { stride, bytes } => {
                let mut at = [(0usize, ScalarType::U8); K];
                for (a, &(i, t)) in at.iter_mut().zip(&cols) {
                    let off = field_offset(&def.props, &[], i)?;
                    if off + t.size() > stride {
                        return None;
                    }
                    *a = (off, t);
                }
                // In range for every row (checked above), so each read succeeds. `$read` reads
                // column `c` of a row.
                macro_rules! rows {
                    ($read:expr) => {
                        bytes
                            .par_chunks_exact(stride.max(1))
                            .map(|row| f(std::array::from_fn(|c| $read(row, c))))
                            .collect_into_vec(&mut out)
                    };
                }
                match uniform_type(&at) {
                    Some(t) => {
                        let offs = at.map(|a| a.0);
                        macro_rules! typed {
                            ($l:ty) => {
                                rows!(|row: &[u8], c: usize| <$l>::at(row, offs[c]))
                            };
                        }
                        uniform_dispatch!(t, typed)
                    }
                    None => rows!(|row: &[u8], c: usize| {
                        let (o, t): (usize, ScalarType) = at[c];
                        t.read_f64(row, o).unwrap_or(f64::NAN)
                    }),
                }
            }
            Layout::Rows { .. } => {
                layout.for_each_row(|row| {
                    let mut v = [0.0f64; K];
                    for (v, &(i, t)) in v.iter_mut().zip(&cols) {
                        *v = t.read_f64(row, field_offset(&def.props, row, i)?)?;
                    }
                    out.push(f(v));
                    Some(())
                })?;
            }
        }
        Some(out)
    }

    /// For each of the scalar properties `props` of `element`, how many rows hold a value
    /// `bad` says yes to: one pass over the rows with no per-row output (in parallel for
    /// fixed-size rows). `None` in the cases where [`map_scalars`](Self::map_scalars) gives
    /// `None`; a value that cannot be read in a fixed-size row counts as NaN.
    pub fn count_scalars(
        &self,
        element: &str,
        props: &[&str],
        bad: impl Fn(f64) -> bool + Sync,
    ) -> Option<Vec<usize>> {
        let (def, data) = self.element_parts(element)?;
        let mut cols = Vec::with_capacity(props.len());
        for name in props {
            let i = def.props.iter().position(|p| p.name == *name)?;
            let PropertyKind::Scalar(t) = def.props.get(i)?.kind else {
                return None;
            };
            cols.push((i, t));
        }
        let k = cols.len();
        let add = |mut a: Vec<usize>, b: Vec<usize>| {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
            a
        };
        match Layout::of(def, data)? {
            Layout::Fixed { stride, bytes } => {
                let mut at = Vec::with_capacity(k);
                for &(i, t) in &cols {
                    let off = field_offset(&def.props, &[], i)?;
                    if off + t.size() > stride {
                        return None;
                    }
                    at.push((off, t));
                }
                const ROWS: usize = 1 << 14;
                // `$read` reads column `c` of a row.
                macro_rules! counts {
                    ($read:expr) => {
                        bytes
                            .par_chunks(stride.max(1) * ROWS)
                            .map(|rows| {
                                let mut n = vec![0usize; k];
                                for row in rows.chunks_exact(stride.max(1)) {
                                    for (c, n) in n.iter_mut().enumerate() {
                                        *n += usize::from(bad($read(row, c)));
                                    }
                                }
                                n
                            })
                            .reduce(|| vec![0; k], add)
                    };
                }
                Some(match uniform_type(&at) {
                    Some(t) => {
                        let offs: Vec<usize> = at.iter().map(|a| a.0).collect();
                        macro_rules! typed {
                            ($l:ty) => {
                                counts!(|row: &[u8], c: usize| <$l>::at(row, offs[c]))
                            };
                        }
                        uniform_dispatch!(t, typed)
                    }
                    None => counts!(|row: &[u8], c: usize| {
                        let (o, t): (usize, ScalarType) = at[c];
                        t.read_f64(row, o).unwrap_or(f64::NAN)
                    }),
                })
            }
            layout @ Layout::Rows { .. } => {
                let mut n = vec![0usize; k];
                layout.for_each_row(|row| {
                    for (n, &(i, t)) in n.iter_mut().zip(&cols) {
                        *n += usize::from(bad(t.read_f64(row, field_offset(&def.props, row, i)?)?));
                    }
                    Some(())
                })?;
                Some(n)
            }
        }
    }

    /// Positions `[x, y, z]` of the `vertex` element (properties `x`, `y`, `z` of any scalar
    /// type, converted to f64), decoded in one pass over the rows: a fixed-stride walk when the
    /// element has no list property, the row offsets otherwise. `None` if there is no `vertex`
    /// element, one of `x`, `y`, `z` is missing or is a list, or the stored rows do not match
    /// the header.
    pub fn vertex_xyz(&self) -> Option<Vec<[f64; 3]>> {
        let (def, data) = self.element_parts("vertex")?;
        let find = |name: &str| -> Option<(usize, ScalarType)> {
            let i = def.props.iter().position(|p| p.name == name)?;
            match def.props.get(i)?.kind {
                PropertyKind::Scalar(t) => Some((i, t)),
                PropertyKind::List { .. } => None,
            }
        };
        let (ix, tx) = find("x")?;
        let (iy, ty) = find("y")?;
        let (iz, tz) = find("z")?;
        let layout = Layout::of(def, data)?;
        let mut out = Vec::with_capacity(def.count);
        match layout {
            Layout::Fixed { stride, bytes } => {
                let ox = field_offset(&def.props, &[], ix)?;
                let oy = field_offset(&def.props, &[], iy)?;
                let oz = field_offset(&def.props, &[], iz)?;
                if [(ox, tx), (oy, ty), (oz, tz)]
                    .iter()
                    .any(|&(o, t)| o + t.size() > stride)
                {
                    return None;
                }
                // In range for every row (checked above), so each read succeeds.
                let rd =
                    |t: ScalarType, row: &[u8], o: usize| t.read_f64(row, o).unwrap_or(f64::NAN);
                let rows = bytes.par_chunks_exact(stride.max(1));
                if [tx, ty, tz] == [ScalarType::F32; 3] {
                    let f = |row: &[u8], o: usize| {
                        le_array(row, o).map_or(f64::NAN, |b| f64::from(f32::from_le_bytes(b)))
                    };
                    rows.map(|row| [f(row, ox), f(row, oy), f(row, oz)])
                        .collect_into_vec(&mut out);
                } else {
                    rows.map(|row| [rd(tx, row, ox), rd(ty, row, oy), rd(tz, row, oz)])
                        .collect_into_vec(&mut out);
                }
            }
            Layout::Rows { .. } => {
                layout.for_each_row(|row| {
                    let ox = field_offset(&def.props, row, ix)?;
                    let oy = field_offset(&def.props, row, iy)?;
                    let oz = field_offset(&def.props, row, iz)?;
                    out.push([
                        tx.read_f64(row, ox)?,
                        ty.read_f64(row, oy)?,
                        tz.read_f64(row, oz)?,
                    ]);
                    Some(())
                })?;
            }
        }
        Some(out)
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

/// Capacity of the read buffer for big files.
const READ_BUF: usize = 4 << 20;
/// Longest header line accepted (a binary file without newlines must not be slurped).
const MAX_HEADER_LINE: u64 = 64 << 10;
/// Largest header accepted.
const MAX_HEADER_BYTES: u64 = 16 << 20;
/// Longest ascii token accepted.
const MAX_TOKEN: usize = 4096;
/// Reserved bulk reads at least this long are read by several threads.
const PARALLEL_READ_MIN: usize = 8 << 20;
/// Bulk reads grow their buffer by at most this much before data is seen.
const BULK_CHUNK: usize = 64 << 20;
/// Reservation cap when the file length is unknown (not a regular file).
const UNKNOWN_LEN_CAP: usize = 64 << 20;

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

/// Writes `vals` encoded as `ty` at offset `off` of consecutive rows of `stride` bytes, the
/// same bytes as [`ScalarType::encode`] value by value, with the type fixed in each loop.
fn put_column(rows: &mut [u8], stride: usize, off: usize, ty: ScalarType, vals: &[f64]) {
    #[inline(always)]
    fn fill<const N: usize>(rows: &mut [u8], stride: usize, off: usize, t: ScalarType, v: &[f64]) {
        for (row, &v) in rows.chunks_exact_mut(stride).zip(v) {
            let e = t.encode(v);
            row[off..off + N].copy_from_slice(&e.buf[..N]);
        }
    }
    use ScalarType as T;
    match ty {
        T::I8 => fill::<1>(rows, stride, off, T::I8, vals),
        T::U8 => fill::<1>(rows, stride, off, T::U8, vals),
        T::I16 => fill::<2>(rows, stride, off, T::I16, vals),
        T::U16 => fill::<2>(rows, stride, off, T::U16, vals),
        T::I32 => fill::<4>(rows, stride, off, T::I32, vals),
        T::U32 => fill::<4>(rows, stride, off, T::U32, vals),
        T::F32 => fill::<4>(rows, stride, off, T::F32, vals),
        T::F64 => fill::<8>(rows, stride, off, T::F64, vals),
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

// ---------------------------------------------------------------------------------------------
// Reading
// ---------------------------------------------------------------------------------------------

/// The open file being read, with the number of bytes consumed so far.
struct Source<'p> {
    r: BufReader<File>,
    /// Bytes consumed from the start of the file.
    pos: u64,
    /// Line of the next byte (1-based); kept up to date by header and ascii reading only.
    line: u64,
    /// File length, when the file is a regular file.
    len: Option<u64>,
    /// For error messages.
    path: &'p Path,
}

impl Source<'_> {
    fn err(&self, msg: impl Into<String>) -> Error {
        Error::format(self.path, msg)
    }

    fn io_err(&self, e: std::io::Error) -> Error {
        Error::io(self.path, e)
    }

    /// Bytes left after the current position, when the file length is known.
    fn remaining(&self) -> Option<u64> {
        self.len.map(|l| l.saturating_sub(self.pos))
    }

    /// How many bytes it is safe to reserve for data still to be read.
    fn reserve_cap(&self) -> usize {
        self.remaining().map_or(UNKNOWN_LEN_CAP, |r| {
            usize::try_from(r).unwrap_or(usize::MAX)
        })
    }

    /// One header line (with its line ending) into `line`; 0 at end of file.
    fn read_line(&mut self, line: &mut Vec<u8>) -> std::io::Result<usize> {
        line.clear();
        let n = (&mut self.r)
            .take(MAX_HEADER_LINE)
            .read_until(b'\n', line)?;
        self.pos += n as u64;
        if line.last() == Some(&b'\n') {
            self.line += 1;
        }
        Ok(n)
    }

    /// Fills `buf` as far as the file allows; returns the number of bytes read.
    fn read_full(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let mut got = 0;
        while let Some(rest) = buf.get_mut(got..).filter(|r| !r.is_empty()) {
            match self.r.read(rest) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        self.pos += got as u64;
        Ok(got)
    }

    /// [`Source::append`] of `n` reserved bytes by several threads at once, each reading its
    /// own stretch of the file at its offset (the file position is set past them after): the
    /// copy out of the page cache and the faults of a fresh buffer no longer hold up one core
    /// while the others wait for the decoding.
    #[cfg(unix)]
    fn append_parallel(&mut self, out: &mut Vec<u8>, n: usize) -> std::io::Result<usize> {
        use std::io::{Seek, SeekFrom};
        use std::mem::MaybeUninit;
        use std::os::unix::fs::FileExt;
        const CHUNK: usize = 4 << 20;
        let start = out.len();
        // What the buffered reader already holds comes first.
        let held = self.r.buffer();
        let head = held.len().min(n);
        out.extend_from_slice(&held[..head]);
        self.r.consume(head);
        let at = self.pos + head as u64;
        let rest = n - head;
        out.spare_capacity_mut()[..rest]
            .par_chunks_mut(CHUNK)
            .for_each(|c| c.fill(MaybeUninit::new(0)));
        // SAFETY: the `rest` bytes past the length were just initialised (and are reserved).
        unsafe { out.set_len(start + head + rest) };
        let file = self.r.get_ref();
        let got: Vec<std::io::Result<usize>> = out[start + head..]
            .par_chunks_mut(CHUNK)
            .enumerate()
            .map(|(k, dst)| {
                let mut done = 0;
                while done < dst.len() {
                    match file.read_at(&mut dst[done..], at + (k * CHUNK + done) as u64) {
                        Ok(0) => break,
                        Ok(m) => done += m,
                        Err(e) if e.kind() == ErrorKind::Interrupted => {}
                        Err(e) => return Err(e),
                    }
                }
                Ok(done)
            })
            .collect();
        // The bytes up to the first short stretch (the end of the file).
        let mut read = 0;
        for (k, g) in got.into_iter().enumerate() {
            let g = match g {
                Ok(g) => g,
                Err(e) => {
                    out.truncate(start);
                    return Err(e);
                }
            };
            read += g;
            if g < CHUNK.min(rest - k * CHUNK) {
                break;
            }
        }
        out.truncate(start + head + read);
        if let Err(e) = self.r.seek(SeekFrom::Start(at + read as u64)) {
            out.truncate(start);
            return Err(e);
        }
        self.pos = at + read as u64;
        Ok(head + read)
    }

    /// Appends up to `n` bytes to `out`, growing it chunk by chunk so that a bogus `n` never
    /// allocates more than the data actually present; returns the number of bytes appended.
    fn append(&mut self, out: &mut Vec<u8>, n: usize) -> std::io::Result<usize> {
        let start = out.len();
        if out.capacity() - start >= n {
            #[cfg(unix)]
            if n >= PARALLEL_READ_MIN {
                return self.append_parallel(out, n);
            }
            // Already reserved (the file is known to hold the bytes): read straight into the
            // spare capacity, without zero-filling it first.
            let res = (&mut self.r).take(n as u64).read_to_end(out);
            let got = out.len() - start;
            self.pos += got as u64;
            return match res {
                Ok(_) => Ok(got),
                Err(e) => {
                    out.truncate(start);
                    Err(e)
                }
            };
        }
        let mut done = 0;
        while done < n {
            let chunk = (n - done).min(BULK_CHUNK);
            let start = out.len();
            out.resize(start + chunk, 0);
            let got = match out.get_mut(start..) {
                Some(dst) => self.read_full(dst),
                None => Ok(0),
            };
            let got = match got {
                Ok(g) => g,
                Err(e) => {
                    out.truncate(start);
                    return Err(e);
                }
            };
            out.truncate(start + got);
            done += got;
            if got < chunk {
                break;
            }
        }
        Ok(done)
    }

    /// Next whitespace-separated token into `tok`: `None` at end of file, `Some(false)` if the
    /// token was longer than [`MAX_TOKEN`] (then `tok` holds its start). Line ends skipped on
    /// the way are counted in [`Source::line`].
    fn next_token(&mut self, tok: &mut Vec<u8>) -> std::io::Result<Option<bool>> {
        tok.clear();
        // Skip whitespace.
        loop {
            let buf = self.r.fill_buf()?;
            if buf.is_empty() {
                return Ok(None);
            }
            let (skip, found) = match buf.iter().position(|b| !b.is_ascii_whitespace()) {
                Some(i) => (i, true),
                None => (buf.len(), false),
            };
            self.line += buf[..skip].iter().filter(|&&b| b == b'\n').count() as u64;
            self.r.consume(skip);
            self.pos += skip as u64;
            if found {
                break;
            }
        }
        // Collect the token.
        let mut complete = true;
        loop {
            let buf = self.r.fill_buf()?;
            if buf.is_empty() {
                break;
            }
            let (take, end) = match buf.iter().position(|b| b.is_ascii_whitespace()) {
                Some(i) => (i, true),
                None => (buf.len(), false),
            };
            let room = MAX_TOKEN.saturating_sub(tok.len());
            if take > room {
                complete = false;
            }
            tok.extend_from_slice(buf.get(..take.min(room)).unwrap_or(&[]));
            self.r.consume(take);
            self.pos += take as u64;
            if end {
                break;
            }
        }
        Ok(Some(complete))
    }

    /// Consumes the rest of the current line, its line end included, and returns the number of
    /// tokens it held.
    fn rest_of_line(&mut self) -> std::io::Result<usize> {
        let mut tokens = 0;
        let mut in_token = false;
        loop {
            let buf = self.r.fill_buf()?;
            if buf.is_empty() {
                return Ok(tokens);
            }
            let mut used = buf.len();
            let mut ended = false;
            for (i, &b) in buf.iter().enumerate() {
                if b == b'\n' {
                    used = i + 1;
                    ended = true;
                    break;
                }
                let space = b.is_ascii_whitespace();
                if !space && !in_token {
                    tokens += 1;
                }
                in_token = !space;
            }
            self.r.consume(used);
            self.pos += used as u64;
            if ended {
                self.line += 1;
                return Ok(tokens);
            }
        }
    }
}

/// Reads the header up to and including the `end_header` line.
fn parse_header(src: &mut Source) -> Result<Header> {
    let mut line = Vec::with_capacity(256);
    let n = src.read_line(&mut line).map_err(|e| src.io_err(e))?;
    let first = line.get(..n).unwrap_or(&[]);
    if first.strip_suffix(b"\n").unwrap_or(first).trim_ascii() != b"ply" {
        return Err(src.err("not a PLY file (missing 'ply' magic)"));
    }
    let mut encoding = None;
    let mut comments = Vec::new();
    let mut obj_info = Vec::new();
    let mut elements: Vec<ElementDef> = Vec::new();
    let mut line_no = 1usize;
    loop {
        line_no += 1;
        if src.pos > MAX_HEADER_BYTES {
            return Err(src.err(format!(
                "header is longer than {MAX_HEADER_BYTES} bytes without 'end_header'"
            )));
        }
        let n = src.read_line(&mut line).map_err(|e| src.io_err(e))?;
        if n == 0 {
            return Err(src.err("header ends before 'end_header'"));
        }
        if line.last() != Some(&b'\n') && n as u64 == MAX_HEADER_LINE {
            return Err(src.err(format!(
                "line {line_no}: header line longer than {MAX_HEADER_LINE} bytes"
            )));
        }
        let text = String::from_utf8_lossy(&line);
        let text = text.trim_end_matches(['\n', '\r']).trim_start();
        if text.is_empty() {
            continue;
        }
        let (kw, rest) = text
            .split_once(|c: char| c.is_ascii_whitespace())
            .unwrap_or((text, ""));
        let words: Vec<&str> = rest.split_ascii_whitespace().collect();
        match kw {
            "format" => {
                if encoding.is_some() {
                    return Err(src.err(format!("line {line_no}: second 'format' line")));
                }
                let [fmt, version] = words.as_slice() else {
                    return Err(src.err(format!(
                        "line {line_no}: malformed format line '{text}' (expected 'format <encoding> 1.0')"
                    )));
                };
                encoding = Some(match *fmt {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::BinaryLe,
                    "binary_big_endian" => Encoding::BinaryBe,
                    other => {
                        return Err(src.err(format!("line {line_no}: unknown format '{other}'")))
                    }
                });
                if version.parse::<f64>().ok() != Some(1.0) {
                    return Err(src.err(format!(
                        "line {line_no}: unsupported ply version '{version}'"
                    )));
                }
            }
            // A carriage return inside the text becomes a space, as the writer does, so a
            // written file reads back the same.
            "comment" => comments.push(one_line(rest.trim_start())),
            "obj_info" => obj_info.push(one_line(rest.trim_start())),
            "element" => {
                let [name, count] = words.as_slice() else {
                    return Err(src.err(format!(
                        "line {line_no}: malformed element line '{text}' (expected 'element <name> <count>')"
                    )));
                };
                let count = count.parse::<usize>().map_err(|_| {
                    src.err(format!(
                        "line {line_no}: element count '{count}' is not a non-negative integer"
                    ))
                })?;
                if elements.iter().any(|e| e.name == *name) {
                    return Err(src.err(format!(
                        "line {line_no}: element '{name}' is declared twice"
                    )));
                }
                elements.push(ElementDef {
                    name: (*name).to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            "property" => {
                let Some(el) = elements.last_mut() else {
                    return Err(src.err(format!(
                        "line {line_no}: property declared before any element"
                    )));
                };
                let ty = |s: &str| {
                    ScalarType::parse(s).ok_or_else(|| {
                        src.err(format!("line {line_no}: unknown property type '{s}'"))
                    })
                };
                let prop = match words.as_slice() {
                    ["list", ct, it, name] => {
                        let count = ty(ct)?;
                        if count.int_range().is_none() {
                            return Err(src.err(format!(
                                "line {line_no}: list count type '{ct}' is not an integer type"
                            )));
                        }
                        Property {
                            name: (*name).to_string(),
                            kind: PropertyKind::List {
                                count,
                                item: ty(it)?,
                            },
                        }
                    }
                    [t, name] if *t != "list" => Property {
                        name: (*name).to_string(),
                        kind: PropertyKind::Scalar(ty(t)?),
                    },
                    _ => {
                        return Err(
                            src.err(format!("line {line_no}: malformed property line '{text}'"))
                        )
                    }
                };
                if el.props.iter().any(|p| p.name == prop.name) {
                    return Err(src.err(format!(
                        "line {line_no}: element '{}' declares property '{}' twice",
                        el.name, prop.name
                    )));
                }
                el.props.push(prop);
            }
            "end_header" => break,
            other => {
                return Err(src.err(format!("line {line_no}: unknown header keyword '{other}'")))
            }
        }
    }
    let encoding = encoding.ok_or_else(|| src.err("header has no 'format' line"))?;
    Ok(Header {
        encoding,
        comments,
        obj_info,
        elements,
    })
}

/// Reads the body of one element into little-endian rows.
fn read_element(src: &mut Source, enc: Encoding, def: &ElementDef) -> Result<ElementData> {
    if def.props.is_empty() {
        // Rows without properties hold no bytes in any encoding.
        return Ok(ElementData::default());
    }
    match (enc, fixed_stride(&def.props)) {
        (Encoding::Ascii, _) => read_ascii(src, def),
        (_, Some(stride)) => read_binary_fixed(src, enc == Encoding::BinaryBe, def, stride),
        (_, None) => read_binary_rows(src, enc == Encoding::BinaryBe, def),
    }
}

fn truncated(src: &Source, def: &ElementDef, row: usize) -> Error {
    src.err(format!(
        "truncated: element '{}' has {} rows but data ends in row {row}",
        def.name, def.count
    ))
}

/// A fixed-stride binary element: one bulk read, then (big endian) an in-place byte swap.
fn read_binary_fixed(
    src: &mut Source,
    big_endian: bool,
    def: &ElementDef,
    stride: usize,
) -> Result<ElementData> {
    let total = def.count.checked_mul(stride).ok_or_else(|| {
        src.err(format!(
            "element '{}' declares {} rows of {stride} bytes, more than can be addressed",
            def.name, def.count
        ))
    })?;
    // Fail before allocating when the file is known to be too short.
    if let Some(rem) = src.remaining() {
        if (total as u64) > rem {
            let rows = usize::try_from(rem / stride as u64).unwrap_or(usize::MAX);
            return Err(truncated(src, def, rows));
        }
    }
    let mut bytes = Vec::with_capacity(total.min(src.reserve_cap()));
    let got = src.append(&mut bytes, total).map_err(|e| src.io_err(e))?;
    if got < total {
        return Err(truncated(src, def, got / stride));
    }
    if big_endian {
        let mut fields = Vec::with_capacity(def.props.len());
        let mut off = 0;
        for p in &def.props {
            if let PropertyKind::Scalar(t) = p.kind {
                if t.size() > 1 {
                    fields.push(off..off + t.size());
                }
                off += t.size();
            }
        }
        if !fields.is_empty() {
            for row in bytes.chunks_exact_mut(stride) {
                for f in &fields {
                    if let Some(x) = row.get_mut(f.clone()) {
                        x.reverse();
                    }
                }
            }
        }
    }
    Ok(ElementData {
        bytes,
        row_offsets: None,
    })
}

/// A binary element with list properties, row by row.
fn read_binary_rows(src: &mut Source, big_endian: bool, def: &ElementDef) -> Result<ElementData> {
    // Smallest possible row: every scalar plus every list count.
    let min_row: usize = def
        .props
        .iter()
        .map(|p| match p.kind {
            PropertyKind::Scalar(t) => t.size(),
            PropertyKind::List { count, .. } => count.size(),
        })
        .sum::<usize>()
        .max(1);
    let max_rows = src.reserve_cap() / min_row;
    let mut offs = Vec::with_capacity(def.count.min(max_rows).saturating_add(1));
    let mut bytes = Vec::with_capacity(def.count.min(max_rows).saturating_mul(min_row));
    offs.push(0);
    let mut tmp = [0u8; 8];
    for row in 0..def.count {
        for p in &def.props {
            match p.kind {
                PropertyKind::Scalar(t) => {
                    let v = read_scalar(src, t, big_endian, &mut tmp, def, row)?;
                    bytes.extend_from_slice(v);
                }
                PropertyKind::List { count, item } => {
                    let c = read_scalar(src, count, big_endian, &mut tmp, def, row)?;
                    let n = count.read_f64(c, 0).unwrap_or(0.0);
                    if n < 0.0 {
                        return Err(src.err(format!(
                            "element '{}' row {row}: list count {n} is negative",
                            def.name
                        )));
                    }
                    bytes.extend_from_slice(c);
                    let n = n as usize;
                    let need = n.checked_mul(item.size());
                    let short = match (need, src.remaining()) {
                        (None, _) => true,
                        (Some(need), Some(rem)) => need as u64 > rem,
                        (Some(_), None) => false,
                    };
                    if short {
                        return Err(src.err(format!(
                            "truncated: element '{}' has {} rows but data ends in row {row} \
                             (list '{}' of {n} items goes past the end of the file)",
                            def.name, def.count, p.name
                        )));
                    }
                    let need = need.unwrap_or(0);
                    let start = bytes.len();
                    let got = src.append(&mut bytes, need).map_err(|e| src.io_err(e))?;
                    if got < need {
                        return Err(truncated(src, def, row));
                    }
                    if big_endian && item.size() > 1 {
                        if let Some(items) = bytes.get_mut(start..) {
                            for it in items.chunks_exact_mut(item.size()) {
                                it.reverse();
                            }
                        }
                    }
                }
            }
        }
        offs.push(bytes.len());
    }
    Ok(ElementData {
        bytes,
        row_offsets: Some(offs),
    })
}

/// One binary scalar as little-endian bytes (a slice of `tmp`).
fn read_scalar<'t>(
    src: &mut Source,
    t: ScalarType,
    big_endian: bool,
    tmp: &'t mut [u8; 8],
    def: &ElementDef,
    row: usize,
) -> Result<&'t [u8]> {
    let size = t.size();
    let buf = tmp.get_mut(..size).unwrap_or(&mut []);
    let got = src.read_full(buf).map_err(|e| src.io_err(e))?;
    if got < size {
        return Err(truncated(src, def, row));
    }
    if big_endian {
        buf.reverse();
    }
    Ok(buf)
}

/// Why an ascii token is not a value of its type.
enum AsciiProblem {
    NotNumber,
    NotInteger,
    OutOfRange,
}

/// Parses an ascii integer (`12`, `-3`, `+4`, or a whole number written as a float, `5.0`).
fn parse_int(tok: &[u8]) -> std::result::Result<i64, AsciiProblem> {
    let s = std::str::from_utf8(tok).map_err(|_| AsciiProblem::NotNumber)?;
    if let Ok(v) = s.parse::<i64>() {
        return Ok(v);
    }
    match s.parse::<f64>() {
        Ok(f) if f.is_finite() && f.fract() == 0.0 => {
            if (-9.2e18..=9.2e18).contains(&f) {
                Ok(f as i64)
            } else {
                Err(AsciiProblem::OutOfRange)
            }
        }
        Ok(f) if f.is_infinite() => Err(AsciiProblem::OutOfRange),
        Ok(_) => Err(AsciiProblem::NotInteger),
        Err(_) => Err(AsciiProblem::NotNumber),
    }
}

/// Parses an ascii token as type `t`, little endian.
fn parse_ascii(tok: &[u8], t: ScalarType) -> std::result::Result<Encoded, AsciiProblem> {
    match t {
        ScalarType::F32 => {
            let s = std::str::from_utf8(tok).map_err(|_| AsciiProblem::NotNumber)?;
            let v = s.parse::<f32>().map_err(|_| AsciiProblem::NotNumber)?;
            let mut e = Encoded {
                buf: [0; 8],
                len: 4,
            };
            e.buf[..4].copy_from_slice(&v.to_le_bytes());
            Ok(e)
        }
        ScalarType::F64 => {
            let s = std::str::from_utf8(tok).map_err(|_| AsciiProblem::NotNumber)?;
            let v = s.parse::<f64>().map_err(|_| AsciiProblem::NotNumber)?;
            Ok(Encoded {
                buf: v.to_le_bytes(),
                len: 8,
            })
        }
        _ => {
            let v = parse_int(tok)?;
            let (lo, hi) = t.int_range().unwrap_or((0, 0));
            if v < lo || v > hi {
                return Err(AsciiProblem::OutOfRange);
            }
            // Exact: the value is a whole number within the type's range.
            Ok(t.encode(v as f64))
        }
    }
}

/// A token for an error message (lossy, shortened).
fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(tok);
    if s.chars().count() > 40 {
        format!("{}…", s.chars().take(40).collect::<String>())
    } else {
        s.into_owned()
    }
}

/// An ascii element, token by token, with one reused token buffer. Each row is one line: a
/// line with too few or too many values for the element's properties is an error naming it.
fn read_ascii(src: &mut Source, def: &ElementDef) -> Result<ElementData> {
    let stride = fixed_stride(&def.props);
    let has_lists = stride.is_none();
    // Every ascii value takes at least two bytes (a digit and a separator).
    let min_row = def.props.len().saturating_mul(2).max(1);
    let max_rows = src.reserve_cap() / min_row + 1;
    let rows_cap = def.count.min(max_rows);
    let mut bytes = Vec::with_capacity(rows_cap.saturating_mul(stride.unwrap_or(min_row)));
    let mut offs = if has_lists {
        let mut o = Vec::with_capacity(rows_cap.saturating_add(1));
        o.push(0);
        Some(o)
    } else {
        None
    };
    let lists = def
        .props
        .iter()
        .filter(|p| matches!(p.kind, PropertyKind::List { .. }))
        .count();
    let mut tok = Vec::with_capacity(64);
    for row in 0..def.count {
        // Blank lines before a row are skipped; the row's first value fixes its line.
        next_ascii(src, &mut tok, def, row)?;
        let mut shape = RowShape {
            line: src.line,
            got: 0,
            want: def.props.len(),
            open_lists: lists,
        };
        for (pi, p) in def.props.iter().enumerate() {
            let (value_type, is_list) = match p.kind {
                PropertyKind::Scalar(t) => (t, None),
                PropertyKind::List { count, item } => (count, Some(item)),
            };
            if pi > 0 {
                shape.next(src, &mut tok, def, row)?;
            }
            shape.got += 1;
            let Some(item) = is_list else {
                let v = parse_ascii(&tok, value_type)
                    .map_err(|e| ascii_error(src, &tok, e, value_type, def, row, &p.name))?;
                bytes.extend_from_slice(v.as_slice());
                continue;
            };
            let n = match parse_int(&tok) {
                Ok(n) if n < 0 => {
                    return Err(src.err(format!(
                        "element '{}' row {row}: list count {n} is negative",
                        def.name
                    )))
                }
                Ok(n) => n,
                Err(e) => return Err(ascii_error(src, &tok, e, value_type, def, row, &p.name)),
            };
            let (_, hi) = value_type.int_range().unwrap_or((0, 0));
            if n > hi {
                return Err(src.err(format!(
                    "element '{}' row {row}: list count {n} is too large for its type {}",
                    def.name,
                    value_type.name()
                )));
            }
            shape.open_lists -= 1;
            shape.want = shape.want.saturating_add(n as usize);
            bytes.extend_from_slice(value_type.encode(n as f64).as_slice());
            for _ in 0..n {
                shape.next(src, &mut tok, def, row)?;
                shape.got += 1;
                let v = parse_ascii(&tok, item)
                    .map_err(|e| ascii_error(src, &tok, e, item, def, row, &p.name))?;
                bytes.extend_from_slice(v.as_slice());
            }
        }
        let extra = src.rest_of_line().map_err(|e| src.io_err(e))?;
        if extra > 0 {
            shape.got += extra;
            return Err(shape.error(src, def, row));
        }
        if let Some(o) = offs.as_mut() {
            o.push(bytes.len());
        }
    }
    Ok(ElementData {
        bytes,
        row_offsets: offs,
    })
}

/// The values of one ascii row read so far, against those its properties call for.
struct RowShape {
    /// The row's line.
    line: u64,
    /// Values read.
    got: usize,
    /// Values called for: one per scalar and list count, plus the items of the lists read.
    want: usize,
    /// Lists whose count is not read yet (each may call for more values).
    open_lists: usize,
}

impl RowShape {
    /// The next value of the row, which must be on the row's line.
    fn next(
        &self,
        src: &mut Source,
        tok: &mut Vec<u8>,
        def: &ElementDef,
        row: usize,
    ) -> Result<()> {
        next_ascii(src, tok, def, row)?;
        if src.line != self.line {
            return Err(self.error(src, def, row));
        }
        Ok(())
    }

    /// The error of a row with the wrong number of values.
    fn error(&self, src: &Source, def: &ElementDef, row: usize) -> Error {
        let at_least = if self.open_lists > 0 { "at least " } else { "" };
        src.err(format!(
            "line {}: {} {row} has {} values, expected {at_least}{}",
            self.line, def.name, self.got, self.want
        ))
    }
}

/// The next ascii token of element `def`, row `row`, or the matching error.
fn next_ascii(src: &mut Source, tok: &mut Vec<u8>, def: &ElementDef, row: usize) -> Result<()> {
    match src.next_token(tok).map_err(|e| src.io_err(e))? {
        None => Err(truncated(src, def, row)),
        Some(false) => Err(src.err(format!(
            "line {}: ascii value '{}' in element '{}' row {row} is longer than {MAX_TOKEN} \
             characters",
            src.line,
            show(tok),
            def.name
        ))),
        Some(true) => Ok(()),
    }
}

/// A warning for data after the last element: any byte of a binary file, anything but
/// whitespace in an ascii one.
fn trailing_data(src: &mut Source, enc: Encoding) -> Result<Option<String>> {
    let what = src.path.display().to_string();
    let path = src.path;
    if enc == Encoding::Ascii {
        loop {
            let buf = src.r.fill_buf().map_err(|e| Error::io(path, e))?;
            let n = buf.len();
            if n == 0 {
                return Ok(None);
            }
            let nl = |b: &[u8]| b.iter().filter(|&&c| c == b'\n').count() as u64;
            if let Some(i) = buf.iter().position(|b| !b.is_ascii_whitespace()) {
                let line = src.line + nl(&buf[..i]);
                return Ok(Some(format!(
                    "{what}: line {line}: data after the last element ignored"
                )));
            }
            src.line += nl(buf);
            src.r.consume(n);
            src.pos += n as u64;
        }
    }
    let extra = match src.remaining() {
        Some(r) => r,
        None => std::io::copy(&mut src.r, &mut std::io::sink()).map_err(|e| src.io_err(e))?,
    };
    Ok((extra > 0).then(|| format!("{what}: {extra} bytes after the last element ignored")))
}

fn ascii_error(
    src: &Source,
    tok: &[u8],
    e: AsciiProblem,
    t: ScalarType,
    def: &ElementDef,
    row: usize,
    prop: &str,
) -> Error {
    let what = match e {
        AsciiProblem::NotNumber => "is not a number".to_string(),
        AsciiProblem::NotInteger => format!("is not an integer (type {})", t.name()),
        AsciiProblem::OutOfRange => format!("is out of range for type {}", t.name()),
    };
    src.err(format!(
        "line {}: ascii value '{}' in element '{}' row {row} {what} (property '{prop}')",
        src.line,
        show(tok),
        def.name
    ))
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
