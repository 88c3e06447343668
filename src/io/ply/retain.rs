//! Dropping vertices from a [`PlyFile`] (those with non-finite coordinates, which never reach
//! an output) while keeping every other element consistent: vertex references in index lists
//! (`vertex_indices`, `vertex_index`) are renumbered; a face that loses a vertex is dropped,
//! any other list just loses the reference (a `range_grid` cell becomes empty).

use super::{ElementData, PlyFile, PropertyKind, ScalarType};
use crate::error::{Error, Result};

fn size(t: ScalarType) -> usize {
    match t {
        ScalarType::I8 | ScalarType::U8 => 1,
        ScalarType::I16 | ScalarType::U16 => 2,
        ScalarType::I32 | ScalarType::U32 | ScalarType::F32 => 4,
        ScalarType::F64 => 8,
    }
}

/// The little-endian value of type `t` at the start of `b`; `None` if `b` is too short.
fn read(t: ScalarType, b: &[u8]) -> Option<f64> {
    let a = |n: usize| -> Option<[u8; 8]> {
        let mut x = [0u8; 8];
        x.get_mut(..n)?.copy_from_slice(b.get(..n)?);
        Some(x)
    };
    Some(match t {
        ScalarType::I8 => f64::from(a(1)?[0] as i8),
        ScalarType::U8 => f64::from(a(1)?[0]),
        ScalarType::I16 => {
            let x = a(2)?;
            f64::from(i16::from_le_bytes([x[0], x[1]]))
        }
        ScalarType::U16 => {
            let x = a(2)?;
            f64::from(u16::from_le_bytes([x[0], x[1]]))
        }
        ScalarType::I32 => {
            let x = a(4)?;
            f64::from(i32::from_le_bytes([x[0], x[1], x[2], x[3]]))
        }
        ScalarType::U32 => {
            let x = a(4)?;
            f64::from(u32::from_le_bytes([x[0], x[1], x[2], x[3]]))
        }
        ScalarType::F32 => {
            let x = a(4)?;
            f64::from(f32::from_le_bytes([x[0], x[1], x[2], x[3]]))
        }
        ScalarType::F64 => f64::from_le_bytes(a(8)?),
    })
}

/// A list item as a vertex index: only a whole, non-negative number refers to a vertex (so a
/// negative, fractional or NaN item is a dangling reference, never vertex 0).
fn as_index(v: f64) -> Option<usize> {
    (v.fract() == 0.0 && v >= 0.0 && v <= usize::MAX as f64).then_some(v as usize)
}

fn write(t: ScalarType, v: f64, out: &mut Vec<u8>) {
    match t {
        ScalarType::I8 => out.push(v as i8 as u8),
        ScalarType::U8 => out.push(v as u8),
        ScalarType::I16 => out.extend_from_slice(&(v as i16).to_le_bytes()),
        ScalarType::U16 => out.extend_from_slice(&(v as u16).to_le_bytes()),
        ScalarType::I32 => out.extend_from_slice(&(v as i32).to_le_bytes()),
        ScalarType::U32 => out.extend_from_slice(&(v as u32).to_le_bytes()),
        ScalarType::F32 => out.extend_from_slice(&(v as f32).to_le_bytes()),
        ScalarType::F64 => out.extend_from_slice(&v.to_le_bytes()),
    }
}

/// Byte ranges of each row of an element; `None` if the stored rows do not fit the bytes.
fn rows(data: &ElementData, count: usize) -> Option<Vec<(usize, usize)>> {
    let ranges: Vec<(usize, usize)> = match &data.row_offsets {
        Some(o) => {
            if o.len() != count.checked_add(1)? {
                return None;
            }
            o.windows(2).map(|w| (w[0], w[1])).collect()
        }
        None => {
            if count == 0 {
                return data.bytes.is_empty().then(Vec::new);
            }
            let stride = data.bytes.len() / count;
            if stride.checked_mul(count)? != data.bytes.len() {
                return None;
            }
            if stride == 0 {
                // A property-less element: no bytes, and rows need not be listed one by one.
                return Some(Vec::new());
            }
            (0..count).map(|i| (i * stride, (i + 1) * stride)).collect()
        }
    };
    ranges
        .iter()
        .all(|&(a, b)| a <= b && b <= data.bytes.len())
        .then_some(ranges)
}

