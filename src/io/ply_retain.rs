//! Dropping vertices from a [`PlyFile`] (those with non-finite coordinates, which never reach
//! an output) while keeping every other element consistent: vertex references in index lists
//! (`vertex_indices`, `vertex_index`) are renumbered; a face that loses a vertex is dropped,
//! any other list just loses the reference (a `range_grid` cell becomes empty).

use super::ply::{ElementData, PlyFile, PropertyKind, ScalarType};
use crate::error::{Error, Result};

fn size(t: ScalarType) -> usize {
    match t {
        ScalarType::I8 | ScalarType::U8 => 1,
        ScalarType::I16 | ScalarType::U16 => 2,
        ScalarType::I32 | ScalarType::U32 | ScalarType::F32 => 4,
        ScalarType::F64 => 8,
    }
}

fn read(t: ScalarType, b: &[u8]) -> f64 {
    let a = |n: usize| -> [u8; 8] {
        let mut x = [0u8; 8];
        x[..n].copy_from_slice(&b[..n]);
        x
    };
    match t {
        ScalarType::I8 => b[0] as i8 as f64,
        ScalarType::U8 => b[0] as f64,
        ScalarType::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
        ScalarType::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
        ScalarType::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        ScalarType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        ScalarType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        ScalarType::F64 => f64::from_le_bytes(a(8)),
    }
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

/// Byte ranges of each row of an element.
fn rows(data: &ElementData, count: usize) -> Vec<(usize, usize)> {
    match &data.row_offsets {
        Some(o) => o.windows(2).map(|w| (w[0], w[1])).collect(),
        None => {
            let stride = data.bytes.len().checked_div(count).unwrap_or(0);
            (0..count).map(|i| (i * stride, (i + 1) * stride)).collect()
        }
    }
}

impl PlyFile {
    /// Keeps only the vertices with `keep[i]`, renumbering vertex references elsewhere.
    pub fn retain_vertices(mut self, keep: &[bool]) -> Result<PlyFile> {
        let bad = |m: &str| Error::Param(format!("cannot drop vertices: {m}"));
        let vi = self
            .element("vertex")
            .ok_or_else(|| bad("no vertex element"))?;
        let n = self.header.elements[vi].count;
        if keep.len() != n {
            return Err(bad("mask length differs from the vertex count"));
        }
        let mut new_index = vec![u32::MAX; n];
        let mut k = 0u32;
        for (i, &kp) in keep.iter().enumerate() {
            if kp {
                new_index[i] = k;
                k += 1;
            }
        }
        // Vertex rows.
        let vrows = rows(&self.data[vi], n);
        let mut bytes = Vec::with_capacity(self.data[vi].bytes.len());
        let mut offs = self.data[vi].row_offsets.as_ref().map(|_| vec![0usize]);
        for (i, &(a, b)) in vrows.iter().enumerate() {
            if keep[i] {
                bytes.extend_from_slice(&self.data[vi].bytes[a..b]);
                if let Some(o) = offs.as_mut() {
                    o.push(bytes.len());
                }
            }
        }
        self.data[vi] = ElementData {
            bytes,
            row_offsets: offs,
        };
        self.header.elements[vi].count = k as usize;
        // Index lists of the other elements.
        for ei in 0..self.header.elements.len() {
            let def = self.header.elements[ei].clone();
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
            let mut out = Vec::with_capacity(data.bytes.len());
            let mut offs = vec![0usize];
            let mut items = Vec::new();
            for (a, b) in rows(data, def.count) {
                let row = &data.bytes[a..b];
                let start = out.len();
                let mut off = 0usize;
                let mut drop_row = false;
                for p in &def.props {
                    match p.kind {
                        PropertyKind::Scalar(t) => {
                            out.extend_from_slice(&row[off..off + size(t)]);
                            off += size(t);
                        }
                        PropertyKind::List { count, item } => {
                            let c = read(count, &row[off..]) as usize;
                            off += size(count);
                            items.clear();
                            for _ in 0..c {
                                items.push(read(item, &row[off..]));
                                off += size(item);
                            }
                            if p.name == "vertex_indices" || p.name == "vertex_index" {
                                let before = items.len();
                                items.retain_mut(|v| {
                                    let old = *v as usize;
                                    match new_index.get(old) {
                                        Some(&m) if m != u32::MAX => {
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
