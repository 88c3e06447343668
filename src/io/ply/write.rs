//! Writing: always binary little endian, atomically.

use super::*;
use rayon::prelude::*;
use std::io::Write;

impl PlyFile {
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
}

/// Writes `vals` encoded as `ty` at offset `off` of consecutive rows of `stride` bytes, the
/// same bytes as [`ScalarType::encode`] value by value, with the type fixed in each loop.
pub(super) fn put_column(rows: &mut [u8], stride: usize, off: usize, ty: ScalarType, vals: &[f64]) {
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