impl PlyFile {
    /// Keeps only the vertices with `keep[i]`, renumbering vertex references elsewhere.
    ///
    /// A list item that is not a whole number in `0..vertex count` (negative, fractional,
    /// NaN, too large) refers to no vertex and is handled like a reference to a dropped vertex.
    /// Stored rows that do not match the header give an error, never a panic.
    pub fn retain_vertices(mut self, keep: &[bool]) -> Result<PlyFile> {
        let bad = |m: &str| Error::Param(format!("cannot drop vertices: {m}"));
        let mismatch = |name: &str| {
            Error::Param(format!(
                "cannot drop vertices: element '{name}': stored rows do not match the header \
                 declaration"
            ))
        };
        let vi = self
            .element("vertex")
            .ok_or_else(|| bad("no vertex element"))?;
        let n = self
            .header
            .elements
            .get(vi)
            .ok_or_else(|| bad("no vertex element"))?
            .count;
        if keep.len() != n {
            return Err(bad("mask length differs from the vertex count"));
        }
        if self.data.len() != self.header.elements.len() {
            return Err(bad("element bodies do not match the declared elements"));
        }
        // New index of every kept vertex.
        let mut new_index: Vec<Option<usize>> = vec![None; n];
        let mut k = 0usize;
        for (slot, &kp) in new_index.iter_mut().zip(keep) {
            if kp {
                *slot = Some(k);
                k += 1;
            }
        }
        // Vertex rows.
        let vdata = &self.data[vi];
        let vrows = rows(vdata, n).ok_or_else(|| mismatch("vertex"))?;
        let mut bytes = Vec::with_capacity(vdata.bytes.len());
        let mut offs = vdata.row_offsets.as_ref().map(|_| vec![0usize]);
        for (&(a, b), _) in vrows.iter().zip(keep).filter(|(_, &kp)| kp) {
            bytes.extend_from_slice(vdata.bytes.get(a..b).ok_or_else(|| mismatch("vertex"))?);
            if let Some(o) = offs.as_mut() {
                o.push(bytes.len());
            }
        }
        self.data[vi] = ElementData {
            bytes,
            row_offsets: offs,
        };
        self.header.elements[vi].count = k;
        // Index lists of the other elements.
        for ei in 0..self.header.elements.len() {
            let def = &self.header.elements[ei];
            if ei == vi
                || !def.props.iter().any(|p| {
                    matches!(p.kind, PropertyKind::List { .. })
                        && (p.name == "vertex_indices" || p.name == "vertex_index")
                })
            {
                continue;
            }
            let is_face = def.name == "face";
            let data = &self.data[ei];
            let ranges = rows(data, def.count).ok_or_else(|| mismatch(&def.name))?;
            let mut out = Vec::with_capacity(data.bytes.len());
            let mut offs = vec![0usize];
            let mut items = Vec::new();
            for (a, b) in ranges {
                let row = data.bytes.get(a..b).ok_or_else(|| mismatch(&def.name))?;
                // The bytes of the row from `off` on.
                let at = |off: usize| row.get(off..).ok_or_else(|| mismatch(&def.name));
                let start = out.len();
                let mut off = 0usize;
                let mut drop_row = false;
                for p in &def.props {
                    match p.kind {
                        PropertyKind::Scalar(t) => {
                            let field =
                                at(off)?.get(..size(t)).ok_or_else(|| mismatch(&def.name))?;
                            out.extend_from_slice(field);
                            off += size(t);
                        }
                        PropertyKind::List { count, item } => {
                            let c = read(count, at(off)?).ok_or_else(|| mismatch(&def.name))?;
                            off += size(count);
                            let c = as_index(c).ok_or_else(|| mismatch(&def.name))?;
                            // Every item must be inside the row: checked before reserving.
                            if c.checked_mul(size(item)).is_none_or(|len| len > row.len()) {
                                return Err(mismatch(&def.name));
                            }
                            items.clear();
                            for _ in 0..c {
                                items
                                    .push(read(item, at(off)?).ok_or_else(|| mismatch(&def.name))?);
                                off += size(item);
                            }
                            if p.name == "vertex_indices" || p.name == "vertex_index" {
                                let before = items.len();
                                items.retain_mut(|v| {
                                    match as_index(*v).and_then(|old| new_index.get(old)) {
                                        Some(&Some(m)) => {
                                            *v = m as f64;
                                            true
                                        }
                                        _ => false,
                                    }
                                });
                                drop_row |= is_face && items.len() != before;
                            }
                            write(count, items.len() as f64, &mut out);
                            for &v in &items {
                                write(item, v, &mut out);
                            }
                        }
                    }
                }
                if off != row.len() {
                    return Err(mismatch(&def.name));
                }
                if drop_row {
                    out.truncate(start);
                } else {
                    offs.push(out.len());
                }
            }
            self.header.elements[ei].count = offs.len() - 1;
            self.data[ei] = ElementData {
                bytes: out,
                row_offsets: Some(offs),
            };
        }
        Ok(self)
    }
}
